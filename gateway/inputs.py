"""The gateway's inputs at the door: parse, judge, keep the newest valid sample per topic, hold faults.

Zenoh callbacks call :meth:`InputStore.on_joint_state` and :meth:`InputStore.on_humans` with the time the
message arrived on both clocks; they only judge and store (``on_humans`` may wake the loop to decide at once).
The safety loop takes one consistent :class:`InputSnapshot` per cycle.

Every input is treated as hostile. A message on a configured topic is rejected, counted by reason and raises a
*topic fault* (δ = 0 for the robots it concerns) when it

- does not parse or does not fit the cell (``not_json``, ``invalid``, ``name_mismatch``, ``wrong_joint_count`` ...);
- is implausible: capsules outside the cell's volume or larger than a body part (``outside_world``,
  ``capsule_too_long``, ``radius_too_large``), joints beyond the URDF's limits (``q_out_of_limits``,
  ``qd_above_limit``);
- breaks the stream's order: stamped ahead of this host's clock by more than ``streams.max_future_stamp_s``
  (``stamp_in_future``), stamp or seq not after the newest accepted (``stamp_backwards``, ``seq_backwards``: a
  forged "newer" frame would otherwise hide every genuine one);
- contradicts itself or what the gateway commanded: joint velocities other than ``override · qd_nominal``, sign
  included (``qd_inconsistent``); joints that moved farther since the newest accepted state than their velocity
  limits allow in the time between the two stamps (``q_jump``); joints whose ``q`` moved other than their reported
  ``qd`` and ``override · qd_nominal`` allow between the stamps (``q_motion_inconsistent``:
  :mod:`gateway.joint_motion`); an applied override above every recent command
  and not braking toward it (``override_above_commanded``, on two joint states in a row, i.e. longer than one
  controller cycle); an ``override_seq`` first reported before that override was sent, or one never sent
  (``echo_before_send``, ``echo_never_sent``: :meth:`gateway.delay.OverridePath.on_state`).

A topic fault lasts until a valid message has arrived after it AND ``streams.fault_hold_s`` has passed since its
last occurrence, so that an attacker interleaving bad frames with good ones keeps the robot stopped instead of
flickering. A contradiction in motion (``qd_inconsistent`` on a joint claimed to move, ``q_motion_inconsistent``)
also names the joints it was seen on, and lasts until each of them has been seen *moving* consistently (an accepted
state whose ``qd`` exceeds the tolerance there, judged over at least
:data:`gateway.joint_motion.PROOF_SPAN_S`): a robot the fault has stopped is consistent whatever its
``qd_nominal`` says, so standing still for the hold proves nothing (a controller reversing ``qd_nominal`` was caught
each time it moved, cleared while it stood, and δ = 1 came back in bursts). An honest controller shows it while it
brakes. An exact repeat of a recently accepted message (same seq and stamp: a duplicated packet) is counted
as ``duplicate`` and is not a fault. A tracker sending faster than its configured ``rate_hz`` has the excess
dropped before it is parsed and counted as ``rate_exceeded`` (:class:`FrameBudget`: twice the rate, a burst of
:data:`FRAME_BURST`): not a fault, since the frames kept are fresh, but a flood of valid frames cannot hold the
interpreter away from the loop. Messages for robots or trackers the cell does not have are counted
(``unknown_robot``, ``unknown_tracker``) and concern no robot.

Ages run on the monotonic clock: a sample's age is its transit time measured at arrival (receive wall clock −
``stamp_ns``, across processes) plus the monotonic time since it arrived, so a wall-clock step on this host cannot
make an old sample look fresh. The snapshot reports a *clock step* fault when this host's wall clock moves
against its monotonic clock by more than ``streams.max_clock_step_s`` between two cycles.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from gateway import joint_motion
from gateway.delay import NS_PER_S, EchoProblem, OverridePath, OverridePathEstimate, WindowMax
from gateway.kernels import check_frame_numbers, frame_numbers
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.humans import HumanCapsules, humans_from_payload, implausible_detail
from hrc_contract.messages import JointState, MessageError, parse_message
from hrc_devices.robots.model import RobotModel
from hrc_runtime.clocks import Clocks

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
TopicKind = Literal["joint_state", "tracker"]

RECENT_MESSAGES = 64
"""(seq, stamp) pairs remembered per topic to recognise an exact repeat (a duplicated packet)."""

LIMIT_MARGIN_RAD = 0.01
"""A joint position this far beyond its URDF limit is still plausible (encoder and interpolation noise) [rad]."""

VELOCITY_LIMIT_FACTOR = 1.05
"""A joint velocity up to this multiple of its URDF limit is still plausible (interpolation overshoot)."""

JUMP_MARGIN_RAD = LIMIT_MARGIN_RAD
"""A joint may move this much farther between two states than its velocity limit allows (encoder noise, the
jitter between a controller's stamp and the instant its position was sampled) [rad]."""

_FAULT_KIND: Mapping[str, str] = {
    "stamp_in_future": "out_of_order",
    "stamp_backwards": "out_of_order",
    "seq_backwards": "out_of_order",
    "outside_world": "implausible",
    "capsule_too_long": "implausible",
    "radius_too_large": "implausible",
    "duplicate_human_id": "implausible",
    "too_many_parts": "implausible",
    "duplicate_part_name": "implausible",
    "person_too_large": "implausible",
    "q_out_of_limits": "implausible",
    "qd_above_limit": "implausible",
    "qd_inconsistent": "inconsistent",
    "q_jump": "inconsistent",
    "q_motion_inconsistent": "inconsistent",
    "echo_before_send": "inconsistent",
    "echo_never_sent": "inconsistent",
}
"""Rejection reason → fault kind; any other reason of a configured topic is ``invalid``."""


FRAME_RATE_FACTOR = 2.0
"""A tracker may send up to this many times its configured ``rate_hz`` before frames are dropped at the door."""

FRAME_BURST = 8
"""Frames a tracker may send at once (a burst after a network hiccup) before the rate applies."""


@dataclass
class FrameBudget:
    """A token bucket over the monotonic clock: ``burst`` frames at once, ``rate_hz`` frames per second after."""

    rate_hz: float
    burst: float
    tokens: float = 0.0
    last_mono_ns: int | None = None

    @classmethod
    def for_rate(cls, configured_rate_hz: float) -> FrameBudget:
        return cls(FRAME_RATE_FACTOR * configured_rate_hz, float(FRAME_BURST), float(FRAME_BURST))

    def admit(self, mono_ns: int) -> bool:
        """Spend a token for a frame arriving at ``mono_ns``; False (drop it) when there is none. A clock that runs
        backwards earns nothing."""
        if self.last_mono_ns is not None and mono_ns > self.last_mono_ns:
            earned = (mono_ns - self.last_mono_ns) * self.rate_hz / NS_PER_S
            self.tokens = min(self.burst, self.tokens + earned)
        if self.last_mono_ns is None or mono_ns > self.last_mono_ns:
            self.last_mono_ns = mono_ns
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


def fault_code(kind: TopicKind, reason: str) -> str:
    """The status's fault code for a rejection ``reason`` on a topic of ``kind``, e.g. ``tracker_implausible``."""
    if reason == "override_above_commanded":
        return "override_not_followed"
    return f"{kind}_{_FAULT_KIND.get(reason, 'invalid')}"


class TopicFault(NamedTuple):
    code: str
    reason: str


class JointStateProblem(NamedTuple):
    """Why a joint state is refused.

    Attributes:
        reason: the rejection reason (counted; its fault code by :func:`fault_code`).
        detail: what was found, for the fault's reason.
        to_prove: the joints a contradiction in motion was seen on (they must be seen moving consistently before
            the fault clears), None for any other problem.
        motion: a state refused only for how its ``q`` moved, as an entry of the motion chain: it stays on the
            chain (not as the robot's state), so the states after it are judged with the velocities it reported. A
            lie that persists is then judged over every state, never over one long gap between two accepted ones
            (whose slack for a turning velocity, A · Δt² / 4, grows until the lie passes).
    """

    reason: str
    detail: str
    to_prove: BoolArray | None = None
    motion: joint_motion.MotionEntry | None = None


class JointSample(NamedTuple):
    """A valid joint state, with when it arrived.

    Attributes:
        transit_ns: receive wall clock − ``stamp_ns`` at arrival, at least 0 [ns].
        received_mono_ns: the gateway's monotonic clock at arrival [ns].
    """

    stamp_ns: int
    seq: int
    q_rad: FloatArray
    qd_nominal_radps: FloatArray
    override: float
    override_seq: int
    mode: str
    transit_ns: int
    received_mono_ns: int


class HumanFrame(NamedTuple):
    """A valid tracker frame, with when it arrived (as :class:`JointSample`)."""

    stamp_ns: int
    seq: int
    capsules: HumanCapsules
    human_count: int
    transit_ns: int
    received_mono_ns: int
    human_starts: tuple[int, ...] | None = None
    """Where each person's capsules start (:attr:`hrc_contract.humans.HumansHeader.human_starts`), or None: the
    tracks compute them."""


def age_s(sample: JointSample | HumanFrame | None, now_mono_ns: int) -> float | None:
    """Age of a sample at ``now_mono_ns``: transit at arrival plus time since, None without a sample [s]."""
    if sample is None:
        return None
    return (sample.transit_ns + max(0, now_mono_ns - sample.received_mono_ns)) / NS_PER_S


class InputSnapshot(NamedTuple):
    """What the loop sees in one cycle.

    Attributes:
        joint: newest valid joint state per configured robot (None if none yet).
        humans: newest valid frame per configured tracker (None if none yet).
        faults: active topic faults (``robot/<r>`` or ``tracker/<t>`` → fault), held as the module says.
        override_path: per robot, what the override echo taught.
        clock_fault: a wall-clock step of this host within the hold time, else None.
    """

    joint: dict[str, JointSample | None]
    humans: dict[str, HumanFrame | None]
    faults: dict[str, TopicFault]
    override_path: dict[str, OverridePathEstimate]
    clock_fault: TopicFault | None = None


@dataclass
class _Stream:
    """One configured topic: order of the accepted messages and its fault."""

    kind: TopicKind
    seq: int = -1
    stamp_ns: int = -1
    recent: deque[tuple[int, int]] = field(default_factory=lambda: deque(maxlen=RECENT_MESSAGES))
    fault: TopicFault | None = None
    fault_mono_ns: int = 0
    valid_since_fault: bool = True
    unproven: BoolArray | None = None
    unproven_fault: TopicFault | None = None

    def order(self, seq: int, stamp_ns: int, received: Clocks, max_future_ns: int) -> str | None:
        """Why this message breaks the stream's order, ``duplicate`` for an exact repeat, or None."""
        if (seq, stamp_ns) in self.recent:
            return "duplicate"
        if stamp_ns > received.wall_ns + max_future_ns:
            return "stamp_in_future"
        if stamp_ns <= self.stamp_ns:
            return "stamp_backwards"
        if seq <= self.seq:
            return "seq_backwards"
        return None

    def accept(self, seq: int, stamp_ns: int) -> None:
        self.seq, self.stamp_ns = seq, stamp_ns
        self.recent.append((seq, stamp_ns))
        self.valid_since_fault = True

    def raise_fault(
        self, reason: str, detail: str, now_mono_ns: int, code: str | None = None, to_prove: BoolArray | None = None
    ) -> None:
        """Start (or restart) the fault: it lasts until a valid message came after it, the hold passed and every
        joint of ``to_prove`` (this and earlier contradictions in motion) has been seen moving consistently."""
        code = code or fault_code(self.kind, reason)
        self.fault = TopicFault(code, f"{reason}: {detail}" if detail else reason)
        self.fault_mono_ns = now_mono_ns
        self.valid_since_fault = False
        if to_prove is not None and to_prove.any():
            self.unproven = to_prove.copy() if self.unproven is None else self.unproven | to_prove
            self.unproven_fault = self.fault

    def prove(self, moving_consistently: BoolArray) -> None:
        """An accepted state showed these joints moving consistently: they need no more proof."""
        if self.unproven is not None:
            self.unproven = self.unproven & ~moving_consistently

    def active_fault(self, now_mono_ns: int, hold_ns: int) -> TopicFault | None:
        if self.fault is not None and self.valid_since_fault and now_mono_ns - self.fault_mono_ns >= hold_ns:
            if self.unproven is None or self.unproven_fault is None or not self.unproven.any():
                self.fault, self.unproven, self.unproven_fault = None, None, None
            else:  # only the proof is missing: show the contradiction it is for, whatever came after it
                joints = ", ".join(str(j) for j in np.flatnonzero(self.unproven))
                kept = f"; kept until joint(s) {joints} are seen moving consistently"
                self.fault = TopicFault(self.unproven_fault.code, self.unproven_fault.reason + kept)
        return self.fault


@dataclass
class _Robot:
    """What the store knows of one robot besides its newest state: limits, commands, override path."""

    n_joints: int
    q_min_rad: FloatArray
    q_max_rad: FloatArray
    qd_max_radps: FloatArray
    t_brake_min_s: float
    commanded: WindowMax
    path: OverridePath = field(default_factory=OverridePath)
    above_commanded: int = 0
    sample: JointSample | None = None
    motion: joint_motion.MotionHistory = field(default_factory=joint_motion.MotionHistory)


def _robot_entry(robot: RobotModel, command_window_ns: int) -> _Robot:
    moving = robot.t_brake_link_s[robot.t_brake_link_s > 0.0]
    qd_max_radps = np.asarray(robot.velocity_limit_radps, dtype=float) * VELOCITY_LIMIT_FACTOR
    return _Robot(
        n_joints=robot.n_joints,
        q_min_rad=np.asarray(robot.model.lowerPositionLimit, dtype=float) - LIMIT_MARGIN_RAD,
        q_max_rad=np.asarray(robot.model.upperPositionLimit, dtype=float) + LIMIT_MARGIN_RAD,
        qd_max_radps=qd_max_radps,
        t_brake_min_s=float(moving.min()) if moving.size else float(robot.braking_time_s.max()),
        commanded=WindowMax(command_window_ns),
    )


class InputStore:
    """Thread-safe store of the newest valid input per topic, with rejection counters and topic faults."""

    def __init__(
        self,
        config: CellConfig,
        robots: Mapping[str, RobotModel],
        on_tracker_change: Callable[[], None] | None = None,
    ) -> None:
        """
        Args:
            config: the cell (trackers, plausibility and stream limits).
            robots: the configured robots' models (joint counts and limits, braking times).
            on_tracker_change: called (on the callback's thread, after storing) when what the loop sees of a
                tracker changed, e.g. ``threading.Event.set`` to wake the loop; must not block.
        """
        check_frame_numbers()  # the door's compiled numbers, held to their reference and compiled before a frame
        streams = config.streams
        self._plausibility = {name: config.tracker_plausibility(name) for name in config.trackers}
        self._max_future_ns = round(streams.max_future_stamp_s * NS_PER_S)
        self._hold_ns = round(streams.fault_hold_s * NS_PER_S)
        self._max_clock_step_ns = round(streams.max_clock_step_s * NS_PER_S)
        self._qd_tolerance = (streams.qd_tolerance_radps, streams.qd_tolerance_ratio)
        self._override_tolerance = streams.override_tolerance
        self._on_tracker_change = on_tracker_change or _nothing
        self._lock = threading.Lock()
        # a command and the joint state that shows it applied are each at most max_data_age_s on their way
        window_ns = round(2 * config.safety.max_data_age_s * NS_PER_S)
        self._command_window_ns = window_ns
        self._robots = {name: _robot_entry(robot, window_ns) for name, robot in robots.items()}
        self._frames: dict[str, HumanFrame | None] = dict.fromkeys(sorted(config.trackers))
        self._frame_budgets = {name: FrameBudget.for_rate(t.rate_hz) for name, t in config.trackers.items()}
        self._streams = {f"robot/{name}": _Stream("joint_state") for name in robots}
        self._streams.update({f"tracker/{name}": _Stream("tracker") for name in config.trackers})
        self._rejected: Counter[tuple[str, str]] = Counter()
        self._received: Counter[str] = Counter()
        self._clock_offset_ns: int | None = None
        self._clock_fault = _Stream("tracker")  # only its fault and hold are used

    # -- callbacks (Zenoh threads) -------------------------------------------------------------

    def on_joint_state(self, key: str, payload: bytes, received: Clocks) -> None:
        """Judge and store a joint state that arrived at ``received``."""
        robot = keys.name_from_key(key, "robot") or "?"
        topic = f"robot/{robot}"
        entry = self._robots.get(robot)
        if entry is None:
            self._count(topic, "unknown_robot")
            return
        try:
            msg = parse_message(payload, JointState)
        except MessageError as exc:
            self._reject(topic, exc.reason, exc.detail, received)
            return
        sample = JointSample(
            msg.stamp_ns,
            msg.seq,
            np.asarray(msg.q, dtype=float),
            np.asarray(msg.qd_nominal, dtype=float),
            msg.override,
            msg.override_seq,
            msg.mode,
            max(0, received.wall_ns - msg.stamp_ns),
            received.mono_ns,
        )
        with self._lock:  # judged under the lock: the newest accepted state is part of the judgement
            # a restarted producer (seq not after the newest, the stream's order judges it) starts a new chain of
            # motion: an emulator restarts its program elsewhere; a restart never clears a missing proof
            order = self._streams[topic].order(msg.seq, msg.stamp_ns, received, self._max_future_ns)
            restarted = order == "seq_backwards"
            # a state the stream's order refuses (future, backwards, a duplicate) is not judged for its motion: it
            # never joins the chain, and a forged stamp cannot move the chain's time
            motion = order is None or restarted
            judged = _joint_state_problem(msg, robot, entry, self._qd_tolerance, restarted, motion)
            if isinstance(judged, JointStateProblem):
                self._reject_locked(topic, judged.reason, judged.detail, received, judged.to_prove)
                if judged.motion is not None:
                    entry.motion.append(judged.motion)
                return
            if not self._in_order(topic, msg.seq, msg.stamp_ns, received):
                return
            if joint_motion.judged_span_s(entry.motion, judged.stamp_ns) >= joint_motion.PROOF_SPAN_S:
                # judged consistent over a stretch long enough for a lie to show: its motion is proof
                self._streams[topic].prove(joint_motion.moving(judged.v_radps, 0.5 * _qd_room(msg, self._qd_tolerance)))
            if restarted:
                entry.motion.clear()
            entry.motion.append(judged)
            previous, entry.sample = entry.sample, sample
            echo = entry.path.on_state(msg.override_seq, msg.stamp_ns, self._max_future_ns)
            if echo is not None:
                self._echo_fault(topic, echo, msg.override_seq, received)
            self._check_override_followed(topic, entry, previous, sample, received)

    def on_humans(self, key: str, payload: bytes, received: Clocks) -> None:
        """Judge and store a tracker frame; call ``on_tracker_change`` when what the loop sees of a configured
        tracker changed (a new frame, or a fault), not for an unknown tracker, a duplicate or a no-op."""
        tracker = keys.name_from_key(key, "tracker") or "?"
        topic = f"tracker/{tracker}"
        if tracker not in self._frames:
            self._count(topic, "unknown_tracker")
            return
        with self._lock:
            admitted = self._frame_budgets[tracker].admit(received.mono_ns)
        if not admitted:
            self._count(topic, "rate_exceeded")  # dropped before parsing; the frames kept stay fresh: no fault
            return
        try:
            header, capsules = humans_from_payload(payload)
        except MessageError as exc:
            self._reject(topic, exc.reason, exc.detail, received)
            self._on_tracker_change()
            return
        mismatch = header.tracker != tracker
        problem = (
            None
            if mismatch
            else implausible_detail(capsules, self._plausibility[tracker], frame_numbers, header.human_starts)
        )
        if mismatch or problem is not None:
            reason = "name_mismatch" if problem is None else problem[0]
            detail = f"tracker {header.tracker!r}" if problem is None else problem[1]
            self._reject(topic, reason, detail, received)
            self._on_tracker_change()
            return
        transit_ns = max(0, received.wall_ns - header.stamp_ns)
        frame = HumanFrame(
            header.stamp_ns,
            header.seq,
            capsules,
            header.human_count,
            transit_ns,
            received.mono_ns,
            header.human_starts,
        )
        with self._lock:
            if not self._in_order(topic, header.seq, header.stamp_ns, received):
                changed = self._streams[topic].fault is not None
            else:
                self._frames[tracker] = frame
                changed = True
        if changed:
            self._on_tracker_change()

    def count_rejection(self, topic: str, reason: str, received: Clocks) -> None:
        """Count a rejection found outside the store (e.g. an exception in a callback) and fault the topic."""
        self._reject(topic, reason, "", received)

    # -- loop side --------------------------------------------------------------------------

    def on_override_sent(self, robot: str, seq: int, delta: float, sent: Clocks) -> None:
        """Record an override the loop sent (its echo teaches the path; its δ bounds the applied override)."""
        entry = self._robots[robot]
        with self._lock:
            entry.path.on_sent(seq, sent.wall_ns, sent.mono_ns)
            entry.commanded.push(sent.mono_ns, delta)

    def snapshot(self, now: Clocks) -> InputSnapshot:
        """The newest samples, the active faults and the override paths at ``now``.

        Built from what the callbacks left ready: a stream without a fault is skipped without a call, and each
        override path's estimate is renewed by its joint states (:attr:`gateway.delay.OverridePath.estimate`).
        """
        with self._lock:
            self._watch_clock(now)
            faults = {}
            for topic, stream in self._streams.items():
                if stream.fault is not None:  # only a stream with a fault can have an active one
                    fault = stream.active_fault(now.mono_ns, self._hold_ns)
                    if fault is not None:
                        faults[topic] = fault
            robots = self._robots.items()
            return InputSnapshot(
                {name: r.sample for name, r in robots},
                dict(self._frames),
                faults,
                {name: r.path.estimate for name, r in robots},
                self._clock_fault.active_fault(now.mono_ns, self._hold_ns),
            )

    def counters(self) -> tuple[dict[str, dict[str, int]], dict[str, int]]:
        """Rejections per topic and reason, and valid messages per topic."""
        with self._lock:
            rejected: dict[str, dict[str, int]] = {}
            for (topic, reason), count in self._rejected.items():
                rejected.setdefault(topic, {})[reason] = count
            return rejected, dict(self._received)

    # -- internals (the lock is held where noted) -----------------------------------------------

    def _count(self, topic: str, reason: str) -> None:
        with self._lock:
            self._rejected[(topic, reason)] += 1

    def _reject(self, topic: str, reason: str, detail: str, received: Clocks) -> None:
        with self._lock:
            self._reject_locked(topic, reason, detail, received)

    def _reject_locked(
        self, topic: str, reason: str, detail: str, received: Clocks, to_prove: BoolArray | None = None
    ) -> None:
        """(lock held) Count a rejection and fault its topic, if configured (``to_prove``: see
        :meth:`_Stream.raise_fault`)."""
        self._rejected[(topic, reason)] += 1
        stream = self._streams.get(topic)
        if stream is not None:
            stream.raise_fault(reason, detail[:200], received.mono_ns, to_prove=to_prove)

    def _in_order(self, topic: str, seq: int, stamp_ns: int, received: Clocks) -> bool:
        """(lock held) Whether to store this valid message; counts it, or its rejection and fault."""
        stream = self._streams[topic]
        problem = stream.order(seq, stamp_ns, received, self._max_future_ns)
        if problem == "duplicate":
            self._rejected[(topic, problem)] += 1
            return False
        if problem is not None:
            self._rejected[(topic, problem)] += 1
            newest = f"seq {seq} stamp_ns {stamp_ns} after seq {stream.seq} stamp_ns {stream.stamp_ns}"
            stream.raise_fault(problem, newest, received.mono_ns)
            if problem != "seq_backwards":  # a newer stamp with an older seq (a restart) is kept, still a fault
                return False
            stream.accept(seq, stamp_ns)
            stream.valid_since_fault = False
        else:
            stream.accept(seq, stamp_ns)
        self._received[topic] += 1
        return True

    def _check_override_followed(
        self, topic: str, entry: _Robot, previous: JointSample | None, sample: JointSample, received: Clocks
    ) -> None:
        """(lock held) Fault a controller whose applied override stays above every recent command without
        braking toward it at the rate the gateway plans with (from 1 to 0 within the smallest braking time)."""
        if previous is None or sample.transit_ns > self._command_window_ns // 2:
            return  # a state this late is stale anyway (its own fault); it may show commands beyond the window
        commanded = entry.commanded.max() or 0.0
        braked = previous.override - (sample.stamp_ns - previous.stamp_ns) / NS_PER_S / entry.t_brake_min_s
        if sample.override <= max(commanded, braked) + self._override_tolerance:
            entry.above_commanded = 0
            return
        entry.above_commanded += 1
        if entry.above_commanded >= 2:
            self._rejected[(topic, "override_above_commanded")] += 1
            detail = f"applied {sample.override:.3f}, commanded at most {commanded:.3f} within the path window"
            self._streams[topic].raise_fault("override_above_commanded", detail, received.mono_ns)

    def _echo_fault(self, topic: str, problem: EchoProblem, override_seq: int, received: Clocks) -> None:
        """(lock held) Fault a robot whose stored state echoes an override seq it cannot have applied."""
        self._rejected[(topic, problem)] += 1
        if problem == "echo_before_send":
            detail = f"override_seq {override_seq} first reported in a state stamped before it was sent"
        else:
            detail = f"override_seq {override_seq} was never sent by this gateway"
        self._streams[topic].raise_fault(problem, detail, received.mono_ns)

    def _watch_clock(self, now: Clocks) -> None:
        """(lock held) Raise a clock-step fault when the wall clock moved against the monotonic one."""
        offset_ns = now.wall_ns - now.mono_ns
        if self._clock_offset_ns is not None:
            step_ns = offset_ns - self._clock_offset_ns
            if abs(step_ns) > self._max_clock_step_ns:
                detail = f"this host's wall clock stepped by {step_ns / NS_PER_S:+.3f} s"
                self._clock_fault.raise_fault("clock_step", detail, now.mono_ns, code="clock_step")
                self._clock_fault.valid_since_fault = True  # clears by time alone
        self._clock_offset_ns = offset_ns


def _qd_room(msg: JointState, qd_tolerance: tuple[float, float]) -> FloatArray:
    """How far ``qd`` may be from ``override · qd_nominal``, per joint: absolute + ratio · |qd_nominal| [rad/s]."""
    absolute, ratio = qd_tolerance
    room_radps: FloatArray = absolute + ratio * np.abs(np.asarray(msg.qd_nominal, dtype=float))
    return room_radps


def _joint_state_problem(
    msg: JointState,
    robot: str,
    entry: _Robot,
    qd_tolerance: tuple[float, float],
    restarted: bool = False,
    motion: bool = True,
) -> JointStateProblem | joint_motion.MotionEntry:
    """(lock held) Why a parsed joint state cannot be this robot's, or its entry on the motion chain (the first of
    a new chain when ``restarted``; its motion not judged unless ``motion``).

    Against the robot (names, joint count, URDF limits), against itself (``qd = override · qd_nominal`` per
    joint, sign included) and against the accepted states before it (:func:`_jump`,
    :func:`gateway.joint_motion.contradiction`).
    """
    if msg.robot != robot:
        return JointStateProblem("name_mismatch", f"robot {msg.robot!r} on the key of {robot!r}")
    if len(msg.q) != entry.n_joints:
        return JointStateProblem("wrong_joint_count", f"{len(msg.q)} joints, the robot has {entry.n_joints}")
    q = np.asarray(msg.q, dtype=float)
    if not ((q >= entry.q_min_rad) & (q <= entry.q_max_rad)).all():
        return JointStateProblem("q_out_of_limits", "a joint position beyond its URDF limit")
    qd = np.asarray(msg.qd, dtype=float)
    qd_nominal = np.asarray(msg.qd_nominal, dtype=float)
    if (np.abs(qd) > entry.qd_max_radps).any() or (np.abs(qd_nominal) > entry.qd_max_radps).any():
        return JointStateProblem("qd_above_limit", "a joint velocity above its URDF limit")
    room_radps = _qd_room(msg, qd_tolerance)
    claimed_radps = msg.override * qd_nominal
    # sign included: joints moving against qd_nominal move where the gateway does not look
    off = np.abs(qd - claimed_radps) > room_radps
    if off.any():
        j = int(np.argmax(off))
        return JointStateProblem(
            "qd_inconsistent",
            f"qd beyond override {msg.override:.3f} × qd_nominal ± tolerance at joint {j}: qd {qd[j]:+.3f} rad/s, "
            f"qd_nominal {qd_nominal[j]:+.3f} rad/s",
            # on a joint claimed to move fast enough for a reversal to show; a standing joint's glitch needs no proof
            off & joint_motion.moving(claimed_radps, 0.5 * room_radps),
        )
    jump = _jump(entry.sample, msg, entry.qd_max_radps)
    if jump is not None:
        return JointStateProblem("q_jump", jump)
    newest = entry.motion[-1] if entry.motion else None
    if newest is not None and (restarted or msg.stamp_ns <= newest.stamp_ns):
        newest = None  # a restart, or not after the newest state: the stream's order judges it
    state = joint_motion.extend(
        newest,
        msg.stamp_ns,
        q,
        qd,
        claimed_radps,
        room_radps,
        entry.qd_max_radps / joint_motion.ACCEL_TIME_MIN_S,
    )
    if newest is not None and motion:
        found = joint_motion.contradiction(entry.motion, state)
        if found is not None:
            return JointStateProblem("q_motion_inconsistent", found.detail, found.joints, state)
    return state


def _jump(previous: JointSample | None, msg: JointState, qd_max_radps: FloatArray) -> str | None:
    """What joint moved farther since ``previous`` than its velocity limit allows, or None.

    |q − q_prev| ≤ qd_max · (stamp − stamp_prev) + :data:`JUMP_MARGIN_RAD`, per joint, on the controller's stamps:
    the allowed motion grows with the gap, so a state after a pause (or a restarted controller) passes. Without a
    previous state, or with a stamp not after it (the stream's order decides those), there is nothing to judge.
    """
    if previous is None or msg.stamp_ns <= previous.stamp_ns:
        return None
    dt_s = (msg.stamp_ns - previous.stamp_ns) / NS_PER_S
    moved_rad = np.abs(np.asarray(msg.q) - previous.q_rad)
    beyond = moved_rad > qd_max_radps * dt_s + JUMP_MARGIN_RAD
    if not beyond.any():
        return None
    j = int(np.argmax(beyond))
    return (
        f"joint {j} moved {moved_rad[j]:.3f} rad in {dt_s * 1e3:.1f} ms, at most "
        f"{qd_max_radps[j] * dt_s + JUMP_MARGIN_RAD:.3f} rad at its velocity limit"
    )


def _nothing() -> None:
    """The default ``on_tracker_change``."""
