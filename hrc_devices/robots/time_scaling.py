"""The time scaling as a pure state machine: override in, program time and joint state out (what a closed
controller does with its speed override; the controller emulator runs it, and any mode that needs the bounded ramp
or the watchdog elsewhere imports it from here).

No I/O and no clocks: the caller passes the times (:class:`controller_emu.node.ControllerNode` does, and is
what the process and the simulated cell drive). One override, then one cycle::

    reason = check_override(message, robot, newest_stamp_ns, now_wall_ns, watchdog_s)  # at arrival
    state = apply_override(state, message, accepted_mono_ns)                            # if reason is None
    state = step(state, trajectory, config, now_mono_ns, dt_s)
    message = joint_state(state, trajectory, robot, seq, now_wall_ns)

Two clocks, never mixed: the override's ``stamp_ns`` is the gateway's wall clock, so it is only compared
with the controller's wall clock (is it stale, is it from the future); the watchdog runs on the
controller's monotonic clock from the moment the override was accepted, so a wall-clock step can neither
keep the robot running on an old command nor stop it while valid commands arrive.

The applied override δ follows the commanded one through bounded rates: it falls by at most
1/braking_time_s per second (full speed to standstill takes braking_time_s, never longer) and rises by at
most 1/accel_time_s per second. The program time τ advances by δ·dt, so δ = 1 runs the program as
planned and δ = 0 holds the robot where it is. Without a valid override for ``watchdog_s`` (or before
the first one) the target is 0: the controller starts, and falls back, into a protective stop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np

from hrc_contract.config import ConfigError, ControllerConfig
from hrc_contract.messages import JointCommand, JointState, Override
from hrc_contract.vocabulary import ControllerMode
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import Trajectory

Mode = ControllerMode

Rejection = Literal["wrong_robot", "old_or_repeated", "stale", "stamp_in_future"]
"""Why a schema-valid override was not accepted (:func:`check_override`)."""

MAX_FUTURE_STAMP_S = 0.005
"""An override stamped further than this ahead of the controller's wall clock is rejected [s].

Overrides are ordered by stamp, so an accepted future stamp masks every genuine override stamped before
it: this bounds how long one forged (or clock-skewed) message can hold back a genuine δ = 0. It is also
the clock agreement the gateway and the controller need (same host, or PTP/NTP-disciplined hosts).
"""

_SNAP = 1e-12
"""δ within this of its target is set to the target, so that a ramp ends exactly on it."""


@dataclass(frozen=True)
class ControllerState:
    """Everything the controller's program and watchdog remember between cycles.

    Attributes:
        tau_s: program time, in [0, trajectory.duration_s) [s].
        delta_applied: override applied in the last step, in [0, 1].
        cycles_completed: number of times the program wrapped back to its start.
        mode: ``running``, ``stopped`` (δ reached 0) or ``protective_stop`` (watchdog expired).
        delta_commanded: ``delta`` of the last accepted override (not yet clipped).
        override_stamp_ns: ``stamp_ns`` of the last accepted override; -1 before any [ns, gateway wall clock].
        override_seq: ``seq`` of the last accepted override; -1 before any.
        override_accepted_mono_ns: when the last override was accepted; None before any
            [ns, the controller's monotonic clock].
    """

    tau_s: float = 0.0
    delta_applied: float = 0.0
    cycles_completed: int = 0
    mode: Mode = "protective_stop"
    delta_commanded: float = 0.0
    override_stamp_ns: int = -1
    override_seq: int = -1
    override_accepted_mono_ns: int | None = None


def check_override(
    msg: Override, robot_name: str, newest_stamp_ns: int, now_wall_ns: int, watchdog_s: float
) -> Rejection | None:
    """Why an override cannot be accepted on arrival, or None if it can.

    Order is decided by ``stamp_ns``, not by ``seq``: a restarted gateway, whose ``seq`` starts again
    at 0, is accepted as soon as its stamps are newer.

    Args:
        msg: a parsed, schema-valid override.
        robot_name: the robot this controller drives.
        newest_stamp_ns: ``stamp_ns`` of the newest override accepted so far; -1 before any [ns].
        now_wall_ns: the controller's wall clock at arrival (Unix epoch, the clock of ``stamp_ns``) [ns].
        watchdog_s: an override stamped longer ago than this is stale [s].

    Returns:
        None, or ``wrong_robot``; ``old_or_repeated`` (stamp not newer than ``newest_stamp_ns``);
        ``stale`` (stamped more than ``watchdog_s`` ago); ``stamp_in_future`` (stamped more than
        :data:`MAX_FUTURE_STAMP_S` ahead).
    """
    if msg.robot != robot_name:
        return "wrong_robot"
    return stamp_rejection(msg.stamp_ns, newest_stamp_ns, now_wall_ns, watchdog_s)


StampRejection = Literal["old_or_repeated", "stale", "stamp_in_future"]
"""Why a command's stamp cannot be accepted (:func:`stamp_rejection`)."""


def stamp_rejection(stamp_ns: int, newest_stamp_ns: int, now_wall_ns: int, watchdog_s: float) -> StampRejection | None:
    """Why a command stamped ``stamp_ns`` cannot be accepted at ``now_wall_ns``, or None: not newer than the newest
    accepted (``old_or_repeated``), older than ``watchdog_s`` (``stale``), more than :data:`MAX_FUTURE_STAMP_S` ahead
    (``stamp_in_future``). Shared by the closed controller's overrides and the open one's joint commands."""
    if stamp_ns <= newest_stamp_ns:
        return "old_or_repeated"
    age_s = (now_wall_ns - stamp_ns) / 1e9
    if age_s > watchdog_s:
        return "stale"
    if -age_s > MAX_FUTURE_STAMP_S:
        return "stamp_in_future"
    return None


JointCommandRejection = Literal["wrong_robot", "wrong_joint_count", "old_or_repeated", "stale", "stamp_in_future"]
"""Why a schema-valid joint command was not accepted (:func:`joint_command_rejection`)."""


def joint_command_rejection(
    msg: JointCommand, robot_name: str, n_joints: int, newest_stamp_ns: int, now_wall_ns: int, watchdog_s: float
) -> JointCommandRejection | None:
    """Why an open controller (the emulator's, or a bridge to a real one) cannot accept a joint command on arrival,
    or None if it can.

    Order is decided by ``stamp_ns``, not by ``seq``: a restarted gateway, whose ``seq`` starts again at 0, is
    accepted as soon as its stamps are newer. Finiteness is the message's own (``parse_message`` refuses NaN and
    infinities as ``non_finite``).

    Args:
        msg: a parsed, schema-valid command.
        robot_name: the robot this controller drives.
        n_joints: the robot model's joint count.
        newest_stamp_ns: ``stamp_ns`` of the newest command accepted so far; -1 before any [ns].
        now_wall_ns: the receiver's wall clock at arrival (the clock of ``stamp_ns``) [ns].
        watchdog_s: a command stamped longer ago than this is stale [s].

    Returns:
        None, or ``wrong_robot``; ``wrong_joint_count`` (not the model's); ``old_or_repeated`` (stamp not newer
        than ``newest_stamp_ns``); ``stale`` (stamped more than ``watchdog_s`` ago); ``stamp_in_future`` (stamped
        more than :data:`MAX_FUTURE_STAMP_S` ahead, as an override).
    """
    if msg.robot != robot_name:
        return "wrong_robot"
    if len(msg.q) != n_joints or len(msg.qd) != n_joints:
        return "wrong_joint_count"
    return stamp_rejection(msg.stamp_ns, newest_stamp_ns, now_wall_ns, watchdog_s)


def apply_override(state: ControllerState, msg: Override, accepted_mono_ns: int) -> ControllerState:
    """The state commanded by an accepted override (:func:`check_override` returned None).

    Args:
        state: current state.
        msg: the accepted override.
        accepted_mono_ns: when it was accepted [ns, the controller's monotonic clock]; the watchdog runs from here.
    """
    return replace(
        state,
        delta_commanded=msg.delta,
        override_stamp_ns=msg.stamp_ns,
        override_seq=msg.seq,
        override_accepted_mono_ns=accepted_mono_ns,
    )


def watchdog_expired(state: ControllerState, config: ControllerConfig, now_mono_ns: int) -> bool:
    """True if no override was accepted within ``config.watchdog_s`` before ``now_mono_ns`` (or none yet).

    Args:
        state: current state.
        config: the watchdog time.
        now_mono_ns: now [ns, the monotonic clock of ``override_accepted_mono_ns``].
    """
    if state.override_accepted_mono_ns is None:
        return True
    return (now_mono_ns - state.override_accepted_mono_ns) / 1e9 > config.watchdog_s


def _ramp(delta: float, target: float, config: ControllerConfig, dt_s: float) -> float:
    """δ moved toward ``target`` at most by dt/braking_time_s (down) or dt/accel_time_s (up)."""
    if target < delta:
        moved = max(target, delta - dt_s / config.braking_time_s)
    else:
        moved = min(target, delta + dt_s / config.accel_time_s)
    return target if abs(moved - target) < _SNAP else moved


def step(
    state: ControllerState, trajectory: Trajectory, config: ControllerConfig, now_mono_ns: int, dt_s: float
) -> ControllerState:
    """Advance the controller by one cycle.

    Args:
        state: state after the overrides of this cycle were applied (:func:`apply_override`).
        trajectory: the program.
        config: braking, acceleration and watchdog times.
        now_mono_ns: now [ns, the monotonic clock of ``apply_override``'s ``accepted_mono_ns``].
        dt_s: time since the previous step [s] (negative values count as 0).

    Returns:
        The state with the new δ_applied, program time τ (wrapped, ``cycles_completed`` counted) and mode.
    """
    dt_s = max(dt_s, 0.0)
    expired = watchdog_expired(state, config, now_mono_ns)
    target = 0.0 if expired else min(max(state.delta_commanded, 0.0), 1.0)
    delta = _ramp(state.delta_applied, target, config, dt_s)
    # Trapezoidal rule: δ changes linearly within the step.
    tau_s = state.tau_s + 0.5 * (state.delta_applied + delta) * dt_s
    wraps = 0
    if tau_s >= trajectory.duration_s:
        wraps = math.floor(tau_s / trajectory.duration_s)
        tau_s -= wraps * trajectory.duration_s
        tau_s = min(max(tau_s, 0.0), math.nextafter(trajectory.duration_s, 0.0))
    mode: Mode = "protective_stop" if expired else ("stopped" if delta == 0.0 else "running")
    return replace(state, tau_s=tau_s, delta_applied=delta, cycles_completed=state.cycles_completed + wraps, mode=mode)


def joint_state(state: ControllerState, trajectory: Trajectory, robot_name: str, seq: int, stamp_ns: int) -> JointState:
    """The contract's joint state message for the current program point.

    ``qd`` is the actual joint velocity δ_applied · qd_nominal; ``qd_nominal`` the programmed one at 100 %.
    """
    q_rad, qd_nominal_radps = trajectory.sample(state.tau_s)
    qd_radps = state.delta_applied * qd_nominal_radps
    return JointState(
        robot=robot_name,
        seq=seq,
        stamp_ns=stamp_ns,
        q=q_rad.tolist(),
        qd=qd_radps.tolist(),
        qd_nominal=qd_nominal_radps.tolist(),
        override=state.delta_applied,
        override_seq=state.override_seq,
        mode=state.mode,
    )


def check_braking_time(config: ControllerConfig, robot: RobotModel) -> None:
    """Refuse a braking time longer than the gateway assumes for any moving link.

    The gateway sizes its separation distances with each link's braking time ``t_brake_link_s``; this
    controller stops all joints together within ``config.braking_time_s``, so that must not be longer.

    Raises:
        ConfigError: ``braking_time_s`` exceeds the smallest braking time of a link moved by a joint.
    """
    moving = robot.t_brake_link_s[robot.t_brake_link_s > 0.0]
    if moving.size == 0:
        return
    limit_s = float(np.min(moving))
    if config.braking_time_s > limit_s:
        link = robot.link_names[int(np.flatnonzero(robot.t_brake_link_s == limit_s)[0])]
        raise ConfigError(
            f"robot {robot.name!r}: controller.braking_time_s = {config.braking_time_s} s is longer than the "
            f"braking time the gateway assumes for link {link!r}; allowed: <= {limit_s} s"
        )
