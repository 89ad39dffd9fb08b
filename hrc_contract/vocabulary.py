"""Names written once for every program: zones and controller modes (docs/contract.md).

The fault codes and rejection reasons are the tables of docs/contract.md (the tests hold the code to them).
"""

from __future__ import annotations

from enum import StrEnum
from typing import Literal


class Zone(StrEnum):
    """A robot's zone (safety-math.md §6)."""

    AUTONOMOUS = "autonomous"
    GUARDED_DISTANCE = "guarded_distance"
    REDUCED_SPEED = "reduced_speed"
    SAFETY_EXCEPTION = "safety_exception"


ZoneName = Literal["autonomous", "guarded_distance", "reduced_speed", "safety_exception"]
"""The values of :class:`Zone`, as the status models declare them (a test holds the two equal)."""

ControllerMode = Literal["running", "stopped", "protective_stop"]
"""``mode`` of a joint state: running, stopped (δ reached 0) or protective_stop (the override watchdog expired)."""
