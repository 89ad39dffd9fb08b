"""The two clocks of a process, read together.

- ``wall_ns``: the Unix-epoch clock (``time.time_ns``). The contract's ``stamp_ns`` are on it, so it is the only
  way to compare times *across* processes (hosts need synchronised clocks, e.g. PTP). It can step.
- ``mono_ns``: the process's monotonic clock (``time.monotonic_ns``). Every age, timeout, hold and watchdog that
  one process measures of itself runs on it: a wall-clock step cannot freeze or stretch them.

The pure cores take a :class:`Clocks` instead of reading a clock, so that tests and the simulated cell pass
theirs.
"""

from __future__ import annotations

import time
from typing import NamedTuple


class Clocks(NamedTuple):
    """One instant on both clocks [ns]."""

    wall_ns: int
    mono_ns: int


def read_clocks() -> Clocks:
    """Now, on both clocks."""
    return Clocks(time.time_ns(), time.monotonic_ns())
