"""Segment–segment distances for all robot-link × human-capsule pairs at once (numpy, vectorised).

The closest points of two segments follow Ericson, *Real-Time Collision Detection* (2005), §5.1.9,
written for broadcasting: links along axis 0, capsules along axis 1. Checked against coal in tests.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

_EPS = 1e-12
_PARALLEL_SIN2 = 1e-14
"""Segments count as parallel when sin² of their angle is below this (a·e − b² loses all digits below it);
the distance error that remains is at most 1e-7 × the segment length."""


class SegmentDistances(NamedTuple):
    """Closest-point data of every (link i, capsule j) pair.

    Attributes:
        distance_m: centre-line distance between the two segments, shape (L, H) [m].
        s_link: abscissa in [0, 1] of the closest point on the link segment, shape (L, H).
        t_capsule: abscissa in [0, 1] of the closest point on the capsule segment, shape (L, H).
    """

    distance_m: FloatArray
    s_link: FloatArray
    t_capsule: FloatArray


def segment_distances(p_a: FloatArray, p_b: FloatArray, h_a: FloatArray, h_b: FloatArray) -> SegmentDistances:
    """Distances between L link segments ``[p_a, p_b]`` (L, 3) and H capsule segments ``[h_a, h_b]`` (H, 3)."""
    d1 = (p_b - p_a)[:, None, :]  # (L, 1, 3)
    d2 = (h_b - h_a)[None, :, :]  # (1, H, 3)
    r = p_a[:, None, :] - h_a[None, :, :]  # (L, H, 3)
    a = (d1 * d1).sum(-1)  # (L, 1): squared link length
    e = (d2 * d2).sum(-1)  # (1, H): squared capsule length
    b = (d1 * d2).sum(-1)  # (L, H)
    c = (d1 * r).sum(-1)  # (L, H)
    f = (d2 * r).sum(-1)  # (L, H)
    link_ok = a > _EPS
    capsule_ok = e > _EPS
    a_safe = np.where(link_ok, a, 1.0)
    e_safe = np.where(capsule_ok, e, 1.0)

    denom = a * e - b * b
    # General case; parallel segments (denom ≈ 0) start from s = 0.
    general = denom > _PARALLEL_SIN2 * a * e
    s = np.where(general, np.clip((b * f - c * e) / np.where(general, denom, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_safe
    # t outside [0, 1]: clamp it and recompute s for the clamped t.
    s_at_t0 = np.clip(-c / a_safe, 0.0, 1.0)
    s_at_t1 = np.clip((b - c) / a_safe, 0.0, 1.0)
    s = np.where(t < 0.0, s_at_t0, np.where(t > 1.0, s_at_t1, s))
    t = np.clip(t, 0.0, 1.0)
    # Degenerate capsule (a point): t = 0, s from projecting the point on the link.
    s = np.where(capsule_ok, s, s_at_t0)
    t = np.where(capsule_ok, t, 0.0)
    # Degenerate link (a point): s = 0, t from projecting the point on the capsule.
    t = np.where(link_ok, t, np.clip(f / e_safe, 0.0, 1.0) * capsule_ok)
    s = np.where(link_ok, s, 0.0)

    closest_link = p_a[:, None, :] + s[..., None] * d1
    closest_capsule = h_a[None, :, :] + t[..., None] * d2
    diff = closest_link - closest_capsule
    distance = np.sqrt(np.einsum("lhj,lhj->lh", diff, diff))
    return SegmentDistances(distance_m=distance, s_link=s, t_capsule=t)
