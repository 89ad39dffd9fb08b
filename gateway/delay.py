"""The measured reaction time of the safeguarding chain (safety-math.md §5, paper Sec. III-D).

    t_delay = t_reaction (configured floor) + age of the human data + age of the joint state
              + override path latency + one controller cycle + one gateway period

Ages are measured at decision time from the capture stamps (``stamp_ns``) of the newest data. The
override path is learned from the controller's ``override_seq``: the first joint state that reports a
new seq, minus the time that override was sent, bounds the path from above.

An echo is evidence only if it could have happened: a state stamped before the override it echoes was sent
(beyond the clocks' agreement) or echoing a seq this gateway never sent is a fault (:data:`EchoProblem`), never a
latency of 0; a seq first reported before it was sent can never confirm it later.
"""

from __future__ import annotations

from collections import deque
from typing import Literal, NamedTuple

NS_PER_S = 1e9

EchoProblem = Literal["echo_before_send", "echo_never_sent"]
"""Why a joint state's ``override_seq`` cannot be an echo of what this gateway sent (:meth:`OverridePath.on_state`)."""


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


class OverridePathEstimate(NamedTuple):
    """What the override echo taught so far (:class:`OverridePath`), None before it is known.

    Attributes:
        latency_s: the largest override path latency within the window [s].
        controller_cycle_s: the largest interval between joint states within the window [s].
        acked_sent_mono_ns: send time of the newest override echoed, on the gateway's monotonic clock [ns].
    """

    latency_s: float | None
    controller_cycle_s: float | None
    acked_sent_mono_ns: int | None


class WindowMax:
    """Largest value pushed within the last ``window_ns`` (monotonic deque: O(1) amortised per push)."""

    def __init__(self, window_ns: int) -> None:
        self._window_ns = window_ns
        self._values: deque[tuple[int, float]] = deque()  # (stamp_ns, value), values decreasing

    def push(self, stamp_ns: int, value: float) -> float:
        """Add a value at ``stamp_ns`` and return the window's maximum."""
        while self._values and self._values[-1][1] <= value:
            self._values.pop()  # a smaller, older value can never be the maximum again
        self._values.append((stamp_ns, value))
        while self._values[0][0] < stamp_ns - self._window_ns:
            self._values.popleft()
        return self._values[0][1]

    def max(self) -> float | None:
        return self._values[0][1] if self._values else None


class OverridePath:
    """Learns the gateway → controller latency and the controller cycle from the joint states.

    Keeps the send time of recent overrides; the estimate is the largest latency seen within the last
    ``window_s`` (conservative), and the controller cycle the largest stamp difference in that window.
    """

    def __init__(self, window_s: float = 1.0, history: int = 4096) -> None:
        self._window_ns = int(window_s * NS_PER_S)
        self._sent_ns: dict[int, tuple[int, int]] = {}
        self._sent_order: deque[int] = deque()
        self._history = history
        self._latency_ns = WindowMax(self._window_ns)
        self._cycle_ns = WindowMax(self._window_ns)
        self._last_echo_seq: int | None = None
        self._max_sent_seq: int = -1
        self._last_state_stamp_ns: int | None = None
        self.acked_sent_mono_ns: int | None = None
        """Send time of the newest override the controller reported, on the gateway's monotonic clock [ns]."""
        self.estimate = OverridePathEstimate(None, None, None)
        """The three together, renewed by :meth:`on_state` (the only call that changes them: a window's maximum
        moves only on a push), so that the loop reads them without recomputing them every cycle."""

    def on_sent(self, seq: int, sent_ns: int, sent_mono_ns: int) -> None:
        """Record an override sent at ``sent_ns`` (wall clock, compared with the controller's stamps) and
        ``sent_mono_ns`` (this process's monotonic clock, for the age of the newest echo)."""
        self._sent_ns[seq] = (sent_ns, sent_mono_ns)
        self._max_sent_seq = max(self._max_sent_seq, seq)
        self._sent_order.append(seq)
        while len(self._sent_order) > self._history:
            self._sent_ns.pop(self._sent_order.popleft(), None)

    def on_state(self, override_seq: int, stamp_ns: int, clock_tolerance_ns: int = 0) -> EchoProblem | None:
        """Record a joint state's echo of the override seq and its stamp; say why the echo is impossible.

        Only the first state that reports a seq can confirm it: the time from sending it to that state's stamp is
        the latency. A seq reported before it was sent (another sender, a previous gateway process, a forged state)
        therefore never confirms it, not even once this gateway sends it.

        Args:
            override_seq: the seq the controller reports as applied (-1 before any).
            stamp_ns: the joint state's stamp [ns, the controller's wall clock].
            clock_tolerance_ns: how far the controller's clock may be behind the gateway's [ns].

        Returns:
            None, or ``echo_before_send``: the first state reporting a seq is stamped more than
            ``clock_tolerance_ns`` before that seq was sent; ``echo_never_sent``: a seq above every seq sent, once
            an echo confirmed the path (before that, a restarted gateway still sees its predecessor's seqs). Neither
            teaches the latency.
        """
        changed = False
        if self._last_state_stamp_ns is not None and stamp_ns > self._last_state_stamp_ns:
            self._cycle_ns.push(stamp_ns, stamp_ns - self._last_state_stamp_ns)
            changed = True
        self._last_state_stamp_ns = stamp_ns
        reason: EchoProblem | None = None
        first_report = override_seq != self._last_echo_seq
        self._last_echo_seq = override_seq
        sent = self._sent_ns.get(override_seq)
        if sent is None:
            if override_seq > self._max_sent_seq and self.acked_sent_mono_ns is not None:
                reason = "echo_never_sent"
        elif first_report:
            sent_ns, sent_mono_ns = sent
            if stamp_ns < sent_ns - clock_tolerance_ns:
                reason = "echo_before_send"
            else:
                self.acked_sent_mono_ns = sent_mono_ns
                self._latency_ns.push(stamp_ns, max(0, stamp_ns - sent_ns))  # ≥ 0 within the clocks' agreement
                changed = True
        if changed:
            self.estimate = OverridePathEstimate(self.latency_s(), self.controller_cycle_s(), self.acked_sent_mono_ns)
        return reason

    def latency_s(self) -> float | None:
        """Largest override path latency within the window, None before the first echo [s]."""
        latency_ns = self._latency_ns.max()
        return None if latency_ns is None else latency_ns / NS_PER_S

    def controller_cycle_s(self) -> float | None:
        """Largest interval between joint states within the window, None before two states [s]."""
        cycle_ns = self._cycle_ns.max()
        return None if cycle_ns is None else cycle_ns / NS_PER_S
