"""Tracker emulator: scripted humans as body capsules, published like one or several real sensors."""

__all__ = [
    "body",
    "emulator",
    "main",
    "occlusion",
    "robot_links",
    "ros2_zed",
    "scenario",
    "sensor",
]
