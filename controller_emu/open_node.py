"""The open controller emulator as one step object: joint command payloads in, ``cycle(now)`` → joint state out.

    node = OpenControllerNode(robot, limits, q0_rad, config)
    node.on_command(payload, now)    # every payload, as it arrives (any thread); now: Clocks
    output = node.cycle(now)         # every config.cycle_s
    publish(output.joint_state); log(output.mode_change)

The open counterpart of :class:`controller_emu.node.ControllerNode` (the pure core is
:mod:`controller_emu.open_follower`), with the same timing rules: a command is checked when it arrives, the newest
accepted one is applied at the next cycle whose time is not before its arrival (each at most once, never in a state
stamped before it arrived), and its arrival is where its watchdog counts from. ``on_command`` may run on a
subscriber's thread while ``cycle`` runs on the loop's: the little they share is guarded by a lock.
"""

from __future__ import annotations

import threading
from collections import Counter, deque
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType

import numpy.typing as npt

from controller_emu.node import PENDING_KEPT, ModeChange
from controller_emu.open_follower import (
    FollowerLimits,
    FollowerState,
    apply_command,
    check_command,
    follower_joint_state,
    initial_state,
    step_follower,
)
from hrc_contract.config import ControllerConfig
from hrc_contract.messages import JointCommand, JointState, MessageError, parse_message
from hrc_contract.vocabulary import ControllerMode
from hrc_runtime.clocks import Clocks


@dataclass(frozen=True)
class OpenControllerOutput:
    """What one cycle produced.

    Attributes:
        state: the follower's state after the cycle (the true state: the auditor checks it).
        joint_state: the contract's message to publish (state and ground-truth keys).
        mode_change: set when the mode changed in this cycle, else None (``silent_s``: the last accepted command's
            age, since its stamp).
        cycle_mono_ns: the cycle's time, the state's sample time [ns, the controller's monotonic clock].
    """

    state: FollowerState
    joint_state: JointState
    mode_change: ModeChange | None
    cycle_mono_ns: int


@dataclass(frozen=True)
class OpenControllerStats:
    """The figures of the stats and progress lines.

    Attributes:
        mode: the current mode.
        command_seq: ``seq`` of the last accepted command; -1 before any.
        commands_accepted: joint commands accepted.
        joint_states: joint state messages produced (cycles run).
        rejected: command payloads rejected, by reason (parse errors and
            :data:`~controller_emu.open_follower.CommandRejection`), sorted by reason.
    """

    mode: ControllerMode
    command_seq: int
    commands_accepted: int
    joint_states: int
    rejected: Mapping[str, int]


@dataclass(frozen=True)
class _Accepted:
    message: JointCommand
    received: Clocks


class OpenControllerNode:
    """One emulated open controller: the joint commands it follows, its watchdog and the joint state it reports.

    Args:
        robot: the robot's name (commands for another robot are rejected; the joint state carries it).
        limits: the follower's limits (:func:`controller_emu.open_follower.follower_limits`).
        q0_rad: where the robot stands at start [rad] (the program's first waypoint).
        config: the controller's cycle (the first step's length).

    Raises:
        ValueError: ``q0_rad`` has not one value per joint of ``limits``, or lies outside the position limits.
    """

    def __init__(self, robot: str, limits: FollowerLimits, q0_rad: npt.ArrayLike, config: ControllerConfig) -> None:
        state = initial_state(q0_rad)
        if state.q_rad.shape != (limits.n_joints,):
            raise ValueError(f"q0_rad has {state.q_rad.size} values; allowed: {limits.n_joints} (one per joint)")
        if (state.q_rad < limits.q_min_rad).any() or (state.q_rad > limits.q_max_rad).any():
            raise ValueError(
                f"q0_rad = {state.q_rad.tolist()} outside the position limits "
                f"[{limits.q_min_rad.tolist()}, {limits.q_max_rad.tolist()}]"
            )
        self.robot = robot
        self.limits = limits
        self.config = config
        self._state = state
        self._last_mono_ns: int | None = None
        self._seq = 0
        self._lock = threading.Lock()
        self._pending: deque[_Accepted] = deque(maxlen=PENDING_KEPT)
        """Accepted commands not applied yet, in order of arrival (each newer than the one before)."""
        self._newest_stamp_ns = -1
        self._accepted = 0
        self._rejected: Counter[str] = Counter()

    @property
    def state(self) -> FollowerState:
        """The state after the last cycle."""
        return self._state

    def on_command(self, payload: bytes, now: Clocks) -> str | None:
        """Parse and check a joint command payload on arrival; keep it if it is the newest valid one.

        Args:
            payload: the payload as received.
            now: arrival. ``now.wall_ns`` is compared with the command's ``stamp_ns``; if it is accepted, its watchdog
                counts on from ``now.mono_ns``.

        Returns:
            None if accepted, else the reason it was rejected (also counted in :meth:`stats`): a
            :attr:`MessageError.reason` or a :data:`~controller_emu.open_follower.CommandRejection`.
        """
        try:
            message = parse_message(payload, JointCommand)
        except MessageError as exc:
            self.count_rejected(exc.reason)
            return exc.reason
        return self.on_message(message, now)

    def on_message(self, message: JointCommand, now: Clocks) -> str | None:
        """Check a parsed joint command on arrival (a vendor face's, e.g. EGM's); as :meth:`on_command` after parsing.

        Returns:
            None if accepted, else the :data:`~controller_emu.open_follower.CommandRejection` (also counted).
        """
        with self._lock:
            reason = check_command(
                message,
                self.robot,
                self.limits.n_joints,
                self._newest_stamp_ns,
                now.wall_ns,
                self.limits.watchdog_s,
            )
            if reason is None:
                self._pending.append(_Accepted(message, now))
                self._newest_stamp_ns = message.stamp_ns
                self._accepted += 1
            else:
                self._rejected[reason] += 1
        return reason

    def count_rejected(self, reason: str) -> None:
        """Count a payload rejected outside :meth:`on_command` (e.g. ``internal_error`` in a callback)."""
        with self._lock:
            self._rejected[reason] += 1

    def cycle(self, now: Clocks) -> OpenControllerOutput:
        """Apply the newest accepted command, move the robot by one step and report the joint state.

        Args:
            now: ``now.mono_ns`` runs the watchdog and gives the step time (since the previous cycle;
                ``config.cycle_s`` for the first); ``now.wall_ns`` is the joint state's ``stamp_ns``.
        """
        now_mono_ns = now.mono_ns
        with self._lock:
            pending = None  # the newest that arrived by this cycle's time; later ones wait for the next cycle
            while self._pending and self._pending[0].received.mono_ns <= now_mono_ns:
                pending = self._pending.popleft()
        before = self._state
        state = before if pending is None else apply_command(before, pending.message, pending.received, self.limits)
        dt_s = self.config.cycle_s if self._last_mono_ns is None else (now_mono_ns - self._last_mono_ns) / 1e9
        self._last_mono_ns = now_mono_ns
        state = step_follower(state, self.limits, dt_s, now_mono_ns)
        message = follower_joint_state(state, self.robot, self._seq, now.wall_ns)
        self._seq += 1
        self._state = state
        change = None
        if state.mode != before.mode:
            expires_ns = state.command_expires_mono_ns
            silent_s = None if expires_ns is None else self.limits.watchdog_s + (now_mono_ns - expires_ns) / 1e9
            change = ModeChange(before=before.mode, after=state.mode, silent_s=silent_s)
        return OpenControllerOutput(state=state, joint_state=message, mode_change=change, cycle_mono_ns=now_mono_ns)

    def stats(self) -> OpenControllerStats:
        """The current figures (safe to call from any thread)."""
        state = self._state
        with self._lock:
            rejected = MappingProxyType(dict(sorted(self._rejected.items())))
            accepted = self._accepted
        return OpenControllerStats(
            mode=state.mode,
            command_seq=state.command_seq,
            commands_accepted=accepted,
            joint_states=self._seq,
            rejected=rejected,
        )
