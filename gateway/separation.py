"""The separation constraint rows and the override δ of Zanchettin et al. 2016, eq. (15) with Sec. III-D.

For each link i and human capsule j, with surface distance d and clearance Δ (eq. (10)–(12)):

    f = max(0, d − Δ)²                                     (clamp first, then square)
    e(r, v, h) = (h − r)ᵀ v      for r ∈ {r_a, r_b}, h ∈ {h_a, h_b}    (4 rows per pair, §2)
    δ (t_b,→i + t_delay) e ≤ f                              (eq. (15b) with t_b → t_b + t_delay)

Every row is an upper bound on δ; δ is the MINIMUM of the bounds, clipped to [0, 1]. Rows with
e ≤ 0 (moving away or sideways) bound nothing.

:func:`build_rows` here is the numpy reference; the gateway's loop builds the same rows with the compiled
:func:`gateway.kernels.build_rows` (the tests hold the two equal on seeded random inputs)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hrc_contract.config import SafetyConfig

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


def override_from_rows(rows: ConstraintRows) -> float:
    """δ = clip(min over rows of the bound, 0, 1); 1 when no row bounds anything; 0 when a bound is not a number
    (fail closed: ``min``/``max`` would pass a nan through to the override)."""
    lowest = rows.min_bound
    if lowest != lowest:
        return 0.0
    return min(max(lowest, 0.0), 1.0)


class SpeedAwareBounds(NamedTuple):
    """The bounds of eq. (15) with the speed-aware stopping time δ t_b (safety-math.md §10), one robot.

    Attributes:
        human_m: the human-alone bound (d − c − K t_delay) / (K t_b,→i) of every (link, capsule) pair, shape (L, H):
            the stop from δ must end before a person approaching at K closes the gap, whatever the link's
            direction.
        row: the largest root in [0, A/B] of each row with e > 0 (inf where e ≤ 0), shape (L, H, 2, 2).
        min_bound: the smallest of all of them (inf when nothing bounds δ).
    """

    human_m: FloatArray
    row: FloatArray
    min_bound: float


def speed_aware_bounds(
    surface_distance_m: FloatArray,
    e_m2ps: FloatArray,
    t_brake_link_s: FloatArray,
    t_delay_s: float,
    human_speed_pair_mps: FloatArray,
    clearance_static_m: float,
) -> SpeedAwareBounds:
    """Largest δ with ``δ (δ t_b + t_delay) e ≤ max(0, d − Δ(δ))²``, Δ(δ) = c + K (δ t_b + t_delay) (§10).

    Per pair write Δ(δ) = c + K t_delay + K t_b δ, so ``d − Δ(δ) = A − B δ`` with A = d − c − K t_delay and
    B = K t_b,→i. Only δ ≤ A / B is allowed at all (the person alone must not close the gap during the stop from δ,
    which lasts δ t_b,→i: the ``human_m`` bound, for every link whatever its direction; 0 when A ≤ 0). On
    [0, A/B], for a row with e > 0:

    - the left side ``L(δ) = e (t_b δ² + t_delay δ)`` is increasing (e > 0, t_b ≥ 0, t_delay ≥ 0, δ ≥ 0);
    - the right side ``R(δ) = (A − B δ)²`` is decreasing (A − B δ ≥ 0 there, B ≥ 0);

    so ``h = L − R`` is increasing, with h(0) = −A² < 0 and h(A/B) = L(A/B) ≥ 0: exactly one root in (0, A/B], and
    the allowed set is [0, root]. ``h(δ) = a δ² + b δ − A²`` with a = e t_b − B² and b = e t_delay + 2 A B > 0, and
    the root is ``2 A² / (b + sqrt(b² + 4 a A²))`` for every sign of a (the conjugate of the quadratic formula: no
    cancellation, and a = 0 gives the linear root A² / b). When a < 0 the discriminant is ≥ 0 because h changes
    sign on [0, A/B].

    Monotonicity (the tests hold it): a larger t_delay lowers A and raises L, a closer person (smaller d at the
    same e, or e shrinking with d as for a point moving straight at the person) lowers R relative to L, and a
    larger K lowers A and raises B: each shrinks the allowed set [0, root], so δ never rises.

    Args:
        surface_distance_m: d of every (link, capsule) pair, shape (L, H) [m].
        e_m2ps: (h − r)ᵀ v at the programmed speed, shape (L, H, 2, 2) [m²/s].
        t_brake_link_s: t_b,→i of each link, shape (L,) [s].
        t_delay_s: the measured delay of the whole chain [s].
        human_speed_pair_mps: K of each pair (ISO 13855: the close speed below the close distance), shape (L, H)
            [m/s].
        clearance_static_m: c [m].

    Returns:
        The bounds; ``min_bound`` is nan when any input is nan (the caller fails closed).
    """
    t_b = t_brake_link_s[:, None]
    a_m = surface_distance_m - clearance_static_m - human_speed_pair_mps * t_delay_s  # A, (L, H)
    b_mps = human_speed_pair_mps * t_b  # B, (L, H)
    with np.errstate(divide="ignore", invalid="ignore"):
        human = np.where(a_m > 0.0, np.where(b_mps > 0.0, a_m / np.where(b_mps > 0.0, b_mps, 1.0), np.inf), 0.0)
        human = np.where(np.isnan(a_m), np.nan, human)
        a4 = a_m[:, :, None, None]
        b4 = b_mps[:, :, None, None]
        quad = e_m2ps * t_b[:, :, None, None] - b4 * b4
        lin = e_m2ps * t_delay_s + 2.0 * a4 * b4
        disc = np.maximum(lin * lin + 4.0 * quad * a4 * a4, 0.0)
        root = 2.0 * a4 * a4 / (lin + np.sqrt(disc))
        root = np.where(a4 > 0.0, root, 0.0)
        row = np.where(e_m2ps > 0.0, root, np.where(np.isnan(e_m2ps + a4), np.nan, np.inf))
    lowest = min(float(human.min()), float(row.min())) if human.size else math.inf
    if np.isnan(human).any() or np.isnan(row).any():
        lowest = math.nan
    return SpeedAwareBounds(human, row, lowest)


def speed_aware_clearance_m(
    safety: SafetyConfig, close_speed_below_m: float, delta: float, t_brake_s: float, t_delay_s: float
) -> float:
    """Δ(δ) = c + K (δ t_b + t_delay) (safety-math.md §10), K at the close speed where that Δ falls below
    ``close_speed_below_m`` (as :func:`decision_clearance_m`) [m]."""
    travel_s = delta * t_brake_s + t_delay_s
    far_m = safety.clearance_static_m + safety.human_speed_mps * travel_s
    speed = safety.human_speed_close_mps if far_m < close_speed_below_m else safety.human_speed_mps
    return safety.clearance_static_m + speed * travel_s
