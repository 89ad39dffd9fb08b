"""The gateway's inputs: newest valid sample per topic, rejections counted by reason.

Zenoh callbacks call :meth:`InputStore.on_joint_state` and :meth:`InputStore.on_humans`; they only
validate and store (and ``on_humans`` may wake the loop to decide at once). The safety loop takes a
consistent :class:`InputSnapshot` once per cycle.
A topic whose newest message was invalid is *latched invalid* until a valid one arrives: the robots it
concerns get δ = 0 meanwhile (contract, "Bad input").
"""

from __future__ import annotations

import threading
from collections import Counter
from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from gateway.delay import OverridePath
from hrc_common import keys
from hrc_common.humans import HumanCapsules, capsules_from_message
from hrc_common.messages import Humans, JointState, MessageError, parse_message

FloatArray = npt.NDArray[np.float64]

FUTURE_STAMP_TOLERANCE_NS = 5_000_000
"""A stamp later than the receive time by more than this is a clock fault (it would hide a delay)."""


class JointSample(NamedTuple):
    stamp_ns: int
    seq: int
    q_rad: FloatArray
    qd_nominal_radps: FloatArray
    override: float
    override_seq: int
    mode: str


class HumanFrame(NamedTuple):
    stamp_ns: int
    seq: int
    capsules: HumanCapsules
    human_count: int


class OverridePathEstimate(NamedTuple):
    latency_s: float | None
    controller_cycle_s: float | None
    acked_sent_ns: int | None


class InputSnapshot(NamedTuple):
    """What the loop sees in one cycle.

    Attributes:
        joint: newest valid joint state per configured robot (None if none yet).
        humans: newest valid frame per configured tracker (None if none yet).
        invalid: topics whose newest message was invalid, with the reason (``robot/<r>`` or ``tracker/<t>``).
        override_path: per robot, what the override echo taught.
    """

    joint: dict[str, JointSample | None]
    humans: dict[str, HumanFrame | None]
    invalid: dict[str, str]
    override_path: dict[str, OverridePathEstimate]


class InputStore:
    """Thread-safe store of the newest valid input per topic, with rejection counters."""

    def __init__(
        self,
        robot_joint_counts: dict[str, int],
        trackers: list[str],
        on_tracker_change: Callable[[], None] | None = None,
    ) -> None:
        """
        Args:
            robot_joint_counts: joints per configured robot.
            trackers: the configured trackers.
            on_tracker_change: called (on the callback's thread, after storing) when what the loop sees
                of a tracker changed, e.g. ``threading.Event.set`` to wake the loop; must not block.
        """
        self._on_tracker_change = on_tracker_change or _nothing
        self._lock = threading.Lock()
        self._joint_counts = dict(robot_joint_counts)
        self._joint: dict[str, JointSample | None] = dict.fromkeys(robot_joint_counts)
        self._frames: dict[str, HumanFrame | None] = dict.fromkeys(trackers)
        self._invalid: dict[str, str] = {}  # topic name -> reason of its newest, invalid message
        self._paths = {name: OverridePath() for name in robot_joint_counts}
        self._rejected: Counter[tuple[str, str]] = Counter()
        self._received: Counter[str] = Counter()

    # -- callbacks (Zenoh threads) -------------------------------------------------------------

    def on_joint_state(self, key: str, payload: bytes, now_ns: int) -> None:
        robot = keys.name_from_key(key, "robot") or "?"
        topic_name = f"robot/{robot}"
        if robot not in self._joint:
            self._reject(topic_name, "unknown_robot", latch=False)
            return
        try:
            msg = parse_message(payload, JointState)
        except MessageError as exc:
            self._reject(topic_name, exc.reason)
            return
        if msg.robot != robot:
            self._reject(topic_name, "name_mismatch")
            return
        if len(msg.q) != self._joint_counts[robot]:
            self._reject(topic_name, "wrong_joint_count")
            return
        if msg.stamp_ns > now_ns + FUTURE_STAMP_TOLERANCE_NS:
            self._reject(topic_name, "stamp_in_future")
            return
        sample = JointSample(
            msg.stamp_ns,
            msg.seq,
            np.asarray(msg.q, dtype=float),
            np.asarray(msg.qd_nominal, dtype=float),
            msg.override,
            msg.override_seq,
            msg.mode,
        )
        with self._lock:
            if _is_old(self._joint[robot], msg.seq, msg.stamp_ns):
                self._rejected[(topic_name, "old_or_repeated")] += 1
                return
            self._joint[robot] = sample
            self._invalid.pop(topic_name, None)
            self._received[topic_name] += 1
            self._paths[robot].on_state(msg.override_seq, msg.stamp_ns)

    def on_humans(self, key: str, payload: bytes, now_ns: int) -> None:
        """Validate and store a tracker frame; call ``on_tracker_change`` when what the loop sees of a
        configured tracker changed (a new frame, or its newest message latched invalid), not for an
        unknown tracker or an old or repeated frame."""
        tracker = keys.name_from_key(key, "tracker") or "?"
        topic_name = f"tracker/{tracker}"
        if tracker not in self._frames:
            self._reject(topic_name, "unknown_tracker", latch=False)
            return
        try:
            msg = parse_message(payload, Humans)
        except MessageError as exc:
            self._reject(topic_name, exc.reason)
            self._on_tracker_change()
            return
        if msg.tracker != tracker:
            self._reject(topic_name, "name_mismatch")
            self._on_tracker_change()
            return
        if msg.stamp_ns > now_ns + FUTURE_STAMP_TOLERANCE_NS:
            self._reject(topic_name, "stamp_in_future")
            self._on_tracker_change()
            return
        frame = HumanFrame(msg.stamp_ns, msg.seq, capsules_from_message(tracker, msg), len(msg.humans))
        with self._lock:
            if _is_old(self._frames[tracker], msg.seq, msg.stamp_ns):
                self._rejected[(topic_name, "old_or_repeated")] += 1
                return
            self._frames[tracker] = frame
            self._invalid.pop(topic_name, None)
            self._received[topic_name] += 1
        self._on_tracker_change()

    def count_rejection(self, topic_name: str, reason: str) -> None:
        """Count a rejection found outside the store (e.g. an exception in a callback)."""
        self._reject(topic_name, reason)

    def _reject(self, topic_name: str, reason: str, latch: bool = True) -> None:
        with self._lock:
            self._rejected[(topic_name, reason)] += 1
            if latch:
                self._invalid[topic_name] = reason

    # -- loop side --------------------------------------------------------------------------

    def on_override_sent(self, robot: str, seq: int, sent_ns: int) -> None:
        with self._lock:
            self._paths[robot].on_sent(seq, sent_ns)

    def snapshot(self) -> InputSnapshot:
        with self._lock:
            joint = dict(self._joint)
            humans = dict(self._frames)
            invalid = dict(self._invalid)
            paths = {
                name: OverridePathEstimate(p.latency_s(), p.controller_cycle_s(), p.acked_sent_ns)
                for name, p in self._paths.items()
            }
        return InputSnapshot(joint, humans, invalid, paths)

    def counters(self) -> tuple[dict[str, dict[str, int]], dict[str, int]]:
        """Rejections per topic and reason, and valid messages per topic."""
        with self._lock:
            rejected: dict[str, dict[str, int]] = {}
            for (topic_name, reason), count in self._rejected.items():
                rejected.setdefault(topic_name, {})[reason] = count
            return rejected, dict(self._received)


def _is_old(previous: JointSample | HumanFrame | None, seq: int, stamp_ns: int) -> bool:
    """Older than, or a repeat of, the newest accepted sample. A producer restart (seq back to 0 with a
    newer stamp) is accepted."""
    if previous is None:
        return False
    return stamp_ns < previous.stamp_ns or (seq <= previous.seq and stamp_ns <= previous.stamp_ns)


def _nothing() -> None:
    """The default ``on_tracker_change``."""
