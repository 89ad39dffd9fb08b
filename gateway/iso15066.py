"""ISO/TS 15066 speed and separation monitoring as a speed override (Pupa et al. 2021; safety-math.md §7).

Protective separation distance, eq. (4)–(10) of the paper, for a robot speed ``v_r`` toward the human:

    S_p(v_r) = v_h (T_r + T_s) + v_r T_r + v_r² / (2 a_s) + C + Z_d + Z_r,       T_s = v_r / a_s

and its inverse, eq. (11): with ``B = S − C − Z_d − Z_r`` the largest speed toward the human at separation S is

    v_r,max = sqrt(v_h² + (a_s T_r)² + 2 a_s B) − v_h − a_s T_r          (0 when B ≤ v_h T_r)

Choices of this gateway (a closed controller that only takes an override δ):

- ``T_r`` is the measured delay of the whole chain, t_delay (safety-math.md §5).
- ``a_s``: the controller brings δ from 1 to 0 within the braking time, so a link point whose speed
  toward the human at full programmed speed is ``v`` decelerates (in that direction) at least at
  ``a_s = v / t_b,→i``, whatever δ is; then ``T_s = δ t_b,→i``, the stop the controller really makes.
  Taking the *magnitude* of the point's velocity instead would overstate a_s for oblique motion and
  understate S_s: unsafe.
- With ``v_r = δ v`` and that ``a_s``, S_p(δ v) ≤ S is a quadratic in δ:

      (v t_b / 2) δ² + (v_h t_b + v T_r) δ − (B − v_h T_r) ≤ 0,

  whose positive root is ``δ_max = v_r,max / v`` (computed in the cancellation-free form
  ``2 b₀ / (b₁ + sqrt(b₁² + 4 a₂ b₀))``, finite as v → 0).
- Points and directions: for every link × human-capsule pair, three link points — both end points and
  the link's closest point to the capsule — each with its velocity at the programmed speed and the
  unit vector to its nearest point on the capsule axis; S is the pair's surface distance (≤ the
  separation of every one of those points). Using every pair rather than only the nearest human point
  covers the paper's caveat that a single direction per link can be unreliable (Sec. VI).
- ``v_h`` is the human speed K, ``human_speed_close_mps`` below ``close_speed_below_m`` (ISO 13855).

QP (12) of the paper for the single decision variable δ (``q̇ = δ q̇_nom``, ``q̇_nom`` the programmed joint
velocity at 100 %), with ``n_kᵀ J_k q̇_nom = v_k`` the toward-the-human speed of point k:

    max δ   s.t.   δ v_k ≤ v_r,max,k                   (ISO/TS 15066, every point k with v_k > 0)
                   −q̇_max ≤ δ q̇_nom ≤ q̇_max             (joint velocity limits, URDF)
                   (δ − δ_prev) |q̇_nom,j| ≤ q̈_max T     (joint acceleration while δ rises)
                   0 ≤ δ ≤ 1

Every constraint is an upper bound on δ (the deceleration side of the acceleration limit is dropped:
a safety bound must always be able to lower δ, and the controller's own braking ramp realises the
deceleration). δ = 0 is feasible, and the objective is monotone, so

    δ* = clip(min(1, min_k δ_max,k, min_j q̇_max,j / |q̇_nom,j|, δ_prev + T min_j q̈_max,j / |q̇_nom,j|), 0, 1).

Fail closed: a nan or inf in the rows' data (separation, speeds toward the human, human speed), a nan bound, or
a joint input that is not finite (q̇_nom, δ_prev, T) gives δ* = 0 — ``min(1.0, nan)`` is 1.0 in Python. The only
infinity that bounds nothing is the one this module makes for a point that does not approach.

``δ_prev`` is the δ commanded in the previous cycle and ``T`` the gateway period: in the paper the
previous velocity is the last commanded one (the robot integrates the QP's output); here the applied
velocity follows the commanded δ through the controller's own ramp. The program's own acceleration
along its path is not constrained (it was planned within the robot's limits at 100 %)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from gateway.kernels import segment_distances
from gateway.kinematics import LinkKinematics
from gateway.separation import human_speed_mps
from hrc_contract.config import SafetyConfig
from hrc_contract.humans import HumanCapsules

FloatArray = npt.NDArray[np.float64]

_EPS = 1e-12

ArrayOrFloat = FloatArray | float


def v_r_max_mps(
    separation_m: ArrayOrFloat,
    v_h_mps: ArrayOrFloat,
    t_r_s: ArrayOrFloat,
    a_s_mps2: ArrayOrFloat,
    c_m: ArrayOrFloat = 0.0,
    z_d_m: ArrayOrFloat = 0.0,
    z_r_m: ArrayOrFloat = 0.0,
) -> FloatArray:
    """Largest robot speed toward the human at separation S, the inverse of S_p (paper eq. (11)) [m/s].

    ``v_r,max = sqrt(v_h² + (a_s T_r)² + 2 a_s B) − v_h − a_s T_r`` with ``B = S − C − Z_d − Z_r``; 0 when
    ``B ≤ v_h T_r`` (the human alone closes the gap during the reaction time).
    """
    b = np.asarray(separation_m, dtype=float) - c_m - z_d_m - z_r_m
    a_t = np.asarray(a_s_mps2, dtype=float) * t_r_s
    v_h = np.asarray(v_h_mps, dtype=float)
    radicand = np.maximum(0.0, v_h * v_h + a_t * a_t + 2.0 * np.asarray(a_s_mps2) * b)
    v = np.sqrt(radicand) - v_h - a_t
    return np.asarray(np.where(b > v_h * t_r_s, np.maximum(v, 0.0), 0.0), dtype=float)


def delta_max(
    v_toward_mps: ArrayOrFloat,
    separation_m: ArrayOrFloat,
    v_h_mps: ArrayOrFloat,
    t_r_s: ArrayOrFloat,
    t_b_s: ArrayOrFloat,
    margin_m: ArrayOrFloat = 0.0,
) -> FloatArray:
    """Largest δ with S_p(δ v) ≤ S when a_s = v / t_b (the controller's stop), i.e. v_r,max / v [1].

    Args:
        v_toward_mps: the point's speed toward the human at full programmed speed, v [m/s].
        separation_m: S [m].
        v_h_mps: human speed [m/s].
        t_r_s: reaction time T_r [s].
        t_b_s: time the controller takes to bring δ from 1 to 0 for this point's link, t_b,→i [s].
        margin_m: C + Z_d + Z_r [m].

    Returns:
        δ_max ≥ 0, +inf where v ≤ 0 (moving away or sideways bounds nothing).
    """
    v = np.asarray(v_toward_mps, dtype=float)
    b0 = np.asarray(separation_m, dtype=float) - margin_m - np.asarray(v_h_mps) * t_r_s  # B − v_h T_r
    a2 = 0.5 * v * t_b_s
    b1 = np.asarray(v_h_mps) * t_b_s + v * t_r_s
    root = 2.0 * b0 / np.maximum(b1 + np.sqrt(np.maximum(0.0, b1 * b1 + 4.0 * a2 * b0)), _EPS)
    return np.asarray(np.where(v > 0.0, np.where(b0 > 0.0, root, 0.0), np.inf), dtype=float)


class Iso15066Rows(NamedTuple):
    """The ISO/TS 15066 constraints of one robot, point by point (the rows of QP (12)).

    Points are indexed [link, capsule, k] with k = 0: link end a, 1: link end b, 2: the link's closest
    point to the capsule.

    Attributes:
        separation_m: S, the surface distance of every (link, capsule) pair, shape (L, H) [m].
        v_toward_mps: speed of each point toward its nearest capsule-axis point at full programmed
            speed, shape (L, H, 3) [m/s].
        v_h_mps: human speed used for each pair, shape (L, H) [m/s].
        bound: the largest δ each point allows (inf where it does not approach), shape (L, H, 3).
    """

    separation_m: FloatArray
    v_toward_mps: FloatArray
    v_h_mps: FloatArray
    bound: FloatArray


def _nearest_on_axis(points: FloatArray, h_a: FloatArray, h_b: FloatArray) -> FloatArray:
    """Nearest point of every capsule axis to every point; points (L, 3), capsules (H, 3) → (L, H, 3)."""
    d = h_b - h_a  # (H, 3)
    length2 = (d * d).sum(-1)  # (H,)
    t = np.einsum("lhj,hj->lh", points[:, None, :] - h_a[None, :, :], d) / np.where(length2 > _EPS, length2, 1.0)
    t = np.where(length2 > _EPS, np.clip(t, 0.0, 1.0), 0.0)
    return np.asarray(h_a[None, :, :] + t[..., None] * d[None, :, :], dtype=float)


def _speed_toward(v: FloatArray, frm: FloatArray, to: FloatArray) -> FloatArray:
    """vᵀ (to − frm)/‖to − frm‖; where the points coincide, the full speed ‖v‖ (worst direction)."""
    diff = to - frm
    dist = np.linalg.norm(diff, axis=-1)
    along = (v * diff).sum(-1) / np.where(dist > _EPS, dist, 1.0)
    return np.asarray(np.where(dist > _EPS, along, np.linalg.norm(v, axis=-1)), dtype=float)


def iso_rows(
    links: LinkKinematics,
    link_radius_m: FloatArray,
    t_brake_link_s: FloatArray,
    humans: HumanCapsules,
    safety: SafetyConfig,
    t_delay_s: float,
) -> Iso15066Rows:
    """ISO/TS 15066 rows of every link × capsule pair (see the module docstring for the choices).

    Args:
        links: link end points and their velocities at the programmed speed (q̇_nominal) [m, m/s].
        link_radius_m: radius of each link capsule, shape (L,) [m].
        t_brake_link_s: t_b,→i of each link, shape (L,) [s].
        humans: human capsules, world frame.
        safety: human speed, static clearance C, Z_d and Z_r.
        t_delay_s: reaction time of the whole chain, T_r [s].
    """
    p_a, p_b, v_a, v_b = links
    h_a, h_b = humans.h_a_world, humans.h_b_world
    n_links, n_capsules = len(p_a), len(h_a)
    seg = segment_distances(p_a, p_b, h_a, h_b)
    surface = np.maximum(0.0, seg.distance_m - link_radius_m[:, None] - humans.radius_m[None, :])
    s = seg.s_link[..., None]  # (L, H, 1)
    # The three points of every pair along axis 2: end a, end b, the closest point (one batch of numpy calls).
    points = np.empty((n_links, n_capsules, 3, 3))
    points[:, :, 0] = p_a[:, None, :]
    points[:, :, 1] = p_b[:, None, :]
    points[:, :, 2] = p_a[:, None, :] + s * (p_b - p_a)[:, None, :]
    velocities = np.empty_like(points)
    velocities[:, :, 0] = v_a[:, None, :]
    velocities[:, :, 1] = v_b[:, None, :]
    velocities[:, :, 2] = (1.0 - s) * v_a[:, None, :] + s * v_b[:, None, :]  # rigid link: affine in s
    targets = np.empty_like(points)
    ends = _nearest_on_axis(np.concatenate((p_a, p_b)), h_a, h_b).reshape(2, n_links, n_capsules, 3)
    targets[:, :, 0] = ends[0]
    targets[:, :, 1] = ends[1]
    targets[:, :, 2] = h_a[None, :, :] + seg.t_capsule[..., None] * (h_b - h_a)[None, :, :]
    v_toward = _speed_toward(velocities, points, targets)  # (L, H, 3)
    v_h = human_speed_mps(safety, surface)
    margin = safety.clearance_static_m + safety.iso15066_human_uncertainty_m + safety.iso15066_robot_uncertainty_m
    bound = delta_max(v_toward, surface[..., None], v_h[..., None], t_delay_s, t_brake_link_s[:, None, None], margin)
    return Iso15066Rows(surface, v_toward, v_h, bound)


def joint_limit_bound(
    qd_nominal_radps: FloatArray,
    velocity_limit_radps: FloatArray,
    acceleration_limit_radps2: float,
    previous_delta: float,
    period_s: float,
) -> float:
    """The joint velocity and acceleration rows of QP (12) reduced to one upper bound on δ.

    ``min_j q̇_max,j / |q̇_nom,j|`` and ``δ_prev + T q̈_max / |q̇_nom,j|`` over the joints that move;
    +inf when no joint moves. Velocity limits that are zero or +inf (a URDF without them) bound nothing.
    0 (fail closed) when q̇_nom, δ_prev, T or q̈_max is not finite or a velocity limit is nan: a nan joint
    would otherwise count as "not moving".
    """
    scalars = previous_delta + period_s + acceleration_limit_radps2
    if not (math.isfinite(scalars) and np.isfinite(qd_nominal_radps).all()) or np.isnan(velocity_limit_radps).any():
        return 0.0
    speed = np.abs(qd_nominal_radps)
    moving = speed > _EPS
    if not moving.any():
        return float("inf")
    speed = speed[moving]
    limit = velocity_limit_radps[moving]
    has_limit = np.isfinite(limit) & (limit > 0.0)
    velocity_bound = float((limit[has_limit] / speed[has_limit]).min()) if has_limit.any() else float("inf")
    acceleration_bound = previous_delta + period_s * acceleration_limit_radps2 / float(speed.max())
    return min(velocity_bound, acceleration_bound)


def rows_are_numbers(rows: Iso15066Rows) -> bool:
    """True if the rows were built from finite data and no bound is nan (+inf bounds of points that do not
    approach are numbers)."""
    return bool(
        np.isfinite(rows.separation_m).all()
        and np.isfinite(rows.v_toward_mps).all()
        and np.isfinite(rows.v_h_mps).all()
        and not np.isnan(rows.bound).any()
    )


def override(rows: Iso15066Rows, joint_bound: float) -> float:
    """δ* of QP (12): clip(min(1, every ISO row's bound, the joint limits' bound), 0, 1); 0 when a row is not
    built from numbers (:func:`rows_are_numbers`) or the joint bound is nan (fail closed)."""
    if math.isnan(joint_bound) or not rows_are_numbers(rows):
        return 0.0
    iso = float(rows.bound.min()) if rows.bound.size else math.inf
    return max(min(1.0, iso, joint_bound), 0.0)
