"""Commissioning: the emulated controller's stopping times measured per joint, the profile the gateway reads.

The measurement drives the real ControllerNode on a simulated clock; these tests hold it to the controller's own
ramp (a stop from δ lasts δ · braking_time_s: the model of safety-math.md §10), show that it follows a changed
controller, and that a controller slower than the profile is refused.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest
from support.paths import REPO_ROOT

from controller_emu.commissioning import (
    DEFAULT_POSES,
    DEFAULT_SPEEDS,
    JointProfile,
    StopTrial,
    check_profile,
    commission,
    joint_profiles,
    main,
    manual_profile_path,
    measure,
    profile_text,
    run_stop_trial,
)
from hrc_contract.config import CellConfig, ConfigError, ControllerConfig
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import Trajectory, load_trajectory

MEASURED = REPO_ROOT / "configs" / "robots" / "ur5_measured.toml"


@pytest.fixture(scope="module")
def trajectory(cell_config: CellConfig, ur5: RobotModel) -> Trajectory:
    return load_trajectory(cell_config.robots["ur5"].program, ur5)


def moving_tau(trajectory: Trajectory) -> float:
    """A program time where the shoulder pan moves fast (the last move of the program, seen in the table)."""
    taus = np.linspace(0.0, trajectory.duration_s, 400, endpoint=False)
    speeds = [abs(trajectory.sample(float(t))[1][0]) for t in taus]
    return float(taus[int(np.argmax(speeds))])


@pytest.mark.parametrize("speed", [1.0 / 3.0, 2.0 / 3.0, 1.0])
def test_a_stop_lasts_override_times_braking_time(
    cell_config: CellConfig, trajectory: Trajectory, speed: float
) -> None:
    config = cell_config.robots["ur5"].controller
    trial = run_stop_trial("ur5", trajectory, config, moving_tau(trajectory), speed)
    assert trial.moving[0]
    assert trial.stop_time_s[0] == pytest.approx(speed * config.braking_time_s, abs=1e-9)
    assert trial.stop_time_s[trial.moving] == pytest.approx(speed * config.braking_time_s, abs=1e-9)
    assert (trial.stop_distance_rad[trial.moving] > 0.0).all()
    assert (trial.stop_distance_rad[~trial.moving] == 0.0).all()


def test_the_measurement_follows_the_controller(cell_config: CellConfig, trajectory: Trajectory) -> None:
    """A slower controller (0.4 s) measures slower: the figure comes from the controller, not from the config."""
    slow = cell_config.robots["ur5"].controller.model_copy(update={"braking_time_s": 0.4})
    trials = measure("ur5", trajectory, slow, DEFAULT_SPEEDS, 6)
    joints = list(cell_config.robots["ur5"].model.joints)
    profiles = joint_profiles(joints, trials, DEFAULT_SPEEDS, 0.1)
    # 0.4 / 3 s is not a whole number of 4 ms cycles: the stop is seen at the next cycle (0.136 s → 0.408 s per δ)
    assert profiles[0].stop_time_s == pytest.approx((0.136, 0.268, 0.4))
    assert profiles[0].per_override_s == pytest.approx(0.408)
    assert {p.braking_time_s for p in profiles} == {0.449}  # 0.408 · 1.1 = 0.4488, rounded up to the ms


def test_a_joint_that_never_moved_takes_the_largest_other_figure() -> None:
    moving = np.array([True, False])
    trials = [StopTrial(0.0, 0.5, moving, np.array([0.2, 0.0]), np.array([0.1, 0.0]))]
    profiles = joint_profiles(["a", "b"], trials, (0.5,), 0.0)
    assert profiles[0] == JointProfile("a", (0.2,), 0.4, 0.1, 0.4, True)
    assert (profiles[1].per_override_s, profiles[1].braking_time_s, profiles[1].measured) == (0.4, 0.4, False)
    assert math.isnan(profiles[1].stop_time_s[0])
    with pytest.raises(ConfigError, match="no joint moved"):
        joint_profiles(["a"], [StopTrial(0.0, 1.0, np.array([False]), np.zeros(1), np.zeros(1))], (1.0,), 0.1)


def test_shipped_measured_profile_is_what_the_command_writes_now() -> None:
    result = commission(None, "ur5", DEFAULT_SPEEDS, DEFAULT_POSES, 0.1)
    assert result.manual == REPO_ROOT / "configs" / "robots" / "ur5.toml"
    assert MEASURED.read_text() == result.text
    measured = tomllib.loads(MEASURED.read_text())
    manual = tomllib.loads(result.manual.read_text())
    assert measured["braking_time_s"] == [0.264] * 6  # 0.24 s measured + 10 %
    assert {k: v for k, v in measured.items() if k != "braking_time_s"} == {
        k: v for k, v in manual.items() if k != "braking_time_s"
    }


def test_a_controller_slower_than_the_profile_is_refused(cell_config: CellConfig) -> None:
    robot_config = cell_config.robots["ur5"]
    manual = manual_profile_path(None, "ur5")
    robot = check_profile(MEASURED.read_text(), manual, "ur5", robot_config)
    assert robot.t_brake_link_s.tolist() == [0.264] * 7
    slow = robot_config.model_copy(update={"controller": ControllerConfig(braking_time_s=0.3)})
    with pytest.raises(ConfigError, match=r"braking_time_s = 0.3 s is longer .* allowed: <= 0.264 s"):
        check_profile(MEASURED.read_text(), manual, "ur5", slow)


def test_profile_text_needs_a_braking_line() -> None:
    with pytest.raises(ConfigError, match="no braking_time_s"):
        profile_text('urdf = "x"\n', [], "h")


def test_command_writes_a_profile_and_refuses_bad_arguments(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "measured.toml"
    assert main(["--poses", "4", "--write", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "shoulder_pan_joint" in printed
    assert "0.264s" in printed
    assert tomllib.loads(out.read_text())["braking_time_s"] == [0.264] * 6
    assert main(["--robot", "kuka"]) == 2
    assert "robot 'kuka' is not in the cell; allowed: ur5" in capsys.readouterr().err
    assert main(["--speeds", "1.5"]) == 2
