"""The open robot's reference and the measured joints: a state that trails the references by the measured round trip
(a slow link) is followed, not a reason to start again; a state far from every reference of that time is."""

from __future__ import annotations

import numpy as np

from gateway.open_robot import RESYNC_RAD, OpenRobot
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
