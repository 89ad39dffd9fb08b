"""Transient contact: body regions → contact-safe relative speed, and the override bound that slows to it (§12).

ISO/TS 15066 Annex A (A.3.2, A.3.3) models a transient contact as two masses joined by the body region's spring k:
the robot's effective mass m_R hits the region's effective mass m_H with relative speed v. With the reduced mass

    μ = (1/m_H + 1/m_R)⁻¹

the peak force is v sqrt(μ k) and the energy transferred ½ μ v², so the largest relative speed of a transient
contact is

    v_max = F_max / sqrt(μ k)          (force form)
    v_max = sqrt(2 E_max / μ)          (energy form; the same when E_max = F_max² / (2 k))

The robot's effective mass m_R per link (:mod:`hrc_devices.robots.effective_mass`): the largest reflected mass
1 / (uᵀ J M(q)⁻¹ Jᵀ u) of any point of the link's capsule in any direction u (the largest eigenvalue of the
translational operational-space inertia Λ), over the program's path and a box of configurations around it, plus a
margin; computed once at start-up and used as a constant per link (no cost per decision). Where a point of the link
cannot move in some direction (the UR5's shoulder, upper arm and forearm: a point on a joint axis), or the robot is
outside the sampled box, m_R = ∞ and μ = m_H: the contact-safe speed of a fixed obstacle. ISO/TS 15066's simple form
M / 2 + m_payload (:func:`simple_robot_mass_kg`) is kept for comparison only: it understates the reflected mass of
those links many times over.

The override bound (:func:`contact_bounds`) is §10's speed-aware form with the stop ending at δ_c instead of 0: a link
whose every point moves at most at the contact-safe speed v_c of a capsule may touch it, so for a link i moving with
largest programmed point speed s_i, δ_c = v_c / s_i is always allowed for that pair, and above it the slow-down from δ
to δ_c (lasting (δ − δ_c) t_b) must end before the person can reach the link.

Pure functions and frozen values.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from hrc_contract.config import BodyRegion, Box
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.effective_mass import moving_mass_kg

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

NO_REGION = "unknown"
"""The region label of a capsule name no region lists: contact-safe speed 0."""
CLAMP_SAMPLES = 5
"""Points along a capsule's axis at which its distance to a clamping box is taken (a conservative lower bound)."""


# -- the formulas of ISO/TS 15066 Annex A ---------------------------------------------------------------------


def reduced_mass_kg(human_mass_kg: float, robot_mass_kg: float) -> float:
    """μ = (1/m_H + 1/m_R)⁻¹ of two bodies [kg] (ISO/TS 15066 eq. (A.3))."""
    return 1.0 / (1.0 / human_mass_kg + 1.0 / robot_mass_kg)


def force_contact_speed_mps(max_force_n: float, spring_constant_n_per_m: float, reduced_mass: float) -> float:
    """v_max = F_max / sqrt(μ k): the relative speed at which the peak force of the contact reaches F_max [m/s]."""
    return max_force_n / math.sqrt(reduced_mass * spring_constant_n_per_m)


def energy_contact_speed_mps(max_energy_j: float, reduced_mass: float) -> float:
    """v_max = sqrt(2 E_max / μ): the relative speed at which the energy transferred reaches E_max [m/s]."""
    return math.sqrt(2.0 * max_energy_j / reduced_mass)


def region_contact_speed_mps(region: BodyRegion, robot_mass_kg: float) -> float:
    """The contact-safe relative speed of a region hit by a robot of effective mass ``robot_mass_kg`` [m/s].

    0 for a region without transient contact (the head); the smaller of the force and the energy form where both are
    configured.
    """
    if not region.transient:
        return 0.0
    mu = reduced_mass_kg(region.mass_kg, robot_mass_kg)
    speeds = []
    if region.max_force_n is not None and region.spring_constant_n_per_m is not None:
        speeds.append(force_contact_speed_mps(region.max_force_n, region.spring_constant_n_per_m, mu))
    if region.max_energy_j is not None:
        speeds.append(energy_contact_speed_mps(region.max_energy_j, mu))
    return min(speeds)


def simple_robot_mass_kg(model: pin.Model, payload_kg: float) -> float:
    """m_R = M / 2 + m_payload (ISO/TS 15066 eq. (A.6)) [kg]: for comparison only (it understates the reflected mass
    of the links near the base many times over; the decision uses :mod:`hrc_devices.robots.effective_mass`)."""
    return 0.5 * moving_mass_kg(model) + payload_kg


# -- body regions of the human capsules ------------------------------------------------------------------------


class RegionTable:
    """Capsule names → their region, with each region's contact-safe speed for a robot mass.

    A capsule name of no region gets :data:`NO_REGION` and speed 0, as does a region without transient contact.
    """

    def __init__(self, regions: Mapping[str, BodyRegion]) -> None:
        self.regions = dict(regions)
        self._region_of = {name: region for region, spec in regions.items() for name in spec.capsules}
        self._cache: tuple[tuple[str, ...], tuple[str, ...]] = ((), ())

    def region_names(self, capsule_names: tuple[str, ...]) -> tuple[str, ...]:
        """The region of every capsule (:data:`NO_REGION` for a name no region lists)."""
        if capsule_names != self._cache[0]:
            self._cache = (capsule_names, tuple(self._region_of.get(n, NO_REGION) for n in capsule_names))
        return self._cache[1]

    def speeds_mps(self, capsule_names: tuple[str, ...], robot_mass_kg: FloatArray) -> FloatArray:
        """v_max of every (link, capsule) pair, shape (L, H), for the links' masses ``robot_mass_kg`` (L,) [m/s]."""
        regions = self.region_names(capsule_names)
        speeds = np.zeros((len(robot_mass_kg), len(regions)))
        by_mass = {float(m): i for i, m in enumerate(robot_mass_kg)}  # links of equal mass share the computation
        for j, region in enumerate(regions):
            spec = self.regions.get(region)
            if spec is None or not spec.transient:
                continue
            # m_R = ∞ (a rigid direction) is μ = m_H: the contact-safe speed of a fixed obstacle; nan stays nan
            column = {m: region_contact_speed_mps(spec, m) for m in by_mass}
            speeds[:, j] = [column[float(m)] for m in robot_mass_kg]
        return speeds


# -- clamping ---------------------------------------------------------------------------------------------------


def box_arrays(boxes: Sequence[Box]) -> tuple[FloatArray, FloatArray]:
    """The boxes' lower and upper corners, shape (B, 3) each [m]."""
    lo = np.array([b.min_m for b in boxes], dtype=float).reshape(-1, 3)
    hi = np.array([b.max_m for b in boxes], dtype=float).reshape(-1, 3)
    return lo, hi


def clamped_pairs(
    v_a_world: FloatArray,
    v_b_world: FloatArray,
    humans: HumanCapsules,
    box_min_m: FloatArray,
    box_max_m: FloatArray,
    margin_m: float,
) -> BoolArray:
    """Which (link, capsule) pairs may pin the capsule against a clamping box, shape (L, H).

    A capsule is near a box when a lower bound of its surface distance to the box is within ``margin_m``: the axis
    point distance at :data:`CLAMP_SAMPLES` points, less half their spacing (the distance to a convex set changes at
    most as fast as the point moves), less the radius. The pair is clamped when either end of the link has a velocity
    component along the direction from the capsule toward that box (the link would push the body part into it).
    """
    n_links, n_capsules = len(v_a_world), humans.n_capsules
    clamped = np.zeros((n_links, n_capsules), dtype=bool)
    if not n_capsules or not len(box_min_m):
        return clamped
    s = np.linspace(0.0, 1.0, CLAMP_SAMPLES)
    axis = humans.h_b_world - humans.h_a_world  # (H, 3)
    points = humans.h_a_world[:, None, :] + s[None, :, None] * axis[:, None, :]  # (H, S, 3)
    half_spacing = 0.5 * np.linalg.norm(axis, axis=-1) / (CLAMP_SAMPLES - 1)  # (H,)
    for lo, hi in zip(box_min_m, box_max_m, strict=True):
        nearest = np.clip(points, lo, hi)  # (H, S, 3)
        gap = np.linalg.norm(points - nearest, axis=-1)  # (H, S)
        k = np.argmin(gap, axis=1)
        lower_m = gap[np.arange(n_capsules), k] - half_spacing - humans.radius_m
        near = lower_m <= margin_m
        if not near.any():
            continue
        toward = nearest[np.arange(n_capsules), k] - points[np.arange(n_capsules), k]  # capsule → box, (H, 3)
        norm = np.linalg.norm(toward, axis=-1, keepdims=True)
        # Inside the box (or on it): every direction can press the body part into it.
        inside = norm[:, 0] <= 1e-9
        u = np.where(norm > 1e-9, toward / np.where(norm > 1e-9, norm, 1.0), 0.0)
        pushes = (v_a_world @ u.T > 0.0) | (v_b_world @ u.T > 0.0)  # (L, H)
        moving = (np.linalg.norm(v_a_world, axis=-1) > 0.0) | (np.linalg.norm(v_b_world, axis=-1) > 0.0)
        clamped |= near[None, :] & (pushes | (inside[None, :] & moving[:, None]))
    return clamped


# -- the override bound ----------------------------------------------------------------------------------------


class ContactBounds(NamedTuple):
    """The bounds of the contact-speed form (safety-math.md §12), one robot.

    Attributes:
        delta_contact: δ_c = v_c / s_i of every (link, capsule) pair, clipped to [0, 1], shape (L, H): at or below it
            every point of link i moves at most at the capsule's contact-safe speed.
        human: δ_c + (d − c − K t_delay)⁺ / (K t_b,→i), shape (L, H): the slow-down from δ to δ_c must end before a
            person approaching at K closes the gap, whatever the link's direction (the pair bound d ≥ Δ(δ)).
        row: δ_c + the root of each row with e > 0 (inf where e ≤ 0), shape (L, H, 2, 2).
        min_bound: the smallest of them (inf when nothing bounds δ; nan when an input is nan).
    """

    delta_contact: FloatArray
    human: FloatArray
    row: FloatArray
    min_bound: float


def contact_bounds(
    surface_distance_m: FloatArray,
    e_m2ps: FloatArray,
    t_brake_link_s: FloatArray,
    t_delay_s: float,
    human_speed_pair_mps: FloatArray,
    clearance_static_m: float,
    delta_contact: FloatArray,
) -> ContactBounds:
    """Largest δ with ``δ (t_delay + (δ − δ_c) t_b) e ≤ max(0, d − Δ_c(δ))²``, Δ_c(δ) = c + K (t_delay + (δ − δ_c) t_b),
    or δ ≤ δ_c (safety-math.md §12).

    With y = δ − δ_c ≥ 0, A = d − c − K t_delay and B = K t_b,→i: only y ≤ A / B is allowed (the human-alone bound;
    y = 0 when A ≤ 0), and on [0, A/B] the row reads h(y) = a y² + b y + c₀ ≤ 0 with

        a = e t_b − B²,   b = e (t_delay + δ_c t_b) + 2 A B,   c₀ = e δ_c t_delay − A²

    where the left side e (y + δ_c)(t_delay + y t_b) increases and the right side (A − B y)² decreases: one root in
    (0, A/B] when c₀ < 0, ``−2 c₀ / (b + sqrt(b² − 4 a c₀))`` (the conjugate form, no cancellation), and y = 0 when
    c₀ ≥ 0. With δ_c = 0 it is :func:`gateway.separation.speed_aware_bounds` exactly (c₀ = −A², b = e t_delay + 2 A B).

    Args:
        surface_distance_m: d of every (link, capsule) pair, shape (L, H) [m].
        e_m2ps: (h − r)ᵀ v at the programmed speed, shape (L, H, 2, 2) [m²/s].
        t_brake_link_s: t_b,→i of each link, shape (L,) [s].
        t_delay_s: the measured delay of the whole chain [s].
        human_speed_pair_mps: K of each pair, shape (L, H) [m/s].
        clearance_static_m: c [m].
        delta_contact: δ_c of every pair in [0, 1], shape (L, H); 0 = separation monitoring (head, clamped).
    """
    t_b = t_brake_link_s[:, None]
    dc = delta_contact
    a_m = surface_distance_m - clearance_static_m - human_speed_pair_mps * t_delay_s  # A, (L, H)
    b_mps = human_speed_pair_mps * t_b  # B, (L, H)
    with np.errstate(divide="ignore", invalid="ignore"):
        slack = np.where(a_m > 0.0, np.where(b_mps > 0.0, a_m / np.where(b_mps > 0.0, b_mps, 1.0), np.inf), 0.0)
        human = np.where(np.isnan(a_m + dc), np.nan, dc + slack)
        a4, b4, dc4 = a_m[:, :, None, None], b_mps[:, :, None, None], dc[:, :, None, None]
        tb4 = t_b[:, :, None, None]
        quad = e_m2ps * tb4 - b4 * b4
        lin = e_m2ps * (t_delay_s + dc4 * tb4) + 2.0 * a4 * b4
        const = e_m2ps * dc4 * t_delay_s - a4 * a4
        disc = np.maximum(lin * lin - 4.0 * quad * const, 0.0)
        root = np.where((a4 > 0.0) & (const < 0.0), -2.0 * const / (lin + np.sqrt(disc)), 0.0)
        row = np.where(e_m2ps > 0.0, dc4 + root, np.where(np.isnan(e_m2ps + a4 + dc4), np.nan, np.inf))
    lowest = min(float(human.min()), float(row.min())) if human.size else math.inf
    if np.isnan(human).any() or np.isnan(row).any():
        lowest = math.nan
    return ContactBounds(dc, human, row, lowest)


def link_joint_mask(model: pin.Model, frame_a_ids: Sequence[int], frame_b_ids: Sequence[int]) -> BoolArray:
    """Which joints move each link's body (the joints supporting its ``frame_a``), shape (L, n)."""
    mask = np.zeros((len(frame_a_ids), model.nv), dtype=bool)
    for i, frame_id in enumerate(frame_a_ids):
        for joint in model.supports[model.frames[frame_id].parentJoint]:
            if joint > 0:
                mask[i, model.joints[joint].idx_v] = True
    return mask


def link_surface_speed_mps(
    v_a_world: FloatArray, v_b_world: FloatArray, qd_radps: FloatArray, joint_mask: BoolArray, radius_m: FloatArray
) -> FloatArray:
    """A bound of the speed of every point of each link's capsule, shape (L,) [m/s]:
    max(|v_a|, |v_b|) + r |ω| with |ω| ≤ Σ |q̇_j| over the revolute joints that move the link (unit axes).

    The axis points move at most as fast as an end (velocity is linear along a rigid segment); a surface point r away
    from the axis adds at most |ω| r.
    """
    squared = np.maximum(np.einsum("lj,lj->l", v_a_world, v_a_world), np.einsum("lj,lj->l", v_b_world, v_b_world))
    return np.asarray(np.sqrt(squared) + radius_m * (joint_mask @ np.abs(qd_radps)), dtype=float)


def contact_delta(contact_speed_mps: FloatArray, link_speed_mps: FloatArray) -> FloatArray:
    """δ_c = v_c / s_i clipped to [0, 1], shape (L, H): 0 where v_c = 0; 1 for a link that does not move [1].

    Args:
        contact_speed_mps: v_c of every pair (already scaled by the planning fraction), shape (L, H) [m/s].
        link_speed_mps: s_i, a bound of the programmed speed of every point of each link's capsule
            (:func:`link_surface_speed_mps`), shape (L,) [m/s].
    """
    s = link_speed_mps[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(s > 0.0, contact_speed_mps / np.where(s > 0.0, s, 1.0), np.inf)
    ratio = np.where(contact_speed_mps > 0.0, ratio, 0.0)
    ratio = np.where(np.isnan(contact_speed_mps + s), np.nan, ratio)
    return np.minimum(ratio, 1.0)
