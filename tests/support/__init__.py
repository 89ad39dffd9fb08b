"""Helpers shared by the tests: known cases, cell files, the secured cell, status examples, a headless browser."""
