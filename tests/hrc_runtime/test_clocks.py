"""Both clocks read together: the monotonic one first, so that a stamp on the wall clock is never earlier than what
happened by the monotonic reading (the controller's echo of an override: ``echo_before_send``)."""

from __future__ import annotations

import pytest

from hrc_runtime import clocks


def test_a_thread_held_between_the_reads_stamps_later_never_earlier(monkeypatch: pytest.MonkeyPatch) -> None:
    """One clock that both read, advanced 10 ms by whichever read comes first (a thread held between them)."""
    now = {"ns": 1_000_000_000}

    def read_then_hold() -> int:
        value = now["ns"]
        now["ns"] += 10_000_000
        return value

    monkeypatch.setattr(clocks.time, "time_ns", read_then_hold)
    monkeypatch.setattr(clocks.time, "monotonic_ns", read_then_hold)
    pair = clocks.read_clocks()
    # an override that arrived during the hold is at or before mono_ns: the wall stamp must not be earlier
    assert pair.wall_ns >= pair.mono_ns
    # held at every read, each attempt spans 20 ms: the third attempt's pair is taken
    assert pair == clocks.Clocks(wall_ns=1_070_000_000, mono_ns=1_060_000_000)


def test_the_real_clocks_are_read() -> None:
    import time

    before_wall, before_mono = time.time_ns(), time.monotonic_ns()
    pair = clocks.read_clocks()
    assert pair.mono_ns >= before_mono
    assert pair.wall_ns >= before_wall - 1_000_000  # a step back of the wall clock meanwhile is not this test's


def test_a_thread_held_between_the_reads_reads_both_again(monkeypatch: pytest.MonkeyPatch) -> None:
    """Held 25 ms between the first two reads (a busy machine), then not: the pair taken is one instant, not the
    first reading, whose wall clock seemed 25 ms ahead of the monotonic one (a clock step to the gateway)."""
    mono = iter([0, 25_000_000, 30_000_000, 30_000_100])
    wall = iter([1_025_000_000, 1_030_000_050])
    monkeypatch.setattr(clocks.time, "monotonic_ns", lambda: next(mono))
    monkeypatch.setattr(clocks.time, "time_ns", lambda: next(wall))
    assert clocks.read_clocks() == clocks.Clocks(wall_ns=1_030_000_050, mono_ns=30_000_000)


def test_held_at_every_attempt_the_last_pair_is_taken() -> None:
    """Never an endless loop, and never a stamp earlier than what happened by the monotonic reading."""
    now = {"ns": 0}

    def hold() -> int:
        now["ns"] += 2 * clocks.MAX_READ_SPREAD_NS
        return now["ns"]

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(clocks.time, "monotonic_ns", hold)
        patch.setattr(clocks.time, "time_ns", hold)
        pair = clocks.read_clocks()
    assert now["ns"] == clocks.READ_ATTEMPTS * 3 * 2 * clocks.MAX_READ_SPREAD_NS  # three reads per attempt
    assert pair.wall_ns > pair.mono_ns
