"""The planner layer's pure parts: timed joint paths, the horizon check and the splice (paper 2, Alg. 1–2).

Pupa et al. 2021 put a planner above the scaling: the robot follows a nominal trajectory at full speed; every loop
the configurations of the next ``horizon_s`` seconds of it are checked against the people (seen and lost, grown by
how far they can walk in the time until the robot gets there, K t, plus a protective clearance); when one of them
is infeasible, a new piece is planned from the last feasible configuration ahead and merged into the trajectory
(the *splice*): the robot keeps following the old trajectory up to the join, then the new piece, then the program.

A :class:`Plan` is that merged trajectory, from the robot's task point at the time of the request on: its first
piece is the old trajectory itself (so q and q̇ are continuous wherever the robot is along it when the plan arrives),
the second the new piece, timed by TOPP-RA within the velocity and acceleration limits (its start velocity is the old
trajectory's at the join), ending at standstill on a program waypoint, from which the program resumes.

Safety never depends on anything here: the LPs (9)/(13) bound every command whatever the robot follows
(docs/planner.md). No I/O, no clock, no threads.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from gateway.kernels import segment_distances
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.model import RobotModel

FloatArray = npt.NDArray[np.float64]

MIN_SEGMENT_S = 0.02
"""Pseudo-time of the shortest waypoint-to-waypoint move in the path parameter of the spline [s]."""
JOIN_TOLERANCE_RAD = 1e-6
"""A plan's first configuration may differ from the trajectory it splices into by this [rad]."""


class Sampler(Protocol):
    """Anything that gives joint positions [rad] and velocities [rad/s] at a time [s] (a program, a timed path)."""

    def sample(self, t_s: float) -> tuple[FloatArray, FloatArray]: ...


@dataclass(frozen=True, eq=False)
class TimedPath:
    """A joint path timed within limits: a callable ``q(t)`` and its derivative, ``duration_s`` long.

    Attributes:
        waypoints_rad: the geometric path's waypoints, shape (W, n) [rad].
        duration_s: the time from the first to the last waypoint [s].
        how: ``"toppra"``, ``"toppra:<gridpoints>"`` after a retry, or ``"trapezoid"`` (the fallback).
    """

    waypoints_rad: FloatArray
    duration_s: float
    how: str
    _position: Callable[[float], FloatArray]
    _velocity: Callable[[float], FloatArray]

    def sample(self, t_s: float) -> tuple[FloatArray, FloatArray]:
        """q [rad] and q̇ [rad/s] at ``t_s``, held at the ends outside [0, duration] (q̇ = 0 after the end)."""
        if t_s >= self.duration_s:
            return np.asarray(self._position(self.duration_s), dtype=float), np.zeros(self.waypoints_rad.shape[1])
        t = max(t_s, 0.0)
        return np.asarray(self._position(t), dtype=float), np.asarray(self._velocity(t), dtype=float)


class Piece(NamedTuple):
    """A stretch of a trajectory: ``source`` from its time ``t0_s`` for ``duration_s``."""

    source: Sampler
    t0_s: float
    duration_s: float


@dataclass(frozen=True, eq=False)
class Plan:
    """A merged trajectory: pieces in order; at its end the robot stands on the program at ``goal_tau_s``.

    Attributes:
        pieces: the old trajectory up to the join, then the new timed path (or the new path alone).
        goal_tau_s: the program time (not wrapped) at which the program resumes after the plan [s].
        start_key: what the plan splices into (``("program", τ)`` or ``("plan", id, t)``): the trajectory and the
            time on it at which the plan starts; :meth:`gateway.open_robot.OpenRobot.adopt` checks it.
        reason: why it was planned (``"horizon"``, ``"request"``).
        planning_s: the planner's time for it (wall clock, for the status; 0 when unknown) [s].
        clearance_m: how far the new path was planned from the people (their capsules grown by it) [m]: the horizon
            check holds the plan to no more (a plan that had to start near someone is not replanned for it at once).
        tool_path_world_m: the tool's positions along the whole plan, evenly spaced in plan time, world frame, shape
            (N, 3) (:func:`tool_path_world_m`, by the planner), for the status and the recording; None if not made [m].
    """

    pieces: tuple[Piece, ...]
    goal_tau_s: float
    start_key: tuple[object, ...]
    reason: str = ""
    planning_s: float = 0.0
    clearance_m: float = math.inf
    tool_path_world_m: FloatArray | None = None

    @property
    def duration_s(self) -> float:
        return float(sum(p.duration_s for p in self.pieces))

    @property
    def new_path(self) -> TimedPath | None:
        """The planned piece (the last one), if it is a timed path."""
        source = self.pieces[-1].source
        return source if isinstance(source, TimedPath) else None

    def pieces_between(self, t0_s: float, t1_s: float) -> tuple[Piece, ...]:
        """The stretch of this plan from its time ``t0_s`` to ``t1_s`` as pieces of its own sources: a plan spliced
        into a plan keeps only that stretch, not the old plan (no chain of plans grows with every replan)."""
        out: list[Piece] = []
        start = 0.0
        for piece in self.pieces:
            end = start + piece.duration_s
            lo, hi = max(t0_s, start), min(t1_s, end)
            if hi > lo:
                out.append(Piece(piece.source, piece.t0_s + (lo - start), hi - lo))
            start = end
        return tuple(out)

    def sample(self, t_s: float) -> tuple[FloatArray, FloatArray]:
        """q [rad] and q̇ [rad/s] at plan time ``t_s`` (from the plan's start)."""
        t = max(t_s, 0.0)
        for piece in self.pieces[:-1]:
            if t < piece.duration_s:
                return piece.source.sample(piece.t0_s + t)
            t -= piece.duration_s
        last = self.pieces[-1]
        return last.source.sample(last.t0_s + min(t, last.duration_s))


# -- the robot's capsules at many configurations ---------------------------------------------------------


def link_ends_world(robot: RobotModel, data: pin.Data, q_rad: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The link segments' ends in the world frame at ``q_rad`` (Pinocchio's forward kinematics), (L, 3) each [m]."""
    pin.framesForwardKinematics(robot.model, data, q_rad)
    r, p = robot.R_world_base, robot.p_world_base
    a = np.array([data.oMf[f].translation for f in robot.frame_a_ids], dtype=float) @ r.T + p
    b = np.array([data.oMf[f].translation for f in robot.frame_b_ids], dtype=float) @ r.T + p
    return a, b


def clearance_to_people_m(
    robot: RobotModel, data: pin.Data, q_rad: FloatArray, humans: HumanCapsules, grow_m: float | FloatArray
) -> float:
    """The smallest surface distance between the robot's link capsules at ``q_rad`` and the people's capsules grown
    by ``grow_m`` (one value, or one per capsule) [m]; +inf with nobody."""
    if not humans.n_capsules:
        return math.inf
    a, b = link_ends_world(robot, data, q_rad)
    centre = segment_distances(a, b, humans.h_a_world, humans.h_b_world).distance_m
    surface = centre - robot.link_radius_m[:, None] - (humans.radius_m + grow_m)[None, :]
    return float(surface.min())


def configuration_valid(
    robot: RobotModel,
    data: pin.Data,
    q_rad: FloatArray,
    humans: HumanCapsules,
    grow_m: float,
    limits_rad: tuple[FloatArray, FloatArray] | None = None,
) -> bool:
    """True when ``q_rad`` is within the joint limits (``limits_rad`` = (lower, upper); default the model's) and keeps
    every link clear of every grown capsule.

    A plain Python ``bool`` (OMPL's validity checker crashes the solve on a numpy bool)."""
    model = robot.model
    lower, upper = (model.lowerPositionLimit, model.upperPositionLimit) if limits_rad is None else limits_rad
    if not bool(np.all(q_rad >= lower) and np.all(q_rad <= upper)):
        return False
    return bool(clearance_to_people_m(robot, data, q_rad, humans, grow_m) > 0.0)


def tool_path_world_m(
    robot: RobotModel, data: pin.Data, path: Sampler, t0_s: float, t1_s: float, points: int
) -> FloatArray:
    """The tool's positions (the end of the robot's last link capsule) in the world frame at ``points`` (≥ 2) times
    evenly spaced from ``t0_s`` to ``t1_s`` on ``path`` (Pinocchio's forward kinematics), shape (points, 3) [m].

    What the operator page and the recording draw of a plan. ~4 ms for 32 points of a TOPP-RA plan (sampling the
    spline dominates): done by the planner, beside the loop, never per status."""
    tool = robot.frame_b_ids[-1]
    out = np.empty((max(points, 2), 3))
    for k, t_s in enumerate(np.linspace(t0_s, t1_s, len(out))):
        q, _ = path.sample(float(t_s))
        pin.forwardKinematics(robot.model, data, q)
        pin.updateFramePlacement(robot.model, data, tool)
        out[k] = robot.R_world_base @ data.oMf[tool].translation + robot.p_world_base
    return out


# -- the horizon check (Alg. 1) -------------------------------------------------------------------------


class HorizonVerdict(NamedTuple):
    """The horizon check of one loop.

    Attributes:
        infeasible_t_s: the time ahead of the first infeasible configuration, None when all are feasible [s].
        last_feasible_t_s: the time ahead of the last feasible configuration before it (0: the current one) [s].
        min_clearance_m: the smallest margin over the configurations checked (negative: infeasible) [m].
    """

    infeasible_t_s: float | None
    last_feasible_t_s: float
    min_clearance_m: float


def horizon_check(
    robot: RobotModel,
    data: pin.Data,
    path: Sampler,
    t_now_s: float,
    horizon_s: float,
    step_s: float,
    humans: HumanCapsules,
    human_speed_mps: float,
    clearance_m: float,
    t_end_s: float = math.inf,
    growth_cap_s: float = math.inf,
) -> HorizonVerdict:
    """Alg. 1's check: the configurations of ``path`` at ``t_now_s + t`` for t = step, 2 step, … ≤ ``horizon_s`` (and
    ≤ ``t_end_s`` on the path) against the people grown by ``clearance_m + human_speed_mps · t`` (a person may walk
    K t before the robot gets there); the first infeasible one and the last feasible one before it.

    Args:
        path: the trajectory the robot follows (the program or a plan); its time ``t_now_s`` is the robot's task point.
        humans: the people the decision keeps clear of (seen, and lost grown by the core).
        human_speed_mps: K (``safety.human_speed_mps``) [m/s].
        clearance_m: the protective clearance the planned path keeps [m].
        t_end_s: the path's end (a plan's duration) [s].
        growth_cap_s: the growth stops at K times this (the planner's own growth: a path planned around people who
            stay where they are passes the check; one who steps into it does not) [s].
    """
    if not humans.n_capsules:
        return HorizonVerdict(None, min(horizon_s, max(t_end_s - t_now_s, 0.0)), math.inf)
    last_feasible = 0.0
    worst = math.inf
    n = math.floor(horizon_s / step_s + 1e-9)  # 0 when the horizon is shorter than a step: nothing checked
    for k in range(1, n + 1):
        t_ahead = k * step_s
        if t_now_s + t_ahead > t_end_s + 1e-9:
            break
        q, _ = path.sample(t_now_s + t_ahead)
        margin = clearance_to_people_m(
            robot, data, q, humans, clearance_m + human_speed_mps * min(t_ahead, growth_cap_s)
        )
        worst = min(worst, margin)
        if margin <= 0.0:
            return HorizonVerdict(t_ahead, last_feasible, worst)
        last_feasible = t_ahead
    return HorizonVerdict(None, last_feasible, worst)


# -- timing (TOPP-RA, with a fallback) ------------------------------------------------------------------


class TimingError(Exception):
    """No timing within the limits was found for a path (TOPP-RA and the fallback both failed)."""


def _pseudo_times(waypoints_rad: FloatArray, qd_max_radps: FloatArray) -> FloatArray:
    """Cumulative time of each waypoint at full speed on the slowest joint: the spline's path parameter [s]."""
    step = np.max(np.abs(np.diff(waypoints_rad, axis=0)) / qd_max_radps, axis=1)
    return np.concatenate(([0.0], np.cumsum(np.maximum(step, MIN_SEGMENT_S))))


def time_path_toppra(
    waypoints_rad: FloatArray,
    qd_start_radps: FloatArray,
    qd_max_radps: FloatArray,
    qdd_max_radps2: FloatArray,
    gridpoints: int | None = None,
) -> TimedPath | None:
    """TOPP-RA's time-optimal timing of the cubic spline through ``waypoints_rad`` (W ≥ 2), starting with joint velocity
    ``qd_start_radps`` and ending at rest, within ±``qd_max_radps`` and ±``qdd_max_radps2``; None when it finds none.

    The spline's parameter is the pseudo-time of :func:`_pseudo_times`; its start tangent points along the start
    velocity, whose size sets ṡ at the start."""
    import toppra
    import toppra.algorithm
    import toppra.constraint

    toppra.setup_logging("ERROR")
    ss = _pseudo_times(waypoints_rad, qd_max_radps)
    moving = bool(np.any(np.abs(qd_start_radps) > 1e-9))
    zeros = np.zeros(waypoints_rad.shape[1])
    # ṡ at the start: the first segment's own rate, so that the spline's start tangent dq/ds = q̇_start / ṡ has the
    # segment's magnitude (a tiny or huge tangent forces a loop or a kink that no acceleration limit allows)
    segment_rate = float(np.linalg.norm(waypoints_rad[1] - waypoints_rad[0])) / float(ss[1] - ss[0])
    sd_start = float(np.linalg.norm(qd_start_radps)) / max(segment_rate, 1e-9) if moving else 0.0
    tangent = np.asarray(qd_start_radps, dtype=float) / sd_start if moving else zeros
    bc = ((1, tangent), (2, zeros)) if moving else ((2, zeros), (2, zeros))
    path = toppra.SplineInterpolator(ss, waypoints_rad, bc_type=bc)
    constraints = [
        toppra.constraint.JointVelocityConstraint(np.stack((-qd_max_radps, qd_max_radps), axis=1)),
        toppra.constraint.JointAccelerationConstraint(np.stack((-qdd_max_radps2, qdd_max_radps2), axis=1)),
    ]
    grid = None if gridpoints is None else np.linspace(0.0, float(ss[-1]), gridpoints)
    algorithm = toppra.algorithm.TOPPRA(constraints, path, gridpoints=grid, parametrizer="ParametrizeConstAccel")
    try:
        trajectory = algorithm.compute_trajectory(sd_start=sd_start, sd_end=0.0)
    except Exception:
        return None
    if trajectory is None or not math.isfinite(float(trajectory.duration)) or trajectory.duration <= 0.0:
        return None
    how = "toppra" if gridpoints is None else f"toppra:{gridpoints}"
    return TimedPath(
        np.array(waypoints_rad, dtype=float),
        float(trajectory.duration),
        how,
        trajectory,
        functools.partial(_derivative, trajectory),
    )


def time_path_trapezoid(waypoints_rad: FloatArray, qd_max_radps: FloatArray, qdd_max_radps2: FloatArray) -> TimedPath:
    """The fallback: straight joint-space moves between the waypoints, each joint-synchronised on a trapezoidal (or
    triangular) profile within the limits, at rest at every waypoint. Starts at rest."""
    starts = [0.0]
    moves: list[tuple[FloatArray, FloatArray, float, float, float, float]] = []
    for q0, q1 in itertools.pairwise(waypoints_rad):
        delta = q1 - q0
        # the slowest joint sets the move: time at speed and accelerating, as a fraction of the path s ∈ [0, 1]
        v = float(np.min(qd_max_radps / np.maximum(np.abs(delta), 1e-12)))  # ds/dt cap
        a = float(np.min(qdd_max_radps2 / np.maximum(np.abs(delta), 1e-12)))  # d²s/dt² cap
        if v * v / a >= 1.0:
            t_acc = math.sqrt(1.0 / a)
            v, duration = a * t_acc, 2.0 * t_acc
        else:
            t_acc = v / a
            duration = 1.0 / v + t_acc
        moves.append((q0, delta, v, a, t_acc, duration))
        starts.append(starts[-1] + duration)

    profile = _Trapezoid(tuple(moves), tuple(starts))
    return TimedPath(
        np.array(waypoints_rad, dtype=float),
        starts[-1],
        "trapezoid",
        functools.partial(profile.at, derivative=False),
        functools.partial(profile.at, derivative=True),
    )


def _derivative(trajectory: Callable[..., FloatArray], t_s: float) -> FloatArray:
    """dq/dt of a TOPP-RA trajectory at ``t_s`` (a module-level function: plans are pickled to the planner process)."""
    return trajectory(t_s, 1)


@dataclass(frozen=True)
class _Trapezoid:
    """The fallback's moves (q0, Δq, v, a, t_acc, duration) and their start times; picklable."""

    moves: tuple[tuple[FloatArray, FloatArray, float, float, float, float], ...]
    starts: tuple[float, ...]

    def at(self, t_s: float, derivative: bool) -> FloatArray:
        """q (or q̇ with ``derivative``) at ``t_s`` [rad, rad/s]."""
        i = max(min(int(np.searchsorted(self.starts, t_s, side="right")) - 1, len(self.moves) - 1), 0)
        q0, delta, v, a, t_acc, duration = self.moves[i]
        t = min(t_s - self.starts[i], duration)
        if t < t_acc:
            s, rate = 0.5 * a * t * t, a * t
        elif duration - t < t_acc:
            left = duration - t
            s, rate = 1.0 - 0.5 * a * left * left, a * left
        else:
            s, rate = 0.5 * a * t_acc * t_acc + v * (t - t_acc), v
        return np.asarray(delta * rate if derivative else q0 + delta * s, dtype=float)


def within_limits(path: TimedPath, qd_max_radps: FloatArray, qdd_max_radps2: FloatArray, step_s: float) -> bool:
    """True when the sampled velocities stay within the limits and the finite-difference accelerations within them
    (a small tolerance for sampling: 2 %)."""
    ts = np.arange(0.0, path.duration_s + step_s, step_s)
    qd = np.array([path.sample(float(t))[1] for t in ts])
    if np.any(np.abs(qd) > 1.02 * qd_max_radps + 1e-6):
        return False
    qdd = np.diff(qd, axis=0) / step_s
    return bool(np.all(np.abs(qdd) <= 1.02 * qdd_max_radps2 + 1e-3))


def time_path(
    waypoints_rad: FloatArray,
    qd_start_radps: FloatArray,
    qd_max_radps: FloatArray,
    qdd_max_radps2: FloatArray,
    valid: Callable[[FloatArray], bool] | None = None,
    check_step_s: float = 0.02,
) -> TimedPath:
    """Time a joint path within the limits: TOPP-RA, then TOPP-RA on denser gridpoints, then with the waypoints
    subdivided (the spline then hugs the checked straight segments), then (only when starting at rest) the
    trapezoidal fallback. Each candidate's samples must pass ``valid`` (the spline may cut a corner into a person).

    Raises:
        TimingError: none of them gave a valid timing.
    """
    attempts: list[tuple[FloatArray, int | None]] = []
    for points in (waypoints_rad, _subdivide(waypoints_rad, 3)):
        attempts += [(points, None), (points, max(100, 40 * len(points)))]
    at_rest = not np.any(np.abs(qd_start_radps) > 1e-9)
    for k in range(len(attempts) + (1 if at_rest else 0)):
        if k < len(attempts):
            points, grid = attempts[k]
            timed = time_path_toppra(points, qd_start_radps, qd_max_radps, qdd_max_radps2, grid)
        else:
            timed = time_path_trapezoid(waypoints_rad, qd_max_radps, qdd_max_radps2)
        if timed is None:
            continue
        times = np.arange(0.0, timed.duration_s + check_step_s, check_step_s)
        if valid is not None and not all(valid(timed.sample(float(t))[0]) for t in times):
            continue
        return timed
    raise TimingError(f"no timing within the limits for a path of {len(waypoints_rad)} waypoints")


def _subdivide(waypoints_rad: FloatArray, parts: int) -> FloatArray:
    """Each segment split into ``parts`` equal straight parts."""
    out = [waypoints_rad[0]]
    for q0, q1 in itertools.pairwise(waypoints_rad):
        out.extend(q0 + (q1 - q0) * (k / parts) for k in range(1, parts + 1))
    return np.array(out, dtype=float)


# -- the splice (Alg. 2) --------------------------------------------------------------------------------


def splice(
    old: Sampler,
    t_now_s: float,
    t_join_s: float,
    new_path: TimedPath,
    goal_tau_s: float,
    start_key: tuple[object, ...],
    reason: str,
    qd_join_radps: FloatArray | None = None,
    planning_s: float = 0.0,
    clearance_m: float = math.inf,
) -> Plan:
    """Alg. 2's merge: the old trajectory from ``t_now_s`` to the join at ``t_join_s`` (on its own clock), then
    ``new_path``, which must start at the old trajectory's configuration at the join and at ``qd_join_radps`` (default:
    the old trajectory's velocity there; the planner passes the robot's δ times it, see
    :class:`gateway.planner.PlanRequest`).

    Raises:
        ValueError: the new path does not start where the old trajectory is at the join (q or q̇ differ).
    """
    q_join, qd_old = old.sample(t_join_s)
    qd_join = qd_old if qd_join_radps is None else qd_join_radps
    q_new, qd_new = new_path.sample(0.0)
    if float(np.max(np.abs(q_new - q_join))) > JOIN_TOLERANCE_RAD:
        raise ValueError(f"the new path starts {float(np.max(np.abs(q_new - q_join))):.3g} rad from the join")
    if float(np.max(np.abs(qd_new - qd_join))) > 1e-3 + 1e-3 * float(np.max(np.abs(qd_join), initial=0.0)):
        raise ValueError(f"the new path starts at another velocity ({qd_new} rad/s, the join's {qd_join} rad/s)")
    pieces: tuple[Piece, ...] = (Piece(new_path, 0.0, new_path.duration_s),)
    if t_join_s > t_now_s:
        before = (
            old.pieces_between(t_now_s, t_join_s)
            if isinstance(old, Plan)
            else (Piece(old, t_now_s, t_join_s - t_now_s),)
        )
        pieces = (*before, *pieces)
    return Plan(pieces, goal_tau_s, start_key, reason, planning_s, clearance_m)
