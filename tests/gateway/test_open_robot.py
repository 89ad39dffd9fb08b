"""The open robot's reference and the measured joints: a state that trails the references by the measured round trip
(a slow link) is followed, not a reason to start again; a state far from every reference of that time is."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from gateway.main import build_node
from gateway.open_robot import RESYNC_RAD, OpenRobot, acceleration_warning, accelerations_over_limit
from hrc_devices.robots.model import load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.config import load_cell_config

MS = 1_000_000
PERIOD_NS = 4 * MS


def panda() -> OpenRobot:
    config = load_cell_config("configs/cell_open_panda.toml")
    robot = load_robot_model("panda", config.robots["panda"])
    trajectory = load_trajectory(config.robots["panda"].program, robot)
    return OpenRobot(robot, trajectory, 0.004, config.robots["panda"].controller.braking_time_s)


def sent_along_a_sweep(open_robot: OpenRobot, n: int, radps: float) -> list[np.ndarray]:
    """``n`` references sent one period apart, the first joint sweeping at ``radps``; the reference of now is the
    last one moved on by a period."""
    q0, _ = open_robot.trajectory.sample(0.0)
    sent = []
    for k in range(n):
        q = np.array(q0, dtype=float)
        q[0] += radps * k * PERIOD_NS / 1e9
        open_robot.sent_q_rad[open_robot.sent_next] = q[open_robot.active]
        open_robot.sent_mono_ns[open_robot.sent_next] = 1_000 * MS + k * PERIOD_NS
        open_robot.sent_next = (open_robot.sent_next + 1) % len(open_robot.sent_mono_ns)
        sent.append(q)
    open_robot.q_ref_rad = sent[-1] + np.eye(len(q0))[0] * radps * PERIOD_NS / 1e9
    return sent


def test_a_state_that_trails_by_the_round_trip_is_followed() -> None:
    open_robot = panda()
    sent = sent_along_a_sweep(open_robot, 100, radps=2.0)
    now_ns = 1_000 * MS + 100 * PERIOD_NS
    shown = sent[-40]  # what the robot was at 160 ms ago: 0.32 rad behind the newest reference
    assert np.max(np.abs(open_robot.q_ref_rad - shown)) > RESYNC_RAD
    assert open_robot.followed(shown, now_ns, round_trip_s=0.2)
    assert not open_robot.followed(shown, now_ns, round_trip_s=0.05), "a short round trip does not reach that far"


def test_a_state_far_from_every_reference_of_the_round_trip_is_not_followed() -> None:
    open_robot = panda()
    sent = sent_along_a_sweep(open_robot, 100, radps=2.0)
    now_ns = 1_000 * MS + 100 * PERIOD_NS
    stopped = sent[0].copy()  # a protective stop 0.4 s ago: the robot stands where it was then
    assert not open_robot.followed(stopped, now_ns, round_trip_s=0.2)
    beside = sent[-40].copy()
    beside[1] += 2 * RESYNC_RAD  # on no reference's path
    assert not open_robot.followed(beside, now_ns, round_trip_s=10.0)


def test_the_reference_of_now_alone_is_followed_without_history() -> None:
    open_robot = panda()
    q0, _ = open_robot.trajectory.sample(0.0)
    open_robot.q_ref_rad = np.array(q0, dtype=float)
    assert open_robot.followed(np.array(q0) + 0.5 * RESYNC_RAD, 5_000 * MS, round_trip_s=0.2)
    assert not open_robot.followed(np.array(q0) + 2.0 * RESYNC_RAD, 5_000 * MS, round_trip_s=0.2)


def test_a_program_accelerating_faster_than_the_open_controllers_qdd_max_is_named_per_move() -> None:
    """The pick and place accelerates panda_joint1 at 5 rad/s² (waypoints' max_accel_radps2) in two moves, above the
    open Panda's q̇max / braking time = 2.175 / 0.5 = 4.35 rad/s²: both moves are named; at a limit exactly that
    acceleration none is, just below it both are."""
    open_robot = panda()
    over = open_robot.accelerations_over_limit
    assert [(o.joint, o.waypoint) for o in over] == [("panda_joint1", 3), ("panda_joint1", 0)]
    assert [o.accel_radps2 for o in over] == pytest.approx([5.0, 5.0])
    assert [o.limit_radps2 for o in over] == pytest.approx([4.35, 4.35])
    joint_names = open_robot.robot.joint_names
    exact = np.full(open_robot.active.size, 5.0)
    assert accelerations_over_limit(open_robot.trajectory, joint_names, open_robot.active, exact) == []
    assert len(accelerations_over_limit(open_robot.trajectory, joint_names, open_robot.active, exact - 1e-6)) == 2


def test_a_program_within_qdd_max_has_no_move_over_it_and_no_warning() -> None:
    config = load_cell_config("configs/cell_open_panda.toml")
    robot = load_robot_model("panda", config.robots["panda"])
    trajectory = load_trajectory("configs/programs/panda_elbow_out.toml", robot)
    open_robot = OpenRobot(robot, trajectory, 0.004, config.robots["panda"].controller.braking_time_s)
    assert open_robot.accelerations_over_limit == []
    assert acceleration_warning("panda", open_robot.accelerations_over_limit) is None


def test_the_gateway_warns_at_start_up_of_an_open_robots_program_it_cannot_follow_at_full_speed(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The operator reads which moves, which joint and the limit, once at start-up (a closed robot: no such line)."""
    with caplog.at_level(logging.WARNING, logger="hrc-gateway"):
        build_node(load_cell_config("configs/cell_open_panda.toml"), None)
    lines = [r.getMessage() for r in caplog.records if "q̈max" in r.getMessage()]
    assert len(lines) == 1
    assert "robot 'panda': 2 move(s)" in lines[0]
    assert "panda_joint1 at 5.00 rad/s² against 4.35 rad/s²" in lines[0]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="hrc-gateway"):
        build_node(load_cell_config("configs/cell.toml"), None)
    assert not [r for r in caplog.records if "q̈max" in r.getMessage()]
