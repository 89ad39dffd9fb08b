"""A recorded program model: the programmed velocity ``qd_nominal`` of a closed controller, located from ``q`` alone.

A real controller reports where the robot is (``q``) and how fast it moves (``qd``, or nothing: ABB RWS), never how
fast its program would move at 100 % override. A commissioning step records one whole program cycle run at a steady
override δ_rec and keeps, per sample, the path point ``q`` and the programmed velocity ``dq/dτ = qd / δ_rec`` (τ the
program time). In operation the bridge locates the robot on that path from ``q`` and reads the programmed velocity
there, which works at any override, δ = 0 included::

    samples = samples_from_readings(readings)          # ControllerReading → (t, q, qd, applied scaling)
    model = record_program(samples, "ur5", joints, recorded_at="2026-01-30")
    save_model(model, "ur5_program.json"); model = load_model("ur5_program.json", "ur5", joints)
    where = model.locate(q_rad, previous_index)         # None: off the program, or ambiguous (see below)

    python -m controller_bridge.program_model record --config configs/cell.toml --robot ur5 --out ur5.json --seconds 20
    python -m controller_bridge.program_model check ur5.json

Locating. A program runs forward only, so with the previous location the search looks from a few samples behind it
to :data:`TRACK_AHEAD_S` of program time ahead, and takes the *first* local minimum of the distance that is as good
as the best one there (within the noise): a program that retraces its path (down to a pick and back up) has two path
points at every ``q`` of that stretch, and the earlier one in program order is the one the robot is on. Without a
previous location (or when the robot is not found near it) every part of the path within the tolerance is a
candidate; their velocities are merged per joint into the largest magnitude when they agree in sign, and when they
do not (a retraced stretch: one candidate moves down, the other up), the located velocity is ``None`` unless the
caller gives the measured motion, which keeps only the candidates moving that way. A wrong sign would tell the
gateway a link moves away from a person when it moves toward them, so the model refuses to guess; the bridge then
falls back to the joint velocity limits.

Accuracy (measured by ``tests/controller_bridge/test_program_model.py`` on the emulator's programs, recording at
δ = 0.5 with q noise of 1e-4 rad): see :data:`STATED_TOLERANCE_RADPS`; one ``locate`` with continuity costs about
60 µs (N ≈ 3000 samples), one without about 0.4–0.6 ms. Near the standstill points of the program
(the ends of every trapezoidal move, the dwells) ``q`` alone cannot resolve the velocity better than
``sqrt(2 a ε)`` (a the program's acceleration, ε the position noise): that is where the worst error is.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, NamedTuple

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from hrc_contract.config import ConfigError
from hrc_contract.errors import HrcError
from hrc_devices.controllers.registry import VENDORS
from hrc_devices.controllers.vendor import ControllerReading, VendorError, VendorInterface
from hrc_runtime.config import load_cell_config

FloatArray = npt.NDArray[np.float64]

SCHEMA = "hrc.program_model/1"
"""The file's schema name and version."""
MIN_RECORD_SCALING = 0.3
"""Lowest applied override a recording may run at: the programmed velocity is ``qd / δ``, so at a small δ the
controller's velocity noise and rounding are multiplied by 1/δ."""
MAX_SCALING_SPREAD = 0.05
"""The applied override may vary by this fraction of its mean over the recorded cycle (a steady override)."""
MAX_GAP_RATIO = 3.0
"""Two samples further apart in time than this many median sample periods are a gap."""
DEFAULT_TOLERANCE_RAD = 0.02
"""A ``q`` farther than this from the path (Euclidean norm over the joints) is off the program [rad]."""
CLOSURE_RAD = 0.01
"""The cycle closes where the recording's path returns to its start, sample by sample, within this [rad]."""
SIGNATURE_RAD = 0.2
"""Closure compares the stretch of path after the start until it has travelled this far (sum of |Δq|) [rad]."""
SMOOTHING_HALF_WINDOW = 3
"""The recording is smoothed by a local quadratic fit over this many samples either side."""
TRACK_BACK_SAMPLES = 3
"""With a previous location, the search starts this many samples behind it (the previous one may be noisy)."""
TRACK_AHEAD_S = 0.5
"""... and ends this far ahead of it in program time [s] (a reading period at δ = 1, plus missed readings)."""
NOISE_TIE = 3.0
"""Two path points whose distances to ``q`` differ by less than this × the noise (per joint) × √n are equally good:
each recorded path point is off the true path by the noise of n joints, so two recordings of one stretch (a retraced
move) are as far apart."""
VELOCITY_CONFLICT_RADPS = 0.05
"""Candidates whose velocities of one joint have opposite signs larger than this conflict [rad/s]."""
MOTION_MIN_RADPS = 0.01
"""A measured motion slower than this (norm over the joints) tells no direction [rad/s]."""
STATED_TOLERANCE_RADPS = 0.12
STATED_TOLERANCE_RATIO = 0.03
"""The stated accuracy: per joint, |located − true qd_nominal| ≤ 0.12 rad/s + 3 % of |true| along the whole program at
any override, δ = 0 included (worst measured 0.10 rad/s, at the robot's departure from a standstill point, before q
has moved farther than the noise: sqrt(2 a · NOISE_TIE σ √n)); p99 ≤ 0.03 rad/s; where |qd_nominal| ≥ 0.3 rad/s
within 0.01 rad/s + 1 %. Measured with q noise σ = 1e-4 rad on the recording and the read-back."""

VelocitySource = Literal["qd", "q_differences"]


class ProgramModelError(ConfigError):
    """A recording that cannot make a program model, or a model file that cannot be used for this robot."""


class ProgramSample(NamedTuple):
    """One read-back of the controller during the recording.

    Attributes:
        t_s: the bridge's monotonic time of the reading [s].
        q_rad: joint positions [rad].
        qd_radps: joint velocities [rad/s] (the controller's target velocity where it offers one); None: not offered.
        scaling: the override the controller applied, in [0, 1] (:func:`applied_scaling`).
        running: the program ran.
    """

    t_s: float
    q_rad: tuple[float, ...]
    qd_radps: tuple[float, ...] | None
    scaling: float
    running: bool = True


def applied_scaling(reading: ControllerReading) -> float:
    """The override the controller applied: ``speed_fraction × speed_scaling`` (UR: slider × trajectory scaling, what
    ur_rtde calls the combined speed scaling; ABB: the speed ratio, no further scaling)."""
    scaling = 1.0 if reading.speed_scaling is None else reading.speed_scaling
    return reading.speed_fraction * scaling


def samples_from_readings(readings: Iterable[ControllerReading]) -> list[ProgramSample]:
    """The recording's samples: monotonic time, ``q``, the target velocity (else the actual one), applied scaling."""
    return [
        ProgramSample(
            r.received_mono_ns / 1e9,
            r.q_rad,
            r.target_qd_radps if r.target_qd_radps is not None else r.qd_radps,
            applied_scaling(r),
            r.running,
        )
        for r in readings
    ]


@dataclass(frozen=True)
class Location:
    """Where the robot is on its program, and the programmed velocity there.

    Attributes:
        index: the path sample the robot is at; pass it as ``previous_index`` to the next :meth:`ProgramModel.locate`.
            None when the velocity was merged from several parts of the path (no single place to continue from).
        tau_s: program time of that place, in [0, duration) [s] (of the nearest part when merged).
        qd_nominal_radps: programmed joint velocity at 100 % override there [rad/s].
        distance_rad: distance from ``q`` to the path [rad].
        parts: how many parts of the path the velocity was taken from (1: tracked or unique).
    """

    index: int | None
    tau_s: float
    qd_nominal_radps: FloatArray
    distance_rad: float
    parts: int


class _Near(NamedTuple):
    at: int
    tau_s: float
    qd_radps: FloatArray
    d2: float


@dataclass(frozen=True, eq=False)
class ProgramModel:
    """One recorded program cycle: the path and its programmed velocity, sample by sample (cyclic).

    Attributes:
        robot: the robot's name.
        joint_names: its joints, in the order of ``q``.
        scaling: the override δ the cycle was recorded at.
        recorded_at: when (ISO 8601 date or time).
        velocity_source: where the velocities came from: ``qd`` (the read-back's velocity, the target one where the
            controller offers it) or ``q_differences`` (the derivative of ``q``).
        tau_s: program time of each sample, from 0, shape (N,) [s].
        duration_s: one program cycle in program time (at 100 % override) [s].
        q_rad: path points (smoothed), shape (N, n) [rad].
        qd_nominal_radps: programmed velocity dq/dτ at each point (smoothed), shape (N, n) [rad/s].
        noise_rad: the recording's position noise per joint, estimated from the smoothing's residuals [rad].
        tolerance_rad: a ``q`` farther than this from the path is off the program [rad].
    """

    robot: str
    joint_names: tuple[str, ...]
    scaling: float
    recorded_at: str
    velocity_source: VelocitySource
    tau_s: FloatArray
    duration_s: float
    q_rad: FloatArray
    qd_nominal_radps: FloatArray
    noise_rad: float
    tolerance_rad: float = DEFAULT_TOLERANCE_RAD

    @property
    def n_samples(self) -> int:
        return int(self.q_rad.shape[0])

    def locate(
        self,
        q_rad: Sequence[float] | FloatArray,
        previous_index: int | None = None,
        motion_radps: FloatArray | None = None,
    ) -> Location | None:
        """The robot's place on the program from its joint positions, and the programmed velocity there.

        Args:
            q_rad: joint positions [rad].
            previous_index: :attr:`Location.index` of the previous call, if any (continuity: the program runs forward).
            motion_radps: the measured joint velocity, if any; only its direction is used, to choose among parts of
                the path that ``q`` cannot tell apart [rad/s].

        Returns:
            The location, or None when ``q`` is farther than :attr:`tolerance_rad` from the path (off the program),
            not finite or of the wrong length, or when parts of the path within the tolerance move in opposite
            directions and nothing tells which one the robot is on (see the module docstring).
        """
        q = np.asarray(q_rad, dtype=float)
        if q.shape != (len(self.joint_names),) or not np.isfinite(q).all():
            return None
        tie_rad = NOISE_TIE * self.noise_rad * math.sqrt(q.shape[0])
        if previous_index is not None and 0 <= previous_index < self.n_samples:
            near = self._track(q, previous_index, tie_rad)
            if near is not None:
                return Location(near.at, near.tau_s, near.qd_radps, math.sqrt(near.d2), 1)
        return self._search(q, motion_radps)

    def _segments(self, starts: npt.NDArray[np.intp], q: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Squared distance from ``q`` to each path segment from sample ``starts[k]`` to the next one (cyclic), and
        where on it the nearest point lies (0 at its start, 1 at its end) [rad², 1]."""
        start = self.q_rad[starts]
        seg = self.q_rad[(starts + 1) % self.n_samples] - start
        rel = q - start
        length2 = np.einsum("ij,ij->i", seg, seg)
        u = np.clip(np.einsum("ij,ij->i", rel, seg) / np.maximum(length2, 1e-300), 0.0, 1.0)
        off = rel - u[:, None] * seg
        return np.einsum("ij,ij->i", off, off), u

    def _near(self, a: int, u: float, d2: float) -> _Near:
        """The point ``u`` of the way along the segment from sample ``a``: program time and velocity interpolated."""
        b = (a + 1) % self.n_samples
        tau_b = self.tau_s[b] if b > a else self.duration_s
        tau = float(self.tau_s[a] + u * (tau_b - self.tau_s[a])) % self.duration_s
        qd = (1.0 - u) * self.qd_nominal_radps[a] + u * self.qd_nominal_radps[b]
        return _Near(a, tau, qd, d2)

    def _track(self, q: FloatArray, previous: int, tie_rad: float) -> _Near | None:
        """The first local minimum of the distance, as good as the best, from ``previous`` forward.

        The few segments behind ``previous`` count only when clearly better than everything ahead (the previous
        location was noisy): as good is not enough, or the search would creep backward along a retraced stretch,
        whose mirror point lies just behind.
        """
        ahead = int(np.searchsorted(self.tau_s, TRACK_AHEAD_S))  # samples per TRACK_AHEAD_S (same at every start)
        idx = (previous + np.arange(-TRACK_BACK_SAMPLES, ahead + 1)) % self.n_samples
        d2, u = self._segments(idx, q)
        best = float(d2.min())
        if best > self.tolerance_rad**2:
            return None
        as_good = d2 <= (math.sqrt(best) + tie_rad) ** 2
        # the forward part on its own: its first segment counts as a minimum when the distance grows after it
        forward = as_good[TRACK_BACK_SAMPLES:] & _local_minima(d2[TRACK_BACK_SAMPLES:], cyclic=False)
        good = as_good & _local_minima(d2, cyclic=False)
        first = int(np.argmax(forward)) + TRACK_BACK_SAMPLES if forward.any() else int(np.argmax(good))
        return self._near(int(idx[first]), float(u[first]), float(d2[first]))

    def _search(self, q: FloatArray, motion_radps: FloatArray | None) -> Location | None:
        """Every part of the path within the tolerance; their velocities merged, or None if they disagree."""
        d2, u = self._segments(np.arange(self.n_samples), q)
        within = np.flatnonzero((d2 <= self.tolerance_rad**2) & _local_minima(d2, cyclic=True))
        if within.size == 0:
            return None
        candidates = [self._near(int(i), float(u[i]), float(d2[i])) for i in within]
        if motion_radps is not None:
            motion = np.asarray(motion_radps, dtype=float)
            if motion.shape == q.shape and np.isfinite(motion).all() and np.linalg.norm(motion) > MOTION_MIN_RADPS:
                candidates = [c for c in candidates if float(c.qd_radps @ motion) >= 0.0] or candidates
        velocities = np.array([c.qd_radps for c in candidates])
        up = velocities.max(axis=0) > VELOCITY_CONFLICT_RADPS
        down = velocities.min(axis=0) < -VELOCITY_CONFLICT_RADPS
        if (up & down).any():
            return None
        pick = np.argmax(np.abs(velocities), axis=0)
        merged = velocities[pick, np.arange(velocities.shape[1])]
        nearest = min(candidates, key=lambda c: c.d2)
        parts = len(candidates)
        return Location(nearest.at if parts == 1 else None, nearest.tau_s, merged, math.sqrt(nearest.d2), parts)

    def summary(self) -> str:
        """What the model holds, for the ``check`` command and the log."""
        peak = np.abs(self.qd_nominal_radps).max(axis=0)
        lines = [
            f"program model of robot {self.robot!r}, recorded {self.recorded_at} at override {self.scaling:.3f} "
            f"(velocities from {self.velocity_source})",
            f"  {self.n_samples} samples over one cycle of {self.duration_s:.3f} s program time "
            f"({self.duration_s / self.scaling:.3f} s as recorded)",
            f"  position noise {self.noise_rad:.2e} rad per joint; off the program beyond {self.tolerance_rad} rad",
            f"  {'joint':<24} {'min q':>9} {'max q':>9} {'peak |qd_nominal|':>18}",
        ]
        for j, name in enumerate(self.joint_names):
            lines.append(
                f"  {name:<24} {self.q_rad[:, j].min():>8.3f}r {self.q_rad[:, j].max():>8.3f}r {peak[j]:>14.3f} rad/s"
            )
        return "\n".join(lines)


def _local_minima(d2: FloatArray, cyclic: bool) -> npt.NDArray[np.bool_]:
    """Where ``d2`` is no larger than either neighbour (the ends compare with their one neighbour unless cyclic)."""
    if cyclic:
        return (d2 <= np.roll(d2, 1)) & (d2 <= np.roll(d2, -1))
    before = np.concatenate(([np.inf], d2[:-1]))
    after = np.concatenate((d2[1:], [np.inf]))
    return (d2 <= before) & (d2 <= after)


# -- recording ----------------------------------------------------------------------------------------------------


def _checked_arrays(
    samples: Sequence[ProgramSample], n_joints: int
) -> tuple[FloatArray, FloatArray, FloatArray | None, FloatArray]:
    """Times, positions, velocities (None if any sample lacks them) and scalings, refused if not usable."""
    if len(samples) < 10:
        raise ProgramModelError(
            f"the recording has {len(samples)} samples; allowed: one whole program cycle (hundreds)"
        )
    for k, s in enumerate(samples):
        if len(s.q_rad) != n_joints or (s.qd_radps is not None and len(s.qd_radps) != n_joints):
            raise ProgramModelError(f"sample {k} has {len(s.q_rad)} joint values; allowed: {n_joints}, one per joint")
        values = [s.t_s, s.scaling, *s.q_rad, *(s.qd_radps or ())]
        if not all(math.isfinite(v) for v in values):
            raise ProgramModelError(
                f"sample {k} (t = {s.t_s} s) holds a non-finite value; allowed: finite t, q, qd, scaling"
            )
        if not s.running:
            raise ProgramModelError(
                f"the program was not running at sample {k} (t = {s.t_s} s); allowed: a running cycle"
            )
    t = np.array([s.t_s for s in samples])
    q = np.array([s.q_rad for s in samples], dtype=float)
    qd = None if any(s.qd_radps is None for s in samples) else np.array([s.qd_radps for s in samples], dtype=float)
    scaling = np.array([s.scaling for s in samples])
    return t, q, qd, scaling


def _check_timing(t: FloatArray, scaling: FloatArray) -> None:
    dt = np.diff(t)
    if (dt <= 0.0).any():
        k = int(np.argmax(dt <= 0.0)) + 1
        raise ProgramModelError(f"sample {k} is not later than the one before it; allowed: increasing times")
    period = float(np.median(dt))
    if dt.max() > MAX_GAP_RATIO * period:
        k = int(np.argmax(dt))
        raise ProgramModelError(
            f"the recording has a gap of {dt[k] * 1e3:.1f} ms after t = {t[k] - t[0]:.3f} s (sample period "
            f"{period * 1e3:.1f} ms); allowed: at most {MAX_GAP_RATIO:g} sample periods: record again"
        )
    low = float(scaling.min())
    if low < MIN_RECORD_SCALING:
        raise ProgramModelError(
            f"the override was {low:.3f} during the recording; allowed: at least {MIN_RECORD_SCALING} (the programmed "
            "velocity is qd / override: a small override multiplies the read-back's noise and rounding)"
        )
    mean = float(scaling.mean())
    if float(scaling.max()) - low > MAX_SCALING_SPREAD * mean:
        raise ProgramModelError(
            f"the override varied from {low:.3f} to {float(scaling.max()):.3f} during the recording; allowed: a steady "
            f"override (within {MAX_SCALING_SPREAD:.0%})"
        )


def find_cycle_end(q_rad: FloatArray) -> int:
    """The sample at which the path has come back to its start: the recording's first whole cycle is ``[0, end)``.

    The stretch of path after the start (until it has travelled :data:`SIGNATURE_RAD`) is compared, sample by sample,
    with the stretch after each later sample; the cycle ends at the best match within :data:`CLOSURE_RAD` once the
    path has left the start. Comparing a stretch, not one point, keeps a program that passes its start again in
    the opposite direction (a retraced move) from closing there.

    Raises:
        ProgramModelError: the path never comes back to its start (less than one cycle, or not a cyclic program).
    """
    step = np.linalg.norm(np.diff(q_rad, axis=0), axis=1)
    travel = np.concatenate(([0.0], np.cumsum(step)))
    width = int(np.searchsorted(travel, SIGNATURE_RAD)) + 1
    far = np.linalg.norm(q_rad - q_rad[0], axis=1)
    left = np.flatnonzero(far > 10.0 * CLOSURE_RAD)
    n = q_rad.shape[0]
    if travel[-1] < 2.0 * SIGNATURE_RAD or left.size == 0 or n - width <= left[0]:
        raise ProgramModelError(
            f"the recording is not one whole program cycle: the robot travelled {travel[-1]:.3f} rad and never came "
            "back to where it started; allowed: at least one whole cycle at a steady override (record longer)"
        )
    starts = np.arange(int(left[0]), n - width + 1)
    window = np.arange(width)
    cost = np.linalg.norm(q_rad[starts[:, None] + window] - q_rad[window], axis=2).max(axis=1)
    ok = np.flatnonzero(cost <= CLOSURE_RAD)
    if ok.size == 0:
        raise ProgramModelError(
            f"the recording is not one whole program cycle: over {n} samples the path never returned to its start "
            f"within {CLOSURE_RAD} rad (closest {cost.min():.4f} rad); allowed: at least one whole cycle plus "
            f"{SIGNATURE_RAD} rad of path, at a steady override (record longer)"
        )
    first_run = ok[: int(np.argmax(np.diff(np.concatenate((ok, [ok[-1] + 2]))) > 1)) + 1]
    return int(starts[first_run[int(np.argmin(cost[first_run]))]])


def _local_fit(tau_s: FloatArray, values: FloatArray, duration_s: float, half: int) -> tuple[FloatArray, FloatArray]:
    """Value and derivative of a quadratic fitted over ``half`` samples either side of each sample (cyclic) [·, ·/s]."""
    n = tau_s.shape[0]
    offsets = np.arange(-half, half + 1)
    idx = np.arange(n)[:, None] + offsets
    wraps = np.floor_divide(idx, n)
    dt = tau_s[idx % n] + wraps * duration_s - tau_s[:, None]
    design = np.stack((np.ones_like(dt), dt, dt * dt), axis=2)  # (n, w, 3)
    weights = np.linalg.pinv(design)  # (n, 3, w)
    neighbours = values[idx % n]  # (n, w, m)
    coeffs = np.einsum("nkw,nwm->nkm", weights, neighbours)
    return coeffs[:, 0, :], coeffs[:, 1, :]


def record_program(
    samples: Sequence[ProgramSample],
    robot: str,
    joint_names: Sequence[str],
    recorded_at: str,
    tolerance_rad: float = DEFAULT_TOLERANCE_RAD,
) -> ProgramModel:
    """Build the program model from a recording of at least one whole cycle at a steady override.

    The programmed velocity is ``qd / δ`` per sample (δ the applied scaling); without ``qd`` (ABB RWS) the derivative
    of ``q`` over program time. Program time advances by ``δ · dt`` between samples. The first whole cycle is used
    (:func:`find_cycle_end`); path and velocities are smoothed by a local quadratic fit (cyclic).

    Raises:
        ProgramModelError: too few samples, wrong joint count, a non-finite value, a stopped program, times not
            increasing, a gap, an override below :data:`MIN_RECORD_SCALING` or not steady, or not one whole cycle.
    """
    if not 0.0 < tolerance_rad <= 0.2:
        raise ProgramModelError(f"tolerance_rad = {tolerance_rad}; allowed: (0, 0.2] rad")
    t, q, qd, scaling = _checked_arrays(samples, len(joint_names))
    end = find_cycle_end(q)
    t, q, scaling = t[: end + 1], q[: end + 1], scaling[: end + 1]
    _check_timing(t, scaling)
    tau_all = np.concatenate(([0.0], np.cumsum(np.diff(t) * 0.5 * (scaling[1:] + scaling[:-1]))))
    tau, duration_s = tau_all[:end], float(tau_all[end])
    q = q[:end]
    half = SMOOTHING_HALF_WINDOW
    q_smooth, dq_dtau = _local_fit(tau, q, duration_s, half)
    residual = q - q_smooth
    dof = 2 * half + 1
    noise_rad = float(np.sqrt(np.mean(residual**2) * dof / (dof - 3)))
    if qd is None:
        velocity, source = dq_dtau, "q_differences"
    else:
        velocity, source = _local_fit(tau, qd[:end] / scaling[:end, None], duration_s, half)[0], "qd"
    return ProgramModel(
        robot=robot,
        joint_names=tuple(joint_names),
        scaling=float(scaling.mean()),
        recorded_at=recorded_at,
        velocity_source=source,  # type: ignore[arg-type]
        tau_s=_read_only(tau),
        duration_s=duration_s,
        q_rad=_read_only(q_smooth),
        qd_nominal_radps=_read_only(velocity),
        noise_rad=max(noise_rad, 1e-7),
        tolerance_rad=tolerance_rad,
    )


def _read_only(array: FloatArray) -> FloatArray:
    out = np.array(array, dtype=float)
    out.setflags(write=False)
    return out


# -- the file -------------------------------------------------------------------------------------------------------

Finite = Annotated[float, Field(allow_inf_nan=False)]


class _ModelFile(BaseModel):
    """The model file (JSON): strict, versioned."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    schema_: Literal["hrc.program_model/1"] = Field(alias="schema")
    robot: Annotated[str, Field(min_length=1, max_length=64)]
    joint_names: Annotated[list[str], Field(min_length=1, max_length=32)]
    scaling: Annotated[float, Field(ge=MIN_RECORD_SCALING, le=1.0)]
    recorded_at: Annotated[str, Field(min_length=1, max_length=64)]
    velocity_source: VelocitySource
    duration_s: Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
    noise_rad: Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
    tolerance_rad: Annotated[float, Field(gt=0.0, le=0.2, allow_inf_nan=False)]
    tau_s: Annotated[list[Finite], Field(min_length=10)]
    q_rad: list[list[Finite]]
    qd_nominal_radps: list[list[Finite]]

    @model_validator(mode="after")
    def _shapes(self) -> _ModelFile:
        n, m = len(self.tau_s), len(self.joint_names)
        for name, rows in (("q_rad", self.q_rad), ("qd_nominal_radps", self.qd_nominal_radps)):
            if len(rows) != n or any(len(row) != m for row in rows):
                raise ValueError(f"{name} must have {n} rows of {m} values (one per sample, one per joint)")
        if any(b <= a for a, b in zip(self.tau_s, self.tau_s[1:], strict=False)) or self.tau_s[-1] >= self.duration_s:
            raise ValueError("tau_s must increase and stay below duration_s")
        return self


def save_model(model: ProgramModel, path: Path | str) -> None:
    """Write the model as JSON (:data:`SCHEMA`)."""
    doc = {
        "schema": SCHEMA,
        "robot": model.robot,
        "joint_names": list(model.joint_names),
        "scaling": model.scaling,
        "recorded_at": model.recorded_at,
        "velocity_source": model.velocity_source,
        "duration_s": model.duration_s,
        "noise_rad": model.noise_rad,
        "tolerance_rad": model.tolerance_rad,
        "tau_s": model.tau_s.tolist(),
        "q_rad": model.q_rad.tolist(),
        "qd_nominal_radps": model.qd_nominal_radps.tolist(),
    }
    Path(path).write_text(json.dumps(doc, separators=(",", ":")) + "\n")


def load_model(path: Path | str, robot: str | None = None, joint_names: Sequence[str] | None = None) -> ProgramModel:
    """Read a model file, refused if it is not one or was recorded for another robot or joint list.

    Raises:
        ProgramModelError: missing, not JSON, not a valid model, or another robot's.
    """
    path = Path(path)
    try:
        raw = json.loads(path.read_text())
        doc = _ModelFile.model_validate(raw)
    except OSError as exc:
        raise ProgramModelError(f"{path}: cannot read the program model ({exc.strerror})") from None
    except json.JSONDecodeError as exc:
        raise ProgramModelError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    except ValidationError as exc:
        first = exc.errors()[0]
        where = ".".join(str(p) for p in first["loc"])
        raise ProgramModelError(f"{path}: not a {SCHEMA} file: {where}: {first['msg']}") from None
    if robot is not None and doc.robot != robot:
        raise ProgramModelError(f"{path} was recorded for robot {doc.robot!r}; allowed: a model of robot {robot!r}")
    if joint_names is not None and list(joint_names) != doc.joint_names:
        raise ProgramModelError(
            f"{path} has joints {', '.join(doc.joint_names)}; allowed: {', '.join(joint_names)} (robot {robot!r})"
        )
    return ProgramModel(
        robot=doc.robot,
        joint_names=tuple(doc.joint_names),
        scaling=doc.scaling,
        recorded_at=doc.recorded_at,
        velocity_source=doc.velocity_source,
        tau_s=_read_only(np.array(doc.tau_s)),
        duration_s=doc.duration_s,
        q_rad=_read_only(np.array(doc.q_rad)),
        qd_nominal_radps=_read_only(np.array(doc.qd_nominal_radps)),
        noise_rad=doc.noise_rad,
        tolerance_rad=doc.tolerance_rad,
    )


# -- the command ----------------------------------------------------------------------------------------------------


def collect_readings(interface: VendorInterface, seconds: float, timeout_s: float = 1.0) -> list[ControllerReading]:
    """Read the controller's read-back for ``seconds`` (monotonic clock); the interface is connected and closed by
    the caller.

    Raises:
        VendorError: a read failed.
    """
    readings: list[ControllerReading] = []
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        readings.append(interface.read(timeout_s))
    return readings


def open_vendor_interface(config_path: str | None, robot: str) -> tuple[VendorInterface, tuple[str, ...]]:
    """The vendor interface the cell file gives ``robot``, not yet connected, and the robot's joint names.

    Raises:
        ProgramModelError: no such robot, or the cell gives it no vendor interface this installation has.
    """
    cell = load_cell_config(config_path)
    if robot not in cell.robots:
        raise ProgramModelError(f"robot {robot!r} is not in the cell; allowed: {', '.join(cell.robots)}")
    robot_config = cell.robots[robot]
    joints = tuple(robot_config.model.joints)
    vendor = VENDORS.get(robot_config.interface.kind)
    if vendor is None:
        raise ProgramModelError(
            f"the cell gives robot {robot!r} no vendor interface (interface = {robot_config.interface.kind!r}); "
            f"allowed: {' or '.join(sorted(VENDORS))}. The emulator's Zenoh face reports qd_nominal itself: no model "
            "needed"
        )
    return vendor.interface(robot_config.interface, len(joints), os.environ), joints


def record_command(config_path: str | None, robot: str, out: Path, seconds: float) -> ProgramModel:
    """Record ``seconds`` of the robot's read-back through its vendor interface, build and save the model."""
    interface, joints = open_vendor_interface(config_path, robot)
    interface.connect()
    try:
        readings = collect_readings(interface, seconds)
    finally:
        interface.close()
    today = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    model = record_program(samples_from_readings(readings), robot, joints, today)
    save_model(model, out)
    return model


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m controller_bridge.program_model",
        description="Record one program cycle of a closed controller (run it at a steady override of at least "
        f"{MIN_RECORD_SCALING}), and check a recorded program model.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    record = sub.add_parser("record", help="record the program through the robot's vendor interface")
    record.add_argument("--config", default=None, help="cell configuration (default configs/cell.toml)")
    record.add_argument("--robot", required=True, help="robot of the cell")
    record.add_argument("--out", required=True, type=Path, help="model file to write (JSON)")
    record.add_argument("--seconds", required=True, type=float, help="how long to record: more than one cycle [s]")
    check = sub.add_parser("check", help="load a model and print its summary")
    check.add_argument("file", type=Path)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        if args.command == "record":
            model = record_command(args.config, args.robot, args.out, args.seconds)
            print(f"wrote {args.out}")
        else:
            model = load_model(args.file)
    except (HrcError, VendorError) as exc:
        print(f"program_model: {exc}", file=sys.stderr)
        return 2
    print(model.summary())
    return 0


if __name__ == "__main__":
    sys.exit(main())
