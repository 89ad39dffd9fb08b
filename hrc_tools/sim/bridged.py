"""The simulated cell with a controller bridge in the path: the vendor's face of the emulated controller, its
dedicated link and the bridge's own pure core, on the cell's one simulated clock.

    override link → bridge.on_override → next_write → (write latency) → the face → the controller's override
    controller cycle → the face's latest state → (output period / poll, read latency) → ControllerReading
        → bridge.on_reading → joint state → state link → gateway

What is real code and what is modelled:

- the bridge: :class:`controller_bridge.bridge.Bridge` with the settings ``hrc-controller-bridge`` derives from the
  cell (:func:`controller_bridge.main.bridge_settings`), driven as its shell drives it (a writer at the heartbeat
  rate, woken at once by every override; a reader per output package or per poll);
- the vendor's exchange over its link (:mod:`hrc_tools.sim.exchanges`, one module per vendor, chosen by the
  interface's kind): readings built from the emulated controller's state by the face's own functions and checked by
  the bridge's own parsers, writes that reach the face as the vendor's do (UR RTDE: packages every output period and
  a slider written as given; ABB RWS: polls of three requests and a POST on one connection). Each face turns an
  accepted write into an override of the controller node stamped with the controller's clock (stamps strictly
  increasing, a seq per face), as the emulator's faces do;
- the vendor link (a dedicated cable next to the controller, :class:`VendorLink`): a fixed one-way latency each way,
  no loss. The Zenoh links on either side of the bridge are the cell's (``LinkFaults``), unchanged.

The gateway therefore learns the whole override path from the bridge's echo (``override_seq`` advances only when
the read-back shows the written value): Zenoh, the bridge's writer, the write latency, the output period or the
poll, and the read latency. Everything is deterministic: the phases of the writer and the reader are drawn from
the run's seed by the caller.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from controller_bridge.bridge import Bridge, BridgeSettings
from controller_emu.node import ControllerNode, ControllerOutput
from hrc_contract.messages import to_payload
from hrc_devices.controllers.descriptor import BridgedConfig
from hrc_devices.controllers.registry import VENDORS, bridged_kinds
from hrc_devices.controllers.vendor import ControllerReading
from hrc_runtime.clocks import Clocks
from hrc_tools.sim.exchanges import EXCHANGES
from hrc_tools.sim.exchanges.base import SimFace, VendorLink
from hrc_tools.sim.links import NS_PER_S, SimLink

__all__ = ["INTERFACES", "SimBridge", "VendorLink", "default_interface"]

INTERFACES = ("zenoh", *bridged_kinds())
"""The ``--interface`` choices: the emulator's own Zenoh face (no bridge), or a bridge to the vendor's face."""

Payload = tuple[str, bytes]
FloatArray = npt.NDArray[np.float64]

_SOURCES = ("program_model", "target_qd", "qd", "velocity_limits")
"""The ``qd_nominal`` sources of :func:`controller_bridge.bridge.nominal_velocity` (``model_miss`` is not one)."""

TRUTH_MIN_SPEED_RADPS = 0.05
"""``qd_nominal`` is compared with the program's where the programmed joint speed (norm) is at least this [rad/s]."""

QD_NOMINAL_LOW_RATIO = 0.98
"""A reported programmed speed below this fraction of the true one is counted as low (2 %: the gateway's ratio)."""


def default_interface(kind: str) -> dict[str, Any]:
    """The cell file's ``[robots.<name>.interface]`` table for ``--interface KIND`` (the shipped cells' values)."""
    if kind == "zenoh":
        return {"kind": "zenoh"}
    if kind not in VENDORS:
        raise ValueError(f"interface {kind!r}; allowed: zenoh, {', '.join(bridged_kinds())}")
    return dict(VENDORS[kind].sim_interface)


# -- the bridged path -----------------------------------------------------------------------------------------------


@dataclass(frozen=True, order=True)
class _Event:
    t_ns: int
    order: int
    kind: str = field(compare=False)
    """``writer`` (the bridge's heartbeat), else the exchange's own."""
    data: Any = field(compare=False, default=None)


@dataclass
class _Truth:
    """The bridge's ``qd_nominal`` against the program's true velocity at the same program point."""

    compared: int = 0
    low: int = 0
    min_ratio: float = math.inf
    min_ratio_t_s: float | None = None
    min_ratio_source: str | None = None

    def add(self, reported: list[float], true_radps: FloatArray, t_s: float, source: str) -> None:
        true_speed = float(np.linalg.norm(true_radps))
        if true_speed < TRUTH_MIN_SPEED_RADPS:
            return
        ratio = float(np.linalg.norm(reported)) / true_speed
        self.compared += 1
        self.low += ratio < QD_NOMINAL_LOW_RATIO
        if ratio < self.min_ratio:
            self.min_ratio, self.min_ratio_t_s, self.min_ratio_source = ratio, t_s, source


class SimBridge:
    """One robot's bridge and its controller's vendor face on the simulated clock.

    The cell calls :meth:`next_event_ns` to know when it is due, :meth:`advance` at that time, and :meth:`on_cycle`
    after each controller cycle (the face keeps the latest state, as the real faces' ``on_cycle``).

    Args:
        interface: the robot's bridged interface from the cell file (rates, watchdog, RTDE frequency).
        settings: the bridge core's settings (:func:`controller_bridge.main.bridge_settings`).
        node: the emulated controller (the faces' writes become its overrides).
        override_link: the gateway → bridge link (the bridge takes every override at its arrival).
        state_link: the bridge → gateway link (joint states).
        state_key: the joint state's key expression.
        clocks: simulated time [ns] → both clocks.
        phase_ns: offsets of the writer's heartbeat and of the reader's first output or poll [ns].
        vendor: the dedicated link's latency (default: :data:`DEFAULT_VENDOR_LINKS`).
    """

    def __init__(
        self,
        interface: BridgedConfig,
        settings: BridgeSettings,
        node: ControllerNode,
        override_link: SimLink[Payload],
        state_link: SimLink[Payload],
        state_key: str,
        clocks: Callable[[int], Clocks],
        phase_ns: tuple[int, int],
        vendor: VendorLink | None = None,
    ) -> None:
        self.kind = interface.kind
        self.core = Bridge(settings)
        self.node = node
        self.face = SimFace(0.0)
        self.latest: ControllerOutput | None = None
        self.latest_value = 0.0
        self._override_link = override_link
        self._state_link = state_link
        self._state_key = state_key
        self._clocks = clocks
        self._heartbeat_ns = round(settings.heartbeat_s * NS_PER_S)
        self._queue: list[_Event] = []
        self._order = 0
        self._writer_busy = False  # the writer waits for its write's answer
        self._wake_pending = False
        self._latencies_s: list[float] = []
        self.truth = _Truth()
        self._sources_seen: dict[str, int] = {}
        self._exchange = EXCHANGES[self.kind](interface, self, vendor)
        self.latest_value = self.face.value
        self.push(phase_ns[0] % max(self._heartbeat_ns, 1), "writer")
        self._exchange.start(phase_ns[1])

    # -- the cell's side ------------------------------------------------------------------------------------------

    def on_cycle(self, output: ControllerOutput) -> None:
        """The controller's latest cycle (the face serves it until the next one), with the face's value then."""
        self.latest = output
        self.latest_value = self.face.value

    def next_event_ns(self) -> int:
        """When something happens next: an override arrives, or a write, reading or tick is due [ns]."""
        arrival = self._override_link.next_arrival_ns()
        queued = self._queue[0].t_ns
        return queued if arrival is None else min(arrival, queued)

    def advance(self, now_ns: int) -> None:
        """Everything due at ``now_ns``: overrides that arrived (each wakes the writer), then the queued events."""
        for arrived_ns, (_, payload) in self._override_link.deliver(now_ns):
            if self.core.on_override(payload, self._clocks(arrived_ns)) is None:
                self._write(arrived_ns)
        while self._queue and self._queue[0].t_ns <= now_ns:
            event = heapq.heappop(self._queue)
            if event.kind == "writer":
                self._write(event.t_ns)
                self.push(event.t_ns + self._heartbeat_ns, "writer")
            else:
                self._exchange.handle(event.kind, event.data, event.t_ns)

    def summary(self) -> dict[str, Any]:
        """The bridge's figures for the run's result (JSON-ready, deterministic)."""
        stats = self.core.stats()
        latencies = self._latencies_s
        return {
            "interface": self.kind,
            "readings": stats.readings,
            "published": stats.published,
            "writes": stats.writes,
            "face_writes": self.face.writes,
            "face_refused": self.face.refused,
            "rejected": dict(stats.rejected),
            "overrides_rejected": dict(stats.overrides_rejected),
            "qd_nominal_sources": dict(stats.qd_nominal_sources),
            "readback_latencies": len(latencies),
            "readback_latency_mean_s": float(np.mean(latencies)) if latencies else None,
            "readback_latency_min_s": min(latencies) if latencies else None,
            "readback_latency_max_s": max(latencies) if latencies else None,
            "qd_nominal_compared": self.truth.compared,
            "qd_nominal_low": self.truth.low,
            "qd_nominal_min_ratio": None if self.truth.compared == 0 else self.truth.min_ratio,
            "qd_nominal_min_ratio_t_s": self.truth.min_ratio_t_s,
            "qd_nominal_min_ratio_source": self.truth.min_ratio_source,
        }

    # -- the exchange's side (hrc_tools.sim.exchanges.base.ExchangeHost) --------------------------------------------

    def clocks(self, t_ns: int) -> Clocks:
        """Both clocks at simulated time ``t_ns``."""
        return self._clocks(t_ns)

    def push(self, t_ns: int, kind: str, data: Any = None) -> None:
        """Queue an event at ``t_ns`` (in the order pushed among events at the same time)."""
        self._order += 1
        heapq.heappush(self._queue, _Event(t_ns, self._order, kind, data))

    def written(self, value: float, t_ns: int) -> None:
        """The write of ``value`` was answered at ``t_ns``: the shell calls ``on_written`` and its writer is free."""
        self.core.on_written(value, self._clocks(t_ns))
        self._writer_busy = False
        if self._wake_pending:
            self._wake_pending = False
            self._write(t_ns)

    def reading(self, reading: ControllerReading, truth_qd_radps: FloatArray, t_ns: int) -> None:
        """A reading arrived: composed by the bridge's core, sent to the gateway; note the latency and the truth."""
        state = self.core.on_reading(reading)
        latency_s = self.core.take_latency_max()
        if latency_s is not None:
            self._latencies_s.append(latency_s)
        if state is None:
            return
        self.truth.add(state.qd_nominal, truth_qd_radps, t_ns / NS_PER_S, self._last_source())
        self._state_link.send((self._state_key, to_payload(state)), t_ns)

    # -- the writer -------------------------------------------------------------------------------------------------

    def _write(self, t_ns: int) -> None:
        """The bridge's writer at ``t_ns`` (its heartbeat, or woken by an override), as ``_write_loop`` does."""
        if self._writer_busy:
            self._wake_pending = True
            return
        value = self.core.next_write(self._clocks(t_ns))
        if value is None:
            return
        self._writer_busy = True
        self._exchange.write(value, t_ns)

    def _last_source(self) -> str:
        """The ``qd_nominal`` source of the joint state just composed (the one count that grew)."""
        sources = dict(self.core.stats().qd_nominal_sources)
        grown = [s for s, n in sources.items() if n > self._sources_seen.get(s, 0) and s in _SOURCES]
        self._sources_seen = sources
        return grown[0] if grown else "-"
