"""LP (9) then LP (13) per cycle without numpy's per-call cost: the decision of :func:`gateway.open_control.decide`,
assembled by numba kernels into buffers kept between cycles.

:func:`gateway.open_control.decide` (numpy) is the reference: it builds each LP with ~40 numpy calls (bounds, the
rows some q̇ in the box could break, ``np.zeros``/``np.concatenate`` of the constraint matrices, finiteness checks,
each answer checked against every row), and those calls cost 1–3 µs each, more than DAQP itself on most cycles. Here
a compiled call per step does the same arithmetic in the same order into preallocated buffers (grown when a cycle
has more rows than any before), and DAQP is called as the reference calls it.

DAQP is called directly (:mod:`gateway.daqp_direct`: ``daqp_quadprog`` through ctypes on these buffers, the
structures bound when the buffers are made), where ``daqp.solve``, the reference's entry, spends ~3.5 µs per call in
its wrapper; where the installed DAQP is not the one declared there, ``daqp.solve`` as the reference. Both run DAQP's C
solver cold on the same data with the same settings: the same answers. A reused ``daqp.Model`` does not fit: its
``update`` keeps the dimensions of its ``setup`` (the rows kept change every cycle) and starts from the previous
active set, which may end on another vertex of a degenerate LP (13) — another answer.

The control flow of :meth:`OpenLp.decide` is the reference's, line by line, with the same fail-closed exits:
non-finite data or an empty velocity box → LP (9) infeasible → ramp stop; an answer that breaks a row → ramp stop;
the cap called once with the same δ*. ``tests/gateway/test_open_kernels.py`` checks both against each other on
seeded random problems, infeasible and non-finite ones included: the same q̇, δ and objective, bit for bit.

What can differ is the summation order of the row products (a loop here, BLAS there): when several rows are active
at the optimum their slacks tie to ~1e-16 and ``bounded_by`` may name another of them; a row whose largest left side
over the box equals its right-hand side to the last bit may be kept by one and dropped by the other (such a row
cannot bind); a check at exactly :data:`ROW_TOLERANCE` may round the other way.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable
from typing import Any

import daqp
import numpy as np

from gateway.daqp_direct import DirectLp, direct_lp_or_none
from gateway.kernels import _compiled
from gateway.open_control import (
    _EXIT_OPTIMAL,
    _SENSE_EQUALITY,
    NO_BOUND,
    ROW_TOLERANCE,
    FloatArray,
    Limits,
    SafetyRows,
    Solution,
    Task,
    with_self_motion_room,
)

log = logging.getLogger(__name__)

_OK = 0
_NOT_FINITE = 1
_EMPTY_BOX = 2


@functools.cache
def _direct_lp_usable() -> bool:
    """Whether DAQP is called directly (:mod:`gateway.daqp_direct`); said once in the log when it is not."""
    why_not = direct_lp_or_none()
    if why_not is not None:
        log.warning("DAQP called through daqp.solve, not directly: %s", why_not)
    return why_not is None


# -- kernels ---------------------------------------------------------------------------------------------------


@_compiled
def _nan_max(a: float, b: float) -> float:
    """``np.maximum`` of two scalars: nan when either is nan."""
    if math.isnan(a):
        return a
    if math.isnan(b):
        return b
    return a if a >= b else b


@_compiled
def _nan_min(a: float, b: float) -> float:
    """``np.minimum`` of two scalars: nan when either is nan."""
    if math.isnan(a):
        return a
    if math.isnan(b):
        return b
    return a if a <= b else b


@_compiled
def _velocity_box(
    qd_prev: Any, q_ref: Any, qd_max: Any, qdd_max: Any, q_min: Any, q_max: Any, dt_s: float, bounds: Any
) -> bool:
    """The bounds (9d)–(9f) into ``bounds`` (4, n): lower, upper (:func:`gateway.open_control.velocity_bounds`), the
    box's centre and half width. True when the box is empty (lower > upper somewhere)."""
    empty = False
    for j in range(qd_prev.size):
        lower = _nan_max(
            _nan_max(qd_prev[j] - qdd_max[j] * dt_s, -qd_max[j]), _nan_min((q_min[j] - q_ref[j]) / dt_s, 0.0)
        )
        upper = _nan_min(
            _nan_min(qd_prev[j] + qdd_max[j] * dt_s, qd_max[j]), _nan_max((q_max[j] - q_ref[j]) / dt_s, 0.0)
        )
        bounds[0, j] = lower
        bounds[1, j] = upper
        bounds[2, j] = 0.5 * (lower + upper)
        bounds[3, j] = 0.5 * _nan_max(upper - lower, 0.0)
        if lower > upper:
            empty = True
    return empty


@_compiled
def _rows_in_box(a_s: Any, f_m2: Any, bounds: Any, kept: Any) -> int:
    """The rows some q̇ in the box could break (:func:`gateway.open_control.rows_within`): their indices into
    ``kept``; returns how many."""
    n = a_s.shape[1]
    centre = bounds[2]
    half = bounds[3]
    m = 0
    for i in range(f_m2.size):
        lhs = 0.0
        reach = 0.0
        for j in range(n):
            a = a_s[i, j]
            lhs += a * centre[j]
            reach += abs(a) * half[j]
        if not (lhs + reach <= f_m2[i]):  # nan keeps the row
            kept[m] = i
            m += 1
    return m


@_compiled
def _lp9(
    a_s: Any,
    f_m2: Any,
    jac: Any,
    x_rate: Any,
    correction: Any,
    qd_prev: Any,
    q_ref: Any,
    qd_max: Any,
    qdd_max: Any,
    q_min: Any,
    q_max: Any,
    dt_s: float,
    bounds: Any,
    kept: Any,
    a9: Any,
    bu9: Any,
    bl9: Any,
    sense9: Any,
) -> Any:
    """LP (9) into the buffers: the velocity box (:func:`_velocity_box`), the rows within it (:func:`_rows_in_box`),
    then A, the bounds and the senses of :func:`gateway.open_control.solve_lp9`. Returns (rows kept, :data:`_OK` /
    :data:`_NOT_FINITE` / :data:`_EMPTY_BOX`)."""
    n = qd_prev.size
    k = x_rate.size
    empty = _velocity_box(qd_prev, q_ref, qd_max, qdd_max, q_min, q_max, dt_s, bounds)
    m = _rows_in_box(a_s, f_m2, bounds, kept)
    finite = True
    for r in range(m):
        i = kept[r]
        for j in range(n):
            v = a_s[i, j]
            a9[r, j] = v
            finite &= math.isfinite(v)
        a9[r, n] = 0.0
        bu9[n + 1 + r] = f_m2[i]
        bl9[n + 1 + r] = -NO_BOUND
        sense9[n + 1 + r] = 0
        finite &= math.isfinite(f_m2[i])
    for r in range(k):
        for j in range(n):
            v = jac[r, j]
            a9[m + r, j] = v
            finite &= math.isfinite(v)
        a9[m + r, n] = -x_rate[r]
        c = correction[r]
        bu9[n + 1 + m + r] = c
        bl9[n + 1 + m + r] = c
        sense9[n + 1 + m + r] = _SENSE_EQUALITY
        finite &= math.isfinite(x_rate[r]) and math.isfinite(c)
    for j in range(n):
        bu9[j] = bounds[1, j]
        bl9[j] = bounds[0, j]
        sense9[j] = 0
        finite &= math.isfinite(bounds[0, j]) and math.isfinite(bounds[1, j])
    bu9[n] = 1.0
    bl9[n] = 0.0
    sense9[n] = 0
    if not finite:
        return m, _NOT_FINITE
    if empty:
        return m, _EMPTY_BOX
    return m, _OK


@_compiled
def _lp13(
    m: int,
    jac: Any,
    x_rate: Any,
    correction: Any,
    delta: float,
    qd_self: Any,
    bounds: Any,
    a9: Any,
    bu9: Any,
    a13: Any,
    bu13: Any,
    bl13: Any,
    sense13: Any,
) -> bool:
    """LP (13) at δ into the buffers (A, bounds, senses of :func:`gateway.open_control.solve_lp13`), its safety rows
    the ``m`` LP (9) kept (``a9``, ``bu9``). False when some of it is not finite."""
    n = qd_self.size
    k = x_rate.size
    finite = True
    for r in range(m):
        for j in range(n):
            a13[r, j] = a9[r, j]
        a13[r, n] = 0.0
        bu13[n + 1 + r] = bu9[n + 1 + r]
        bl13[n + 1 + r] = -NO_BOUND
        sense13[n + 1 + r] = 0
    for r in range(k):
        for j in range(n):
            v = jac[r, j]
            a13[m + r, j] = v
            finite &= math.isfinite(v)
        a13[m + r, n] = 0.0
        target = delta * x_rate[r] + correction[r]
        bu13[n + 1 + m + r] = target
        bl13[n + 1 + m + r] = target
        sense13[n + 1 + m + r] = _SENSE_EQUALITY
        finite &= math.isfinite(target)
    gap = 0.0
    first = True
    for j in range(n):
        for v in (bounds[0, j], bounds[1, j], qd_self[j]):
            w = abs(v)
            gap = w if first else _nan_max(gap, w)
            first = False
    gap_max = gap * 2.0 + 1.0
    base = m + k
    for r in range(n):
        for j in range(n):
            a13[base + r, j] = 1.0 if j == r else 0.0  # q̇ − t ≤ q̇⁰
            a13[base + n + r, j] = 1.0 if j == r else 0.0  # q̇ + t ≥ q̇⁰
        a13[base + r, n] = -1.0
        a13[base + n + r, n] = 1.0
        s = qd_self[r]
        bu13[n + 1 + base + r] = s
        bl13[n + 1 + base + r] = -NO_BOUND
        bu13[n + 1 + base + n + r] = NO_BOUND
        bl13[n + 1 + base + n + r] = s
        sense13[n + 1 + base + r] = 0
        sense13[n + 1 + base + n + r] = 0
        finite &= math.isfinite(s)
    for j in range(n):
        bu13[j] = bounds[1, j]
        bl13[j] = bounds[0, j]
        sense13[j] = 0
        finite &= math.isfinite(bounds[0, j]) and math.isfinite(bounds[1, j])
    bu13[n] = gap_max
    bl13[n] = 0.0
    sense13[n] = 0
    finite &= math.isfinite(gap_max)
    return finite


@_compiled
def _breaks_a_row(a_s: Any, f_m2: Any, qd: Any) -> bool:
    """Whether ``qd`` breaks a row beyond :data:`ROW_TOLERANCE` (:func:`gateway.open_control.violated_rows` is not
    empty); nan counts as broken."""
    n = qd.size
    for i in range(f_m2.size):
        lhs = 0.0
        scale = 0.0
        for j in range(n):
            a = a_s[i, j]
            lhs += a * qd[j]
            scale += abs(a) * abs(qd[j])
        scale += abs(f_m2[i]) + 1.0
        if not (lhs - f_m2[i] <= ROW_TOLERANCE * scale):
            return True
    return False


@_compiled
def _tightest(m: int, a9: Any, bu9: Any, qd: Any) -> int:
    """The kept row closest to active (:func:`gateway.open_control.bounded_by`): its position among the kept rows,
    -1 when none is active."""
    n = qd.size
    best = -1
    best_ratio = 0.0
    best_slack = 0.0
    best_scale = 0.0
    for r in range(m):
        lhs = 0.0
        scale = 0.0
        for j in range(n):
            a = a9[r, j]
            lhs += a * qd[j]
            scale += abs(a) * abs(qd[j])
        f = bu9[n + 1 + r]
        scale += abs(f) + 1e-12
        slack = f - lhs
        ratio = slack / scale
        if best < 0 or ratio < best_ratio or math.isnan(ratio):
            best, best_ratio, best_slack, best_scale = r, ratio, slack, scale
            if math.isnan(ratio):  # np.argmin: the first nan
                break
    if best >= 0 and best_slack <= 1e-6 * best_scale:
        return best
    return -1


@_compiled
def _ramp_stop(qd_prev: Any, qd_max: Any, dt_s: float, t_brake_max_s: float, qd_out: Any) -> float:
    """:func:`gateway.open_control.ramp_stop_ratio` into ``qd_out``; returns the ratio."""
    n = qd_prev.size
    fraction = 0.0
    for j in range(n):
        if not math.isfinite(qd_prev[j]):
            qd_out[:] = 0.0
            return 0.0
    for j in range(n):
        fraction = _nan_max(fraction, abs(qd_prev[j]) / qd_max[j])
    if fraction <= 0.0:
        qd_out[:] = 0.0
        return 0.0
    left = fraction - dt_s / t_brake_max_s
    ratio = (left if left > 0.0 else 0.0) / fraction  # Python's max(0.0, left), nan included
    for j in range(n):
        qd_out[j] = qd_prev[j] * ratio
    return ratio


# -- the decision --------------------------------------------------------------------------------------------------


class OpenLp:
    """The buffers of LP (9) and (13) of one robot, kept between cycles, and :meth:`decide`.

    Building one compiles the kernels (or loads them from numba's on-disk cache) with a small problem of the loop's
    argument types, so the first cycle is not slow.
    """

    def __init__(self) -> None:
        self._shape = (-1, -1, -1)  # (joints n, task rows k, row capacity)
        self._m = 0
        self._cost9 = np.zeros(0)
        self._cost13 = np.zeros(0)
        self._direct9: DirectLp | None = None
        self._direct13: DirectLp | None = None
        self._warm_up()

    def _warm_up(self) -> None:
        """Every kernel, with the task Jacobian in either memory order (Pinocchio's are Fortran-ordered)."""
        n = 2
        rows = SafetyRows(np.array([[1.0, 0.0]]), np.array([0.99]), np.zeros(1, np.intp), np.zeros(1, np.intp), 0)
        limits = Limits(np.full(n, 2.0), np.full(n, 4.0), np.full(n, -3.0), np.full(n, 3.0), 0.5)
        for jacobian in (np.eye(n), np.asfortranarray(np.eye(n))):
            task = Task(jacobian, np.ones(n), np.zeros(n))
            self.decide(rows, task, np.ones(n), np.zeros(n), limits, 0.004, np.ones(n), lambda d: d, ("l",))
            self.decide(rows, task, np.full(n, 1.9), np.zeros(n), limits, 0.004, np.ones(n), lambda d: d, ("l",))
        self._shape = (-1, -1, -1)

    def _buffers(self, n: int, k: int, m_all: int) -> None:
        if self._shape[:2] == (n, k) and self._shape[2] >= m_all:
            return
        rows = max(m_all, 2 * self._shape[2] if self._shape[:2] == (n, k) else 0, 64)
        self._shape = (n, k, rows)
        self._bounds = np.empty((4, n))  # lower, upper, the box's centre and half width
        self._kept = np.empty(rows, dtype=np.intp)
        self._a9 = np.empty((rows + k, n + 1))
        self._bu9 = np.empty(n + 1 + rows + k)
        self._bl9 = np.empty(n + 1 + rows + k)
        self._sense9 = np.zeros(n + 1 + rows + k, dtype=np.intc)
        self._a13 = np.empty((rows + k + 2 * n, n + 1))
        self._bu13 = np.empty(n + 1 + rows + k + 2 * n)
        self._bl13 = np.empty(n + 1 + rows + k + 2 * n)
        self._sense13 = np.zeros(n + 1 + rows + k + 2 * n, dtype=np.intc)
        self._cost9 = np.zeros(n + 1)
        self._cost9[n] = -1.0
        self._cost13 = np.zeros(n + 1)
        self._cost13[n] = 1.0
        self._direct9 = self._direct13 = None
        if _direct_lp_usable():
            self._direct9 = DirectLp(self._cost9, self._a9, self._bu9, self._bl9, self._sense9)
            self._direct13 = DirectLp(self._cost13, self._a13, self._bu13, self._bl13, self._sense13)

    def lp9(
        self,
        rows: SafetyRows,
        task: Task,
        qd_prev_radps: FloatArray,
        q_ref_rad: FloatArray,
        limits: Limits,
        dt_s: float,
    ) -> tuple[FloatArray, float] | None:
        """The bounds, the rows within them and LP (9) (:func:`gateway.open_control.solve_lp9` after
        :func:`~gateway.open_control.velocity_bounds` and :func:`~gateway.open_control.rows_within`): the largest δ
        and a q̇ with it, or None when infeasible, not finite or the solver fails. Leaves the kept rows and the bounds
        in the buffers for :meth:`lp13`."""
        n = qd_prev_radps.size
        k = task.x_rate.size
        self._buffers(n, k, rows.f_m2.size)
        m, status = _lp9(
            rows.a_s,
            rows.f_m2,
            task.jacobian,
            task.x_rate,
            task.correction,
            qd_prev_radps,
            q_ref_rad,
            limits.qd_max_radps,
            limits.qdd_max_radps2,
            limits.q_min_rad,
            limits.q_max_rad,
            dt_s,
            self._bounds,
            self._kept,
            self._a9,
            self._bu9,
            self._bl9,
            self._sense9,
        )
        self._m = m
        if status != _OK:
            return None
        if self._direct9 is not None:
            exitflag, z = self._direct9.solve(m + k), self._direct9.z
        else:
            end = n + 1 + m + k
            z, _, exitflag, _ = daqp.solve(
                None, self._cost9, self._a9[: m + k], self._bu9[:end], self._bl9[:end], self._sense9[:end]
            )
        if exitflag not in _EXIT_OPTIMAL:
            return None
        return z[:n].copy(), float(min(max(z[n], 0.0), 1.0))

    def lp13(self, task: Task, delta: float, qd_self_radps: FloatArray) -> tuple[FloatArray, float] | None:
        """LP (13) at δ on the rows and bounds of the last :meth:`lp9` (:func:`gateway.open_control.solve_lp13`)."""
        n = qd_self_radps.size
        k = task.x_rate.size
        m = self._m
        if not _lp13(
            m,
            task.jacobian,
            task.x_rate,
            task.correction,
            delta,
            qd_self_radps,
            self._bounds,
            self._a9,
            self._bu9,
            self._a13,
            self._bu13,
            self._bl13,
            self._sense13,
        ):
            return None
        if self._direct13 is not None:
            exitflag, z = self._direct13.solve(m + k + 2 * n), self._direct13.z
        else:
            end = n + 1 + m + k + 2 * n
            z, _, exitflag, _ = daqp.solve(
                None, self._cost13, self._a13[: m + k + 2 * n], self._bu13[:end], self._bl13[:end], self._sense13[:end]
            )
        if exitflag not in _EXIT_OPTIMAL:
            return None
        return z[:n].copy(), float(z[n])

    def bounded_by(self, rows: SafetyRows, qd_radps: FloatArray, delta: float, link_names: tuple[str, ...]) -> str:
        """:func:`gateway.open_control.bounded_by` on the rows the last :meth:`lp9` kept."""
        if delta >= 1.0 - 1e-9:
            return "none"
        r = _tightest(self._m, self._a9, self._bu9, qd_radps)
        if r < 0:
            return "limits"
        i = int(self._kept[r])
        return f"safety:{link_names[int(rows.link[i])]}/{int(rows.capsule[i])}"

    def decide(
        self,
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
        """One cycle's command: :func:`gateway.open_control.decide` (the same arguments, the same answer)."""
        best = self.lp9(rows, task, qd_prev_radps, q_ref_rad, limits, dt_s)

        def stop(why: str) -> Solution:
            qd = np.empty_like(qd_prev_radps)
            ratio = _ramp_stop(qd_prev_radps, limits.qd_max_radps, dt_s, limits.t_brake_max_s, qd)
            return Solution(qd, delta_prev * ratio if math.isfinite(delta_prev) else 0.0, f"ramp_stop:{why}")

        if best is None:
            cap(bound_if_infeasible)
            return stop("lp9_infeasible")
        qd9, delta_star = best
        if _breaks_a_row(rows.a_s, rows.f_m2, qd9):
            cap(0.0)
            return stop("lp9_breaks_a_row")
        allowed = cap(delta_star)
        if not (allowed > 0.0):  # nan too
            return stop("commanded")
        delta = min(delta_star, allowed)
        why = self.bounded_by(rows, qd9, delta_star, link_names) if delta == delta_star else "zone"
        room = with_self_motion_room(delta, delta_star, task)
        second = self.lp13(task, room, qd_self_radps)
        if second is not None and not _breaks_a_row(rows.a_s, rows.f_m2, second[0]):
            return Solution(second[0], room, "lp13", why, second[1])
        if delta < delta_star:  # LP (9)'s q̇ is for δ*, not for the cap
            return stop("capped_infeasible")
        return Solution(qd9, delta, "lp9", why)
