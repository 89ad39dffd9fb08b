"""Open controllers: the joint velocities and δ of LP (9), then the self-motion of LP (13) (paper 1, Sec. III).

A robot whose controller follows joint references at its cycle (``controller.control = "open"``, e.g. ABB EGM) is
driven by the gateway itself: each cycle it solves, with the variables z = (q̇_{k+1}, δ_k),

    max δ                                                               (9a)
    t_{b,→i} (h − r)ᵀ J_r(q) q̇ ≤ f           every row of every link–capsule pair, t_{b,→i} + t_delay   (9b)
    J_task(q_ref) q̇ − δ x'(τ) = K ε                                     (9c)  CLIK on the task (the tool's pose)
    q̇_k − q̈max Δt ≤ q̇ ≤ q̇_k + q̈max Δt                                (9d)
    −q̇max ≤ q̇ ≤ q̇max                                                  (9e)
    q_min ≤ q_ref + Δt q̇ ≤ q_max                                       (9f)
    0 ≤ δ ≤ 1                                                           (9g)

then, with δ fixed at the optimum δ* (half a percent below it when δ* < 1: :data:`SELF_MOTION_ROOM`), LP (13):
min ‖q̇ − q̇⁰‖_∞ over the same rows, which uses the redundant degrees of freedom to follow the reference self-motion
q̇⁰ (here: away from the nearest people, back to the program's posture when nobody is near) without slowing the task.
The safety rows are those of eq. (15) (docs/safety-math.md §2–§4) with q̇ free instead of δ q̇_nominal: the same
distances, Δ, f and horizons, evaluated at the *measured* joints.

LP (9) can be infeasible (a robot moving faster than q̈max Δt that must stop: (9d) forbids it in one step). Then, and
whenever an input fails closed, the command is :func:`ramp_stop`: the current joint velocity scaled down along its
own direction, to standstill within the controller's stop time T_c ≤ every t_b,→i, the stop the rows model
(safety-math.md §13: the previous cycle's rows bound it).

Every command is checked against the rows before it leaves (:func:`violated_rows`): a solver's answer that breaks a
row beyond the solver's tolerance is not sent; the ramp stop is. Pure numpy and DAQP; no state, no I/O.

This numpy form is the reference: the gateway's loop runs :meth:`gateway.open_kernels.OpenLp.decide`, the same
decision compiled into buffers kept between cycles (a third of the time), checked against :func:`decide` in
``tests/gateway/test_open_kernels.py``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple

import daqp
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]

NO_BOUND = 1e30
"""DAQP's "no bound" (its default for an absent lower bound)."""
ROW_TOLERANCE = 1e-6
"""How far a solver's answer may exceed a row's right-hand side and still be sent, relative to the row's scale plus
1 m² (DAQP's primal tolerance is 1e-6): 1e-6 m² on a row with f = 0 lets a link approach at about a micrometre per
second. A row exceeded by more fails the command closed (the ramp stop)."""
SELF_MOTION_ROOM = 0.005
"""When LP (9) bounds δ below 1, LP (13) runs at δ* (1 − this): at δ* itself LP (9)'s vertex leaves the redundant
joints no range (the rows that bind fix every direction), so the self-motion could never take the arm away from the
rows that slow it. Half a percent of δ is about what one cycle's acceleration window (9d) lets δ change (q̈max Δt /
q̇ ≈ 1 %), so LP (13) stays feasible; it also leaves the binding rows that much slack for the next cycle's tightening.
Measured (docs/benchmarks.md, "Guarded distance, elbow out"): 0.001 too little, 0.003–0.01 alike."""
_SENSE_EQUALITY = 5
_EXIT_OPTIMAL = (1, 2)  # DAQP: 1 optimal, 2 soft-optimal


class SafetyRows(NamedTuple):
    """The rows (9b) of one robot and cycle that could bind: ``a_s @ q̇ ≤ f_m2``.

    Attributes:
        a_s: per row, (t_b,→i + t_delay) (h − r)ᵀ J_r over the active joints, shape (m, n) [m² per rad].
        f_m2: the right-hand side max(0, d − Δ)² of the row's pair, shape (m,) [m²].
        link: the link index of each row, shape (m,).
        capsule: the capsule index of each row, shape (m,).
        dropped: rows left out because no q̇ within the velocity limits can reach their right-hand side.
    """

    a_s: FloatArray
    f_m2: FloatArray
    link: IntArray
    capsule: IntArray
    dropped: int


class Limits(NamedTuple):
    """What the open robot's joints may do (the active joints only).

    Attributes:
        qd_max_radps: velocity limits (URDF), shape (n,).
        qdd_max_radps2: acceleration bound q̈max, shape (n,): q̇max / T_c, so that the controller can stop every joint
            from its velocity limit together within its stop time T_c (``controller.braking_time_s``).
        q_min_rad, q_max_rad: position limits (URDF), shape (n,).
        t_brake_max_s: T_c, the ramp stop's length from full speed [s]; at most every link's t_b,→i (checked at
            start-up as for a closed controller).
    """

    qd_max_radps: FloatArray
    qdd_max_radps2: FloatArray
    q_min_rad: FloatArray
    q_max_rad: FloatArray
    t_brake_max_s: float


class Task(NamedTuple):
    """The task equality (9c) of one cycle: ``jacobian @ q̇ = δ x_rate + correction``.

    Attributes:
        jacobian: J_task(q_ref) over the active joints, shape (k, n) (k = 6: the tool's linear and angular velocity).
        x_rate: x'(τ), the task velocity at δ = 1, shape (k,) [m/s, rad/s].
        correction: K ε, the CLIK term, shape (k,) [m/s, rad/s].
    """

    jacobian: FloatArray
    x_rate: FloatArray
    correction: FloatArray


class Solution(NamedTuple):
    """A command for the next cycle.

    Attributes:
        qd_radps: q̇_{k+1} over the active joints, shape (n,) [rad/s].
        delta: δ_k (for the task's time and display; 0 for a ramp stop).
        how: ``"lp13"`` (LP (13) after (9)), ``"lp9"`` (LP (9) alone: (13) failed), or ``"ramp_stop:<why>"``.
        bounded_by: what bounds δ: ``"none"`` at δ = 1, ``"safety:<link>/<capsule index>"`` for the tightest safety
            row, ``"limits"`` for the joint limits and the task; empty for a ramp stop.
        self_motion_gap_radps: LP (13)'s objective ‖q̇ − q̇⁰‖_∞, None without it [rad/s].
    """

    qd_radps: FloatArray
    delta: float
    how: str
    bounded_by: str = ""
    self_motion_gap_radps: float | None = None


def safety_rows(
    jac_a: FloatArray,
    jac_b: FloatArray,
    p_a_m: FloatArray,
    p_b_m: FloatArray,
    h_a_m: FloatArray,
    h_b_m: FloatArray,
    f_m2: FloatArray,
    horizon_s: FloatArray,
    qd_max_radps: FloatArray,
) -> SafetyRows:
    """The rows (9b) that could bind: per link i, capsule j, link end r ∈ {a, b} and capsule end h ∈ {h_a, h_b}
    the row ``horizon_i (h − r)ᵀ J_r q̇ ≤ f_ij`` (the four corners of safety-math.md §2).

    A row whose left side cannot reach ``f`` for any q̇ within the velocity limits (``Σ |a_k| q̇max_k ≤ f``) can
    never bind and is left out (counted in ``dropped``): exact, not a heuristic, and most rows of a far person.

    Args:
        jac_a, jac_b: position Jacobians of each link's ends, world frame, shape (L, 3, n).
        p_a_m, p_b_m: the link ends, shape (L, 3) [m].
        h_a_m, h_b_m: the capsules' ends, shape (H, 3) [m].
        f_m2: max(0, d − Δ)² of every pair, shape (L, H) [m²].
        horizon_s: t_b,→i + t_delay of every link, shape (L,) [s].
        qd_max_radps: velocity limits, shape (n,) [rad/s].
    """
    n_links, n_caps = f_m2.shape
    n = jac_a.shape[2]
    blocks = []
    for p, jac in ((p_a_m, jac_a), (p_b_m, jac_b)):
        for h in (h_a_m, h_b_m):
            toward = h[None, :, :] - p[:, None, :]  # (L, H, 3)
            blocks.append(np.einsum("ljc,lcn->ljn", toward, jac) * horizon_s[:, None, None])
    a_all = np.stack(blocks, axis=2).reshape(n_links * n_caps * 4, n)
    f_all = np.repeat(f_m2.reshape(-1), 4)
    reach = np.abs(a_all) @ qd_max_radps
    keep = ~(reach <= f_all)  # nan in either keeps the row (and fails the solve closed)
    link, capsule = np.divmod(np.repeat(np.arange(n_links * n_caps), 4), n_caps)
    return SafetyRows(np.ascontiguousarray(a_all[keep]), f_all[keep], link[keep], capsule[keep], int((~keep).sum()))


def velocity_bounds(
    qd_prev_radps: FloatArray, q_ref_rad: FloatArray, limits: Limits, dt_s: float
) -> tuple[FloatArray, FloatArray]:
    """Lower and upper bounds on q̇_{k+1} from (9d)–(9f), per joint [rad/s]. Empty (lower > upper) where the joint
    cannot keep every limit: the LP is then infeasible.

    A reference already beyond a position limit (a ramp stop runs along the current direction and may cross one) may
    stay or come back, never go deeper: (9f) then bounds q̇ by 0 instead of demanding the way back within one cycle,
    which (9d) forbids (LP (9) would stay infeasible at standstill, the robot stuck at the limit for good)."""
    lower = np.maximum.reduce(
        (
            qd_prev_radps - limits.qdd_max_radps2 * dt_s,
            -limits.qd_max_radps,
            np.minimum((limits.q_min_rad - q_ref_rad) / dt_s, 0.0),
        )
    )
    upper = np.minimum.reduce(
        (
            qd_prev_radps + limits.qdd_max_radps2 * dt_s,
            limits.qd_max_radps,
            np.maximum((limits.q_max_rad - q_ref_rad) / dt_s, 0.0),
        )
    )
    return lower, upper


def rows_within(rows: SafetyRows, lower: FloatArray, upper: FloatArray) -> SafetyRows:
    """The rows some q̇ in the box ``lower``–``upper`` (the bounds (9d)–(9f)) could break: the largest left side over the
    box, ``a·c + |a|·h`` (c the box's centre, h its half width), above ``f``. The others hold for every q̇ the LP may
    choose, so leaving them out changes no solution (exact); within one cycle's acceleration window that is most
    rows. Counted in ``dropped``."""
    centre, half = 0.5 * (lower + upper), 0.5 * np.maximum(upper - lower, 0.0)
    keep = ~(rows.a_s @ centre + np.abs(rows.a_s) @ half <= rows.f_m2)  # nan keeps the row
    if keep.all():
        return rows
    return SafetyRows(
        rows.a_s[keep], rows.f_m2[keep], rows.link[keep], rows.capsule[keep], rows.dropped + int((~keep).sum())
    )


def solve_lp9(rows: SafetyRows, task: Task, lower: FloatArray, upper: FloatArray) -> tuple[FloatArray, float] | None:
    """LP (9): the largest δ and a q̇ with it, or None when infeasible (or the solver fails)."""
    n = lower.size
    k = task.x_rate.size
    m = rows.f_m2.size
    a = np.zeros((m + k, n + 1))
    a[:m, :n] = rows.a_s
    a[m:, :n] = task.jacobian
    a[m:, n] = -task.x_rate
    upper_all = np.concatenate((upper, [1.0], rows.f_m2, task.correction))
    lower_all = np.concatenate((lower, [0.0], np.full(m, -NO_BOUND), task.correction))
    sense = np.zeros(n + 1 + m + k, dtype=np.int32)
    sense[n + 1 + m :] = _SENSE_EQUALITY
    cost = np.zeros(n + 1)
    cost[n] = -1.0
    if not (np.isfinite(a).all() and np.isfinite(upper_all).all() and np.isfinite(lower_all).all()):
        return None
    if (lower > upper).any():
        return None
    z, _, exitflag, _ = daqp.solve(None, cost, a, upper_all, lower_all, sense)
    if exitflag not in _EXIT_OPTIMAL:
        return None
    return np.asarray(z[:n], dtype=float), float(min(max(z[n], 0.0), 1.0))


def solve_lp13(
    rows: SafetyRows,
    task: Task,
    delta: float,
    lower: FloatArray,
    upper: FloatArray,
    qd_self_radps: FloatArray,
) -> tuple[FloatArray, float] | None:
    """LP (13) at δ fixed: the q̇ nearest (∞-norm) to the reference ``qd_self_radps`` that keeps every row and the
    task at δ; with its objective [rad/s]. None when infeasible (then LP (9)'s q̇ stands)."""
    n = lower.size
    k = task.x_rate.size
    m = rows.f_m2.size
    a = np.zeros((m + k + 2 * n, n + 1))
    a[:m, :n] = rows.a_s
    a[m : m + k, :n] = task.jacobian
    eye = np.eye(n)
    a[m + k : m + k + n, :n] = eye  # q̇ − t ≤ q̇⁰
    a[m + k : m + k + n, n] = -1.0
    a[m + k + n :, :n] = eye  # q̇ + t ≥ q̇⁰
    a[m + k + n :, n] = 1.0
    target = delta * task.x_rate + task.correction
    gap_max = float(np.max(np.abs(np.concatenate((lower, upper, qd_self_radps)))) * 2.0 + 1.0)
    upper_all = np.concatenate((upper, [gap_max], rows.f_m2, target, qd_self_radps, np.full(n, NO_BOUND)))
    lower_all = np.concatenate((lower, [0.0], np.full(m, -NO_BOUND), target, np.full(n, -NO_BOUND), qd_self_radps))
    sense = np.zeros(n + 1 + m + k + 2 * n, dtype=np.int32)
    sense[n + 1 + m : n + 1 + m + k] = _SENSE_EQUALITY
    cost = np.zeros(n + 1)
    cost[n] = 1.0
    if not (np.isfinite(a).all() and np.isfinite(upper_all).all() and np.isfinite(lower_all).all()):
        return None
    z, _, exitflag, _ = daqp.solve(None, cost, a, upper_all, lower_all, sense)
    if exitflag not in _EXIT_OPTIMAL:
        return None
    return np.asarray(z[:n], dtype=float), float(z[n])


def violated_rows(rows: SafetyRows, qd_radps: FloatArray) -> IntArray:
    """The rows that ``qd_radps`` breaks beyond :data:`ROW_TOLERANCE` (relative to the row's scale)."""
    lhs = rows.a_s @ qd_radps
    scale = np.abs(rows.a_s) @ np.abs(qd_radps) + np.abs(rows.f_m2) + 1.0
    over = ~(lhs - rows.f_m2 <= ROW_TOLERANCE * scale)  # nan counts as broken
    return np.flatnonzero(over)


def ramp_stop(qd_prev_radps: FloatArray, limits: Limits, dt_s: float) -> FloatArray:
    """The stop along the current direction: the speed fraction s = max_j |q̇_j| / q̇max_j falls by Δt / T_c each cycle
    (``limits.t_brake_max_s``), so from s the stop lasts s T_c and no joint decelerates faster than q̈max = q̇max / T_c.
    Zero when the velocity is not finite (the controller's own stop)."""
    return ramp_stop_ratio(qd_prev_radps, limits, dt_s)[0]


def ramp_stop_ratio(qd_prev_radps: FloatArray, limits: Limits, dt_s: float) -> tuple[FloatArray, float]:
    """:func:`ramp_stop` and the factor it scaled the velocity by (0 for a velocity that is not finite)."""
    if not np.isfinite(qd_prev_radps).all():
        return np.zeros_like(qd_prev_radps), 0.0
    fraction = float(np.max(np.abs(qd_prev_radps) / limits.qd_max_radps, initial=0.0))
    if fraction <= 0.0:
        return np.zeros_like(qd_prev_radps), 0.0
    ratio = max(0.0, fraction - dt_s / limits.t_brake_max_s) / fraction
    return np.asarray(qd_prev_radps * ratio, dtype=float), ratio


def bounded_by(rows: SafetyRows, qd_radps: FloatArray, delta: float, link_names: tuple[str, ...]) -> str:
    """What bounds δ: ``none`` at δ = 1; else the safety row closest to active (``safety:<link>/<capsule>``) when one
    is active, or ``limits`` (the joint limits and the task)."""
    if delta >= 1.0 - 1e-9:
        return "none"
    if rows.f_m2.size:
        slack = rows.f_m2 - rows.a_s @ qd_radps
        scale = np.abs(rows.a_s) @ np.abs(qd_radps) + np.abs(rows.f_m2) + 1e-12
        k = int(np.argmin(slack / scale))
        if slack[k] <= 1e-6 * scale[k]:
            return f"safety:{link_names[int(rows.link[k])]}/{int(rows.capsule[k])}"
    return "limits"


def decide(
    rows: SafetyRows,
    task: Task,
    qd_prev_radps: FloatArray,
    q_ref_rad: FloatArray,
    limits: Limits,
    dt_s: float,
    qd_self_radps: FloatArray,
    cap: Callable[[float], float],
    link_names: tuple[str, ...],
    delta_prev: float = 0.0,
    bound_if_infeasible: float = 0.0,
) -> Solution:
    """One cycle's command: LP (9), then LP (13) at min(δ*, ``cap(δ*)``), each answer checked against the rows; the
    ramp stop when a solve fails, an answer breaks a row, or the cap is 0 (or not a number).

    Args:
        cap: the zones and faults: the most δ they allow given the LPs' δ* (called exactly once, so it may advance a
            state machine).
        delta_prev: δ of the previous command: a ramp stop scales it as it scales the velocity (the task's time keeps
            pace with the motion along the path).
        bound_if_infeasible: what ``cap`` is told when LP (9) has no solution: eq. (15)'s bound at the program's
            velocity (the robot must slow faster than q̈max allows: a bound below the current speed, not a stop
            demanded by the separation; the zones judge it as the closed mode would).
    """
    lower, upper = velocity_bounds(qd_prev_radps, q_ref_rad, limits, dt_s)
    every_row = rows  # every answer is checked against all of them
    rows = rows_within(rows, lower, upper)
    best = solve_lp9(rows, task, lower, upper)

    def stop(why: str) -> Solution:
        qd, ratio = ramp_stop_ratio(qd_prev_radps, limits, dt_s)
        return Solution(qd, delta_prev * ratio if math.isfinite(delta_prev) else 0.0, f"ramp_stop:{why}")

    if best is None:
        cap(bound_if_infeasible)
        return stop("lp9_infeasible")
    qd9, delta_star = best
    if violated_rows(every_row, qd9).size:
        cap(0.0)
        return stop("lp9_breaks_a_row")
    allowed = cap(delta_star)
    if not (allowed > 0.0):  # nan too
        return stop("commanded")
    delta = min(delta_star, allowed)
    why = bounded_by(rows, qd9, delta_star, link_names) if delta == delta_star else "zone"
    room = with_self_motion_room(delta, delta_star, task)
    second = solve_lp13(rows, task, room, lower, upper, qd_self_radps)
    if second is not None and not violated_rows(every_row, second[0]).size:
        return Solution(second[0], room, "lp13", why, second[1])
    if delta < delta_star:  # LP (9)'s q̇ is for δ*, not for the cap
        return stop("capped_infeasible")
    return Solution(qd9, delta, "lp9", why)


def with_self_motion_room(delta: float, delta_star: float, task: Task) -> float:
    """δ for LP (13): δ* (1 − :data:`SELF_MOTION_ROOM`) when LP (9) bounds it below 1 (as :func:`bounded_by` reads
    it), nothing lower was asked for and the robot has joints beyond the task (a UR5 has none: its LP (9) *is* eq.
    (15) and keeps eq. (15)'s δ); else ``delta`` (at δ = 1 the redundancy is free already; a zone's lower δ leaves room
    of its own)."""
    redundant = task.jacobian.shape[1] > task.jacobian.shape[0]
    if redundant and delta == delta_star and delta_star < 1.0 - 1e-9:
        return delta_star * (1.0 - SELF_MOTION_ROOM)
    return delta


def fixed_cap(value: float) -> Callable[[float], float]:
    """A cap that does not depend on δ* (tests, and a decision that is already faulted)."""
    return lambda _delta_star: value


def self_motion_reference(
    task: Task,
    delta: float,
    toward_posture_radps: FloatArray,
    away_from_people_radps: FloatArray,
) -> FloatArray:
    """q̇⁰ of LP (13): the minimum-norm task velocity at δ plus, in the task's null space, the pull back to the
    program's posture and the push away from people (both already scaled) [rad/s]."""
    jac = task.jacobian
    pinv = np.linalg.pinv(jac, rcond=1e-6)
    null = np.eye(jac.shape[1]) - pinv @ jac
    task_radps = pinv @ (delta * task.x_rate + task.correction)
    return np.asarray(task_radps + null @ (toward_posture_radps + away_from_people_radps), dtype=float)


def away_from_people(
    jac_a: FloatArray,
    jac_b: FloatArray,
    p_a_m: FloatArray,
    p_b_m: FloatArray,
    surface_distance_m: FloatArray,
    closest_human_point_m: FloatArray,
    influence_m: float,
    gain_radps: float,
) -> FloatArray:
    """A joint velocity that moves each link's ends away from the nearest person within ``influence_m``: Σ over links
    of w_i J_rᵀ n_i, n_i the unit direction from the person's nearest point to the link end, w_i = (1 − d_i /
    influence) clipped to [0, 1]; scaled so its largest joint speed is ``gain_radps`` at full weight [rad/s].

    Args:
        surface_distance_m: per link, the distance to the nearest person, shape (L,) (inf with nobody) [m].
        closest_human_point_m: per link, that person's nearest point, shape (L, 3) [m].
    """
    n = jac_a.shape[2]
    push = np.zeros(n)
    if not math.isfinite(influence_m) or influence_m <= 0.0:
        return push
    weight = np.clip(1.0 - surface_distance_m / influence_m, 0.0, 1.0)
    weight = np.where(np.isfinite(weight), weight, 0.0)
    for i in np.flatnonzero(weight > 0.0):
        for p, jac in ((p_a_m[i], jac_a[i]), (p_b_m[i], jac_b[i])):
            away = p - closest_human_point_m[i]
            norm = float(np.linalg.norm(away))
            if norm > 1e-9:
                push += weight[i] * (jac.T @ (away / norm))
    peak = float(np.max(np.abs(push), initial=0.0))
    if peak <= 1e-12:
        return push
    return np.asarray(push * (gain_radps * float(weight.max()) / peak), dtype=float)
