"""The controller emulator as one step object: override payloads in, ``cycle(now)`` → joint state out.

    node = ControllerNode(robot, trajectory, config)
    node.on_override(payload, now)   # every payload, as it arrives (any thread); now: Clocks
    output = node.cycle(now)         # every config.cycle_s
    publish(output.joint_state); log(output.mode_change)

The node reads no clock and does no I/O: ``controller_emu/main.py`` passes the process's clocks
(:func:`hrc_runtime.clocks.read_clocks`) and publishes over Zenoh, ``hrc_tools/sim/cell.py`` passes simulated times
and sends over simulated links. Both clocks come with every call: the wall clock is compared only with
the gateway's stamps, the monotonic clock runs the watchdog and measures the step.

An override is checked when it arrives (:func:`hrc_devices.robots.time_scaling.check_override`), and the newest
accepted one is applied at the next cycle whose time is not before its arrival, so each is applied at most once
and never in a state stamped before it arrived (a cycle's thread held off the CPU between reading its clock and
taking the override would otherwise report, in a state stamped then, an override the gateway decided later: its
``echo_before_send`` check, seen in the soak); its arrival is when the watchdog starts counting. ``on_override``
may run on a subscriber's thread while ``cycle`` runs on the loop's: the little they share is guarded by a lock.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

from hrc_contract.config import ControllerConfig
from hrc_contract.messages import JointState, MessageError, Override, parse_message
from hrc_devices.robots.program import Trajectory
from hrc_devices.robots.time_scaling import (
    ControllerState,
    Mode,
    apply_override,
    check_override,
    joint_state,
    step,
)
from hrc_runtime.clocks import Clocks


@dataclass(frozen=True)
class ModeChange:
    """The controller changed mode in a cycle (for the log).

    Attributes:
        before: the mode before the cycle.
        after: the mode after it.
        silent_s: time since the last accepted override; None before any [s, monotonic].
    """

    before: Mode
    after: Mode
    silent_s: float | None


@dataclass(frozen=True)
class ControllerOutput:
    """What one cycle produced.

    Attributes:
        state: the controller's state after the cycle (the true state: the auditor checks it).
        joint_state: the contract's message to publish (state and ground-truth keys).
        mode_change: set when the mode changed in this cycle, else None.
        cycle_mono_ns: the cycle's time, the state's sample time [ns, the controller's monotonic clock].
    """

    state: ControllerState
    joint_state: JointState
    mode_change: ModeChange | None
    cycle_mono_ns: int = 0


@dataclass(frozen=True)
class ControllerStats:
    """The figures of the stats and progress lines.

    Attributes:
        mode: the current mode.
        delta_applied: the applied override, in [0, 1].
        tau_s: program time [s].
        cycles_completed: program cycles completed.
        override_seq: ``seq`` of the last accepted override; -1 before any.
        joint_states: joint state messages produced (cycles run).
        rejected: override payloads rejected, by reason (parse errors and
            :data:`~hrc_devices.robots.time_scaling.Rejection`), sorted by reason.
    """

    mode: Mode
    delta_applied: float
    tau_s: float
    cycles_completed: int
    override_seq: int
    joint_states: int
    rejected: Mapping[str, int]


@dataclass(frozen=True)
class _Accepted:
    message: Override
    accepted_mono_ns: int


PENDING_KEPT = 8
"""Accepted overrides kept until a cycle takes them (one a gateway period arrives per cycle; the oldest goes)."""


class ControllerNode:
    """One emulated controller: its program, its override watchdog and the joint state it reports.

    Args:
        robot: the robot's name (overrides for another robot are rejected; the joint state carries it).
        trajectory: the program.
        config: cycle, braking, acceleration and watchdog times.
        tau0_s: program time to start at, in [0, trajectory.duration_s) [s].

    Raises:
        ValueError: ``tau0_s`` outside the program.
    """

    def __init__(self, robot: str, trajectory: Trajectory, config: ControllerConfig, tau0_s: float = 0.0) -> None:
        if not 0.0 <= tau0_s < trajectory.duration_s:
            raise ValueError(f"tau0_s = {tau0_s} s; allowed: [0, {trajectory.duration_s}) s (the program's duration)")
        self.robot = robot
        self.trajectory = trajectory
        self.config = config
        self._state = ControllerState(tau_s=tau0_s)
        self._last_mono_ns: int | None = None
        self._seq = 0
        self._lock = threading.Lock()
        self._pending: deque[_Accepted] = deque(maxlen=PENDING_KEPT)
        """Accepted overrides not applied yet, in order of arrival (each newer than the one before)."""
        self._newest_stamp_ns = -1
        self._rejected: Counter[str] = Counter()

    @property
    def state(self) -> ControllerState:
        """The state after the last cycle."""
        return self._state

    def on_override(self, payload: bytes, now: Clocks) -> str | None:
        """Parse and check an override payload on arrival; keep it if it is the newest valid one.

        Args:
            payload: the payload as received.
            now: arrival. ``now.wall_ns`` is compared with the override's ``stamp_ns``; if it is accepted,
                the watchdog counts from ``now.mono_ns``.

        Returns:
            None if accepted, else the reason it was rejected (also counted in :meth:`stats`): a
            :attr:`MessageError.reason` or a :data:`~hrc_devices.robots.time_scaling.Rejection`.
        """
        try:
            message = parse_message(payload, Override)
        except MessageError as exc:
            self.count_rejected(exc.reason)
            return exc.reason
        with self._lock:
            reason = check_override(message, self.robot, self._newest_stamp_ns, now.wall_ns, self.config.watchdog_s)
            if reason is None:
                self._pending.append(_Accepted(message, now.mono_ns))
                self._newest_stamp_ns = message.stamp_ns
            else:
                self._rejected[reason] += 1
        return reason

    def count_rejected(self, reason: str) -> None:
        """Count a payload rejected outside :meth:`on_override` (e.g. ``internal_error`` in a callback)."""
        with self._lock:
            self._rejected[reason] += 1

    def cycle(self, now: Clocks) -> ControllerOutput:
        """Apply the newest accepted override, advance the program by one step and report the joint state.

        Args:
            now: ``now.mono_ns`` runs the watchdog and gives the step time (since the previous cycle;
                ``config.cycle_s`` for the first); ``now.wall_ns`` is the joint state's ``stamp_ns``.
        """
        now_mono_ns = now.mono_ns
        with self._lock:
            pending = None  # the newest that arrived by this cycle's time; later ones wait for the next cycle
            while self._pending and self._pending[0].accepted_mono_ns <= now_mono_ns:
                pending = self._pending.popleft()
        before = self._state
        state = before if pending is None else apply_override(before, pending.message, pending.accepted_mono_ns)
        dt_s = self.config.cycle_s if self._last_mono_ns is None else (now_mono_ns - self._last_mono_ns) / 1e9
        self._last_mono_ns = now_mono_ns
        state = step(state, self.trajectory, self.config, now_mono_ns, dt_s)
        message = joint_state(state, self.trajectory, self.robot, self._seq, now.wall_ns)
        self._seq += 1
        self._state = state
        change = None
        if state.mode != before.mode:
            accepted_ns = state.override_accepted_mono_ns
            silent_s = None if accepted_ns is None else (now_mono_ns - accepted_ns) / 1e9
            change = ModeChange(before=before.mode, after=state.mode, silent_s=silent_s)
        return ControllerOutput(state=state, joint_state=message, mode_change=change, cycle_mono_ns=now_mono_ns)

    def stats(self) -> ControllerStats:
        """The current figures (safe to call from any thread)."""
        state = self._state
        with self._lock:
            rejected = MappingProxyType(dict(sorted(self._rejected.items())))
        return ControllerStats(
            mode=state.mode,
            delta_applied=state.delta_applied,
            tau_s=state.tau_s,
            cycles_completed=state.cycles_completed,
            override_seq=state.override_seq,
            joint_states=self._seq,
            rejected=rejected,
        )
