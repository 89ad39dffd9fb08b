"""Simulated network links: delay, jitter, loss and duplication on a simulated clock, seeded.

Each message sent at ``sent_ns`` is lost with probability ``loss``; otherwise it arrives at
``sent_ns + delay_s + U(0, jitter_s)``, and with probability ``duplication`` a second copy arrives with
its own jitter. With ``in_order`` (the default, like Zenoh over TCP: one publisher's messages never overtake
each other) a message arrives no earlier than the one sent before it; without it, messages overtake each other
when their jitter differs (reordering, which the gateway treats as a stream fault).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass, field
from typing import Generic, TypeVar

import numpy as np

NS_PER_S = 1_000_000_000

T = TypeVar("T")


@dataclass(frozen=True)
class LinkFault:
    """What one direction of one path does to its messages.

    Attributes:
        delay_s: fixed one-way delay [s].
        jitter_s: extra delay, uniform in [0, jitter_s], drawn per message [s].
        loss: probability that a message is lost.
        duplication: probability that a delivered message arrives a second time.
        in_order: messages arrive in the order they were sent (jitter delays, never reorders).
    """

    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0
    duplication: float = 0.0
    in_order: bool = True

    def __post_init__(self) -> None:
        for name in ("delay_s", "jitter_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                raise ValueError(f"{name} = {value}; allowed: a finite value >= 0")
        for name in ("loss", "duplication"):
            value = getattr(self, name)
            if not 0.0 <= value < 1.0:
                raise ValueError(f"{name} = {value}; allowed: 0 <= {name} < 1")

    @property
    def max_delay_s(self) -> float:
        """The longest a delivered message can take [s]."""
        return self.delay_s + self.jitter_s


@dataclass(frozen=True)
class LinkFaults:
    """The faults of the three paths of the cell (the same for every robot and tracker).

    Attributes:
        tracker_to_gateway: humans messages.
        controller_to_gateway: joint states.
        gateway_to_controller: overrides.
    """

    tracker_to_gateway: LinkFault = LinkFault()
    controller_to_gateway: LinkFault = LinkFault()
    gateway_to_controller: LinkFault = LinkFault()


@dataclass(frozen=True, order=True)
class _InFlight(Generic[T]):
    arrive_ns: int
    order: int
    item: T = field(compare=False)


@dataclass
class LinkCounters:
    sent: int = 0
    lost: int = 0
    duplicated: int = 0
    delivered: int = 0


class SimLink(Generic[T]):
    """One direction of one path: items go in with :meth:`send`, come out in arrival order with :meth:`deliver`.

    Args:
        fault: what the link does.
        rng: its own random generator (seeded by the caller).
    """

    def __init__(self, fault: LinkFault, rng: np.random.Generator) -> None:
        self.fault = fault
        self._rng = rng
        self._in_flight: list[_InFlight[T]] = []
        self._order = 0
        self._last_arrival_ns = -1
        self.counters = LinkCounters()

    def _arrival_ns(self, sent_ns: int) -> int:
        jitter_s = self._rng.random() * self.fault.jitter_s if self.fault.jitter_s > 0.0 else 0.0
        arrive_ns = sent_ns + round((self.fault.delay_s + jitter_s) * NS_PER_S)
        if self.fault.in_order:
            arrive_ns = max(arrive_ns, self._last_arrival_ns)
            self._last_arrival_ns = arrive_ns
        return arrive_ns

    def _push(self, arrive_ns: int, item: T) -> None:
        self._order += 1
        heapq.heappush(self._in_flight, _InFlight(arrive_ns, self._order, item))

    def send(self, item: T, sent_ns: int) -> None:
        """Put an item on the link at simulated time ``sent_ns`` [ns]."""
        self.counters.sent += 1
        fault = self.fault
        if fault.loss > 0.0 and self._rng.random() < fault.loss:
            self.counters.lost += 1
            return
        self._push(self._arrival_ns(sent_ns), item)
        if fault.duplication > 0.0 and self._rng.random() < fault.duplication:
            self.counters.duplicated += 1
            self._push(self._arrival_ns(sent_ns), item)

    def next_arrival_ns(self) -> int | None:
        """Arrival time of the next item in flight, None if none [ns]."""
        return self._in_flight[0].arrive_ns if self._in_flight else None

    def deliver(self, now_ns: int) -> list[tuple[int, T]]:
        """The items that have arrived by ``now_ns``, as ``(arrival_ns, item)`` in arrival order."""
        out = []
        while self._in_flight and self._in_flight[0].arrive_ns <= now_ns:
            flight = heapq.heappop(self._in_flight)
            out.append((flight.arrive_ns, flight.item))
        self.counters.delivered += len(out)
        return out
