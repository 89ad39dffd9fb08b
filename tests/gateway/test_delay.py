"""The delay budget and the override path's learned latency and controller cycle (safety-math.md §5)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway.delay import DelayBudget, OverridePath

T0 = 1_790_000_000_000_000_000  # [ns since epoch]
MS = 1_000_000  # [ns]


def mono(wall_ns: int) -> int:
    """The gateway's monotonic clock at wall time ``wall_ns`` (its own origin) [ns]."""
    return wall_ns - T0 + 7 * MS


def test_total_sums_the_parts() -> None:
    budget = DelayBudget(
        t_reaction_s=0.04,
        human_age_s=0.03,
        joint_state_age_s=0.004,
        override_path_s=0.012,
        controller_cycle_s=0.004,
        gateway_period_s=0.004,
    )
    assert budget.total_s == pytest.approx(0.094)


def test_every_part_counts_once() -> None:
    base = DelayBudget(0.01, 0.02, 0.03, 0.04, 0.05, 0.06)
    for field in DelayBudget._fields:
        bumped = base._replace(**{field: getattr(base, field) + 1.0})
        assert bumped.total_s == pytest.approx(base.total_s + 1.0), field
    assert DelayBudget(0, 0, 0, 0, 0, 0).total_s == 0.0


def test_latency_is_first_echo_stamp_minus_send_time() -> None:
    path = OverridePath()
    assert path.latency_s() is None
    assert path.acked_sent_mono_ns is None
    path.on_sent(1, T0, mono(T0))
    path.on_state(override_seq=0, stamp_ns=T0 + 4 * MS)  # not yet applied: nothing learned
    assert path.latency_s() is None
    path.on_state(override_seq=1, stamp_ns=T0 + 12 * MS)  # first state reporting seq 1
    assert path.latency_s() == pytest.approx(0.012)
    assert path.acked_sent_mono_ns == mono(T0)
    path.on_state(override_seq=1, stamp_ns=T0 + 16 * MS)  # later states with the same seq do not count
    assert path.latency_s() == pytest.approx(0.012)


def test_latency_is_the_largest_in_the_window() -> None:
    path = OverridePath(window_s=1.0)
    path.on_sent(1, T0, mono(T0))
    path.on_state(1, T0 + 30 * MS)  # 30 ms
    path.on_sent(2, T0 + 100 * MS, mono(T0 + 100 * MS))
    path.on_state(2, T0 + 110 * MS)  # 10 ms
    assert path.latency_s() == pytest.approx(0.030)
    assert path.acked_sent_mono_ns == mono(T0 + 100 * MS)


def test_unknown_seq_is_ignored() -> None:
    path = OverridePath()
    path.on_sent(5, T0, mono(T0))
    path.on_state(override_seq=99, stamp_ns=T0 + 10 * MS)
    path.on_state(override_seq=-1, stamp_ns=T0 + 14 * MS)
    assert path.latency_s() is None
    assert path.acked_sent_mono_ns is None
    path.on_state(override_seq=5, stamp_ns=T0 + 20 * MS)
    assert path.latency_s() == pytest.approx(0.020)


def test_window_forgets_old_samples() -> None:
    path = OverridePath(window_s=1.0)
    path.on_sent(1, T0, mono(T0))
    path.on_state(1, T0 + 50 * MS)  # 50 ms, at t = 0.05 s
    path.on_sent(2, T0 + 2000 * MS, mono(T0 + 2000 * MS))
    path.on_state(2, T0 + 2010 * MS)  # 10 ms, at t = 2.01 s: the 50 ms sample is older than 1 s
    assert path.latency_s() == pytest.approx(0.010)


def test_send_history_is_bounded() -> None:
    path = OverridePath(history=2)
    for seq in (1, 2, 3):
        path.on_sent(seq, T0 + seq * MS, mono(T0 + seq * MS))
    path.on_state(1, T0 + 10 * MS)  # seq 1 was evicted: unknown
    assert path.latency_s() is None
    path.on_state(3, T0 + 11 * MS)
    assert path.latency_s() == pytest.approx(0.008)


def test_an_echo_within_the_clock_tolerance_is_a_latency_of_zero() -> None:
    # a controller clock up to the tolerance behind the gateway's: the state stamp precedes the send time
    path = OverridePath()
    path.on_sent(1, T0 + 10 * MS, mono(T0 + 10 * MS))
    assert path.on_state(1, T0 + 5 * MS, clock_tolerance_ns=5 * MS) is None
    assert path.latency_s() == 0.0
    assert path.acked_sent_mono_ns == mono(T0 + 10 * MS)


def test_an_echo_before_its_send_beyond_the_tolerance_teaches_nothing() -> None:
    """Issue 17: it was clipped to a latency of 0 and confirmed the path."""
    path = OverridePath()
    path.on_sent(1, T0 + 10 * MS, mono(T0 + 10 * MS))
    assert path.on_state(1, T0 + 5 * MS - 1, clock_tolerance_ns=5 * MS) == "echo_before_send"
    assert path.estimate == (None, None, None)
    assert path.on_state(1, T0 + 14 * MS, clock_tolerance_ns=5 * MS) is None  # the same seq again: no news
    assert path.latency_s() is None
    assert path.acked_sent_mono_ns is None
    path.on_sent(2, T0 + 20 * MS, mono(T0 + 20 * MS))
    assert path.on_state(2, T0 + 26 * MS, clock_tolerance_ns=5 * MS) is None  # the next override confirms
    assert path.latency_s() == pytest.approx(0.006)


def test_a_seq_above_every_seq_sent_is_never_sent_once_confirmed() -> None:
    path = OverridePath()
    path.on_sent(1, T0, mono(T0))
    assert path.on_state(3, T0 + 2 * MS) is None  # before the first confirmation: a previous gateway's seq
    assert path.on_state(1, T0 + 6 * MS) is None
    assert path.on_state(2, T0 + 10 * MS) == "echo_never_sent"
    assert path.on_state(2, T0 + 14 * MS) == "echo_never_sent"  # every state that reports it
    assert path.on_state(-1, T0 + 18 * MS) is None  # below every seq sent (a restarted controller): unknown
    assert path.acked_sent_mono_ns == mono(T0)
    assert path.latency_s() == pytest.approx(0.006)


def test_a_seq_reported_before_it_was_sent_never_confirms_it() -> None:
    path = OverridePath()
    path.on_state(2, T0)
    path.on_sent(1, T0 + 1 * MS, mono(T0 + 1 * MS))
    path.on_sent(2, T0 + 5 * MS, mono(T0 + 5 * MS))
    assert path.on_state(2, T0 + 8 * MS) is None  # still 2: reported before it was sent, no news
    assert path.latency_s() is None
    path.on_sent(3, T0 + 9 * MS, mono(T0 + 9 * MS))
    assert path.on_state(3, T0 + 12 * MS) is None
    assert path.latency_s() == pytest.approx(0.003)


def test_controller_cycle_from_stamp_differences() -> None:
    path = OverridePath(window_s=1.0)
    assert path.controller_cycle_s() is None
    path.on_state(-1, T0)
    assert path.controller_cycle_s() is None  # one state: no interval yet
    for stamp_ms in (4, 8, 14, 18):
        path.on_state(-1, T0 + stamp_ms * MS)
    assert path.controller_cycle_s() == pytest.approx(0.006)  # largest interval: 8 → 14 ms
    path.on_state(-1, T0 + 18 * MS)  # repeated stamp: no interval
    path.on_state(-1, T0 + 2000 * MS)  # a 1.982 s gap
    assert path.controller_cycle_s() == pytest.approx(1.982)
    path.on_state(-1, T0 + 3100 * MS)  # the 1.982 s sample (at t = 2 s) is now older than the window
    assert path.controller_cycle_s() == pytest.approx(1.1)


def test_cycle_random_against_max_of_intervals() -> None:
    rng = np.random.default_rng(12)
    for _ in range(20):
        stamps = T0 + np.cumsum(rng.integers(1 * MS, 10 * MS, 50))
        path = OverridePath(window_s=10.0)  # long enough to keep all
        for s in stamps:
            path.on_state(-1, int(s))
        assert path.controller_cycle_s() == pytest.approx(np.diff(stamps).max() / 1e9)


def test_window_max_forgets_values_older_than_the_window() -> None:
    from gateway.delay import WindowMax

    window = WindowMax(window_ns=10)
    pushes = [(0, 1.0), (1, 3.0), (2, 2.0), (5, 1.0), (12, 0.5), (13, 0.2), (20, 0.1)]
    assert [window.push(t, v) for t, v in pushes] == [1.0, 3.0, 3.0, 3.0, 2.0, 1.0, 0.5]
    assert window.max() == 0.5
    assert WindowMax(10).max() is None
