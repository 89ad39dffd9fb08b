"""The open controller's EGM face judged by abb-robot-client's ``EGM`` (a client this project does not write): its
``receive_from_robot`` reads the emulator's joints in degrees, its ``send_to_robot`` drives it (a 6-axis UR5 by
joints and speed references, a Panda with the arm angle and fingers in ``externalJoints``), silence is EGM's position
mode (converge on the last reference, stop after the communication timeout), and foreign or broken datagrams are
counted and dropped. The emulator's loop runs in a thread at its real rate; nothing is judged on timing."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from dataclasses import replace

import numpy as np
import numpy.typing as npt
import pytest
from abb_robot_client._egm_protobuf import egm_pb2
from abb_robot_client.egm import EGM, EGMRobotState
from support.egm import EmulatorLoop
from support.paths import DEFAULT_CELL_PATH

from controller_emu.egm_face import EgmFace, robot_message, sender_is_pc, sensor_command
from controller_emu.open_follower import follower_limits
from controller_emu.open_node import OpenControllerNode
from hrc_contract.config import CellConfig, ControllerConfig
from hrc_devices.controllers.abb_egm.codec import EgmSensor, MciState, encode_sensor, joints_deg
from hrc_devices.controllers.abb_egm.wire import EgmError
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import Clocks, read_clocks
from hrc_runtime.config import load_cell_config

FloatArray = npt.NDArray[np.float64]
WATCHDOG_S = 0.1
DEADLINE_S = 20.0  # generous: a loaded 2-core machine


def _node(name: str, model: RobotModel, q0: FloatArray) -> OpenControllerNode:
    config = ControllerConfig(control="open", watchdog_s=WATCHDOG_S, braking_time_s=0.24)
    limits = follower_limits(model, WATCHDOG_S, stop_time_s=0.24, on_silence="hold_reference")
    return OpenControllerNode(name, limits, q0, config)


@pytest.fixture
def ur5_node(cell_config: CellConfig, ur5: RobotModel) -> OpenControllerNode:
    q0, _ = load_trajectory(cell_config.robots["ur5"].program, ur5).sample(0.0)
    return _node("ur5", ur5, np.asarray(q0, dtype=float))


@pytest.fixture(scope="module")
def panda_cell() -> tuple[CellConfig, RobotModel]:
    config = load_cell_config(DEFAULT_CELL_PATH.parent / "cell_open_panda.toml")
    return config, load_robot_model("panda", config.robots["panda"])


@pytest.fixture
def panda_node(panda_cell: tuple[CellConfig, RobotModel]) -> OpenControllerNode:
    config, model = panda_cell
    q0, _ = load_trajectory(config.robots["panda"].program, model).sample(0.0)
    return _node("panda", model, np.asarray(q0, dtype=float))


@pytest.fixture
def client() -> Iterator[EGM]:
    egm = EGM(port=0)  # a free port of its own: the kernel's choice
    yield egm
    egm.close()


def _emulator(node: OpenControllerNode, client: EGM) -> EmulatorLoop:
    return EmulatorLoop(node, EgmFace(node, "127.0.0.1", client.socket.getsockname()[1]))


def _receive(client: EGM) -> EGMRobotState:
    ok, state = client.receive_from_robot(timeout=5.0)
    assert ok, "no EgmRobot within 5 s"
    return state


def _latest(client: EGM) -> EGMRobotState:
    """The newest EgmRobot: the ones queued in the socket while the test did not read are skipped."""
    state = _receive(client)
    while True:
        ok, newer = client.receive_from_robot(timeout=0.0)
        if not ok:
            return state
        state = newer


def _poll(condition: Callable[[], bool], what: str, deadline_s: float = DEADLINE_S) -> None:
    end = time.monotonic() + deadline_s
    while not condition():
        assert time.monotonic() < end, f"not within {deadline_s} s: {what}"
        time.sleep(0.01)


def _at_rest_on(node: OpenControllerNode, target: FloatArray) -> bool:
    """The robot stands on ``target`` (within 0.05°, below 0.01 rad/s): not merely passing through it."""
    state = node.state
    return bool(np.max(np.abs(state.q_rad - target)) < np.radians(0.05) and np.max(np.abs(state.qd_radps)) < 0.01)


def _drive(
    client: EGM, reference: Callable[[float], tuple[FloatArray, FloatArray]], until: Callable[[], bool]
) -> EGMRobotState:
    """Answer every EgmRobot with ``reference(feedback time [s])`` (q [rad], q̇ [rad/s]) until ``until()``; the
    last state read. A 6-axis reference goes as ``joint_angles`` and ``speed_ref``, a longer one's rest as
    ``external_joints`` and ``external_joints_speed``."""
    end = time.monotonic() + DEADLINE_S
    state = _receive(client)
    while not until():
        assert time.monotonic() < end, f"the emulator did not get there within {DEADLINE_S} s"
        feedback_time = state.robot_message.feedBack.time
        q_rad, qd_radps = reference(feedback_time.sec + feedback_time.usec * 1e-6)
        joints, external = joints_deg(q_rad)
        speed, speed_external = joints_deg(qd_radps)
        sent = client.send_to_robot(
            np.array(joints),
            np.array(speed),
            external_joints=np.array(external) if external else None,
            external_joints_speed=np.array(speed_external) if speed_external else None,
        )
        assert sent
        state = _receive(client)
    return state


# --- the field's client reads the feedback ------------------------------------------------------------------------


def test_the_clients_receive_reads_the_panda_in_degrees_with_the_arm_angle_in_external_joints(
    panda_node: OpenControllerNode, client: EGM
) -> None:
    q0 = panda_node.state.q_rad.copy()
    with _emulator(panda_node, client) as emulator:
        state = _receive(client)
        np.testing.assert_allclose(state.joint_angles, np.degrees(q0[:6]), rtol=0, atol=1e-9)
        np.testing.assert_allclose(state.external_axes, np.degrees(q0[6:]), rtol=0, atol=1e-9)
        assert state.external_axes[0] == pytest.approx(np.degrees(q0[6]))  # the arm angle first
        np.testing.assert_allclose(state.joint_angles_planned, np.degrees(q0[:6]), rtol=0, atol=1e-9)
        assert (state.rapid_running, state.motors_on) == (True, True)
        message = state.robot_message
        assert message.header.mtype == egm_pb2.EgmHeader.MSGTYPE_DATA
        assert message.mciState.state == egm_pb2.EgmMCIState.MCI_STOPPED  # no reference yet
        seqnos = [message.header.seqno] + [_receive(client).robot_message.header.seqno for _ in range(5)]
        assert np.all(np.diff(seqnos) == 1), "the controller numbers its messages consecutively"
        _poll(lambda: emulator.face.stats().sent >= 6, "six sent counted")  # counted just after the send


# --- the field's client drives the emulator -------------------------------------------------------------------


def test_the_clients_joint_references_drive_a_6_axis_robot_to_a_target(
    ur5_node: OpenControllerNode, client: EGM
) -> None:
    q0 = ur5_node.state.q_rad.copy()
    target = q0 + np.array([0.3, -0.2, 0.25, 0.1, -0.1, 0.4])
    with _emulator(ur5_node, client) as emulator:
        state = _drive(client, lambda t: (target, np.zeros(6)), lambda: _at_rest_on(ur5_node, target))
        np.testing.assert_allclose(ur5_node.state.q_ref_rad, target, rtol=0, atol=1e-12)
        assert ur5_node.state.mode == "running"
        np.testing.assert_allclose(state.joint_angles, np.degrees(target), rtol=0, atol=0.2)
        assert state.robot_message.mciConvergenceMet
        stats = emulator.face.stats()
    assert stats.accepted > 0
    assert dict(stats.refused) == {}
    assert state.robot_message.mciState.state == egm_pb2.EgmMCIState.MCI_RUNNING


def test_a_moving_reference_with_its_speed_is_followed_then_silence_converges_on_the_last_one(
    panda_node: OpenControllerNode, client: EGM
) -> None:
    """Joint 1 of the Panda ramps at 0.3 rad/s with its feed-forward; the robot follows the accepted reference. Then
    the PC falls silent: the robot converges on the last reference and holds it (EGM's position mode) until the
    communication timeout, then stands in a protective stop (``mciState`` STOPPED); references resume it."""
    q0 = panda_node.state.q_rad.copy()
    speed_radps = 0.3
    t0_s: list[float] = []

    def ramp(t_s: float) -> tuple[FloatArray, FloatArray]:
        t0_s.append(t_s) if not t0_s else None
        q, qd = q0.copy(), np.zeros_like(q0)
        q[0] += speed_radps * (t_s - t0_s[0] + 0.004)  # the reference for the end of the coming cycle
        qd[0] = speed_radps
        return q, qd

    with _emulator(panda_node, client) as emulator:
        _drive(client, ramp, lambda: bool(panda_node.state.q_rad[0] - q0[0] > 0.3))
        following = panda_node.state
        assert following.mode == "running"
        assert following.qd_radps[0] == pytest.approx(speed_radps, rel=0.3)
        assert following.q_ref_rad is not None
        assert abs(following.q_rad[0] - following.q_ref_rad[0]) < 0.02, "on the accepted reference"
        # silence
        _poll(lambda: panda_node.state.mode == "protective_stop", "the stop after the communication timeout")
        _poll(lambda: bool(np.all(panda_node.state.qd_radps == 0.0)), "standstill")
        held = panda_node.state
        assert held.q_ref_rad is not None
        np.testing.assert_allclose(held.q_rad, held.q_ref_rad, rtol=0, atol=2e-3)  # converged on the last reference
        assert _latest(client).robot_message.mciState.state == egm_pb2.EgmMCIState.MCI_STOPPED
        # resumption from where it stands
        target = held.q_rad + np.array([0.0, 0.1, 0, 0, 0, 0, 0, 0, 0])
        _drive(client, lambda t: (target, np.zeros(9)), lambda: _at_rest_on(panda_node, target))
        assert panda_node.state.mode == "running"
        assert dict(emulator.face.stats().refused) == {}


# --- what is refused ------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("sender", "pc", "expected"),
    [
        (("127.0.0.1", 6510), ("127.0.0.1", 6510), True),
        (("127.0.0.1", 6510), ("127.0.0.5", 6510), True),  # a PC bound to all addresses answers from 127.0.0.1
        (("127.0.0.1", 6511), ("127.0.0.1", 6510), False),
        (("10.0.0.9", 6510), ("10.0.0.8", 6510), False),
        (("10.0.0.9", 6510), ("127.0.0.1", 6510), False),
        (("10.0.0.8", 6510), ("10.0.0.8", 6510), True),
    ],
)
def test_only_the_pcs_address_is_listened_to(sender: tuple[str, int], pc: tuple[str, int], expected: bool) -> None:
    assert sender_is_pc(sender, pc) is expected


def test_foreign_broken_and_wrong_datagrams_are_counted_and_dropped(panda_node: OpenControllerNode) -> None:
    face = EgmFace(panda_node, "127.0.0.1", 6510)
    face._pc = ("127.0.0.1", 6510)  # as start() resolves it, without a socket
    joints, external = joints_deg(panda_node.state.q_rad)
    good = encode_sensor(EgmSensor(seqno=1, tm_ms=0, planned_deg=joints, planned_external_deg=external))
    now = read_clocks()
    assert face.on_datagram(good, ("10.1.2.3", 6510), now) == "foreign_sender"
    assert face.on_datagram(b"\x0b", ("127.0.0.1", 6510), now) == "malformed"
    six = encode_sensor(EgmSensor(seqno=1, tm_ms=0, planned_deg=joints))
    assert face.on_datagram(six, ("127.0.0.1", 6510), now) == "joint_count"
    short_speed = encode_sensor(
        replace(EgmSensor(seqno=1, tm_ms=0, planned_deg=joints, planned_external_deg=external), speed_ref_degps=(1.0,))
    )
    assert face.on_datagram(short_speed, ("127.0.0.1", 6510), now) == "joint_count"
    assert face.on_datagram(good, ("127.0.0.1", 6510), now) is None
    stats = face.stats()
    assert (stats.received, stats.accepted) == (5, 1)
    assert dict(stats.refused) == {"foreign_sender": 1, "joint_count": 2, "malformed": 1}
    assert panda_node.stats().commands_accepted == 1


def test_a_sensor_datagram_becomes_a_command_in_radians() -> None:
    data = encode_sensor(
        EgmSensor(seqno=9, tm_ms=0, planned_deg=(90.0,) * 6, planned_external_deg=(-45.0,), speed_ref_degps=())
    )
    command = sensor_command(data, "panda7", 7, seq=3, stamp_ns=5)
    np.testing.assert_allclose(command.q, [np.pi / 2] * 6 + [-np.pi / 4])
    assert command.qd == [0.0] * 7  # no speed reference: no feed-forward
    assert (command.robot, command.seq, command.stamp_ns) == ("panda7", 3, 5)
    with_speed = encode_sensor(replace(EgmSensor(9, 0, (90.0,) * 6, (-45.0,)), speed_ref_degps=(1.0,) * 6))
    command = sensor_command(with_speed, "panda7", 7, seq=4, stamp_ns=6)
    np.testing.assert_allclose(command.qd, [np.radians(1.0)] * 6 + [0.0])  # no external speed: none for the arm angle
    assert len(sensor_command(data, "ur5", 6, seq=0, stamp_ns=5).q) == 6  # a track or positioner: not the arm's
    with pytest.raises(EgmError, match="joint_count"):
        sensor_command(data, "panda", 9, seq=0, stamp_ns=5)  # the fingers are missing


def test_the_robot_message_reports_following_and_convergence(ur5_node: OpenControllerNode) -> None:
    output = ur5_node.cycle(Clocks(1_790_000_000_000_000_000, 1_000_000_000))
    message = robot_message(output, seqno=1, tm_ms=0)
    assert (message.mci, message.mci_convergence_met) == (MciState.STOPPED, False)
    assert message.planned_deg == message.feedback_deg  # no reference: it plans to stay
    assert message.feedback_time_us == 1_790_000_000_000_000
