"""A human body as capsules: one ~1.75 m adult standing on the floor, possibly reaching forward.

The body is built in its own frame (forward, left, up) with the origin on the floor between the feet,
then turned by the heading and moved to the floor position. Upper-body points lean forward about the
hips while reaching; the arm angles are measured from the vertical, so that the hand of a fully
stretched arm ends at about table height, :data:`REACH_FORWARD_M` in front of the body's centre line.

Proportions follow adult anthropometric tables (stature 1.75 m: shoulder height ≈ 0.82 of the
stature, hip joint ≈ 0.51, knee ≈ 0.285, upper arm ≈ 0.17, forearm ≈ 0.155); radii are generous
rather than tight, since they stand for a tracked body including clothes and tracking error.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

Vector = npt.NDArray[np.float64]

STATURE_M = 1.75
"""Top of the head above the floor [m]."""

CAPSULE_NAMES = (
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
)
"""Names of the capsules of one body, in the order :func:`body_capsules` returns them."""

# Body frame: x forward, y left, z up, origin on the floor between the feet [m].
HIP_PIVOT_Z_M = 0.95
"""Height of the axis the upper body leans about [m]."""
SHOULDER_Y_M = 0.19
SHOULDER_Z_M = 1.44
UPPER_ARM_M = 0.30
FOREARM_M = 0.27
HAND_M = 0.08
"""Wrist to the middle of the fingers; the capsule radius covers the finger tips [m]."""

LEAN_MAX_RAD = 0.35
"""Forward lean of the upper body at reach 1 (≈ 20°) [rad]."""
SHOULDER_FLEXION_RAD = (0.05, 1.08)
"""Angle of the upper arm from the vertical, hanging and fully reached (≈ 62°: hand at table height) [rad]."""
ELBOW_FLEXION_RAD = (0.20, 0.0)
"""Extra flexion of the forearm relative to the upper arm, hanging and fully reached [rad]."""
ADDUCTION_RAD = (-0.05, 0.165)
"""Angle of the arm towards the body's midline, hanging (slightly outward) and fully reached [rad]."""

REACH_FORWARD_M = 0.73
"""Distance of the end of the hand in front of the body's centre line at reach 1 [m]."""

_RADIUS_M = {
    "head": 0.11,
    "torso": 0.17,
    "pelvis": 0.13,
    "upper_arm": 0.05,
    "forearm": 0.045,
    "hand": 0.05,
    "thigh": 0.08,
    "shin": 0.06,
}


class BodyCapsule(NamedTuple):
    """A capsule of a body in the world frame: the segment ``a``–``b`` [m] swept by a sphere of ``radius_m``."""

    name: str
    a: Vector
    b: Vector
    radius_m: float


@dataclass(frozen=True)
class BodyPose:
    """Where a person stands and what they do.

    Attributes:
        x_m, y_m: position on the floor in the world frame (between the feet) [m].
        heading_rad: direction the person faces, from the world x axis towards y [rad].
        reach: how far the right arm is stretched forward at table height, in [0, 1]
            (0 = hanging, 1 = fully stretched, upper body leaning forward).
        both_arms: the left arm reaches like the right one (otherwise it hangs).
    """

    x_m: float
    y_m: float
    heading_rad: float
    reach: float = 0.0
    both_arms: bool = False

    def __post_init__(self) -> None:
        if not all(np.isfinite([self.x_m, self.y_m, self.heading_rad, self.reach])):
            raise ValueError(f"pose values must be finite, got {self}")
        if not 0.0 <= self.reach <= 1.0:
            raise ValueError(f"reach = {self.reach}; allowed: 0 <= reach <= 1")


def _radius_m(name: str) -> float:
    return _RADIUS_M[name.removesuffix("_l").removesuffix("_r")]


def _lerp(pair: tuple[float, float], s: float) -> float:
    return pair[0] + (pair[1] - pair[0]) * s


def _lean(points: Vector, lean_rad: float) -> Vector:
    """Points of the upper body rotated forward about the hip axis (y axis at height HIP_PIVOT_Z_M)."""
    c, s = np.cos(lean_rad), np.sin(lean_rad)
    x, y, z = points[:, 0], points[:, 1], points[:, 2] - HIP_PIVOT_Z_M
    return np.column_stack((c * x + s * z, y, HIP_PIVOT_Z_M + c * z - s * x))


def _arm_points(shoulder: Vector, reach: float, side: float) -> tuple[Vector, Vector, Vector]:
    """Elbow, wrist and hand end of one arm in the body frame [m]; ``side`` is +1 left, -1 right."""
    flexion = _lerp(SHOULDER_FLEXION_RAD, reach)
    forearm_flexion = flexion + _lerp(ELBOW_FLEXION_RAD, reach)
    inward = -side * np.sin(_lerp(ADDUCTION_RAD, reach))
    across = np.sqrt(1.0 - inward**2)

    def direction(angle_rad: float) -> Vector:
        return np.array([np.sin(angle_rad) * across, inward, -np.cos(angle_rad) * across])

    elbow = shoulder + UPPER_ARM_M * direction(flexion)
    wrist = elbow + FOREARM_M * direction(forearm_flexion)
    hand = wrist + HAND_M * direction(forearm_flexion)
    return elbow, wrist, hand


def body_capsules_local(reach: float = 0.0, both_arms: bool = False) -> tuple[BodyCapsule, ...]:
    """The capsules of a body standing at the origin of its own frame (x forward, y left, z up).

    Args:
        reach: arm stretch in [0, 1] (see :class:`BodyPose`).
        both_arms: the left arm reaches too.

    Returns:
        One capsule per name of :data:`CAPSULE_NAMES`, in that order [m].
    """
    lean_rad = LEAN_MAX_RAD * reach
    # Points that lean with the upper body: head, torso, shoulders.
    head_a, head_b, torso_a, torso_b, shoulder_l, shoulder_r = _lean(
        np.array(
            [
                [0.0, 0.0, 1.57],
                [0.0, 0.0, STATURE_M - _RADIUS_M["head"]],
                [0.0, 0.0, 1.12],
                [0.0, 0.0, 1.36],
                [0.0, SHOULDER_Y_M, SHOULDER_Z_M],
                [0.0, -SHOULDER_Y_M, SHOULDER_Z_M],
            ]
        ),
        lean_rad,
    )
    elbow_l, wrist_l, hand_l = _arm_points(shoulder_l, reach if both_arms else 0.0, side=1.0)
    elbow_r, wrist_r, hand_r = _arm_points(shoulder_r, reach, side=-1.0)
    # The lower body stands still; the shins end one radius above the floor, so the feet touch it.
    hip_l, knee_l, ankle_l = np.array([[0.0, 0.09, 0.90], [0.02, 0.10, 0.50], [0.0, 0.10, _RADIUS_M["shin"]]])
    hip_r, knee_r, ankle_r = hip_l * [1, -1, 1], knee_l * [1, -1, 1], ankle_l * [1, -1, 1]
    pelvis_a, pelvis_b = np.array([[0.0, 0.08, 0.93], [0.0, -0.08, 0.93]])
    segments = {
        "head": (head_a, head_b),
        "torso": (torso_a, torso_b),
        "pelvis": (pelvis_a, pelvis_b),
        "upper_arm_l": (shoulder_l, elbow_l),
        "upper_arm_r": (shoulder_r, elbow_r),
        "forearm_l": (elbow_l, wrist_l),
        "forearm_r": (elbow_r, wrist_r),
        "hand_l": (wrist_l, hand_l),
        "hand_r": (wrist_r, hand_r),
        "thigh_l": (hip_l, knee_l),
        "thigh_r": (hip_r, knee_r),
        "shin_l": (knee_l, ankle_l),
        "shin_r": (knee_r, ankle_r),
    }
    return tuple(
        BodyCapsule(name, np.asarray(a, dtype=float), np.asarray(b, dtype=float), _radius_m(name))
        for name, (a, b) in segments.items()
    )


def body_capsules(pose: BodyPose) -> tuple[BodyCapsule, ...]:
    """The capsules of a body in the world frame.

    Args:
        pose: floor position [m], heading [rad] and reach of the person.

    Returns:
        One capsule per name of :data:`CAPSULE_NAMES`, in that order, in world coordinates [m];
        the arrays are read-only.
    """
    local = body_capsules_local(pose.reach, pose.both_arms)
    c, s = np.cos(pose.heading_rad), np.sin(pose.heading_rad)
    R_world_body = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    p_world_body = np.array([pose.x_m, pose.y_m, 0.0])
    a_body = np.array([cap.a for cap in local])
    b_body = np.array([cap.b for cap in local])
    a_world = a_body @ R_world_body.T + p_world_body
    b_world = b_body @ R_world_body.T + p_world_body
    a_world.setflags(write=False)
    b_world.setflags(write=False)
    return tuple(BodyCapsule(cap.name, a_world[i], b_world[i], cap.radius_m) for i, cap in enumerate(local))
