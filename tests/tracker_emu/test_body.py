"""The human body model: proportions, contact with the floor, reach and heading."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_emu.body import CAPSULE_NAMES, REACH_FORWARD_M, BodyCapsule, BodyPose, body_capsules

REQUIRED_NAMES = {
    "head",
    "torso",
    "pelvis",
    "upper_arm_l",
    "upper_arm_r",
    "forearm_l",
    "forearm_r",
    "hand_l",
    "hand_r",
    "thigh_l",
    "thigh_r",
    "shin_l",
    "shin_r",
}


def by_name(capsules: tuple[BodyCapsule, ...]) -> dict[str, BodyCapsule]:
    return {c.name: c for c in capsules}


def forward_of(pose: BodyPose, p_world: np.ndarray) -> float:
    """Distance of a point in front of the body's centre line, along the heading [m]."""
    heading = np.array([np.cos(pose.heading_rad), np.sin(pose.heading_rad)])
    return float((p_world[:2] - [pose.x_m, pose.y_m]) @ heading)


def lateral_of(pose: BodyPose, p_world: np.ndarray) -> float:
    """Distance of a point to the left of the body's centre line [m]."""
    left = np.array([-np.sin(pose.heading_rad), np.cos(pose.heading_rad)])
    return float((p_world[:2] - [pose.x_m, pose.y_m]) @ left)


def test_capsules_have_the_expected_names_and_sane_values() -> None:
    capsules = body_capsules(BodyPose(1.0, 2.0, 0.3, reach=0.4))
    names = [c.name for c in capsules]
    assert len(capsules) >= 13
    assert set(names) >= REQUIRED_NAMES
    assert names == list(CAPSULE_NAMES)
    assert len(set(names)) == len(names)
    for c in capsules:
        assert c.a.shape == (3,)
        assert c.b.shape == (3,)
        assert np.all(np.isfinite(c.a))
        assert np.all(np.isfinite(c.b))
        assert 0.0 < c.radius_m < 0.25


def test_radii_are_those_of_an_adult() -> None:
    caps = by_name(body_capsules(BodyPose(0.0, 0.0, 0.0)))
    expected = {"head": 0.11, "torso": 0.17, "upper_arm_r": 0.05, "forearm_r": 0.045, "hand_r": 0.05}
    expected |= {"thigh_l": 0.08, "shin_l": 0.06}
    for name, radius in expected.items():
        assert caps[name].radius_m == pytest.approx(radius, abs=0.02)


@pytest.mark.parametrize("reach", [0.0, 0.5, 1.0])
def test_feet_on_the_floor_and_head_at_standing_height(reach: float) -> None:
    capsules = body_capsules(BodyPose(3.0, -1.0, 2.0, reach=reach))
    lowest_m = min(min(c.a[2], c.b[2]) - c.radius_m for c in capsules)
    assert lowest_m == pytest.approx(0.0, abs=0.01)
    head = by_name(capsules)["head"]
    top_m = max(head.a[2], head.b[2]) + head.radius_m
    assert 1.6 <= top_m <= 1.76
    assert 1.5 <= (head.a[2] + head.b[2]) / 2 <= 1.75
    highest_m = max(max(c.a[2], c.b[2]) + c.radius_m for c in capsules)
    assert highest_m == pytest.approx(top_m)


def test_segment_lengths_do_not_change_with_reach() -> None:
    def lengths(reach: float) -> np.ndarray:
        return np.array([np.linalg.norm(c.b - c.a) for c in body_capsules(BodyPose(0, 0, 0, reach, both_arms=True))])

    np.testing.assert_allclose(lengths(0.0), lengths(0.37), atol=1e-9)
    np.testing.assert_allclose(lengths(0.0), lengths(1.0), atol=1e-9)


@pytest.mark.parametrize("heading_rad", [0.0, np.pi / 2, np.pi, -2.5])
def test_full_reach_puts_the_right_hand_in_front_at_table_height(heading_rad: float) -> None:
    pose = BodyPose(1.35, 0.4, heading_rad, reach=1.0)
    hand = by_name(body_capsules(pose))["hand_r"]
    assert 0.6 <= forward_of(pose, hand.b) <= 0.8
    assert forward_of(pose, hand.b) == pytest.approx(REACH_FORWARD_M, abs=0.02)
    assert 0.55 <= forward_of(pose, (hand.a + hand.b) / 2) <= 0.8
    assert 0.95 <= hand.b[2] <= 1.25
    assert -0.2 <= lateral_of(pose, hand.b) <= 0.0  # right of the centre line, not far out
    # The left arm keeps hanging unless both arms reach.
    assert forward_of(pose, by_name(body_capsules(pose))["hand_l"].b) < 0.35
    both = by_name(body_capsules(BodyPose(1.35, 0.4, heading_rad, reach=1.0, both_arms=True)))
    assert forward_of(pose, both["hand_l"].b) == pytest.approx(forward_of(pose, hand.b))
    assert lateral_of(pose, both["hand_l"].b) == pytest.approx(-lateral_of(pose, hand.b))


def test_no_reach_keeps_the_hand_near_the_hip() -> None:
    pose = BodyPose(0.0, 0.0, 0.7)
    caps = by_name(body_capsules(pose))
    hip_r = caps["thigh_r"].a
    assert np.linalg.norm(caps["hand_r"].b - hip_r) < 0.3
    assert abs(forward_of(pose, caps["hand_r"].b)) < 0.2
    assert 0.65 <= caps["hand_r"].b[2] <= 0.95


def test_reach_moves_the_hand_monotonically_forward() -> None:
    pose = BodyPose(0.0, 0.0, 0.0)
    forward = [
        forward_of(pose, by_name(body_capsules(BodyPose(0.0, 0.0, 0.0, r)))["hand_r"].b) for r in np.linspace(0, 1, 11)
    ]
    assert np.all(np.diff(forward) > 0)


def test_reaching_leans_the_torso_forward() -> None:
    pose = BodyPose(0.0, 0.0, 0.0)
    upright = by_name(body_capsules(pose))
    leaning = by_name(body_capsules(BodyPose(0.0, 0.0, 0.0, reach=1.0)))
    assert forward_of(pose, leaning["head"].b) > forward_of(pose, upright["head"].b) + 0.1
    np.testing.assert_allclose(leaning["shin_l"].a, upright["shin_l"].a)


def test_heading_rotates_the_body_about_its_position() -> None:
    rng = np.random.default_rng(3)
    for _ in range(20):
        x_m, y_m = rng.uniform(-5, 5, size=2)
        heading_rad = rng.uniform(-np.pi, np.pi)
        reach = rng.uniform(0, 1)
        reference = body_capsules(BodyPose(0.0, 0.0, 0.0, reach))
        turned = body_capsules(BodyPose(x_m, y_m, heading_rad, reach))
        c, s = np.cos(heading_rad), np.sin(heading_rad)
        R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        for ref, cap in zip(reference, turned, strict=True):
            np.testing.assert_allclose(cap.a, R @ ref.a + [x_m, y_m, 0], atol=1e-12)
            np.testing.assert_allclose(cap.b, R @ ref.b + [x_m, y_m, 0], atol=1e-12)
            assert cap.radius_m == ref.radius_m


def test_facing_minus_x_puts_the_hand_towards_the_robot() -> None:
    hand = by_name(body_capsules(BodyPose(1.35, 0.0, np.pi, reach=1.0)))["hand_r"]
    assert hand.b[0] == pytest.approx(1.35 - REACH_FORWARD_M, abs=0.02)
    assert hand.b[1] > 0.0  # the right hand of someone facing -x is on the +y side


def test_capsule_arrays_are_read_only() -> None:
    cap = body_capsules(BodyPose(0.0, 0.0, 0.0))[0]
    with pytest.raises(ValueError, match="read-only"):
        cap.a[0] = 1.0


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"reach": 1.5}, "reach"),
        ({"reach": -0.1}, "reach"),
        ({"x_m": float("nan")}, "finite"),
        ({"heading_rad": float("inf")}, "finite"),
    ],
)
def test_invalid_pose_is_rejected(kwargs: dict[str, float], message: str) -> None:
    values = {"x_m": 0.0, "y_m": 0.0, "heading_rad": 0.0, "reach": 0.0} | kwargs
    with pytest.raises(ValueError, match=message):
        BodyPose(values["x_m"], values["y_m"], values["heading_rad"], values["reach"])
