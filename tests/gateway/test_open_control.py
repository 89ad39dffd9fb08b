"""LP (9) and (13) of paper 1 for open controllers (gateway/open_control.py, gateway/open_robot.py).

The solutions are checked against an independent LP solver (HiGHS), the UR5 (no redundancy) against the closed
mode's eq. (15), and every fallback against the rows it must keep.
"""

from __future__ import annotations

from typing import Any

import highspy
import numpy as np
import pytest

from gateway import open_control
from gateway.open_control import Limits, SafetyRows, Task
from gateway.open_robot import OpenRobot, active_joints
from gateway.reference.kinematics import link_kinematics
from gateway.reference.separation import build_rows
from gateway.separation import override_from_rows
from hrc_contract.config import ConfigError
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.model import load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.config import load_cell_config

DT_S = 0.004


def _limits(n: int, qd_max: float = 2.0, t_brake_s: float = 0.02) -> Limits:
    return Limits(np.full(n, qd_max), np.full(n, qd_max / t_brake_s), np.full(n, -3.0), np.full(n, 3.0), t_brake_s)


def _random_problem(seed: int, n: int = 7, m: int = 40) -> tuple[SafetyRows, Task, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    a = rng.normal(0.0, 0.3, (m, n))
    qd_task = rng.normal(0.0, 0.6, n)
    f = np.abs(a @ qd_task) * rng.uniform(0.4, 3.0, m)  # rows that bound δ somewhere around 0.4–1
    rows = SafetyRows(a, f, np.zeros(m, np.intp), np.arange(m), 0)
    jac = rng.normal(0.0, 0.5, (6, n))
    task = Task(jac, jac @ qd_task, jac @ rng.normal(0.0, 0.02, n))  # a correction the joints can make
    qd_prev = 0.5 * qd_task
    return rows, task, qd_prev, np.zeros(n)


def _highs_lp9(rows: SafetyRows, task: Task, lower: np.ndarray, upper: np.ndarray) -> float | None:
    """LP (9) by HiGHS (an independent simplex): the largest δ, None when infeasible."""
    n = lower.size
    h = highspy.Highs()  # type: ignore[no-untyped-call]
    h.setOptionValue("output_flag", False)
    inf = highspy.kHighsInf
    for j in range(n):
        h.addVar(float(lower[j]), float(upper[j]))
    h.addVar(0.0, 1.0)
    h.changeColCost(n, -1.0)
    for k in range(rows.f_m2.size):
        h.addRow(-inf, float(rows.f_m2[k]), n, np.arange(n, dtype=np.int32), rows.a_s[k])
    for k in range(task.x_rate.size):
        coef = np.append(task.jacobian[k], -task.x_rate[k])
        h.addRow(float(task.correction[k]), float(task.correction[k]), n + 1, np.arange(n + 1, dtype=np.int32), coef)
    h.run()
    if h.getModelStatus() != highspy.HighsModelStatus.kOptimal:
        return None
    return float(h.getSolution().col_value[n])


@pytest.mark.parametrize("seed", range(12))
def test_lp9_finds_the_delta_an_independent_solver_finds(seed: int) -> None:
    rows, task, qd_prev, q_ref = _random_problem(seed)
    limits = _limits(7)
    lower, upper = open_control.velocity_bounds(qd_prev, q_ref, limits, DT_S)
    ours = open_control.solve_lp9(rows, task, lower, upper)
    theirs = _highs_lp9(rows, task, lower, upper)
    assert (ours is None) == (theirs is None)
    if ours is not None and theirs is not None:
        qd, delta = ours
        assert delta == pytest.approx(theirs, abs=1e-6)
        assert not open_control.violated_rows(rows, qd).size
        assert np.allclose(task.jacobian @ qd, delta * task.x_rate + task.correction, atol=1e-6)
        assert ((qd >= lower - 1e-7) & (qd <= upper + 1e-7)).all()


def test_the_random_problems_are_not_all_trivial() -> None:
    found = []
    for seed in range(12):
        rows, task, qd_prev, q_ref = _random_problem(seed)
        lower, upper = open_control.velocity_bounds(qd_prev, q_ref, _limits(7), DT_S)
        found.append(_highs_lp9(rows, task, lower, upper))
    deltas = [d for d in found if d is not None]
    assert any(0.0 < d < 1.0 - 1e-6 for d in deltas)  # some are bounded by a row
    assert len(deltas) >= 6


def test_lp13_keeps_the_task_at_delta_and_comes_nearer_to_the_self_motion_reference() -> None:
    rows, task, qd_prev, q_ref = _random_problem(2)
    limits = _limits(7)
    lower, upper = open_control.velocity_bounds(qd_prev, q_ref, limits, DT_S)
    best = open_control.solve_lp9(rows, task, lower, upper)
    assert best is not None
    qd9, delta = best
    wish = qd9 + np.array([0.0, 0.0, 0.3, 0.0, 0.0, 0.0, 0.0])
    second = open_control.solve_lp13(rows, task, delta, lower, upper, wish)
    assert second is not None
    qd13, gap = second
    assert np.allclose(task.jacobian @ qd13, delta * task.x_rate + task.correction, atol=1e-6)
    assert not open_control.violated_rows(rows, qd13).size
    assert gap == pytest.approx(float(np.max(np.abs(qd13 - wish))), abs=1e-6)
    assert gap <= float(np.max(np.abs(qd9 - wish))) + 1e-9


def test_an_lp9_that_cannot_stop_in_time_falls_back_to_the_ramp_stop() -> None:
    # Moving at 1.5 rad/s on joint 0; one row forbids any motion of joint 0 toward the person (f = 0): stopping in
    # one cycle needs 1.5 rad/s in 4 ms, (9d) allows 4 rad/s² · 4 ms.
    n = 2
    rows = SafetyRows(np.array([[1.0, 0.0]]), np.array([0.0]), np.zeros(1, np.intp), np.zeros(1, np.intp), 0)
    task = Task(np.zeros((0, n)), np.zeros(0), np.zeros(0))
    limits = _limits(n, qd_max=2.0, t_brake_s=0.5)
    qd_prev = np.array([1.5, 0.0])
    solution = open_control.decide(
        rows, task, qd_prev, np.zeros(n), limits, DT_S, np.zeros(n), open_control.fixed_cap(1.0), ("l0",)
    )
    assert solution.how == "ramp_stop:lp9_infeasible"
    assert solution.delta == 0.0
    # speed fraction 0.75 falls by Δt / t_b,max = 0.008 along the same direction
    assert solution.qd_radps == pytest.approx(qd_prev * (0.75 - 0.008) / 0.75)


def test_lp13_runs_a_half_percent_below_a_bounded_delta_on_a_redundant_arm_only() -> None:
    seven = Task(np.zeros((6, 7)), np.zeros(6), np.zeros(6))  # a Panda: one joint beyond the tool's pose
    six = Task(np.zeros((6, 6)), np.zeros(6), np.zeros(6))  # a UR5: LP (9) is eq. (15), no room to make
    assert open_control.with_self_motion_room(0.6, 0.6, seven) == pytest.approx(0.6 * (1.0 - 0.005))
    assert open_control.with_self_motion_room(0.6, 0.6, six) == 0.6
    assert open_control.with_self_motion_room(1.0, 1.0, seven) == 1.0  # unbounded: the redundancy is free
    assert open_control.with_self_motion_room(1.0 - 1e-14, 1.0 - 1e-14, seven) == 1.0 - 1e-14  # 1 to the solver
    assert open_control.with_self_motion_room(0.3, 0.6, seven) == 0.3  # a zone asked for less: room of its own


def test_the_self_motion_has_room_where_lp9_bounds_delta_on_a_redundant_arm() -> None:
    """Two joints, a 1-D task (J = [1, 1]): the redundant direction is (1, −1). LP (9) bounds δ where both joints are
    at the top of their one-cycle window, so at δ* itself the self-motion has no range at all (either joint lower
    would lower δ). Half a percent below δ*, LP (13) can follow the reference's wish to slow joint 1."""
    rows = SafetyRows(np.zeros((0, 2)), np.zeros(0), np.zeros(0, np.intp), np.zeros(0, np.intp), 0)
    task = Task(np.array([[1.0, 1.0]]), np.array([1.0]), np.zeros(1))
    limits = _limits(2, qd_max=2.0, t_brake_s=0.5)  # q̈max Δt = 0.016
    qd_prev = np.array([0.3, 0.3])
    solution = open_control.decide(
        rows, task, qd_prev, np.zeros(2), limits, DT_S, np.array([0.316, 0.0]), open_control.fixed_cap(1.0), ("l0",)
    )
    assert solution.how == "lp13"
    assert solution.delta == pytest.approx(0.632 * 0.995)
    assert solution.qd_radps[0] == pytest.approx(0.316)
    assert solution.qd_radps[1] == pytest.approx(0.316 - 0.632 * 0.005)  # 0.316 at δ*: no self-motion at all
    assert float(task.jacobian[0] @ solution.qd_radps) == pytest.approx(solution.delta, abs=1e-9)


def test_the_ramp_stop_ends_within_the_longest_braking_time_and_never_brakes_a_joint_harder_than_its_bound() -> None:
    limits = Limits(np.array([2.0, 1.0, 3.0]), np.array([4.0, 5.0, 6.0]), -np.ones(3), np.ones(3), 0.5)
    qd = np.array([2.0, -0.4, 1.5])
    steps = 0
    while np.any(qd != 0.0):
        nxt = open_control.ramp_stop(qd, limits, DT_S)
        assert (np.abs(nxt - qd) <= limits.qdd_max_radps2 * DT_S + 1e-12).all()
        assert (np.sign(nxt) * np.sign(qd) >= 0).all()  # the same direction, never a reversal
        qd, steps = nxt, steps + 1
    assert steps * DT_S <= limits.t_brake_max_s + DT_S
    assert open_control.ramp_stop(np.array([np.nan, 1.0, 0.0]), limits, DT_S).tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("cap", [0.0, float("nan"), -1.0])
def test_a_zero_or_invalid_cap_commands_the_ramp_stop(cap: float) -> None:
    rows, task, qd_prev, q_ref = _random_problem(2)  # LP (9) has a solution
    solution = open_control.decide(
        rows, task, qd_prev, q_ref, _limits(7), DT_S, qd_prev, open_control.fixed_cap(cap), ("l",)
    )
    assert solution.how == "ramp_stop:commanded"
    assert solution.qd_radps == pytest.approx(open_control.ramp_stop(qd_prev, _limits(7), DT_S))


def test_a_solver_answer_that_breaks_a_row_is_never_sent(monkeypatch: pytest.MonkeyPatch) -> None:
    rows, task, qd_prev, q_ref = _random_problem(2)

    def lying_solve(*args: object, **kwargs: object) -> tuple[np.ndarray, float, int, dict[str, object]]:
        return np.full(8, 2.0), -1.0, 1, {}  # "optimal", far beyond the rows

    monkeypatch.setattr("gateway.open_control.daqp.solve", lying_solve)
    solution = open_control.decide(
        rows, task, qd_prev, q_ref, _limits(7), DT_S, qd_prev, open_control.fixed_cap(1.0), ("l",)
    )
    assert solution.how == "ramp_stop:lp9_breaks_a_row"


def test_rows_that_no_velocity_within_the_limits_can_reach_are_left_out_and_counted() -> None:
    jac = np.zeros((1, 3, 2))
    jac[0, 0, 0] = 1.0  # the link's ends move along x with joint 0
    p = np.zeros((1, 3))
    near, far = np.array([[0.5, 0.0, 0.0]]), np.array([[0.5, 0.0, 0.0]])
    h_a = np.concatenate((near, far))
    f = np.array([[0.05, 10.0]])  # the second capsule is far: f beyond any reach
    rows = open_control.safety_rows(jac, jac, p, p, h_a, h_a, f, np.array([0.3]), np.array([2.0, 2.0]))
    assert rows.dropped == 4
    assert rows.capsule.tolist() == [0, 0, 0, 0]
    assert rows.a_s[0] == pytest.approx([0.3 * 0.5, 0.0])


# -- a real robot ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ur5() -> tuple[Any, Any, Any]:
    config = load_cell_config(None)
    robot = load_robot_model("ur5", config.robots["ur5"])
    return config, robot, load_trajectory(config.robots["ur5"].program, robot)


@pytest.mark.parametrize(("tau_s", "hand_ahead_m"), [(0.5, 1.3), (0.5, 2.0), (2.8, 1.3), (2.8, 1.6), (4.8, 1.4)])
def test_a_ur5_in_open_mode_gets_the_delta_of_the_closed_mode(
    ur5: tuple[Any, Any, Any], tau_s: float, hand_ahead_m: float
) -> None:
    """No redundancy (6 joints, a 6-D task): LP (9) reduces to eq. (15) (paper 1, Sec. III-C) on the same inputs."""
    config, robot, trajectory = ur5
    q, qd_nominal = trajectory.sample(tau_s)
    links = link_kinematics(robot, robot.model.createData(), q, qd_nominal)
    hand = links.p_b_world[-1] + np.array([hand_ahead_m, 0.0, 0.0])
    humans = HumanCapsules(hand[None], hand[None], np.array([0.05]), ("h0",), ("hand",))
    rows = build_rows(
        links, robot.link_radius_m, robot.t_brake_link_s, float(robot.braking_time_s.max()), humans, config.safety, 0.1
    )
    closed = override_from_rows(rows)
    open_robot = OpenRobot(robot, trajectory, DT_S, config.robots["ur5"].controller.braking_time_s)
    assert active_joints(robot, open_robot.tool_frame_id).tolist() == list(range(6))
    open_robot.tau_s, open_robot.q_ref_rad, open_robot.qd_prev_radps = tau_s, q.copy(), closed * qd_nominal
    open_robot.last_mono_ns = 0  # no time passes before this decision: τ and q_ref stay where they are
    command = open_robot.command(
        q, closed * qd_nominal, 0, links, rows, humans, None, None, open_control.fixed_cap(1.0)
    )
    assert command.solution.delta == pytest.approx(closed, abs=1e-7)
    assert command.solution.qd_radps == pytest.approx(closed * qd_nominal, abs=1e-6)


def test_an_open_controller_whose_stop_outlasts_a_links_braking_time_is_refused(ur5: tuple[Any, Any, Any]) -> None:
    _, robot, trajectory = ur5
    shortest = float(robot.t_brake_link_s.min())
    OpenRobot(robot, trajectory, DT_S, shortest)  # at the limit: accepted
    with pytest.raises(ConfigError, match="braking_time_s"):
        OpenRobot(robot, trajectory, DT_S, shortest + 0.01)


def test_a_reference_beyond_a_position_limit_may_stay_or_come_back_never_go_deeper() -> None:
    limits = _limits(7)
    q_ref = np.zeros(7)
    q_ref[2] = float(limits.q_min_rad[2]) - 0.05  # crossed by a ramp stop
    q_ref[4] = float(limits.q_max_rad[4]) + 0.05
    lower, upper = open_control.velocity_bounds(np.zeros(7), q_ref, limits, DT_S)
    assert (lower <= upper).all()  # standing still is allowed: LP (9) has its stop
    assert lower[2] == 0.0  # not deeper below the lower limit
    assert upper[2] > 0.0  # and back up
    assert upper[4] == 0.0
    assert lower[4] < 0.0
    inside = np.zeros(7)
    near_lower, _ = open_control.velocity_bounds(np.zeros(7), inside + limits.q_min_rad + 1e-4, limits, DT_S)
    assert near_lower == pytest.approx(np.full(7, -1e-4 / DT_S))  # inside the range (9f) is unchanged
