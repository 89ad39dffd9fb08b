"""The measured reaction time of the safeguarding chain (safety-math.md §5, paper Sec. III-D).

    t_delay = t_reaction (configured floor) + age of the human data + age of the joint state
              + override path latency + one controller cycle + one gateway period

Ages are measured at decision time from the capture stamps (``stamp_ns``) of the newest data. The
override path is learned from the controller's ``override_seq``: the first joint state that reports a
new seq, minus the time that override was sent, bounds the path from above.
"""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

NS_PER_S = 1e9


class DelayBudget(NamedTuple):
    """The parts of t_delay of one decision [s]."""

    t_reaction_s: float
    human_age_s: float
    joint_state_age_s: float
    override_path_s: float
    controller_cycle_s: float
    gateway_period_s: float

    @property
    def total_s(self) -> float:
        return (
            self.t_reaction_s
            + self.human_age_s
            + self.joint_state_age_s
            + self.override_path_s
            + self.controller_cycle_s
            + self.gateway_period_s
        )


class OverridePath:
    """Learns the gateway → controller latency and the controller cycle from the joint states.

    Keeps the send time of recent overrides; the estimate is the largest latency seen within the last
    ``window_s`` (conservative), and the controller cycle the largest stamp difference in that window.
    """

    def __init__(self, window_s: float = 1.0, history: int = 4096) -> None:
        self._window_ns = int(window_s * NS_PER_S)
        self._sent_ns: dict[int, int] = {}
        self._sent_order: deque[int] = deque()
        self._history = history
        self._latency: deque[tuple[int, int]] = deque()  # (stamp_ns, latency_ns)
        self._cycle: deque[tuple[int, int]] = deque()  # (stamp_ns, cycle_ns)
        self._last_ack_seq: int | None = None
        self._last_state_stamp_ns: int | None = None
        self.acked_sent_ns: int | None = None
        """Send time of the newest override the controller reported [ns since epoch]."""

    def on_sent(self, seq: int, sent_ns: int) -> None:
        self._sent_ns[seq] = sent_ns
        self._sent_order.append(seq)
        while len(self._sent_order) > self._history:
            self._sent_ns.pop(self._sent_order.popleft(), None)

    def on_state(self, override_seq: int, stamp_ns: int) -> None:
        """Record a joint state's echo of the override seq and its stamp."""
        if self._last_state_stamp_ns is not None and stamp_ns > self._last_state_stamp_ns:
            self._push(self._cycle, stamp_ns, stamp_ns - self._last_state_stamp_ns)
        self._last_state_stamp_ns = stamp_ns
        sent = self._sent_ns.get(override_seq)
        if sent is None:
            return
        if override_seq != self._last_ack_seq:
            self._last_ack_seq = override_seq
            self.acked_sent_ns = sent
            self._push(self._latency, stamp_ns, max(0, stamp_ns - sent))

    def _push(self, window: deque[tuple[int, int]], stamp_ns: int, value_ns: int) -> None:
        window.append((stamp_ns, value_ns))
        while window and window[0][0] < stamp_ns - self._window_ns:
            window.popleft()

    def latency_s(self) -> float | None:
        """Largest override path latency within the window, None before the first echo [s]."""
        return max(v for _, v in self._latency) / NS_PER_S if self._latency else None

    def controller_cycle_s(self) -> float | None:
        """Largest interval between joint states within the window, None before two states [s]."""
        return max(v for _, v in self._cycle) / NS_PER_S if self._cycle else None
