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
    """Now, on both clocks: the monotonic one first.

    A thread can be held between the two reads. Read in this order, whatever happened by the monotonic reading
    happened before the wall-clock stamp: the controller emulator takes the overrides that arrived by its cycle's
    monotonic time and stamps the cycle's state on the wall clock, so an override it applies is never reported in a
    state stamped before the override arrived. In the other order a thread held 10 ms between the reads applied
    overrides that arrived up to 10 ms after its stamp (the gateway's ``echo_before_send``: 2 in a 60-minute soak).
    """
    mono_ns = time.monotonic_ns()
    return Clocks(time.time_ns(), mono_ns)
