"""Joint states consistent with themselves: how far ``q`` moved between stamps against the velocities reported.

A controller reports, per joint, its position ``q``, its velocity ``qd`` and the programmed velocity ``qd_nominal``
with the override it applies (``override · qd_nominal`` is the velocity it claims to run at). The door already
checks ``qd`` against ``override · qd_nominal`` within one state (``qd_inconsistent``) and ``q``'s change against
the velocity *limits* (``q_jump``). This module checks ``q``'s change against the velocities reported: a state
whose ``q`` advances at the programmed speed while ``qd`` and ``qd_nominal`` say 0 passes both of those, and the
gateway, believing the robot still, would command δ = 1.

**The bound (per joint).** Between two accepted states a < c, the joint moved Δq = q_c − q_a. Over each interval
[t_{i−1}, t_i] of the chain of accepted states between them, a velocity whose rate of change is at most A has its
mean within A · Δt_i / 4 of the mean of its two endpoint samples (the trapezoid). So

    | Δq − Σ (v_{i−1} + v_i) / 2 · Δt_i |  ≤  slack,

with v the reported ``qd``; and separately with v = ``override · qd_nominal``, whose per-state tolerance (the door's
``streams.qd_tolerance_*``) adds Σ tol_i · Δt_i. The slack holds what the stamps and the controller's noise allow:

    slack = 2 · Q_NOISE_RAD + 3 · STAMP_JITTER_S · max |v| + Σ A · Δt_i² / 4,   A = velocity limit / ACCEL_TIME_MIN_S.

A stamp off by ε from the instant its ``q`` was taken moves the sum's interval boundaries by ε; the sum telescopes, so
a steady error costs ε times the velocity at each end, and a change of the error within the stretch once more (the
UR bridge's stamp offset moves rarely; the emulator's and ABB's stamps are the instants their ``q`` belongs to).
Position noise enters at the two ends only. So a state is judged against every accepted state of the last
:data:`WINDOW_S`: a contradiction grows with the stretch while the slack barely does. A state that reports 0 while
its ``q`` advances at v is refused once v · T > 2 mrad + A · Δt · T / 4 over a stretch T (at 4 ms between states on a
UR5: any v above about 0.07 rad/s, within 0.25 s; 2 mrad in one 4 ms step above 0.5 rad/s).

What it catches is a contradiction *in motion*: a controller standing still (override 0, ``qd`` 0, ``q`` constant)
is consistent whatever ``qd_nominal`` says. That is why a contradiction found here, or by ``qd_inconsistent``,
names the joints it was seen on, and the door (:mod:`gateway.inputs`) keeps the fault until each of them has been
seen moving consistently (:func:`moving`), not merely until a still robot has been consistent for the hold.
"""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

NS_PER_S = 1e9

Q_NOISE_RAD = 0.001
"""How far a reported ``q`` may be from the position its velocities integrate to, at each end of a judged stretch
[rad]: encoder quantisation and the controller's filtering of ``qd`` (a real UR's ``actual_qd`` is its own estimate,
not the difference of ``actual_q``: docs/controllers.md)."""

STAMP_JITTER_S = 0.004
"""How far a stamp may be from the instant its ``q`` was taken [s]: one controller cycle (the emulator reads its
monotonic clock, then stamps with its wall clock; the UR bridge stamps the controller's time plus the smallest
offset of the last second, which moves when that offset leaves the window; ABB's ``qd`` is ``q`` differenced over
the very receive times it is stamped with)."""

ACCEL_TIME_MIN_S = 0.05
"""No joint reaches its velocity limit from rest in less than this [s]: A = limit / this bounds how far a velocity
may turn within one interval (the A · Δt² / 4 term; 0.25 mrad at 4 ms for a UR5 base; it loosens the check only
across long gaps between states)."""

STAMP_SPEED_FACTOR = 3.0
"""The stamps' error counts this many times :data:`STAMP_JITTER_S` at the stretch's largest speed: once at each end,
once for a change of the error within the stretch (the UR bridge's offset moving) [1]."""

WINDOW_S = 0.25
"""A state is judged against every accepted state stamped within this before it [s]."""

PROOF_SPAN_S = 0.1
"""A state proves a joint moving consistently only when judged against accepted states reaching this far back [s]: a
lie too small to show over one 4 ms step shows over this (a liar whose every state is refused for the whole window is
judged over one long interval, far too loosely to prove anything)."""

HISTORY_STATES = 160
"""Accepted states kept per robot (500 Hz × :data:`WINDOW_S`, and some)."""


class MotionEntry(NamedTuple):
    """One accepted state with the running sums of its chain (each sum from the chain's first state to this one).

    Attributes:
        stamp_ns: the state's stamp [ns].
        q_rad: positions [rad].
        v_radps: the reported ``qd`` [rad/s].
        w_radps: ``override · qd_nominal`` [rad/s].
        w_room_radps: how far ``qd`` may be from w in this state (the door's ``streams.qd_tolerance_*``) [rad/s].
        moved_v_rad, moved_w_rad: Σ (v_{i−1} + v_i) / 2 · Δt_i, the same for w [rad].
        room_w_rad: Σ tol_i · Δt_i, the per-state tolerance of ``qd`` against w over each interval [rad].
        turn_rad: Σ A · Δt_i² / 4 [rad].
        packed: the eight arrays above as the rows of one array (shape (8, n), in :data:`_PACKED` order), so that
            judging a state against the window stacks one array per anchor, not eight.
    """

    stamp_ns: int
    q_rad: FloatArray
    v_radps: FloatArray
    w_radps: FloatArray
    w_room_radps: FloatArray
    moved_v_rad: FloatArray
    moved_w_rad: FloatArray
    room_w_rad: FloatArray
    turn_rad: FloatArray
    packed: FloatArray


_PACKED = MotionEntry._fields[1:-1]
"""The rows of :attr:`MotionEntry.packed`."""
_Q, _V, _W, _ROOM, _MOVED_V, _MOVED_W, _ROOM_W, _TURN = range(len(_PACKED))


def _entry(stamp_ns: int, *arrays: FloatArray) -> MotionEntry:
    """An entry of the eight arrays (in :data:`_PACKED` order), packed once."""
    packed = np.stack(np.broadcast_arrays(*arrays))
    q, v, w, room, moved_v, moved_w, room_w, turn = packed
    return MotionEntry(stamp_ns, q, v, w, room, moved_v, moved_w, room_w, turn, packed)


class MotionContradiction(NamedTuple):
    """Joints whose ``q`` moved other than the velocities reported allow.

    Attributes:
        joints: per joint, contradicted against ``qd`` or ``override · qd_nominal``.
        detail: the worst contradicted joint, what it moved and what was allowed, for the fault's reason.
    """

    joints: BoolArray
    detail: str


def extend(
    previous: MotionEntry | None,
    stamp_ns: int,
    q_rad: FloatArray,
    v_radps: FloatArray,
    w_radps: FloatArray,
    w_room_radps: FloatArray,
    accel_radps2: FloatArray,
) -> MotionEntry:
    """The entry of a state that follows ``previous`` on the chain (a new chain without one).

    Args:
        w_room_radps: how far ``qd`` may be from ``override · qd_nominal`` in this state, per joint [rad/s]; over
            an interval the larger of its two states' counts.
        accel_radps2: A per joint [rad/s²].
    """
    if previous is None:
        zero = np.zeros_like(q_rad)
        return _entry(stamp_ns, q_rad, v_radps, w_radps, w_room_radps, zero, zero, zero, zero)
    dt_s = max(0, stamp_ns - previous.stamp_ns) / NS_PER_S
    p = previous
    return _entry(
        stamp_ns,
        q_rad,
        v_radps,
        w_radps,
        w_room_radps,
        p.moved_v_rad + 0.5 * (p.v_radps + v_radps) * dt_s,
        p.moved_w_rad + 0.5 * (p.w_radps + w_radps) * dt_s,
        p.room_w_rad + np.maximum(p.w_room_radps, w_room_radps) * dt_s,
        p.turn_rad + accel_radps2 * dt_s * dt_s / 4.0,
    )


class MotionHistory(deque[MotionEntry]):
    """The accepted states of one chain, oldest first (a deque of at most :data:`HISTORY_STATES`), with their packed
    arrays and stamps kept side by side in one buffer: judging a state against the window takes a view of it instead
    of stacking an array per anchor (a joint state arrives every 4 ms per robot; the stacking was most of its cost)."""

    def __init__(self, maxlen: int = HISTORY_STATES) -> None:
        super().__init__(maxlen=maxlen)
        self._packed: FloatArray | None = None  # (2 · maxlen, 8, n): rows [start, end) mirror the deque
        self._stamps = np.zeros(2 * maxlen, dtype=np.int64)
        self._start = self._end = 0

    def append(self, entry: MotionEntry) -> None:
        maxlen = self.maxlen or HISTORY_STATES
        if self._packed is None or self._packed.shape[1:] != entry.packed.shape:
            super().clear()
            self._packed = np.empty((2 * maxlen, *entry.packed.shape))
            self._start = self._end = 0
        if self._end == self._packed.shape[0]:  # full: the newest maxlen − 1 rows move to the front
            keep = min(len(self), maxlen - 1)
            self._packed[:keep] = self._packed[self._end - keep : self._end]
            self._stamps[:keep] = self._stamps[self._end - keep : self._end]
            self._start, self._end = 0, keep
        super().append(entry)
        self._packed[self._end] = entry.packed
        self._stamps[self._end] = entry.stamp_ns
        self._end += 1
        self._start = self._end - len(self)

    def clear(self) -> None:
        super().clear()
        self._start = self._end = 0

    def window(self, oldest_ns: float) -> tuple[FloatArray, npt.NDArray[np.int64]]:
        """The packed arrays (anchors, 8, n) and stamps of the entries stamped at or after ``oldest_ns``, or of the
        newest alone when none is; views, valid until the next append. Raises IndexError when empty."""
        if not self or self._packed is None:
            raise IndexError("an empty history has no window")
        stamps = self._stamps[self._start : self._end]
        first = min(int(np.searchsorted(stamps, oldest_ns, side="left")), len(stamps) - 1)
        return self._packed[self._start + first : self._end], stamps[first:]


def _window(history: deque[MotionEntry], oldest_ns: float) -> tuple[FloatArray, npt.NDArray[np.int64]]:
    """The packed arrays and stamps of the anchors within the window (any deque; a :class:`MotionHistory` without
    stacking). The stamps of a chain increase (older or repeated states are refused before they are kept)."""
    if isinstance(history, MotionHistory):
        return history.window(oldest_ns)
    anchors = [a for a in history if a.stamp_ns >= oldest_ns] or [history[-1]]
    return np.stack([a.packed for a in anchors]), np.array([a.stamp_ns for a in anchors], dtype=np.int64)


def _slack_rad(speed_max_radps: FloatArray, turn_rad: FloatArray) -> FloatArray:
    """What the stamps and the noise allow over a stretch whose largest speed is ``speed_max_radps`` [rad]."""
    return 2.0 * Q_NOISE_RAD + STAMP_SPEED_FACTOR * STAMP_JITTER_S * speed_max_radps + turn_rad


def _suffix_max(values: FloatArray) -> FloatArray:
    """Row k: the largest of rows k.. (per column)."""
    return np.asarray(np.maximum.accumulate(values[::-1], axis=0)[::-1])


class _Judged(NamedTuple):
    """A state against each anchor (rows) and joint (columns): how far ``q`` moved from what each velocity
    integrates to, and how far it may [rad]."""

    anchor_stamps_ns: npt.NDArray[np.int64]
    moved_rad: FloatArray
    integrated_v_rad: FloatArray
    integrated_w_rad: FloatArray
    error_v_rad: FloatArray
    allowed_v_rad: FloatArray
    error_w_rad: FloatArray
    allowed_w_rad: FloatArray


def _judge(history: deque[MotionEntry], state: MotionEntry) -> _Judged | None:
    if not history:
        return None
    # the newest accepted state always, however old: a stream slower than the window is still judged
    stack, stamps = _window(history, state.stamp_ns - WINDOW_S * NS_PER_S)  # (anchors, 8, joints)
    moved_rad = state.q_rad - stack[:, _Q]
    turn_rad = state.turn_rad - stack[:, _TURN]
    speed_v = np.maximum(_suffix_max(np.abs(stack[:, _V])), np.abs(state.v_radps))
    speed_w = np.maximum(_suffix_max(np.abs(stack[:, _W])), np.abs(state.w_radps))
    integrated_v = state.moved_v_rad - stack[:, _MOVED_V]
    integrated_w = state.moved_w_rad - stack[:, _MOVED_W]
    return _Judged(
        stamps,
        moved_rad,
        integrated_v,
        integrated_w,
        np.abs(moved_rad - integrated_v),
        _slack_rad(speed_v, turn_rad),
        np.abs(moved_rad - integrated_w),
        state.room_w_rad - stack[:, _ROOM_W] + _slack_rad(speed_w, turn_rad),
    )


def contradiction(history: deque[MotionEntry], state: MotionEntry) -> MotionContradiction | None:
    """What joints of ``state`` (already :func:`extend`-ed from the newest of ``history``) moved other than the
    velocities reported since any state of ``history`` within :data:`WINDOW_S` (and the newest), or None.

    ``history`` holds accepted states, oldest first, on one chain; an empty one judges nothing.
    """
    judged = _judge(history, state)
    if judged is None:
        return None
    off_v = judged.error_v_rad - judged.allowed_v_rad
    off_w = judged.error_w_rad - judged.allowed_w_rad
    off = np.maximum(off_v, off_w)
    joints: BoolArray = np.asarray((off > 0.0).any(axis=0))
    if not joints.any():
        return None
    k, j = (int(i) for i in np.unravel_index(int(np.argmax(off)), off.shape))
    of_qd = off_v[k, j] >= off_w[k, j]
    integrated = judged.integrated_v_rad if of_qd else judged.integrated_w_rad
    dt_ms = (state.stamp_ns - int(judged.anchor_stamps_ns[k])) / 1e6
    detail = (
        f"joint {j} moved {judged.moved_rad[k, j]:+.4f} rad in {dt_ms:.1f} ms, "
        f"{'qd' if of_qd else 'override × qd_nominal'} integrate to {integrated[k, j]:+.4f} rad "
        f"({off[k, j]:.4f} rad beyond the tolerance)"
    )
    return MotionContradiction(joints, detail)


def tolerance_used(history: deque[MotionEntry], state: MotionEntry) -> float:
    """The largest share of its tolerance a state's motion uses, over anchors, joints and both velocities (> 1:
    a contradiction; 0 without a history) [1]. For measuring honest streams (``bench.joint_motion``)."""
    judged = _judge(history, state)
    if judged is None:
        return 0.0
    return float(
        max((judged.error_v_rad / judged.allowed_v_rad).max(), (judged.error_w_rad / judged.allowed_w_rad).max())
    )


def judged_span_s(history: deque[MotionEntry], stamp_ns: int) -> float:
    """How far back the accepted states within :data:`WINDOW_S` of ``stamp_ns`` reach (0 without any) [s]."""
    for entry in history:  # oldest first
        if stamp_ns - entry.stamp_ns <= WINDOW_S * NS_PER_S:
            return (stamp_ns - entry.stamp_ns) / NS_PER_S
    return 0.0


def moving(velocity_radps: FloatArray, threshold_radps: FloatArray) -> BoolArray:
    """Joints whose velocity exceeds ``threshold_radps``, per joint. The door passes half its ``qd`` tolerance: a
    reversed ``qd_nominal`` differs from ``qd`` by twice the speed, so above that a reversal shows."""
    return np.asarray(np.abs(velocity_radps) > threshold_radps)
