"""Names written once for every program: zones, controller modes and fault codes (docs/contract.md)."""

from __future__ import annotations

from enum import StrEnum


class Zone(StrEnum):
    AUTONOMOUS = "autonomous"
    GUARDED_DISTANCE = "guarded_distance"
    REDUCED_SPEED = "reduced_speed"
    SAFETY_EXCEPTION = "safety_exception"
