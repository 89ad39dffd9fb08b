"""What the emulated controller's RTDE face serves for each output variable, and its data packages.

    arm = ArmModel(robot_model)                       # the robot's Pinocchio model: TCP, elbow, momentum, torques
    values = snapshot(output, previous, slider, t_s, registers, arm)   # every variable of one cycle, flat tuples
    packer = DataPacker(recipe)                       # per output recipe: header, id and values in one struct
    message = packer.pack(values)                     # a whole ``U`` message

:data:`OUTPUTS` is the one table: every fixed-name output of :data:`~hrc_devices.controllers.ur_rtde.codec.OUTPUT_TYPES`
(UR's RTDE guide as an e-Series 5.11 serves it; the codec holds the types, a test checks both tables hold the same
names) with where its value comes from:

- ``state``: the controller's cycle (:func:`output_values`: joints, override, slider, modes, the cycle's time; and
  ``target_qdd``, the joints' mean acceleration over the cycle);
- ``model``: the robot's Pinocchio model at the cycle's joints (:class:`ArmModel`: TCP and elbow, momentum, torques);
- ``inputs``: the value a client last wrote to that input (0 before any write), as the controller reads inputs back;
- ``constant``: what the emulator has no model of (currents, temperatures, voltages, I/O, payload): a stated value,
  the same in every package, with the reason in the table. Never a measurement: a client must not draw conclusions
  from them.

The general purpose registers follow the same rules without a row each: ``output_{bit,int,double}_register_X`` are
constant 0 (no URScript program writes them), ``input_{bit,int,double}_register_X`` read back the last write.

The emulated drive follows its target exactly, so every ``actual_*`` equals its ``target_*``.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Mapping
from dataclasses import dataclass
from itertools import chain
from types import MappingProxyType
from typing import Literal, NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from controller_emu.node import ControllerOutput
from hrc_contract.config import ConfigError
from hrc_devices.controllers.ur_rtde import codec as rtde
from hrc_devices.controllers.ur_rtde.codec import MessageType, Recipe
from hrc_devices.robots.model import RobotModel

Source = Literal["state", "model", "inputs", "constant"]
Flat = tuple[bool | int | float, ...]
"""A value as packed: a scalar is a 1-tuple, a vector its elements."""

JOINT_RUNNING_MODE = 253
"""``joint_mode`` (and ``tool_mode``) of a powered joint that runs (UR's JOINT_RUNNING_MODE)."""
NOMINAL_BUS_V = 48.0
"""The robot's DC bus [V]: what the voltages show without an electrical model."""
ROOM_C = 25.0
"""The temperature shown without a thermal model [°C]."""
GRAVITY_MPS2 = 9.81


class Output(NamedTuple):
    """Where one output variable's value comes from.

    Attributes:
        source: ``state``, ``model``, ``inputs`` or ``constant``.
        value: the constant's value (a ``constant``), the value before any write (``inputs``); else None.
        why: what the value is, and for a constant why it is one.
    """

    source: Source
    value: object
    why: str


def _state(why: str) -> Output:
    return Output("state", None, why)


def _model(why: str) -> Output:
    return Output("model", None, why)


def _constant(value: object, why: str) -> Output:
    return Output("constant", value, why)


_ZERO6 = (0.0,) * 6
_NO_DRIVE = "no drive model (motor torque constants, current loops): 0 A, not a measurement; torques: target_moment"
_NO_FORCE = "no force sensing: the emulated arm touches nothing and carries no payload, so the ideal reading is 0"
_NO_IO = "nothing is wired to the emulated controller (output writes are ignored and counted io_ignored)"
_NO_ELECTRICS = "no electrical model"
_NO_PAYLOAD = "no payload is set: the model ends at the tool flange"

OUTPUTS: Mapping[str, Output] = MappingProxyType(
    {
        "timestamp": _state("the time of the controller cycle the package carries, since the face started [s]"),
        "target_q": _state("the program's joints at the cycle [rad]"),
        "target_qd": _state("applied override × the program's velocity [rad/s]"),
        "target_qdd": _state("target_qd's change over the cycle / its duration [rad/s²] (0 in the first)"),
        "target_current": _constant(_ZERO6, _NO_DRIVE),
        "target_moment": _model(
            "inverse dynamics of the URDF's inertias at target q, qd, qdd, gravity of the mount [N·m]"
        ),
        "actual_q": _state("= target_q (the emulated drive follows exactly) [rad]"),
        "actual_qd": _state("= target_qd [rad/s]"),
        "actual_current": _constant(_ZERO6, _NO_DRIVE),
        "joint_control_output": _constant(_ZERO6, _NO_DRIVE),
        "actual_TCP_pose": _model("tool0 in UR's base frame, (x, y, z [m], rotation vector [rad]) (no TCP offset)"),
        "actual_TCP_speed": _model("tool0's linear [m/s] and angular [rad/s] velocity in the base frame"),
        "actual_TCP_force": _constant(_ZERO6, _NO_FORCE),
        "target_TCP_pose": _model("= actual_TCP_pose"),
        "target_TCP_speed": _model("= actual_TCP_speed"),
        "actual_digital_input_bits": _constant(0, _NO_IO),
        "joint_temperatures": _constant((ROOM_C,) * 6, "no thermal model: a room's 25 °C"),
        "actual_execution_time": _constant(0.0, "the real-time thread's execution time is not measured [ms]"),
        "robot_mode": _state("7 running: the emulated arm is always powered, its brakes released"),
        "joint_mode": _constant((JOINT_RUNNING_MODE,) * 6, "253 running, as robot_mode 7"),
        "safety_mode": _state("1 normal, 3 protective stop (the emulator's watchdog stop)"),
        "safety_status": _state("= safety_mode (the same codes for normal and protective stop)"),
        "actual_tool_accelerometer": _model(
            "tool0's acceleration minus gravity in tool0's axes [m/s²] (at rest: 9.81 m/s² upward)"
        ),
        "speed_scaling": _state("the ramp toward a raised slider, 0 while held (see rtde_face)"),
        "target_speed_fraction": _state("the slider in force at the cycle"),
        "actual_momentum": _model("|Σ mᵢ vᵢ| of the URDF's links [kg·m/s]"),
        "actual_main_voltage": _constant(NOMINAL_BUS_V, f"{_NO_ELECTRICS}: the nominal 48 V [V]"),
        "actual_robot_voltage": _constant(NOMINAL_BUS_V, f"{_NO_ELECTRICS}: the nominal 48 V [V]"),
        "actual_robot_current": _constant(0.0, f"{_NO_ELECTRICS}: 0 A, not a measurement"),
        "actual_joint_voltage": _constant((NOMINAL_BUS_V,) * 6, f"{_NO_ELECTRICS}: the nominal 48 V [V]"),
        "actual_digital_output_bits": _constant(0, _NO_IO),
        "runtime_state": _state("2 playing; 3 pausing, 4 paused in the watchdog's stop"),
        "elbow_position": _model("the elbow joint's origin in the base frame [m]"),
        "elbow_velocity": _model("its velocity in the base frame [m/s]"),
        "robot_status_bits": _state("power on, + program running while not held"),
        "safety_status_bits": _state("normal, or protective stopped"),
        "analog_io_types": _constant(0, _NO_IO),
        "standard_analog_input0": _constant(0.0, _NO_IO),
        "standard_analog_input1": _constant(0.0, _NO_IO),
        "standard_analog_output0": _constant(0.0, _NO_IO),
        "standard_analog_output1": _constant(0.0, _NO_IO),
        "io_current": _constant(0.0, _NO_IO),
        "euromap67_input_bits": _constant(0, "no Euromap67 module"),
        "euromap67_output_bits": _constant(0, "no Euromap67 module"),
        "euromap67_24V_voltage": _constant(0.0, "no Euromap67 module"),
        "euromap67_24V_current": _constant(0.0, "no Euromap67 module"),
        "tool_mode": _constant(JOINT_RUNNING_MODE, "253 running, as the joints"),
        "tool_analog_input_types": _constant(0, _NO_IO),
        "tool_analog_input0": _constant(0.0, _NO_IO),
        "tool_analog_input1": _constant(0.0, _NO_IO),
        "tool_output_voltage": _constant(0, "tool power off (no tool) [V]"),
        "tool_output_current": _constant(0.0, "tool power off (no tool) [A]"),
        "tool_temperature": _constant(ROOM_C, "no thermal model: a room's 25 °C"),
        "tcp_force_scalar": _constant(0.0, _NO_FORCE),
        "output_bit_registers0_to_31": _constant(0, "no URScript program writes the output registers"),
        "output_bit_registers32_to_63": _constant(0, "no URScript program writes the output registers"),
        "input_bit_registers0_to_31": Output("inputs", 0, "the bits a client last wrote"),
        "input_bit_registers32_to_63": Output("inputs", 0, "the bits a client last wrote"),
        "tool_output_mode": _constant(0, "assumed default: digital outputs (no tool is attached)"),
        "tool_digital_output0_mode": _constant(1, "assumed default: 1 sinking/NPN (no tool is attached)"),
        "tool_digital_output1_mode": _constant(1, "assumed default: 1 sinking/NPN (no tool is attached)"),
        "payload": _constant(0.0, _NO_PAYLOAD),
        "payload_cog": _constant((0.0,) * 3, _NO_PAYLOAD),
        "payload_inertia": _constant(_ZERO6, _NO_PAYLOAD),
        "script_control_line": _constant(0, "the emulated program is no URScript: no line controls the robot"),
        "ft_raw_wrench": _constant(_ZERO6, _NO_FORCE),
    }
)
"""Every fixed-name output variable the face serves, by name (see the module docstring)."""


def _flat(value: object) -> Flat:
    return tuple(value) if isinstance(value, tuple | list) else (value,)  # type: ignore[return-value]


def _register_defaults() -> dict[str, Flat]:
    """Every general purpose register's value before any write: False, 0 or 0.0."""
    defaults: dict[str, Flat] = {}
    for direction in ("input", "output"):
        for index in range(64, 128):
            defaults[f"{direction}_bit_register_{index}"] = (False,)
        for index in range(48):
            defaults[f"{direction}_int_register_{index}"] = (0,)
            defaults[f"{direction}_double_register_{index}"] = (0.0,)
    return defaults


_FIXED_VALUES: dict[str, Flat] = {
    **_register_defaults(),
    **{name: _flat(out.value) for name, out in OUTPUTS.items() if out.source in ("constant", "inputs")},
}
"""The constants, and the inputs' values before any write, flat (never changed: each cycle copies it; a plain dict,
as copying a read-only proxy takes 20 times as long)."""


def is_read_back(name: str) -> bool:
    """True for an input a client writes whose last value the outputs show (registers)."""
    return rtde.input_type(name) is not None and rtde.output_type(name) is not None


# -- state: the controller's cycle ------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StateWords:
    """The controller's state as RTDE reports it (:func:`output_values`)."""

    runtime_state: int
    safety_mode: int
    speed_scaling: float
    robot_status_bits: int
    safety_status_bits: int


def state_words(output: ControllerOutput, slider_fraction: float) -> StateWords:
    """The RTDE state words for the emulator's mode and applied override (``slider_fraction``: the slider value
    last accepted, in [0, 1])."""
    held = output.state.mode == "protective_stop"
    if held:
        runtime = rtde.RUNTIME_PAUSING if output.state.delta_applied > 0.0 else rtde.RUNTIME_PAUSED
        return StateWords(
            runtime_state=runtime,
            safety_mode=rtde.SAFETY_PROTECTIVE_STOP,
            speed_scaling=0.0,
            robot_status_bits=rtde.ROBOT_STATUS_POWER_ON,
            safety_status_bits=rtde.SAFETY_STATUS_PROTECTIVE_STOPPED,
        )
    return StateWords(
        runtime_state=rtde.RUNTIME_PLAYING,
        safety_mode=rtde.SAFETY_NORMAL,
        speed_scaling=_ramp_scaling(output.state.delta_applied, slider_fraction),
        robot_status_bits=rtde.ROBOT_STATUS_POWER_ON | rtde.ROBOT_STATUS_PROGRAM_RUNNING,
        safety_status_bits=rtde.SAFETY_STATUS_NORMAL,
    )


def _ramp_scaling(delta_applied: float, slider_fraction: float) -> float:
    """``applied / slider`` while the applied override is still below the slider, else 1 (a scaling is at most 1)."""
    if slider_fraction <= 0.0 or delta_applied >= slider_fraction:
        return 1.0
    return max(0.0, delta_applied / slider_fraction)


def output_values(output: ControllerOutput, slider_fraction: float, timestamp_s: float) -> Mapping[str, object]:
    """The ``state`` outputs of one cycle that need no other cycle (all but ``target_qdd``), by name.

    What the bridge reads; the simulated cell builds its packages with it.

    Args:
        output: the controller cycle.
        slider_fraction: the slider value in force at it, in [0, 1].
        timestamp_s: controller time [s].
    """
    joint = output.joint_state
    words = state_words(output, slider_fraction)
    q = tuple(joint.q)
    qd = tuple(joint.qd)
    return {
        "timestamp": timestamp_s,
        "actual_q": q,
        "actual_qd": qd,
        "target_q": q,
        "target_qd": qd,
        "speed_scaling": words.speed_scaling,
        "target_speed_fraction": slider_fraction,
        "runtime_state": words.runtime_state,
        "robot_mode": rtde.ROBOT_MODE_RUNNING,
        "safety_mode": words.safety_mode,
        "safety_status": words.safety_mode,
        "robot_status_bits": words.robot_status_bits,
        "safety_status_bits": words.safety_status_bits,
    }


def joint_acceleration(output: ControllerOutput, previous: ControllerOutput | None) -> tuple[float, ...]:
    """``target_qdd``: the change of the joint velocities since the previous cycle over its duration [rad/s²];
    zeros for the first cycle (or a cycle not after the previous one)."""
    n = len(output.joint_state.qd)
    if previous is None or output.cycle_mono_ns <= previous.cycle_mono_ns:
        return (0.0,) * n
    dt_s = (output.cycle_mono_ns - previous.cycle_mono_ns) / 1e9
    return tuple((a - b) / dt_s for a, b in zip(output.joint_state.qd, previous.joint_state.qd, strict=True))


# -- model: the robot's Pinocchio model ------------------------------------------------------------------------------


class ArmModel:
    """The ``model`` outputs from the robot's Pinocchio model, in UR's conventions.

    Poses and velocities are in the URDF's ``base`` frame, which the ur_description URDFs place where the controller
    has its base frame (``base_link`` turned by π about z): the TCP is the flange ``tool0`` with no TCP offset; the
    elbow is the origin of the third joint. Gravity is the cell's, turned into the robot's mounting.

    Args:
        robot: the robot's model (its URDF, joints and mounting in the cell).

    Raises:
        ConfigError: the URDF has no ``base`` or ``tool0`` frame, or fewer than three joints.
    """

    BASE_FRAME = "base"
    TCP_FRAME = "tool0"
    ELBOW_JOINT = 3
    """Pinocchio's joint id of the elbow (ids start at 1)."""

    def __init__(self, robot: RobotModel) -> None:
        missing = [f for f in (self.BASE_FRAME, self.TCP_FRAME) if not robot.model.existFrame(f)]
        if missing or robot.model.njoints <= self.ELBOW_JOINT:
            frames = ", ".join(f.name for f in robot.model.frames)
            raise ConfigError(
                f"robot {robot.name!r}: RTDE's TCP and elbow need the frames {self.BASE_FRAME!r} and "
                f"{self.TCP_FRAME!r} and >= {self.ELBOW_JOINT} joints (a ur_description URDF); the URDF has: {frames}"
            )
        self._model = pin.Model(robot.model)  # a copy: its gravity is the mounting's
        self._model.gravity.linear = robot.R_world_base.T @ np.array([0.0, 0.0, -GRAVITY_MPS2])
        self._data = self._model.createData()
        self._base = int(self._model.getFrameId(self.BASE_FRAME))
        self._tcp = int(self._model.getFrameId(self.TCP_FRAME))

    def values(self, q: Flat, qd: Flat, qdd: Flat) -> dict[str, Flat]:
        """Every ``model`` output at the joints' positions [rad], velocities [rad/s] and accelerations [rad/s²]."""
        model, data = self._model, self._data
        q_a, qd_a, qdd_a = np.asarray(q, float), np.asarray(qd, float), np.asarray(qdd, float)
        pin.forwardKinematics(model, data, q_a, qd_a, qdd_a)
        base = pin.updateFramePlacement(model, data, self._base)
        tcp = pin.updateFramePlacement(model, data, self._tcp)
        R_base = base.rotation  # the base is fixed: velocities in its axes are the world's turned
        tcp_in_base = base.actInv(tcp)
        pose = np.concatenate((tcp_in_base.translation, pin.log3(tcp_in_base.rotation)))
        twist = pin.getFrameVelocity(model, data, self._tcp, pin.LOCAL_WORLD_ALIGNED)
        speed = np.concatenate((R_base.T @ twist.linear, R_base.T @ twist.angular))
        # classical (not spatial) acceleration of tool0's origin, in tool0's axes, minus gravity: what an
        # accelerometer fixed there measures
        accel = pin.getFrameClassicalAcceleration(model, data, self._tcp, pin.LOCAL).linear
        specific_force = accel - tcp.rotation.T @ model.gravity.linear
        elbow = base.actInv(data.oMi[self.ELBOW_JOINT]).translation
        elbow_velocity = R_base.T @ pin.getVelocity(model, data, self.ELBOW_JOINT, pin.LOCAL_WORLD_ALIGNED).linear
        moment = pin.rnea(model, data, q_a, qd_a, qdd_a)
        momentum = pin.computeCentroidalMomentum(model, data, q_a, qd_a).linear
        return {
            "actual_TCP_pose": _floats(pose),
            "target_TCP_pose": _floats(pose),
            "actual_TCP_speed": _floats(speed),
            "target_TCP_speed": _floats(speed),
            "actual_tool_accelerometer": _floats(specific_force),
            "elbow_position": _floats(elbow),
            "elbow_velocity": _floats(elbow_velocity),
            "target_moment": _floats(moment),
            "actual_momentum": (math.hypot(*momentum),),
        }


def _floats(values: npt.NDArray[np.float64]) -> Flat:
    return tuple(values.tolist())


# -- one cycle's values and the packages --------------------------------------------------------------------------


def snapshot(
    output: ControllerOutput,
    previous: ControllerOutput | None,
    slider_fraction: float,
    timestamp_s: float,
    inputs: Mapping[str, Flat],
    arm: ArmModel | None,
) -> dict[str, Flat]:
    """Every output variable's value in one controller cycle, flat, by name.

    Args:
        output: the cycle.
        previous: the cycle before it (for ``target_qdd``), or None.
        slider_fraction: the slider in force at the cycle.
        timestamp_s: the cycle's controller time [s].
        inputs: the inputs written so far, flat, by name (read back: :func:`is_read_back`).
        arm: the robot's model; None leaves out the ``model`` outputs (no recipe asks for one).
    """
    values = _FIXED_VALUES.copy()
    values.update(inputs)
    for name, value in output_values(output, slider_fraction, timestamp_s).items():
        values[name] = _flat(value)
    qdd = joint_acceleration(output, previous)
    values["target_qdd"] = qdd
    if arm is not None:
        values.update(arm.values(values["actual_q"], values["actual_qd"], qdd))
    return values


class DataPacker:
    """One output recipe's data package, built once at setup: the whole ``U`` message (header, recipe id, values in
    order) is one pre-compiled struct, filled from a :func:`snapshot` per package.

    Args:
        recipe: the output recipe (every name served: :func:`~hrc_devices.controllers.ur_rtde.codec.output_type`).
    """

    def __init__(self, recipe: Recipe) -> None:
        self.recipe = recipe
        self._struct = struct.Struct(">HBB" + recipe.layout.format[1:])
        self._names = recipe.names
        self.needs_model = any(name in OUTPUTS and OUTPUTS[name].source == "model" for name in recipe.names)
        """True if a value of the recipe comes from the robot's model."""

    @property
    def size(self) -> int:
        """The message's size, header included [bytes]."""
        return self._struct.size

    def pack(self, values: Mapping[str, Flat]) -> bytes:
        """The data package of ``values`` (a :func:`snapshot`; with the model's values if :attr:`needs_model`)."""
        flat = chain.from_iterable([values[name] for name in self._names])
        return self._struct.pack(self._struct.size, MessageType.DATA_PACKAGE, self.recipe.recipe_id, *flat)
