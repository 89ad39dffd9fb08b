"""An *open* controller as a pure state machine: joint references in, bounded joint motion out (issue 34).

An open controller (``robots.<r>.controller.control = "open"``, as ABB's Externally Guided Motion) runs no
program of its own: the gateway streams a joint command every tick (``hrc.joint_command/1``: the reference
position q_{k+1} [rad] for the next cycle and velocity q̇_{k+1} [rad/s]) and the controller follows it within
its own limits. No I/O and no clocks: the caller passes the times (:class:`controller_emu.open_node.OpenControllerNode`
does). One command, then one cycle::

    reason = check_command(message, robot, n_joints, newest_stamp_ns, now_wall_ns, watchdog_s)  # at arrival
    state = apply_command(state, message, received, limits)                                      # if None
    state = step_follower(state, limits, dt_s, now_mono_ns)
    message = follower_joint_state(state, robot, seq, now_wall_ns)

**The law** (EGM's: joint speed = position gain × (reference − feedback) + speed reference), per joint::

    q̇_cmd = q̇_ref + K · (q_ref − (q + q̇_ref · Δt))          K = min(gain_per_s, 1/Δt)

``q_ref`` is the position for the *end* of this cycle (q_{k+1}), so it is compared with where the robot will be
at that instant if it moves at q̇_ref, not with where it is now: a robot that follows exactly has no error (the
literal ``q_ref − q`` would read the one cycle of look-ahead as an error and run the robot one cycle ahead of its
reference). ``K ≤ 1/Δt`` keeps a late, long cycle from over-correcting (K = 1/Δt is dead-beat). Then, per joint j:

1. clipped to the URDF velocity limit ±v_max,j;
2. clipped to the speed from which the joint can still stop at its position limit at a_j (the limits are never
   crossed: the bound holds at the end of every step and is reachable from the previous one within a_j);
3. rate-limited by the acceleration bound a_j = v_max,j / t_b,j (t_b,j the model's ``braking_time_s``): every
   joint stops from its velocity limit within its braking time, the t_b the gateway's rows assume.

q advances by the trapezoid of the two velocities (as the gateway's consistency check integrates ``qd``). A jump of
the reference larger than about 2 a_j / K² (22 mrad on the Panda) is closed at the acceleration bound and overshot a
little (a P-law with a saturated acceleration, as EGM's): the gateway sends references it can follow (LP (9d)).

**Silence.** A command is followed until it is ``watchdog_s`` old (its age at arrival on the wall clock, then the
monotonic clock since): meanwhile, with no newer command, its reference moves on at its q̇_ref (the robot keeps
the last commanded velocity, as EGM in *velocity* mode does). After that the robot is in a protective stop: every
joint decelerates at its a_j to standstill (from v_max within t_b) and stays there; a new valid command resumes
following from where the robot is (no jump: q and q̇ are continuous, q̇ changes by at most a_j·Δt). This is the
worse of EGM's two behaviours for a person nearby (in *position* mode EGM converges on the last reference, one
cycle ahead, and stops sooner), so the gateway's budget is tested against it; but a real EGM keeps the last
speed up to its ``\\CommTimeout`` (1 s by default) and then only raises an error in RAPID. The gateway never
relies on either: it budgets a silent link up to the *controller's* ``watchdog_s`` (its ``gateway_period_s``)
plus the stop within t_b, which only a watchdog of this kind delivers (docs/controllers.md, "Open controllers").

**Silence, EGM's position mode** (``FollowerLimits.on_silence = "hold_reference"``, the emulator's EGM face): each
command is one cycle's reference; a cycle with no newer one keeps the last ``q_ref`` where it is and drops the
feed-forward (q̇_ref = 0 after the step it was sent for), so the robot converges on the last reference (at K, within
its limits) and holds it; after ``watchdog_s`` (EGM's communication timeout) the protective stop above follows.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import numpy.typing as npt

from hrc_contract.config import ConfigError
from hrc_contract.messages import JointCommand, JointState
from hrc_contract.vocabulary import ControllerMode
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.time_scaling import JointCommandRejection, joint_command_rejection
from hrc_runtime.clocks import Clocks

FloatArray = npt.NDArray[np.float64]

SilenceBehaviour = Literal["keep_speed", "hold_reference"]
"""What an open controller does between commands, until its watchdog: ``keep_speed`` moves the reference on at the
last q̇_ref (EGM's velocity mode); ``hold_reference`` holds the last q_ref without feed-forward (EGM's position
mode)."""

CommandRejection = JointCommandRejection
"""Why a schema-valid joint command was not accepted (:func:`check_command`)."""

POSITION_GAIN_PER_S = 20.0
"""K of the law [1/s]: the position error decays with a time constant of 1/K = 50 ms.

50 ms is the control lag users measure on ABB's EGM (40–50 ms; ABB states 10–20 ms), so the emulator corrects
no faster than the real one. K · Δt = 0.08 at 4 ms: the discrete loop converges without overshoot, and a reference
one gateway period early or late (q_ref off by q̇ · 4 ms) moves the command by 8 % of q̇ only. A 10 mrad offset is
gone (5 %) in 0.15 s.
"""


@dataclass(frozen=True)
class FollowerLimits:
    """What bounds an open controller's motion, per joint in the order of the robot's joints.

    Attributes:
        velocity_limit_radps: v_max,j, the URDF's velocity limits [rad/s], > 0.
        accel_limit_radps2: a_j = v_max,j / t_b,j [rad/s²], > 0.
        q_min_rad, q_max_rad: the URDF's position limits [rad] (infinite for a joint without).
        gain_per_s: K of the law [1/s], > 0.
        watchdog_s: a command older than this is not followed [s], > 0.
        on_silence: what the controller does between commands until the watchdog (:data:`SilenceBehaviour`).

    Raises:
        ValueError: arrays of different lengths, a limit that is not positive and finite, q_min > q_max, or a gain
            or watchdog that is not positive and finite.
    """

    velocity_limit_radps: FloatArray
    accel_limit_radps2: FloatArray
    q_min_rad: FloatArray
    q_max_rad: FloatArray
    gain_per_s: float = POSITION_GAIN_PER_S
    watchdog_s: float = 0.1
    on_silence: SilenceBehaviour = "keep_speed"

    def __post_init__(self) -> None:
        arrays = (self.velocity_limit_radps, self.accel_limit_radps2, self.q_min_rad, self.q_max_rad)
        shapes = {np.shape(a) for a in arrays}
        if len(shapes) != 1 or len(next(iter(shapes))) != 1 or next(iter(shapes))[0] < 1:
            raise ValueError(f"limits of shapes {[np.shape(a) for a in arrays]}; allowed: one value per joint each")
        for name in ("velocity_limit_radps", "accel_limit_radps2"):
            values = getattr(self, name)
            if not np.all(np.isfinite(values) & (values > 0.0)):
                raise ValueError(f"{name} = {values.tolist()}; allowed: finite values > 0")
        if (
            np.any(np.isnan(self.q_min_rad))
            or np.any(np.isnan(self.q_max_rad))
            or np.any(self.q_min_rad > self.q_max_rad)
        ):
            raise ValueError(
                f"q_min_rad = {self.q_min_rad.tolist()}, q_max_rad = {self.q_max_rad.tolist()}; allowed: q_min <= q_max"
            )
        for name in ("gain_per_s", "watchdog_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} = {value}; allowed: finite > 0")

    @property
    def n_joints(self) -> int:
        return int(self.velocity_limit_radps.shape[0])


def follower_limits(
    robot: RobotModel,
    watchdog_s: float,
    gain_per_s: float = POSITION_GAIN_PER_S,
    stop_time_s: float | None = None,
    on_silence: SilenceBehaviour = "keep_speed",
) -> FollowerLimits:
    """The limits of ``robot``'s open controller: the URDF's velocity and position limits, a_j = v_max,j / t_b,j, or
    a_j = v_max,j / ``stop_time_s`` when given (the controller's ``braking_time_s``: every joint together from its
    velocity limit to standstill in that time, the stop the gateway's ramp plans with; docs/safety-math.md §13).

    Args:
        robot: the robot model (URDF limits, per-joint ``braking_time_s``).
        watchdog_s: the controller's ``watchdog_s`` [s].
        gain_per_s: K of the law [1/s].
        stop_time_s: the controller's stop from full speed [s]; None: each joint's own braking time.
        on_silence: between commands, until the watchdog (:data:`SilenceBehaviour`).

    Raises:
        ConfigError: a joint whose URDF velocity limit is not positive (an open controller could not move it, and
            a_j would be 0): names the joints.
    """
    v_max = np.asarray(robot.velocity_limit_radps, dtype=float).copy()
    bad = [name for name, v in zip(robot.joint_names, v_max, strict=True) if not (np.isfinite(v) and v > 0.0)]
    if bad:
        raise ConfigError(
            f"robot {robot.name!r}: joints {bad} have no positive velocity limit in the URDF; allowed: an open "
            "controller needs v_max > 0 for every joint (its acceleration bound is v_max / braking_time_s)"
        )
    return FollowerLimits(
        velocity_limit_radps=v_max,
        accel_limit_radps2=v_max
        / (np.asarray(robot.braking_time_s, dtype=float) if stop_time_s is None else np.full(v_max.shape, stop_time_s)),
        q_min_rad=np.asarray(robot.model.lowerPositionLimit, dtype=float).copy(),
        q_max_rad=np.asarray(robot.model.upperPositionLimit, dtype=float).copy(),
        gain_per_s=gain_per_s,
        watchdog_s=watchdog_s,
        on_silence=on_silence,
    )


@dataclass(frozen=True)
class FollowerState:
    """Everything an open controller remembers between cycles.

    Attributes:
        q_rad: joint positions [rad].
        qd_radps: joint velocities, the actual ones [rad/s].
        qd_ref_radps: the accepted command's ``qd`` [rad/s]; zeros before any (and, holding the reference, after
            the step the command was applied to).
        mode: ``running`` while it follows a command, ``protective_stop`` otherwise (none yet, or silence).
        q_ref_rad: the reference position for the end of the next step [rad]: the accepted command's ``q``, moved on
            at ``qd_ref_radps`` for each step taken since; None before any command.
        command_stamp_ns: ``stamp_ns`` of the last accepted command; -1 before any [ns, gateway wall clock].
        command_seq: ``seq`` of the last accepted command; -1 before any.
        command_expires_mono_ns: when the last accepted command becomes ``watchdog_s`` old; None before any
            [ns, the controller's monotonic clock].
    """

    q_rad: FloatArray
    qd_radps: FloatArray
    qd_ref_radps: FloatArray
    mode: ControllerMode = "protective_stop"
    q_ref_rad: FloatArray | None = None
    command_stamp_ns: int = -1
    command_seq: int = -1
    command_expires_mono_ns: int | None = None


def initial_state(q_rad: npt.ArrayLike) -> FollowerState:
    """A robot standing at ``q_rad`` [rad], in a protective stop until the first valid command."""
    q = np.array(q_rad, dtype=float)
    return FollowerState(q_rad=q, qd_radps=np.zeros_like(q), qd_ref_radps=np.zeros_like(q))


def check_command(
    msg: JointCommand, robot_name: str, n_joints: int, newest_stamp_ns: int, now_wall_ns: int, watchdog_s: float
) -> CommandRejection | None:
    """Why a joint command cannot be accepted on arrival, or None if it can: the rules every open controller applies
    (:func:`hrc_devices.robots.time_scaling.joint_command_rejection`, shared with the EGM bridge)."""
    return joint_command_rejection(msg, robot_name, n_joints, newest_stamp_ns, now_wall_ns, watchdog_s)


def apply_command(state: FollowerState, msg: JointCommand, received: Clocks, limits: FollowerLimits) -> FollowerState:
    """The state following an accepted command (:func:`check_command` returned None).

    Args:
        state: current state.
        msg: the accepted command.
        received: its arrival on both clocks. It is followed until ``limits.watchdog_s`` after its stamp: its age at
            arrival (wall clock, against its ``stamp_ns``; 0 if stamped ahead) plus the monotonic time since.
        limits: the watchdog time.
    """
    age_ns = max(received.wall_ns - msg.stamp_ns, 0)
    return replace(
        state,
        q_ref_rad=np.array(msg.q, dtype=float),
        qd_ref_radps=np.array(msg.qd, dtype=float),
        command_stamp_ns=msg.stamp_ns,
        command_seq=msg.seq,
        command_expires_mono_ns=received.mono_ns + round(limits.watchdog_s * 1e9) - age_ns,
    )


def following(state: FollowerState, now_mono_ns: int) -> bool:
    """True while the last accepted command is at most ``watchdog_s`` old at ``now_mono_ns`` (False before any)."""
    return state.command_expires_mono_ns is not None and now_mono_ns <= state.command_expires_mono_ns


def stop_speed_radps(
    distance_rad: FloatArray, qd_radps: FloatArray, accel_radps2: FloatArray, dt_s: float
) -> FloatArray:
    """The largest speed toward a limit ``distance_rad`` ahead, at the end of a step, that still stops before it.

    The v' with v'²/(2a) + v' Δt/2 = d − (v + v') Δt/2: having moved the step's trapezoid, the joint stops within
    what is left decelerating by a·Δt per step (the discrete stop covers v'²/(2a) + v' Δt/2 at most). If v²/(2a) +
    v Δt/2 ≤ d held at the start, v − a·Δt meets the bound with room to spare: it never asks for more than ``a``, and
    a joint held against its limit comes to rest there instead of chattering about it.

    Args:
        distance_rad: distance to the limit ahead, ≥ 0 [rad] (inf: no limit).
        qd_radps: velocity toward the limit at the start of the step [rad/s].
        accel_radps2: the deceleration available [rad/s²].
        dt_s: the step [s].
    """
    a_dt = accel_radps2 * dt_s
    inner = a_dt * a_dt + 2.0 * accel_radps2 * (distance_rad - 0.5 * qd_radps * dt_s)
    return np.asarray(-a_dt + np.sqrt(np.maximum(inner, 0.0)), dtype=float)


def step_follower(state: FollowerState, limits: FollowerLimits, dt_s: float, now_mono_ns: int) -> FollowerState:
    """Advance the controller by one cycle (the law, limits and silence of the module docstring).

    Args:
        state: state after the commands of this cycle were applied (:func:`apply_command`).
        limits: velocity, acceleration and position limits, gain and watchdog.
        dt_s: time since the previous step [s] (negative values count as 0).
        now_mono_ns: now [ns, the monotonic clock of :func:`apply_command`'s ``received.mono_ns``].

    Returns:
        The state at the end of the step: q, q̇, the reference moved on by one step, the mode.
    """
    dt_s = max(dt_s, 0.0)
    follow = following(state, now_mono_ns)
    mode: ControllerMode = "running" if follow else "protective_stop"
    if dt_s == 0.0:
        return replace(state, mode=mode)
    q, qd = state.q_rad, state.qd_radps
    a = limits.accel_limit_radps2
    q_ref = state.q_ref_rad
    if follow and q_ref is not None:
        gain = min(limits.gain_per_s, 1.0 / dt_s)
        target = state.qd_ref_radps + gain * (q_ref - (q + state.qd_ref_radps * dt_s))
        if limits.on_silence == "keep_speed":
            q_ref = q_ref + state.qd_ref_radps * dt_s  # the reference of the next step, if no newer command comes
            qd_ref = state.qd_ref_radps
        else:
            qd_ref = np.zeros_like(q)  # no newer command: converge on q_ref (EGM's position mode)
    else:
        target = np.zeros_like(q)
        qd_ref = state.qd_ref_radps
    v_max = limits.velocity_limit_radps
    target = np.clip(target, -v_max, v_max)
    up = stop_speed_radps(np.maximum(limits.q_max_rad - q, 0.0), qd, a, dt_s)
    down = stop_speed_radps(np.maximum(q - limits.q_min_rad, 0.0), -qd, a, dt_s)
    target = np.maximum(np.minimum(target, up), -down)
    qd_new = np.clip(target, qd - a * dt_s, qd + a * dt_s)
    # The position clip only catches rounding: the stop speed keeps q inside its limits.
    q_new = np.clip(q + 0.5 * (qd + qd_new) * dt_s, limits.q_min_rad, limits.q_max_rad)
    return replace(state, q_rad=q_new, qd_radps=qd_new, q_ref_rad=q_ref, qd_ref_radps=qd_ref, mode=mode)


def follower_joint_state(state: FollowerState, robot_name: str, seq: int, stamp_ns: int) -> JointState:
    """The contract's joint state message of an open controller (docs/contract.md, "Joint command").

    An open controller applies no override: it reports ``override`` 1.0 and ``qd_nominal`` = ``qd``, the velocity it
    has (so the gateway's door holds it to the same ``qd = override · qd_nominal`` and to its q's motion, in every
    mode: a protective stop decelerates as it reports); ``override_seq`` the accepted command's ``seq`` (-1 before
    any); ``mode`` ``running`` while it follows, ``protective_stop`` otherwise.
    """
    return JointState(
        robot=robot_name,
        seq=seq,
        stamp_ns=stamp_ns,
        q=state.q_rad.tolist(),
        qd=state.qd_radps.tolist(),
        qd_nominal=state.qd_radps.tolist(),
        override=1.0,
        override_seq=state.command_seq,
        mode=state.mode,
    )
