"""The planner layer's pure parts and the planner itself on the open Panda of configs/cell_open_panda_planner.toml:
timing within limits (TOPP-RA and the fallback), the horizon check (seen, grown and lost people), the splice's
continuity, the validity checker's plain bool, deterministic plans for a seed, the planner's refusals, adoption by
the open robot, and when the replanner asks."""

from __future__ import annotations

import itertools
import math
import os
import signal
import time

import numpy as np
import pytest
from support.hanging_planner import HangingPlanner

from gateway import plan as plan_math
from gateway.core import RobotDecision, SafetyCore
from gateway.delay import DelayBudget
from gateway.open_robot import OpenRobot
from gateway.plan import Plan, TimedPath
from gateway.planner import PATH_ATTEMPTS, TOOL_PATH_POINTS, JointPlanner, PlanOutcome, PlanRequest
from gateway.planner_worker import (
    DIED,
    PlannerHealth,
    ProcessPlanner,
    Replanner,
    SimulatedPlanner,
    ThreadedPlanner,
    goal_candidates,
    join_lead_s,
    restart_backoff_s,
)
from gateway.status import robot_status
from gateway.zones import ZoneThresholds
from hrc_contract.config import CellConfig, PlannerConfig
from hrc_contract.humans import NO_HUMANS, HumanCapsules
from hrc_contract.vocabulary import Zone
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import Trajectory, load_trajectory
from hrc_runtime.config import load_cell_config
from hrc_tools.cell.procs import load_scale

CONFIG = "configs/cell_open_panda_planner.toml"
PICK = np.array([1.2, 0.2, 0.0, -2.0, 0.0, 2.2, 0.785, 0.03, 0.03])
PLACE = np.array([-1.2, 0.2, 0.0, -2.0, 0.0, 2.2, 0.785, 0.01, 0.01])


def person(x_m: float, y_m: float, grow_m: float = 0.0, human: str = "p1") -> HumanCapsules:
    """A standing person (torso, head, legs) at (x, y); ``grow_m`` grows the radii (a lost track's reach) [m]."""
    a = np.array([[x_m, y_m, 1.0], [x_m, y_m, 1.65], [x_m, y_m, 0.1]])
    b = np.array([[x_m, y_m, 1.5], [x_m, y_m, 1.75], [x_m, y_m, 0.95]])
    return HumanCapsules(a, b, grow_m + np.array([0.18, 0.11, 0.15]), (human,) * 3, ("torso", "head", "legs"))


@pytest.fixture(scope="module")
def config() -> CellConfig:
    return load_cell_config(CONFIG)


@pytest.fixture(scope="module")
def panda(config: CellConfig) -> RobotModel:
    return load_robot_model("panda", config.robots["panda"])


@pytest.fixture(scope="module")
def program(config: CellConfig, panda: RobotModel) -> Trajectory:
    return load_trajectory(config.robots["panda"].program, panda)


def open_robot(config: CellConfig, panda: RobotModel, program: Trajectory) -> OpenRobot:
    return OpenRobot(panda, program, 0.004, config.robots["panda"].controller.braking_time_s)


@pytest.fixture(scope="module")
def planner(config: CellConfig, panda: RobotModel, program: Trajectory) -> JointPlanner:
    robot = open_robot(config, panda, program)
    limits = robot.limits
    return JointPlanner(panda, robot.active, limits.qd_max_radps, limits.qdd_max_radps2, time_limit_s=1.0)


def limits(planner: JointPlanner) -> tuple[np.ndarray, np.ndarray]:
    return planner.qd_max_radps, planner.qdd_max_radps2


# -- timing ---------------------------------------------------------------------------------------------


def test_toppra_times_random_paths_within_the_limits_through_their_ends(planner: JointPlanner) -> None:
    qd_max, qdd_max = limits(planner)
    rng = np.random.default_rng(7)
    for _ in range(3):
        points = PICK[:7] + rng.uniform(-0.6, 0.6, size=(5, 7))
        timed = plan_math.time_path(points, np.zeros(7), qd_max, qdd_max)
        assert plan_math.within_limits(timed, qd_max, qdd_max, 0.01)
        np.testing.assert_allclose(timed.sample(0.0)[0], points[0], atol=1e-6)
        np.testing.assert_allclose(timed.sample(timed.duration_s)[0], points[-1], atol=1e-6)
        np.testing.assert_allclose(timed.sample(timed.duration_s + 1.0)[1], 0.0)


def test_a_timing_that_starts_moving_starts_at_that_velocity(planner: JointPlanner) -> None:
    qd_max, qdd_max = limits(planner)
    points = np.array([PICK[:7], 0.5 * (PICK + PLACE)[:7] + 0.3, PLACE[:7]])
    qd_start = 0.3 * (points[1] - points[0])
    timed = plan_math.time_path(points, qd_start, qd_max, qdd_max)
    np.testing.assert_allclose(timed.sample(0.0)[1], qd_start, atol=1e-3)
    assert plan_math.within_limits(timed, qd_max, qdd_max, 0.01)


def test_the_trapezoid_fallback_stays_within_the_limits_and_stops_at_every_waypoint(planner: JointPlanner) -> None:
    qd_max, qdd_max = limits(planner)
    points = np.array([PICK[:7], PICK[:7] + 0.4, PLACE[:7]])
    timed = plan_math.time_path_trapezoid(points, qd_max, qdd_max)
    assert plan_math.within_limits(timed, qd_max, qdd_max, 0.002)
    first_s = float(np.max(np.abs(points[1] - points[0]) / qd_max))  # at least the time at full speed
    assert timed.duration_s > first_s
    t = 0.0
    for point in points:  # at rest on each waypoint, found by bisection of the position along the moves
        ts = np.linspace(t, timed.duration_s, 2000)
        k = int(np.argmin([np.max(np.abs(timed.sample(float(x))[0] - point)) for x in ts]))
        assert np.max(np.abs(timed.sample(float(ts[k]))[0] - point)) < 1e-3
        assert np.max(np.abs(timed.sample(float(ts[k]))[1])) < 0.05
        t = float(ts[k])


# -- the validity checker and the horizon check --------------------------------------------------------------


def test_the_validity_checker_returns_a_plain_bool(planner: JointPlanner) -> None:
    inside, outside = person(0.6, 0.0), person(3.0, 0.0)
    for humans, expected in ((inside, False), (outside, True), (NO_HUMANS, True)):
        answer = planner.valid(0.5 * (PICK + PLACE), humans, 0.1)
        assert type(answer) is bool
        assert answer is expected
    beyond = PICK.copy()
    beyond[0] = 10.0  # outside joint 1's limits
    assert planner.valid(beyond, NO_HUMANS, 0.0) is False


def test_the_horizon_check_finds_a_person_in_the_swing_and_nobody_elsewhere(
    panda: RobotModel, program: Trajectory
) -> None:
    data = panda.model.createData()
    tau_s = 0.35  # just after the dwell at the pick: the swing ahead passes the front
    blocked = plan_math.horizon_check(panda, data, program, tau_s, 1.0, 0.1, person(1.0, 0.0), 1.6, 0.1)
    assert blocked.infeasible_t_s is not None
    assert 0.0 <= blocked.last_feasible_t_s < blocked.infeasible_t_s
    assert blocked.min_clearance_m <= 0.0
    clear = plan_math.horizon_check(panda, data, program, tau_s, 1.0, 0.1, person(3.5, 2.5), 1.6, 0.1)
    assert clear.infeasible_t_s is None
    assert clear.min_clearance_m > 0.0
    nobody = plan_math.horizon_check(panda, data, program, tau_s, 1.0, 0.1, NO_HUMANS, 1.6, 0.1)
    assert nobody.infeasible_t_s is None


def test_the_horizon_check_grows_people_by_k_times_the_time_ahead_and_sees_lost_tracks(
    panda: RobotModel, program: Trajectory
) -> None:
    data = panda.model.createData()
    far = person(1.9, 0.0)
    still = plan_math.horizon_check(panda, data, program, 0.35, 1.0, 0.1, far, 0.0, 0.1)
    walking = plan_math.horizon_check(panda, data, program, 0.35, 1.0, 0.1, far, 1.6, 0.1)
    assert still.infeasible_t_s is None  # where they stand, the swing passes them
    assert walking.infeasible_t_s is not None  # at K = 1.6 m/s they can be in the way when the robot gets there
    capped = plan_math.horizon_check(panda, data, program, 0.35, 1.0, 0.1, far, 1.6, 0.1, growth_cap_s=0.0)
    assert capped.infeasible_t_s is None
    lost = person(1.9, 0.0, grow_m=1.0, human="lost:p1")  # the core grows a lost track's radii by its reach
    assert plan_math.horizon_check(panda, data, program, 0.35, 1.0, 0.1, lost, 0.0, 0.1).infeasible_t_s is not None


# -- the splice ---------------------------------------------------------------------------------------------


def test_the_splice_keeps_q_and_qd_continuous_at_the_start_and_the_join(
    planner: JointPlanner, program: Trajectory
) -> None:
    t_now, t_join = 0.32, 0.4  # early in the swing (accelerating: 0.5 rad/s at the join)
    q_join, qd_join = program.sample(t_join)
    bend = np.array([0.0, -0.3, 0.0, 0.3, 0.0, 0.0, 0.0])
    points = np.array([q_join[:7], 0.5 * (q_join + PLACE)[:7] + bend, PLACE[:7]])
    timed = plan_math.time_path(points, qd_join[:7], *limits(planner))
    full = TimedPath(
        np.c_[points, np.tile(q_join[7:], (3, 1))],
        timed.duration_s,
        timed.how,
        lambda t: np.r_[timed.sample(t)[0], q_join[7:]],
        lambda t: np.r_[timed.sample(t)[1], 0.0, 0.0],
    )
    held = np.r_[qd_join[:7], 0.0, 0.0]  # the fingers are not planned (held where they are)
    plan = plan_math.splice(program, t_now, t_join, full, 9.0, ("program", t_now), "horizon", held)
    for t_plan, t_old in ((0.0, t_now), (0.05, t_now + 0.05)):
        np.testing.assert_allclose(plan.sample(t_plan)[0], program.sample(t_old)[0])
        np.testing.assert_allclose(plan.sample(t_plan)[1], program.sample(t_old)[1])
    before, after = plan.sample(t_join - t_now - 1e-6), plan.sample(t_join - t_now + 1e-6)
    np.testing.assert_allclose(before[0], after[0], atol=1e-5)
    np.testing.assert_allclose(before[1][:7], after[1][:7], atol=1e-3)
    np.testing.assert_allclose(plan.sample(plan.duration_s)[0][:7], PLACE[:7], atol=1e-6)
    with pytest.raises(ValueError, match="from the join"):
        plan_math.splice(program, t_now, t_join + 0.2, full, 9.0, ("program", t_now), "horizon", held)


# -- the planner ----------------------------------------------------------------------------------------------


def request(program: Trajectory, humans: HumanCapsules, seed: int, clearance_m: float = 0.3) -> PlanRequest:
    """From the pick at rest (τ = 0.1, in its dwell) to the place, around ``humans``."""
    return PlanRequest(
        "panda", program, 0.1, 0.1, ((PLACE, 2.5),), humans, clearance_m, ("program", 0.1), "horizon", seed, 0.0
    )


def test_plans_go_around_the_person_within_the_limits_and_repeat_for_a_seed(
    planner: JointPlanner, program: Trajectory
) -> None:
    humans = person(1.0, 0.0)
    first = planner.solve(request(program, humans, 3))
    again = planner.solve(request(program, humans, 3))
    assert first.plan is not None, first.failure
    assert again.plan is not None
    new, same = first.plan.new_path, again.plan.new_path
    assert new is not None
    assert same is not None
    np.testing.assert_array_equal(new.waypoints_rad, same.waypoints_rad)
    assert len(new.waypoints_rad) >= 3  # not the straight swing: that passes through the person
    data = planner.robot.model.createData()
    lower = planner.robot.model.lowerPositionLimit[:7] + planner.limit_margin_rad
    upper = planner.robot.model.upperPositionLimit[:7] - planner.limit_margin_rad
    for t in np.arange(0.0, first.plan.duration_s, 0.02):
        q, _ = first.plan.sample(float(t))
        assert plan_math.clearance_to_people_m(planner.robot, data, q, humans, 0.3) > -1e-3
        assert np.all(q[:7] >= lower - 1e-6)  # inside the limits by the margin: a ramp stop cannot cross them
        assert np.all(q[:7] <= upper + 1e-6)
    speeds = np.array([np.abs(new.sample(float(t))[1][:7]) for t in np.arange(0.0, new.duration_s, 0.01)])
    assert np.all(speeds <= 1.02 * planner.qd_max_radps)
    np.testing.assert_allclose(first.plan.sample(first.plan.duration_s)[0][:7], PLACE[:7], atol=1e-6)


def test_the_planner_says_why_there_is_no_plan(planner: JointPlanner, program: Trajectory) -> None:
    at_goal = PLACE.copy()
    at_goal[:7] = PLACE[:7]
    tool_place = plan_math.link_ends_world(planner.robot, planner.robot.model.createData(), PLACE)[1][-1]
    on_the_goal = person(float(tool_place[0]), float(tool_place[1]))
    outcome = planner.solve(request(program, on_the_goal, 1))
    assert outcome.plan is None
    assert outcome.failure == "goal_invalid"
    walled = HumanCapsules(  # one huge capsule around the whole robot: not even the start is free at any clearance
        np.array([[0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 2.0]]), np.array([2.0]), ("p",), ("wall",)
    )
    assert planner.solve(request(program, walled, 1)).failure == "start_invalid"


# -- adoption and the replanner -------------------------------------------------------------------------------


def plan_from(program: Trajectory, t_now: float, planner: JointPlanner) -> Plan:
    outcome = planner.solve(
        PlanRequest(
            "panda", program, t_now, t_now + 0.1, ((PLACE, 2.5),), person(1.0, 0.0), 0.3, ("program", t_now), "h", 2
        )
    )
    assert outcome.plan is not None, outcome.failure
    return outcome.plan


def test_the_open_robot_adopts_a_plan_only_from_where_it_is(
    config: CellConfig, panda: RobotModel, program: Trajectory, planner: JointPlanner
) -> None:
    robot = open_robot(config, panda, program)
    robot.tau_s = 0.35
    plan = plan_from(program, 0.35, planner)
    robot.tau_s = 0.3  # the plan starts ahead of the robot: it cannot jump there
    assert not robot.adopt(plan)
    robot.tau_s = 0.9  # the robot is past the join: too late
    assert not robot.adopt(plan)
    robot.tau_s = 0.4
    q_before, qd_before = robot.reference_sample()
    assert robot.adopt(plan)
    q_after, qd_after = robot.reference_sample()
    np.testing.assert_allclose(q_after, q_before)
    np.testing.assert_allclose(qd_after, qd_before)
    assert not robot.adopt(plan)  # a plan for the program, while the robot follows a plan
    robot._advance(plan.duration_s)  # the plan ends: the program resumes at its goal
    assert robot.plan is None
    assert math.isclose(robot.tau_s, plan.goal_tau_s + 0.05, abs_tol=1e-9)
    np.testing.assert_allclose(robot.reference_sample()[0][:7], program.sample(robot.tau_s)[0][:7])


class Recorder:
    """A backend that records requests and never answers (a silent planner)."""

    def __init__(self) -> None:
        self.requests: list[PlanRequest] = []

    def submit(self, request: PlanRequest) -> bool:
        self.requests.append(request)
        return True

    def poll(self) -> list[PlanOutcome]:
        return []

    def health(self) -> PlannerHealth:
        return PlannerHealth()

    def close(self) -> None:
        pass


def test_the_replanner_asks_on_a_blocked_horizon_or_the_request_and_not_while_faulted(
    config: CellConfig, panda: RobotModel, program: Trajectory
) -> None:
    settings = PlannerConfig(enabled=True, horizon_s=1.0, check_every_s=0.1, retry_after_s=0.5, time_limit_s=0.1)
    robot = open_robot(config, panda, program)
    robot.tau_s = 0.35
    backend = Recorder()
    replanner = Replanner("panda", settings, 1.6, robot)
    resume_m = 0.5  # the zones' resume distance (protective + hysteresis; ~1.2 m in the shipped cell)
    replanner.cycle(0, person(1.0, 0.0), False, True, resume_m, backend)
    assert backend.requests == []  # faulted: blind, nothing to plan around
    replanner.cycle(200_000_000, person(1.0, 0.0), False, False, resume_m, backend)
    assert [r.reason for r in backend.requests] == ["horizon"]
    assert backend.requests[0].goals[0][1] > 0.35
    replanner.cycle(300_000_000, person(1.0, 0.0), False, False, resume_m, backend)
    assert len(backend.requests) == 1  # one request in flight at a time
    replanner.cycle(2_000_000_000, person(1.0, 0.0), False, False, resume_m, backend)
    assert replanner.stats.failures["timeout"] == 1  # a planner that never answers is given up on
    assert len(backend.requests) == 2
    quiet = Replanner("panda", settings, 1.6, open_robot(config, panda, program))
    quiet.open_robot.tau_s = 0.35
    quiet.cycle(0, person(3.5, 3.0), False, False, resume_m, backend)
    assert len(backend.requests) == 2  # far away, no request (16): nothing to do
    quiet.cycle(200_000_000, person(3.5, 3.0), True, False, resume_m, backend)
    assert backend.requests[-1].reason == "request"


def test_the_join_lies_ahead_of_where_the_robot_gets_while_the_planner_works() -> None:
    assert join_lead_s(0.1, 0.5, 1.0, 0.3) == pytest.approx(0.1)  # the configured lead where it is clear
    assert join_lead_s(0.1, 0.04, 0.1, 0.3) == pytest.approx(0.04)  # not beyond the last feasible configuration ...
    # ... unless the robot gets past it before the answer: a robot creeping at δ = 0.05 inside the clearance
    assert join_lead_s(0.1, 0.0, 0.05, 0.3) == pytest.approx(0.015)
    assert join_lead_s(0.1, 0.0, 1.0, 0.3) == pytest.approx(0.1)  # never beyond the configured lead
    assert join_lead_s(0.1, 0.0, 0.0, 0.3) == 0.0  # a robot standing still joins where it stands


def test_the_replanner_joins_ahead_by_what_the_robot_covers_in_its_planners_answer_time(
    config: CellConfig, panda: RobotModel, program: Trajectory
) -> None:
    settings = PlannerConfig(enabled=True, horizon_s=1.0, check_every_s=0.1, retry_after_s=0.5, time_limit_s=0.5)
    robot = open_robot(config, panda, program)
    robot.tau_s, robot.delta_prev = 0.35, 0.2
    backend = Recorder()
    replanner = Replanner("panda", settings, 1.6, robot)
    close = person(0.6, 0.0)  # the robot is already inside the clearance: no configuration ahead is feasible
    replanner.cycle(0, close, False, False, 0.5, backend)
    first = backend.requests[-1]
    assert first.t_join_s - first.t_now_s == pytest.approx(0.2 * settings.join_lead_s)  # before any answer
    replanner.take(PlanOutcome("panda", None, "no_path", 0.3, first.start_key), 300_000_000)  # answered in 0.3 s
    assert replanner.answer_time_s() == pytest.approx(0.3)
    replanner.cycle(900_000_000, close, False, False, 0.5, backend)
    second = backend.requests[-1]
    assert second is not first
    assert second.t_join_s - second.t_now_s == pytest.approx(0.2 * 0.3)  # δ × the answer time: not passed meanwhile


def test_goal_candidates_are_the_next_program_waypoints(program: Trajectory) -> None:
    assert len(goal_candidates(program, 0.35)) == 1  # the next station only: a later one would skip it
    goals = goal_candidates(program, 0.35, count=2)
    np.testing.assert_allclose(goals[0][0], program.waypoints_rad[1])
    assert goals[0][1] == pytest.approx(float(program.arrival_s[1]))
    assert goals[1][1] == pytest.approx(program.duration_s)  # back at the pick, next cycle
    later = goal_candidates(program, 10 * program.duration_s + 0.35)
    assert later[0][1] == pytest.approx(10 * program.duration_s + float(program.arrival_s[1]))


def test_the_simulated_planner_answers_at_the_next_poll(planner: JointPlanner, program: Trajectory) -> None:
    backend = SimulatedPlanner({"panda": planner})
    assert backend.submit(request(program, person(1.0, 0.0), 4))
    done = backend.poll()
    assert len(done) == 1
    assert done[0].plan is not None
    assert backend.poll() == []


def test_the_status_shows_the_plan_the_robot_follows(
    config: CellConfig, panda: RobotModel, program: Trajectory, planner: JointPlanner
) -> None:
    robot = open_robot(config, panda, program)
    robot.tau_s = 0.35
    replanner = Replanner("panda", PlannerConfig(enabled=True), 1.6, robot)
    replanner.take(PlanOutcome("panda", plan_from(program, 0.35, planner), "", 0.042, ("program", 0.35)), 0)
    replanner.take(PlanOutcome("panda", None, "no_path", 0.3, ("program", 1.0)), 0)
    decision = RobotDecision(
        "panda",
        Zone.REDUCED_SPEED,
        0.5,
        0.5,
        1.3,
        None,
        DelayBudget(0.04, 0.03, 0.004, 0.012, 0.004, 0.004),
        1.0,
        ZoneThresholds(1.0, 1.15, 1.9, 2.4),
        (),
        {"joint_state": 0.004},
        "running",
        plan=replanner.view(),
    )
    shown = robot_status(decision, 1).plan
    assert shown is not None
    assert shown.following
    assert shown.plan_time_s == 0.0
    assert shown.plan_duration_s is not None
    assert shown.plan_duration_s > 0.0
    assert shown.path_waypoints is not None
    assert shown.path_waypoints >= 2
    assert (shown.adopted, shown.rejected, shown.failures) == (1, 0, {"no_path": 1})
    assert shown.planning_last_s == 0.3
    assert shown.planning_total_s == pytest.approx(0.342)
    # the plan as the tool's path: bounded, from the plan's start to its end, by forward kinematics (the planner's)
    path = shown.path_tool_m
    assert path is not None
    assert len(path) == TOOL_PATH_POINTS
    plan = robot.plan
    assert plan is not None
    data = panda.model.createData()
    start = plan_math.link_ends_world(panda, data, plan.sample(0.0)[0])[1][-1]
    end = plan_math.link_ends_world(panda, data, plan.sample(plan.duration_s)[0])[1][-1]
    np.testing.assert_allclose(path[0], start, atol=1e-4)
    np.testing.assert_allclose(path[-1], end, atol=1e-4)
    assert max(math.dist(a, b) for a, b in itertools.pairwise(path)) < 0.5  # a line, not scattered points
    assert (shown.planner_running, shown.planner_deaths, shown.planner_restarts) == (True, 0, 0)
    # the planner made it with the plan: every decision shows the same array, none computes it; gone with the plan
    assert replanner.view().path_tool_world_m is replanner.view().path_tool_world_m
    robot.plan = None
    assert robot_status(decision._replace(plan=replanner.view()), 1).plan.path_tool_m is None  # type: ignore[union-attr]
    assert robot_status(decision._replace(plan=None), 1).plan is None


class Crashes(JointPlanner):
    def solve(self, request: PlanRequest) -> PlanOutcome:
        raise RuntimeError("boom")


def wait_for(backend: ThreadedPlanner | ProcessPlanner) -> list[PlanOutcome]:
    """Poll until an answer comes (at most 30 s: a planner thread that never answers fails the test)."""
    for _ in range(3000):
        done = backend.poll()
        if done:
            return done
        time.sleep(0.01)
    raise AssertionError("the planner thread never answered")


def test_the_threaded_planner_answers_from_its_own_thread_and_survives_a_crash(
    planner: JointPlanner, panda: RobotModel, program: Trajectory
) -> None:
    backend = ThreadedPlanner({"panda": planner})
    try:
        assert backend.poll() == []
        assert backend.submit(request(program, person(1.0, 0.0), 5))
        done = wait_for(backend)
        assert done[0].plan is not None
        assert done[0].robot == "panda"
    finally:
        backend.close()
    assert not backend.submit(request(program, person(1.0, 0.0), 5))  # closed
    crashing = ThreadedPlanner({"panda": Crashes(panda, planner.active, planner.qd_max_radps, planner.qdd_max_radps2)})
    try:
        crashing.submit(request(program, person(1.0, 0.0), 5))
        outcome = wait_for(crashing)[0]
        assert outcome.plan is None
        assert outcome.failure == "error:RuntimeError"
        crashing.submit(request(program, person(1.0, 0.0), 6))
        assert wait_for(crashing)[0].failure == "error:RuntimeError"  # the thread lives on
    finally:
        crashing.close()


def test_the_core_builds_the_planner_layer_only_when_enabled(config: CellConfig, panda: RobotModel) -> None:
    core = SafetyCore(config, {"panda": panda})  # the gateway's default backend: the planner's own process
    try:
        assert isinstance(core.planner, ProcessPlanner)
        assert core.states["panda"].replanner is not None
    finally:
        core.close()
    off = config.model_copy(update={"planner": config.planner.model_copy(update={"enabled": False})})
    plain = SafetyCore(off, {"panda": panda})
    assert plain.planner is None
    assert plain.states["panda"].replanner is None
    simulated = SafetyCore(config, {"panda": panda}, SimulatedPlanner)
    assert isinstance(simulated.planner, SimulatedPlanner)


class FirstPathsCut(JointPlanner):
    """A planner whose first ``cut`` paths go straight through the person (no timing can keep them clear)."""

    cut: int = 0
    seeds: list[int]

    def path(
        self, q_start_rad: np.ndarray, q_goal_rad: np.ndarray, humans: HumanCapsules, grow_m: float, seed: int
    ) -> np.ndarray | None:
        self.seeds.append(seed)
        if len(self.seeds) <= self.cut:
            return np.array([q_start_rad, q_goal_rad])  # the straight swing, through the person at (1, 0)
        return super().path(q_start_rad, q_goal_rad, humans, grow_m, seed)


@pytest.mark.parametrize("cut", [1, PATH_ATTEMPTS - 1, PATH_ATTEMPTS])
def test_a_path_that_cannot_be_timed_clear_of_the_person_is_searched_again_with_the_next_seed(
    planner: JointPlanner, program: Trajectory, cut: int
) -> None:
    cutting = FirstPathsCut(planner.robot, planner.active, planner.qd_max_radps, planner.qdd_max_radps2, 1.0)
    cutting.cut, cutting.seeds = cut, []
    outcome = cutting.solve(request(program, person(1.0, 0.0), 3))
    first_level = cutting.seeds[: min(cut + 1, PATH_ATTEMPTS)]
    assert first_level == [3 + k for k in range(len(first_level))]  # the seeds in turn, at the first clearance
    if cut < PATH_ATTEMPTS:
        assert outcome.plan is not None, outcome.failure
        assert len(cutting.seeds) == cut + 1
    else:  # every attempt at the first clearance cut through: given up, and said why
        assert outcome.plan is None
        assert outcome.failure == "no_timing"
        assert len(cutting.seeds) == PATH_ATTEMPTS


def test_a_plan_spliced_into_a_plan_keeps_only_the_stretch_it_needs(program: Trajectory, planner: JointPlanner) -> None:
    first = plan_from(program, 0.35, planner)
    t_now, t_join = 0.05, 0.3  # across the first plan's join (0.1 s after its start)
    q_join, _ = first.sample(t_join)
    again = planner.solve(
        PlanRequest(
            "panda", first, t_now, t_join, ((PLACE, 2.5),), person(1.0, 0.0), 0.3, ("plan", 1, t_now), "h", 3, 0.0
        )
    )
    assert again.plan is not None, again.failure
    second = again.plan
    assert not any(isinstance(piece.source, Plan) for piece in second.pieces)  # no chain of plans
    for t in np.linspace(0.0, t_join - t_now - 1e-6, 7):
        np.testing.assert_allclose(second.sample(float(t))[0], first.sample(t_now + float(t))[0], atol=1e-9)
    np.testing.assert_allclose(second.sample(t_join - t_now)[0][:7], q_join[:7], atol=1e-6)


def test_the_process_planner_answers_from_its_own_process(planner: JointPlanner, program: Trajectory) -> None:
    backend = ProcessPlanner({"panda": planner})
    try:
        assert backend.submit(request(program, person(1.0, 0.0), 5))
        outcome = wait_for(backend)[0]
        assert outcome.plan is not None, outcome.failure
        here = planner.solve(request(program, person(1.0, 0.0), 5)).plan
        assert here is not None
        new, theirs = here.new_path, outcome.plan.new_path
        assert new is not None
        assert theirs is not None
        np.testing.assert_array_equal(theirs.waypoints_rad, new.waypoints_rad)  # the same seed, the same plan
        assert backend.submit(request(program, person(1.0, 0.0), 5)._replace(robot="nobody"))
        assert wait_for(backend)[0].failure == "error:KeyError"
    finally:
        backend.close()
    assert not backend.submit(request(program, person(1.0, 0.0), 5))


def test_a_dead_planner_process_is_counted_its_request_failed_and_it_is_started_again(
    planner: JointPlanner, program: Trajectory
) -> None:
    backend = ProcessPlanner({"panda": planner})
    try:
        first = backend.pid
        assert first is not None
        assert backend.submit(request(program, person(1.0, 0.0), 5))
        os.kill(first, signal.SIGKILL)  # while it imports the libraries or plans: the request is in flight
        deadline = time.monotonic() + 10.0 * load_scale()
        answers: list[PlanOutcome] = []
        while backend.health().deaths == 0 and time.monotonic() < deadline:
            answers += backend.poll()
            time.sleep(0.01)
        health = backend.health()
        assert (health.running, health.deaths, health.restarts) == (False, 1, 0)
        assert health.last_exit == "signal SIGKILL"
        assert [a.failure for a in answers if a.plan is None] == [DIED]  # not left waiting for the time-out
        assert not backend.submit(request(program, person(1.0, 0.0), 5))  # refused until it runs again
        while backend.health().restarts == 0 and time.monotonic() < deadline:  # after the first backoff step
            backend.poll()
            time.sleep(0.01)
        assert backend.health() == (True, 1, 1, "signal SIGKILL")
        assert backend.pid not in (None, first)
        assert backend.submit(request(program, person(1.0, 0.0), 5))
        outcome = wait_for(backend)[0]
        assert outcome.plan is not None, outcome.failure
    finally:
        backend.close()
    assert not backend.submit(request(program, person(1.0, 0.0), 5))


def test_a_hung_planner_process_is_killed_counted_and_started_again(program: Trajectory) -> None:
    """A child alive but silent on its request for ``hang_after_s``: killed, counted as a death that says ``hung``, its
    request answered as failed, and a new child started."""
    backend = ProcessPlanner({"panda": HangingPlanner()}, hang_after_s=1.0)  # type: ignore[dict-item]
    try:
        first = backend.pid
        assert backend.submit(request(program, person(1.0, 0.0), 5))
        deadline = time.monotonic() + 20.0 * load_scale()
        answers: list[PlanOutcome] = []
        while backend.health().restarts == 0 and time.monotonic() < deadline:
            answers += backend.poll()
            time.sleep(0.01)
        health = backend.health()
        assert (health.running, health.deaths, health.restarts) == (True, 1, 1), health
        assert health.last_exit == "hung (no answer in 1 s), signal SIGKILL"
        assert [a.failure for a in answers] == [DIED]
        assert backend.pid not in (None, first)
    finally:
        backend.close()


def test_a_planner_process_answering_in_time_is_never_taken_for_hung(
    planner: JointPlanner, program: Trajectory
) -> None:
    backend = ProcessPlanner({"panda": planner}, hang_after_s=15.0 * load_scale())
    try:
        for _ in range(2):
            assert backend.submit(request(program, person(1.0, 0.0), 5))
            assert wait_for(backend)[0].plan is not None
        assert backend.health().deaths == 0
    finally:
        backend.close()


def test_the_restart_backoff_doubles_up_to_eight_seconds() -> None:
    assert [restart_backoff_s(n) for n in range(1, 8)] == [0.5, 1.0, 2.0, 4.0, 8.0, 8.0, 8.0]
    assert restart_backoff_s(0) == 0.5
