"""An open Panda driven by the gateway (GatewayNode: door, tracks, core, LP (9)/(13)) and a simulated open controller,
in simulated time (tests/support/open_cell.py): the program runs, every LP command keeps the rows rebuilt here with
the numpy reference, a fault commands the ramp stop, and the test switch that drops the delay breaks the rows."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from support.open_cell import OpenCell, Step, standing_person

from gateway import open_control
from gateway.reference.kinematics import link_kinematics
from gateway.reference.separation import build_rows

WALK_START_S = 1.0


def walking_person(t_s: float) -> list[dict[str, object]]:
    """A person walking from 3.5 m in front of the robot to 1.9 m (at 1 m/s), reaching 0.4 m ahead, and standing
    there: beyond the protective distance (the robot slows, it does not stop)."""
    x = max(1.9, 3.5 - max(0.0, t_s - WALK_START_S))
    return standing_person((x, 0.6), (x - 0.4, 0.4, 1.2))


def broken_rows(cell: OpenCell, step: Step, t_delay_s: float) -> np.ndarray:
    """The rows (9b) rebuilt independently (numpy reference rows, Pinocchio Jacobians) at the measured joints, with
    the people the decision saw and ``t_delay_s``; the indices the step's command breaks."""
    robot = cell.robot
    helper = cell.node.core.states[cell.name].open
    assert helper is not None
    links = link_kinematics(robot, robot.model.createData(), step.q_rad, np.zeros_like(step.q_rad))
    humans = step.people
    rows = build_rows(
        links,
        robot.link_radius_m,
        robot.t_brake_link_s,
        float(robot.braking_time_s.max()),
        humans,
        cell.config.safety,
        t_delay_s,
    )
    jac_a, jac_b = helper.link_jacobians(step.q_rad)
    safety = open_control.safety_rows(
        jac_a,
        jac_b,
        links.p_a_world,
        links.p_b_world,
        humans.h_a_world,
        humans.h_b_world,
        rows.f_m2,
        rows.horizon_s,
        helper.limits.qd_max_radps,
    )
    assert step.command is not None
    return open_control.violated_rows(safety, np.asarray(step.command.qd)[helper.active])


def test_an_open_panda_runs_its_program_at_full_speed_with_nobody_in_the_cell() -> None:
    cell = OpenCell()
    steps = cell.run(3.0)
    running = [s for s in steps if s.t_s > 0.1]
    assert all(s.decision.delta > 1.0 - 1e-6 and s.decision.zone.value == "autonomous" for s in running)
    assert {s.decision.open_command.solution.how for s in running} == {"lp13"}  # type: ignore[union-attr]
    qd_max = np.asarray(cell.robot.velocity_limit_radps)
    assert all((np.abs(np.asarray(s.command.qd)) <= qd_max + 1e-9).all() for s in running if s.command)
    # the program advances at its own pace (τ ≈ the time run) and the joints move
    assert cell.node.core.states["panda"].open.tau_s == pytest.approx(3.0, abs=0.1)  # type: ignore[union-attr]
    assert np.ptp([s.q_rad[0] for s in steps]) > 0.5


def test_a_late_decision_goes_on_from_the_reference_sent_last_without_a_ramp_stop() -> None:
    """The loop misses one decision in 37 (a late tick, 8 ms instead of 4) over a whole program cycle: the program
    goes on at full speed with LP (13). Before, the reference jumped ahead by the time lost, the program's velocity
    there lay outside the acceleration window (9d) in its decelerations and each late tick in one began a ramp stop
    (113 of 1289 decisions)."""
    cell = OpenCell()
    duration_s = cell.trajectory.duration_s + 0.2
    steps = cell.run(duration_s, held_up=lambda n: n % 37 == 36)
    cycles = math.ceil(duration_s / 0.004)
    assert len(steps) == cycles - cycles // 37  # the late ticks made no decision
    running = [s for s in steps if s.t_s > 0.1]
    assert {s.decision.open_command.solution.how for s in running} == {"lp13"}  # type: ignore[union-attr]
    assert all(s.decision.delta > 1.0 - 1e-6 for s in running)
    # the time lost slows the program by as much: τ moves one period per decision (at δ = 1)
    tau_s = cell.node.core.states["panda"].open.tau_s  # type: ignore[union-attr]
    assert tau_s == pytest.approx(len(steps) * 0.004, abs=0.03)


def test_every_command_of_the_lps_keeps_the_rows_with_the_measured_delay() -> None:
    cell = OpenCell()
    steps = cell.run(4.5, walking_person)
    checked = 0
    for step in steps[::5]:
        solution = step.decision.open_command.solution if step.decision.open_command else None
        if solution is None or not solution.how.startswith("lp"):
            continue
        assert not broken_rows(cell, step, step.decision.delay.total_s).size, step.t_s
        checked += 1
    deltas = [s.decision.delta for s in steps]
    assert checked > 100
    assert min(deltas[-100:]) < 1.0  # the person near slowed it: the rows were binding, not idle
    assert max(deltas[-100:]) > 0.0


def test_without_the_delay_the_commands_break_the_rows_that_have_it() -> None:
    """The teeth: the test switch that drops the delay (``unsafe_ignore_delay_for_tests``) lets commands through that
    break the rows built with the delay the gateway measured."""
    base = OpenCell().config
    safety = base.safety.model_copy(update={"unsafe_ignore_delay_for_tests": True})
    cell = OpenCell(base.model_copy(update={"safety": safety}))
    honest = OpenCell()
    steps = cell.run(4.5, walking_person)
    honest_steps = honest.run(4.5, walking_person)
    t_delay = max(s.decision.delay.total_s for s in honest_steps[-200:])
    broken = [
        s.t_s
        for s in steps[::5]
        if s.command is not None
        and s.decision.open_command is not None
        and s.decision.open_command.solution.how.startswith("lp")
        and broken_rows(cell, s, t_delay).size
    ]
    assert broken


def test_a_stale_joint_state_stops_the_open_robot_along_its_path_within_its_braking_time() -> None:
    cell = OpenCell()
    before = cell.run(1.2)
    assert np.abs(before[-1].qd_radps).max() > 0.2  # moving
    cell.silent_joint_states = True
    steps = cell.run(1.0)
    faulted = [s for s in steps if any(f.code == "joint_state_stale" for f in s.decision.faults)]
    assert faulted
    assert all(s.decision.open_command.solution.how.startswith("ramp_stop") for s in faulted)  # type: ignore[union-attr]
    first = next(k for k, s in enumerate(steps) if s in faulted)
    speeds = [float(np.abs(np.asarray(s.command.qd)).max()) for s in steps[first:] if s.command is not None]
    assert all(b <= a + 1e-12 for a, b in itertools.pairwise(speeds))  # never faster
    stopped_after_s = next(k for k, v in enumerate(speeds) if v == 0.0) * 0.004
    assert stopped_after_s <= float(cell.robot.braking_time_s.max()) + 0.004


def test_a_person_standing_close_to_the_path_holds_the_open_robot_in_the_safety_exception() -> None:
    cell = OpenCell()
    cell.run(1.0)
    steps = cell.run(1.5, lambda t: standing_person((0.3, 1.0)))
    assert steps[-1].decision.zone.value == "safety_exception"
    assert np.abs(steps[-1].qd_radps).max() < 1e-6
