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


MAX_READ_SPREAD_NS = 1_000_000
"""A reading of both clocks is one instant within this [ns]: the monotonic clock read again after the wall clock
moved on by at most this much. A thread held longer between the reads reads both again (:func:`read_clocks`)."""

READ_ATTEMPTS = 3


def read_clocks() -> Clocks:
    """Now, on both clocks: the monotonic one first, the wall clock within :data:`MAX_READ_SPREAD_NS` after it.

    A thread can be held between the two reads. Read in this order, whatever happened by the monotonic reading
    happened before the wall-clock stamp: the controller emulator takes the overrides that arrived by its cycle's
    monotonic time and stamps the cycle's state on the wall clock, so an override it applies is never reported in a
    state stamped before the override arrived. In the other order a thread held 10 ms between the reads applied
    overrides that arrived up to 10 ms after its stamp (the gateway's ``echo_before_send``: 2 in a 60-minute soak).

    And a thread held between the reads would pair instants apart: the gateway, which watches the wall clock
    against the monotonic one, saw such a pair as its wall clock stepping by the hold and back (``clock_step``,
    δ = 0 for every robot; a test of two arms on a loaded machine, 2026-12-06). So the monotonic clock is read again
    after the wall clock, and a pair further apart than :data:`MAX_READ_SPREAD_NS` is read anew, up to
    :data:`READ_ATTEMPTS` times (then the last pair is taken: a later stamp, never an earlier one).
    """
    for _ in range(READ_ATTEMPTS):
        mono_ns = time.monotonic_ns()
        wall_ns = time.time_ns()
        if time.monotonic_ns() - mono_ns <= MAX_READ_SPREAD_NS:
            break
    return Clocks(wall_ns, mono_ns)
