"""The gateway as one step object: messages in, ``cycle(now)`` → overrides out.

    payload ──on_joint_state / on_humans──▶ InputStore (judged, newest kept)
    cycle(now) ──▶ snapshot ──▶ SafetyCore.step ──▶ one decision and one Override message per robot

The process (``gateway/main.py``) feeds it from Zenoh and publishes what ``cycle`` returns; the simulated cell
(``hrc_tools/sim/cell.py``) feeds it from simulated links on a simulated clock. Both run this very object, so the sweep
proves the program, not a copy of its loop. No I/O and no clock inside: every time is passed in.
"""

from __future__ import annotations

import contextlib
import threading
from collections import Counter
from collections.abc import Callable, Mapping
from typing import Any, NamedTuple, Protocol

from gateway.core import RobotDecision, SafetyCore, TrackReset
from gateway.delay import NS_PER_S
from gateway.inputs import InputSnapshot, InputStore
from gateway.planner import JointPlanner
from gateway.planner_worker import PlannerBackend
from gateway.tracks import TrackEvent, TrackRecord
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.humans import NO_HUMANS, HumanCapsules
from hrc_contract.messages import JointCommand, MessageError, Override, parse_message
from hrc_contract.messages import TrackReset as TrackResetMessage
from hrc_devices.robots.model import RobotModel
from hrc_runtime.clocks import Clocks

RESET_TOPIC = "operator/track_reset"
"""The counters' topic of the operators' resets."""
RESET_MAX_AGE_S = 2.0
"""A reset stamped longer ago than this is refused (``stale``): a recorded reset replayed later must not release
people the operator never checked [s]."""


class GatewayCycle(NamedTuple):
    """What one cycle decided.

    Attributes:
        seq: the seq of this cycle's overrides.
        decisions: per robot, the decision (what the status shows).
        overrides: per robot, the message to publish: an ``Override`` on ``hrc/<cell>/robot/<robot>/override``, or for
            an open robot a ``JointCommand`` on ``…/joint_command`` (none before its first joint state).
        inputs: the snapshot the decisions were made from.
        track_events: the tracks' changes this cycle (lost, released), in order.
        tracks: every track after this cycle (seen, lost, recently released).
        now: the decision time on both clocks.
        capsules: the people the decisions kept clear of: every seen capsule and every lost track's, grown.
    """

    seq: int
    decisions: dict[str, RobotDecision]
    overrides: dict[str, Override | JointCommand]
    inputs: InputSnapshot
    track_events: tuple[TrackEvent, ...] = ()
    tracks: tuple[TrackRecord, ...] = ()
    now: Clocks | None = None
    capsules: HumanCapsules = NO_HUMANS


class NodeRecorder(Protocol):
    """Told of everything that changes the node, in the order the node saw it (``hrc-gateway --record``).

    Called with the node's order lock held: every method must return at once (queue, never write).
    """

    def on_input(self, key: str, payload: bytes, received: Clocks) -> None: ...

    def on_internal_error(self, key: str, received: Clocks) -> None: ...

    def on_cycle(self, now: Clocks, period_s: float, cycle: GatewayCycle) -> None: ...


class GatewayNode:
    """The gateway's state and step: the input store, the safety core, and the override sequence.

    Args:
        config: the cell.
        robots: the models of ``config.robots``.
        on_tracker_change: called on the caller's thread when a tracker message changed what the next cycle
            sees (to wake an event-driven loop); must not block.
        recorder: told of every input and cycle. Then one lock orders each input against each whole cycle
            (callbacks run on Zenoh threads while the loop cycles), so the recorded order is the order the node
            saw them in and a replay in that order decides the same; without a recorder there is no lock.

    Raises:
        ConfigError: as :class:`SafetyCore`.
    """

    def __init__(
        self,
        config: CellConfig,
        robots: Mapping[str, RobotModel],
        on_tracker_change: Callable[[], None] | None = None,
        recorder: NodeRecorder | None = None,
        planner_backend: Callable[[dict[str, JointPlanner]], PlannerBackend] | None = None,
    ) -> None:
        self.config = config
        self.robots = dict(robots)
        self.core = SafetyCore(config, self.robots, planner_backend)
        self._open = frozenset(name for name, state in self.core.states.items() if state.open is not None)
        self.inputs = InputStore(config, self.robots, on_tracker_change)
        self.seq = 0
        self._resets: list[TrackReset] = []
        self._reset_stamp_ns = -1
        self._reset_lock = threading.Lock()
        self.reset_counters: Counter[str] = Counter()
        """Operators' resets: ``accepted`` and refused by reason (parse reasons, ``stamp_in_future``, ``stale``,
        ``stamp_backwards``)."""
        self._recorder = recorder
        self._order: contextlib.AbstractContextManager[Any] = (
            contextlib.nullcontext() if recorder is None else threading.Lock()
        )

    # -- inputs (any thread) ----------------------------------------------------------------------

    def on_joint_state(self, key: str, payload: bytes, received: Clocks) -> None:
        """A payload on ``hrc/<cell>/robot/<robot>/state`` arrived at ``received``."""
        self.inputs.on_joint_state(key, payload, received)

    def on_humans(self, key: str, payload: bytes, received: Clocks) -> None:
        """A payload on ``hrc/<cell>/tracker/<tracker>/humans`` arrived at ``received``."""
        self.inputs.on_humans(key, payload, received)

    def on_track_reset(self, payload: bytes, received: Clocks) -> None:
        """An operator's reset of a lost person (``hrc/<cell>/operator/track_reset``): judged, queued for the next
        cycle, counted. Only the ``operator`` certificate may put it (access control); here it must also be fresh
        and newer than the last one accepted (a replayed reset is refused)."""
        try:
            msg = parse_message(payload, TrackResetMessage)
        except MessageError as exc:
            self._count_reset(exc.reason)
            return
        max_future_ns = round(self.config.streams.max_future_stamp_s * NS_PER_S)
        if msg.stamp_ns > received.wall_ns + max_future_ns:
            self._count_reset("stamp_in_future")
        elif msg.stamp_ns < received.wall_ns - round(RESET_MAX_AGE_S * NS_PER_S):
            self._count_reset("stale")
        else:
            with self._reset_lock:
                if msg.stamp_ns <= self._reset_stamp_ns:
                    self.reset_counters["stamp_backwards"] += 1
                    return
                self._reset_stamp_ns = msg.stamp_ns
                self._resets.append(TrackReset(msg.track, msg.operator))
                self.reset_counters["accepted"] += 1

    def _count_reset(self, reason: str) -> None:
        with self._reset_lock:
            self.reset_counters[reason] += 1

    def counters(self) -> tuple[dict[str, dict[str, int]], dict[str, int]]:
        """Rejections per topic and reason, and valid messages per topic (the inputs' and the operators' resets)."""
        rejected, received = self.inputs.counters()
        with self._reset_lock:
            refused = {reason: n for reason, n in self.reset_counters.items() if reason != "accepted"}
            accepted = self.reset_counters["accepted"]
        if refused:
            rejected[RESET_TOPIC] = refused
        if accepted:
            received[RESET_TOPIC] = accepted
        return rejected, received

    def on_message(self, key: str, payload: bytes, received: Clocks) -> None:
        """A payload on either input key (routed by the key)."""
        with self._order:
            if self._recorder is not None:
                self._recorder.on_input(key, payload, received)
            if keys.name_from_key(key, "tracker") is not None:
                self.on_humans(key, payload, received)
            elif key.endswith("/" + RESET_TOPIC):
                self.on_track_reset(payload, received)
            else:
                self.on_joint_state(key, payload, received)

    def on_internal_error(self, key: str, received: Clocks) -> None:
        """Handling a message on ``key`` raised: count it and fault the topic (δ = 0 for what it concerns)."""
        kind = "tracker" if keys.name_from_key(key, "tracker") is not None else "robot"
        with self._order:
            if self._recorder is not None:
                self._recorder.on_internal_error(key, received)
            self.inputs.count_rejection(f"{kind}/{keys.name_from_key(key, kind) or '?'}", "internal_error", received)

    # -- the loop -----------------------------------------------------------------------------------

    def cycle(self, now: Clocks, period_s: float) -> GatewayCycle:
        """Decide for every robot at ``now`` and stamp the overrides with ``now.wall_ns``.

        Args:
            now: the decision time on both clocks.
            period_s: the time until the next decision the delay budget counts: the loop's worst recent interval
                between decisions, at least its period [s].
        """
        with self._order:
            snapshot = self.inputs.snapshot(now)
            with self._reset_lock:
                resets, self._resets = tuple(self._resets), []
            decisions = self.core.step(snapshot, now, period_s, resets)
            self.seq += 1
            overrides: dict[str, Override | JointCommand] = {}
            for name, decision in decisions.items():
                command = decision.open_command
                if command is not None:
                    overrides[name] = JointCommand(
                        robot=name,
                        seq=self.seq,
                        stamp_ns=now.wall_ns,
                        q=command.q_rad.tolist(),
                        qd=command.qd_radps.tolist(),
                        delta=decision.delta,
                    )
                    # an open controller applies no override: it reports 1 while it follows (the stop is in q̇)
                    self.inputs.on_override_sent(name, self.seq, 1.0, now)
                elif name not in self._open:
                    overrides[name] = Override(robot=name, seq=self.seq, stamp_ns=now.wall_ns, delta=decision.delta)
                    self.inputs.on_override_sent(name, self.seq, decision.delta, now)
            cycle = GatewayCycle(
                self.seq,
                decisions,
                overrides,
                snapshot,
                tuple(self.core.track_events),
                self.core.track_records(),
                now,
                self.core.capsules,
            )
            if self._recorder is not None:
                self._recorder.on_cycle(now, period_s, cycle)
        return cycle

    def stop_overrides(self, now: Clocks) -> dict[str, Override | JointCommand]:
        """δ = 0 for every closed robot, q̇ = 0 at the reference for every open one: the last word on shutdown (their
        watchdogs would stop them anyway)."""
        self.seq += 1
        out: dict[str, Override | JointCommand] = {}
        for name in self.robots:
            open_robot = self.core.states[name].open
            if open_robot is None:
                out[name] = Override(robot=name, seq=self.seq, stamp_ns=now.wall_ns, delta=0.0)
            elif open_robot.q_ref_rad is not None:
                q = open_robot.q_ref_rad.tolist()
                out[name] = JointCommand(
                    robot=name, seq=self.seq, stamp_ns=now.wall_ns, q=q, qd=[0.0] * len(q), delta=0.0
                )
        return out
