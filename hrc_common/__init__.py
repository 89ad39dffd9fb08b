"""Shared parts of the three programs: wire messages, key expressions, configuration, process plumbing."""
