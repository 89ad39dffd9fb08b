"""A fixed-rate loop on a monotonic clock that reports its lateness (the cycle time is part of the delay)."""

from __future__ import annotations

import math
import threading
import time

RECENT_CYCLE_DECAY = 0.98
"""Per cycle, the weight of the longest recent cycle in :attr:`RateLoop.guard_s` (halves in ~35 cycles)."""


MAX_TICK_PERIODS = 256
"""Tick periods kept between two status documents (25 Hz status at up to 1 kHz ticks needs 40)."""


class RateLoop:
    """Fixed-rate loop on the monotonic clock that measures its own lateness, with optional event cycles.

    ``sleep()`` waits until the next period boundary, a *tick*. A tick that overran skips the missed
    boundaries (counted in ``missed_cycles``) instead of bursting to catch up.

    Given a ``wake`` event, ``sleep()`` also returns as soon as it is set, for an *event cycle* (new data
    to act on at once), and the next ``sleep()`` waits for the same boundary as before: event cycles do
    not move the ticks, and are neither late nor missed ticks (``event_cycles`` counts them apart from
    ``tick_cycles``). Two limits keep a flood of wake-ups from starving the loop or delaying its ticks:

    - event cycles start at least ``min_event_interval_s`` apart (a wake-up meanwhile waits until then);
    - no event cycle starts when the next tick is due within :attr:`guard_s`: that tick serves the wake-up
      instead (a reaction later by at most that), and an event cycle shorter than the guard cannot make it
      late. The guard is ``event_guard_s`` or, if longer, the recent cycles' duration (reported by
      :meth:`cycle_took`; the longest recent one, its weight halving about every 35 cycles): with many robots
      a cycle takes longer than a fixed guard, and an event cycle started just before a tick made it late.

    ``wake`` is cleared when ``sleep()`` returns (a tick or an event cycle takes everything that arrived
    before), so a wake-up set during the cycle leads to one more event cycle.
    """

    def __init__(self, period_s: float, min_event_interval_s: float = 0.0, event_guard_s: float = 0.0) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s = {period_s}; allowed: > 0")
        if not (min_event_interval_s >= 0.0 and event_guard_s >= 0.0):
            raise ValueError(
                f"min_event_interval_s = {min_event_interval_s}, event_guard_s = {event_guard_s}; allowed: >= 0"
            )
        self.period_s = period_s
        self.min_event_interval_s = min_event_interval_s
        self.event_guard_s = event_guard_s
        self._next_s = time.monotonic() + period_s
        self._last_event_s = -math.inf
        self.missed_cycles = 0
        self.last_lateness_s = 0.0
        """Lateness of the last tick [s] (event cycles leave it as it is)."""
        self.tick_cycles = 0
        self.tick_periods_s: list[float] = []
        """Each tick's interval from the previous tick [s], since :meth:`take_tick_periods` (at most
        :data:`MAX_TICK_PERIODS` kept; the Prometheus histogram observes each)."""
        self._last_tick_s: float | None = None
        self.event_cycles = 0
        self.wakes_served_by_tick = 0
        """Wake-ups left to the next tick because it was due within ``event_guard_s``."""
        self.last_was_event = False
        """Whether the cycle ``sleep()`` last returned for is an event cycle (else a tick)."""
        self._recent_cycle_s = 0.0

    @property
    def guard_s(self) -> float:
        """No event cycle starts when the next tick is due within this [s] (at most one period)."""
        return min(self.period_s, max(self.event_guard_s, self._recent_cycle_s))

    def cycle_took(self, duration_s: float) -> None:
        """The cycle ``sleep()`` last returned for took ``duration_s`` of the loop's time [s]."""
        self._recent_cycle_s = max(duration_s, self._recent_cycle_s * RECENT_CYCLE_DECAY)

    @property
    def next_tick_s(self) -> float:
        """When the next tick is due [monotonic s]."""
        return self._next_s

    def sleep(self, stop: threading.Event, wake: threading.Event | None = None) -> bool:
        """Wait for the next tick or, given ``wake``, until it is set (within the limits above).

        ``stop`` must wake the wait too: with ``wake``, pass a :class:`StopEvent` and its
        :meth:`StopEvent.wake_event` (or set ``wake`` whenever ``stop`` is set).

        Returns:
            False when ``stop`` is set, else True (see ``last_was_event`` for which cycle it is).
        """
        while not stop.is_set():
            now_s = time.monotonic()
            to_tick_s = self._next_s - now_s
            if to_tick_s <= 0.0:
                self._tick(-to_tick_s, wake)
                return not stop.is_set()
            if wake is None:
                stop.wait(to_tick_s)
                continue
            if not wake.is_set():
                wake.wait(to_tick_s)  # set by new data, by stop, or times out at the tick
                continue
            to_event_s = max(0.0, self._last_event_s + self.min_event_interval_s - now_s)
            if to_tick_s - to_event_s <= self.guard_s:
                self.wakes_served_by_tick += 1
                stop.wait(to_tick_s)  # the tick comes first or soon after: it serves the wake-up
            elif to_event_s > 0.0:
                stop.wait(to_event_s)  # rate-limited
            else:
                wake.clear()
                self._last_event_s = now_s
                self.event_cycles += 1
                self.last_was_event = True
                return not stop.is_set()
        return False

    def take_tick_periods(self) -> list[float]:
        """The tick periods since the previous call [s], oldest first; the list starts empty again."""
        periods, self.tick_periods_s = self.tick_periods_s, []
        return periods

    def _tick(self, late_s: float, wake: threading.Event | None) -> None:
        if wake is not None:
            wake.clear()
        now_s = time.monotonic()
        if self._last_tick_s is not None and len(self.tick_periods_s) < MAX_TICK_PERIODS:
            self.tick_periods_s.append(now_s - self._last_tick_s)
        self._last_tick_s = now_s
        self.last_lateness_s = late_s
        missed = int(late_s // self.period_s)
        self.missed_cycles += missed
        self._next_s += (missed + 1) * self.period_s
        self.tick_cycles += 1
        self.last_was_event = False
