"""Configuration loading: the default cell loads; unsafe or broken files refuse with one line naming the field."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError
from support.cell_files import Edit, replace_once, write_cell
from support.paths import DEFAULT_CELL_PATH, REPO_ROOT

from hrc_contract.config import (
    ISO13855_WALKING_SPEED_MPS,
    UNSAFE_ENV_VAR,
    CellConfig,
    ConfigError,
    ControllerConfig,
    PlausibilityConfig,
    SafetyConfig,
    StreamsConfig,
    TrackingConfig,
    ZonesConfig,
    unsafe_allowed,
)
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.config import load_cell_config, one_line
from hrc_tools.sim.scenarios import generate_case
from hrc_tools.sim.sweep import CellVariant
from hrc_tools.sim.sweep import cli as sweep_cli
from tracker_emu.scenario import Scenario, humans_at, load_scenario

CONFIGS = DEFAULT_CELL_PATH.parent
UR5_JOINTS = [
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
]

_replace = replace_once  # the edits below read as before


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
    assert "braking_time_s.0: Input should be greater than or equal to 0.02 (given -0.244)" in message


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
        ("latency_s = 0.03", "latency_s = 1e9", "trackers.front.latency_s"),  # a frame held for ever, and each after
    ],
)
def test_invalid_values_name_the_field(tmp_path: Path, old: str, new: str, field: str) -> None:
    message = refuse(write_cell(tmp_path, cell=_replace(old, new)))
    assert field in message


@pytest.mark.parametrize(
    ("noise_std_m", "margin_m", "accepted"),
    [
        (0.0666, 0.1, True),  # 0.1 + 6 × 0.0666 = 0.4996 m
        (0.0667, 0.1, False),  # 0.5002 m: the margin's cap, loosened by the noise alone
        (0.0, 0.5, True),
        (0.001, 0.5, False),  # the margin at its cap: any noise breaks it
        (1e9, 0.0, False),
    ],
)
def test_a_trackers_noise_cannot_loosen_the_match_beyond_its_cap(
    tmp_path: Path, noise_std_m: float, margin_m: float, accepted: bool
) -> None:
    """The tracks match a detection within association_margin_m + 3σ + 3σ (gateway/tracks.py): the noise a cell file
    states for a tracker counts against the same 0.5 m cap as the margin, else one large noise_std_m would let one
    person's detection release another's track."""

    def edit(text: str) -> str:
        text = replace_once("noise_std_m = 0.01\n", "noise_std_m = 0.0\n")(text)  # the side tracker the noisiest
        text = replace_once("noise_std_m = 0.015", f"noise_std_m = {noise_std_m}")(text)
        return f"{text}\n[tracking]\nassociation_margin_m = {margin_m}\n"

    path = write_cell(tmp_path, cell=edit)
    if accepted:
        assert load_cell_config(path).trackers["side"].noise_std_m == noise_std_m
        return
    message = refuse(path)
    assert "trackers.side.noise_std_m" in message
    assert "association_margin_m + 6 × noise_std_m <= 0.5 m" in message


@pytest.mark.parametrize(
    ("base_x_m", "tracking", "refused_with"),
    [
        (5.2, "", "within tracking.exit_band_m = 0.4 m of the covered volume's x face"),  # 0.3 m from +x: in the band
        (-5.2, "", "within tracking.exit_band_m = 0.4 m"),
        (6.0, "", "outside the trackers' covered volume"),
        (5.05, "", None),  # 0.45 m from the face: beyond the band
        (5.0, "exit_band_m = 0.6", "within tracking.exit_band_m = 0.6 m"),  # 0.5 m from +x
        # doors on the -x face only: a robot in the +x band is not where anyone leaves
        (5.2, "exit_zones = [{ min_m = [-6.0, -1.0, -0.2], max_m = [-5.0, 1.0, 2.6] }]", None),
        (-5.2, "exit_zones = [{ min_m = [-6.0, -1.0, -0.2], max_m = [-5.0, 1.0, 2.6] }]", "of the covered volume's x"),
    ],
)
def test_a_robot_stands_inside_the_covered_volume_away_from_where_people_leave(
    tmp_path: Path, base_x_m: float, tracking: str, refused_with: str | None
) -> None:
    """The exit rule releases a lost person whose every capsule lay in the exit band, moving out: a robot standing
    there would have people lost beside it released as 'left'; a robot outside the covered volume has nobody seen."""

    def edit(text: str) -> str:
        text = replace_once("xyz = [0.0, 0.0, 0.8]", f"xyz = [{base_x_m}, 0.0, 0.8]")(text)
        return f"{text}\n[tracking]\n{tracking}\n"

    path = write_cell(tmp_path, cell=edit)
    if refused_with is None:
        assert load_cell_config(path).robots["ur5"].base_pose_world.xyz[0] == base_x_m
        return
    message = refuse(path)
    assert "robots.ur5.base_pose_world" in message
    assert refused_with in message


@pytest.mark.parametrize("speed_mps", [0.0, 0.05])
def test_standing_in_the_exit_band_is_not_leaving(tmp_path: Path, speed_mps: float) -> None:
    """With exit_speed_min_mps at 0, a lost person standing in the exit band (or stepping in) would count as having
    left: the cell file is refused, naming the field."""
    message = refuse(write_cell(tmp_path, cell=lambda text: f"{text}\n[tracking]\nexit_speed_min_mps = {speed_mps}\n"))
    assert "tracking.exit_speed_min_mps" in message
    assert TrackingConfig(exit_speed_min_mps=0.1).exit_speed_min_mps == 0.1


def test_negative_link_radius(tmp_path: Path) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace("radius_m = 0.08", "radius_m = -0.08")))
    assert "links.0.radius_m" in message


def test_no_trackers_refused(tmp_path: Path) -> None:
    def drop_trackers(text: str) -> str:
        return text[: text.index("[trackers.front]")]

    message = refuse(write_cell(tmp_path, cell=drop_trackers))
    assert "trackers" in message


# -- bounds on time limits and braking times ----------------------------------------------------------------


def _set(section: str, key: str, value: str) -> Edit:
    """``key = value`` in ``[section]`` of the cell file: the key's line replaced, or the line added."""

    def edit(text: str) -> str:
        header = re.search(rf"(?m)^\[{re.escape(section)}\].*\n", text)
        assert header, f"[{section}] not in the file: the test is out of date"
        start = header.end()
        end = text.find("\n[", start)
        end = len(text) if end < 0 else end + 1
        body, n = re.subn(rf"(?m)^{key} = .*$", f"{key} = {value}", text[start:end])
        if n == 0:
            body = f"{key} = {value}\n" + body
        return text[:start] + body + text[end:]

    return edit


def _field(config: CellConfig, section: str, key: str) -> object:
    node: object = config
    for part in [*section.split("."), key]:
        node = node[part] if isinstance(node, dict) else getattr(node, part)
    return node


BOUNDS = [
    # section, key, refused, accepted at the bound, what the message says is allowed
    ("safety", "t_reaction_s", "1.5", "1.0", "less than or equal to 1"),
    ("safety", "t_reaction_s", "-0.01", "0.0", "greater than or equal to 0"),
    ("safety", "max_data_age_s", "3600.0", "1.0", "less than or equal to 1"),
    ("safety", "iso15066_joint_acceleration_limit_radps2", "573.0", "100.0", "less than or equal to 100"),
    ("zones", "adaptive_speed_hold_s", "2000.0", "60.0", "less than or equal to 60"),
    ("robots.ur5.controller", "braking_time_s", "1e-9", "0.02", "greater than or equal to 0.02"),
    ("robots.ur5.controller", "braking_time_s", "240.0", "5.0", "less than or equal to 5"),
    ("robots.ur5.controller", "accel_time_s", "1e-9", "0.02", "greater than or equal to 0.02"),
    ("robots.ur5.controller", "accel_time_s", "500.0", "10.0", "less than or equal to 10"),
    ("robots.ur5.controller", "watchdog_s", "3600.0", "1.0", "less than or equal to 1"),
    ("plausibility", "max_capsule_length_m", "3.0", "2.5", "less than or equal to 2.5"),
    ("plausibility", "max_capsule_length_m", "0.0", "0.01", "greater than 0"),
    ("plausibility", "max_capsule_radius_m", "1.5", "1.0", "less than or equal to 1"),
    ("plausibility", "max_capsule_radius_m", "-0.1", "0.01", "greater than 0"),
    ("streams", "max_future_stamp_s", "0.06", "0.05", "less than or equal to 0.05"),
    ("streams", "max_future_stamp_s", "-0.001", "0.0", "greater than or equal to 0"),
    ("streams", "fault_hold_s", "0.05", "0.1", "greater than or equal to 0.1"),
    ("streams", "fault_hold_s", "3600.0", "10.0", "less than or equal to 10"),
    ("streams", "max_clock_step_s", "0.0005", "0.001", "greater than or equal to 0.001"),
    ("streams", "max_clock_step_s", "0.06", "0.05", "less than or equal to 0.05"),
    ("streams", "qd_tolerance_radps", "0.2", "0.1", "less than or equal to 0.1"),
    ("streams", "qd_tolerance_radps", "-0.01", "0.0", "greater than or equal to 0"),
    ("streams", "qd_tolerance_ratio", "0.2", "0.1", "less than or equal to 0.1"),
    ("streams", "override_tolerance", "0.03", "0.02", "less than or equal to 0.02"),
]


@pytest.mark.parametrize(("section", "key", "refused", "at_bound", "allowed"), BOUNDS)
def test_bound_refuses_beyond_and_accepts_at_it(
    tmp_path: Path, section: str, key: str, refused: str, at_bound: str, allowed: str
) -> None:
    message = refuse(write_cell(tmp_path, cell=_set(section, key, refused)))
    assert f"{section}.{key}: " in message  # the field
    assert f"(given {float(refused)!r})" in message  # what was given
    assert allowed in message  # what is allowed
    config = load_cell_config(write_cell(tmp_path, cell=_set(section, key, at_bound)))
    assert _field(config, section, key) == float(at_bound)


@pytest.mark.parametrize(
    ("refused", "at_bound", "allowed"),
    [("1e-9", "0.02", "greater than or equal to 0.02"), ("530.0", "5.0", "less than or equal to 5")],
)
def test_joint_braking_time_bounds(tmp_path: Path, refused: str, at_bound: str, allowed: str) -> None:
    message = refuse(write_cell(tmp_path, robot=_replace("[0.244, 0.530", f"[0.244, {refused}")))
    assert f"robots.ur5.model.braking_time_s.1: Input should be {allowed} (given {float(refused)!r})" in message
    config = load_cell_config(write_cell(tmp_path, robot=_replace("[0.244, 0.530", f"[0.244, {at_bound}")))
    robot = load_robot_model("ur5", config.robots["ur5"])
    assert robot.braking_time_s[1] == float(at_bound)


def test_every_time_limit_that_guards_safety_has_an_upper_bound() -> None:
    """A field in seconds that limits data age, silence or reaction must have an upper bound (a new one too)."""
    guarded = {
        (SafetyConfig, "t_reaction_s"),
        (SafetyConfig, "max_data_age_s"),
        (ZonesConfig, "adaptive_speed_hold_s"),
        (ControllerConfig, "watchdog_s"),
        (ControllerConfig, "braking_time_s"),
        (ControllerConfig, "accel_time_s"),
        (StreamsConfig, "max_future_stamp_s"),
        (StreamsConfig, "fault_hold_s"),
        (StreamsConfig, "max_clock_step_s"),
    }
    for model, name in guarded:
        limits = [m for m in model.model_fields[name].metadata if hasattr(m, "le") or hasattr(m, "lt")]
        assert limits, f"{model.__name__}.{name} has no upper bound"
        description = model.model_fields[name].description or ""
        assert "At most" in description or "–" in description, f"{model.__name__}.{name}: the bound is not explained"


# -- the test-only setting needs the environment to name it --------------------------------------------------


UNSAFE_LINE = "[safety]\nunsafe_ignore_delay_for_tests = true\n"


def test_unsafe_setting_refused_without_the_environment_variable(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(UNSAFE_ENV_VAR, raising=False)
    message = refuse(write_cell(tmp_path, cell=_replace("[safety]\n", UNSAFE_LINE)))
    assert "safety.unsafe_ignore_delay_for_tests: true is refused" in message
    assert "allowed: false, or true with the environment variable HRC_ALLOW_UNSAFE=unsafe_ignore_delay_for_tests" in (
        message
    )


@pytest.mark.parametrize("value", ["", "unsafe", "unsafe_ignore_delay", "something_else,unsafe_ignore_delay_for_test"])
def test_unsafe_setting_refused_when_the_variable_names_something_else(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, value: str
) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, value)
    assert "HRC_ALLOW_UNSAFE" in refuse(write_cell(tmp_path, cell=_replace("[safety]\n", UNSAFE_LINE)))


@pytest.mark.parametrize("value", ["unsafe_ignore_delay_for_tests", "other, unsafe_ignore_delay_for_tests"])
def test_unsafe_setting_accepted_when_the_variable_names_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, value: str
) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, value)
    config = load_cell_config(write_cell(tmp_path, cell=_replace("[safety]\n", UNSAFE_LINE)))
    assert config.safety.unsafe_ignore_delay_for_tests is True


def test_unsafe_allowed_reads_a_comma_separated_list() -> None:
    assert UNSAFE_ENV_VAR == "HRC_ALLOW_UNSAFE"
    assert unsafe_allowed("a", {UNSAFE_ENV_VAR: "a"})
    assert unsafe_allowed("a", {UNSAFE_ENV_VAR: "b, a ,c"})
    assert not unsafe_allowed("a", {UNSAFE_ENV_VAR: "ab"})
    assert not unsafe_allowed("a", {})


def test_unsafe_setting_refused_on_every_validation_path(
    cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Not only the TOML loader: the model itself, and the sweep's cell variant (re-validated dumps)."""
    monkeypatch.delenv(UNSAFE_ENV_VAR, raising=False)
    with pytest.raises(ValidationError, match="HRC_ALLOW_UNSAFE=unsafe_ignore_delay_for_tests"):
        SafetyConfig(unsafe_ignore_delay_for_tests=True)
    with pytest.raises(ValidationError, match="HRC_ALLOW_UNSAFE=unsafe_ignore_delay_for_tests"):
        CellVariant(unsafe_ignore_delay=True).apply(cell_config)
    assert SafetyConfig(unsafe_ignore_delay_for_tests=False).unsafe_ignore_delay_for_tests is False


def test_sweep_refuses_the_unsafe_flag_without_the_variable(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.delenv(UNSAFE_ENV_VAR, raising=False)
    with pytest.raises(SystemExit) as exit_info:
        sweep_cli(["--scenarios", "1", "--workers", "1", "--unsafe-ignore-delay", "--quiet"])
    assert exit_info.value.code == 2
    assert "HRC_ALLOW_UNSAFE=unsafe_ignore_delay_for_tests" in capsys.readouterr().err


def test_gateway_exits_2_on_the_unsafe_setting_without_the_variable(tmp_path: Path) -> None:
    path = write_cell(tmp_path, cell=_replace("[safety]\n", UNSAFE_LINE))
    env = {k: v for k, v in os.environ.items() if k != UNSAFE_ENV_VAR}
    result = subprocess.run(
        [sys.executable, "-m", "gateway", "--config", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        env=env,
        cwd=REPO_ROOT,
        check=False,
    )
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "safety.unsafe_ignore_delay_for_tests" in lines[0]
    assert "HRC_ALLOW_UNSAFE=unsafe_ignore_delay_for_tests" in lines[0]


# -- plausibility and streams -----------------------------------------------------------------------------


def test_new_sections_default_to_the_shipped_file(cell_config: CellConfig) -> None:
    assert cell_config.plausibility == PlausibilityConfig()
    assert cell_config.streams == StreamsConfig()
    p, s = cell_config.plausibility, cell_config.streams
    assert (p.world_min_m, p.world_max_m) == ((-7.0, -7.0, -0.2), (7.0, 7.0, 2.6))
    assert (p.max_capsule_length_m, p.max_capsule_radius_m) == (1.0, 0.35)
    assert (s.max_future_stamp_s, s.fault_hold_s, s.max_clock_step_s) == (0.005, 0.5, 0.02)
    assert (s.qd_tolerance_radps, s.qd_tolerance_ratio, s.override_tolerance) == (0.01, 0.02, 0.001)


def test_new_sections_are_in_the_effective_config(cell_config: CellConfig) -> None:
    from gateway.status import effective_config

    published = json.loads(effective_config(cell_config).model_dump_json())
    assert published["plausibility"] == cell_config.plausibility.model_dump(mode="json")
    assert published["streams"] == cell_config.streams.model_dump(mode="json")


@pytest.mark.parametrize(
    ("world_min", "world_max", "message"),
    [
        ("[-7.0, 7.0, -0.2]", "[7.0, 7.0, 2.6]", "world_min_m y = 7.0 is not below world_max_m y = 7.0; allowed: "),
        ("[-7.0, -7.0, 3.0]", "[7.0, 7.0, 2.6]", "world_min_m z = 3.0 is not below world_max_m z = 2.6; allowed"),
        ("[-60.0, -7.0, -0.2]", "[50.0, 7.0, 2.6]", "110.0 m wide along x; allowed: at most 100.0 m"),
        ("[-7.0, -7.0, nan]", "[7.0, 7.0, 2.6]", "plausibility.world_min_m.2: Input should be a finite number"),
        ("[-7.0, -7.0]", "[7.0, 7.0, 2.6]", "plausibility.world_min_m"),
    ],
)
def test_world_volume_refused(tmp_path: Path, world_min: str, world_max: str, message: str) -> None:
    edit = _set("plausibility", "world_min_m", world_min)
    path = write_cell(tmp_path, cell=lambda text: _set("plausibility", "world_max_m", world_max)(edit(text)))
    assert message in refuse(path)


def test_world_volume_at_the_width_limit_accepted(tmp_path: Path) -> None:
    edit = _set("plausibility", "world_min_m", "[-50.0, -7.0, -0.2]")
    path = write_cell(tmp_path, cell=lambda text: _set("plausibility", "world_max_m", "[50.0, 7.0, 2.6]")(edit(text)))
    assert load_cell_config(path).plausibility.world_min_m == (-50.0, -7.0, -0.2)


def test_misspelt_key_in_a_new_section_refused(tmp_path: Path) -> None:
    assert "streams.fault_hold: Extra inputs are not permitted" in refuse(
        write_cell(tmp_path, cell=_set("streams", "fault_hold", "0.5"))
    )


NOISE_MARGIN_M = 0.2
"""Room left for sensor noise around the true capsules: > 6 σ of the noisiest sensor the sweep draws (0.03 m)."""


def _assert_capsules_fit(scenario: Scenario, p: PlausibilityConfig, step_s: float) -> int:
    lo = np.asarray(p.world_min_m) + NOISE_MARGIN_M
    hi = np.asarray(p.world_max_m) - NOISE_MARGIN_M
    seen = 0
    for t_s in np.arange(0.0, scenario.duration_s + 1e-9, step_s):
        for human in humans_at(scenario, float(t_s)):
            for c in human.capsules:
                for point in (c.a, c.b):
                    assert np.all((point >= lo) & (point <= hi)), (scenario.description, t_s, c.name, point)
                assert np.linalg.norm(c.b - c.a) <= p.max_capsule_length_m - 2 * NOISE_MARGIN_M, (c.name, t_s)
                assert c.radius_m <= p.max_capsule_radius_m - NOISE_MARGIN_M / 2, c.name
                seen += 1
    return seen


def test_shipped_scenarios_fit_the_default_world(cell_config: CellConfig) -> None:
    files = sorted(Path(cell_config.scenarios_dir).glob("*.toml"))
    assert len(files) >= 4
    for path in files:
        assert _assert_capsules_fit(load_scenario(path), cell_config.plausibility, 0.05) > 0, path


def test_sweep_people_fit_the_default_world(cell_config: CellConfig) -> None:
    """The sweep's people reach 5.1 m from the base (approach from ≤ 5 m, cross ≤ 3 m off and ± 4 m along)."""
    seen = 0
    for index in range(40):
        case = generate_case(0, index, 10.0, cell_config.safety.max_data_age_s)
        seen += _assert_capsules_fit(case.scenario, cell_config.plausibility, 0.1)
    assert seen > 10_000


def test_range_errors_quote_the_given_value() -> None:
    try:
        ControllerConfig(watchdog_s=3600.0)
    except ValidationError as exc:
        line = one_line(exc, "cell.toml")
    else:
        pytest.fail("a watchdog of an hour was accepted")
    assert line == "cell.toml: watchdog_s: Input should be less than or equal to 1 (given 3600.0)"
