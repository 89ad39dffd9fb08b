"""Scenario files: parsing, validation, presence, interpolation, looping and the story each one tells."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from support.paths import REPO_ROOT

from hrc_contract.config import ConfigError, TrackingConfig
from tracker_emu.body import BodyCapsule
from tracker_emu.scenario import (
    HumanScript,
    Keyframe,
    Scenario,
    TrackedHuman,
    available_scenarios,
    humans_at,
    load_scenario,
    pose_at,
    scenario_path,
)
from tracker_emu.sensor import centre_m, covered_volume, inside

SCENARIOS_DIR = REPO_ROOT / "configs" / "scenarios"
ROBOT_TOOL_AREA_CENTRE_WORLD = np.array([0.0, 0.0, 1.1])


def scenario(name: str) -> Scenario:
    return load_scenario(scenario_path(SCENARIOS_DIR, name))


def capsule(human: TrackedHuman, name: str) -> BodyCapsule:
    return next(c for c in human.capsules if c.name == name)


def position_x_m(human: TrackedHuman) -> float:
    """x of the body's floor position (midway between the ankles) [m]."""
    return float((capsule(human, "shin_l").b[0] + capsule(human, "shin_r").b[0]) / 2)


def nearest_x_m(humans: list[TrackedHuman]) -> float:
    """Smallest x of any capsule surface (the robot is at x = 0, humans come from +x) [m]."""
    return min(float(min(c.a[0], c.b[0])) - c.radius_m for h in humans for c in h.capsules)


def two_keyframe_scenario(**human: object) -> Scenario:
    keyframes = [
        Keyframe(t_s=2.0, xy_m=(4.0, 0.0), heading_rad=3.0, reach=0.0),
        Keyframe(t_s=6.0, xy_m=(2.0, 1.0), heading_rad=-3.0, reach=1.0),
    ]
    return Scenario(
        description="test",
        duration_s=10.0,
        loop=True,
        humans=[HumanScript.model_validate({"id": "h1", "keyframes": keyframes, **human})],
    )


def test_the_required_scenarios_exist() -> None:
    names = available_scenarios(SCENARIOS_DIR)
    assert {"walk_in_reach_leave", "two_people", "standing_inside", "fast_approach"} <= set(names)


@pytest.mark.parametrize("path", sorted(SCENARIOS_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_every_scenario_file_parses(path: Path) -> None:
    s = load_scenario(path)
    assert s.duration_s > 0
    assert s.description
    for human in s.humans:
        assert 0.0 <= human.start_s < human.end_s <= s.duration_s


def test_the_default_scenario_of_the_cell_exists() -> None:
    from hrc_runtime.config import load_cell_config

    config = load_cell_config(None)
    assert scenario_path(config.scenarios_dir, config.default_scenario).is_file()


def test_presence_window_is_first_to_last_keyframe() -> None:
    s = two_keyframe_scenario()
    assert humans_at(s, 1.99) == []
    assert [h.id for h in humans_at(s, 2.0)] == ["h1"]
    assert [h.id for h in humans_at(s, 6.0)] == ["h1"]
    assert humans_at(s, 6.01) == []


def test_pose_is_interpolated_midway() -> None:
    s = two_keyframe_scenario()
    pose = pose_at(s.humans[0], 4.0)
    assert pose is not None
    assert (pose.x_m, pose.y_m) == pytest.approx((3.0, 0.5))
    assert pose.reach == pytest.approx(0.5)
    # 3.0 → -3.0 rad the short way round passes through π, not through 0.
    assert abs(pose.heading_rad) == pytest.approx(math.pi)
    quarter = pose_at(s.humans[0], 3.0)
    assert quarter is not None
    assert quarter.heading_rad == pytest.approx(3.0 + (2 * math.pi - 6.0) / 4)


def test_pose_at_keyframes_is_the_keyframe() -> None:
    s = scenario("walk_in_reach_leave")
    for k in s.humans[0].keyframes:
        pose = pose_at(s.humans[0], k.t_s)
        assert pose is not None
        assert (pose.x_m, pose.y_m, pose.reach) == pytest.approx((*k.xy_m, k.reach))
        assert math.cos(pose.heading_rad - k.heading_rad) == pytest.approx(1.0)


def test_both_arms_is_passed_to_the_body() -> None:
    (one_arm,) = humans_at(two_keyframe_scenario(), 6.0)
    (both,) = humans_at(two_keyframe_scenario(both_arms=True), 6.0)
    np.testing.assert_allclose(capsule(both, "hand_r").b, capsule(one_arm, "hand_r").b)
    assert np.linalg.norm(capsule(both, "hand_l").b - capsule(one_arm, "hand_l").b) > 0.4


def test_looping_wraps_the_time() -> None:
    s = two_keyframe_scenario()
    for t_s in (4.0, 2.5, 8.0):
        expected = humans_at(s, t_s)
        for later in (t_s + 10.0, t_s + 30.0):
            got = humans_at(s, later)
            assert [h.id for h in got] == [h.id for h in expected]
            for h_got, h_exp in zip(got, expected, strict=True):
                for c_got, c_exp in zip(h_got.capsules, h_exp.capsules, strict=True):
                    np.testing.assert_allclose(c_got.a, c_exp.a, atol=1e-9)


def test_without_loop_nobody_after_the_end() -> None:
    s = two_keyframe_scenario().model_copy(update={"loop": False})
    assert humans_at(s, 14.0) == []
    assert humans_at(s, 4.0) != []


def test_walk_in_reach_leave_tells_its_story() -> None:
    s = scenario("walk_in_reach_leave")
    assert s.loop
    assert 25.0 <= s.duration_s <= 35.0
    assert humans_at(s, 1.0) == []  # nobody
    (far,) = humans_at(s, 4.0)  # someone far away
    assert far.id == "h1"
    assert nearest_x_m([far]) > 3.5
    approach = [position_x_m(humans_at(s, t)[0]) for t in np.arange(3.2, 6.8, 0.2)]
    assert np.all(np.diff(approach) < 0)  # approaching
    speeds = -np.diff(approach) / 0.2
    assert np.all((speeds > 1.0) & (speeds < 1.4))
    (standing,) = humans_at(s, 8.0)
    assert position_x_m(standing) == pytest.approx(1.45, abs=0.05)
    hand_during_reach = [capsule(humans_at(s, t)[0], "hand_r") for t in np.arange(10.0, 12.4, 0.2)]
    for hand in hand_during_reach:  # very close: the hand in the robot's working area
        assert hand.b[0] < 0.8
        assert 0.95 <= hand.b[2] <= 1.25
        assert np.linalg.norm(hand.b - ROBOT_TOOL_AREA_CENTRE_WORLD) < 0.8
    leaving = [position_x_m(humans_at(s, t)[0]) for t in np.arange(15.4, 19.0, 0.2)]
    assert np.all(np.diff(leaving) > 0)  # leaving
    last_seen_s = max(h.end_s for h in s.humans)
    assert s.duration_s - last_seen_s >= 5.0  # nobody for at least 5 s before the restart
    assert humans_at(s, s.duration_s - 0.1) == []
    assert humans_at(s, s.duration_s + 1.0) == []  # the restart begins with nobody again


def test_two_people_one_reaches_one_crosses() -> None:
    s = scenario("two_people")
    assert len(s.humans) == 2
    seen_both = [t for t in np.arange(0.0, s.duration_s, 0.1) if len(humans_at(s, t)) == 2]
    assert seen_both
    reaching = [
        t for t in np.arange(0.0, s.duration_s, 0.1) if any(capsule(h, "hand_r").b[0] < 0.8 for h in humans_at(s, t))
    ]
    assert reaching
    crosser = next(h for h in s.humans if abs(h.keyframes[-1].xy_m[1] - h.keyframes[0].xy_m[1]) > 4.0)
    for k in crosser.keyframes:
        assert 2.5 <= k.xy_m[0] <= 3.0
    assert s.duration_s - max(h.end_s for h in s.humans) >= 4.0
    assert humans_at(s, s.duration_s - 0.1) == []


def test_standing_inside_is_always_there_and_still() -> None:
    s = scenario("standing_inside")
    assert s.loop
    assert s.duration_s == pytest.approx(30.0)
    for t_s in np.arange(0.0, 61.0, 0.5):
        (human,) = humans_at(s, t_s)
        pelvis = capsule(human, "pelvis")
        assert (pelvis.a[:2] + pelvis.b[:2]) / 2 == pytest.approx([2.0, 0.5], abs=0.01)


def test_fast_approach_walks_at_about_1_8_mps() -> None:
    s = scenario("fast_approach")
    (human,) = s.humans
    k0, k1 = human.keyframes[0], human.keyframes[1]
    assert k0.xy_m[0] == pytest.approx(6.0)
    assert k1.xy_m[0] == pytest.approx(1.2, abs=0.1)
    assert math.dist(k0.xy_m, k1.xy_m) / (k1.t_s - k0.t_s) == pytest.approx(1.8, abs=0.1)
    assert max(k.reach for k in human.keyframes) > 0.9
    assert s.duration_s - human.end_s >= 4.0


GOOD_HUMAN = """
[[humans]]
id = "h1"
[[humans.keyframes]]
t_s = 1.0
xy_m = [5.0, 0.0]
heading_rad = 3.14
[[humans.keyframes]]
t_s = 3.0
xy_m = [3.0, 0.0]
heading_rad = 3.14
"""


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "s.toml"
    path.write_text('description = "x"\nduration_s = 10.0\nloop = true\n' + text)
    return path


def test_a_valid_file_in_the_test_folder_loads(tmp_path: Path) -> None:
    s = load_scenario(write(tmp_path, GOOD_HUMAN))
    assert s.humans[0].keyframes[1].xy_m == (3.0, 0.0)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (GOOD_HUMAN.replace("t_s = 3.0", "t_s = 0.5"), "strictly increasing"),
        (GOOD_HUMAN.replace("t_s = 3.0", "t_s = 1.0"), "strictly increasing"),
        (GOOD_HUMAN.replace("xy_m = [3.0, 0.0]", "xy_m = [-5.0, 0.0]"), r"5\.00 m/s; allowed: <= 3\.0 m/s"),
        (GOOD_HUMAN.replace('id = "h1"', 'id = "h1"\ncolor = "red"'), "color: Extra inputs are not permitted"),
        (
            GOOD_HUMAN.replace("heading_rad = 3.14\n[", "heading_rad = 3.14\nreach = 2\n["),
            "reach: .*less than or equal to 1",
        ),
        (GOOD_HUMAN.replace("t_s = 3.0", "t_s = 12.0"), "after duration_s = 10.0"),
        (GOOD_HUMAN.replace("t_s = 1.0", "t_s = -1.0"), "t_s: .*greater than or equal to 0"),
        (GOOD_HUMAN + GOOD_HUMAN, r"human ids \['h1'\] appear more than once"),
        ("", None),
    ],
)
def test_invalid_scenario_files_are_rejected_with_a_readable_message(
    tmp_path: Path, text: str, expected: str | None
) -> None:
    path = write(tmp_path, text)
    if expected is None:  # a scenario without humans is valid: an empty cell
        assert load_scenario(path).humans == []
        return
    with pytest.raises(ConfigError, match=expected) as info:
        load_scenario(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path))


def test_missing_and_broken_files(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such file"):
        load_scenario(tmp_path / "nope.toml")
    (tmp_path / "bad.toml").write_text("duration_s = [")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_scenario(tmp_path / "bad.toml")
    (tmp_path / "short.toml").write_text("description = 'x'\nduration_s = 5.0\n")
    with pytest.raises(ConfigError, match="loop: Field required"):
        load_scenario(tmp_path / "short.toml")


def test_unknown_scenario_name_lists_the_available_ones() -> None:
    with pytest.raises(ConfigError, match="unknown scenario 'nope'") as info:
        scenario_path(SCENARIOS_DIR, "nope")
    for name in available_scenarios(SCENARIOS_DIR):
        assert name in str(info.value)
    with pytest.raises(ConfigError, match="unknown scenario"):
        scenario_path(SCENARIOS_DIR, "../cell")


@pytest.mark.parametrize("path", sorted(SCENARIOS_DIR.glob("*.toml")), ids=lambda p: p.stem)
def test_people_come_and_go_through_the_boundary_of_the_covered_volume(path: Path) -> None:
    """Nobody appears or vanishes inside the volume the trackers cover: for the gateway, that is a person lost."""
    s = load_scenario(path)
    coverage = covered_volume(TrackingConfig())
    for human in s.humans:
        always_there = s.loop and human.start_s == 0.0 and human.end_s == s.duration_s
        if always_there:  # present through every restart (standing_inside): never appears nor vanishes
            assert human.keyframes[0].xy_m == human.keyframes[-1].xy_m
            continue
        for t_s in (human.start_s, human.end_s):
            (person,) = [h for h in humans_at(s, t_s) if h.id == human.id]
            assert not inside(coverage, centre_m(person)), f"{human.id} at t = {t_s} s"


def test_fixtures_parse_and_are_checked(tmp_path: Path) -> None:
    s = scenario("occluded_behind_robot")
    (cabinet,) = s.fixtures
    assert cabinet.name == "cabinet"
    assert cabinet.radius_m > 0.0
    fixture = '[[fixtures]]\nname = "shelf"\na_m = [1.0, 0.0, 0.0]\nb_m = [1.0, 0.0, 2.0]\nradius_m = 0.3\n'
    assert load_scenario(write(tmp_path, fixture)).fixtures[0].b_m == (1.0, 0.0, 2.0)
    with pytest.raises(ConfigError, match=r"radius_m: .*greater than 0"):
        load_scenario(write(tmp_path, fixture.replace("0.3", "0.0")))
    with pytest.raises(ConfigError, match="b_m"):
        load_scenario(write(tmp_path, fixture.replace("[1.0, 0.0, 2.0]", "[1.0, 0.0]")))
    assert scenario("walk_in_reach_leave").fixtures == []


def test_the_occlusion_scenarios_exist_with_their_cells() -> None:
    from hrc_runtime.config import load_cell_config

    one = load_cell_config(REPO_ROOT / "configs" / "cell_one_sensor.toml")
    assert list(one.trackers) == ["front"]
    assert one.default_scenario == "occluded_behind_robot"
    assert scenario_path(one.scenarios_dir, "complementary_views").is_file()
    for cell in ("cell.toml", "cell_two_arms.toml", "cell_one_sensor.toml"):
        config = load_cell_config(REPO_ROOT / "configs" / cell)
        assert all(t.occlusion and t.position_m is not None for t in config.trackers.values()), cell
