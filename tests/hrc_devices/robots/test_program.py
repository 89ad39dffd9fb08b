"""The controller emulator's program: file format, validation, and the time-parameterised trajectory."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pinocchio as pin
import pytest

from hrc_contract.config import ConfigError
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import Trajectory, build_trajectory, load_program, load_trajectory, parse_program
from hrc_runtime.config import load_cell_config

LINK_FRAMES = ("upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link", "ee_link", "tool0")


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    config = load_cell_config(None)
    return load_robot_model("ur5", config.robots["ur5"])


@pytest.fixture(scope="module")
def program_path() -> Path:
    return Path(load_cell_config(None).robots["ur5"].program)


@pytest.fixture(scope="module")
def trajectory(robot: RobotModel, program_path: Path) -> Trajectory:
    return load_trajectory(program_path, robot)


def _waypoint(q_rad: list[float], speed: float = 1.0, accel: float = 4.0, dwell: float = 0.0) -> dict[str, Any]:
    return {"q_rad": q_rad, "max_speed_radps": speed, "max_accel_radps2": accel, "dwell_s": dwell}


def _two_point_program(**overrides: Any) -> dict[str, Any]:
    first = _waypoint([0.0, -1.5, 1.5, -1.5, -1.57, 0.0], dwell=0.2)
    second = _waypoint([0.5, -1.2, 1.2, -1.5, -1.57, 0.5])
    second.update(overrides)
    return {"waypoints": [first, second]}


def _random_program(rng: np.random.Generator, robot: RobotModel) -> dict[str, Any]:
    count = int(rng.integers(2, 6))
    waypoints = []
    for _ in range(count):
        q = rng.uniform(-3.0, 3.0, robot.n_joints).tolist()
        waypoints.append(
            _waypoint(
                q,
                speed=float(rng.uniform(0.05, 3.1)),
                accel=float(rng.uniform(0.5, 20.0)),
                dwell=float(rng.choice([0.0, rng.uniform(0.0, 0.5)])),
            )
        )
    return {"waypoints": waypoints}


def _tool_and_links_world(robot: RobotModel, q_rad: np.ndarray) -> tuple[np.ndarray, float]:
    """tool0 position in the world [m] and the lowest link frame height in the world [m]."""
    model = robot.model
    data = model.createData()
    pin.framesForwardKinematics(model, data, q_rad)
    p_world = {
        f: robot.R_world_base @ data.oMf[model.getFrameId(f)].translation + robot.p_world_base for f in LINK_FRAMES
    }
    return p_world["tool0"], float(min(p[2] for p in p_world.values()))


def _tcp_speed_mps(robot: RobotModel, q_rad: np.ndarray, qd_radps: np.ndarray) -> float:
    model = robot.model
    data = model.createData()
    pin.forwardKinematics(model, data, q_rad, qd_radps)
    pin.updateFramePlacements(model, data)
    v = pin.getFrameVelocity(model, data, model.getFrameId("tool0"), pin.LOCAL_WORLD_ALIGNED).linear
    return float(np.linalg.norm(v))


# --- known answers -------------------------------------------------------------------------------


def test_triangular_and_trapezoidal_durations(robot: RobotModel) -> None:
    # Fastest joint moves 0.5 rad. Cap 1 rad/s, 4 rad/s²: v²/a = 0.25 < 0.5, trapezoid: T = D/v + v/a = 0.75 s.
    trapezoid = build_trajectory(parse_program(_two_point_program()), robot)
    move = trapezoid.segments[1]
    assert move.duration_s == pytest.approx(0.75)
    assert move.speed_radps == pytest.approx(1.0)
    # Cap 2 rad/s: v²/a = 1 > 0.5, triangular: T = 2 sqrt(D/a) = 2 sqrt(0.125), peak a·T/2.
    triangle = build_trajectory(parse_program(_two_point_program(max_speed_radps=2.0)), robot)
    move = triangle.segments[1]
    assert move.duration_s == pytest.approx(2.0 * np.sqrt(0.125))
    assert move.speed_radps == pytest.approx(4.0 * np.sqrt(0.125))
    # Dwell 0.2 s at waypoint 0, the move in, the move back (waypoint 0's caps, same profile).
    assert trapezoid.duration_s == pytest.approx(0.2 + 0.75 + 0.75)
    np.testing.assert_allclose(trapezoid.arrival_s, [0.0, 0.2 + 0.75])


def test_all_joints_arrive_together(robot: RobotModel) -> None:
    trajectory = build_trajectory(parse_program(_two_point_program()), robot)
    move = trajectory.segments[1]
    mid_q, mid_qd = trajectory.sample(move.t_start_s + move.duration_s / 2)
    start, end = trajectory.waypoints_rad
    # Synchronised: every joint is halfway at half time, with speed in proportion to its travel.
    np.testing.assert_allclose(mid_q, (start + end) / 2, atol=1e-12)
    np.testing.assert_allclose(mid_qd, (end - start) / 0.5 * move.speed_radps, atol=1e-12)


# --- invariants of the default program and of random programs -----------------------------------


def _check_trajectory(trajectory: Trajectory, robot: RobotModel, program: dict[str, Any]) -> None:
    duration = trajectory.duration_s
    # Continuity at every phase boundary and at the wrap.
    for segment in trajectory.segments:
        for t in (segment.t_start_s, segment.t_start_s + segment.duration_s):
            before, _ = trajectory.sample(t - 1e-9)
            after, _ = trajectory.sample(t + 1e-9)
            np.testing.assert_allclose(before, after, atol=1e-7)
    np.testing.assert_allclose(trajectory.sample(0.0)[0], trajectory.sample(duration)[0], atol=1e-12)
    np.testing.assert_allclose(trajectory.sample(duration - 1e-9)[0], trajectory.waypoints_rad[0], atol=1e-7)
    np.testing.assert_allclose(trajectory.sample(-0.25)[0], trajectory.sample(duration - 0.25)[0], atol=1e-9)
    # Waypoints are reached at their arrival times.
    for index, t_arrival in enumerate(trajectory.arrival_s):
        np.testing.assert_allclose(trajectory.sample(t_arrival)[0], trajectory.waypoints_rad[index], atol=1e-9)
    # qd_nominal is dq/dt (central differences; the error is bounded by the acceleration).
    h = 1e-5
    ts = np.linspace(0.0, duration, 2001)
    for t in ts:
        q_minus, _ = trajectory.sample(t - h)
        q_plus, _ = trajectory.sample(t + h)
        _, qd = trajectory.sample(t)
        np.testing.assert_allclose((q_plus - q_minus) / (2 * h), qd, atol=50.0 * h)
    # Speed and acceleration caps of the fastest joint, URDF velocity limits of every joint.
    for segment in trajectory.segments:
        waypoint = program["waypoints"][segment.waypoint]
        local = np.linspace(0.0, segment.duration_s, 201)
        qds = np.array([trajectory.sample(segment.t_start_s + t)[1] for t in local])
        if segment.distance_rad == 0.0:
            assert np.all(qds == 0.0), "a dwell stands still"
            continue
        assert np.max(np.abs(qds)) <= waypoint["max_speed_radps"] * (1 + 1e-9)
        assert np.all(np.abs(qds) <= robot.velocity_limit_radps)
        qdds = np.diff(qds, axis=0) / np.diff(local)[:, None]
        assert np.max(np.abs(qdds)) <= waypoint["max_accel_radps2"] * (1 + 1e-6)
        # Every move starts and ends at rest.
        np.testing.assert_allclose(qds[0], 0.0, atol=1e-12)
        np.testing.assert_allclose(qds[-1], 0.0, atol=1e-12)


def test_default_program_trajectory_invariants(trajectory: Trajectory, robot: RobotModel, program_path: Path) -> None:
    program = load_program(program_path).model_dump()
    _check_trajectory(trajectory, robot, program)


@pytest.mark.parametrize("seed", range(5))
def test_random_program_trajectory_invariants(seed: int, robot: RobotModel) -> None:
    rng = np.random.default_rng(seed)
    program = _random_program(rng, robot)
    # Caps below 3.1 rad/s and positions within ±3 rad are always allowed for the UR5.
    trajectory = build_trajectory(parse_program(program), robot)
    _check_trajectory(trajectory, robot, program)


def test_dwell_stands_still_at_the_waypoint(trajectory: Trajectory) -> None:
    dwells = [s for s in trajectory.segments if s.distance_rad == 0.0]
    assert [s.duration_s for s in dwells] == [pytest.approx(0.3), pytest.approx(0.3)]
    for segment in dwells:
        for t in np.linspace(segment.t_start_s, segment.t_start_s + segment.duration_s, 7):
            q, qd = trajectory.sample(float(t))
            np.testing.assert_allclose(q, trajectory.waypoints_rad[segment.waypoint], atol=1e-9)
            assert np.all(qd == 0.0)


# --- the default program is a pick and place in front of the robot ------------------------------


def test_default_program_tool_positions(trajectory: Trajectory, robot: RobotModel, program_path: Path) -> None:
    program = load_program(program_path)
    tools = {}
    for waypoint, q in zip(program.waypoints, trajectory.waypoints_rad, strict=True):
        tool, _ = _tool_and_links_world(robot, q)
        tools[waypoint.name] = tool
    # The positions documented in the program file, to the millimetre.
    expected = {
        "pick_above": (0.45, -0.35, 1.10),
        "pick": (0.45, -0.35, 0.90),
        "pick_retreat": (0.45, -0.35, 1.10),
        "place_above": (0.60, 0.30, 1.15),
        "place": (0.60, 0.30, 0.95),
        "place_retreat": (0.60, 0.30, 1.15),
    }
    assert set(tools) == set(expected)
    for name, xyz in expected.items():
        np.testing.assert_allclose(tools[name], xyz, atol=1e-3, err_msg=name)
    # Pick on one side, place on the other; the gripper waits at both.
    dwell_at = {program.waypoints[s.waypoint].name for s in trajectory.segments if s.distance_rad == 0.0}
    assert dwell_at == {"pick", "place"}


def test_default_program_stays_in_its_work_region(trajectory: Trajectory, robot: RobotModel) -> None:
    speeds = []
    for t in np.arange(0.0, trajectory.duration_s, 0.005):
        q, qd = trajectory.sample(float(t))
        tool, z_min = _tool_and_links_world(robot, q)
        assert 0.35 <= tool[0] <= 0.7
        assert -0.4 <= tool[1] <= 0.4
        assert 0.85 <= tool[2] <= 1.3
        assert z_min > 0.8 + 0.05, "every link stays clear of the table at z = 0.8 m"
        speeds.append(_tcp_speed_mps(robot, q, qd))
    assert 1.0 <= max(speeds) <= 1.5
    assert 5.0 <= trajectory.duration_s <= 8.0


# --- errors --------------------------------------------------------------------------------------


def test_wrong_joint_count_is_refused(robot: RobotModel) -> None:
    program = {"waypoints": [_waypoint([0.0] * 5), _waypoint([0.1] * 5)]}
    with pytest.raises(ConfigError, match=r"waypoint 0 has 5 joint values; allowed: 6"):
        build_trajectory(parse_program(program), robot)


def test_mixed_joint_counts_are_refused() -> None:
    program = {"waypoints": [_waypoint([0.0] * 6), _waypoint([0.1] * 5)]}
    with pytest.raises(ConfigError, match=r"waypoint 1 has 5 joint values"):
        parse_program(program)


def test_position_outside_limits_is_refused(robot: RobotModel) -> None:
    program = _two_point_program(q_rad=[0.0, -1.2, 3.5, -1.5, -1.57, 0.5])
    with pytest.raises(ConfigError, match=r"elbow_joint = 3.5 rad is outside its limits; allowed: \[-3.1416, 3.1416\]"):
        build_trajectory(parse_program(program), robot)


def test_speed_above_urdf_limit_is_refused(robot: RobotModel) -> None:
    program = _two_point_program(max_speed_radps=4.0)
    with pytest.raises(ConfigError, match=r"above its URDF velocity limit .* allowed: max_speed_radps <= 3.150"):
        build_trajectory(parse_program(program), robot)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        ({"max_speed_radps": -1.0}, r"waypoints.1.max_speed_radps: Input should be greater than 0"),
        ({"max_accel_radps2": 0.0}, r"waypoints.1.max_accel_radps2: Input should be greater than 0"),
        ({"dwell_s": -0.1}, r"waypoints.1.dwell_s: Input should be greater than or equal to 0"),
        ({"max_speed_rad": 1.0}, r"waypoints.1.max_speed_rad: Extra inputs are not permitted"),
        ({"q_rad": [0.0, float("nan"), 0, 0, 0, 0]}, r"waypoints.1.q_rad.1"),
    ],
)
def test_invalid_waypoint_fields_are_refused(overrides: dict[str, Any], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        parse_program(_two_point_program(**overrides))


def test_unknown_top_level_field_and_single_waypoint_are_refused() -> None:
    with pytest.raises(ConfigError, match="speed_scale: Extra inputs are not permitted"):
        parse_program({**_two_point_program(), "speed_scale": 1.0})
    with pytest.raises(ConfigError, match="waypoints: List should have at least 2 items"):
        parse_program({"waypoints": _two_point_program()["waypoints"][:1]})


def test_repeated_waypoint_is_refused(robot: RobotModel) -> None:
    program = _two_point_program(q_rad=[0.0, -1.5, 1.5, -1.5, -1.57, 0.0])
    with pytest.raises(ConfigError, match="equals the waypoint before it; allowed: distinct consecutive"):
        build_trajectory(parse_program(program), robot)


def test_program_files_errors_are_one_line(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such file"):
        load_program(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[[waypoints]\n")
    with pytest.raises(ConfigError, match="not valid TOML") as info:
        load_program(bad)
    assert "\n" not in str(info.value)
    unknown = tmp_path / "unknown.toml"
    unknown.write_text("[[waypoints]]\nq_rad = [0.0]\nmax_speed_radps = 1.0\nmax_accel_radps2 = 1.0\nspeed = 2\n")
    with pytest.raises(ConfigError, match=r"unknown.toml: waypoints.0.speed: Extra inputs") as info:
        load_program(unknown)
    assert "\n" not in str(info.value)
