"""Skeletons become capsules: 3D keypoints of a body tracker → the gateway's body capsules.

Pure (no transport, no clock): keypoints in the cell's world frame (z up) [m], a mask of the keypoints the tracker
saw, and a small per-person memory passed in and returned.

    keypoints (N, 3) + seen (N,) ──body_capsules──▶ BodyCapsules (names, a, b, radius) + PersonMemory

Formats (:data:`FORMATS`): ZED ``BODY_34`` and ``BODY_38`` (``zed_msgs/Object.body_format`` 1 and 2), Azure Kinect
body tracking (K4ABT, 32 joints), COCO-17 and OpenPose BODY_25 in 3D, MediaPipe Pose (33 landmarks). The keypoint
orders are the publishers' own (see each ``*_NAMES`` constant for its source).

Capsules. Each capsule of :data:`SEGMENTS` joins two keypoint groups (an end is the mean of its group's seen
keypoints); its radius is the larger of the anthropometric radius (:data:`ANTHROPOMETRY`) and the distance of every
seen keypoint assigned to it, plus the tracker's stated uncertainty. So every seen keypoint lies inside a capsule
(by construction, not by luck). The names are the gateway's (``tracker_emu.body``: ``head``, ``torso``, ``pelvis``,
``upper_arm_l`` …), plus ``shoulders`` and ``foot_l``/``foot_r``; a format always yields the same names.

Missing keypoints never shrink a person. A capsule whose end is not seen becomes a sphere around the nearest seen
joint of its chain (elbow, shoulder, neck for a forearm) with the radius of everything beyond it (forearm length
for an elbow, upper arm + forearm for a shoulder, P95 lengths), enclosed together with the capsule last seen for
that segment (:class:`PersonMemory`, kept ``memory_s``) in one capsule (:func:`enclosing_capsule`): the part is
covered wherever it can be now, and the volume covered a frame ago is still covered. A person whose torso cannot
be placed (no pelvis or no neck) is reported as a whole body: vertical capsules around what is seen, grown to a
P95 stature (:data:`WHOLE_BODY_NAMES`), never dropped.

Plausibility at the gateway's door: reach spheres reach :data:`MAX_RADIUS_M` + uncertainty and the whole body's
capsules :data:`WHOLE_BODY_PIECE_M` long; a cell that reads skeleton trackers needs ``max_capsule_radius_m`` above
that, or the door refuses such a frame (``radius_too_large``: counted, δ = 0).

Hostile input raises :class:`SkeletonError` (a :class:`~hrc_contract.messages.MessageError`, counted like native
input): a seen keypoint that is not finite (``non_finite``) or beyond :data:`MAX_COORDINATE_M` (``absurd_keypoint``),
a keypoint array of the wrong shape (``wrong_keypoint_count``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hrc_contract.messages import Capsule, Human, MessageError

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

MAX_COORDINATE_M = 100.0
"""A seen keypoint farther than this from the world origin on any axis is not a person in a cell [m]."""

# ---------------------------------------------------------------------------------------------------------------------
# Anthropometry
# ---------------------------------------------------------------------------------------------------------------------


class SegmentSize(NamedTuple):
    """Size of a body segment: radius of the capsule around its axis and the longest the axis can be [m]."""

    radius_m: float
    length_m: float


ANTHROPOMETRY: dict[str, SegmentSize] = {
    "head": SegmentSize(0.145, 0.30),
    "torso": SegmentSize(0.19, 0.65),
    "shoulders": SegmentSize(0.09, 0.45),
    "pelvis": SegmentSize(0.15, 0.35),
    "upper_arm": SegmentSize(0.070, 0.40),
    "forearm": SegmentSize(0.060, 0.31),
    "hand": SegmentSize(0.05, 0.21),
    "thigh": SegmentSize(0.120, 0.52),
    "shin": SegmentSize(0.075, 0.52),
    "foot": SegmentSize(0.06, 0.295),
}
"""Radius and longest length per segment [m]: men's 95th percentile of the 2012 U.S. Army anthropometric survey
(ANSUR II; Gordon et al., NATICK/TR-15/007, 2014), rounded up to the next 5 mm, computed (unweighted percentiles)
from the survey's public per-person file ``ANSUR_II_MALE_Public.csv`` (n = 4,082; e.g. GitHub KhadijehValipour/ANSUR
at d20788f), 2026-12-02. Radii are half the breadth or ``circumference / 2π``: head, tragion to top of head (P95
141 mm); torso, half the chest breadth (320); upper arm, biceps circumference flexed (418); forearm, forearm
circumference flexed (348); hand, half the hand breadth (96); thigh, thigh circumference (723); shin, calf
circumference (443); foot, half the foot breadth (111); shoulders and pelvis: half the difference of the bideltoid
and biacromial breadths (135) and half the buttock depth (291), rounded up generously. Lengths: neck to vertex
(stature − cervicale height, 260), biacromial breadth (447), bi-iliac breadth (305), shoulder–elbow length (394),
radiale–stylion (295; forearm + hand 0.52 m ≥ forearm–hand length 520), hand length (210), knee joint to hip joint
(trochanterion − lateral femoral epicondyle height, 458) and ankle to knee joint (lateral femoral epicondyle −
lateral malleolus height, 460), both taken as 0.52 m, foot length (293). The torso's 0.65 m (cervicale −
trochanterion height, 667) only bounds a torso with no far end seen, which no format has. Never below the tracker
emulator's radii (``tracker_emu.body``). They stand for a large man, clothes excluded (the uncertainty parameter adds
the tracker's error)."""

STATURE_M = 1.87
"""Stature, men's 95th percentile (ANSUR II, as above) [m]: the height of a whole-body report."""
NECK_TO_SHOULDER_M = 0.25
"""Neck keypoint to a shoulder joint: half the biacromial breadth (P95 447 mm), rounded up [m]."""
PELVIS_TO_HIP_M = 0.155
"""Pelvis keypoint to a hip joint: half the bi-iliac breadth (P95 305 mm), rounded up [m]."""
WHOLE_BODY_RADIUS_M = 0.30
"""Radius of a whole-body report around the vertical through what is seen: half the bideltoid breadth (P95) [m]."""
WHOLE_BODY_PIECE_M = 0.90
"""Longest capsule of a whole-body report (its height is cut into pieces no longer than this) [m]."""


def _reach_m(*segments: str) -> float:
    return sum(ANTHROPOMETRY[s].length_m for s in segments)


# ---------------------------------------------------------------------------------------------------------------------
# Formats
# ---------------------------------------------------------------------------------------------------------------------

ZED_34_NAMES = (
    "pelvis", "naval_spine", "chest_spine", "neck", "left_clavicle", "left_shoulder", "left_elbow", "left_wrist",
    "left_hand", "left_handtip", "left_thumb", "right_clavicle", "right_shoulder", "right_elbow", "right_wrist",
    "right_hand", "right_handtip", "right_thumb", "left_hip", "left_knee", "left_ankle", "left_foot", "right_hip",
    "right_knee", "right_ankle", "right_foot", "head", "nose", "left_eye", "left_ear", "right_eye", "right_ear",
    "left_heel", "right_heel",
)  # fmt: skip
"""ZED SDK ``BODY_34_PARTS`` (``sl::BODY_34_PARTS``, the SDK's own enum as its Unity plugin spells it)."""

K4ABT_32_NAMES = ZED_34_NAMES[:32]
"""Azure Kinect ``k4abt_joint_id_t`` (``K4ABT_JOINT_PELVIS`` = 0 … ``K4ABT_JOINT_EAR_RIGHT`` = 31): the first 32 of
``BODY_34`` (the ZED format extends K4ABT's by the heels)."""

ZED_38_NAMES = (
    "pelvis", "spine_1", "spine_2", "spine_3", "neck", "nose", "left_eye", "right_eye", "left_ear", "right_ear",
    "left_clavicle", "right_clavicle", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
    "right_wrist", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_big_toe",
    "right_big_toe", "left_small_toe", "right_small_toe", "left_heel", "right_heel", "left_hand_thumb_4",
    "right_hand_thumb_4", "left_hand_index_1", "right_hand_index_1", "left_hand_middle_4", "right_hand_middle_4",
    "left_hand_pinky_1", "right_hand_pinky_1",
)  # fmt: skip
"""ZED SDK ``BODY_38_PARTS``."""

ZED_18_NAMES = (
    "nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder", "left_elbow", "left_wrist",
    "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle", "right_eye", "left_eye",
    "right_ear", "left_ear",
)  # fmt: skip
"""ZED SDK ``BODY_18_PARTS`` (the OpenPose COCO-18 order)."""

COCO_17_NAMES = (
    "nose", "left_eye", "right_eye", "left_ear", "right_ear", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
    "right_ankle",
)  # fmt: skip
"""COCO keypoints (cocodataset.org, ``person_keypoints``)."""

BODY_25_NAMES = (
    "nose", "neck", "right_shoulder", "right_elbow", "right_wrist", "left_shoulder", "left_elbow", "left_wrist",
    "mid_hip", "right_hip", "right_knee", "right_ankle", "left_hip", "left_knee", "left_ankle", "right_eye",
    "left_eye", "right_ear", "left_ear", "left_big_toe", "left_small_toe", "left_heel", "right_big_toe",
    "right_small_toe", "right_heel",
)  # fmt: skip
"""OpenPose ``BODY_25`` (doc/02_output.md of CMU-Perceptual-Computing-Lab/openpose)."""

MEDIAPIPE_33_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye", "right_eye_outer",
    "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder", "right_shoulder", "left_elbow",
    "right_elbow", "left_wrist", "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index",
    "left_thumb", "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle",
    "left_heel", "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip
"""MediaPipe Pose landmarks (``PoseLandmark``, 33; world landmarks in metres)."""


class FormatSpec(NamedTuple):
    """Which keypoints of a format make each joint group of the body (names of the format's keypoints)."""

    name: str
    keypoint_names: tuple[str, ...]
    groups: dict[str, tuple[str, ...]]
    """Joint group → keypoint names: ``pelvis``, ``neck``, ``head``, ``shoulder_l``, ``elbow_l``, ``wrist_l``,
    ``hand_l`` (hand end; empty: the format has no hand), ``hip_l``, ``knee_l``, ``ankle_l``, ``foot_l`` (empty:
    no foot), and ``_r``; every keypoint of the format belongs to some group or to ``extra`` members of a capsule."""
    extra: dict[str, tuple[str, ...]]
    """Capsule name → further keypoints it must cover (spine keypoints for the torso, clavicles for the shoulders)."""


def _sides(groups: dict[str, tuple[str, ...]]) -> dict[str, tuple[str, ...]]:
    """Expand ``{"shoulder": ("{s}_shoulder",)}`` into ``shoulder_l``/``shoulder_r`` with ``left``/``right``."""
    out: dict[str, tuple[str, ...]] = {}
    for key, names in groups.items():
        if "{s}" not in "".join(names) and key in ("pelvis", "neck", "head"):
            out[key] = names
            continue
        out[f"{key}_l"] = tuple(n.format(s="left") for n in names)
        out[f"{key}_r"] = tuple(n.format(s="right") for n in names)
    return out


_FACE = ("nose", "left_eye", "right_eye", "left_ear", "right_ear")
_LIMBS = {"shoulder": ("{s}_shoulder",), "elbow": ("{s}_elbow",), "wrist": ("{s}_wrist",)}
_LEGS = {"hip": ("{s}_hip",), "knee": ("{s}_knee",), "ankle": ("{s}_ankle",)}
_SHOULDERS = ("left_shoulder", "right_shoulder")
_HIPS = ("left_hip", "right_hip")

ZED_34 = FormatSpec(
    "zed_body_34",
    ZED_34_NAMES,
    _sides(
        {
            "pelvis": ("pelvis", *_HIPS),
            "neck": ("neck", *_SHOULDERS),
            "head": ("head", *_FACE),
            **_LIMBS,
            "hand": ("{s}_hand", "{s}_handtip", "{s}_thumb"),
            **_LEGS,
            "foot": ("{s}_foot", "{s}_heel"),
        }
    ),
    {"torso": ("naval_spine", "chest_spine"), "shoulders": ("left_clavicle", "right_clavicle")},
)
K4ABT_32 = FormatSpec(
    "k4abt_32",
    K4ABT_32_NAMES,
    {**ZED_34.groups, "foot_l": ("left_foot",), "foot_r": ("right_foot",)},
    ZED_34.extra,
)
ZED_38 = FormatSpec(
    "zed_body_38",
    ZED_38_NAMES,
    _sides(
        {
            "pelvis": ("pelvis", *_HIPS),
            "neck": ("neck", *_SHOULDERS),
            "head": _FACE,
            **_LIMBS,
            "hand": ("{s}_hand_thumb_4", "{s}_hand_index_1", "{s}_hand_middle_4", "{s}_hand_pinky_1"),
            **_LEGS,
            "foot": ("{s}_big_toe", "{s}_small_toe", "{s}_heel"),
        }
    ),
    {"torso": ("spine_1", "spine_2", "spine_3"), "shoulders": ("left_clavicle", "right_clavicle")},
)
COCO_17 = FormatSpec(
    "coco_17",
    COCO_17_NAMES,
    _sides({"pelvis": _HIPS, "neck": _SHOULDERS, "head": _FACE, **_LIMBS, "hand": (), **_LEGS, "foot": ()}),
    {},
)
ZED_18 = FormatSpec(
    "zed_body_18",
    ZED_18_NAMES,
    _sides({"pelvis": _HIPS, "neck": ("neck", *_SHOULDERS), "head": _FACE, **_LIMBS, "hand": (), **_LEGS, "foot": ()}),
    {},
)
BODY_25 = FormatSpec(
    "body_25",
    BODY_25_NAMES,
    _sides(
        {
            "pelvis": ("mid_hip", *_HIPS),
            "neck": ("neck", *_SHOULDERS),
            "head": _FACE,
            **_LIMBS,
            "hand": (),
            **_LEGS,
            "foot": ("{s}_big_toe", "{s}_small_toe", "{s}_heel"),
        }
    ),
    {},
)
MEDIAPIPE_33 = FormatSpec(
    "mediapipe_33",
    MEDIAPIPE_33_NAMES,
    _sides(
        {
            "pelvis": _HIPS,
            "neck": _SHOULDERS,
            "head": (*_FACE, "left_eye_inner", "left_eye_outer", "right_eye_inner", "right_eye_outer", "mouth_left",
                     "mouth_right"),
            **_LIMBS,
            "hand": ("{s}_pinky", "{s}_index", "{s}_thumb"),
            **_LEGS,
            "foot": ("{s}_heel", "{s}_foot_index"),
        }
    ),
    {},
)  # fmt: skip

FORMATS = {f.name: f for f in (ZED_18, ZED_34, ZED_38, K4ABT_32, COCO_17, BODY_25, MEDIAPIPE_33)}
"""Every supported format by name."""


# ---------------------------------------------------------------------------------------------------------------------
# Segments
# ---------------------------------------------------------------------------------------------------------------------


class SegmentSpec(NamedTuple):
    """A capsule of the body: from joint group ``a`` to ``b`` (``b`` empty: a sphere around ``a`` of the
    segment's length), and where it can be when not seen: ``(group, radius_m)`` nearest first."""

    name: str
    size: str
    a: str
    b: str
    fallbacks: tuple[tuple[str, float], ...]


def _limb(side: str) -> tuple[SegmentSpec, ...]:
    s = f"_{side}"
    neck_reach = NECK_TO_SHOULDER_M
    pelvis_reach = PELVIS_TO_HIP_M
    return (
        SegmentSpec(
            f"upper_arm{s}",
            "upper_arm",
            f"shoulder{s}",
            f"elbow{s}",
            ((f"shoulder{s}", _reach_m("upper_arm")), ("neck", neck_reach + _reach_m("upper_arm"))),
        ),
        SegmentSpec(
            f"forearm{s}",
            "forearm",
            f"elbow{s}",
            f"wrist{s}",
            (
                (f"elbow{s}", _reach_m("forearm")),
                (f"shoulder{s}", _reach_m("upper_arm", "forearm")),
                ("neck", neck_reach + _reach_m("upper_arm", "forearm")),
            ),
        ),
        SegmentSpec(
            f"hand{s}",
            "hand",
            f"wrist{s}",
            f"hand{s}",
            (
                (f"wrist{s}", _reach_m("hand")),
                (f"elbow{s}", _reach_m("forearm", "hand")),
                (f"shoulder{s}", _reach_m("upper_arm", "forearm", "hand")),
                ("neck", neck_reach + _reach_m("upper_arm", "forearm", "hand")),
            ),
        ),
        SegmentSpec(
            f"thigh{s}",
            "thigh",
            f"hip{s}",
            f"knee{s}",
            ((f"hip{s}", _reach_m("thigh")), ("pelvis", pelvis_reach + _reach_m("thigh"))),
        ),
        SegmentSpec(
            f"shin{s}",
            "shin",
            f"knee{s}",
            f"ankle{s}",
            (
                (f"knee{s}", _reach_m("shin")),
                (f"hip{s}", _reach_m("thigh", "shin")),
                ("pelvis", pelvis_reach + _reach_m("thigh", "shin")),
            ),
        ),
        SegmentSpec(
            f"foot{s}",
            "foot",
            f"ankle{s}",
            f"foot{s}",
            (
                (f"ankle{s}", _reach_m("foot")),
                (f"knee{s}", _reach_m("shin", "foot")),
                (f"hip{s}", _reach_m("thigh", "shin", "foot")),
                ("pelvis", pelvis_reach + _reach_m("thigh", "shin", "foot")),
            ),
        ),
    )


SEGMENTS: tuple[SegmentSpec, ...] = (
    SegmentSpec("head", "head", "neck", "head", (("neck", _reach_m("head")),)),
    SegmentSpec("torso", "torso", "pelvis", "neck", ()),
    SegmentSpec(
        "shoulders",
        "shoulders",
        "shoulder_l",
        "shoulder_r",
        (("neck", NECK_TO_SHOULDER_M),),
    ),
    SegmentSpec("pelvis", "pelvis", "hip_l", "hip_r", (("pelvis", PELVIS_TO_HIP_M),)),
    *_limb("l"),
    *_limb("r"),
)
"""Every capsule of a placed person, in output order; names as the gateway's body (``tracker_emu.body``)."""

MAX_RADIUS_M = max(r + ANTHROPOMETRY[s.size].radius_m for s in SEGMENTS for _, r in s.fallbacks)
"""Largest radius a capsule of a placed person can get before uncertainty and memory (a hand seen nowhere: a
sphere around the neck reaching to the finger tips) [m]."""

WHOLE_BODY_NAMES = tuple(f"body_{i}" for i in range(int(np.ceil(STATURE_M / WHOLE_BODY_PIECE_M))))
"""Capsule names of a person reported as a whole body (bottom to top)."""


class _CompiledSegment(NamedTuple):
    name: str
    base_radius_m: float
    a: tuple[int, ...]
    b: tuple[int, ...]
    members: tuple[int, ...]
    fallbacks: tuple[tuple[tuple[int, ...], float], ...]


class CompiledFormat(NamedTuple):
    """A format's segments as keypoint indices (built once by :func:`compile_format`)."""

    spec: FormatSpec
    segments: tuple[_CompiledSegment, ...]
    pelvis: tuple[int, ...]
    neck: tuple[int, ...]

    @property
    def n_keypoints(self) -> int:
        return len(self.spec.keypoint_names)


def compile_format(spec: FormatSpec) -> CompiledFormat:
    """Resolve a format's groups to keypoint indices.

    Raises:
        ValueError: a group names a keypoint the format does not have, or a keypoint belongs to no capsule.
    """
    index = {name: i for i, name in enumerate(spec.keypoint_names)}
    unknown = {n for names in (*spec.groups.values(), *spec.extra.values()) for n in names} - index.keys()
    if unknown:
        raise ValueError(f"{spec.name}: unknown keypoints {sorted(unknown)}; known: {list(spec.keypoint_names)}")

    def group(name: str) -> tuple[int, ...]:
        return tuple(index[n] for n in spec.groups[name])

    compiled = []
    for seg in SEGMENTS:
        size = ANTHROPOMETRY[seg.size]
        a, b = group(seg.a), group(seg.b)
        base_radius_m = size.radius_m
        if not b:  # the format has no keypoint at the far end: a sphere around ``a`` reaching it
            b = a
            base_radius_m = float(np.hypot(size.length_m, size.radius_m))
        members = tuple(dict.fromkeys((*a, *b, *(index[n] for n in spec.extra.get(seg.name, ())))))
        fallbacks = tuple((group(g), r) for g, r in seg.fallbacks if group(g))
        compiled.append(_CompiledSegment(seg.name, base_radius_m, a, b, members, fallbacks))
    covered = {i for seg in compiled for i in seg.members}
    if len(covered) != len(spec.keypoint_names):
        orphans = [spec.keypoint_names[i] for i in range(len(spec.keypoint_names)) if i not in covered]
        raise ValueError(f"{spec.name}: keypoints {orphans} belong to no capsule")
    return CompiledFormat(spec, tuple(compiled), group("pelvis"), group("neck"))


COMPILED = {name: compile_format(spec) for name, spec in FORMATS.items()}
"""Every format of :data:`FORMATS`, compiled."""


# ---------------------------------------------------------------------------------------------------------------------
# Capsules
# ---------------------------------------------------------------------------------------------------------------------


class SkeletonError(MessageError):
    """Keypoints that cannot be a person; ``reason``: ``non_finite``, ``absurd_keypoint``, ``wrong_keypoint_count``,
    ``no_keypoints`` (nothing seen of a person reported as detected)."""


class PersonUnplacedError(Exception):
    """A person placed in a recent frame whose torso (pelvis or neck) is not seen in this one: the frame does not
    place them, so they are left out of it and the gateway's tracks keep them as lost (their last capsules, growing
    at the reach speed), never a smaller volume. Not a fault of the tracker."""


class BodyCapsules(NamedTuple):
    """The capsules of one person in the world frame.

    Attributes:
        names: capsule names (always the same for a format; :data:`WHOLE_BODY_NAMES` for a whole body).
        a_m, b_m: end points, shape (K, 3) [m].
        radius_m: radii, shape (K,) [m].
        estimated: names of the capsules not seen in this frame (reach spheres, memory).
        whole_body: the torso could not be placed; the capsules are a whole body around what is seen.
    """

    names: tuple[str, ...]
    a_m: FloatArray
    b_m: FloatArray
    radius_m: FloatArray
    estimated: tuple[str, ...]
    whole_body: bool

    def to_human(self, human_id: str) -> Human:
        """This person as a contract :class:`~hrc_contract.messages.Human`."""
        return Human(
            id=human_id,
            capsules=[
                Capsule(name=n, a=tuple(a), b=tuple(b), radius=float(r))
                for n, a, b, r in zip(self.names, self.a_m.tolist(), self.b_m.tolist(), self.radius_m, strict=True)
            ],
        )


class SeenCapsule(NamedTuple):
    """A capsule as last seen: end points [m], radius [m] and the capture time of its frame [ns]."""

    a_m: FloatArray
    b_m: FloatArray
    radius_m: float
    stamp_ns: int


@dataclass(frozen=True)
class PersonMemory:
    """What a person's capsules were when last seen, per capsule name. Pass the returned one to the next frame."""

    seen: dict[str, SeenCapsule] = field(default_factory=dict)


def segment_distance_m(points_m: FloatArray, a_m: FloatArray, b_m: FloatArray) -> FloatArray:
    """Distance of each point (M, 3) to the segment ``a``–``b`` [m]."""
    axis = b_m - a_m
    length2 = float(axis @ axis)
    if length2 == 0.0:
        return np.asarray(np.linalg.norm(points_m - a_m, axis=-1), dtype=np.float64)
    t = np.clip((points_m - a_m) @ axis / length2, 0.0, 1.0)
    return np.asarray(np.linalg.norm(points_m - (a_m + t[..., None] * axis), axis=-1), dtype=np.float64)


def enclosing_capsule(
    first: tuple[FloatArray, FloatArray, float], second: tuple[FloatArray, FloatArray, float]
) -> tuple[FloatArray, FloatArray, float]:
    """One capsule that contains two capsules ``(a, b, radius)``.

    The axis joins the two farthest apart of the four end points; the radius is the largest distance of an end point
    to that axis plus its capsule's radius. Containment: a point of a capsule is a point ``s`` of its segment plus at
    most its radius, and the distance to a segment is convex, so along the segment it is largest at an end point.
    """
    ends = np.array([first[0], first[1], second[0], second[1]])
    radii = np.array([first[2], first[2], second[2], second[2]])
    gaps = np.linalg.norm(ends[:, None, :] - ends[None, :, :], axis=-1)
    i, j = np.unravel_index(int(np.argmax(gaps)), gaps.shape)
    a, b = ends[i], ends[j]
    radius = float((segment_distance_m(ends, a, b) + radii).max())
    return a.copy(), b.copy(), radius


def check_keypoints(fmt: CompiledFormat, keypoints_m: FloatArray, seen: BoolArray) -> None:
    """Refuse keypoints that cannot be a person.

    Raises:
        SkeletonError: ``wrong_keypoint_count`` (shape not ``(N, 3)`` and ``(N,)`` for the format's N),
            ``non_finite`` (a seen keypoint with NaN or an infinity), ``absurd_keypoint`` (a seen coordinate beyond
            ±:data:`MAX_COORDINATE_M`).
    """
    n = fmt.n_keypoints
    if keypoints_m.shape != (n, 3) or seen.shape != (n,):
        raise SkeletonError(
            "wrong_keypoint_count",
            f"{fmt.spec.name}: keypoints {keypoints_m.shape} and seen {seen.shape}, expected ({n}, 3) and ({n},)",
        )
    values = keypoints_m[seen]
    if not np.isfinite(values).all():
        raise SkeletonError("non_finite", f"{fmt.spec.name}: a seen keypoint is not finite")
    if values.size and float(np.abs(values).max()) > MAX_COORDINATE_M:
        raise SkeletonError(
            "absurd_keypoint", f"{fmt.spec.name}: a keypoint beyond ±{MAX_COORDINATE_M} m from the world origin"
        )


def _group_point(keypoints_m: FloatArray, seen: BoolArray, group: tuple[int, ...]) -> FloatArray | None:
    idx = [i for i in group if seen[i]]
    if not idx:
        return None
    return np.asarray(keypoints_m[idx].mean(axis=0), dtype=np.float64)


def _seen_members(keypoints_m: FloatArray, seen: BoolArray, members: tuple[int, ...]) -> FloatArray:
    return np.asarray(keypoints_m[[i for i in members if seen[i]]], dtype=np.float64).reshape(-1, 3)


def body_capsules(
    fmt: CompiledFormat,
    keypoints_m: FloatArray,
    seen: BoolArray,
    *,
    stamp_ns: int,
    uncertainty_m: float,
    memory: PersonMemory | None = None,
    memory_s: float = 1.0,
    floor_z_m: float = 0.0,
) -> tuple[BodyCapsules, PersonMemory]:
    """The capsules of one person from their keypoints.

    Args:
        fmt: the keypoint format (:data:`COMPILED`).
        keypoints_m: keypoints in the world frame (z up), shape (N, 3) [m]; unseen rows are ignored.
        seen: which keypoints the tracker saw, shape (N,).
        stamp_ns: capture time of the frame [ns] (ages the memory).
        uncertainty_m: the tracker's stated keypoint uncertainty, added to every radius [m] (e.g. 3σ).
        memory: the person's memory returned by the previous call (None: a new person).
        memory_s: how long a capsule last seen is kept for a segment that stays unseen [s].
        floor_z_m: height of the floor in the world frame, for a whole-body report [m].

    Returns:
        The capsules and the person's new memory.

    Without a seen pelvis or neck the person cannot be placed: if they were placed within ``memory_s``,
    :class:`PersonUnplacedError` (leave them out of the frame: lost, never a smaller volume); else a whole-body report
    (:func:`whole_body_capsules`, a person never placed: nothing seen of them could have reached further).

    Raises:
        SkeletonError: see :func:`check_keypoints`.
        PersonUnplacedError: see above.
        ValueError: ``uncertainty_m`` or ``memory_s`` negative or not finite (a programming error).
    """
    if not (np.isfinite(uncertainty_m) and uncertainty_m >= 0.0 and np.isfinite(memory_s) and memory_s >= 0.0):
        raise ValueError(f"uncertainty_m = {uncertainty_m}, memory_s = {memory_s}; allowed: finite, >= 0")
    check_keypoints(fmt, keypoints_m, seen)
    memory = memory or PersonMemory()
    if _group_point(keypoints_m, seen, fmt.pelvis) is None or _group_point(keypoints_m, seen, fmt.neck) is None:
        if any(0 <= stamp_ns - c.stamp_ns <= memory_s * 1e9 for c in memory.seen.values()):
            # A whole-body column around what is seen would not cover an arm that reached out a frame ago.
            raise PersonUnplacedError(f"pelvis or neck not seen; placed {len(memory.seen)} capsule(s) recently")
        return whole_body_capsules(keypoints_m[seen], uncertainty_m, floor_z_m), memory
    n = len(fmt.segments)
    a_out, b_out, r_out = np.empty((n, 3)), np.empty((n, 3)), np.empty(n)
    estimated: list[str] = []
    remembered = dict(memory.seen)
    for k, seg in enumerate(fmt.segments):
        members = _seen_members(keypoints_m, seen, seg.members)
        a = _group_point(keypoints_m, seen, seg.a)
        b = _group_point(keypoints_m, seen, seg.b)
        complete = len(members) == len(seg.members)
        if a is not None and b is not None:
            radius = seg.base_radius_m
            if len(members):
                radius = max(radius, float(segment_distance_m(members, a, b).max()))
            capsule = (a, b, radius + uncertainty_m)
            if not complete and seg.fallbacks:  # the unseen keypoints can be anywhere their chain reaches (the
                # torso has no chain: its unseen spine keypoints lie between its ends)
                capsule = enclosing_capsule(capsule, _reach_capsule(keypoints_m, seen, seg, members, uncertainty_m))
        else:
            capsule = _reach_capsule(keypoints_m, seen, seg, members, uncertainty_m)
        if complete:  # the whole segment seen: its capsule is what the memory keeps
            remembered[seg.name] = SeenCapsule(capsule[0], capsule[1], capsule[2], stamp_ns)
        else:  # keep covering what was seen last too
            last = remembered.get(seg.name)
            if last is not None and 0 <= stamp_ns - last.stamp_ns <= memory_s * 1e9:
                capsule = enclosing_capsule(capsule, (last.a_m, last.b_m, last.radius_m))
            estimated.append(seg.name)
        a_out[k], b_out[k], r_out[k] = capsule
    body = BodyCapsules(tuple(s.name for s in fmt.segments), a_out, b_out, r_out, tuple(estimated), False)
    return body, PersonMemory(remembered)


def _reach_capsule(
    keypoints_m: FloatArray, seen: BoolArray, seg: _CompiledSegment, members: FloatArray, uncertainty_m: float
) -> tuple[FloatArray, FloatArray, float]:
    """A sphere around the nearest seen joint of the segment's chain reaching every point the segment can have.

    The torso is seen when this runs (the person is placed), and every chain ends at the pelvis or the neck, so one
    fallback is always seen. The sphere also covers the segment's own seen keypoints (one end may be seen).
    """
    base = ANTHROPOMETRY_RADIUS_BY_SEGMENT[seg.name]
    for group, reach_m in seg.fallbacks:
        centre = _group_point(keypoints_m, seen, group)
        if centre is None:
            continue
        radius = reach_m + base
        if len(members):
            radius = max(radius, float(np.linalg.norm(members - centre, axis=1).max()) + base)
        return centre, centre.copy(), radius + uncertainty_m
    raise SkeletonError("unplaceable", f"{seg.name}: no joint of its chain seen")  # unreachable: see the docstring


ANTHROPOMETRY_RADIUS_BY_SEGMENT = {s.name: ANTHROPOMETRY[s.size].radius_m for s in SEGMENTS}


def whole_body_capsules(seen_m: FloatArray, uncertainty_m: float, floor_z_m: float = 0.0) -> BodyCapsules:
    """Vertical capsules around the seen keypoints, as tall as a P95 person standing on the floor (taller if a seen
    keypoint is higher), as wide as their spread plus half a P95 shoulder breadth."""
    if len(seen_m) == 0:
        raise SkeletonError("no_keypoints", "a person without a single seen keypoint cannot be placed")
    centre = seen_m.mean(axis=0)
    spread_m = float(np.linalg.norm(seen_m[:, :2] - centre[:2], axis=1).max())
    radius = spread_m + WHOLE_BODY_RADIUS_M + uncertainty_m
    bottom = min(floor_z_m, float(seen_m[:, 2].min()))
    top = max(floor_z_m + STATURE_M, float(seen_m[:, 2].max()))
    pieces = len(WHOLE_BODY_NAMES)
    # axes from the floor to the top (the end caps reach beyond): every seen keypoint is within ``spread`` of the
    # vertical through the centre and between the ends; extra height (a person on a ladder) makes the pieces longer
    z = np.linspace(bottom, top, pieces + 1)
    a = np.column_stack((np.full(pieces, centre[0]), np.full(pieces, centre[1]), z[:-1]))
    b = np.column_stack((np.full(pieces, centre[0]), np.full(pieces, centre[1]), z[1:]))
    return BodyCapsules(WHOLE_BODY_NAMES, a, b, np.full(pieces, radius), WHOLE_BODY_NAMES, True)


def covers(body: BodyCapsules, points_m: FloatArray, tolerance_m: float = 1e-9) -> npt.NDArray[np.bool_]:
    """Which points (M, 3) lie inside some capsule of ``body`` [m] (for tests and checks)."""
    inside = np.zeros(len(points_m), dtype=bool)
    for a, b, r in zip(body.a_m, body.b_m, body.radius_m, strict=True):
        inside |= segment_distance_m(points_m, a, b) <= r + tolerance_m
    return inside
