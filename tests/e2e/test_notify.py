"""The three programs under a service manager's eyes: a real ``NOTIFY_SOCKET`` bound here, the real programs as
subprocesses, their outputs watched on loopback Zenoh (the program connects to this test's session, so its
very first publication is seen).

- ``READY=1`` comes once the program does its job and not before: the first output (an override, a joint state,
  a tracker frame published after its latency) was made before ``READY=1`` arrived (same host, same wall clock).
- The gateway's ``WATCHDOG=1`` comes from its safety loop: at least two per ``WATCHDOG_USEC`` while the loop runs,
  none once the loop stalls (test-only ``HRC_TEST_STALL_AFTER_CYCLES``) though the process lives on.
- ``STOPPING=1`` on SIGTERM, and exit code 0.
- Under the journal (``JOURNAL_STREAM`` naming its standard error) a program logs ``<N>`` lines without timestamps.
"""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
import zenoh

from hrc_contract import keys
from hrc_runtime.config import load_cell_config
from hrc_runtime.sd_notify import PINGS_PER_TIMEOUT, STALL_ENV_VAR
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import (
    Program,
    free_endpoint,
    free_port,
    log_tail,
    start_program,
    stop_program,
    wait_for,
    wait_or_fail,
)

pytestmark = pytest.mark.e2e

WATCHDOG_S = 1.0
"""``WATCHDOG_USEC`` given to the programs [s]."""

STALL_AFTER_CYCLES = 750
"""The gateway's loop stalls after this many cycles (3 s at the default 250 Hz)."""

START_TIMEOUT_S = 60.0
CELL = "demo"


@dataclass(frozen=True)
class Notice:
    """One datagram received on the notify socket."""

    wall_ns: int
    mono_s: float
    fields: tuple[str, ...]


@dataclass
class NotifySocket:
    """A bound datagram socket (``value`` is what ``NOTIFY_SOCKET`` says) that records every message."""

    value: str
    sock: socket.socket
    notices: list[Notice] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def receive(self, closed: threading.Event) -> None:
        while not closed.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            except OSError:
                return
            with self.lock:
                self.notices.append(Notice(time.time_ns(), time.monotonic(), tuple(data.decode().split("\n"))))

    def with_field(self, wanted: str) -> list[Notice]:
        with self.lock:
            return [n for n in self.notices if wanted in n.fields]


@contextmanager
def notify_socket(tmp_path: Path, abstract: bool) -> Iterator[NotifySocket]:
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    if abstract:
        value = f"@hrc-test-{uuid.uuid4().hex}"
        sock.bind(b"\0" + value[1:].encode())
    else:
        value = str(tmp_path / "notify.sock")
        sock.bind(value)
    sock.settimeout(0.05)
    notify = NotifySocket(value, sock)
    closed = threading.Event()
    thread = threading.Thread(target=notify.receive, args=(closed,), daemon=True)
    thread.start()
    try:
        yield notify
    finally:
        closed.set()
        thread.join(5.0)
        sock.close()


@dataclass
class Watched:
    """Samples received on a key expression: arrival (monotonic s) and the decoded message."""

    samples: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def on_sample(self, sample: zenoh.Sample) -> None:
        message = json.loads(sample.payload.to_bytes())
        with self.lock:
            self.samples.append((time.monotonic(), message))

    def snapshot(self) -> list[tuple[float, dict[str, Any]]]:
        with self.lock:
            return list(self.samples)


@contextmanager
def watch(endpoint: str, key_expr: str) -> Iterator[Watched]:
    """A Zenoh session listening on ``endpoint`` (the program connects to it), subscribed before it starts."""
    watched = Watched()
    with zenoh.open(session_config([endpoint], [])) as session:
        subscriber = session.declare_subscriber(key_expr, watched.on_sample)
        yield watched
        del subscriber


def _wait_ready(notify: NotifySocket, proc: Program, log: Path) -> Notice:
    wait_or_fail(lambda: bool(notify.with_field("READY=1")), START_TIMEOUT_S, "READY=1", [log], [proc])
    return notify.with_field("READY=1")[0]


def _stop_with_sigterm(notify: NotifySocket, proc: Program, log: Path) -> None:
    sent_s = time.monotonic()
    assert stop_program(proc, signal.SIGTERM) == 0, log_tail(log)
    stopping = notify.with_field("STOPPING=1")
    assert len(stopping) == 1, log_tail(log)
    assert stopping[0].mono_s >= sent_s


def test_gateway_ready_after_its_first_override_watchdog_from_its_loop_stopping_on_sigterm(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    endpoint, log = free_endpoint(), tmp_path / "gateway.log"
    with notify_socket(tmp_path, abstract=True) as notify, watch(endpoint, keys.robot_override(CELL, "*")) as overrides:
        monkeypatch.setenv("NOTIFY_SOCKET", notify.value)
        monkeypatch.setenv("WATCHDOG_USEC", str(round(WATCHDOG_S * 1e6)))
        monkeypatch.setenv(STALL_ENV_VAR, str(STALL_AFTER_CYCLES))
        proc = start_program("gateway", ["--zenoh-connect", endpoint, "--http-port", str(free_port())], log)
        try:
            ready = _wait_ready(notify, proc, log)
            wait_for(lambda: bool(overrides.snapshot()), 5.0, "an override on Zenoh", [proc])
            first_override = overrides.snapshot()[0][1]
            assert first_override["stamp_ns"] <= ready.wall_ns, "READY=1 before the first override was made"
            assert any(f.startswith("STATUS=ur5 ") for f in ready.fields), ready.fields

            # The loop stalls after STALL_AFTER_CYCLES: overrides stop; wait until none came for 1.5 timeouts.
            def stalled() -> bool:
                samples = overrides.snapshot()
                return len(samples) >= STALL_AFTER_CYCLES // 2 and time.monotonic() - samples[-1][0] > 1.5 * WATCHDOG_S

            wait_for(stalled, 30.0, "the loop to stall", [proc])
            last_override_s = overrides.snapshot()[-1][0]
            pings = [n.mono_s for n in notify.with_field("WATCHDOG=1")]
            running = [t for t in pings if t >= ready.mono_s]
            assert len(running) >= 8, pings
            # At least two pings in every WATCHDOG_USEC window while the loop ran.
            assert max(b - a for a, b in zip(running, running[2:], strict=False)) <= WATCHDOG_S, running
            # The pings stopped with the loop (within one ping interval of its last override), not later.
            ping_every_s = WATCHDOG_S / PINGS_PER_TIMEOUT
            assert last_override_s - pings[-1] <= 2 * ping_every_s, (last_override_s, pings[-1])
            assert pings[-1] <= last_override_s + ping_every_s, (last_override_s, pings[-1])
            assert proc.poll() is None  # the process lives on: only the watchdog can tell
            _stop_with_sigterm(notify, proc, log)
        finally:
            if proc.poll() is None:
                stop_program(proc)


def test_controller_ready_after_its_first_joint_state_and_logs_for_the_journal(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    endpoint, log = free_endpoint(), tmp_path / "controller.log"
    log.touch()
    stat = os.stat(log)
    with notify_socket(tmp_path, abstract=False) as notify, watch(endpoint, keys.robot_state(CELL, "ur5")) as states:
        monkeypatch.setenv("NOTIFY_SOCKET", notify.value)
        monkeypatch.setenv("WATCHDOG_USEC", str(round(WATCHDOG_S * 1e6)))
        monkeypatch.setenv("JOURNAL_STREAM", f"{stat.st_dev}:{stat.st_ino}")  # its stderr is "the journal"
        proc = start_program("controller_emu", ["--zenoh-connect", endpoint], log)
        try:
            ready = _wait_ready(notify, proc, log)
            wait_for(lambda: bool(states.snapshot()), 5.0, "a joint state on Zenoh", [proc])
            assert states.snapshot()[0][1]["stamp_ns"] <= ready.wall_ns, "READY=1 before the first joint state"
            assert any(f.startswith("STATUS=ur5 protective_stop") for f in ready.fields), ready.fields
            wait_for(lambda: len(notify.with_field("WATCHDOG=1")) >= 3, 5.0, "watchdog pings", [proc])
            _stop_with_sigterm(notify, proc, log)
        finally:
            if proc.poll() is None:
                stop_program(proc)
    lines = log.read_text().splitlines()
    assert any(line.startswith("<6>hrc-controller-emu INFO controller ur5") for line in lines), lines
    # Every line: the syslog priority of its level, the logger, the level, no timestamp (the journal adds it).
    priorities = {"<7>": "DEBUG", "<6>": "INFO", "<4>": "WARNING", "<3>": "ERROR", "<2>": "CRITICAL"}
    for line in lines:
        match = re.fullmatch(r"(<\d>)\S+ ([A-Z]+) .*", line)
        assert match is not None, line
        assert priorities.get(match[1]) == match[2], line


def test_tracker_ready_after_its_first_frame_is_published(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    config = load_cell_config(None)
    latency_ns = {name: round(tracker.latency_s * 1e9) for name, tracker in config.trackers.items()}
    endpoint, log = free_endpoint(), tmp_path / "tracker.log"
    with notify_socket(tmp_path, abstract=True) as notify, watch(endpoint, keys.tracker_humans(CELL, "*")) as frames:
        monkeypatch.setenv("NOTIFY_SOCKET", notify.value)
        monkeypatch.setenv("WATCHDOG_USEC", str(round(WATCHDOG_S * 1e6)))
        proc = start_program("tracker_emu", ["--zenoh-connect", endpoint], log)
        try:
            ready = _wait_ready(notify, proc, log)
            wait_for(lambda: bool(frames.snapshot()), 5.0, "a tracker frame on Zenoh", [proc])
            first = frames.snapshot()[0][1]
            # Published no earlier than capture + latency: READY=1 came after that.
            assert first["stamp_ns"] + latency_ns[first["tracker"]] <= ready.wall_ns, "READY=1 before the first frame"
            wait_for(lambda: len(notify.with_field("WATCHDOG=1")) >= 3, 5.0, "watchdog pings", [proc])
            _stop_with_sigterm(notify, proc, log)
        finally:
            if proc.poll() is None:
                stop_program(proc)
