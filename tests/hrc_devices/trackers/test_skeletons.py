"""Skeletons → capsules: every keypoint covered, missing keypoints never shrink a person, bad keypoints refused."""

from __future__ import annotations

import numpy as np
import pytest
from support.skeleton_poses import standing_keypoints

from hrc_devices.trackers.skeletons import (
    ANTHROPOMETRY,
    COMPILED,
    NECK_TO_SHOULDER_M,
    PELVIS_TO_HIP_M,
    SEGMENTS,
    STATURE_M,
    WHOLE_BODY_NAMES,
    BodyCapsules,
    PersonUnplacedError,
    SkeletonError,
    body_capsules,
    covers,
    enclosing_capsule,
    segment_distance_m,
)

FORMATS = sorted(COMPILED)
NAMES = tuple(s.name for s in SEGMENTS)


def _all_seen(kp: np.ndarray) -> np.ndarray:
    return np.ones(len(kp), dtype=bool)


def _points_in(body: BodyCapsules, names: set[str], rng: np.random.Generator, n: int = 200) -> np.ndarray:
    """Random points inside the capsules of ``body`` named ``names`` (on their surfaces and within)."""
    points = []
    for name, a, b, r in zip(body.names, body.a_m, body.b_m, body.radius_m, strict=True):
        if name not in names:
            continue
        t = rng.random(n)[:, None]
        u = rng.normal(size=(n, 3))
        u *= (r * rng.random(n) ** (1 / 3) / np.linalg.norm(u, axis=1))[:, None]
        points.append(a + t * (b - a) + u)
    return np.concatenate(points)


@pytest.mark.parametrize("name", FORMATS)
def test_every_keypoint_of_a_standing_person_is_covered(name: str) -> None:
    fmt = COMPILED[name]
    kp = standing_keypoints(fmt)
    body, memory = body_capsules(fmt, kp, _all_seen(kp), stamp_ns=0, uncertainty_m=0.03)
    assert body.names == NAMES
    assert covers(body, kp).all()
    assert not body.estimated
    assert not body.whole_body
    assert set(memory.seen) == set(NAMES)
    # never thinner than the anthropometric radius plus the uncertainty
    for seg, r in zip(SEGMENTS, body.radius_m, strict=True):
        assert r >= ANTHROPOMETRY[seg.size].radius_m + 0.03 - 1e-12


@pytest.mark.parametrize("name", FORMATS)
def test_every_keypoint_is_covered_for_random_poses(name: str) -> None:
    fmt = COMPILED[name]
    rng = np.random.default_rng(20)
    for _ in range(50):
        kp = standing_keypoints(fmt, *rng.uniform(-3, 3, 2), rng.uniform(-np.pi, np.pi))
        kp = kp + rng.normal(0.0, 0.08, kp.shape)  # a distorted, noisy skeleton
        seen = rng.random(len(kp)) > 0.2
        body, _ = body_capsules(fmt, kp, seen, stamp_ns=0, uncertainty_m=0.0)
        assert covers(body, kp[seen]).all()
        assert body.names in (NAMES, WHOLE_BODY_NAMES)


@pytest.mark.parametrize("name", FORMATS)
def test_a_missing_keypoint_never_reduces_the_covered_volume(name: str) -> None:
    """Frame 1 sees everyone; frame 2 (the person moved 3 cm) misses one keypoint: the points of frame 1's capsules
    of every segment that keypoint belongs to are still covered, and so is the true position of the hidden
    keypoint."""
    fmt = COMPILED[name]
    rng = np.random.default_rng(7)
    kp1 = standing_keypoints(fmt)
    body1, memory = body_capsules(fmt, kp1, _all_seen(kp1), stamp_ns=0, uncertainty_m=0.02)
    kp2 = kp1 + np.array([0.03, 0.0, 0.0])
    for hidden in range(fmt.n_keypoints):
        seen = _all_seen(kp2)
        seen[hidden] = False
        body2, _ = body_capsules(fmt, kp2, seen, stamp_ns=33_000_000, uncertainty_m=0.02, memory=memory)
        assert body2.names == body1.names  # a segment never vanishes
        touched = {seg.name for seg in fmt.segments if hidden in seg.members} | set(body2.estimated)
        assert covers(body2, _points_in(body1, touched, rng)).all(), fmt.spec.keypoint_names[hidden]
        assert covers(body2, kp2).all(), fmt.spec.keypoint_names[hidden]


@pytest.mark.parametrize("name", FORMATS)
def test_a_hidden_forearm_without_memory_is_covered_where_it_can_be(name: str) -> None:
    """No memory (a new person): elbow and wrist unseen; the sphere around the shoulder reaches the true elbow,
    wrist and hand."""
    fmt = COMPILED[name]
    kp = standing_keypoints(fmt)
    seen = _all_seen(kp)
    hidden = [i for i, n in enumerate(fmt.spec.keypoint_names) if "right" in n and ("elbow" in n or "wrist" in n)]
    seen[hidden] = False
    body, _ = body_capsules(fmt, kp, seen, stamp_ns=0, uncertainty_m=0.0)
    assert {"upper_arm_r", "forearm_r", "hand_r"} <= set(body.estimated)
    assert covers(body, kp).all()  # the hidden ones too


def test_memory_expires() -> None:
    fmt = COMPILED["zed_body_34"]
    kp = standing_keypoints(fmt)
    _, memory = body_capsules(fmt, kp, _all_seen(kp), stamp_ns=0, uncertainty_m=0.0)
    far = kp + np.array([2.0, 0.0, 0.0])  # walked 2 m in 2 s with the left hand hidden
    seen = _all_seen(far)
    seen[list(fmt.segments[NAMES.index("hand_l")].b)] = False
    fresh, _ = body_capsules(fmt, far, seen, stamp_ns=500_000_000, uncertainty_m=0.0, memory=memory, memory_s=1.0)
    old, _ = body_capsules(fmt, far, seen, stamp_ns=2_000_000_000, uncertainty_m=0.0, memory=memory, memory_s=1.0)
    k = NAMES.index("hand_l")
    assert np.linalg.norm(fresh.b_m[k] - fresh.a_m[k]) > 1.5  # still reaches back to where the hand was
    assert np.linalg.norm(old.b_m[k] - old.a_m[k]) == 0.0  # a sphere around the wrist only


@pytest.mark.parametrize("name", FORMATS)
def test_a_person_without_a_torso_is_a_whole_body_not_dropped(name: str) -> None:
    fmt = COMPILED[name]
    kp = standing_keypoints(fmt)
    seen = np.zeros(len(kp), dtype=bool)
    seen[[i for i, n in enumerate(fmt.spec.keypoint_names) if "knee" in n or "ankle" in n]] = True
    body, _ = body_capsules(fmt, kp, seen, stamp_ns=0, uncertainty_m=0.05)
    assert body.whole_body
    assert body.names == WHOLE_BODY_NAMES
    assert covers(body, kp).all()  # grown to body size: the unseen head and hands too
    assert body.a_m[:, 2].min() <= 0.0
    assert body.b_m[:, 2].max() >= 1.8


def test_enclosing_capsule_contains_both() -> None:
    rng = np.random.default_rng(3)
    for _ in range(200):
        c1 = (rng.normal(size=3), rng.normal(size=3), float(rng.uniform(0, 0.5)))
        c2 = (rng.normal(size=3), rng.normal(size=3), float(rng.uniform(0, 0.5)))
        a, b, r = enclosing_capsule(c1, c2)
        for ca, cb, cr in (c1, c2):
            t = rng.random((100, 1))
            u = rng.normal(size=(100, 3))
            u *= cr / np.linalg.norm(u, axis=1, keepdims=True)
            assert (segment_distance_m(ca + t * (cb - ca) + u, a, b) <= r + 1e-9).all()


@pytest.mark.parametrize(
    ("value", "reason"), [(np.nan, "non_finite"), (np.inf, "non_finite"), (1e6, "absurd_keypoint")]
)
def test_a_bad_seen_keypoint_is_refused(value: float, reason: str) -> None:
    fmt = COMPILED["coco_17"]
    kp = standing_keypoints(fmt)
    kp[9, 1] = value
    with pytest.raises(SkeletonError) as err:
        body_capsules(fmt, kp, _all_seen(kp), stamp_ns=0, uncertainty_m=0.0)
    assert err.value.reason == reason


def test_an_unseen_keypoint_may_be_anything() -> None:
    fmt = COMPILED["coco_17"]
    kp = standing_keypoints(fmt)
    kp[9] = np.nan
    seen = _all_seen(kp)
    seen[9] = False
    body, _ = body_capsules(fmt, kp, seen, stamp_ns=0, uncertainty_m=0.0)
    assert np.isfinite(body.radius_m).all()
    assert np.isfinite(body.a_m).all()


def test_wrong_keypoint_count_is_refused() -> None:
    fmt = COMPILED["mediapipe_33"]
    with pytest.raises(SkeletonError) as err:
        body_capsules(fmt, np.zeros((17, 3)), np.ones(17, dtype=bool), stamp_ns=0, uncertainty_m=0.0)
    assert err.value.reason == "wrong_keypoint_count"


def test_capsules_become_a_contract_human() -> None:
    fmt = COMPILED["body_25"]
    kp = standing_keypoints(fmt)
    body, _ = body_capsules(fmt, kp, _all_seen(kp), stamp_ns=0, uncertainty_m=0.0)
    human = body.to_human("7")
    assert [c.name for c in human.capsules] == list(NAMES)
    assert human.capsules[0].radius == pytest.approx(body.radius_m[0])


@pytest.mark.parametrize("hidden", ["neck", "pelvis"])
def test_a_placed_person_whose_torso_is_hidden_is_unplaced_never_a_smaller_whole_body(hidden: str) -> None:
    """An arm reaching out 1 m, then the neck (or pelvis) hidden: a whole-body column around what is seen would not
    cover the arm of a frame ago; the person is left out of the frame instead (lost at the gateway), memory kept."""
    fmt = COMPILED["zed_body_34"]
    kp = standing_keypoints(fmt)
    names = fmt.spec.keypoint_names
    shoulder = kp[names.index("right_shoulder")]
    for k, joint in enumerate(("right_elbow", "right_wrist", "right_hand", "right_handtip", "right_thumb")):
        kp[names.index(joint)] = shoulder + np.array([0.25 * (k + 1), 0.0, 0.0])  # straight out along x
    _, memory = body_capsules(fmt, kp, _all_seen(kp), stamp_ns=0, uncertainty_m=0.0)
    seen = _all_seen(kp)
    seen[list(getattr(fmt, hidden))] = False
    seen[[names.index(j) for j in ("right_elbow", "right_wrist", "right_hand", "right_handtip", "right_thumb")]] = False
    with pytest.raises(PersonUnplacedError):
        body_capsules(fmt, kp, seen, stamp_ns=100_000_000, uncertainty_m=0.0, memory=memory)
    # What it replaces: the column around what is seen leaves out the hand that reached out a frame ago.
    column, _ = body_capsules(fmt, kp, seen, stamp_ns=100_000_000, uncertainty_m=0.0)
    assert column.whole_body  # never placed before: the whole-body report stays (docs/ros2.md)
    assert not covers(column, kp[[names.index("right_handtip")]]).any()
    # Placed too long ago (beyond memory_s): a whole-body report again.
    late, _ = body_capsules(fmt, kp, seen, stamp_ns=2_000_000_000, uncertainty_m=0.0, memory=memory, memory_s=1.0)
    assert late.whole_body


# Men's 95th percentiles [mm] computed from ANSUR II's public per-person file (ANSUR_II_MALE_Public.csv, n = 4,082,
# unweighted), 2026-12-02: the table of hrc_devices/trackers/skeletons.py must never be smaller.
ANSUR_II_MEN_P95_MM = {
    "tragion_top_of_head": 141, "chest_breadth": 320, "biceps_circumference_flexed": 418,
    "forearm_circumference_flexed": 348, "hand_breadth": 96, "thigh_circumference": 723, "calf_circumference": 443,
    "foot_breadth": 111, "neck_to_vertex": 260, "biacromial_breadth": 447, "bi_iliac_breadth": 305,
    "shoulder_elbow_length": 394, "radiale_stylion_length": 295, "forearm_hand_length": 520, "hand_length": 210,
    "hip_to_knee_joint": 458, "knee_to_ankle_joint": 460, "foot_length": 293, "stature": 1870,
}  # fmt: skip


def test_the_anthropometry_is_at_least_the_ansur_ii_mens_95th_percentile() -> None:
    p95_m = {k: v / 1000 for k, v in ANSUR_II_MEN_P95_MM.items()}
    size = ANTHROPOMETRY
    tau = 2 * np.pi
    assert size["head"].radius_m >= p95_m["tragion_top_of_head"]
    assert size["torso"].radius_m >= p95_m["chest_breadth"] / 2
    assert size["upper_arm"].radius_m >= p95_m["biceps_circumference_flexed"] / tau
    assert size["forearm"].radius_m >= p95_m["forearm_circumference_flexed"] / tau
    assert size["hand"].radius_m >= p95_m["hand_breadth"] / 2
    assert size["thigh"].radius_m >= p95_m["thigh_circumference"] / tau
    assert size["shin"].radius_m >= p95_m["calf_circumference"] / tau
    assert size["foot"].radius_m >= p95_m["foot_breadth"] / 2
    assert size["head"].length_m >= p95_m["neck_to_vertex"]
    assert size["shoulders"].length_m >= p95_m["biacromial_breadth"]
    assert size["pelvis"].length_m >= p95_m["bi_iliac_breadth"]
    assert size["upper_arm"].length_m >= p95_m["shoulder_elbow_length"]
    assert size["forearm"].length_m >= p95_m["radiale_stylion_length"]
    assert size["forearm"].length_m + size["hand"].length_m >= p95_m["forearm_hand_length"]
    assert size["hand"].length_m >= p95_m["hand_length"]
    assert size["thigh"].length_m >= p95_m["hip_to_knee_joint"]
    assert size["shin"].length_m >= p95_m["knee_to_ankle_joint"]
    assert size["foot"].length_m >= p95_m["foot_length"]
    assert p95_m["stature"] <= STATURE_M
    assert p95_m["biacromial_breadth"] / 2 <= NECK_TO_SHOULDER_M
    assert p95_m["bi_iliac_breadth"] / 2 <= PELVIS_TO_HIP_M
