"""The notify protocol (hrc_runtime/sd_notify.py) over real datagram sockets, and the journal's log format.

The programs themselves are tested over a real ``NOTIFY_SOCKET`` in test_e2e_notify.py.
"""

from __future__ import annotations

import itertools
import logging
import os
import socket
import sys
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from hrc_runtime.logs import JournalFormatter, stderr_is_journal, syslog_priority
from hrc_runtime.sd_notify import (
    PINGS_PER_TIMEOUT,
    LoopNotifier,
    Notifier,
    single_line,
    socket_address,
    stall_after_cycles,
    watchdog_timeout_s,
)

# -- addresses and environment -------------------------------------------------------------------


def test_socket_addresses_of_a_path_and_of_the_abstract_namespace() -> None:
    assert socket_address("/run/systemd/notify") == "/run/systemd/notify"
    assert socket_address("@hrc/notify") == b"\0hrc/notify"
    assert socket_address("@") is None
    assert socket_address("vsock:2:1234") is None
    assert socket_address("relative/path") is None


@pytest.mark.parametrize(
    ("environ", "expected_s"),
    [
        ({"WATCHDOG_USEC": "2000000"}, 2.0),
        ({"WATCHDOG_USEC": "500000", "WATCHDOG_PID": "42"}, 0.5),
        ({"WATCHDOG_USEC": "500000", "WATCHDOG_PID": "43"}, None),  # another process's watchdog
        ({"WATCHDOG_USEC": "0"}, None),
        ({"WATCHDOG_USEC": "soon"}, None),
        ({}, None),
    ],
)
def test_the_watchdog_timeout_is_this_process_s(environ: dict[str, str], expected_s: float | None) -> None:
    assert watchdog_timeout_s(environ, pid=42) == expected_s


def test_the_test_only_stall_takes_a_positive_cycle_count() -> None:
    assert stall_after_cycles({"HRC_TEST_STALL_AFTER_CYCLES": "250"}) == 250
    assert stall_after_cycles({}) is None
    assert stall_after_cycles({"HRC_TEST_STALL_AFTER_CYCLES": "0"}) is None
    assert stall_after_cycles({"HRC_TEST_STALL_AFTER_CYCLES": "-3"}) is None


def test_a_status_is_one_short_line() -> None:
    assert single_line("ur5 reduced_speed\n  δ=0.40") == "ur5 reduced_speed δ=0.40"
    assert len(single_line("x " * 500)) == 200


# -- datagrams -----------------------------------------------------------------------------------


@pytest.fixture(params=["path", "abstract"])
def listener(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[tuple[socket.socket, str]]:
    """A bound datagram socket and its ``NOTIFY_SOCKET`` value (a file path, or ``@name``)."""
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    if request.param == "path":
        value = str(tmp_path / "notify.sock")
        sock.bind(value)
    else:
        value = f"@hrc-test-{uuid.uuid4().hex}"
        sock.bind(b"\0" + value[1:].encode())
    sock.settimeout(5.0)
    with sock:
        yield sock, value


def test_messages_arrive_as_one_datagram_each(listener: tuple[socket.socket, str]) -> None:
    sock, value = listener
    with Notifier.from_environment({"NOTIFY_SOCKET": value}) as notifier:
        assert notifier.enabled
        assert notifier.ready("ur5 guarded_distance\nδ=1.00")
        assert notifier.watchdog()
        assert notifier.stopping()
    assert sock.recv(4096) == "READY=1\nSTATUS=ur5 guarded_distance δ=1.00".encode()
    assert sock.recv(4096) == b"WATCHDOG=1"
    assert sock.recv(4096) == b"STOPPING=1"


def test_without_notify_socket_nothing_is_sent() -> None:
    notifier = Notifier.from_environment({})
    assert not notifier.enabled
    assert not notifier.ready()
    assert not notifier.watchdog()


def test_a_vanished_socket_is_logged_once_and_never_raises(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with Notifier.from_environment({"NOTIFY_SOCKET": str(tmp_path / "gone.sock")}) as notifier:
        assert not notifier.watchdog()
        assert not notifier.watchdog()
    assert len([r for r in caplog.records if "cannot notify" in r.getMessage()]) == 1


def test_a_full_socket_never_blocks_the_sender(listener: tuple[socket.socket, str]) -> None:
    _, value = listener  # never read: its queue fills up
    results: list[bool] = []
    with Notifier.from_environment({"NOTIFY_SOCKET": value}) as notifier:
        sender = threading.Thread(target=lambda: results.extend(notifier.watchdog() for _ in range(5000)), daemon=True)
        sender.start()
        sender.join(10.0)
        assert not sender.is_alive(), "a send blocked on a full socket"
    assert results[0]
    assert not results[-1]


# -- the loop's notifications --------------------------------------------------------------------


class _Recorder(Notifier):
    """A notifier that records what it would send, with the loop time of each call."""

    def __init__(self) -> None:
        super().__init__("/unused")
        self.sent: list[tuple[float, tuple[str, ...]]] = []
        self.now_s = 0.0

    def send(self, *fields: str) -> bool:
        self.sent.append((self.now_s, fields))
        return True


def _run(loop: LoopNotifier, recorder: _Recorder, times_s: list[float], ready_from_s: float = 0.0) -> None:
    for now_s in times_s:
        recorder.now_s = now_s
        loop.cycle_done(now_s, lambda: "ur5 autonomous", ready=now_s >= ready_from_s)


def test_ready_once_when_the_loop_has_done_its_job_and_pings_four_times_per_timeout() -> None:
    recorder = _Recorder()
    loop = LoopNotifier(recorder, watchdog_timeout_s=1.0)
    _run(loop, recorder, [i * 0.004 for i in range(1000)], ready_from_s=0.5)  # 4 s of a 250 Hz loop
    ready = [t for t, fields in recorder.sent if "READY=1" in fields]
    pings = [t for t, fields in recorder.sent if fields == ("WATCHDOG=1",)]
    assert ready == [pytest.approx(0.5)]
    assert next(f for _, f in recorder.sent if "READY=1" in f) == ("READY=1", "STATUS=ur5 autonomous")
    gaps = [b - a for a, b in itertools.pairwise(pings)]
    assert max(gaps) <= 1.0 / PINGS_PER_TIMEOUT + 0.004 + 1e-9
    assert len(pings) >= 4 * PINGS_PER_TIMEOUT - 1
    statuses = [t for t, fields in recorder.sent if fields[0].startswith("STATUS=")]
    assert 2 <= len(statuses) <= 4  # every second after READY


def test_no_watchdog_no_pings_and_outside_systemd_nothing() -> None:
    recorder = _Recorder()
    loop = LoopNotifier(recorder, watchdog_timeout_s=None)
    _run(loop, recorder, [0.0, 0.5, 1.0])
    assert not [f for _, f in recorder.sent if f == ("WATCHDOG=1",)]
    silent = LoopNotifier(Notifier(None), watchdog_timeout_s=1.0)
    silent.cycle_done(0.0, lambda: pytest.fail("no status is built outside systemd"))
    assert silent.cycles == 1


def test_the_test_only_stall_blocks_the_loop_until_stopped() -> None:
    loop = LoopNotifier(Notifier(None), watchdog_timeout_s=None, stall_after_cycles=2)
    stop = threading.Event()
    loop.cycle_done(0.0, str)
    loop.stall_for_tests(stop)  # 1 cycle: returns at once
    loop.cycle_done(0.0, str)
    stalled = threading.Thread(target=loop.stall_for_tests, args=(stop,), daemon=True)
    stalled.start()
    stalled.join(0.2)
    assert stalled.is_alive()
    stop.set()
    stalled.join(5.0)
    assert not stalled.is_alive()


# -- logs for the journal ------------------------------------------------------------------------


def test_syslog_priorities_keep_the_level() -> None:
    assert [syslog_priority(level) for level in (50, 40, 30, 20, 10, 5, 25)] == [2, 3, 4, 6, 7, 7, 6]


def test_journal_lines_carry_the_priority_on_every_line_and_no_timestamp() -> None:
    try:
        raise ValueError("bad frame")
    except ValueError:
        record = logging.LogRecord("hrc-gateway", logging.ERROR, __file__, 1, "cycle failed", None, sys.exc_info())
    lines = JournalFormatter().format(record).splitlines()
    assert lines[0] == "<3>hrc-gateway ERROR cycle failed"
    assert len(lines) > 2
    assert all(line.startswith("<3>") for line in lines)
    warning = logging.LogRecord("hrc-gateway", logging.WARNING, __file__, 1, "fault %s", ("tracker_stale",), None)
    assert JournalFormatter().format(warning) == "<4>hrc-gateway WARNING fault tracker_stale"


def test_stderr_is_the_journal_only_when_journal_stream_names_it(tmp_path: Path) -> None:
    with (tmp_path / "stream").open("w") as stream, (tmp_path / "other").open("w") as other:
        stat = os.fstat(stream.fileno())
        environ = {"JOURNAL_STREAM": f"{stat.st_dev}:{stat.st_ino}"}
        assert stderr_is_journal(environ, stream.fileno())
        assert not stderr_is_journal(environ, other.fileno())  # inherited, but output redirected
        assert not stderr_is_journal({}, stream.fileno())
        assert not stderr_is_journal({"JOURNAL_STREAM": "garbage"}, stream.fileno())
