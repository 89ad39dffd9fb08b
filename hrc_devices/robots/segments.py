"""Segment–segment distances for all robot-link × human-capsule pairs at once (numpy, vectorised).

The closest points of two segments follow Ericson, *Real-Time Collision Detection* (2005), §5.1.9,
written for broadcasting: links along axis 0, capsules along axis 1. Checked against coal in tests.

The tracker emulator's line of sight and the references of the gateway use it; the gateway's eq. (15) loop runs the
compiled twin in :mod:`gateway.kernels`, which the tests hold to these results (1e-12 m).
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


def _clip01(x: FloatArray) -> FloatArray:
    """``np.clip(x, 0, 1)`` in place: ``maximum`` then ``minimum`` cost half of ``np.clip`` on small arrays."""
    np.maximum(x, 0.0, out=x)
    return np.minimum(x, 1.0, out=x)


def segment_distances(p_a: FloatArray, p_b: FloatArray, h_a: FloatArray, h_b: FloatArray) -> SegmentDistances:
    """Distances between L link segments ``[p_a, p_b]`` (L, 3) and H capsule segments ``[h_a, h_b]`` (H, 3)."""
    # At 7 × 30 pairs the cost is the number of numpy calls (1–3 µs each), not the arithmetic: dot products
    # over the coordinate axis are batched matrix products (one call instead of a multiply and a reduction
    # over a length-3 axis), and the rare cases (degenerate segments) are handled only when present.
    d1 = p_b - p_a  # (L, 3)
    d2 = h_b - h_a  # (H, 3)
    r = p_a[:, None, :] - h_a[None, :, :]  # (L, H, 3)
    a = (d1 * d1).sum(1)  # (L,): squared link length
    e = (d2 * d2).sum(1)  # (H,): squared capsule length
    b = d1 @ d2.T  # (L, H)
    c = (r @ d1[:, :, None])[..., 0]  # (L, H): d1_i · r_ij
    f = (r.transpose(1, 0, 2) @ d2[:, :, None])[..., 0].T  # (L, H): d2_j · r_ij
    link_ok = a > _EPS
    capsule_ok = e > _EPS
    degenerate = not (link_ok.all() and capsule_ok.all())
    if degenerate:
        a = np.where(link_ok, a, 1.0)
        e = np.where(capsule_ok, e, 1.0)

    ae = np.multiply.outer(a, e)
    denom = ae - b * b
    # General case; parallel segments (denom ≈ 0) start from s = 0 (b f − c e divided by +inf).
    general = denom > _PARALLEL_SIN2 * ae
    s = b * f
    s -= c * e
    s /= np.where(general, denom, np.inf)
    t = b * _clip01(s)
    t += f
    t /= e
    # Clamp t to [0, 1] and take the s closest to that capsule point: one expression for the three branches
    # t < 0, t > 1 and 0 ≤ t ≤ 1 of Ericson's code. Where t was inside, it gives back the first step's s
    # (unclamped: a s − b t + c = 0; clamped: the optimum's KKT condition keeps (b t − c) / a beyond the
    # bound); for parallel pairs it picks another closest pair at the same distance.
    t = _clip01(t)
    if degenerate:
        t *= capsule_ok  # a point capsule: t = 0, s from projecting the point on the link (below)
    s = b * t
    s -= c
    s /= a[:, None]
    s = _clip01(s)
    if degenerate:
        # A point link: s = 0, t from projecting the point on the capsule.
        t = np.where(link_ok[:, None], t, _clip01(f / e) * capsule_ok)
        s *= link_ok[:, None]

    # Closest link point minus closest capsule point: r + s d1 − t d2.
    diff = s[..., None] * d1[:, None, :]
    diff += r
    diff -= t[..., None] * d2[None, :, :]
    distance = np.sqrt((diff[..., None, :] @ diff[..., :, None])[..., 0, 0])
    return SegmentDistances(distance_m=distance, s_link=s, t_capsule=t)
