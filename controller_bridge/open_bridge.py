"""The open controller bridge's pure core: the gateway's joint commands in, joint references out, the controller's
joint feedback in, the contract's joint state out (an *open* controller, e.g. ABB EGM: ``control = "open"``).

    bridge = OpenBridge(settings)
    bridge.on_command(payload, now)            # every hrc.joint_command/1 payload (any thread); now: Clocks
    state = bridge.on_feedback(feedback)       # every JointFeedback the controller sends; None: nothing to publish
    reference = bridge.reference(now)          # what to answer it with; None before the first command
    interface.send_reference(reference.q_rad, reference.qd_radps); bridge.on_sent(reference)

No I/O and no clock is read here: ``controller_bridge/main.py`` passes the process's clocks, tests pass theirs.

**Commands** are checked on arrival by the rules of every open controller
(:func:`hrc_devices.robots.time_scaling.joint_command_rejection`, the emulator's too): this robot, the model's joint
count, stamped after the newest accepted (order by ``stamp_ns``, never ``seq``), neither older than ``watchdog_s``
nor more than 5 ms ahead; payloads that do not parse (NaN and infinities included) are refused by reason. Every
refusal is counted; the newest accepted command wins.

**References.** The controller speaks first (EGM: an ``EgmRobot`` every 4 ms) and is answered once per feedback.
The gateway's command is the reference for the next cycle (q_{k+1}, q̇_{k+1}); the two 4 ms cycles run on different
clocks, so a controller cycle often sees no new command and the next one two. The answer is therefore, with ``t``
the time since the newest command arrived (the bridge's monotonic clock):

- ``follow`` (its first answer) and then ``extrapolate``, while ``t ≤ extrapolate_s`` and the command is within its
  ``watchdog_s``: q + q̇ · t and q̇ (the reference moved on at its own velocity, as the emulator's Zenoh-driven
  controller does between commands);
- ``hold`` otherwise: the last position reference sent for this command (its q if none was), with
  **no feed-forward** (q̇ = 0): the controller converges on it and stands (EGM's position mode). The bridge keeps
  answering: a real EGM that hears nothing keeps its last speed until its communication timeout (``\\CommTimeout``,
  1 s by default) and then only raises an error in RAPID, so **the bridge does not rely on the controller's own
  silence behaviour**: a silent gateway is answered with a standing reference within ``extrapolate_s``.

Before the first command nothing is sent: the controller stands where it is (the emulator in its protective stop;
a real EGM's ``EGMRunJoint`` waits for the PC until its ``\\CondTime``).

**Feedback → joint state**, as the emulator's Zenoh-driven open controller reports it
(``controller_emu.open_follower.follower_joint_state``): ``q`` the controller's feedback; ``qd`` = ``qd_nominal``
(an open controller applies no override: ``override`` 1.0); ``override_seq`` the echo (below); ``mode``
``running`` while the controller follows and the newest command is within its watchdog, else ``protective_stop``.

**Velocities** (EGM's feedback has none): q differenced over **the controller's own stamps** (EGM ``feedBack.time``,
µs), never over receive times: on a loaded host datagrams arrive bunched, and a difference over receive intervals
(0.5 ms for 4 ms of motion) came out far above the URDF limits elsewhere (the RWS bridge's poll). The difference
spans at least ``velocity_window_s`` of controller time (the newest earlier sample at least that old: 2 cycles, 8 ms,
so that a stamp read up to 0.5 ms late costs at most 6 % of the speed; its lag, half the window, is within the
gateway's stamp term). A controller without stamps (no ``feedBack.time``) falls back to the receive times with a
window of :data:`RECEIVE_TIME_WINDOW_CYCLES` cycles (counted as ``qd_sources.receive_time``). The stamp of the joint
state is the controller's time on the bridge's wall clock (:class:`controller_bridge.bridge.StampClock`: plus the
smallest offset of the last second), so q and qd agree over the stamps the gateway judges them by. A feedback whose
controller time does not advance is refused (``time_backwards``); after a gap longer than ``max_diff_gap_s`` the
history starts again (nothing is published until the window is spanned: no guessed velocity).

**The echo.** ``override_seq`` is the seq of the newest command whose reference the controller reports back (EGM
``planned`` equal, within :data:`ECHO_TOLERANCE_RAD`, to a reference sent for it) among those sent before the
feedback's stamp: the gateway's measured command path then includes the EGM link both ways. References repeat (a
standing robot is sent the same q every cycle), so a reference shown back can only confirm one sent before the
controller's cycle that shows it: never a later one (the gateway would see an echo stamped before its command was
sent, ``echo_before_send``, seen in the end-to-end test before this rule). Of equal references sent before that
cycle the newest is taken, which may still have been in flight (loopback: microseconds): the same reference, so
the same motion, but a command path up to one exchange short. A controller that reports no reference confirms the
seq of the reference sent before the previous feedback (one exchange: not a proof, counted in ``echo_unproven``).
"""

from __future__ import annotations

import math
import threading
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from controller_bridge.bridge import StampClock
from hrc_contract.messages import JointCommand, JointState, MessageError, parse_message
from hrc_contract.vocabulary import ControllerMode
from hrc_devices.controllers.vendor import JointFeedback
from hrc_devices.robots.time_scaling import joint_command_rejection
from hrc_runtime.clocks import Clocks

__all__ = ["OpenBridge", "OpenBridgeSettings", "OpenBridgeStats", "Reference", "feedback_problem"]

FloatArray = npt.NDArray[np.float64]
NS_PER_S = 1e9

ECHO_TOLERANCE_RAD = 1e-7
"""A reported reference within this of a sent one (every joint) shows it [rad] (degrees and back: ~1e-15)."""

SENT_KEPT = 64
"""References kept for the echo (0.26 s at 250 Hz: longer than any watchdog lets a command live unanswered)."""

WINDOW_SLACK_S = 1e-6
"""A sample this much short of the window still spans it [s] (EGM's stamps are whole microseconds; rounding)."""

RECEIVE_TIME_WINDOW_CYCLES = 4
"""Without the controller's stamps, q is differenced over at least this many controller cycles of receive time."""

How = Literal["follow", "extrapolate", "hold"]


@dataclass(frozen=True)
class OpenBridgeSettings:
    """What the core needs to know of the robot and its interface.

    Attributes:
        robot: the robot's name.
        n_joints: the model's joint count.
        watchdog_s: a command older than this is refused at arrival and not followed after [s].
        extrapolate_s: the reference moves on at its velocity for at most this long after its command arrived [s].
        cycle_s: the controller's cycle [s] (EGM: 4 ms).
        velocity_window_s: q is differenced over at least this much controller time [s].
        max_diff_gap_s: a longer gap between feedbacks restarts the history [s].

    Raises:
        ValueError: a time that is not positive and finite, or ``extrapolate_s`` not below ``watchdog_s``.
    """

    robot: str
    n_joints: int
    watchdog_s: float
    extrapolate_s: float
    cycle_s: float
    velocity_window_s: float
    max_diff_gap_s: float

    def __post_init__(self) -> None:
        for name in ("watchdog_s", "cycle_s", "velocity_window_s", "max_diff_gap_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} = {value}; allowed: finite > 0 [s]")
        if not (math.isfinite(self.extrapolate_s) and 0.0 <= self.extrapolate_s < self.watchdog_s):
            raise ValueError(f"extrapolate_s = {self.extrapolate_s}; allowed: 0 <= it < watchdog_s = {self.watchdog_s}")
        if self.n_joints < 1:
            raise ValueError(f"n_joints = {self.n_joints}; allowed: >= 1")
        if self.velocity_window_s >= self.max_diff_gap_s:
            raise ValueError(
                f"velocity_window_s = {self.velocity_window_s} s; allowed: < max_diff_gap_s = {self.max_diff_gap_s} s"
            )


class Reference(NamedTuple):
    """One answer to the controller.

    Attributes:
        q_rad: the position reference [rad].
        qd_radps: the feed-forward velocity [rad/s] (0 when holding).
        seq: the gateway command's ``seq`` it comes from.
        how: ``follow`` (first send), ``extrapolate`` or ``hold`` (module docstring).
    """

    q_rad: tuple[float, ...]
    qd_radps: tuple[float, ...]
    seq: int
    how: How


@dataclass(frozen=True)
class OpenBridgeStats:
    """The figures of the statistics and progress lines.

    Attributes:
        mode: the mode of the last joint state published (None before any).
        command_seq: ``seq`` of the newest accepted command; -1 before any.
        echo_seq: the ``override_seq`` reported (the newest command the controller showed back); -1 before any.
        echo_unproven: echoes taken without the controller's reference (it reported none).
        commands_accepted: joint commands accepted.
        feedbacks: valid feedbacks taken.
        published: joint states composed.
        references: references sent, by how (``follow``, ``extrapolate``, ``hold``).
        command_age_max_s: the oldest a command was when a ``follow`` or ``extrapolate`` reference left [s].
        qd_sources: joint states by the clock q was differenced over (``controller_time``, ``receive_time``).
        rejected: feedbacks and vendor errors refused, by reason.
        commands_rejected: joint command payloads refused, by reason.
        watchdog_expired: no command within ``watchdog_s`` (the bridge holds the last reference).
    """

    mode: ControllerMode | None
    command_seq: int
    echo_seq: int
    echo_unproven: int
    commands_accepted: int
    feedbacks: int
    published: int
    references: Mapping[str, int]
    command_age_max_s: float | None
    qd_sources: Mapping[str, int]
    rejected: Mapping[str, int]
    commands_rejected: Mapping[str, int]
    watchdog_expired: bool


class _Command(NamedTuple):
    q_rad: FloatArray
    qd_radps: FloatArray
    seq: int
    received_mono_ns: int
    expires_mono_ns: int


class _Sample(NamedTuple):
    t_s: float
    q_rad: FloatArray


def feedback_problem(feedback: JointFeedback, n_joints: int) -> str | None:
    """Why a feedback cannot be used (``wrong_joint_count``, ``non_finite``), or None."""
    vectors = [feedback.q_rad] + ([] if feedback.reference_rad is None else [feedback.reference_rad])
    if any(len(v) != n_joints for v in vectors):
        return "wrong_joint_count"
    times = [] if feedback.controller_time_s is None else [feedback.controller_time_s]
    if not all(isinstance(x, int | float) and math.isfinite(x) for v in vectors for x in v) or not all(
        math.isfinite(t) for t in times
    ):
        return "non_finite"
    return None


class OpenBridge:
    """One open robot's bridge core (see the module docstring). ``on_command`` may run on a subscriber's thread
    while the rest runs on the reader's: a lock guards what they share."""

    def __init__(self, settings: OpenBridgeSettings) -> None:
        self.settings = settings
        self._lock = threading.Lock()
        self._command: _Command | None = None
        self._newest_stamp_ns = -1
        self._accepted = 0
        self._commands_rejected: Counter[str] = Counter()
        self._rejected: Counter[str] = Counter()
        self._last_sent: Reference | None = None
        self._last_sent_for: int | None = None
        """The seq of the command last sent as ``follow`` (each command is followed once, then extrapolated)."""
        self._sent: deque[tuple[int, FloatArray, int]] = deque(maxlen=SENT_KEPT)
        """(seq, q_ref, sent wall clock [ns]) of the references sent, oldest first."""
        self._previous_sent_seq = -1
        self._echo_seq = -1
        self._echo_unproven = 0
        self._history: deque[_Sample] = deque()
        self._stamp_clock = StampClock()
        self._seq = 0
        self._feedbacks = 0
        self._references: Counter[str] = Counter()
        self._qd_sources: Counter[str] = Counter()
        self._age_max_s: float | None = None
        self._mode: ControllerMode | None = None
        self._expired = True

    # -- commands (any thread) ----------------------------------------------------------------------------------

    def on_command(self, payload: bytes, now: Clocks) -> str | None:
        """Parse and check a joint command payload on arrival; keep it if it is the newest valid one.

        Returns:
            None if accepted, else the reason (counted): a :attr:`MessageError.reason` or a
            :data:`~hrc_devices.robots.time_scaling.JointCommandRejection`.
        """
        try:
            message = parse_message(payload, JointCommand)
        except MessageError as exc:
            self.count_command_rejected(exc.reason)
            return exc.reason
        s = self.settings
        with self._lock:
            reason = joint_command_rejection(
                message, s.robot, s.n_joints, self._newest_stamp_ns, now.wall_ns, s.watchdog_s
            )
            if reason is not None:
                self._commands_rejected[reason] += 1
                return reason
            age_ns = max(now.wall_ns - message.stamp_ns, 0)
            self._command = _Command(
                q_rad=np.array(message.q, dtype=float),
                qd_radps=np.array(message.qd, dtype=float),
                seq=message.seq,
                received_mono_ns=now.mono_ns,
                expires_mono_ns=now.mono_ns + round(s.watchdog_s * NS_PER_S) - age_ns,
            )
            self._newest_stamp_ns = message.stamp_ns
            self._accepted += 1
        return None

    def count_command_rejected(self, reason: str) -> None:
        """Count a joint command refused outside :meth:`on_command` (e.g. ``internal_error`` in a callback)."""
        with self._lock:
            self._commands_rejected[reason] += 1

    def count_rejected(self, reason: str) -> None:
        """Count a failed read or send (a :class:`~hrc_devices.controllers.vendor.VendorError` reason)."""
        with self._lock:
            self._rejected[reason] += 1

    # -- references -----------------------------------------------------------------------------------------------

    def reference(self, now: Clocks) -> Reference | None:
        """The answer to the controller at ``now`` (module docstring); None before the first command."""
        with self._lock:
            command = self._command
            if command is None:
                return None
            s = self.settings
            since_s = max(now.mono_ns - command.received_mono_ns, 0) / NS_PER_S
            fresh = now.mono_ns <= command.expires_mono_ns
            self._expired = not fresh
            if fresh and since_s <= s.extrapolate_s:
                if self._last_sent_for != command.seq:
                    return Reference(
                        tuple(command.q_rad.tolist()), tuple(command.qd_radps.tolist()), command.seq, "follow"
                    )
                q = command.q_rad + command.qd_radps * since_s
                return Reference(tuple(q.tolist()), tuple(command.qd_radps.tolist()), command.seq, "extrapolate")
            last = self._last_sent
            sent_before = last is not None and last.seq == command.seq
            q_hold = np.asarray(last.q_rad, dtype=float) if last is not None and sent_before else command.q_rad
            return Reference(tuple(q_hold.tolist()), (0.0,) * s.n_joints, command.seq, "hold")

    def on_sent(self, reference: Reference, now: Clocks) -> None:
        """Record a reference the controller was sent (the echo looks for it; a hold is sent again as is)."""
        with self._lock:
            self._previous_sent_seq = -1 if self._last_sent is None else self._last_sent.seq
            self._last_sent = reference
            self._references[reference.how] += 1
            if reference.how == "follow":
                self._last_sent_for = reference.seq
            command = self._command
            if reference.how != "hold" and command is not None:
                age_s = (now.mono_ns - command.received_mono_ns) / NS_PER_S
                self._age_max_s = age_s if self._age_max_s is None else max(self._age_max_s, age_s)
            if not self._sent or self._sent[-1][0] != reference.seq or reference.how != "hold":
                self._sent.append((reference.seq, np.asarray(reference.q_rad, dtype=float), now.wall_ns))

    # -- feedback -------------------------------------------------------------------------------------------------

    def on_feedback(self, feedback: JointFeedback) -> JointState | None:
        """Compose the contract's joint state from one feedback; None for a refused one (counted) or while the
        velocity window is not spanned yet."""
        s = self.settings
        with self._lock:
            problem = feedback_problem(feedback, s.n_joints)
            controller_time_s = feedback.controller_time_s
            own_clock = controller_time_s is not None
            t_s = feedback.received_mono_ns / NS_PER_S if controller_time_s is None else controller_time_s
            if problem is None and self._history and t_s <= self._history[-1].t_s:
                problem = "time_backwards"
            if problem is not None:
                self._rejected[problem] += 1
                return None
            self._feedbacks += 1
            q = np.asarray(feedback.q_rad, dtype=float)
            if self._history and t_s - self._history[-1].t_s > s.max_diff_gap_s:
                self._history.clear()  # a gap: the controller may have moved any way meanwhile
            window_s = (s.velocity_window_s if own_clock else RECEIVE_TIME_WINDOW_CYCLES * s.cycle_s) - WINDOW_SLACK_S
            base = next((sample for sample in reversed(self._history) if t_s - sample.t_s >= window_s), None)
            self._history.append(_Sample(t_s, q))
            while len(self._history) > 1 and t_s - self._history[1].t_s >= window_s:
                self._history.popleft()  # keep the newest sample at least a window old, and the ones after it
            # every valid feedback teaches the stamp clock its offset, published or not
            stamp_ns = self._stamp_clock.stamp_ns(feedback.received_wall_ns, feedback.controller_time_s)
            self._confirm(feedback, stamp_ns)
            if base is None:
                return None  # nothing to difference over yet: no joint state rather than a guessed velocity
            qd = (q - base.q_rad) / (t_s - base.t_s)
            self._qd_sources["controller_time" if own_clock else "receive_time"] += 1
            command = self._command
            fresh = command is not None and feedback.received_mono_ns <= command.expires_mono_ns
            mode: ControllerMode = "running" if feedback.following and feedback.running and fresh else "protective_stop"
            state = JointState(
                robot=s.robot,
                seq=self._seq,
                stamp_ns=stamp_ns,
                q=q.tolist(),
                qd=qd.tolist(),
                qd_nominal=qd.tolist(),
                override=1.0,
                override_seq=self._echo_seq,
                mode=mode,
            )
            self._seq += 1
            self._mode = mode
            return state

    def _confirm(self, feedback: JointFeedback, stamp_ns: int) -> None:
        """(lock held) Advance the echo: the newest reference sent before the feedback's stamp that the controller
        shows back (module docstring)."""
        if feedback.reference_rad is None:
            if self._previous_sent_seq >= 0 and self._previous_sent_seq != self._echo_seq:
                self._echo_seq = self._previous_sent_seq
                self._echo_unproven += 1
            return
        shown = np.asarray(feedback.reference_rad, dtype=float)
        for i in range(len(self._sent) - 1, -1, -1):
            seq, q_sent, sent_wall_ns = self._sent[i]
            if sent_wall_ns < stamp_ns and np.all(np.abs(q_sent - shown) <= ECHO_TOLERANCE_RAD):
                self._echo_seq = seq
                for _ in range(i):
                    self._sent.popleft()  # sent before the one shown: the controller has moved past them
                return

    # -- figures --------------------------------------------------------------------------------------------------

    def stats(self) -> OpenBridgeStats:
        """The current figures (safe to call from any thread)."""
        with self._lock:
            return OpenBridgeStats(
                mode=self._mode,
                command_seq=-1 if self._command is None else self._command.seq,
                echo_seq=self._echo_seq,
                echo_unproven=self._echo_unproven,
                commands_accepted=self._accepted,
                feedbacks=self._feedbacks,
                published=self._seq,
                references=MappingProxyType(dict(sorted(self._references.items()))),
                command_age_max_s=self._age_max_s,
                qd_sources=MappingProxyType(dict(sorted(self._qd_sources.items()))),
                rejected=MappingProxyType(dict(sorted(self._rejected.items()))),
                commands_rejected=MappingProxyType(dict(sorted(self._commands_rejected.items()))),
                watchdog_expired=self._expired,
            )
