"""ABB EGM's two joint messages, pure: :class:`EgmRobot` (controller → PC) and :class:`EgmSensor` (PC → controller).

    data = encode_robot(EgmRobot(seqno=1, tm_ms=4, feedback_deg=(0.0, 10.0, ...), motors=MotorState.ON, ...))
    robot = decode_robot(data)
    q_rad = joints_rad(sensor.planned_deg, sensor.planned_external_deg, n_joints=7)

**Which ``egm.proto``.** Two versions circulate; this codec speaks the one compiled into ``abb-robot-client`` 0.4.0
(``abb_robot_client/_egm_protobuf/egm_pb2.py``, package ``abb.egm``, proto2), which ABB ships with RobotWare 6.07 and
later: ``EgmMeasuredForce`` is ``{optional bool fcActive = 1; repeated double force = 2}`` (the older file has
``repeated double force = 1`` alone), and ``EgmRobot`` goes on with ``moveIndex`` (11), ``CollisionInfo`` (12) and
``RAPIDfromRobot`` (13), which this codec neither sends nor reads (unknown fields are skipped, as protobuf does).
The fields used, by number::

    EgmHeader   {1 seqno uint32, 2 tm uint32 [ms], 3 mtype enum (2 DATA from the robot, 3 CORRECTION from the PC)}
    EgmJoints   {1 joints repeated double}                 [deg]; [deg/s] in a speed reference
    EgmClock    {1 sec uint64, 2 usec uint64}              (both required)
    EgmFeedBack / EgmPlanned {1 joints EgmJoints, 3 externalJoints EgmJoints, 4 time EgmClock}  (2 cartesian: not used)
    EgmSpeedRef {1 joints EgmJoints, 3 externalJoints EgmJoints}                                (2 cartesians: not used)
    EgmRobot    {1 header, 2 feedBack, 3 planned, 4 motorState {1 state}, 5 mciState {1 state},
                 6 mciConvergenceMet bool, 8 rapidExecState {1 state}, 9 measuredForce, 10 utilizationRate double}
    EgmSensor   {1 header, 2 planned EgmPlanned, 3 speedRef EgmSpeedRef}

Repeated doubles are written one by one (proto2's default, as ``egm_pb2`` does) and read either way (packed too).

**Joints.** Degrees (and deg/s) on the wire, radians on our side (:func:`joints_deg`, :func:`joints_rad`). An ABB
robot has at most six axes in ``joints``; a 7-axis arm sends its seventh (the arm angle) as ``externalJoints[0]``.
Here the seventh joint of the robot's model (index 6) is that value, and any further joints (the Panda's two fingers)
follow it in ``externalJoints``, in the model's order. (On a YuMi the arm angle sits between axes 2
and 3 physically; a bridge to a real YuMi would map it there.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

import numpy as np
import numpy.typing as npt

from hrc_devices.controllers.abb_egm.wire import (
    EgmError,
    WireValue,
    field_bool,
    field_double,
    field_message,
    field_varint,
    read_doubles,
    read_fields,
)

__all__ = [
    "MAX_DATAGRAM_BYTES",
    "MAX_JOINTS",
    "ROBOT_AXES",
    "EgmRobot",
    "EgmSensor",
    "MciState",
    "MessageType",
    "MotorState",
    "RapidState",
    "decode_robot",
    "decode_sensor",
    "encode_robot",
    "encode_sensor",
    "joints_deg",
    "joints_rad",
]

MAX_DATAGRAM_BYTES = 2048
"""The largest EGM datagram accepted [bytes]. An ``EgmRobot`` of a 7-axis arm with everything this codec sends is
about 200 bytes; an ``EgmSensor`` about 150."""

MAX_JOINTS = 16
"""Most values accepted in one joint list (``joints`` or ``externalJoints``)."""

ROBOT_AXES = 6
"""The most axes an ABB robot sends in ``joints``; a seventh rides in ``externalJoints[0]``."""


class MessageType(IntEnum):
    """``EgmHeader.MessageType``."""

    UNDEFINED = 0
    COMMAND = 1
    DATA = 2
    CORRECTION = 3
    PATH_CORRECTION = 4


class MotorState(IntEnum):
    """``EgmMotorState.MotorStateType``."""

    UNDEFINED = 0
    ON = 1
    OFF = 2


class MciState(IntEnum):
    """``EgmMCIState.MCIStateType``: the state of EGM's motion (running while it follows the sensor)."""

    UNDEFINED = 0
    ERROR = 1
    STOPPED = 2
    RUNNING = 3


class RapidState(IntEnum):
    """``EgmRapidCtrlExecState.RapidCtrlExecStateType``."""

    UNDEFINED = 0
    STOPPED = 1
    RUNNING = 2


@dataclass(frozen=True)
class EgmRobot:
    """What the controller sends every cycle (the fields this codec knows; the module docstring).

    Attributes:
        seqno: the header's sequence number (``uint32``).
        tm_ms: the header's time stamp [ms] (``uint32``; the controller's clock).
        feedback_deg: ``feedBack.joints``: the measured joint angles [deg].
        feedback_external_deg: ``feedBack.externalJoints`` [deg]: a 7-axis arm's arm angle first.
        feedback_time_us: ``feedBack.time`` as microseconds (``sec · 10⁶ + usec``); None when absent [µs].
        planned_deg: ``planned.joints``: where the controller is taking the robot [deg].
        planned_external_deg: ``planned.externalJoints`` [deg].
        motors: ``motorState``.
        mci: ``mciState``.
        mci_convergence_met: ``mciConvergenceMet``; None when absent.
        rapid: ``rapidExecState``.
        force_control_active: ``measuredForce.fcActive``; None when absent.
        measured_force: ``measuredForce.force`` (tag 2 in this ``egm.proto``); empty when absent [N, Nm].
        utilization_rate_pct: ``utilizationRate``; None when absent [%].
    """

    seqno: int
    tm_ms: int
    feedback_deg: tuple[float, ...]
    feedback_external_deg: tuple[float, ...] = ()
    feedback_time_us: int | None = None
    planned_deg: tuple[float, ...] = ()
    planned_external_deg: tuple[float, ...] = ()
    motors: MotorState = MotorState.UNDEFINED
    mci: MciState = MciState.UNDEFINED
    mci_convergence_met: bool | None = None
    rapid: RapidState = RapidState.UNDEFINED
    force_control_active: bool | None = None
    measured_force: tuple[float, ...] = ()
    utilization_rate_pct: float | None = None


@dataclass(frozen=True)
class EgmSensor:
    """What the PC sends back (joint mode: ``EGMActJoint`` / ``EGMRunJoint``).

    Attributes:
        seqno: the header's sequence number (abb-robot-client's go 1, 3, 5, …: not consecutive).
        tm_ms: the header's time stamp [ms] (abb-robot-client sends none: 0).
        planned_deg: ``planned.joints``: the joint reference [deg].
        planned_external_deg: ``planned.externalJoints`` [deg]: a 7-axis arm's arm angle first.
        speed_ref_degps: ``speedRef.joints``: the feed-forward joint speed [deg/s]; empty when absent.
        speed_ref_external_degps: ``speedRef.externalJoints`` [deg/s].
        mtype: the header's message type (``CORRECTION`` from abb-robot-client).
    """

    seqno: int
    tm_ms: int
    planned_deg: tuple[float, ...]
    planned_external_deg: tuple[float, ...] = ()
    speed_ref_degps: tuple[float, ...] = ()
    speed_ref_external_degps: tuple[float, ...] = ()
    mtype: MessageType = MessageType.CORRECTION


# --- encoding -------------------------------------------------------------------------------------------------------


def _header(seqno: int, tm_ms: int, mtype: MessageType) -> bytes:
    return field_message(
        1, field_varint(1, seqno & 0xFFFF_FFFF) + field_varint(2, tm_ms & 0xFFFF_FFFF) + field_varint(3, mtype)
    )


def _joints(values: tuple[float, ...]) -> bytes:
    return b"".join(field_double(1, v) for v in values)


def _joint_set(joints: tuple[float, ...], external: tuple[float, ...], time_us: int | None = None) -> bytes:
    """An ``EgmFeedBack``, ``EgmPlanned`` or ``EgmSpeedRef`` body (the same numbers for joints and external)."""
    body = field_message(1, _joints(joints)) if joints else b""
    if external:
        body += field_message(3, _joints(external))
    if time_us is not None:
        body += field_message(4, field_varint(1, time_us // 1_000_000) + field_varint(2, time_us % 1_000_000))
    return body


def encode_robot(msg: EgmRobot) -> bytes:
    """The ``EgmRobot`` datagram of ``msg`` (header type ``DATA``, as a controller sends)."""
    out = _header(msg.seqno, msg.tm_ms, MessageType.DATA)
    out += field_message(2, _joint_set(msg.feedback_deg, msg.feedback_external_deg, msg.feedback_time_us))
    if msg.planned_deg or msg.planned_external_deg:
        out += field_message(3, _joint_set(msg.planned_deg, msg.planned_external_deg, msg.feedback_time_us))
    out += field_message(4, field_varint(1, msg.motors))
    out += field_message(5, field_varint(1, msg.mci))
    if msg.mci_convergence_met is not None:
        out += field_bool(6, msg.mci_convergence_met)
    out += field_message(8, field_varint(1, msg.rapid))
    if msg.force_control_active is not None or msg.measured_force:
        force = b"" if msg.force_control_active is None else field_bool(1, msg.force_control_active)
        out += field_message(9, force + b"".join(field_double(2, v) for v in msg.measured_force))
    if msg.utilization_rate_pct is not None:
        out += field_double(10, msg.utilization_rate_pct)
    return out


def encode_sensor(msg: EgmSensor) -> bytes:
    """The ``EgmSensor`` datagram of ``msg`` (what abb-robot-client's ``send_to_robot`` sends)."""
    out = _header(msg.seqno, msg.tm_ms, msg.mtype)
    out += field_message(2, _joint_set(msg.planned_deg, msg.planned_external_deg))
    out += field_message(3, _joint_set(msg.speed_ref_degps, msg.speed_ref_external_degps))
    return out


# --- decoding -------------------------------------------------------------------------------------------------------


def _message(values: list[WireValue] | None, what: str) -> dict[int, list[WireValue]]:
    """An embedded message's fields, its occurrences merged (protobuf: parse their bytes concatenated)."""
    if not values:
        return {}
    if not all(isinstance(v, bytes) for v in values):
        raise EgmError("malformed", f"{what}: not an embedded message")
    return read_fields(b"".join(v for v in values if isinstance(v, bytes)))


def _scalar(fields: dict[int, list[WireValue]], number: int, what: str) -> int | None:
    """A varint field's last value (protobuf: the last one wins), or None when absent."""
    values = fields.get(number)
    if not values:
        return None
    value = values[-1]
    if not isinstance(value, int):
        raise EgmError("malformed", f"{what}: not a varint")
    return value


def _double(fields: dict[int, list[WireValue]], number: int, what: str) -> float | None:
    values = fields.get(number)
    if not values:
        return None
    value = values[-1]
    if not isinstance(value, float):
        raise EgmError("malformed", f"{what}: not a double")
    if not math.isfinite(value):
        raise EgmError("non_finite", f"{what} = {value}; allowed: a finite value")
    return value


def _enum(fields: dict[int, list[WireValue]], number: int, what: str) -> int:
    """A state message's ``state`` (field 1 of field ``number``); 0 (UNDEFINED) when absent or unknown."""
    value = _scalar(_message(fields.get(number), what), 1, f"{what}.state")
    return 0 if value is None else value


def _joint_lists(fields: dict[int, list[WireValue]], what: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    joints = _message(fields.get(1), f"{what}.joints")
    external = _message(fields.get(3), f"{what}.externalJoints")
    return (
        read_doubles(joints.get(1, []), f"{what}.joints", MAX_JOINTS),
        read_doubles(external.get(1, []), f"{what}.externalJoints", MAX_JOINTS),
    )


def _header_fields(fields: dict[int, list[WireValue]]) -> tuple[int, int, int]:
    header = _message(fields.get(1), "header")
    return (
        _scalar(header, 1, "header.seqno") or 0,
        _scalar(header, 2, "header.tm") or 0,
        _scalar(header, 3, "header.mtype") or 0,
    )


def _top_fields(data: bytes) -> dict[int, list[WireValue]]:
    if len(data) > MAX_DATAGRAM_BYTES:
        raise EgmError("oversize", f"{len(data)} bytes; allowed: at most {MAX_DATAGRAM_BYTES}")
    return read_fields(data)


def _known(enum: type[IntEnum], value: int) -> int:
    return value if value in enum._value2member_map_ else 0


def decode_robot(data: bytes) -> EgmRobot:
    """An ``EgmRobot`` datagram.

    Raises:
        EgmError: not a valid ``EgmRobot`` (the reasons of :class:`EgmError`).
    """
    fields = _top_fields(data)
    seqno, tm_ms, _ = _header_fields(fields)
    feedback = _message(fields.get(2), "feedBack")
    feedback_deg, feedback_external_deg = _joint_lists(feedback, "feedBack")
    clock = _message(feedback.get(4), "feedBack.time")
    time_us = None
    if clock:
        time_us = (_scalar(clock, 1, "time.sec") or 0) * 1_000_000 + (_scalar(clock, 2, "time.usec") or 0)
    planned_deg, planned_external_deg = _joint_lists(_message(fields.get(3), "planned"), "planned")
    force = _message(fields.get(9), "measuredForce")
    fc_active = _scalar(force, 1, "measuredForce.fcActive")
    convergence = _scalar(fields, 6, "mciConvergenceMet")
    return EgmRobot(
        seqno=seqno,
        tm_ms=tm_ms,
        feedback_deg=feedback_deg,
        feedback_external_deg=feedback_external_deg,
        feedback_time_us=time_us,
        planned_deg=planned_deg,
        planned_external_deg=planned_external_deg,
        motors=MotorState(_known(MotorState, _enum(fields, 4, "motorState"))),
        mci=MciState(_known(MciState, _enum(fields, 5, "mciState"))),
        mci_convergence_met=None if convergence is None else bool(convergence),
        rapid=RapidState(_known(RapidState, _enum(fields, 8, "rapidExecState"))),
        force_control_active=None if fc_active is None else bool(fc_active),
        measured_force=read_doubles(force.get(2, []), "measuredForce.force", MAX_JOINTS),
        utilization_rate_pct=_double(fields, 10, "utilizationRate"),
    )


def decode_sensor(data: bytes) -> EgmSensor:
    """An ``EgmSensor`` datagram.

    Raises:
        EgmError: not a valid ``EgmSensor`` (the reasons of :class:`EgmError`).
    """
    fields = _top_fields(data)
    seqno, tm_ms, mtype = _header_fields(fields)
    planned_deg, planned_external_deg = _joint_lists(_message(fields.get(2), "planned"), "planned")
    speed_deg, speed_external_deg = _joint_lists(_message(fields.get(3), "speedRef"), "speedRef")
    return EgmSensor(
        seqno=seqno,
        tm_ms=tm_ms,
        planned_deg=planned_deg,
        planned_external_deg=planned_external_deg,
        speed_ref_degps=speed_deg,
        speed_ref_external_degps=speed_external_deg,
        mtype=MessageType(_known(MessageType, mtype)),
    )


# --- joints: our radians, EGM's degrees -----------------------------------------------------------------------------


def joints_deg(q_rad: npt.ArrayLike) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """``joints`` and ``externalJoints`` [deg] of a robot's joint vector [rad]: the first six, then the rest (a
    seventh joint, the arm angle, as ``externalJoints[0]``)."""
    q_deg = np.degrees(np.asarray(q_rad, dtype=float)).tolist()
    return tuple(q_deg[:ROBOT_AXES]), tuple(q_deg[ROBOT_AXES:])


def joints_rad(axes_deg: tuple[float, ...], external_deg: tuple[float, ...], n_joints: int) -> npt.NDArray[np.float64]:
    """A robot's joint vector [rad] from ``joints`` and ``externalJoints`` [deg] (the inverse of :func:`joints_deg`).

    Extra external joints beyond the robot's (a track, a positioner) are ignored.

    Raises:
        EgmError: ``joint_count``: fewer values than the robot's ``n_joints`` (or more than six in ``joints``, or
            a six-axis robot's axes split between the lists).
    """
    n_axes = min(n_joints, ROBOT_AXES)
    if len(axes_deg) != n_axes or len(external_deg) < n_joints - n_axes:
        raise EgmError(
            "joint_count",
            f"{len(axes_deg)} joints and {len(external_deg)} external joints; allowed: {n_axes} joints"
            + (" and the arm angle as externalJoints[0]" if n_joints > ROBOT_AXES else "")
            + f" for this {n_joints}-joint robot",
        )
    q_rad: npt.NDArray[np.float64] = np.radians(np.array(axes_deg + external_deg[: n_joints - n_axes], dtype=float))
    return q_rad
