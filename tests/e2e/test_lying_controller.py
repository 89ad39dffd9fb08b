"""A lying controller end to end (issue 32, item 6): joint states that contradict themselves, against a real gateway.

The cell runs ``standing_inside`` (a person 2 m from the robot: the robot moves, δ > 0). The test then stops the
controller emulator and takes its place: a :class:`~controller_emu.node.ControllerNode` in this process, following the
gateway's overrides over real Zenoh as the emulator does, publishing its joint states on the robot's key, first
honestly (the cell recovers and moves), then lying:

- ``still``: ``q`` advances at the programmed speed (each 4 ms step within the URDF limit) while ``qd`` and
  ``qd_nominal`` say 0 (the gateway, believing the robot still, would command δ = 1);
- ``reversed``: ``qd_nominal`` reversed while ``qd`` still says where the robot goes (caught as ``qd_inconsistent``;
  once stopped by the fault the robot is consistent whatever it says, and δ came back in bursts).

Both follow the gateway's δ like a real driver over a real arm: stopped, they stand. Every status for the whole lie
must show δ = 0 with ``joint_state_inconsistent`` (no burst between detections), and the controller's own applied
override must have fallen to 0.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest
import zenoh

from controller_emu.node import ControllerNode
from hrc_contract import keys
from hrc_contract.messages import JointState, to_payload
from hrc_devices.robots.model import load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import read_clocks
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import Cell, running_cell, stop_program

pytestmark = pytest.mark.e2e

READY_S = 25.0
DETECT_S = 3.0
LIE_S = 3.0
"""How long each lie is watched: several times the fault's hold (0.5 s), so a fault that clears shows as a burst."""
CYCLE_S = 0.004
RESTART_GAP_S = 1.5
"""This test's controller starts its program from the beginning, elsewhere than the emulator stopped: after this
long the jump is within every joint's velocity limit (``q_jump``), so the takeover is only a restart."""

Lie = Callable[[JointState], JointState]


def _honest(state: JointState) -> JointState:
    return state


def _still(state: JointState) -> JointState:
    zero = [0.0] * len(state.q)
    return state.model_copy(update={"qd": zero, "qd_nominal": zero})


def _reversed(state: JointState) -> JointState:
    return state.model_copy(update={"qd_nominal": [-v for v in state.qd_nominal]})


class _Controller:
    """The emulated controller in this process: overrides in, a joint state every 4 ms out, told how to lie."""

    def __init__(self, cell: Cell) -> None:
        config = load_cell_config(None)
        robot = config.robots["ur5"]
        self.node = ControllerNode(
            "ur5", load_trajectory(robot.program, load_robot_model("ur5", robot)), robot.controller
        )
        self.lie: Lie = _honest
        self.applied = 1.0
        self._cell = cell
        self._stop = threading.Event()

    @contextmanager
    def running(self) -> Iterator[None]:
        with zenoh.open(session_config(connect=[self._cell.gateway_endpoint])) as session:
            key = keys.robot_state(self._cell.name, "ur5")
            pub = session.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
            session.declare_subscriber(
                keys.robot_override(self._cell.name, "ur5"),
                lambda sample: self.node.on_override(sample.payload.to_bytes(), read_clocks()),
            )
            thread = threading.Thread(target=self._run, args=(pub,), daemon=True)
            thread.start()
            try:
                yield
            finally:
                self._stop.set()
                thread.join()

    def _run(self, pub: Any) -> None:
        next_s = time.monotonic()
        while not self._stop.is_set():
            output = self.node.cycle(read_clocks())
            self.applied = output.state.delta_applied
            pub.put(to_payload(self.lie(output.joint_state)))
            next_s += CYCLE_S
            self._stop.wait(max(0.0, next_s - time.monotonic()))


def _codes(status: dict[str, Any]) -> set[str]:
    return {f["code"] for f in status["faults"]}


def _moving(status: dict[str, Any]) -> bool:
    return not status["faults"] and status["delta"] > 0.0 and (status["delta_applied"] or 0.0) > 0.0


def _hold_stopped(cell: Cell, controller: _Controller, duration_s: float) -> list[str]:
    """Every status for ``duration_s`` shows δ = 0 with ``joint_state_inconsistent``; the reasons seen."""
    start = time.monotonic()
    reasons: list[str] = []
    seen = 0
    while (elapsed_s := time.monotonic() - start) < duration_s:
        status = cell.robot()
        if status is not None:
            seen += 1
            rejected = cell.get("/api/v1/status").json()["inputs"]["rejected"]
            assert status["delta"] == 0.0, (f"{elapsed_s:.3f} s into the lie", status, reasons[-1:], rejected)
            assert "joint_state_inconsistent" in _codes(status), (f"{elapsed_s:.3f} s", status, rejected)
            reasons += [f["reason"] for f in status["faults"] if f["code"] == "joint_state_inconsistent"]
        time.sleep(0.02)
    assert seen >= 20
    assert controller.applied == 0.0  # the controller's own state: it has braked to a standstill
    return reasons


@pytest.mark.parametrize(
    ("lie", "reason"),
    [(_still, "q_motion_inconsistent"), (_reversed, "qd_inconsistent")],
    ids=["q_advancing_under_zero_velocities", "reversed_qd_nominal"],
)
def test_a_lying_controller_keeps_its_robot_stopped_without_bursts(tmp_path: Path, lie: Lie, reason: str) -> None:
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        cell.wait_until(_moving, READY_S, "a moving robot")
        stop_program(cell.controller)
        time.sleep(RESTART_GAP_S)
        controller = _Controller(cell)
        with controller.running():
            cell.wait_until(_moving, READY_S, "the robot moving again under this test's controller")
            controller.lie = lie
            cell.wait_until(
                lambda s: "joint_state_inconsistent" in _codes(s) and s["delta"] == 0.0, DETECT_S, "the lie caught"
            )
            reasons = _hold_stopped(cell, controller, LIE_S)
            assert any(r.startswith(reason) for r in reasons), sorted(set(reasons))
            assert reasons[-1].endswith("are seen moving consistently"), reasons[-1]
            rejected = cell.get("/api/v1/status").json()["inputs"]["rejected"]["robot/ur5"]
            assert rejected.get(reason, 0) >= 1, rejected
