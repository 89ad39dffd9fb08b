"""RateLoop: fixed-rate ticks with event cycles in between; StopEvent and the signal handler that sets it.

No timed assertions beyond generous bounds: the periods are long (seconds) where a wait must be cut short,
and the tick schedule is checked by its arithmetic, not by the clock.
"""

from __future__ import annotations

import gc
import logging
import os
import signal
import threading
import time

import pytest

from hrc_runtime.logs import logging_through_a_queue
from hrc_runtime.rate_loop import RateLoop
from hrc_runtime.realtime import collections_paused
from hrc_runtime.signals import StopEvent, stop_on_signals

LONG_S = 30.0  # a period no test waits for: returning at all proves the wait was cut short


def _set_later(event: threading.Event, after_s: float = 0.05) -> threading.Thread:
    def set_it() -> None:
        time.sleep(after_s)
        event.set()

    thread = threading.Thread(target=set_it, daemon=True)
    thread.start()
    return thread


# -- ticks --------------------------------------------------------------------------------------------


def test_ticks_keep_a_fixed_schedule_without_wake() -> None:
    rate = RateLoop(0.01)
    first_s = rate.next_tick_s
    stop = threading.Event()
    for _ in range(5):
        assert rate.sleep(stop)
        assert not rate.last_was_event
    assert rate.tick_cycles == 5
    assert rate.event_cycles == 0
    # Boundaries advance by whole periods, whatever the lateness (skipped ones are counted as missed).
    assert rate.next_tick_s == pytest.approx(first_s + (5 + rate.missed_cycles) * 0.01)


def test_an_overrun_skips_the_missed_ticks_and_counts_them() -> None:
    rate = RateLoop(0.01)
    stop = threading.Event()
    assert rate.sleep(stop)
    time.sleep(0.055)  # the cycle overran by more than 4 periods
    assert rate.sleep(stop)
    assert rate.missed_cycles >= 4
    assert rate.last_lateness_s >= 0.04
    assert rate.next_tick_s > time.monotonic() - 0.01  # no burst of catch-up ticks


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="period_s"):
        RateLoop(0.0)
    with pytest.raises(ValueError, match="allowed: >= 0"):
        RateLoop(0.01, min_event_interval_s=-1.0)


# -- event cycles -------------------------------------------------------------------------------------


def test_wake_returns_early_for_an_event_cycle_and_keeps_the_tick_schedule() -> None:
    rate = RateLoop(LONG_S)
    tick_s = rate.next_tick_s
    stop, wake = threading.Event(), threading.Event()
    _set_later(wake)
    assert rate.sleep(stop, wake)
    assert rate.last_was_event
    assert (rate.event_cycles, rate.tick_cycles, rate.missed_cycles) == (1, 0, 0)
    assert rate.next_tick_s == tick_s  # the same boundary: the event cycle did not move the ticks
    assert rate.last_lateness_s == 0.0  # nor is it a late tick
    assert not wake.is_set()  # taken by this cycle


def test_a_wake_set_before_sleep_is_an_event_cycle_at_once() -> None:
    rate = RateLoop(LONG_S)
    stop, wake = threading.Event(), threading.Event()
    wake.set()
    assert rate.sleep(stop, wake)
    assert rate.last_was_event


def test_event_cycles_then_the_tick_on_its_schedule() -> None:
    rate = RateLoop(0.2)
    tick_s = rate.next_tick_s
    stop, wake = threading.Event(), threading.Event()
    for _ in range(3):
        wake.set()
        assert rate.sleep(stop, wake)
        assert rate.last_was_event
    assert rate.sleep(stop, wake)  # no wake-up: the tick
    assert not rate.last_was_event
    assert time.monotonic() >= tick_s
    assert (rate.event_cycles, rate.tick_cycles) == (3, 1)
    assert rate.next_tick_s == pytest.approx(tick_s + (1 + rate.missed_cycles) * 0.2)


def test_event_cycles_are_rate_limited() -> None:
    rate = RateLoop(0.1, min_event_interval_s=LONG_S)
    stop, wake = threading.Event(), threading.Event()
    wake.set()
    assert rate.sleep(stop, wake)
    assert rate.last_was_event
    wake.set()  # too soon after the last event cycle: the next tick serves it
    assert rate.sleep(stop, wake)
    assert not rate.last_was_event
    assert not wake.is_set()  # the tick took it
    assert (rate.event_cycles, rate.tick_cycles) == (1, 1)


def test_no_event_cycle_when_the_tick_is_due_within_the_guard() -> None:
    rate = RateLoop(0.05, event_guard_s=0.05)  # the tick is always within the guard
    stop, wake = threading.Event(), threading.Event()
    wake.set()
    assert rate.sleep(stop, wake)
    assert not rate.last_was_event
    assert rate.event_cycles == 0
    assert rate.wakes_served_by_tick == 1
    assert not wake.is_set()


def test_a_flood_of_wake_ups_leaves_the_ticks_their_schedule() -> None:
    rate = RateLoop(0.02, min_event_interval_s=0.005, event_guard_s=0.002)
    first_s = rate.next_tick_s
    started_s = first_s - 0.02
    stop, wake = threading.Event(), threading.Event()
    flooding = threading.Event()
    flooding.set()

    def flood() -> None:
        while flooding.is_set():
            wake.set()
            time.sleep(0.0002)

    thread = threading.Thread(target=flood, daemon=True)
    thread.start()
    try:
        while rate.tick_cycles < 10:
            assert rate.sleep(stop, wake)
    finally:
        flooding.clear()
        thread.join()
    assert rate.event_cycles > 0
    # At most one event cycle per min_event_interval_s, whatever the flood.
    assert rate.event_cycles <= (rate.next_tick_s - started_s) / 0.005 + 1
    assert rate.next_tick_s == pytest.approx(first_s + (10 + rate.missed_cycles) * 0.02)


# -- stopping -------------------------------------------------------------------------------------------


def test_stop_ends_the_wait_at_once() -> None:
    rate = RateLoop(LONG_S)
    stop = threading.Event()
    _set_later(stop)
    assert not rate.sleep(stop)


def test_stop_event_wakes_a_wait_on_its_wake_event() -> None:
    rate = RateLoop(LONG_S)
    stop = StopEvent()
    wake = stop.wake_event()
    _set_later(stop)
    assert not rate.sleep(stop, wake)
    assert rate.event_cycles == 0


def test_a_set_stop_event_makes_its_wake_events_set() -> None:
    stop = StopEvent()
    before = stop.wake_event()
    stop.set()
    assert before.is_set()
    assert stop.wake_event().is_set()


def test_a_signal_ends_the_wait_at_once() -> None:
    rate = RateLoop(LONG_S)
    before = signal.getsignal(signal.SIGINT)
    with stop_on_signals() as stop:
        wake = stop.wake_event()
        timer = threading.Timer(0.05, os.kill, (os.getpid(), signal.SIGINT))
        timer.start()
        try:
            assert not rate.sleep(stop, wake)
        finally:
            timer.cancel()
    assert stop.is_set()
    assert signal.getsignal(signal.SIGINT) is before  # restored


def test_the_guard_grows_with_long_cycles_and_shrinks_back() -> None:
    """An event cycle as long as the recent cycles cannot start where it would make the next tick late."""
    rate = RateLoop(0.01, event_guard_s=0.0002)
    assert rate.guard_s == 0.0002
    rate.cycle_took(0.003)
    assert rate.guard_s == 0.003
    rate.cycle_took(0.05)  # a cycle longer than the period: the guard is at most one period
    assert rate.guard_s == 0.01
    for _ in range(400):
        rate.cycle_took(0.0001)
    assert rate.guard_s == 0.0002  # back to the configured guard once the cycles are short again


def test_no_event_cycle_when_the_tick_is_due_within_a_recent_cycles_length() -> None:
    rate = RateLoop(0.05, event_guard_s=0.0)
    rate.cycle_took(0.05)  # the recent cycles are as long as the period: the tick is always within the guard
    stop, wake = threading.Event(), threading.Event()
    wake.set()
    assert rate.sleep(stop, wake)
    assert not rate.last_was_event
    assert rate.wakes_served_by_tick == 1


class _Collect(logging.Handler):
    def __init__(self) -> None:
        super().__init__()
        self.lines: list[tuple[str, int, int]] = []  # message, policy and priority of the writing thread

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append((record.getMessage(), os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))


def _may_use_fifo() -> bool:
    return hasattr(os, "SCHED_FIFO") and os.geteuid() == 0


@pytest.mark.parametrize("priority", [0, pytest.param(2, marks=pytest.mark.skipif(not _may_use_fifo(), reason="root"))])
def test_logging_through_a_queue_writes_every_record_on_its_own_thread(priority: int) -> None:
    root = logging.getLogger()
    collect = _Collect()
    before = root.handlers[:]
    root.handlers = [collect]
    try:
        with logging_through_a_queue(priority):
            assert root.handlers != [collect]  # the caller's records go into the queue
            logging.getLogger("hrc.test").warning("one %d", 1)
            other = threading.Thread(target=lambda: logging.getLogger("hrc.test").warning("two"))
            other.start()
            other.join()
        assert root.handlers == [collect]  # put back
    finally:
        root.handlers = before
    messages = [m for m, _, _ in collect.lines if not m.startswith("the log writer thread")]
    assert sorted(messages) == ["one 1", "two"]  # every record written by the time the block ends
    policy = os.SCHED_FIFO if priority else os.SCHED_OTHER
    assert all((p, prio) == (policy, priority) for m, p, prio in collect.lines if m in messages)


# -- garbage collection next to the loop -----------------------------------------------------------------


def test_collections_are_paused_meanwhile_and_resume_after_even_on_error() -> None:
    assert gc.isenabled()
    with collections_paused():
        assert not gc.isenabled()
    assert gc.isenabled()
    with pytest.raises(RuntimeError), collections_paused():
        raise RuntimeError("boom")
    assert gc.isenabled()


def test_collections_paused_leaves_them_off_if_they_were_off() -> None:
    gc.disable()
    try:
        with collections_paused():
            pass
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_the_rate_loop_hands_over_each_tick_period_once() -> None:
    """Every tick's interval from the previous tick is kept for the status (the metrics observe each), and taken
    once: the next status gets only the ticks after it."""
    import threading

    from hrc_runtime.rate_loop import MAX_TICK_PERIODS, RateLoop

    rate = RateLoop(0.002)
    stop = threading.Event()
    for _ in range(6):
        assert rate.sleep(stop)
    periods = rate.take_tick_periods()
    assert len(periods) == 5, "six ticks, five intervals"
    assert all(p > 0.0 for p in periods)
    assert sum(periods) >= 4 * 0.002, "the ticks are a period apart (or later), never earlier"
    assert rate.take_tick_periods() == []
    assert rate.sleep(stop)
    assert len(rate.take_tick_periods()) == 1
    rate.tick_periods_s = [0.002] * MAX_TICK_PERIODS
    assert rate.sleep(stop)
    assert len(rate.take_tick_periods()) == MAX_TICK_PERIODS, "bounded between two statuses"
