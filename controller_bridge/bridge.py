"""The controller bridge's pure core: overrides in, speed writes out, read-backs in, joint states out.

    bridge = Bridge(settings, locate=model.locate)     # locate: the recorded program model, or None
    bridge.on_override(payload, now)                   # every override payload (any thread); now: Clocks
    fraction = bridge.next_write(now)                  # at the heartbeat rate and on a new override
    if fraction is not None: bridge.on_written(interface.write_speed_fraction(fraction), now)
    state = bridge.on_reading(interface.read(timeout_s))   # every read-back; None = nothing to publish

No I/O and no clock is read here: ``controller_bridge/main.py`` passes the process's clocks, tests pass theirs.

**Writing δ.** The newest valid override is quantised as the vendor does (:func:`quantise`: never above δ; below
the vendor's floor the value is the vendor's stop, see :data:`SPEED_INPUTS`), then made *provable*
(:func:`distinct_value`) and written; the heartbeat writes again. A real controller keeps its speed input forever,
so the bridge runs the watchdog the contract gives the controller: with no valid override for ``watchdog_s`` it
writes 0 itself.

**Every write provable (the dither).** A read-back can only prove a *change*: a reading that shows the value
already in force says nothing about a write of that same value. So the value written for an override is c =
quantise(δ), or if c equals the value in force (the last read-back) or a value written and not yet read back, the
first of c − d, c − 2d, … that equals none of them (d: the vendor's ``dither_step``, UR 1e-4 of its continuous
slider, ABB one percent), as long as it stays ≥ the vendor's floor. The dither only ever goes *down*: the bridge
never writes above δ. No two writes awaiting their read-back share a value, and none equals the value in force, so
a reading that shows v proves that the controller applied the write of v.

At the floor (and at 0, a stop) there is no lower value to dither to, and the bridge falls back to the old rule: the
write of a value already in force is confirmed by the next reading showing it, which proves nothing about the link.
That is safe: the value in force is then the floor or 0, so the robot crawls or stands whatever the link's delay,
and the next raise is a change, measured over the whole path (the gateway's window keeps the largest latency).

**Stop-and-wait.** To keep the dither small, at most one write that is not a decrease awaits its read-back
(:meth:`Bridge.next_write`): a value *lower* than the last written is written at once (a safety decrease never
waits); any other new value only once every earlier write has been read back. While one is awaited, the heartbeat
writes the last written value again (it feeds the controller's watchdog; it is not a new write, and its read-back
confirms the first write of that value, the conservative time). A steady δ therefore alternates c and c − d, one
write per read-back: the mean reduction is about d / 2 (ABB: half a percent step, UR: 5e-5) beyond the quantisation.

**The override echo.** ``override_seq`` is the seq of the newest override a confirmed write carried (the newest
override accepted when the write was handed out), confirmed by a reading received after that write, and stamped at
or after it, that shows its value; writes awaiting their read-back written before the confirmed one are then
superseded (the controller applies writes in order, so their value can never show again). Never on write. The stamp
rule matters for a write that cannot be proven (at the floor, at 0): a reading taken before it and received after it
shows the same value, and its stamp would put the echo before the gateway sent the override (``echo_before_send``,
seen once in a full test run beside ``bench.cpu_hog``). The gateway's measured override path (gateway send → bridge
→ vendor link → controller → vendor link → bridge → gateway) therefore includes the vendor link's delay with a
steady δ too, and the read-back latency in the statistics covers every provable write.

**What is reported, and why (ramps).** Let s be the controller's read-back of the scaling it applies
(``speed_fraction × speed_scaling``; 0 while the program does not run), a the ratio the robot really runs at, p the
programmed velocity (at 100 %), so the robot's velocity is a · p. The read-back runs *ahead* of a through every ramp:
after a drop, the controller brakes while s already shows the new value (a > s); after a raise, it accelerates
while ABB's speed ratio (and any read-back of the input rather than of the applied scaling) already shows the new
value (a < s). What the gateway needs, in this order:

1. ``qd_nominal`` ≥ p per joint (magnitude, same sign) whenever the controller behaves: the gateway bounds δ with
   it, and a programmed velocity below the truth lets it command too high a δ;
2. ``override · qd_nominal ≈ qd`` (its consistency check), so ``override`` must be a *lower* bound of a;
3. ``|qd_nominal|`` ≤ the URDF's limits (its ``qd_above_limit`` check).

A lower bound of a. Let R be ``rise_time_s``, the longest time the controller takes to reach a raised speed input
(from 0 to 1; at least the emulator's ``accel_time_s``). A behaving controller moves a toward its input c: down at
any rate but never below c (it brakes *to* the new value), up reaching c within R. So at any time u,
``a(u) ≥ min c over [u − R, u]``: within R of the start of that window a has risen to at least the window's minimum,
and it never falls below a value the input does not go below. The bridge knows every value c took, because it is the
only writer: the read-backs (each holding from its reading until the next one), plus the writes not yet read back
(awaiting their read-back, or handed out and not yet reported written: a decrease acts before any read-back shows it;
on UR times the last ``speed_scaling``). Their minimum over the window is m (:class:`ReadbackWindow`), and

    a_lo = max(m, max_j |v_j| / limit_j),   qd_nominal = v / a_lo,   override = a_lo,

with v the controller's velocity (``target_qd``; ABB offers none: the difference of q, see below). Since
``|v_j| = a · |p_j| ≤ a · limit_j``, both terms are ≤ a, so a_lo ≤ a and ``|qd_nominal| = (a / a_lo) · |p| ≥ |p|``
(1), with the sign of v, which is p's; ``override · qd_nominal = v ≈ qd`` (2, exactly for ABB); and
``|qd_nominal_j| = |v_j| / a_lo ≤ limit_j`` (3). The price is conservatism: through a ramp ``qd_nominal`` exceeds p by
a / a_lo (up to the limits while braking to 0), for R after a drop below the window's values.

Times are the controller's own where the vendor gives one (RTDE's ``timestamp``, so the window does not depend on
when packages arrive; each package's s and ``target_qd`` come from the same controller cycle, so a package repeating
an older cycle still has s ≤ a), else the bridge's receive times (ABB). ABB's q is differenced over the poll
interval, so its v is the mean of a · p over [t_prev, t]: the window then starts R before the *previous* reading
(``t_prev − R``), which bounds a from below over the whole interval; the speed ratio is read before q in the same poll
(8 ms on the simulated link), and a write between the two is still handed out or awaited, so it is in m. The q
samples are not exactly the receive times apart: the controller serves q of its latest cycle, after a request whose
round trip varies, so the samples may be up to j = ``sample_jitter_s`` closer than the Δt between receipts (and v up
to Δt / (Δt − j) faster than Δq / Δt: in the simulated cell the poll waits for writes, and Δq / Δt swings ±20 %). The
bridge therefore uses ``v = Δq / (Δt − j)`` (an upper bound of the mean velocity) and reports ``qd = Δq / Δt`` with
``override = a_lo · (Δt − j) / Δt``, so ``override · qd_nominal = qd`` still. A reading that waited in the bridge
(a busy host between the answer's arrival and the clock read) shortens the next interval by more than j; q is then
differenced over an earlier reading (:func:`difference_base`, up to :data:`DIFF_BASES` back within
``max_diff_gap_s``), the newest over which its change is a velocity the joints can have. What remains is the lag of
a mean: an accelerating program's velocity at the last sample exceeds the interval's mean by up to |dp/dt| · Δt / 2
(half a poll, or half the longer interval over an earlier reading; a program model has none). A history
the bridge cannot vouch for counts as 0 (the controller may be accelerating from standstill): before the first
reading, after a gap longer than ``max_diff_gap_s`` and when the controller's clock goes back or leaps.

With R = 0 the window is the current reading alone (and the pending writes): allowed for UR only, whose
``speed_scaling × target_speed_fraction`` is the applied scaling while it rises (the emulator's is;
``docs/controllers.md`` says what to check on a real UR before relying on it). The default is the conservative 1 s.

What is lost: ``override`` ≤ a, so a behaving controller never shows an override above the commands, and the gateway's
``override_above_commanded`` check can fire through a bridge only when the read-back stays above every recent command
for a whole window R with no lower write awaiting its read-back (a read-back that confirmed a write, then went back
up), or the robot moves on some joint faster than the commanded fraction of its limit. A controller
that ignores the speed input is caught by the echo instead: a written value its read-back never shows is never
confirmed, ``override_seq`` stops advancing and the gateway's ``override_path_stale`` stops the robot. A controller
whose read-back shows the written value while it runs faster is caught by nothing here (nor was it before): that is
what a program model's measured ratio, or the controller's own safety functions, are for.

The bridge reports

- ``qd``: the measured joint velocity (``actual_qd``; for ABB the difference of q over the sample times), never
  derived from the override.
- ``qd_nominal`` and ``override``, from the first source that applies (counted per source in the statistics):
  1. ``program_model``: the recorded program's velocity at the located point (``ProgramModel.locate``): independent
     of the scaling, exact through ramps and at δ ≈ 0. ``override`` is then the ratio measured along it
     (``qd · p / p · p``), at most U, the braking envelope of s (``U = max(s, U_prev − Δt / t_b)``, t_b the
     smallest braking time the gateway plans with; on the same times as the window), so the gateway's
     ``override_above_commanded`` check keeps its meaning with a model; U where the program stands nearly still.
  2. ``target_qd`` (``qd`` for ABB): ``v / a_lo`` while a_lo ≥ ``min_scaling`` (the gateway's
     ``streams.qd_tolerance_ratio``, 0.02), ``override`` = a_lo.
  3. ``velocity_limits``: the URDF's joint velocity limits with the sign of the motion (+ for a joint at rest):
     never zero; ``override`` = a_lo. Used below ``min_scaling``, where ``|v_j − a_lo · limit_j| ≤ a_lo · limit_j <
     min_scaling · limit_j`` stays within the gateway's tolerance (a_lo ≥ |v_j| / limit_j).

**Hostile answers.** A reading with the wrong joint count, a non-finite value, a fraction outside [0, 1] or a
time not after the previous one is refused and counted by reason (as are the interface's own
:class:`~hrc_devices.controllers.vendor.VendorError` reasons, through :meth:`Bridge.count_rejected`); nothing is
published for it. With no valid reading for ``read_timeout_s`` the shell stops publishing (there is nothing to publish)
and reconnects: the gateway's staleness check then stops the robot.
"""

from __future__ import annotations

import math
import threading
from collections import Counter, deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from types import MappingProxyType
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hrc_contract.messages import JointState, MessageError, Override, parse_message
from hrc_contract.vocabulary import ControllerMode
from hrc_devices.controllers.descriptor import SpeedInput
from hrc_devices.controllers.vendor import ControllerReading
from hrc_runtime.clocks import Clocks

FloatArray = npt.NDArray[np.float64]
Locate = Callable[[FloatArray, FloatArray], "FloatArray | None"]
"""The recorded program model (``ProgramModel.locate``): joint positions [rad] and the measured velocity (its
direction tells retraced stretches apart) [rad/s] → the programmed velocity there [rad/s], or None."""

NS_PER_S = 1e9

MAX_FUTURE_STAMP_S = 0.005
"""An override stamped further ahead of this host's wall clock is refused [s] (the contract's controller rule)."""

READBACK_TOLERANCE = 1e-6
"""A read-back within this of a written value shows it (far below the smallest dither step, UR's 1e-4)."""

MAX_AWAITING_WRITES = 1024
"""Writes kept awaiting their read-back (each one lower than the one before: decreases written at once); the oldest
beyond this is forgotten, which is safe: a value is written again only as a raise, and a raise waits for the newest
write's read-back, after which no older write's value can show again."""

DIFF_BASES = 4
"""How many earlier readings q may be differenced against (:func:`difference_base`)."""
MODEL_STANDSTILL_RADPS = 0.01
"""Where the program model's velocity is below this on every joint, the ratio is not measured along it (U is
reported instead): ``|qd − U · p| ≤ U · |p|`` stays within the gateway's absolute tolerance (0.01 rad/s) [rad/s]."""


def quantise(delta: float, speed_input: SpeedInput) -> float:
    """The value to write for δ: rounded down to the step, 0 below the floor; never above δ.

    Args:
        delta: the override δ, in [0, 1] (outside: clipped; not finite: 0).
        speed_input: the vendor's input.
    """
    if not math.isfinite(delta):
        return 0.0
    delta = min(max(delta, 0.0), 1.0)
    value = delta
    if speed_input.step is not None:
        n = math.floor(delta / speed_input.step + 1e-9)  # 0.29 / 0.01 = 28.999…: one step, not two
        value = n * speed_input.step
        if value > delta:
            value = (n - 1) * speed_input.step
    return 0.0 if value < speed_input.floor - 1e-12 else value


def _same(a: float, b: float) -> bool:
    return abs(a - b) <= READBACK_TOLERANCE


def distinct_value(target: float, taken: Sequence[float], speed_input: SpeedInput) -> float | None:
    """The write that proves itself: the first of target, target − d, target − 2d, … (d: ``dither_step``) that
    equals no value in ``taken``, as long as it stays ≥ the floor; None when there is none (at the floor, at 0).

    Never above ``target``. On a stepped input the values stay on its grid (whole steps of ``step``).

    Args:
        target: the quantised δ (:func:`quantise`) [1].
        taken: the value in force and the values awaiting their read-back [1].
        speed_input: the vendor's input.
    """
    base, step = quantise(target, speed_input), speed_input.step
    for k in range(len(taken) + 1):  # each value taken rules out at most one candidate
        if step is None:
            value = base - k * speed_input.dither_step
        else:  # whole steps: exactly the values the vendor writes and reads back (ABB: p / 100)
            value = (round(base / step) - k * round(speed_input.dither_step / step)) * step
        if value < speed_input.floor - 1e-12 or value > target:
            return None
        if not any(_same(value, other) for other in taken):
            return value
    return None


@dataclass(frozen=True)
class BridgeSettings:
    """What the core needs to know of the robot, the cell and the interface.

    Attributes:
        robot: the robot's name (overrides for another are refused; the joint state carries it).
        speed_input: the vendor's speed input (:data:`SPEED_INPUTS`).
        velocity_limit_radps: the URDF's joint velocity limits, one per joint [rad/s].
        braking_time_s: t_b of the envelope (the program model's override): the smallest braking time the gateway
            plans with for a moving link [s].
        watchdog_s: no valid override for this long → write 0 [s].
        heartbeat_s: the speed input is written at least this often [s].
        min_scaling: below this applied scaling ``qd_nominal`` is not derived from the controller [1].
        max_diff_gap_s: q is not differentiated over a longer gap between readings; after one (or a leap of the
            controller's clock) the read-back history counts as 0 [s].
        rise_time_s: R, the longest time the controller takes to reach a raised speed input (the module docstring,
            "A lower bound of a"); 0: the read-back is the applied scaling while it rises (UR only) [s].
        sample_jitter_s: for a differenced q, how much the controller's sampling of q may differ from the bridge's
            receive times (the controller's cycle and the request's round-trip variation) [s].
    """

    robot: str
    speed_input: SpeedInput
    velocity_limit_radps: tuple[float, ...]
    braking_time_s: float
    watchdog_s: float
    heartbeat_s: float
    min_scaling: float = 0.02
    max_diff_gap_s: float = 0.1
    rise_time_s: float = 1.0
    sample_jitter_s: float = 0.0

    def __post_init__(self) -> None:
        if not self.velocity_limit_radps or not all(v > 0 and math.isfinite(v) for v in self.velocity_limit_radps):
            raise ValueError(f"velocity_limit_radps = {self.velocity_limit_radps}; allowed: > 0, finite, one a joint")
        for name in ("rise_time_s", "sample_jitter_s"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise ValueError(f"{name} = {value}; allowed: >= 0, finite")
        for name in ("braking_time_s", "watchdog_s", "heartbeat_s", "min_scaling", "max_diff_gap_s"):
            value = getattr(self, name)
            if not (value > 0 and math.isfinite(value)):
                raise ValueError(f"{name} = {value}; allowed: > 0, finite")


@dataclass(frozen=True)
class BridgeStats:
    """The figures of the stats document and the progress lines.

    Attributes:
        readings: valid readings so far.
        published: joint states composed.
        rejected: refused readings and interface errors, by reason (sorted).
        overrides_rejected: refused override payloads, by reason (sorted).
        writes: speed writes made.
        last_readback: the last valid read-back of the speed input (``speed_fraction``), None before any [1].
        last_applied: the last reported ``override`` [1].
        readback_latency_s: write → first reading showing its value, the last provable write measured [s].
        readback_latency_max_s: the largest since the last :meth:`Bridge.take_latency_max` [s].
        override_seq: the seq confirmed by the read-back, -1 before any.
        watchdog_expired: the bridge writes 0 because no valid override came for ``watchdog_s``.
        qd_nominal_sources: joint states per ``qd_nominal`` source.
        mode: the mode of the last joint state (None before any).
        awaiting: writes awaiting their read-back now.
        dithered: writes made below their quantised δ to differ from the value in force or an awaited one.
        unprovable: writes of a value already in force (at the floor or 0: no lower value to dither to).
    """

    readings: int
    published: int
    rejected: Mapping[str, int]
    overrides_rejected: Mapping[str, int]
    writes: int
    last_readback: float | None
    last_applied: float | None
    readback_latency_s: float | None
    readback_latency_max_s: float | None
    override_seq: int
    watchdog_expired: bool
    qd_nominal_sources: Mapping[str, int]
    mode: ControllerMode | None
    awaiting: int = 0
    dithered: int = 0
    unprovable: int = 0


class _Accepted(NamedTuple):
    seq: int
    value: float
    """Quantised δ."""
    accepted_mono_ns: int


class _Handed(NamedTuple):
    """What :meth:`Bridge.next_write` handed out."""

    value: float
    seq: int | None
    """The newest accepted override's seq (None: the watchdog's or the initial 0)."""
    accepted_mono_ns: int | None
    fresh: bool
    """A new write (True) or the heartbeat repeating the last written value (False)."""
    dithered: bool


class _Write(NamedTuple):
    """A write awaiting its read-back."""

    value: float
    seq: int | None
    written_mono_ns: int
    provable: bool
    """Its value differed from the value in force and every other awaited value when written."""
    written_wall_ns: int
    """When it was written on the bridge's wall clock [ns]: only a reading stamped at or after it confirms it."""


class NominalVelocity(NamedTuple):
    """``qd_nominal`` [rad/s], the reported ``override`` [1] and the source they came from."""

    qd_nominal_radps: FloatArray
    override: float
    source: str


class _Held(NamedTuple):
    """A read-back value, in force from its reading's time until the next reading's (``end_s``, inf until then)."""

    t_s: float
    value: float
    end_s: float


class ReadbackWindow:
    """The smallest read-back over a trailing window: m of the module docstring ("A lower bound of a").

    Each pushed value holds from its time until the next push; :meth:`minimum` is the smallest value in force at any
    instant of ``[start_s, now]``. A monotonic queue (values increasing from front to back): amortised O(1) per reading
    at 500 Hz over a window of seconds. ``start_s`` must not decrease from call to call (it follows the readings).
    """

    def __init__(self) -> None:
        self._held: deque[_Held] = deque()

    def reset(self, t_s: float) -> None:
        """Forget the history: from ``t_s`` the controller may be accelerating from standstill (a value of 0)."""
        self._held.clear()
        self._held.append(_Held(t_s, 0.0, math.inf))

    def push(self, t_s: float, value: float) -> None:
        """A reading at ``t_s`` [s] shows ``value`` [1] (times strictly increasing: :meth:`reset` otherwise)."""
        held = self._held
        if held:
            held[-1] = held[-1]._replace(end_s=t_s)
        while held and held[-1].value >= value:  # newer and no larger: the older one can never be the minimum
            held.pop()
        held.append(_Held(t_s, value, math.inf))

    def minimum(self, start_s: float) -> float:
        """The smallest value in force at any instant since ``start_s`` [s]; 0 with nothing pushed."""
        held = self._held
        while len(held) > 1 and held[0].end_s <= start_s:
            held.popleft()
        return held[0].value if held else 0.0


def braking_envelope(previous: float | None, dt_s: float, readback: float, braking_time_s: float) -> float:
    """U = max(s, U_prev − Δt / t_b): the highest ratio a controller braking within t_b may still apply [1]."""
    if previous is None:
        return readback
    return max(readback, previous - max(dt_s, 0.0) / braking_time_s)


def scaling_lower_bound(readback_min: float, velocity_radps: FloatArray, velocity_limit_radps: FloatArray) -> float:
    """a_lo = max(m, max_j |v_j| / limit_j), ≥ 0: a lower bound of the applied scaling (the module docstring).

    Not clipped at 1: ``v / a_lo`` stays within the limits even when v is above them (a differenced v bounded from
    above, or a controller beyond its limits, which the gateway's ``qd_above_limit`` refuses on ``qd``).

    Args:
        readback_min: m, the smallest read-back and pending write over the window [1].
        velocity_radps: v, the controller's velocity (``target_qd``, or the differenced q) [rad/s].
        velocity_limit_radps: the URDF's limits [rad/s].
    """
    moving = float(np.max(np.abs(velocity_radps) / velocity_limit_radps))
    return max(min(readback_min, 1.0), moving, 0.0)


def nominal_velocity(
    scaling_lo: float,
    envelope: float,
    qd_radps: FloatArray,
    target_qd_radps: FloatArray | None,
    model_qd_radps: FloatArray | None,
    velocity_limit_radps: FloatArray,
    min_scaling: float,
    sample_share: float = 1.0,
) -> NominalVelocity:
    """``qd_nominal`` and ``override`` from the first source that applies (the module docstring, 1–3).

    Args:
        scaling_lo: a_lo, the lower bound of the applied scaling (:func:`scaling_lower_bound`) [1].
        envelope: U, the braking envelope of the applied scaling (0 when the program does not run) [1].
        qd_radps: the measured joint velocity [rad/s].
        target_qd_radps: the controller's target velocity, None without [rad/s].
        model_qd_radps: the program model's velocity at the robot's position, None without [rad/s].
        velocity_limit_radps: the URDF's limits [rad/s].
        min_scaling: below this a_lo, source 2 is not used [1].
        sample_share: for a differenced q, the shortest share of the interval the samples may really be apart,
            (Δt − jitter) / Δt: v = qd / share bounds the velocity from above, and ``override`` = a_lo · share keeps
            ``override · qd_nominal = qd`` [1].
    """
    if model_qd_radps is not None:
        override = envelope
        speed2 = float(model_qd_radps @ model_qd_radps)
        if np.max(np.abs(model_qd_radps)) >= MODEL_STANDSTILL_RADPS and speed2 > 0.0:
            measured = float(qd_radps @ model_qd_radps) / speed2
            override = min(max(measured, 0.0), envelope, 1.0)
        return NominalVelocity(model_qd_radps, override, "program_model")
    if scaling_lo >= min_scaling:
        if target_qd_radps is not None:
            return NominalVelocity(target_qd_radps / scaling_lo, scaling_lo, "target_qd")
        return NominalVelocity(qd_radps / sample_share / scaling_lo, scaling_lo * sample_share, "qd")
    motion = target_qd_radps if target_qd_radps is not None and np.any(target_qd_radps) else qd_radps
    sign = np.where(motion < 0.0, -1.0, 1.0)
    share = 1.0 if target_qd_radps is not None else sample_share
    return NominalVelocity(sign * velocity_limit_radps, scaling_lo * share, "velocity_limits")


def difference_base(
    q_rad: FloatArray,
    received_mono_ns: int,
    earlier: Sequence[ControllerReading],
    velocity_limit_radps: FloatArray,
    max_gap_s: float,
) -> ControllerReading | None:
    """The reading to difference ``q_rad`` against: the newest of ``earlier`` (oldest first) over which the change
    of q is a velocity the joints can have (within their limits), else the newest within ``max_gap_s``; None if
    none is that recent.

    Receive times are not the instants the controller took q: a reading that waited in the bridge (the host busy
    between the answer's arrival and the clock read) makes the next interval look shorter than it was, and q's
    difference over it faster than any joint moves (seen at load 6: ``qd_above_limit`` at the gateway, a false
    stop). Over a longer interval the same error weighs less. A velocity beyond the limits over every base is
    reported as it is: the gateway refuses it."""
    newest: ControllerReading | None = None
    for base in reversed(earlier):
        dt_s = (received_mono_ns - base.received_mono_ns) / NS_PER_S
        if not 0.0 < dt_s <= max_gap_s:
            continue
        newest = base if newest is None else newest
        if np.all(np.abs(q_rad - np.asarray(base.q_rad, dtype=float)) <= velocity_limit_radps * dt_s):
            return base
    return newest


def reading_problem(reading: ControllerReading, n_joints: int, previous_mono_ns: int | None) -> str | None:
    """Why a reading cannot be used (``wrong_joint_count``, ``non_finite``, ``out_of_range``, ``time_backwards``)."""
    vectors = [reading.q_rad, reading.qd_radps, reading.target_qd_radps]
    if any(v is not None and len(v) != n_joints for v in vectors):
        return "wrong_joint_count"
    scalars = [reading.speed_fraction, 1.0 if reading.speed_scaling is None else reading.speed_scaling]
    times = [] if reading.controller_time_s is None else [reading.controller_time_s]
    values = [x for v in vectors if v is not None for x in v] + scalars + times
    if not all(isinstance(x, int | float) and math.isfinite(x) for x in values):
        return "non_finite"
    if not all(0.0 <= x <= 1.0 for x in scalars):
        return "out_of_range"
    if previous_mono_ns is not None and reading.received_mono_ns <= previous_mono_ns:
        return "time_backwards"
    if reading.received_wall_ns < 0:
        return "out_of_range"
    return None


STAMP_WINDOW_S = 1.0
"""The controller time over which :class:`StampClock` takes its smallest offset [s]: long enough that a late reading
(the bridge's thread descheduled, packages bunched) is never the smallest, short enough that a controller clock
slower than the bridge's by r drags the stamps at most r × this into the past (1 ms at r = 1e-3, an NTP slew is at
most 5e-4)."""


class StampClock:
    """The joint states' stamps [ns, the bridge's wall clock] from the controller's own time, where the vendor gives
    one (RTDE ``timestamp``).

    Each reading's offset is its arrival minus its controller time; the stamp is its controller time plus the
    smallest offset of the readings of the last :data:`STAMP_WINDOW_S` of controller time (a sliding minimum). A
    reading's arrival is never before it was taken, so the smallest offset is the one nearest the true one: a reading
    received late keeps the time it was taken (two readings taken 2 ms apart and received 0.5 ms apart stay 2 ms
    apart: the gateway's ``q_jump`` check; a late one does not look fresher than it is: its age counts in the
    gateway's delay), and no stamp is after its reading's arrival. Without the controller's time, or when it does
    not advance by (0, 1] s (a restarted controller, a gap): the arrival, and the window starts again.

    Clamping a late reading's stamp to its arrival instead (what this replaced) made it look younger by its lateness
    and the interval to the next reading shorter than the motion between them (``q_jump`` under load). Whatever the
    controller's clock does, a stamp is at most :data:`STAMP_WINDOW_S` before its arrival (the gateway then finds
    the joint state stale: the robot stops).
    """

    def __init__(self, window_s: float = STAMP_WINDOW_S) -> None:
        self._window_ns = round(window_s * NS_PER_S)
        self._offsets: deque[tuple[int, int]] = deque()  # (controller ns, offset ns), offsets increasing; newest last

    def stamp_ns(self, received_wall_ns: int, controller_time_s: float | None) -> int:
        """The stamp of a reading received at ``received_wall_ns`` [ns] taken at ``controller_time_s`` [s]."""
        if controller_time_s is None:
            self._offsets.clear()
            return received_wall_ns
        controller_ns = round(controller_time_s * NS_PER_S)
        if self._offsets and not 0 < controller_ns - self._offsets[-1][0] <= NS_PER_S:
            self._offsets.clear()
        offset_ns = received_wall_ns - controller_ns
        while self._offsets and self._offsets[-1][1] >= offset_ns:
            self._offsets.pop()
        self._offsets.append((controller_ns, offset_ns))
        # out of the window on either clock: a controller clock that nearly stops cannot keep an old offset, so a
        # stamp is never more than the window before its arrival
        while True:
            oldest_controller_ns, oldest_offset_ns = self._offsets[0]
            oldest_arrival_ns = oldest_controller_ns + oldest_offset_ns
            if oldest_controller_ns >= controller_ns - self._window_ns and (
                oldest_arrival_ns >= received_wall_ns - self._window_ns
            ):
                break
            self._offsets.popleft()  # never the newest: its times are this reading's
        return controller_ns + self._offsets[0][1]


def _time_s(reading: ControllerReading) -> float:
    """The reading's time: the controller's own where the vendor gives one, else the bridge's receive time [s]."""
    if reading.controller_time_s is not None:
        return reading.controller_time_s
    return reading.received_mono_ns / NS_PER_S


class Bridge:
    """One controller bridge: override watchdog, speed writes, read-back echo and the joint state it reports.

    Args:
        settings: the robot, the vendor's input and the limits.
        locate: the recorded program model's ``locate`` (q [rad] → programmed velocity [rad/s] or None); None
            without a model.
    """

    def __init__(self, settings: BridgeSettings, locate: Locate | None = None) -> None:
        self.settings = settings
        self._locate = locate
        self._limits = np.asarray(settings.velocity_limit_radps, dtype=float)
        self._n = len(settings.velocity_limit_radps)
        self._lock = threading.Lock()
        self._newest: _Accepted | None = None
        self._newest_stamp_ns = -1
        self._stamp_clock = StampClock()
        self._overrides_rejected: Counter[str] = Counter()
        # writes
        self._handed: _Handed | None = None
        self._last_write: tuple[float, int] | None = None  # (value, mono_ns)
        self._carried_mono_ns: int | None = None  # accepted_mono_ns of the override the last new write carried
        self._awaiting: deque[_Write] = deque(maxlen=MAX_AWAITING_WRITES)
        self._in_force: float | None = None  # the last read-back
        self._writes = 0
        self._dithered = 0
        self._unprovable = 0
        self._watchdog_expired = False
        # readings
        self._previous: ControllerReading | None = None
        self._bases: deque[ControllerReading] = deque(maxlen=DIFF_BASES)  # what q may be differenced against
        self._envelope: float | None = None
        self._window = ReadbackWindow()
        self._override_seq = -1
        self._seq = 0
        self._readings = 0
        self._rejected: Counter[str] = Counter()
        self._sources: Counter[str] = Counter()
        self._last_readback: float | None = None
        self._last_applied: float | None = None
        self._latency_s: float | None = None
        self._latency_max_s: float | None = None
        self._mode: ControllerMode | None = None

    # -- overrides (the subscriber's thread) ---------------------------------------------------------

    def on_override(self, payload: bytes, now: Clocks) -> str | None:
        """Parse and check an override on arrival; keep it if it is the newest valid one.

        Order is by ``stamp_ns`` (a restarted gateway starts again at seq 0, as the contract says); an override for
        another robot (``wrong_robot``), not newer than the newest accepted (``old_or_repeated``), older than the
        watchdog time (``stale``) or stamped ahead of ``now.wall_ns`` by more than :data:`MAX_FUTURE_STAMP_S`
        (``stamp_in_future``) is refused, as is one that does not parse (its :class:`MessageError` reason).

        Returns:
            None if accepted, else the reason (also counted).
        """
        try:
            message = parse_message(payload, Override)
        except MessageError as exc:
            self.count_override_rejected(exc.reason)
            return exc.reason
        age_s = (now.wall_ns - message.stamp_ns) / NS_PER_S
        with self._lock:
            reason: str | None = None
            if message.robot != self.settings.robot:
                reason = "wrong_robot"
            elif message.stamp_ns <= self._newest_stamp_ns:
                reason = "old_or_repeated"
            elif age_s > self.settings.watchdog_s:
                reason = "stale"
            elif -age_s > MAX_FUTURE_STAMP_S:
                reason = "stamp_in_future"
            if reason is not None:
                self._overrides_rejected[reason] += 1
                return reason
            value = quantise(message.delta, self.settings.speed_input)
            self._newest = _Accepted(message.seq, value, now.mono_ns)
            self._newest_stamp_ns = message.stamp_ns
        return None

    def count_override_rejected(self, reason: str) -> None:
        """Count an override refused outside :meth:`on_override` (e.g. ``internal_error`` in a callback)."""
        with self._lock:
            self._overrides_rejected[reason] += 1

    # -- writes (the writer's loop) --------------------------------------------------------------

    def next_write(self, now: Clocks) -> float | None:
        """What to write to the speed input now, or None (nothing new to write and the heartbeat is not due).

        The target is the newest accepted override's quantised δ, or 0 once no valid override came for
        ``watchdog_s``. Stop-and-wait (the module docstring): a target lower than the last written value is written
        at once; a new override otherwise once no write awaits its read-back; while one does, the heartbeat repeats
        the last written value (never above the target: the target is not lower than it). Every new value is made
        provable with :func:`distinct_value`.
        """
        with self._lock:
            newest = self._newest
            silent = newest is None or now.mono_ns - newest.accepted_mono_ns > self.settings.watchdog_s * NS_PER_S
            self._watchdog_expired = silent
            target, seq, accepted = (
                (0.0, None, None) if silent or newest is None else (newest.value, newest.seq, newest.accepted_mono_ns)
            )
            last = self._last_write
            heartbeat_due = last is None or now.mono_ns - last[1] >= self.settings.heartbeat_s * NS_PER_S
            if last is None or target < last[0]:
                handed = self._new_write(target, seq, accepted)  # a safety decrease never waits
            elif self._awaiting or accepted == self._carried_mono_ns:
                if not heartbeat_due:
                    return None
                handed = _Handed(last[0], seq, accepted, fresh=False, dithered=False)
            else:
                handed = self._new_write(target, seq, accepted)
            self._handed = handed
            return handed.value

    def on_written(self, written: float, now: Clocks) -> None:
        """The value :meth:`next_write` handed out was written at ``now`` (``written``: as the vendor quantised it)."""
        with self._lock:
            self._last_write = (written, now.mono_ns)
            self._writes += 1
            handed, self._handed = self._handed, None
            if handed is None or not handed.fresh:
                return
            self._carried_mono_ns = handed.accepted_mono_ns
            self._dithered += handed.dithered
            if any(_same(w.value, written) for w in self._awaiting):
                return  # not new to the controller: the earlier write of this value stands (the conservative time)
            if self._in_force is None:  # before the first reading nothing is proven: it confirms no override
                self._awaiting.append(_Write(written, None, now.mono_ns, False, now.wall_ns))
                return
            provable = not _same(self._in_force, written)
            self._unprovable += not provable
            self._awaiting.append(_Write(written, handed.seq, now.mono_ns, provable, now.wall_ns))

    # -- readings (the reader's loop) ------------------------------------------------------------

    def count_rejected(self, reason: str) -> None:
        """Count a failed read or write (a :class:`~hrc_devices.controllers.vendor.VendorError` reason)."""
        with self._lock:
            self._rejected[reason] += 1

    def on_reading(self, reading: ControllerReading) -> JointState | None:
        """Compose the contract's joint state from a read-back; None for a refused reading (counted), or while q
        must be differentiated and no earlier reading within ``max_diff_gap_s`` exists."""
        with self._lock:
            previous = self._previous
            problem = reading_problem(reading, self._n, None if previous is None else previous.received_mono_ns)
            if problem is not None:
                self._rejected[problem] += 1
                return None
            self._previous = reading
            self._readings += 1
            self._last_readback = reading.speed_fraction
            stamp_ns = self._stamp_clock.stamp_ns(reading.received_wall_ns, reading.controller_time_s)
            self._confirm(reading, stamp_ns)
            self._in_force = reading.speed_fraction
            dt_s = None if previous is None else (reading.received_mono_ns - previous.received_mono_ns) / NS_PER_S
            t_s, previous_t_s = _time_s(reading), None if previous is None else _time_s(previous)
            scaling = 1.0 if reading.speed_scaling is None else reading.speed_scaling
            applied = reading.speed_fraction * scaling if reading.running else 0.0
            gap_s = self.settings.max_diff_gap_s
            if previous_t_s is None or dt_s is None or not (0.0 < t_s - previous_t_s <= gap_s) or dt_s > gap_s:
                self._window.reset(t_s)  # a history the bridge cannot vouch for: the controller may be accelerating
                self._bases.clear()
            self._window.push(t_s, applied)
            self._envelope = envelope = braking_envelope(
                self._envelope,
                0.0 if previous_t_s is None else t_s - previous_t_s,
                applied,
                self.settings.braking_time_s,
            )
            if not reading.running:
                self._envelope = envelope = 0.0
            q = np.asarray(reading.q_rad, dtype=float)
            share = 1.0
            if reading.qd_radps is not None:
                qd = np.asarray(reading.qd_radps, dtype=float)
                start_s = t_s - self.settings.rise_time_s
            else:
                differenced = self._differenced(q, reading)
                if differenced is None:
                    return None  # nothing to differentiate yet: no joint state rather than a guessed velocity
                qd, start_s, share = differenced
            target = None if reading.target_qd_radps is None else np.asarray(reading.target_qd_radps, dtype=float)
            pending = [w.value for w in self._awaiting] + ([] if self._handed is None else [self._handed.value])
            readback_min = min([self._window.minimum(start_s)] + [scaling * w for w in pending])
            scaling_lo = scaling_lower_bound(readback_min, qd / share if target is None else target, self._limits)
            model = self._locate_model(q, qd)
            nominal = nominal_velocity(
                scaling_lo, envelope, qd, target, model, self._limits, self.settings.min_scaling, share
            )
            self._sources[nominal.source] += 1
            mode: ControllerMode = "running"
            if not reading.running or self._watchdog_expired:
                mode = "protective_stop"
            elif applied == 0.0 and nominal.override == 0.0:
                mode = "stopped"  # the controller holds its input at 0 and the robot stands
            state = JointState(
                robot=self.settings.robot,
                seq=self._seq,
                stamp_ns=stamp_ns,
                q=q.tolist(),
                qd=qd.tolist(),
                qd_nominal=nominal.qd_nominal_radps.tolist(),
                override=min(max(nominal.override, 0.0), 1.0),
                override_seq=self._override_seq,
                mode=mode,
            )
            self._seq += 1
            self._last_applied = state.override
            self._mode = mode
            return state

    def _differenced(self, q: FloatArray, reading: ControllerReading) -> tuple[FloatArray, float, float] | None:
        """(lock held) q differenced against :func:`difference_base`: the velocity [rad/s], the start of the
        read-back window it needs [s] and the share of the interval the samples may really be apart [1]; None
        without a base."""
        base = difference_base(q, reading.received_mono_ns, self._bases, self._limits, self.settings.max_diff_gap_s)
        self._bases.append(reading)
        if base is None:
            return None
        span_s = (reading.received_mono_ns - base.received_mono_ns) / NS_PER_S
        qd: FloatArray = (q - np.asarray(base.q_rad, dtype=float)) / span_s
        start_s = _time_s(base) - self.settings.rise_time_s  # qd: the mean since the base reading
        return qd, start_s, max(span_s - self.settings.sample_jitter_s, 0.5 * span_s) / span_s

    def silence_s(self, now_mono_ns: int) -> float | None:
        """Time since the last valid reading, None before any [s]."""
        with self._lock:
            previous = self._previous
        return None if previous is None else (now_mono_ns - previous.received_mono_ns) / NS_PER_S

    def take_latency_max(self) -> float | None:
        """The largest read-back latency since the previous call [s]; starts again empty."""
        with self._lock:
            value, self._latency_max_s = self._latency_max_s, None
        return value

    def stats(self) -> BridgeStats:
        """The current figures (any thread)."""
        with self._lock:
            return BridgeStats(
                readings=self._readings,
                published=self._seq,
                rejected=MappingProxyType(dict(sorted(self._rejected.items()))),
                overrides_rejected=MappingProxyType(dict(sorted(self._overrides_rejected.items()))),
                writes=self._writes,
                last_readback=self._last_readback,
                last_applied=self._last_applied,
                readback_latency_s=self._latency_s,
                readback_latency_max_s=self._latency_max_s,
                override_seq=self._override_seq,
                watchdog_expired=self._watchdog_expired,
                qd_nominal_sources=MappingProxyType(dict(sorted(self._sources.items()))),
                mode=self._mode,
                awaiting=len(self._awaiting),
                dithered=self._dithered,
                unprovable=self._unprovable,
            )

    # -- internals (lock held) -------------------------------------------------------------------

    def _new_write(self, target: float, seq: int | None, accepted_mono_ns: int | None) -> _Handed:
        """A new write for ``target``: the provable value (:func:`distinct_value`), else ``target`` itself."""
        taken = [w.value for w in self._awaiting]
        if self._in_force is not None:
            taken.append(self._in_force)
        value = distinct_value(target, taken, self.settings.speed_input)
        if value is None:
            return _Handed(target, seq, accepted_mono_ns, fresh=True, dithered=False)
        return _Handed(value, seq, accepted_mono_ns, fresh=True, dithered=value < target)

    def _confirm(self, reading: ControllerReading, stamp_ns: int) -> None:
        """Confirm the awaited write whose value the reading shows (written before it was received, and before its
        stamp ``stamp_ns``: a reading taken before the write, received after it, shows the value in force, which an
        unprovable write shares; its stamp would put the override's echo before the gateway sent it), and the
        override it carried; the writes awaited before it are superseded."""
        shown, t_ns = reading.speed_fraction, reading.received_mono_ns
        for index in range(len(self._awaiting) - 1, -1, -1):
            write = self._awaiting[index]
            if write.written_mono_ns <= t_ns and write.written_wall_ns <= stamp_ns and _same(write.value, shown):
                break
        else:
            return
        if write.seq is not None:
            self._override_seq = write.seq
        if write.provable:
            self._latency_s = (t_ns - write.written_mono_ns) / NS_PER_S
            self._latency_max_s = max(self._latency_s, self._latency_max_s or 0.0)
        for _ in range(index + 1):
            self._awaiting.popleft()

    def _locate_model(self, q_rad: FloatArray, qd_radps: FloatArray) -> FloatArray | None:
        """The program model's velocity at ``q_rad`` (counted ``model_miss`` when it cannot locate the robot)."""
        if self._locate is None:
            return None
        qd = self._locate(q_rad, qd_radps)
        if qd is None:
            self._sources["model_miss"] += 1
            return None
        qd = np.asarray(qd, dtype=float)
        if qd.shape != (self._n,) or not np.isfinite(qd).all():
            self._sources["model_invalid"] += 1
            return None
        return qd
