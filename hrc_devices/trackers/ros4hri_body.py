"""ROS4HRI bodies (REP 155): a body's joint states drive a kinematic human model → keypoints → the gateway's capsules.

Pure (no transport, no clock). What a ROS4HRI body tracker (``ros4hri/hri_fullbody``) publishes per tracked body:

- ``/humans/bodies/<id>/joint_states`` (``sensor_msgs/JointState``): the 20 joint angles of a human model generated
  per body from the ``ros4hri/human_description`` template, each joint named ``<joint>_<id>``;
- the body's root pose on ``/tf`` (``tf2_msgs/TFMessage``): frame ``body_<id>`` in the camera's frame;

    JointState ──decode_joint_state──▶ BodyJoints (angles by joint, checked against the model's limits)
    TFMessage  ──decode_body_poses──▶ BodyPose per ``body_<id>`` (parent frame checked)
    BodyJoints + BodyPose + Placement ──body_keypoints (Pinocchio FK)──▶ keypoints in the world
        ──hrc_devices.trackers.skeletons.body_capsules (format :data:`ROS4HRI_BODY`)──▶ BodyCapsules

The model. :func:`human_joints` is our own generator of the template's kinematic structure (the same joint names,
axes, origins and limits, as functions of the body's height), written from ``urdf/human-tpl.xacro`` of
https://github.com/ros4hri/human_description, branch ``humble-devel``, commit
``70669dfeaccc5c7e19215567f8943affae583701`` (2024-02-05, "fix joint limits for the arms"): a size unit
``u = height / 7.5``; the root ``body`` at the hips; ``waist`` (pitch) and a fixed ``torso`` 2.75 u up to the shoulder
line; the head's roll, yaw, pitch 0.25 u above it and the ``head`` frame ``(u/4, 0, u/2)`` further; per arm a yaw,
pitch and roll at ``±0.8 u`` to the side, the ``elbow`` 1.6 u and the ``wrist`` 1 u down the arm; per leg a yaw,
pitch and roll at ``±0.6 u`` from the root, the ``knee`` 1.5 u and the ``ankle`` 2 u down. Straight (all angles 0)
the model stands 7.5 u tall: ankles 3.5 u below the root, the top of the head (a sphere of radius u/2 around the
point 3.5 u above the root) 4 u above it. The joint names in a message carry the body's id
(``hri_fullbody/fullbody_detector.py`` of https://github.com/ros4hri/hri_fullbody, branch ``humble-devel``, commit
``217e77a23425e6023270e3ef6e3697bffea13d8a``: ``js.name = [jn + "_%s" % body_id for jn in HUMAN_JOINT_NAMES]``;
its model is the template at its default height, 1.65 m). :func:`human_urdf` writes the structure as URDF and
:func:`build_human_model` loads it with Pinocchio for the forward kinematics.

Keypoints are the origins of every link frame of the model (:data:`KEYPOINT_NAMES`). A link's origin depends on the
joints above it that have an offset beyond them (a joint turns about an axis through its own origin); a joint the
message leaves out makes every keypoint that depends on it *unseen*, so that the skeleton rule applies: the segment
becomes a sphere around its nearest known joint reaching as far as a P95 body part does, never smaller. The model's
segments are no longer than those P95 lengths for a model up to :data:`MAX_HEIGHT_M` (checked when the model is
built), so the sphere covers wherever the model's part can be. The hands and feet the model lacks are spheres of a P95
hand and foot around the wrists and ankles (the skeleton formats without hands do the same). A missing ``waist``
leaves the torso unplaced: a body placed within the memory time is left out of the frame (lost at the gateway,
:class:`hrc_devices.trackers.skeletons.PersonUnplacedError`), else it is a whole body
(:func:`hrc_devices.trackers.skeletons.whole_body_capsules`).

Hostile input raises :class:`~hrc_devices.trackers.ros2_people.Ros2MessageError` (a
:class:`~hrc_contract.messages.MessageError`, counted like any refused input) with a short ``reason``:
``too_large``, ``not_cdr``, ``bad_stamp``, ``joint_count_mismatch`` (names and positions of unequal length),
``unknown_joint`` (a name that is not ``<joint>_<id>`` of the model), ``duplicate_joint``, ``non_finite`` (an angle,
a translation or a rotation), ``joint_out_of_limits`` (an angle beyond the model's limits by more than
:data:`LIMIT_TOLERANCE_RAD`: absurd, like a keypoint beyond the cell), ``absurd_keypoint`` (a root beyond
±``MAX_COORDINATE_M``), ``bad_quaternion`` (not of unit norm), ``wrong_frame`` (a ``body_<id>`` frame whose parent is
not the configured frame), ``bad_body_id``, ``too_many_people``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin
from rosbags.typesys.store import Typestore

from hrc_devices.trackers.ros2_people import MAX_PEOPLE, Placement, Ros2MessageError, decode_cdr, stamp_ns
from hrc_devices.trackers.skeletons import (
    ANTHROPOMETRY,
    MAX_COORDINATE_M,
    NECK_TO_SHOULDER_M,
    STATURE_M,
    BodyCapsules,
    CompiledFormat,
    FormatSpec,
    PersonMemory,
    body_capsules,
    compile_format,
)

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

JOINT_STATE = "sensor_msgs/msg/JointState"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"

TEMPLATE_HEIGHT_M = 1.65
"""The template's default height, the one ``hri_fullbody`` builds its models at [m]."""
DEFAULT_HEIGHT_M = STATURE_M
"""Height of the model when the cell does not say: the P95 stature of :mod:`hrc_devices.trackers.skeletons` [m]."""
MAX_HEIGHT_M = STATURE_M
"""Tallest model whose segments stay within the P95 lengths of :data:`hrc_devices.trackers.skeletons.ANTHROPOMETRY` (the
upper arm, 1.6 u, is the first to outgrow them) [m]."""
MIN_HEIGHT_M = 1.0
LIMIT_TOLERANCE_RAD = 0.01
"""An angle this far beyond a limit is accepted and clamped to it (an IK solver's rounding) [rad]."""
QUATERNION_TOLERANCE = 0.01
"""A root rotation whose quaternion norm differs from 1 by more than this is refused."""
BODY_FRAME_PREFIX = "body_"
MAX_ID_LENGTH = 64
"""Longest body id (the contract's ``Human.id``)."""


# ---------------------------------------------------------------------------------------------------------------------
# The model
# ---------------------------------------------------------------------------------------------------------------------


class JointSpec(NamedTuple):
    """One joint of the human model, as the template defines it.

    Attributes:
        name: the joint's name without the body id (a message names it ``<name>_<id>``).
        parent, child: link names without the body id.
        origin_m: the child frame's origin in the parent frame [m] (no rotation: the template has none).
        axis: the rotation axis in the child frame; None for a fixed joint.
        lower_rad, upper_rad: the angle's limits [rad] (0 for a fixed joint).
    """

    name: str
    parent: str
    child: str
    origin_m: tuple[float, float, float]
    axis: tuple[float, float, float] | None = None
    lower_rad: float = 0.0
    upper_rad: float = 0.0


def human_joints(height_m: float) -> tuple[JointSpec, ...]:
    """The template's joints for a body ``height_m`` tall, parents before children.

    Source: ``urdf/human-tpl.xacro`` of ros4hri/human_description at ``70669dfeaccc5c7e19215567f8943affae583701``
    (properties ``size_unit = height / 7.5``, ``head_radius = u/2``, ``neck_length = 0.25 u``,
    ``neck_shoulder_length = 0.8 u``, ``upperarm_length = 1.6 u``, ``forearm_length = u``, ``torso_height = 2.75 u``,
    ``waist_length = 1.2 u``, ``tight_length = 1.5 u``, ``tibia_length = 2 u``; macros ``arm`` and ``leg`` with
    ``reflect`` = 1 left, -1 right).
    """
    u = height_m / 7.5
    head_radius = u / 2
    joints = [
        JointSpec("waist", "body", "waist", (0.0, 0.0, 0.0), (0.0, 1.0, 0.0), -0.2, 1.0),
        JointSpec("torso", "waist", "torso", (0.0, 0.0, 2.75 * u)),
        JointSpec("r_head", "torso", "r_head", (0.0, 0.0, 0.25 * u), (1.0, 0.0, 0.0), -1.0, 1.0),
        JointSpec("y_head", "r_head", "y_head", (0.0, 0.0, 0.0), (0.0, 0.0, 1.0), -1.4, 1.4),
        JointSpec("p_head", "y_head", "p_head", (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), -1.5, 1.5),
        JointSpec("head", "p_head", "head", (head_radius / 2, 0.0, head_radius)),
    ]
    for s, reflect in (("l", 1.0), ("r", -1.0)):
        joints += [
            JointSpec(f"{s}_y_shoulder", "torso", f"{s}_y_shoulder", (0.0, reflect * 0.8 * u, 0.0),
                      (0.0, 0.0, -reflect), -1.1, 1.9),
            JointSpec(f"{s}_p_shoulder", f"{s}_y_shoulder", f"{s}_p_shoulder", (0.0, 0.0, 0.0),
                      (reflect, 0.0, 0.0), -0.4, 3.3),
            JointSpec(f"{s}_r_shoulder", f"{s}_p_shoulder", f"{s}_shoulder", (0.0, 0.0, 0.0),
                      (0.0, 0.0, reflect), -1.7, 1.5),
            JointSpec(f"{s}_elbow", f"{s}_shoulder", f"{s}_elbow", (0.0, 0.0, -1.6 * u), (0.0, -1.0, 0.0), 0.0, 2.5),
            JointSpec(f"{s}_wrist", f"{s}_elbow", f"{s}_wrist", (0.0, 0.0, -u)),
        ]  # fmt: skip
    for s, reflect in (("l", 1.0), ("r", -1.0)):
        joints += [
            JointSpec(f"{s}_y_hip", "body", f"{s}_y_hip", (0.0, reflect * 0.6 * u, 0.0), (0.0, 0.0, -1.0), -0.1, 0.6),
            JointSpec(f"{s}_p_hip", f"{s}_y_hip", f"{s}_p_hip", (0.0, 0.0, 0.0), (reflect, 0.0, 0.0), -0.4, 3.3),
            JointSpec(f"{s}_r_hip", f"{s}_p_hip", f"{s}_hip", (0.0, 0.0, 0.0), (0.0, -1.0, 0.0), -0.4, 0.7),
            JointSpec(f"{s}_knee", f"{s}_hip", f"{s}_knee", (0.0, 0.0, -1.5 * u), (0.0, -1.0, 0.0), -2.5, 0.0),
            JointSpec(f"{s}_ankle", f"{s}_knee", f"{s}_ankle", (0.0, 0.0, -2.0 * u)),
        ]  # fmt: skip
    return tuple(joints)


JOINT_NAMES = tuple(j.name for j in human_joints(TEMPLATE_HEIGHT_M) if j.axis is not None)
"""The 20 moving joints, in the order ``hri_fullbody`` publishes them (``HUMAN_JOINT_NAMES``)."""
KEYPOINT_NAMES = ("body", *(j.child for j in human_joints(TEMPLATE_HEIGHT_M)))
"""Every link of the model: its frame origins are the keypoints (27)."""


def human_urdf(height_m: float) -> str:
    """The model as URDF text (links and joints named without a body id; no geometry: kinematics only)."""
    joints = human_joints(height_m)
    lines = ['<?xml version="1.0"?>', '<robot name="human">']
    lines += [f'  <link name="{name}"/>' for name in KEYPOINT_NAMES]
    for j in joints:
        kind = "fixed" if j.axis is None else "revolute"
        lines.append(f'  <joint name="{j.name}" type="{kind}">')
        lines.append(f'    <parent link="{j.parent}"/><child link="{j.child}"/>')
        lines.append(f'    <origin xyz="{j.origin_m[0]!r} {j.origin_m[1]!r} {j.origin_m[2]!r}" rpy="0 0 0"/>')
        if j.axis is not None:
            lines.append(f'    <axis xyz="{j.axis[0]!r} {j.axis[1]!r} {j.axis[2]!r}"/>')
            lines.append(f'    <limit lower="{j.lower_rad!r}" upper="{j.upper_rad!r}" effort="1000" velocity="0.5"/>')
        lines.append("  </joint>")
    lines.append("</robot>")
    return "\n".join(lines)


@dataclass(frozen=True)
class HumanModel:
    """The Pinocchio model of one body height and what each keypoint depends on.

    Attributes:
        height_m: the body's height [m].
        model: the Pinocchio model (read-only; each call makes its own data).
        q_index: joint name → its index in the configuration vector.
        limits_rad: joint name → (lower, upper) [rad].
        keypoint_frames: the Pinocchio frame of each of :data:`KEYPOINT_NAMES`.
        depends_on: per keypoint, the joints whose angles move its origin.
    """

    height_m: float
    model: pin.Model
    q_index: Mapping[str, int]
    limits_rad: Mapping[str, tuple[float, float]]
    keypoint_frames: tuple[int, ...]
    depends_on: tuple[frozenset[str], ...]


def build_human_model(height_m: float = DEFAULT_HEIGHT_M) -> HumanModel:
    """Generate the URDF of a body ``height_m`` tall and load it with Pinocchio.

    Raises:
        ValueError: ``height_m`` not finite or outside [:data:`MIN_HEIGHT_M`, :data:`MAX_HEIGHT_M`] (a taller model
            outgrows the reach spheres that stand for a missing joint).
    """
    if not (math.isfinite(height_m) and MIN_HEIGHT_M <= height_m <= MAX_HEIGHT_M):
        raise ValueError(f"body height {height_m} m; allowed: {MIN_HEIGHT_M} to {MAX_HEIGHT_M} m")
    _check_within_reach(human_joints(height_m))
    model = pin.buildModelFromXML(human_urdf(height_m))
    q_index = {name: int(model.joints[model.getJointId(name)].idx_q) for name in JOINT_NAMES}
    limits = {
        name: (float(model.lowerPositionLimit[i]), float(model.upperPositionLimit[i])) for name, i in q_index.items()
    }
    frames, depends = [], []
    for name in KEYPOINT_NAMES:
        frame_id = int(model.getFrameId(name, pin.FrameType.BODY))
        frames.append(frame_id)
        depends.append(_moved_by(model, frame_id))
    return HumanModel(height_m, model, q_index, limits, tuple(frames), tuple(depends))


def _moved_by(model: pin.Model, frame_id: int) -> frozenset[str]:
    """The joints whose angle moves a frame's origin: those of its chain with an offset after them (a joint
    rotates about an axis through its own origin, so it moves only what lies at a distance beyond it)."""
    frame = model.frames[frame_id]
    chain = [int(j) for j in model.supports[frame.parentJoint] if j > 0]
    offsets = [bool(np.any(model.jointPlacements[j].translation)) for j in chain[1:]]
    offsets.append(bool(np.any(frame.placement.translation)))
    return frozenset(str(model.names[j]) for i, j in enumerate(chain) if any(offsets[i:]))


def _check_within_reach(joints: tuple[JointSpec, ...]) -> None:
    """The model's segments no longer than the P95 ones their reach spheres assume.

    Raises:
        ValueError: a segment longer (the message names it).
    """
    by_name = {j.name: j for j in joints}
    lengths = {
        "upper_arm": abs(by_name["l_elbow"].origin_m[2]),
        "forearm": abs(by_name["l_wrist"].origin_m[2]),
        "thigh": abs(by_name["l_knee"].origin_m[2]),
        "shin": abs(by_name["l_ankle"].origin_m[2]),
    }
    for segment, length_m in lengths.items():
        if length_m > ANTHROPOMETRY[segment].length_m + 1e-3:
            raise ValueError(f"the model's {segment} is {length_m:.3f} m, longer than P95's {ANTHROPOMETRY[segment]}")
    if abs(by_name["l_y_shoulder"].origin_m[1]) > NECK_TO_SHOULDER_M:
        raise ValueError("the model's shoulders are wider than P95's")


ROS4HRI_BODY = FormatSpec(
    "ros4hri_body",
    KEYPOINT_NAMES,
    {
        "pelvis": ("body", "waist"),
        "neck": ("torso", "r_head", "y_head", "p_head"),
        "head": ("head",),
        **{
            f"{group}_{side}": tuple(f"{side}_{n}" for n in names)
            for side in ("l", "r")
            for group, names in {
                "shoulder": ("y_shoulder", "p_shoulder", "shoulder"),
                "elbow": ("elbow",),
                "wrist": ("wrist",),
                "hand": (),
                "hip": ("y_hip", "p_hip", "hip"),
                "knee": ("knee",),
                "ankle": ("ankle",),
                "foot": (),
            }.items()
        },
    },
    {},
)
"""The model's links as the skeleton's joint groups (no hand, no foot: spheres of a P95 hand and foot around the
wrists and ankles)."""
ROS4HRI_COMPILED: CompiledFormat = compile_format(ROS4HRI_BODY)


# ---------------------------------------------------------------------------------------------------------------------
# Messages
# ---------------------------------------------------------------------------------------------------------------------


class BodyJoints(NamedTuple):
    """A body's joint angles from one JointState: by joint name without the id [rad], within the limits."""

    stamp_ns: int
    angles_rad: Mapping[str, float]


class BodyPose(NamedTuple):
    """The ``body_<id>`` frame in its parent frame: ``p_parent = R_parent_body @ p_body + p_parent_body`` [m]."""

    body_id: str
    stamp_ns: int
    R_parent_body: FloatArray
    p_parent_body: FloatArray


def check_body_id(body_id: str) -> str:
    """A body id as a person id: 1 to 64 characters.

    Raises:
        Ros2MessageError: ``bad_body_id``.
    """
    if not 0 < len(body_id) <= MAX_ID_LENGTH:
        raise Ros2MessageError("bad_body_id", f"body id of {len(body_id)} characters; allowed: 1 to {MAX_ID_LENGTH}")
    return body_id


def joint_angles(human: HumanModel, body_id: str, names: list[str], positions: FloatArray) -> dict[str, float]:
    """Check a JointState's names and positions against the model; the angles by joint name.

    Raises:
        Ros2MessageError: ``joint_count_mismatch``, ``unknown_joint``, ``duplicate_joint``, ``non_finite``,
            ``joint_out_of_limits``.
    """
    if len(names) != len(positions):
        raise Ros2MessageError(
            "joint_count_mismatch", f"{len(names)} names and {len(positions)} positions; allowed: as many"
        )
    suffix = f"_{body_id}"
    angles: dict[str, float] = {}
    for name, value in zip(names, positions.tolist(), strict=True):
        joint = name[: -len(suffix)] if name.endswith(suffix) else ""
        if joint not in human.q_index:
            raise Ros2MessageError(
                "unknown_joint", f"joint {name[:80]!r} of body {body_id!r}; allowed: <joint>_{body_id} of {JOINT_NAMES}"
            )
        if joint in angles:
            raise Ros2MessageError("duplicate_joint", f"joint {name[:80]!r} twice")
        if not math.isfinite(value):
            raise Ros2MessageError("non_finite", f"joint {name[:80]!r} angle {value}")
        lower, upper = human.limits_rad[joint]
        if not lower - LIMIT_TOLERANCE_RAD <= value <= upper + LIMIT_TOLERANCE_RAD:
            raise Ros2MessageError(
                "joint_out_of_limits", f"joint {name[:80]!r} at {value:.4g} rad; allowed: {lower} to {upper} rad"
            )
        angles[joint] = min(max(value, lower), upper)
    return angles


def decode_joint_state(payload: bytes, store: Typestore, human: HumanModel, body_id: str) -> BodyJoints:
    """A ``sensor_msgs/msg/JointState`` of body ``body_id`` → its checked angles (velocities and efforts unused).

    Raises:
        Ros2MessageError: ``too_large``, ``not_cdr``, ``bad_stamp``, and those of :func:`joint_angles`.
    """
    msg = decode_cdr(payload, JOINT_STATE, store)
    positions = np.asarray(msg.position, dtype=np.float64).reshape(-1)
    angles = joint_angles(human, check_body_id(body_id), [str(n) for n in msg.name], positions)
    return BodyJoints(stamp_ns(msg.header), angles)


def rotation_of_quaternion(x: float, y: float, z: float, w: float) -> FloatArray:
    """The rotation matrix of a unit quaternion (ROS order x, y, z, w).

    Raises:
        Ros2MessageError: ``non_finite``, ``bad_quaternion`` (norm off 1 by more than :data:`QUATERNION_TOLERANCE`).
    """
    q = np.array([w, x, y, z], dtype=np.float64)
    if not np.isfinite(q).all():
        raise Ros2MessageError("non_finite", "a rotation is not finite")
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUATERNION_TOLERANCE:
        raise Ros2MessageError("bad_quaternion", f"quaternion of norm {norm:.4g}; allowed: 1 ± {QUATERNION_TOLERANCE}")
    w, x, y, z = (q / norm).tolist()
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _body_pose(transform: Any, body_id: str) -> BodyPose:
    t, r = transform.transform.translation, transform.transform.rotation
    translation = np.array([t.x, t.y, t.z], dtype=np.float64)
    if not np.isfinite(translation).all():
        raise Ros2MessageError("non_finite", f"body {body_id[:80]!r}: translation not finite")
    if float(np.abs(translation).max()) > MAX_COORDINATE_M:
        raise Ros2MessageError("absurd_keypoint", f"body {body_id[:80]!r} beyond ±{MAX_COORDINATE_M} m")
    rotation = rotation_of_quaternion(float(r.x), float(r.y), float(r.z), float(r.w))
    return BodyPose(body_id, stamp_ns(transform.header), rotation, translation)


def decode_body_poses(payload: bytes, store: Typestore, parent_frame: str | None) -> tuple[BodyPose, ...]:
    """A ``tf2_msgs/msg/TFMessage`` → the poses of the ``body_<id>`` frames in it (newest per body); every other
    transform of /tf is ignored (the model's own links, other robots).

    Args:
        parent_frame: the frame a body's transform must be given in (the camera's); None: any.

    Raises:
        Ros2MessageError: ``too_large``, ``not_cdr``, ``wrong_frame``, ``bad_body_id``, ``too_many_people``, and those
            of a pose: ``bad_stamp``, ``non_finite``, ``absurd_keypoint``, ``bad_quaternion``.
    """
    msg = decode_cdr(payload, TF_MESSAGE, store)
    poses: dict[str, BodyPose] = {}
    for transform in msg.transforms:
        child = str(transform.child_frame_id)
        if not child.startswith(BODY_FRAME_PREFIX):
            continue
        body_id = check_body_id(child[len(BODY_FRAME_PREFIX) :])
        parent = str(transform.header.frame_id)
        if parent_frame is not None and parent != parent_frame:
            raise Ros2MessageError("wrong_frame", f"{child[:80]!r} in frame {parent[:80]!r}; expected {parent_frame!r}")
        pose = _body_pose(transform, body_id)
        if body_id not in poses and len(poses) >= MAX_PEOPLE:
            raise Ros2MessageError("too_many_people", f"more than {MAX_PEOPLE} bodies in one TF message")
        if body_id not in poses or pose.stamp_ns >= poses[body_id].stamp_ns:
            poses[body_id] = pose
    return tuple(poses.values())


# ---------------------------------------------------------------------------------------------------------------------
# Keypoints and capsules
# ---------------------------------------------------------------------------------------------------------------------


def body_keypoints(human: HumanModel, angles_rad: Mapping[str, float]) -> tuple[FloatArray, BoolArray]:
    """Forward kinematics: the keypoints (:data:`KEYPOINT_NAMES`) in the ``body_<id>`` frame.

    Args:
        human: the model.
        angles_rad: the known joint angles by name [rad] (checked: :func:`joint_angles`); a joint left out is
            unknown.

    Returns:
        keypoints, shape (27, 3) [m], and which are known (a keypoint is unknown when a joint it depends on is).
    """
    q = np.zeros(human.model.nq)
    for name, angle in angles_rad.items():
        q[human.q_index[name]] = angle
    data = human.model.createData()
    pin.framesForwardKinematics(human.model, data, q)
    keypoints = np.array([data.oMf[f].translation for f in human.keypoint_frames], dtype=np.float64)
    known = frozenset(angles_rad)
    seen = np.array([deps <= known for deps in human.depends_on], dtype=bool)
    return keypoints, seen


def body_capsules_world(
    human: HumanModel,
    joints: BodyJoints,
    pose: BodyPose,
    placement: Placement,
    *,
    stamp_ns: int,
    uncertainty_m: float,
    memory: PersonMemory | None = None,
    memory_s: float = 1.0,
    floor_z_m: float = 0.0,
) -> tuple[BodyCapsules, PersonMemory]:
    """One body's capsules in the world frame: FK in the body frame, the root pose into the parent (camera) frame,
    the placement into the world, then :func:`hrc_devices.trackers.skeletons.body_capsules`.

    Args:
        human: the model.
        joints: the body's angles.
        pose: its ``body_<id>`` frame in the parent frame.
        placement: the parent frame in the world.
        stamp_ns, uncertainty_m, memory, memory_s, floor_z_m: see :func:`hrc_devices.trackers.skeletons.body_capsules`.

    Raises:
        SkeletonError: a keypoint beyond the world's bounds.
    """
    keypoints_body, seen = body_keypoints(human, joints.angles_rad)
    keypoints_parent = keypoints_body @ pose.R_parent_body.T + pose.p_parent_body
    keypoints_world = keypoints_parent @ placement.R_world_sensor.T + placement.p_world_sensor
    return body_capsules(
        ROS4HRI_COMPILED,
        np.where(seen[:, None], keypoints_world, 0.0),
        seen,
        stamp_ns=stamp_ns,
        uncertainty_m=uncertainty_m,
        memory=memory,
        memory_s=memory_s,
        floor_z_m=floor_z_m,
    )
