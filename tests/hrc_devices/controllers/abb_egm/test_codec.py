"""The EGM codec judged by the ``egm_pb2`` compiled into abb-robot-client (protobuf's own parser and serializer):
ours encodes, theirs decodes, and back; a 7-axis arm's arm angle in ``externalJoints[0]``; the version of
``egm.proto`` (``measuredForce.force`` at tag 2); then hostile bytes refused with a reason."""

from __future__ import annotations

import contextlib
import math
import struct

import numpy as np
import pytest
from abb_robot_client._egm_protobuf import egm_pb2

from hrc_devices.controllers.abb_egm.codec import (
    MAX_DATAGRAM_BYTES,
    EgmRobot,
    EgmSensor,
    MciState,
    MessageType,
    MotorState,
    RapidState,
    decode_robot,
    decode_sensor,
    encode_robot,
    encode_sensor,
    joints_deg,
    joints_rad,
)
from hrc_devices.controllers.abb_egm.wire import EgmError, field_double, field_message, read_varint

PANDA_Q_RAD = (0.1, -0.785, -0.05, -2.356, 0.02, 1.571, 0.785)


def _robot_7axis() -> EgmRobot:
    joints, external = joints_deg(PANDA_Q_RAD)
    return EgmRobot(
        seqno=4_000_000_000,
        tm_ms=123_456,
        feedback_deg=joints,
        feedback_external_deg=external,
        feedback_time_us=1_790_000_123_456_789,
        planned_deg=tuple(v + 0.5 for v in joints),
        planned_external_deg=tuple(v - 0.5 for v in external),
        motors=MotorState.ON,
        mci=MciState.RUNNING,
        mci_convergence_met=True,
        rapid=RapidState.RUNNING,
        force_control_active=True,
        measured_force=(1.0, -2.0, 3.5, 0.0, 0.25, -0.125),
        utilization_rate_pct=12.5,
    )


def test_a_7_axis_robot_message_encoded_here_is_read_by_egm_pb2_field_by_field() -> None:
    msg = _robot_7axis()
    theirs = egm_pb2.EgmRobot()
    theirs.ParseFromString(encode_robot(msg))
    assert theirs.IsInitialized()
    assert (theirs.header.seqno, theirs.header.tm) == (4_000_000_000, 123_456)
    assert theirs.header.mtype == egm_pb2.EgmHeader.MSGTYPE_DATA
    assert list(theirs.feedBack.joints.joints) == list(msg.feedback_deg)
    assert len(theirs.feedBack.joints.joints) == 6
    assert list(theirs.feedBack.externalJoints.joints) == [math.degrees(PANDA_Q_RAD[6])]
    assert (theirs.feedBack.time.sec, theirs.feedBack.time.usec) == (1_790_000_123, 456_789)
    assert list(theirs.planned.joints.joints) == list(msg.planned_deg)
    assert list(theirs.planned.externalJoints.joints) == list(msg.planned_external_deg)
    assert theirs.motorState.state == egm_pb2.EgmMotorState.MOTORS_ON
    assert theirs.mciState.state == egm_pb2.EgmMCIState.MCI_RUNNING
    assert theirs.mciConvergenceMet is True
    assert theirs.rapidExecState.state == egm_pb2.EgmRapidCtrlExecState.RAPID_RUNNING
    assert theirs.measuredForce.fcActive is True
    assert list(theirs.measuredForce.force) == [1.0, -2.0, 3.5, 0.0, 0.25, -0.125]
    assert theirs.utilizationRate == 12.5
    # and the bytes are protobuf's own: same fields, same order, repeated doubles not packed
    assert theirs.SerializeToString() == encode_robot(msg)


def test_a_robot_message_from_egm_pb2_decodes_to_the_same_values() -> None:
    theirs = egm_pb2.EgmRobot()
    theirs.header.seqno, theirs.header.tm = 17, 68
    theirs.header.mtype = egm_pb2.EgmHeader.MSGTYPE_DATA
    theirs.feedBack.joints.joints.extend([10.0, -20.0, 30.0, -40.0, 50.0, -60.0])
    theirs.feedBack.externalJoints.joints.extend([45.0])
    theirs.feedBack.time.sec, theirs.feedBack.time.usec = 5, 4000
    theirs.feedBack.cartesian.pos.x = 1.0  # not read here: skipped as protobuf skips unknown fields
    theirs.feedBack.cartesian.pos.y = 2.0
    theirs.feedBack.cartesian.pos.z = 3.0
    theirs.planned.joints.joints.extend([11.0, -21.0, 31.0, -41.0, 51.0, -61.0])
    theirs.motorState.state = egm_pb2.EgmMotorState.MOTORS_OFF
    theirs.mciState.state = egm_pb2.EgmMCIState.MCI_STOPPED
    theirs.rapidExecState.state = egm_pb2.EgmRapidCtrlExecState.RAPID_STOPPED
    theirs.testSignals.signals.extend([1.0, 2.0])
    theirs.moveIndex = 9
    theirs.RAPIDfromRobot.dnum.extend([3.0])
    ours = decode_robot(theirs.SerializeToString())
    assert (ours.seqno, ours.tm_ms) == (17, 68)
    assert ours.feedback_deg == (10.0, -20.0, 30.0, -40.0, 50.0, -60.0)
    assert ours.feedback_external_deg == (45.0,)
    assert ours.feedback_time_us == 5_004_000
    assert ours.planned_deg == (11.0, -21.0, 31.0, -41.0, 51.0, -61.0)
    assert (ours.motors, ours.mci, ours.rapid) == (MotorState.OFF, MciState.STOPPED, RapidState.STOPPED)
    assert (ours.mci_convergence_met, ours.force_control_active, ours.utilization_rate_pct) == (None, None, None)
    np.testing.assert_allclose(
        joints_rad(ours.feedback_deg, ours.feedback_external_deg, 7), np.radians([10, -20, 30, -40, 50, -60, 45])
    )


def test_this_is_the_egm_proto_with_force_at_tag_2() -> None:
    """abb-robot-client's ``egm.proto`` (the newer one): ``fcActive`` 1, ``force`` 2; the older file's ``force`` at
    tag 1 reads here as a bool's varint where doubles were: refused, not misread."""
    ours = decode_robot(field_message(9, field_double(2, 7.5) + field_double(2, -1.0)))
    assert ours.measured_force == (7.5, -1.0)
    theirs = egm_pb2.EgmRobot()
    theirs.ParseFromString(encode_robot(EgmRobot(seqno=0, tm_ms=0, feedback_deg=(), measured_force=(7.5, -1.0))))
    assert list(theirs.measuredForce.force) == [7.5, -1.0]
    with pytest.raises(EgmError, match="fcActive: not a varint"):
        decode_robot(field_message(9, field_double(1, 7.5)))  # the older file's EgmMeasuredForce


def test_a_sensor_message_from_abb_robot_clients_send_to_robot_is_decoded() -> None:
    """What ``EGM.send_to_robot(joint_angles, speed_ref)`` builds (its code, with its seqno and no ``tm``)."""
    theirs = egm_pb2.EgmSensor()
    theirs.header.mtype = egm_pb2.EgmHeader.MessageType.Value("MSGTYPE_CORRECTION")
    theirs.header.seqno = 3
    theirs.planned.joints.joints.extend([1.5, 2.5, 3.5, 4.5, 5.5, 6.5])
    theirs.planned.externalJoints.joints.extend([-7.5])
    theirs.speedRef.joints.joints.extend([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    theirs.speedRef.externalJoints.joints.extend([-0.7])
    ours = decode_sensor(theirs.SerializeToString())
    assert ours == EgmSensor(
        seqno=3,
        tm_ms=0,
        planned_deg=(1.5, 2.5, 3.5, 4.5, 5.5, 6.5),
        planned_external_deg=(-7.5,),
        speed_ref_degps=(0.1, 0.2, 0.3, 0.4, 0.5, 0.6),
        speed_ref_external_degps=(-0.7,),
        mtype=MessageType.CORRECTION,
    )
    np.testing.assert_allclose(
        joints_rad(ours.planned_deg, ours.planned_external_deg, 7), np.radians([1.5, 2.5, 3.5, 4.5, 5.5, 6.5, -7.5])
    )


def test_a_sensor_message_encoded_here_is_protobufs_own_bytes() -> None:
    joints, external = joints_deg(PANDA_Q_RAD)
    ours = EgmSensor(seqno=5, tm_ms=20, planned_deg=joints, planned_external_deg=external, speed_ref_degps=(1.0,) * 6)
    theirs = egm_pb2.EgmSensor()
    theirs.ParseFromString(encode_sensor(ours))
    assert list(theirs.planned.joints.joints) == list(joints)
    assert list(theirs.planned.externalJoints.joints) == list(external)
    assert list(theirs.speedRef.joints.joints) == [1.0] * 6
    assert (theirs.header.seqno, theirs.header.tm, theirs.header.mtype) == (5, 20, 3)
    assert theirs.SerializeToString() == encode_sensor(ours)
    assert decode_sensor(encode_sensor(ours)) == ours


def test_packed_doubles_and_repeated_submessages_decode_as_protobuf_merges_them() -> None:
    packed = field_message(1, b"\x0a\x10" + struct.pack("<2d", 1.0, 2.0))  # joints [1, 2] packed
    data = field_message(2, packed) + field_message(2, field_message(1, field_double(1, 3.0)))
    theirs = egm_pb2.EgmSensor()
    theirs.ParseFromString(data)
    assert decode_sensor(data).planned_deg == tuple(theirs.planned.joints.joints) == (1.0, 2.0, 3.0)


@pytest.mark.parametrize("n_joints", [1, 6, 7])
def test_joints_survive_the_trip_to_degrees_and_back(n_joints: int) -> None:
    q_rad = np.random.default_rng(n_joints).uniform(-3.0, 3.0, n_joints)
    joints, external = joints_deg(q_rad)
    assert len(joints) == min(n_joints, 6)
    np.testing.assert_allclose(joints_rad(joints, external, n_joints), q_rad, rtol=0, atol=1e-12)


def test_joint_counts_that_are_not_the_robots_are_refused() -> None:
    with pytest.raises(EgmError, match=r"joint_count.*arm angle as externalJoints"):
        joints_rad((0.0,) * 6, (), 7)
    with pytest.raises(EgmError, match="joint_count"):
        joints_rad((0.0,) * 7, (), 7)
    with pytest.raises(EgmError, match="joint_count"):
        joints_rad((0.0,) * 5, (), 6)
    assert joints_rad((0.0,) * 6, (90.0, 1.0), 6).shape == (6,)  # a track or positioner is not the arm's


@pytest.mark.parametrize(
    ("data", "reason"),
    [
        (b"\x0a\x05\x08", "malformed"),  # the header announces 5 bytes, 1 is there
        (b"\x12\x02\x0a\x09", "malformed"),  # planned.joints announced past the end
        (b"\x0b", "malformed"),  # a group (wire type 3)
        (b"\x00\x01", "malformed"),  # field number 0
        (b"\x08" + b"\xff" * 11, "malformed"),  # a varint longer than 10 bytes
        (b"\x12\x03\x0a\x01\x08", "malformed"),  # joints as a varint, not doubles
        (field_message(2, field_message(1, field_double(1, math.nan))), "non_finite"),
        (field_message(3, field_message(1, field_double(1, math.inf))), "non_finite"),
        (field_message(2, field_message(1, field_double(1, 0.0) * 17)), "too_many"),
        (b"\x00" * (MAX_DATAGRAM_BYTES + 1), "oversize"),
    ],
)
def test_hostile_sensor_bytes_are_refused_with_a_reason(data: bytes, reason: str) -> None:
    with pytest.raises(EgmError) as info:
        decode_sensor(data)
    assert info.value.reason == reason


def test_truncated_robot_messages_never_raise_anything_but_egm_error() -> None:
    data = encode_robot(_robot_7axis())
    for end in range(len(data)):
        with contextlib.suppress(EgmError):
            decode_robot(data[:end])


def test_varints_read_as_protobuf_writes_them() -> None:
    for value in (0, 1, 127, 128, 300, 2**32 - 1, 2**63):
        header = egm_pb2.EgmClock(sec=value, usec=0).SerializeToString()
        assert read_varint(header, 1) == (value, len(header) - 2)
