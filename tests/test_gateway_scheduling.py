"""CPU scheduling of the gateway: the safety loop under SCHED_FIFO when allowed, the HTTP child niced."""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path

import pytest
from pydantic import ValidationError

from bench.procs import free_port, running_cell
from gateway import main as gateway_main
from gateway.http_server import NICENESS_INCREMENT, HttpServerProcess
from gateway.status import effective_config
from hrc_common.config import CellConfig, GatewayConfig


def _may_use_fifo() -> bool:
    try:
        os.sched_get_priority_max(os.SCHED_FIFO)
    except (AttributeError, OSError):
        return False
    return os.geteuid() == 0


def test_priority_range_is_validated() -> None:
    assert GatewayConfig().loop_realtime_priority == 0
    assert GatewayConfig(loop_realtime_priority=99).loop_realtime_priority == 99
    for bad in (-1, 100):
        with pytest.raises(ValidationError, match="loop_realtime_priority"):
            GatewayConfig(loop_realtime_priority=bad)


def test_refused_realtime_scheduling_warns_and_goes_on(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    def refuse(pid: int, policy: int, param: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    with caplog.at_level(logging.WARNING, logger="hrc-gateway"):
        gateway_main._use_realtime_scheduling(10)
    assert "could not run the safety loop under SCHED_FIFO priority 10" in caplog.text


@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_realtime_scheduling_applies_to_the_calling_thread_only() -> None:
    seen: dict[str, int] = {}

    def loop_thread() -> None:
        gateway_main._use_realtime_scheduling(7)
        seen["policy"] = os.sched_getscheduler(0)
        seen["priority"] = os.sched_getparam(0).sched_priority

    thread = threading.Thread(target=loop_thread)
    thread.start()
    thread.join()
    assert seen == {"policy": os.SCHED_FIFO, "priority": 7}
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # this (other) thread is unchanged


def test_http_child_lowers_its_cpu_priority(cell_config: CellConfig) -> None:
    http = HttpServerProcess("127.0.0.1", free_port(), effective_config(cell_config))
    try:
        pid = http._proc.pid
        expected = min(19, os.getpriority(os.PRIO_PROCESS, 0) + NICENESS_INCREMENT)
        deadline = time.monotonic() + 20.0
        niceness = os.getpriority(os.PRIO_PROCESS, pid)
        while niceness != expected and time.monotonic() < deadline:
            time.sleep(0.05)
            niceness = os.getpriority(os.PRIO_PROCESS, pid)
        assert niceness == expected
    finally:
        http.close()


def test_input_priority_must_stay_below_the_loop() -> None:
    assert GatewayConfig(loop_realtime_priority=10, io_realtime_priority=9).io_realtime_priority == 9
    assert GatewayConfig(loop_realtime_priority=0, io_realtime_priority=0).io_realtime_priority == 0
    for loop, inputs in ((10, 10), (10, 11), (0, 5)):
        with pytest.raises(ValidationError, match="io_realtime_priority"):
            GatewayConfig(loop_realtime_priority=loop, io_realtime_priority=inputs)


class _Payload:
    def __init__(self, data: bytes) -> None:
        self._data = data

    def to_bytes(self) -> bytes:
        return self._data


class _Sample:
    def __init__(self, key: str, data: bytes) -> None:
        self.key_expr = key
        self.payload = _Payload(data)


class _RecordingNode:
    def __init__(self) -> None:
        self.messages: list[tuple[str, bytes, int, int]] = []

    def on_message(self, key: str, payload: bytes, received: object) -> None:
        self.messages.append((key, payload, os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))


@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_receiving_threads_put_themselves_under_fifo_below_the_loop() -> None:
    node = _RecordingNode()
    on_sample = gateway_main._callback(node, 4)  # type: ignore[arg-type]
    thread = threading.Thread(target=lambda: [on_sample(_Sample("k", b"m%d" % i)) for i in range(3)])  # type: ignore[arg-type]
    thread.start()
    thread.join()
    assert node.messages == [
        ("k", b"m0", os.SCHED_FIFO, 4),
        ("k", b"m1", os.SCHED_FIFO, 4),
        ("k", b"m2", os.SCHED_FIFO, 4),
    ]
    normal = gateway_main._callback(node, 0)  # type: ignore[arg-type]
    normal(_Sample("k", b"n"))  # type: ignore[arg-type]
    assert node.messages[-1] == ("k", b"n", os.SCHED_OTHER, 0)


def _thread_priorities(pid: int) -> list[tuple[int, int]]:
    """(policy, priority) of every thread of process ``pid``."""
    found = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            found.append((os.sched_getscheduler(int(task)), os.sched_getparam(int(task)).sched_priority))
        except OSError:  # the thread ended meanwhile
            continue
    return found


@pytest.mark.e2e
@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_running_gateway_has_its_loop_and_receiving_threads_under_fifo(tmp_path: Path) -> None:
    """The shipped cell: the loop at priority 10, the threads that received inputs and the HTTP feed thread at 5,
    every other at normal."""
    with running_cell(tmp_path) as cell:
        cell.wait_until(lambda s: s["delta"] > 0.0, 60.0, "the robot moving (inputs received)")
        priorities = _thread_priorities(cell.gateway.pid)
    fifo = sorted(p for policy, p in priorities if policy == os.SCHED_FIFO)
    assert fifo.count(10) == 1, priorities
    assert fifo.count(5) >= 2, priorities  # the HTTP feed thread and the receiving threads
    assert set(fifo) == {5, 10}, priorities
    assert any(policy == os.SCHED_OTHER for policy, _ in priorities), priorities


@pytest.mark.skipif(not _may_use_fifo(), reason="SCHED_FIFO needs root or CAP_SYS_NICE")
def test_the_http_feed_thread_runs_under_fifo_when_asked(cell_config: CellConfig) -> None:
    for priority, policy in ((3, os.SCHED_FIFO), (0, os.SCHED_OTHER)):
        http = HttpServerProcess("127.0.0.1", free_port(), effective_config(cell_config), None, priority)
        try:
            native_id = http._writer.native_id
            assert native_id is not None
            deadline = time.monotonic() + 10.0
            while os.sched_getscheduler(native_id) != policy and time.monotonic() < deadline:
                time.sleep(0.01)
            assert (os.sched_getscheduler(native_id), os.sched_getparam(native_id).sched_priority) == (policy, priority)
        finally:
            http.close()
