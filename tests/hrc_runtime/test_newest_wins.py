"""A newest-wins subscriber (hrc_runtime/newest_wins.py) between two real sessions over loopback: a burst keeps the
newest samples only, a steady stream arrives whole and in order, a failing handler does not stop it, and the intake
thread ends with the session."""

from __future__ import annotations

import threading
import time

import pytest
import zenoh

from hrc_runtime.newest_wins import RING_CAPACITY, declare_newest_wins
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_port

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

KEY = "test/newest_wins"


def _wait_for(predicate, timeout_s: float = 5.0) -> bool:  # type: ignore[no-untyped-def]
    end_s = time.monotonic() + timeout_s
    while time.monotonic() < end_s:
        if predicate():
            return True
        time.sleep(0.01)
    return predicate()


def _intake_threads(name: str) -> list[threading.Thread]:
    return [t for t in threading.enumerate() if t.name == name]


def test_a_burst_behind_a_held_handler_keeps_only_the_newest_samples() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    held = threading.Event()
    release = threading.Event()
    received: list[int] = []

    def on_sample(sample: zenoh.Sample) -> None:
        received.append(int(sample.payload.to_bytes()))
        if len(received) == 1:  # the first sample holds the intake thread, as a frozen process would
            held.set()
            release.wait(10.0)

    seen_by_session: list[int] = []  # what reached the receiving session, by a plain subscriber beside the ring

    with (
        zenoh.open(session_config(listen=[endpoint])) as receiver,
        zenoh.open(session_config(connect=[endpoint])) as sender,
    ):
        subscriber = declare_newest_wins(receiver, KEY, on_sample, capacity=8, name="test-burst")
        receiver.declare_subscriber(KEY, lambda sample: seen_by_session.append(int(sample.payload.to_bytes())))
        # BLOCK: the burst is the receiver's to thin out; DROP let a loaded host's sender lose its last samples (500
        # never arrived: a loaded run, 2026-12-06)
        publisher = sender.declare_publisher(KEY, express=True, congestion_control=zenoh.CongestionControl.BLOCK)
        assert _wait_for(lambda: publisher.matching_status.matching)
        publisher.put(b"0")
        assert held.wait(5.0)
        for k in range(1, 501):
            publisher.put(str(k).encode())
        # all of it arrived meanwhile, into the ring (a fixed 0.3 s was not always enough on a loaded host)
        assert _wait_for(lambda: bool(seen_by_session) and seen_by_session[-1] == 500, 30.0)
        time.sleep(0.05)  # the plain subscriber's thread may run a sample before the ring has taken it
        release.set()
        assert _wait_for(lambda: received and received[-1] == 500)
        time.sleep(0.1)
        del subscriber
    assert received[0] == 0
    assert 2 <= len(received) <= 1 + 8 + 1  # the held one, the ring, at most one more taken as the ring filled
    assert received[1:] == sorted(received[1:])
    assert received[1] > 400  # the oldest of the burst were dropped, not delivered late


def test_a_steady_stream_arrives_whole_in_order_and_a_failing_handler_does_not_stop_it() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    received: list[int] = []

    def on_sample(sample: zenoh.Sample) -> None:
        value = int(sample.payload.to_bytes())
        received.append(value)
        if value == 3:
            raise RuntimeError("a handler that fails once")

    with (
        zenoh.open(session_config(listen=[endpoint])) as receiver,
        zenoh.open(session_config(connect=[endpoint])) as sender,
    ):
        subscriber = declare_newest_wins(receiver, KEY, on_sample, name="test-steady")
        publisher = sender.declare_publisher(KEY, express=True, congestion_control=zenoh.CongestionControl.BLOCK)
        assert _wait_for(lambda: publisher.matching_status.matching)
        for k in range(200):
            # at most half a ring ahead of the handler: a stream it keeps up with (at 500 Hz an idle host's intake
            # does; a host loaded with 3 busy processes on 2 cores once fell a ring behind and dropped, as it should)
            assert _wait_for(lambda k=k: k - len(received) < RING_CAPACITY // 2, 30.0)
            publisher.put(str(k).encode())
            time.sleep(0.002)
        assert _wait_for(lambda: len(received) == 200)
        assert _intake_threads("test-steady")
        del subscriber
    assert received == list(range(200))
    assert _wait_for(lambda: not _intake_threads("test-steady"))  # ended with the session


def test_a_ring_without_room_is_refused() -> None:
    with zenoh.open(session_config()) as session, pytest.raises(ValueError, match="allowed: >= 1"):
        declare_newest_wins(session, KEY, lambda sample: None, capacity=0)
