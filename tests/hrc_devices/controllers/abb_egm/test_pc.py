"""The PC's side of EGM (``EgmPc``) against the emulator's EGM face over loopback UDP: it reads the joints in radians,
drives the robot to a reference, and its errors say why (timeout, nothing to answer yet, a bad reference); broken
datagrams are skipped and counted."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import numpy as np
import pytest
from support.egm import EmulatorLoop

from controller_emu.egm_face import EgmFace
from controller_emu.open_follower import follower_limits
from controller_emu.open_node import OpenControllerNode
from hrc_contract.config import CellConfig, ControllerConfig
from hrc_devices.controllers.abb_egm.codec import EgmRobot, encode_robot, joints_deg
from hrc_devices.controllers.abb_egm.pc import EgmPc
from hrc_devices.controllers.vendor import VendorError
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory

DEADLINE_S = 20.0


@pytest.fixture
def node(cell_config: CellConfig, ur5: RobotModel) -> OpenControllerNode:
    q0, _ = load_trajectory(cell_config.robots["ur5"].program, ur5).sample(0.0)
    limits = follower_limits(ur5, 0.1, stop_time_s=0.24, on_silence="hold_reference")
    return OpenControllerNode("ur5", limits, q0, ControllerConfig(control="open", braking_time_s=0.24))


@pytest.fixture
def pc() -> Iterator[EgmPc]:
    with EgmPc("127.0.0.1", 0, n_joints=6) as server:
        yield server


def test_the_pc_reads_the_emulator_and_drives_it_to_a_reference(node: OpenControllerNode, pc: EgmPc) -> None:
    q0 = node.state.q_rad.copy()
    target = q0 + np.array([-0.2, 0.1, 0.1, -0.1, 0.2, -0.3])
    with EmulatorLoop(node, EgmFace(node, "127.0.0.1", pc.port)):
        first = pc.receive(timeout_s=5.0)
        np.testing.assert_allclose(first.q_rad, q0, rtol=0, atol=1e-12)
        assert (first.following, first.motors_on, first.rapid_running) == (False, True, True)
        end = time.monotonic() + DEADLINE_S
        feedback = first
        while not (np.max(np.abs(feedback.q_rad - target)) < 1e-3 and feedback.following):
            assert time.monotonic() < end, f"not on the reference within {DEADLINE_S} s"
            pc.send(target, np.zeros(6))
            feedback = pc.receive(timeout_s=5.0)
        assert feedback.seqno > first.seqno
        assert feedback.planned_rad is not None
        np.testing.assert_allclose(feedback.planned_rad, target, rtol=0, atol=1e-9)
    np.testing.assert_allclose(node.state.q_ref_rad, target, rtol=0, atol=1e-12)
    assert pc.refused == {}


def test_errors_say_why(pc: EgmPc) -> None:
    with pytest.raises(VendorError, match="nothing to answer yet") as info:
        pc.send(np.zeros(6), np.zeros(6))
    assert info.value.reason == "closed"
    with pytest.raises(VendorError, match="allowed: 6 finite each"):
        pc.send(np.zeros(7), np.zeros(7))
    with pytest.raises(VendorError) as info:
        pc.receive(timeout_s=0.05)
    assert info.value.reason == "timeout"
    with pytest.raises(VendorError) as info:
        EgmPc("127.0.0.1", pc.port, n_joints=6).open()  # the port is taken
    assert info.value.reason == "connect"


def test_broken_datagrams_are_skipped_and_counted(pc: EgmPc) -> None:
    joints, _ = joints_deg(np.full(6, 0.5))
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as robot:
        robot.sendto(b"\x0b", ("127.0.0.1", pc.port))
        robot.sendto(encode_robot(EgmRobot(seqno=1, tm_ms=0, feedback_deg=joints[:5])), ("127.0.0.1", pc.port))
        robot.sendto(encode_robot(EgmRobot(seqno=2, tm_ms=0, feedback_deg=joints)), ("127.0.0.1", pc.port))
        feedback = pc.receive(timeout_s=5.0)
        assert feedback.seqno == 2
        np.testing.assert_allclose(feedback.q_rad, np.full(6, 0.5))
        assert pc.refused == {"joint_count": 1, "malformed": 1}
        pc.send(np.zeros(6), np.zeros(6))  # answered to the sender
        robot.settimeout(5.0)
        data, _ = robot.recvfrom(2048)
    assert len(data) > 0


def test_a_pc_bound_to_its_controller_skips_and_counts_every_other_sender() -> None:
    joints, _ = joints_deg(np.full(6, 0.25))
    datagram = encode_robot(EgmRobot(seqno=1, tm_ms=0, feedback_deg=joints))
    with (
        EgmPc("0.0.0.0", 0, n_joints=6, controller_host="127.0.0.1") as pc,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as stranger,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as robot,
    ):
        stranger.bind(("127.0.0.2", 0))
        stranger.sendto(datagram, ("127.0.0.1", pc.port))
        with pytest.raises(VendorError) as info:
            pc.receive(timeout_s=0.2)  # the stranger's EgmRobot is not the robot's feedback
        assert info.value.reason == "timeout"
        assert pc.refused == {"foreign_sender": 1}
        robot.bind(("127.0.0.1", 0))
        robot.sendto(datagram, ("127.0.0.1", pc.port))
        feedback = pc.receive(timeout_s=5.0)
        np.testing.assert_allclose(feedback.q_rad, np.full(6, 0.25))
