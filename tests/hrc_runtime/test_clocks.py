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
    assert pair == clocks.Clocks(wall_ns=1_010_000_000, mono_ns=1_000_000_000)


def test_the_real_clocks_are_read() -> None:
    import time

    before_wall, before_mono = time.time_ns(), time.monotonic_ns()
    pair = clocks.read_clocks()
    assert pair.mono_ns >= before_mono
    assert pair.wall_ns >= before_wall - 1_000_000  # a step back of the wall clock meanwhile is not this test's
