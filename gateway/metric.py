"""The separation constraint rows and the override δ of Zanchettin et al. 2016, eq. (15) with Sec. III-D.

For each link i and human capsule j, with surface distance d and clearance Δ (eq. (10)–(12)):

    f = max(0, d − Δ)²                                     (clamp first, then square)
    e(r, v, h) = (h − r)ᵀ v      for r ∈ {r_a, r_b}, h ∈ {h_a, h_b}    (4 rows per pair, §2)
    δ (t_b,→i + t_delay) e ≤ f                              (eq. (15b) with t_b → t_b + t_delay)

Every row is an upper bound on δ; δ is the MINIMUM of the bounds, clipped to [0, 1]. Rows with
e ≤ 0 (moving away or sideways) bound nothing.

:func:`build_rows` here is the numpy reference; the gateway's loop builds the same rows with the compiled
:func:`gateway.kernels.build_rows` (the tests hold the two equal on seeded random inputs).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from gateway.geometry import segment_distances
from gateway.kinematics import LinkKinematics
from hrc_common.config import SafetyConfig
from hrc_common.humans import HumanCapsules

FloatArray = npt.NDArray[np.float64]


class ConstraintRows(NamedTuple):
    """The rows of eq. (15) for one robot, with what they were built from.

    Attributes:
        surface_distance_m: d of every (link, capsule) pair, shape (L, H) [m].
        clearance_m: Δ of every pair, shape (L, H) [m].
        f_m2: right-hand side max(0, d − Δ)², shape (L, H) [m²].
        e_m2ps: (h − r)ᵀ v, shape (L, H, 2, 2) indexed [link, capsule, link end, capsule end] [m²/s].
        horizon_s: t_b,→i + t_delay of every link, shape (L,) [s].
        bound: the largest δ each row allows (inf where e ≤ 0), shape (L, H, 2, 2).
        min_bound: the smallest of them, inf when none bounds anything (no capsule, or e ≤ 0 everywhere).
    """

    surface_distance_m: FloatArray
    clearance_m: FloatArray
    f_m2: FloatArray
    e_m2ps: FloatArray
    horizon_s: FloatArray
    bound: FloatArray
    min_bound: float


def human_speed_mps(safety: SafetyConfig, separation_m: FloatArray) -> FloatArray:
    """K of ISO 13855 at each separation: ``human_speed_close_mps`` below ``close_speed_below_m``, else
    ``human_speed_mps`` [m/s]. The one statement of the close-speed rule for the numpy code (the compiled rows in
    ``gateway.kernels`` inline the same comparison)."""
    return np.where(separation_m < safety.close_speed_below_m, safety.human_speed_close_mps, safety.human_speed_mps)


def human_speed_at_mps(safety: SafetyConfig, separation_m: float) -> float:
    """:func:`human_speed_mps` for one separation, in plain floats (a numpy call on a 0-d array costs ~4 µs)."""
    return safety.human_speed_close_mps if separation_m < safety.close_speed_below_m else safety.human_speed_mps


def clearance_m(safety: SafetyConfig, separation_m: FloatArray, t_brake_max_s: float, t_delay_s: float) -> FloatArray:
    """Δ = c + K (max_i t_b,i + t_delay), eq. (11)–(12), with K of :func:`human_speed_mps`."""
    return safety.clearance_static_m + human_speed_mps(safety, separation_m) * (t_brake_max_s + t_delay_s)


def decision_clearance_m(safety: SafetyConfig, t_brake_max_s: float, t_delay_s: float) -> float:
    """The decision's Δ (eq. (11)–(12)): at the walking speed K, or at the close speed where that Δ falls below
    ``close_speed_below_m`` (ISO 13855): :func:`clearance_m` at the separation :func:`clearance_m` gives at
    infinity."""
    travel_s = t_brake_max_s + t_delay_s
    far_m = safety.clearance_static_m + safety.human_speed_mps * travel_s
    return safety.clearance_static_m + human_speed_at_mps(safety, far_m) * travel_s


def build_rows(
    links: LinkKinematics,
    link_radius_m: FloatArray,
    t_brake_link_s: FloatArray,
    t_brake_max_s: float,
    humans: HumanCapsules,
    safety: SafetyConfig,
    t_delay_s: float,
) -> ConstraintRows:
    """Build the constraint rows of every link × capsule pair (safety-math.md §2–§4), with numpy.

    The reference of the compiled :func:`gateway.kernels.build_rows` that the gateway runs (the tests hold the
    two to the same rows).

    Args:
        links: link end points and their velocities at the programmed speed (q̇_nominal) [m, m/s].
        link_radius_m: radius of each link capsule, shape (L,) [m].
        t_brake_link_s: t_b,→i of each link, shape (L,) [s].
        t_brake_max_s: max_i t_b,i over all joints, for the clearance [s].
        humans: human capsules, world frame.
        safety: safety parameters (human speed K, static clearance c).
        t_delay_s: reaction time of the whole chain [s].
    """
    seg = segment_distances(links.p_a_world, links.p_b_world, humans.h_a_world, humans.h_b_world)
    surface = np.maximum(0.0, seg.distance_m - link_radius_m[:, None] - humans.radius_m[None, :])
    clearance = clearance_m(safety, surface, t_brake_max_s, t_delay_s)
    f = np.square(np.maximum(0.0, surface - clearance))

    r_ends = np.stack((links.p_a_world, links.p_b_world), axis=1)  # (L, 2, 3)
    v_ends = np.stack((links.v_a_world, links.v_b_world), axis=1)  # (L, 2, 3)
    h_ends = np.stack((humans.h_a_world, humans.h_b_world), axis=1)  # (H, 2, 3)
    r_dot_v = (r_ends * v_ends).sum(-1)  # (L, 2)
    n_links, n_caps = len(r_ends), len(h_ends)
    # (h − r)ᵀv = hᵀv − rᵀv; hᵀv for all pairs as one matrix product (an einsum costs 15× more here).
    h_dot_v = (v_ends.reshape(2 * n_links, 3) @ h_ends.reshape(2 * n_caps, 3).T).reshape(n_links, 2, n_caps, 2)
    e = h_dot_v.transpose(0, 2, 1, 3) - r_dot_v[:, None, :, None]  # (L, H, 2, 2)

    horizon = t_brake_link_s + t_delay_s
    lhs = horizon[:, None, None, None] * e
    approaching = lhs > 0.0
    bound = np.where(approaching, f[:, :, None, None] / np.where(approaching, lhs, 1.0), np.inf)
    return ConstraintRows(surface, clearance, f, e, horizon, bound, float(bound.min()) if bound.size else math.inf)


def override_from_rows(rows: ConstraintRows) -> float:
    """δ = clip(min over rows of the bound, 0, 1); 1 when no row bounds anything; 0 when a bound is not a number
    (fail closed: ``min``/``max`` would pass a nan through to the override)."""
    lowest = rows.min_bound
    if lowest != lowest:
        return 0.0
    return min(max(lowest, 0.0), 1.0)
