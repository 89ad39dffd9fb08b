"""CPU scheduling of the gateway: the safety loop under SCHED_FIFO when allowed, the HTTP child niced."""

from __future__ import annotations

import logging
import os
import threading
import time

import pytest
from pydantic import ValidationError

from bench.procs import free_port
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
