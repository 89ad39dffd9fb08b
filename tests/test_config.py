"""Configuration loading: the default cell loads; unsafe or broken files refuse with one line naming the field."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from hrc_common.config import (
    DEFAULT_CELL_PATH,
    ISO13855_WALKING_SPEED_MPS,
    CellConfig,
    ConfigError,
    SafetyConfig,
    load_cell_config,
)
from hrc_common.robot_model import load_robot_model

CONFIGS = DEFAULT_CELL_PATH.parent
UR5_JOINTS = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]

Edit = Callable[[str], str]


def _replace(old: str, new: str) -> Edit:
    def edit(text: str) -> str:
        assert old in text, f"{old!r} not in the file: the test is out of date"
        return text.replace(old, new, 1)

    return edit


def write_cell(tmp_path: Path, cell: Edit | None = None, robot: Edit | None = None) -> Path:
    """Copies of configs/cell.toml, robots/ur5.toml and the program under tmp_path, edited; the cell's
    ``model =`` points at the edited robot copy."""
    (tmp_path / "robots").mkdir(exist_ok=True)
    (tmp_path / "programs").mkdir(exist_ok=True)
    shutil.copy(CONFIGS / "programs" / "ur5_pick_place.toml", tmp_path / "programs" / "ur5_pick_place.toml")
    robot_text = (CONFIGS / "robots" / "ur5.toml").read_text()
    (tmp_path / "robots" / "ur5_edited.toml").write_text(robot(robot_text) if robot else robot_text)
    cell_text = (CONFIGS / "cell.toml").read_text()
    cell_text = _replace('model = "robots/ur5.toml"', 'model = "robots/ur5_edited.toml"')(cell_text)
    path = tmp_path / "cell.toml"
    path.write_text(cell(cell_text) if cell else cell_text)
    return path


def load_all(path: Path) -> None:
    """What the gateway does at start-up: the cell file, then the robot model against its URDF."""
    config = load_cell_config(path)
    load_robot_model("ur5", config.robots["ur5"])


def refuse(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_all(path)
    message = str(info.value)
    assert "\n" not in message, "a ConfigError is one line"
    return message


# -- the default -------------------------------------------------------------------------------


def test_default_config_loads(cell_config: CellConfig) -> None:
    assert cell_config.cell == "demo"
    assert set(cell_config.robots) == {"ur5"}
    assert set(cell_config.trackers) == {"front", "side"}
    s = cell_config.safety
    assert (s.method, s.human_speed_mps, s.clearance_static_m, s.t_reaction_s, s.max_data_age_s) == (
        "zanchettin2016",
        1.6,
        0.05,
        0.04,
        0.2,
    )
    robot = cell_config.robots["ur5"]
    assert robot.base_pose_world.xyz == (0.0, 0.0, 0.8)
    assert list(robot.model.joints) == UR5_JOINTS
    assert robot.model.braking_time_s == [0.244, 0.530, 0.164, 0.164, 0.164, 0.164]
    assert Path(robot.model.urdf).is_absolute()
    assert Path(robot.model.urdf).is_file()
    assert Path(robot.program).is_file()
    assert Path(cell_config.scenarios_dir).is_absolute()


def test_default_robot_model_loads(ur5) -> None:
    assert ur5.joint_names == tuple(UR5_JOINTS)
    assert ur5.link_names == ("base", "shoulder", "upper_arm", "forearm", "wrist_1", "wrist_2", "tool")
    # t_b,→i: the base link moves with the pan joint only (0.244 s); every other link also with the shoulder
    np.testing.assert_allclose(ur5.t_brake_link_s, [0.244] + [0.530] * 6)
    np.testing.assert_allclose(ur5.p_world_base, [0.0, 0.0, 0.8])


def test_copied_config_loads_with_same_content(tmp_path: Path, cell_config: CellConfig) -> None:
    copy = load_cell_config(write_cell(tmp_path))
    assert copy.safety == cell_config.safety
    assert copy.robots["ur5"].model == cell_config.robots["ur5"].model
    load_robot_model("ur5", copy.robots["ur5"])


def test_sha256_is_stable_and_changes_with_content(tmp_path: Path, cell_config: CellConfig) -> None:
    digest = cell_config.sha256()
    assert len(digest) == 64
    int(digest, 16)
    assert load_cell_config(None).sha256() == digest
    changed = load_cell_config(write_cell(tmp_path, cell=_replace("t_reaction_s = 0.04", "t_reaction_s = 0.05")))
    assert changed.sha256() != digest


def test_defaults_are_the_safe_values() -> None:
    safety = SafetyConfig()
    assert safety.human_speed_mps == ISO13855_WALKING_SPEED_MPS == 1.6
    assert safety.allow_human_speed_below_iso13855 is False


# -- refusals -----------------------------------------------------------------------------------


def test_negative_braking_time(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace("[0.244, 0.530", "[-0.244, 0.530")))
    assert "braking_time_s" in message
    assert "greater than 0" in message


def test_human_speed_below_iso13855_refused_without_the_flag(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, cell=_replace("human_speed_mps = 1.6", "human_speed_mps = 1.2")))
    assert "human_speed_mps" in message
    assert "1.6" in message  # what is allowed
    assert "allow_human_speed_below_iso13855" in message


def test_human_speed_below_iso13855_accepted_with_the_flag(tmp_path: Path) -> None:
    path = write_cell(
        tmp_path,
        cell=_replace("human_speed_mps = 1.6", "human_speed_mps = 1.2\nallow_human_speed_below_iso13855 = true"),
    )
    config = load_cell_config(path)
    assert config.safety.human_speed_mps == 1.2
    assert config.safety.allow_human_speed_below_iso13855 is True


def test_close_speed_below_walking_speed_refused(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, cell=_replace("human_speed_close_mps = 2.0", "human_speed_close_mps = 1.0")))
    assert "human_speed_close_mps" in message


def test_link_frame_not_in_urdf_lists_the_frames(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace('frame_b = "tool0"', 'frame_b = "gripper_tip"')))
    assert "gripper_tip" in message
    assert "'tool'" in message  # the link
    for frame in ("shoulder_link", "wrist_3_link", "tool0", "ee_link"):
        assert frame in message  # the allowed frames are listed


def test_non_rigid_link_segment_refused(tmp_path: Path) -> None:
    # shoulder_link → wrist_1_link spans the elbow: their distance changes with the elbow angle.
    # (The brief's example shoulder_link → forearm_link is in fact rigid: the shoulder_link origin lies on the
    # shoulder_lift axis, so it is a point fixed in the upper arm too, and the code rightly accepts it.)
    robot = _replace(
        'frame_a = "upper_arm_link"\nframe_b = "forearm_link"', 'frame_a = "shoulder_link"\nframe_b = "wrist_1_link"'
    )
    message = refuse(write_cell(tmp_path, robot=robot))
    assert "'upper_arm'" in message
    assert "rigid" in message
    assert "allowed" in message


def test_segment_through_a_joint_axis_point_is_rigid(tmp_path: Path) -> None:
    robot = _replace(
        'frame_a = "upper_arm_link"\nframe_b = "forearm_link"', 'frame_a = "shoulder_link"\nframe_b = "forearm_link"'
    )
    config = load_cell_config(write_cell(tmp_path, robot=robot))
    load_robot_model("ur5", config.robots["ur5"])


def test_joint_list_with_one_joint_missing(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace(', "wrist_3_joint"]', "]")))
    assert "braking_time_s" in message
    assert "one per joint" in message


def test_joint_list_in_the_wrong_order(tmp_path: Path) -> None:
    robot = _replace('["shoulder_pan_joint", "shoulder_lift_joint"', '["shoulder_lift_joint", "shoulder_pan_joint"')
    message = refuse(write_cell(tmp_path, robot=robot))
    assert "joints" in message
    assert str(UR5_JOINTS) in message  # what is allowed, in order


def test_unknown_joint_name(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace('"wrist_3_joint"]', '"wrist_4_joint"]')))
    assert "wrist_4_joint" in message
    assert "wrist_3_joint" in message


def test_missing_cell_file(tmp_path: Path) -> None:
    message = refuse(tmp_path / "nothere.toml")
    assert "nothere.toml" in message
    assert "no such file" in message


def test_missing_robot_model_file(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, cell=_replace("robots/ur5_edited.toml", "robots/ur6.toml")))
    assert "ur6.toml" in message
    assert "no such file" in message


def test_missing_program_file(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, cell=_replace("programs/ur5_pick_place.toml", "programs/nothing.toml")))
    assert "robots.ur5.program" in message
    assert "nothing.toml" in message


def test_missing_urdf(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace("ur_description/urdf/ur5_robot.urdf", "no/robot.urdf")))
    assert "no/robot.urdf" in message
    assert "allowed" in message


def test_bad_toml(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, cell=_replace('cell = "demo"', 'cell = = "demo"')))
    assert "cell.toml" in message
    assert "not valid TOML" in message


def test_bad_robot_toml(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace("radius_m = 0.08", "radius_m = [0.08")))
    assert "ur5_edited.toml" in message
    assert "not valid TOML" in message


@pytest.mark.parametrize(
    ("old", "new", "field"),
    [
        ("clearance_static_m = 0.05", "clearance_static_m = -0.05", "safety.clearance_static_m"),
        ("t_reaction_s = 0.04", "t_reaction_s = nan", "safety.t_reaction_s"),
        ("max_data_age_s = 0.2", "max_data_age_s = 0.0", "safety.max_data_age_s"),
        ('method = "zanchettin2016"', 'method = "magic"', "safety.method"),
        ("[safety]", "[safety]\nhuman_speed = 1.6", "safety.human_speed"),  # a misspelt key is not ignored
        ("reduced_speed_below = 0.98", "reduced_speed_below = 98", "zones.reduced_speed_below"),
        ('cell = "demo"', 'cell = "Demo Cell"', "cell"),
        ("rate_hz = 250.0", "rate_hz = 1.0", "gateway.rate_hz"),
    ],
)
def test_invalid_values_name_the_field(tmp_path: Path, old: str, new: str, field: str) -> None:
    message = refuse(write_cell(tmp_path, cell=_replace(old, new)))
    assert field in message


def test_negative_link_radius(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace("radius_m = 0.08", "radius_m = -0.08")))
    assert "links.0.radius_m" in message


def test_no_trackers_refused(tmp_path: Path) -> None:
    def drop_trackers(text: str) -> str:
        return text[: text.index("[trackers.front]")]

    message = refuse(write_cell(tmp_path, cell=drop_trackers))
    assert "trackers" in message
