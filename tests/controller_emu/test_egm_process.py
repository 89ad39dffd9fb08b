"""``hrc-controller-emu --egm HOST:PORT`` as a process: an open Panda (configs/cell_two_arms.toml with ``control =
"open"``) plays ABB EGM's controller side toward abb-robot-client's ``EGM``, which reads its feedback and drives it;
the truth key shows the same motion, the cell's state key stays silent (a bridge's); SIGINT ends it cleanly."""

from __future__ import annotations

import signal
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh
from abb_robot_client.egm import EGM, EGMRobotState
from support.cell_files import open_panda_cell
from support.recorder import Recorder

from hrc_contract import keys
from hrc_contract.messages import JointState, parse_message
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import Program, free_endpoint, start_program, stop_all

pytestmark = pytest.mark.e2e

CELL, ROBOT = "twoarms", "panda"
Q0 = np.array([0.5, 0.2, 0.0, -2.0, 0.0, 2.2, 0.785, 0.03, 0.03])  # the program's first waypoint
DEADLINE_S = 30.0


@pytest.fixture
def client() -> Iterator[EGM]:
    egm = EGM(port=0)
    yield egm
    egm.close()


@pytest.fixture
def egm_controller(tmp_path: Path, client: EGM) -> Iterator[tuple[Program, str, Path]]:
    endpoint = free_endpoint()
    log_path = tmp_path / "controller.log"
    egm = f"127.0.0.1:{client.socket.getsockname()[1]}"
    args = ["--config", str(open_panda_cell(tmp_path)), "--robot", ROBOT, "--zenoh-listen", endpoint, "--egm", egm]
    proc = start_program("controller_emu", args, log_path)
    try:
        yield proc, endpoint, log_path
    finally:
        stop_all([proc])


def _receive(client: EGM, timeout_s: float = DEADLINE_S) -> EGMRobotState:
    ok, state = client.receive_from_robot(timeout=timeout_s)
    assert ok, f"no EgmRobot within {timeout_s} s"
    return state


def test_abb_robot_client_reads_and_drives_the_emulators_egm_face(
    egm_controller: tuple[Program, str, Path], client: EGM
) -> None:
    proc, endpoint, log_path = egm_controller
    truth = Recorder(lambda payload: parse_message(payload, JointState))
    reported = Recorder(lambda payload: parse_message(payload, JointState))
    state = _receive(client)  # the controller speaks first, once it runs (start-up included)
    np.testing.assert_allclose(state.joint_angles, np.degrees(Q0[:6]), rtol=0, atol=1e-6)
    np.testing.assert_allclose(state.external_axes, np.degrees(Q0[6:]), rtol=0, atol=1e-6)
    assert (state.rapid_running, state.motors_on) == (True, True)
    target = Q0 + np.array([0.2, -0.1, 0.0, 0.15, 0.0, 0.0, -0.2, 0.0, 0.0])
    target_deg = np.degrees(target)
    with zenoh.open(session_config(connect=[endpoint])) as session:
        truth_sub = session.declare_subscriber(keys.truth_robot_state(CELL, ROBOT), truth.on_sample)
        state_sub = session.declare_subscriber(keys.robot_state(CELL, ROBOT), reported.on_sample)
        end = time.monotonic() + DEADLINE_S
        while np.max(np.abs(np.r_[state.joint_angles, state.external_axes] - target_deg)) > 0.05:
            assert time.monotonic() < end, f"the emulator did not follow within {DEADLINE_S} s"
            assert client.send_to_robot(target_deg[:6], np.zeros(6), external_joints=target_deg[6:])
            state = _receive(client, 5.0)
        # the truth the auditor reads is the same robot, on the reference
        end = time.monotonic() + DEADLINE_S
        while truth.latest() is None or np.max(np.abs(np.array(truth.latest().q) - target)) > np.radians(0.1):
            assert time.monotonic() < end, "the truth key does not show the robot on the reference"
            assert client.send_to_robot(target_deg[:6], np.zeros(6), external_joints=target_deg[6:])
            _receive(client, 5.0)
        assert truth.latest().mode == "running"
        assert reported.items() == [], "with EGM the state key is the bridge's: the emulator publishes none there"
        del truth_sub, state_sub
    proc.send_signal(signal.SIGINT)
    assert proc.wait(10.0) == 0
    log = log_path.read_text()
    assert "EGM (EgmRobot to 127.0.0.1:" in log
    assert "Traceback" not in log
