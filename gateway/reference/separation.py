"""Constraint rows of eq. (15) in numpy: the reference of the compiled :func:`gateway.kernels.build_rows`."""

from __future__ import annotations

import math

import numpy as np

from gateway.kinematics import LinkKinematics
from gateway.separation import ConstraintRows, FloatArray, clearance_m
from hrc_contract.config import SafetyConfig
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.segments import segment_distances


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
