"""ROS4HRI bodies: JointState and TFMessage bytes serialised by ``rosbags`` from the standard definitions → the human
model's forward kinematics → capsules.

Known answers are worked out by hand from the template's numbers (``ros4hri/human_description``, ``human-tpl.xacro``
at 70669dfe: size unit u = height / 7.5; torso 2.75 u, neck 0.25 u, head frame (u/4, 0, u/2) beyond the neck,
shoulders ±0.8 u, upper arm 1.6 u, forearm u, hips ±0.6 u, thigh 1.5 u, tibia 2 u), not by the generator.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pytest

from hrc_contract.messages import MessageError
from hrc_devices.ros2.rmw_zenoh import typestore
from hrc_devices.trackers.ros2_people import IDENTITY, Placement
from hrc_devices.trackers.ros4hri_body import (
    DEFAULT_HEIGHT_M,
    JOINT_NAMES,
    JOINT_STATE,
    KEYPOINT_NAMES,
    TEMPLATE_HEIGHT_M,
    TF_MESSAGE,
    BodyJoints,
    BodyPose,
    HumanModel,
    body_capsules_world,
    body_keypoints,
    build_human_model,
    decode_body_poses,
    decode_joint_state,
    human_joints,
    rotation_of_quaternion,
)
from hrc_devices.trackers.skeletons import BodyCapsules, PersonUnplacedError, covers

STORE = typestore("jazzy")
T = STORE.types
STAMP_NS = 1_790_000_000_000_005_000
BODY = "ukxbg"
CAMERA = "camera_color_optical_frame"
HEIGHT_M = DEFAULT_HEIGHT_M
U = HEIGHT_M / 7.5


@pytest.fixture(scope="module")
def human() -> HumanModel:
    return build_human_model(HEIGHT_M)


# -- messages, built by rosbags from the standard sensor_msgs and tf2_msgs definitions ------------------------------


def _header(frame_id: str, stamp_ns: int = STAMP_NS) -> Any:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec), frame_id=frame_id)


def joint_state_bytes(angles: dict[str, float], body_id: str = BODY, names: list[str] | None = None) -> bytes:
    """A JointState as hri_fullbody publishes it: names ``<joint>_<id>``, the positions, no velocity or effort."""
    msg = T[JOINT_STATE](
        header=_header(CAMERA),
        name=names if names is not None else [f"{j}_{body_id}" for j in angles],
        position=np.array(list(angles.values()), dtype=np.float64),
        velocity=np.zeros(0),
        effort=np.zeros(0),
    )
    return bytes(STORE.serialize_cdr(msg, JOINT_STATE))


def tf_bytes(poses: list[tuple[str, str, tuple[float, ...], tuple[float, ...]]]) -> bytes:
    """A TFMessage of (child, parent, xyz, quaternion xyzw)."""
    transforms = [
        T["geometry_msgs/msg/TransformStamped"](
            header=_header(parent),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
            ),
        )
        for child, parent, xyz, q in poses
    ]
    return bytes(STORE.serialize_cdr(T[TF_MESSAGE](transforms=transforms), TF_MESSAGE))


def standing(**angles: float) -> dict[str, float]:
    """Every joint at 0 (straight, arms hanging) but those given."""
    return {name: angles.get(name, 0.0) for name in JOINT_NAMES}


def on_floor(x: float = 0.0, y: float = 0.0) -> BodyPose:
    """The body frame upright at hip height above (x, y): a straight model's ankles on the floor."""
    return BodyPose(BODY, STAMP_NS, np.eye(3), np.array([x, y, 3.5 * U]))


def capsules(human: HumanModel, angles: dict[str, float], pose: BodyPose, placement: Placement = IDENTITY) -> Any:
    body, _ = body_capsules_world(
        human, BodyJoints(STAMP_NS, angles), pose, placement, stamp_ns=STAMP_NS, uncertainty_m=0.05
    )
    return body


def keypoints_world(human: HumanModel, angles: Mapping[str, float], pose: BodyPose) -> np.ndarray:
    kp, _ = body_keypoints(human, angles)
    return kp @ pose.R_parent_body.T + pose.p_parent_body


def at(name: str, human: HumanModel, angles: Mapping[str, float], pose: BodyPose) -> np.ndarray:
    return np.asarray(keypoints_world(human, angles, pose)[KEYPOINT_NAMES.index(name)])


def random_angles(human: HumanModel, rng: np.random.Generator) -> dict[str, float]:
    return {n: float(rng.uniform(*human.limits_rad[n])) for n in JOINT_NAMES}


def random_pose(rng: np.random.Generator) -> BodyPose:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    x, y, z, w = q
    return BodyPose(BODY, STAMP_NS, rotation_of_quaternion(x, y, z, w), rng.uniform(-3.0, 3.0, size=3))


def points_in(body: BodyCapsules, rng: np.random.Generator, per_capsule: int = 300) -> np.ndarray:
    """Random points inside every capsule of a body (uniform along the axis, in a ball around it)."""
    out = []
    for a, b, r in zip(body.a_m, body.b_m, body.radius_m, strict=True):
        t = rng.uniform(size=(per_capsule, 1))
        direction = rng.normal(size=(per_capsule, 3))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        out.append(a + t * (b - a) + direction * r * rng.uniform(size=(per_capsule, 1)) ** (1 / 3))
    return np.concatenate(out)


# -- the model: known answers -----------------------------------------------------------------------------------


def test_the_model_has_the_templates_twenty_joints_and_limits(human: HumanModel) -> None:
    assert human.model.nq == 20
    assert JOINT_NAMES == (
        "waist", "r_head", "y_head", "p_head", "l_y_shoulder", "l_p_shoulder", "l_r_shoulder", "l_elbow",
        "r_y_shoulder", "r_p_shoulder", "r_r_shoulder", "r_elbow", "l_y_hip", "l_p_hip", "l_r_hip", "l_knee",
        "r_y_hip", "r_p_hip", "r_r_hip", "r_knee",
    )  # fmt: skip  # hri_fullbody's HUMAN_JOINT_NAMES
    assert human.limits_rad["waist"] == (-0.2, 1.0)
    assert human.limits_rad["l_y_shoulder"] == (-1.1, 1.9)  # the arms' limits of 2024-02-05
    assert human.limits_rad["r_elbow"] == (0.0, 2.5)
    assert human.limits_rad["l_knee"] == (-2.5, 0.0)
    assert len(KEYPOINT_NAMES) == 27


def test_straight_the_model_is_as_tall_as_asked_and_stands_on_the_floor(human: HumanModel) -> None:
    angles, pose = standing(), on_floor()
    for side, y in (("l", 1.0), ("r", -1.0)):
        np.testing.assert_allclose(at(f"{side}_ankle", human, angles, pose), (0.0, y * 0.6 * U, 0.0), atol=1e-12)
        np.testing.assert_allclose(at(f"{side}_knee", human, angles, pose), (0.0, y * 0.6 * U, 2.0 * U), atol=1e-12)
        np.testing.assert_allclose(
            at(f"{side}_shoulder", human, angles, pose), (0.0, y * 0.8 * U, 6.25 * U), atol=1e-12
        )
        np.testing.assert_allclose(at(f"{side}_wrist", human, angles, pose), (0.0, y * 0.8 * U, 3.65 * U), atol=1e-12)
    np.testing.assert_allclose(at("head", human, angles, pose), (U / 4, 0.0, 7.0 * U), atol=1e-12)
    # the head is a sphere of radius u/2 around the head frame moved u/4 back: its top is the model's height
    top = at("head", human, angles, pose) + np.array([-U / 4, 0.0, U / 2])
    assert top[2] == pytest.approx(HEIGHT_M)
    body = capsules(human, angles, pose)
    assert covers(body, np.array([top, (0.0, 0.6 * U, 0.0), (0.0, -0.6 * U, 0.0)])).all()
    assert (body.a_m[:, 2] - body.radius_m).min() <= 0.0  # down to the floor


def test_the_template_height_scales_every_length(human: HumanModel) -> None:
    small = build_human_model(TEMPLATE_HEIGHT_M)
    ratio = TEMPLATE_HEIGHT_M / HEIGHT_M
    angles = standing(l_p_shoulder=1.0, r_elbow=1.2, waist=0.3, l_knee=-0.7)
    kp_small, _ = body_keypoints(small, angles)
    kp_large, _ = body_keypoints(human, angles)
    np.testing.assert_allclose(kp_small, kp_large * ratio, atol=1e-12)


def test_arms_and_legs_move_where_the_template_says(human: HumanModel) -> None:
    pose = on_floor()
    shoulder_z = 6.25 * U
    out = standing(l_p_shoulder=math.pi / 2, r_p_shoulder=math.pi / 2)  # both arms raised sideways
    np.testing.assert_allclose(at("l_wrist", human, out, pose), (0.0, 3.4 * U, shoulder_z), atol=1e-12)
    np.testing.assert_allclose(at("r_wrist", human, out, pose), (0.0, -3.4 * U, shoulder_z), atol=1e-12)
    bent = standing(l_elbow=math.pi / 2)  # the forearm forward
    np.testing.assert_allclose(at("l_wrist", human, bent, pose), (U, 0.8 * U, shoulder_z - 1.6 * U), atol=1e-12)
    kneel = standing(r_knee=-math.pi / 2)  # the shin backward
    np.testing.assert_allclose(at("r_ankle", human, kneel, pose), (-2.0 * U, -0.6 * U, 2.0 * U), atol=1e-12)
    bow = standing(waist=0.5)  # the torso forward
    torso = (2.75 * U * math.sin(0.5), 0.0, 3.5 * U + 2.75 * U * math.cos(0.5))
    np.testing.assert_allclose(at("torso", human, bow, pose), torso, atol=1e-12)


def test_the_root_pose_moves_the_model(human: HumanModel) -> None:
    # body_<id> turned 90° about z (a quaternion from /tf), 2 m ahead: the left shoulder points to -x
    (pose,) = decode_body_poses(
        tf_bytes(
            [(f"body_{BODY}", CAMERA, (2.0, 0.0, 3.5 * U), (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)))]
        ),
        STORE,
        CAMERA,
    )
    np.testing.assert_allclose(at("l_shoulder", human, standing(), pose), (2.0 - 0.8 * U, 0.0, 6.25 * U), atol=1e-9)


def test_a_model_taller_than_the_p95_reach_is_refused() -> None:
    with pytest.raises(ValueError, match="allowed"):
        build_human_model(2.1)
    with pytest.raises(ValueError, match="allowed"):
        build_human_model(float("nan"))
    assert [j.name for j in human_joints(1.7)][:2] == ["waist", "torso"]


# -- from bytes to capsules: every keypoint inside ----------------------------------------------------------------


def test_rosbags_bytes_to_capsules_that_contain_every_keypoint(human: HumanModel) -> None:
    rng = np.random.default_rng(155)
    placement = Placement(np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]]).T, np.array([3.0, 0.0, 2.2]))
    for _ in range(100):
        angles = random_angles(human, rng)
        joints = decode_joint_state(joint_state_bytes(angles), STORE, human, BODY)
        assert set(joints.angles_rad) == set(JOINT_NAMES)
        q = rng.normal(size=4)
        transform = (f"body_{BODY}", CAMERA, tuple(rng.uniform(-2.0, 2.0, 3)), tuple(q / np.linalg.norm(q)))
        (pose,) = decode_body_poses(tf_bytes([transform]), STORE, CAMERA)
        body, _ = body_capsules_world(human, joints, pose, placement, stamp_ns=STAMP_NS, uncertainty_m=0.0)
        kp = keypoints_world(human, joints.angles_rad, pose) @ placement.R_world_sensor.T + placement.p_world_sensor
        assert not body.whole_body
        assert covers(body, kp).all()


def test_a_missing_joint_never_reduces_the_covered_volume(human: HumanModel) -> None:
    rng = np.random.default_rng(20)
    for trial in range(40):
        angles, pose = random_angles(human, rng), random_pose(rng)
        full = capsules(human, angles, pose)
        inside_full = points_in(full, rng, per_capsule=100)
        for missing in JOINT_NAMES[1:]:  # the waist: see the next test
            partial = capsules(human, {n: a for n, a in angles.items() if n != missing}, pose)
            assert covers(partial, inside_full, tolerance_m=1e-9).all(), (trial, missing)
            assert partial.estimated  # what depends on it is not seen


def test_without_the_waist_the_torso_cannot_be_placed_and_the_person_is_a_whole_body(human: HumanModel) -> None:
    angles = standing()
    del angles["waist"]
    body = capsules(human, angles, on_floor(1.0, 1.0))
    assert body.whole_body
    kp, seen = body_keypoints(human, angles)
    assert [KEYPOINT_NAMES[i] for i in np.flatnonzero(seen)] == [
        "body", "waist", "l_y_hip", "l_p_hip", "l_hip", "l_knee", "l_ankle",
        "r_y_hip", "r_p_hip", "r_hip", "r_knee", "r_ankle",
    ]  # fmt: skip
    assert covers(body, kp[seen] + np.array([1.0, 1.0, 3.5 * U])).all()
    assert covers(body, np.array([[1.0, 1.0, 0.0], [1.0, 1.0, HEIGHT_M]])).all()  # a P95 stature around the hips


def test_an_unknown_elbow_makes_the_forearm_a_sphere_around_the_elbow(human: HumanModel) -> None:
    angles = standing()
    del angles["r_elbow"]
    _, seen = body_keypoints(human, angles)
    assert [KEYPOINT_NAMES[i] for i in np.flatnonzero(~seen)] == ["r_wrist"]
    body = capsules(human, angles, on_floor())
    assert set(body.estimated) == {"forearm_r", "hand_r"}
    k = body.names.index("forearm_r")
    np.testing.assert_allclose(body.a_m[k], at("r_elbow", human, standing(), on_floor()), atol=1e-12)
    assert body.radius_m[k] >= 0.31  # P95 forearm, longer than the model's u


# -- hostile input ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("payload", "reason"),
    [
        (joint_state_bytes(standing(waist=float("nan"))), "non_finite"),
        (joint_state_bytes(standing(l_knee=float("inf"))), "non_finite"),
        (joint_state_bytes(standing(l_elbow=3.0)), "joint_out_of_limits"),
        (joint_state_bytes(standing(r_knee=0.5)), "joint_out_of_limits"),
        (joint_state_bytes(standing(y_head=1e300)), "joint_out_of_limits"),
        (joint_state_bytes(standing(), body_id="other"), "unknown_joint"),
        (joint_state_bytes({"l_wrist": 0.0}), "unknown_joint"),  # a fixed joint is no joint of the message
        (joint_state_bytes({"waist": 0.0, "r_knee": 0.0}, names=[f"waist_{BODY}", f"waist_{BODY}"]), "duplicate_joint"),
        (joint_state_bytes({"waist": 0.0}, names=[f"waist_{BODY}", f"r_knee_{BODY}"]), "joint_count_mismatch"),
        (joint_state_bytes(standing())[:40], "not_cdr"),
        (tf_bytes([]), "not_cdr"),  # another type
    ],
)
def test_hostile_joint_states_are_refused_with_a_reason(human: HumanModel, payload: bytes, reason: str) -> None:
    with pytest.raises(MessageError) as refused:
        decode_joint_state(payload, STORE, human, BODY)
    assert refused.value.reason == reason


def test_an_angle_a_rounding_beyond_a_limit_is_clamped(human: HumanModel) -> None:
    joints = decode_joint_state(joint_state_bytes(standing(l_elbow=-0.005)), STORE, human, BODY)
    assert joints.angles_rad["l_elbow"] == 0.0


def test_a_partial_joint_state_is_accepted_and_its_missing_joints_are_unknown(human: HumanModel) -> None:
    joints = decode_joint_state(joint_state_bytes({"waist": 0.1, "l_elbow": 1.0}), STORE, human, BODY)
    assert joints.angles_rad == {"waist": 0.1, "l_elbow": 1.0}


UNIT = (0.0, 0.0, 0.0, 1.0)


@pytest.mark.parametrize(
    ("transforms", "reason"),
    [
        ([(f"body_{BODY}", "base_link", (1.0, 0.0, 0.0), UNIT)], "wrong_frame"),
        ([(f"body_{BODY}", CAMERA, (float("nan"), 0.0, 0.0), UNIT)], "non_finite"),
        ([(f"body_{BODY}", CAMERA, (1e6, 0.0, 0.0), UNIT)], "absurd_keypoint"),
        ([(f"body_{BODY}", CAMERA, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0))], "bad_quaternion"),
        ([(f"body_{BODY}", CAMERA, (1.0, 0.0, 0.0), (0.0, 0.0, 0.0, 5.0))], "bad_quaternion"),
        ([(f"body_{BODY}", CAMERA, (1.0, 0.0, 0.0), (float("inf"), 0.0, 0.0, 1.0))], "non_finite"),
        ([("body_", CAMERA, (1.0, 0.0, 0.0), UNIT)], "bad_body_id"),
    ],
)
def test_hostile_body_frames_are_refused_with_a_reason(transforms: list[Any], reason: str) -> None:
    with pytest.raises(MessageError) as refused:
        decode_body_poses(tf_bytes(transforms), STORE, CAMERA)
    assert refused.value.reason == reason


def test_other_frames_on_tf_are_ignored_and_the_newest_body_pose_wins() -> None:
    payload = tf_bytes(
        [
            (f"waist_{BODY}", f"body_{BODY}", (float("nan"), 0.0, 0.0), UNIT),  # the model's own links: not ours
            ("tool0", "base_link", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0)),
            (f"body_{BODY}", CAMERA, (1.0, 2.0, 3.0), UNIT),
        ]
    )
    (pose,) = decode_body_poses(payload, STORE, CAMERA)
    assert pose.body_id == BODY
    np.testing.assert_allclose(pose.p_parent_body, (1.0, 2.0, 3.0))


def test_fuzzed_bytes_never_raise_anything_but_a_refusal(human: HumanModel) -> None:
    rng = np.random.default_rng(7)
    good_js = joint_state_bytes(standing())
    good_tf = tf_bytes([(f"body_{BODY}", CAMERA, (1.0, 0.0, 0.0), UNIT)])
    for i in range(300):
        data = bytearray(good_js if i % 2 else good_tf)
        for k in rng.integers(4, len(data), size=int(rng.integers(1, 12))):
            data[k] = int(rng.integers(0, 256))
        cut = int(rng.integers(0, len(data) + 1)) if i % 3 else len(data)
        try:
            if i % 2:
                decode_joint_state(bytes(data[:cut]), STORE, human, BODY)
            else:
                decode_body_poses(bytes(data[:cut]), STORE, CAMERA)
        except MessageError:
            pass


def test_a_body_placed_a_frame_ago_without_the_waist_now_is_left_out_not_a_whole_body(human: HumanModel) -> None:
    """The arms may have reached out a frame ago: a whole-body column around the hips would not cover them, so the
    body is unplaced (left out of the frame: lost at the gateway, its capsules growing from the last ones)."""
    angles = standing(l_p_shoulder=1.5)
    pose = on_floor(1.0, 1.0)
    _, memory = body_capsules_world(
        human, BodyJoints(STAMP_NS, angles), pose, IDENTITY, stamp_ns=STAMP_NS, uncertainty_m=0.0
    )
    del angles["waist"]
    later_ns = STAMP_NS + 33_000_000
    with pytest.raises(PersonUnplacedError):
        body_capsules_world(
            human, BodyJoints(later_ns, angles), pose, IDENTITY, stamp_ns=later_ns, uncertainty_m=0.0, memory=memory
        )
