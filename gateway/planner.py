"""Joint-space planning around people: OMPL's RRT-Connect (paper 2's planner) and TOPP-RA's timing.

One request is one plan: the start (the join ahead on the trajectory the robot follows, with its velocity), the goal
(a program waypoint), the people grown by a clearance, the robot's limits, a time limit and a seed. The validity
checker is the robot's link capsules (Pinocchio's forward kinematics) against the grown human capsules (the
segment distances the gateway checks against coal); joint limits are the state space's bounds. The path is
simplified (OMPL's shortcutting), then timed by :func:`gateway.plan.time_path` and spliced into the old trajectory.

Blocking and slow (10–400 ms): call it in :class:`gateway.planner_worker.ProcessPlanner`'s process, never from the
safety loop (nor from a thread of its process: OMPL and TOPP-RA hold the interpreter lock for long stretches).
Deterministic for a given seed (OMPL's RNG is seeded before each solve; the time limit can still cut a search short on
a loaded machine).
"""

from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from gateway import plan as plan_math
from gateway.plan import Plan, Sampler, TimingError
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.model import RobotModel

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

CHECK_RESOLUTION = 0.01
"""OMPL's motion-check resolution as a fraction of the state space's extent (~0.1 rad over a Panda's 7 joints)."""
LIMIT_MARGIN_RAD = 0.3
"""Planned paths keep the active joints this far inside their limits [rad]: a ramp stop (LP (9) infeasible, a zone
at δ = 0) continues along the current direction for up to the stop time, and a reference beyond a limit makes (9f)
and so LP (9) infeasible: the robot would be stuck at the limit (seen in an end-to-end run before this margin)."""
EXTRA_CLEARANCE_M = (0.4, 0.2, 0.0)
"""The people are first grown by these on top of the request's clearance (largest first): a path farther from
them is faster as well as feasible (eq. (15) slows any approach within a band beyond Δ)."""
INFLATION_STEPS = (0.5, 0.0)
"""When the start is inside the grown people (a person close by: the request (16)), the clearance is then tried at
these fractions of itself: a plan that starts there must first be allowed to leave."""
PATH_ATTEMPTS = 3
"""Paths searched per goal and clearance when a path's timing fails (TOPP-RA's spline or the trapezoid cuts into a
person): the next with the seed + 1. RRT-Connect's path for one seed is one random draw; which draw a machine gets
depends on the last bits of the collision distances (a test's plan that timed on one machine cut a corner on
another, 2026-12-05), so one untimeable path says nothing about the goal."""

TOOL_PATH_POINTS = 32
"""The tool's positions along a plan made for the status and the recording (evenly spaced in plan time): a line
through them, and a status of bounded size whatever the plan."""


class PlanRequest(NamedTuple):
    """What one plan needs (built by :class:`gateway.planner_worker.Replanner` in the loop; immutable).

    Attributes:
        robot: the robot's name.
        old: the trajectory the robot follows (the program or the current plan) and its time now.
        t_now_s, t_join_s: the robot's task time on ``old`` at the request, and the join's (≥ t_now) [s].
        goals: candidate goals (program waypoints in order) with their program times: (q [rad], τ [s]).
        humans: the people (seen and lost, grown by the core).
        clearance_m: the clearance the new path keeps to them [m].
        start_key: the trajectory and time the plan starts from (checked on adoption).
        reason: ``"horizon"`` or ``"request"``.
        seed: OMPL's seed (≥ 1).
        speed_fraction: the new path starts at this fraction of the old trajectory's velocity at the join (the robot's
            δ: a robot the scaling has stopped starts the new path from rest, one at full speed at full speed).
    """

    robot: str
    old: Sampler
    t_now_s: float
    t_join_s: float
    goals: tuple[tuple[FloatArray, float], ...]
    humans: HumanCapsules
    clearance_m: float
    start_key: tuple[object, ...]
    reason: str
    seed: int
    speed_fraction: float = 1.0


class PlanOutcome(NamedTuple):
    """A planner's answer: a plan, or why there is none, and the time it took (wall clock) [s]."""

    robot: str
    plan: Plan | None
    failure: str
    planning_s: float
    start_key: tuple[object, ...]


@dataclass
class JointPlanner:
    """RRT-Connect + simplification + TOPP-RA for one robot (its own Pinocchio data: one thread at a time).

    Attributes:
        robot: the model (links, radii, limits, base pose).
        active: the joints planned (velocity indices); the others stay at the start's values.
        qd_max_radps, qdd_max_radps2: the active joints' limits for the timing.
        time_limit_s: RRT-Connect's time limit per solve [s].
        simplify_s: the time for OMPL's path simplification; 0: until it no longer improves (deterministic: a time
            budget would give another path on a loaded machine) [s].
    """

    robot: RobotModel
    active: IntArray
    qd_max_radps: FloatArray
    qdd_max_radps2: FloatArray
    time_limit_s: float = 0.3
    simplify_s: float = 0.0
    limit_margin_rad: float = LIMIT_MARGIN_RAD
    data: pin.Data = field(init=False)
    limits_rad: tuple[FloatArray, FloatArray] = field(init=False)
    """The joint range planned in (lower, upper): the model's, the active joints' narrowed by the margin [rad]."""

    def __post_init__(self) -> None:
        self.data = self.robot.model.createData()
        self.limits_rad = self._range(None)

    def _range(self, q_start_rad: FloatArray | None) -> tuple[FloatArray, FloatArray]:
        """The model's limits, the active joints' narrowed by the margin and widened again to take in the start."""
        lower = np.array(self.robot.model.lowerPositionLimit, dtype=float)
        upper = np.array(self.robot.model.upperPositionLimit, dtype=float)
        lower[self.active] += self.limit_margin_rad
        upper[self.active] -= self.limit_margin_rad
        if q_start_rad is not None:
            lower = np.minimum(lower, q_start_rad)
            upper = np.maximum(upper, q_start_rad)
        return lower, upper

    def valid(self, q_rad: FloatArray, humans: HumanCapsules, grow_m: float) -> bool:
        """The validity checker: a plain ``bool`` (see :func:`gateway.plan.configuration_valid`), in the planned range
        :attr:`limits_rad`."""
        return plan_math.configuration_valid(self.robot, self.data, q_rad, humans, grow_m, self.limits_rad)

    def path(
        self, q_start_rad: FloatArray, q_goal_rad: FloatArray, humans: HumanCapsules, grow_m: float, seed: int
    ) -> FloatArray | None:
        """RRT-Connect from ``q_start_rad`` to ``q_goal_rad`` (full configurations; the inactive joints of the goal
        are taken from the start), simplified: the waypoints (W, n) [rad], or None (no exact solution in time)."""
        from ompl import base as ob
        from ompl import geometric as og
        from ompl import util as ou

        ou.setLogLevel(ou.LOG_NONE)
        ou.RNG.setSeed(max(1, int(seed)))
        active = self.active
        n = int(active.size)
        base = np.array(q_start_rad, dtype=float)
        space = ob.RealVectorStateSpace(n)
        bounds = ob.RealVectorBounds(n)
        lower, upper = self.limits_rad
        for k, j in enumerate(active):
            bounds.setLow(k, float(lower[j]))
            bounds.setHigh(k, float(upper[j]))
        space.setBounds(bounds)
        setup = og.SimpleSetup(space)

        def full(state: object) -> FloatArray:
            q = base.copy()
            q[active] = [state[k] for k in range(n)]  # type: ignore[index]
            return q

        def checker(state: object) -> bool:
            return bool(self.valid(full(state), humans, grow_m))

        setup.setStateValidityChecker(checker)
        info = setup.getSpaceInformation()
        info.setStateValidityCheckingResolution(CHECK_RESOLUTION)
        start, goal = space.allocState(), space.allocState()
        for k, j in enumerate(active):
            start[k] = float(q_start_rad[j])
            goal[k] = float(q_goal_rad[j])
        setup.setStartAndGoalStates(start, goal)
        setup.setPlanner(og.RRTConnect(info))
        solved = setup.solve(self.time_limit_s)
        if not bool(solved) or not setup.haveExactSolutionPath():
            return None
        setup.simplifySolution(self.simplify_s)
        result = setup.getSolutionPath()
        points = np.array([full(result.getState(i)) for i in range(result.getStateCount())], dtype=float)
        return _drop_repeats(points)

    def solve(self, request: PlanRequest) -> PlanOutcome:
        """Plan, time and splice one request; never raises for a path it cannot find (the failure says why)."""
        started = time.perf_counter()
        outcome = self._solve(request)
        elapsed = time.perf_counter() - started
        plan = outcome[0]
        if plan is not None:  # the path shown (status, recording): here, not in the loop (~4 ms)
            path_m = plan_math.tool_path_world_m(self.robot, self.data, plan, 0.0, plan.duration_s, TOOL_PATH_POINTS)
            plan = dataclasses.replace(plan, planning_s=elapsed, tool_path_world_m=path_m)
        return PlanOutcome(request.robot, plan, outcome[1], elapsed, request.start_key)

    def _solve(self, request: PlanRequest) -> tuple[Plan | None, str]:
        q_join, qd_nominal = request.old.sample(request.t_join_s)
        qd_join = min(max(request.speed_fraction, 0.0), 1.0) * qd_nominal
        self.limits_rad = self._range(q_join)
        failure = "no_goal"
        levels = [request.clearance_m + extra for extra in EXTRA_CLEARANCE_M]
        levels += [request.clearance_m * fraction for fraction in INFLATION_STEPS]
        for grow_m in levels:
            if not self.valid(q_join, request.humans, grow_m):
                failure = "start_invalid"
                continue
            for q_goal, goal_tau_s in request.goals:
                plan, failure = self._solve_goal(request, q_join, qd_join, q_goal, goal_tau_s, grow_m)
                if plan is not None:
                    return plan, ""
            if failure == "no_timing" or (failure == "no_path" and grow_m <= request.clearance_m):
                break  # a level that fails with valid ends at the request's clearance: lower ones need not be tried
        return None, failure

    def _solve_goal(
        self,
        request: PlanRequest,
        q_join: FloatArray,
        qd_join: FloatArray,
        q_goal: FloatArray,
        goal_tau_s: float,
        grow_m: float,
    ) -> tuple[Plan | None, str]:
        """One goal at one clearance: path, timing (at the join's velocity, else from rest: the LPs' (9d) smooths the
        step of the reference), splice; the plan or why not."""
        humans = request.humans
        goal = np.array(q_goal, dtype=float)
        inactive = np.setdiff1d(np.arange(goal.size), self.active)
        goal[inactive] = q_join[inactive]
        if not self.valid(goal, humans, grow_m):
            return None, "goal_invalid"

        def clear(q_active: FloatArray) -> bool:
            return self.valid(_fill(q_join, self.active, q_active), humans, grow_m)

        failure = "no_path"
        for attempt in range(PATH_ATTEMPTS):
            points = self.path(q_join, goal, humans, grow_m, request.seed + attempt)
            if points is None:
                return None, failure  # RRT-Connect found none in its time: another seed would not either, as a rule
            for qd_start in (qd_join, np.zeros_like(qd_join)):
                try:
                    timed = plan_math.time_path(
                        points[:, self.active], qd_start[self.active], self.qd_max_radps, self.qdd_max_radps2, clear
                    )
                except TimingError:
                    continue
                try:
                    plan = plan_math.splice(
                        request.old,
                        request.t_now_s,
                        request.t_join_s,
                        _FullPath(timed, q_join, self.active),
                        goal_tau_s,
                        request.start_key,
                        request.reason,
                        _fill(np.zeros_like(qd_start), self.active, qd_start[self.active]),  # the others are held
                        clearance_m=grow_m,
                    )
                except ValueError:
                    return None, "no_join"
                return plan, ""
            failure = "no_timing"
        return None, failure


def warm_up() -> None:
    """Import OMPL and TOPP-RA (1–2 s on a loaded 2-core machine): done once before the first request, so that the
    first plan is not late by the imports."""
    import ompl.base
    import ompl.geometric  # noqa: F401
    import toppra.algorithm
    import toppra.constraint  # noqa: F401


def _fill(q_base_rad: FloatArray, active: IntArray, q_active_rad: FloatArray) -> FloatArray:
    q = np.array(q_base_rad, dtype=float)
    q[active] = q_active_rad
    return q


class _FullPath(plan_math.TimedPath):
    """A timed path of the active joints seen as full configurations (the others held at the start's values)."""

    def __init__(self, timed: plan_math.TimedPath, q_base_rad: FloatArray, active: IntArray) -> None:
        waypoints = np.repeat(np.asarray(q_base_rad, dtype=float)[None, :], len(timed.waypoints_rad), axis=0)
        waypoints[:, active] = timed.waypoints_rad
        base = np.array(q_base_rad, dtype=float)
        position = functools.partial(_filled, timed, base, active, False)
        velocity = functools.partial(_filled, timed, base, active, True)
        super().__init__(waypoints, timed.duration_s, timed.how, position, velocity)


def _filled(
    timed: plan_math.TimedPath, base_rad: FloatArray, active: IntArray, derivative: bool, t_s: float
) -> FloatArray:
    """q (the others at ``base_rad``) or q̇ (the others 0) of a timed path of the active joints (picklable)."""
    q, qd = timed.sample(t_s)
    if derivative:
        out = np.zeros_like(base_rad)
        out[active] = qd
        return out
    return _fill(base_rad, active, q)


def _drop_repeats(points: FloatArray) -> FloatArray:
    """Consecutive waypoints closer than 1e-6 rad merged (TOPP-RA's spline needs strictly increasing knots)."""
    keep = [0]
    for i in range(1, len(points)):
        if float(np.max(np.abs(points[i] - points[keep[-1]]))) > 1e-6:
            keep.append(i)
    if keep[-1] != len(points) - 1 and len(keep) > 1:
        keep[-1] = len(points) - 1
    return points[keep] if len(keep) > 1 else points[[0, -1]]
