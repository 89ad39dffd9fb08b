"""``./run-cell.sh --config configs/cell_two_arms.toml`` (``hrc-cell``): one controller emulator per robot, the
status shows both robots running, ``hrc-audit`` (a Zenoh client of the gateway) audits both against the ground
truth; Ctrl-C stops everything with exit code 0; ``--record DIR`` leaves a cell recording with both robots' topics
and a gateway recording that ``hrc-replay`` reproduces.

Plain TCP on loopback like the other end-to-end tests (the launcher over mutual TLS is tests/test_security_cell.py's).
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from mcap.reader import make_reader
from support.paths import DEFAULT_CELL_PATH

from hrc_contract.status_models import GatewayStatus
from hrc_tools.cell.procs import StartupError, free_port, log_tail, start_program, stop_program, wait_for

pytestmark = pytest.mark.e2e

CONFIG = DEFAULT_CELL_PATH.parent / "cell_two_arms.toml"
READY_S = 40.0
AUDIT_S = 6.0


def _status(http_port: int) -> GatewayStatus | None:
    try:
        response = httpx.get(f"http://127.0.0.1:{http_port}/api/v1/status", timeout=2.0)
    except (httpx.HTTPError, OSError):
        return None
    return GatewayStatus.model_validate_json(response.content) if response.status_code == 200 else None


def _both_running(http_port: int) -> bool:
    status = _status(http_port)
    return (
        status is not None
        and set(status.robots) == {"ur5", "panda"}
        and all(not r.faults and r.controller_mode == "running" for r in status.robots.values())
    )


def test_hrc_cell_runs_the_two_arm_cell_with_one_controller_per_robot(tmp_path: Path) -> None:
    http_port, zenoh_port = free_port(), free_port()
    log = tmp_path / "hrc-cell.log"
    record_dir = tmp_path / "recording"
    args = ["--config", str(CONFIG), "--insecure-plain-tcp", "--http-port", str(http_port), "--record", str(record_dir)]
    proc = start_program("hrc_tools.cell", [*args, "--zenoh-port", str(zenoh_port)], log)
    try:
        wait_for(lambda: _both_running(http_port), READY_S, "both robots running without faults", [proc])
    except StartupError as exc:
        stop_program(proc)
        raise AssertionError(f"{exc}\n{log_tail(log, 30)}") from None
    audit_json, audit_log = tmp_path / "audit.json", tmp_path / "audit.log"
    audit_args = ["--config", str(CONFIG), "--zenoh-mode", "client", "--zenoh-connect", f"tcp/127.0.0.1:{zenoh_port}"]
    audit = start_program(
        "hrc_tools.audit", [*audit_args, "--duration-s", str(AUDIT_S), "--json", str(audit_json)], audit_log
    )
    try:
        audit_code = audit.wait(READY_S)
    finally:
        stop_program(audit)
        assert stop_program(proc, signal.SIGINT) == 0, log_tail(log, 30)
    assert audit_code == 0, log_tail(audit_log, 30)
    report = json.loads(audit_json.read_text())
    assert set(report["robots"]) == {"ur5", "panda"}
    for robot, audited in report["robots"].items():
        assert audited["cycles"] > 250, (robot, audited)  # 4 ms controller cycles: >= 1 s of each robot audited
        assert audited["violations"] == 0, (robot, audited)
    text = log.read_text()
    assert "(gateway, controller-ur5, controller-panda, tracker, recorder)" in text
    assert "controller panda of cell 'twoarms'" in text
    assert "controller ur5 of cell 'twoarms'" in text

    _check_recordings(record_dir)


def _check_recordings(record_dir: Path) -> None:
    with (record_dir / "cell.mcap").open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None
    topics = {channel.topic for channel in summary.channels.values()}
    for robot in ("ur5", "panda"):
        assert any(robot in topic and "state" in topic for topic in topics), topics
        assert any(robot in topic and "override" in topic for topic in topics), topics
    assert all(channel.schema_id != 0 for channel in summary.channels.values())
    replay = subprocess.run(
        [sys.executable, "-m", "hrc_tools.record.replay", str(record_dir / "gateway.mcap")],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert replay.returncode == 0, replay.stdout + replay.stderr
