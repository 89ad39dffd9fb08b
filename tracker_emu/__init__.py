"""Tracker emulator: scripted humans as body capsules, published like one or several real sensors."""
