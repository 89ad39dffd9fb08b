"""Hostile input end to end (issue 9): a forger on the bus next to a genuine tracker, against the real programs.

The cell runs ``standing_inside`` (a person 2 m from the robot: the robot moves, δ > 0). A test session then
puts forged tracker frames on ``hrc/demo/tracker/front/humans`` over real Zenoh. Every case must stop the robot
(δ = 0 in the gateway's status AND an applied override of 0 at the controller) with the fault named in the
status, for as long as the forgery goes on, and the cell must recover by itself afterwards.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh

from hrc_contract import keys
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import Cell, running_cell

pytestmark = pytest.mark.e2e

READY_S = 25.0
DETECT_S = 3.0
RECOVER_S = 10.0
FORGE_S = 2.0
TRACKER_PERIOD_S = 1 / 30


def _codes(status: dict[str, Any]) -> set[str]:
    return {f["code"] for f in status["faults"]}


def _moving(status: dict[str, Any]) -> bool:
    return not status["faults"] and status["delta"] > 0.0 and (status["delta_applied"] or 0.0) > 0.0


def _frame(seq: int, stamp_ns: int, humans: list[dict[str, Any]]) -> bytes:
    return json.dumps(
        {"schema": "hrc.humans/1", "tracker": "front", "seq": seq, "stamp_ns": stamp_ns, "humans": humans}
    ).encode()


@contextmanager
def _forger(cell: Cell, make: Callable[[int], bytes]) -> Iterator[None]:
    """Put ``make(k)`` on the front tracker's key at the tracker's rate until the block ends."""
    stop = threading.Event()
    with zenoh.open(session_config(connect=[cell.gateway_endpoint])) as session:
        pub = session.declare_publisher(
            keys.tracker_humans(cell.name, "front"), congestion_control=zenoh.CongestionControl.BLOCK
        )

        def run() -> None:
            k = 0
            while not stop.is_set():
                pub.put(make(k))
                k += 1
                stop.wait(TRACKER_PERIOD_S)

        thread = threading.Thread(target=run, daemon=True)
        thread.start()
        try:
            yield
        finally:
            stop.set()
            thread.join()


def _hold_stopped(cell: Cell, code: str, duration_s: float) -> None:
    """Every status for ``duration_s`` shows δ = 0 with ``code`` among the faults, and the controller stopped."""
    end = time.monotonic() + duration_s
    seen = 0
    while time.monotonic() < end:
        status = cell.robot()
        if status is not None:
            seen += 1
            assert status["delta"] == 0.0, status
            assert code in _codes(status), status
        time.sleep(0.05)
    assert seen >= 5
    status = cell.robot()
    assert status is not None
    assert status["delta_applied"] == 0.0  # the controller's own report: it has braked to a standstill


def _run_case(tmp_path: Path, code: str, make: Callable[[int], bytes]) -> None:
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        cell.wait_until(_moving, READY_S, "a moving robot")
        with _forger(cell, make):
            cell.wait_until(lambda s: code in _codes(s) and s["delta"] == 0.0, DETECT_S, f"a {code} fault")
            _hold_stopped(cell, code, FORGE_S)
        cell.wait_until(_moving, RECOVER_S, "recovery once the forger stopped")


def test_forged_future_nobody_frames_keep_the_robot_stopped(tmp_path: Path) -> None:
    """Issue 9, hole 3: "nobody here" stamped 4 ms ahead, interleaved with the genuine tracker's frames."""
    _run_case(tmp_path, "tracker_out_of_order", lambda k: _frame(10**9 + k, time.time_ns() + 4_000_000, []))


def test_a_kilometre_capsule_stops_the_robot(tmp_path: Path) -> None:
    """Issue 9, hole 1: a capsule kilometres long whose axis passes about a hand's width from the robot."""
    capsule = {"name": "forearm_r", "a": [-3000.0, 0.1, 1.3], "b": [3000.0, 0.1, 1.3], "radius": 0.03}
    humans = [{"id": "ghost", "capsules": [capsule]}]
    _run_case(tmp_path, "tracker_implausible", lambda k: _frame(10**9 + k, time.time_ns(), humans))


def test_a_person_without_capsules_stops_the_robot(tmp_path: Path) -> None:
    """Issue 9, hole 2: a detected person with an empty capsule list is not "nobody"."""
    humans = [{"id": "h1", "capsules": []}]
    _run_case(tmp_path, "tracker_invalid", lambda k: _frame(10**9 + k, time.time_ns(), humans))
