"""Known keypoints of one standing person (≈1.80 m, arms hanging, facing +x) by keypoint name, for every format of
``hrc_devices.trackers.skeletons``: the tests of the skeleton and ROS 2 people decoders build their inputs from
these."""

from __future__ import annotations

import numpy as np

from hrc_devices.trackers.skeletons import CompiledFormat

_SIDE = {"left": 1.0, "right": -1.0}

# (x forward, y left for "left_*", z up) [m], body frame, origin on the floor between the feet
_CENTRE = {
    "pelvis": (0.0, 0.0, 0.95), "mid_hip": (0.0, 0.0, 0.93), "naval_spine": (0.0, 0.0, 1.10),
    "spine_1": (0.0, 0.0, 1.05), "spine_2": (0.0, 0.0, 1.20), "spine_3": (0.0, 0.0, 1.35),
    "chest_spine": (0.0, 0.0, 1.30), "neck": (0.0, 0.0, 1.52), "head": (0.02, 0.0, 1.66), "nose": (0.10, 0.0, 1.64),
}  # fmt: skip
_SIDED = {
    "eye": (0.08, 0.035, 1.68), "eye_inner": (0.085, 0.02, 1.68), "eye_outer": (0.075, 0.05, 1.68),
    "ear": (0.0, 0.075, 1.66), "mouth": (0.09, 0.025, 1.60), "clavicle": (0.0, 0.08, 1.48),
    "shoulder": (0.0, 0.19, 1.45), "elbow": (0.02, 0.21, 1.16), "wrist": (0.05, 0.22, 0.90),
    "hand": (0.06, 0.22, 0.84), "handtip": (0.07, 0.22, 0.73), "thumb": (0.10, 0.20, 0.84),
    "hand_thumb_4": (0.11, 0.20, 0.82), "hand_index_1": (0.07, 0.21, 0.83), "hand_middle_4": (0.07, 0.22, 0.72),
    "hand_pinky_1": (0.05, 0.24, 0.83), "pinky": (0.05, 0.24, 0.82), "index": (0.08, 0.21, 0.76),
    "hip": (0.0, 0.10, 0.92), "knee": (0.02, 0.11, 0.50), "ankle": (0.0, 0.11, 0.08), "foot": (0.15, 0.11, 0.02),
    "heel": (-0.05, 0.11, 0.02), "big_toe": (0.20, 0.09, 0.02), "small_toe": (0.17, 0.15, 0.02),
    "foot_index": (0.20, 0.10, 0.02),
}  # fmt: skip


def body_point(name: str) -> tuple[float, float, float]:
    """Position of a keypoint by its format name (``left_elbow``, ``right_hand_thumb_4``, ``mouth_left``) [m]."""
    if name in _CENTRE:
        return _CENTRE[name]
    for side, sign in _SIDE.items():
        if name.startswith(f"{side}_"):
            x, y, z = _SIDED[name.removeprefix(f"{side}_")]
            return x, sign * y, z
        if name.endswith(f"_{side}"):  # mouth_left
            x, y, z = _SIDED[name.removesuffix(f"_{side}")]
            return x, sign * y, z
    raise KeyError(name)


def standing_keypoints(fmt: CompiledFormat, x_m: float = 2.0, y_m: float = 1.0, heading_rad: float = 0.0) -> np.ndarray:
    """The standing person's keypoints in ``fmt``'s order, in the world frame (z up), shape (N, 3) [m]."""
    local = np.array([body_point(n) for n in fmt.spec.keypoint_names])
    c, s = np.cos(heading_rad), np.sin(heading_rad)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return local @ R.T + np.array([x_m, y_m, 0.0])
