"""The simulated cell with a controller bridge in the path: the vendor's face of the emulated controller, its
dedicated link and the bridge's own pure core, on the cell's one simulated clock.

    override link → bridge.on_override → next_write → (write latency) → the face → the controller's override
    controller cycle → the face's latest state → (output period / poll, read latency) → ControllerReading
        → bridge.on_reading → joint state → state link → gateway

What is real code and what is modelled:

- the bridge: :class:`controller_bridge.bridge.Bridge` with the settings ``hrc-controller-bridge`` derives from the
  cell (:func:`controller_bridge.main.bridge_settings`), driven as its shell drives it (a writer at the heartbeat
  rate, woken at once by every override; a reader per output package or per poll);
- the readings: built from the emulated controller's state by the faces' own functions and checked by the bridge's
  own parsers. UR (:func:`controller_emu.rtde_outputs.output_values`, then
  :func:`hrc_devices.controllers.ur_rtde.client.reading_from_values`): on the face's 2 ms control ticks, every output
  period (2 ms at 500 Hz, 8 ms at 125 Hz), a package of the controller's latest cycle if it is new (one per cycle),
  stamped with the cycle's time, so ``target_speed_fraction`` shows a slider write in the first package of the first
  cycle after it and ``speed_scaling × target_speed_fraction`` the applied override while it ramps up. ABB (the RWS
  documents of :mod:`controller_emu.rws_face` parsed by :mod:`hrc_devices.controllers.abb_rws.client`): a poll every
  ``poll_rate_hz`` of three requests in sequence (speed ratio, execution state, joint target: q printed ``.7g`` in
  degrees), no velocities (the bridge differentiates q);
- the writes: UR's slider is a double written as given (one package, no answer); ABB's speed ratio an integer
  percent rounded down (:func:`hrc_devices.controllers.abb_rws.client.speed_ratio_pct`), a POST whose 204 returns after
  a round trip. Reads and writes of ABB share one keep-alive HTTP connection (the interface holds a lock), so a write
  waits for the request in progress and a poll for a write. Each face turns an accepted write into an override of the
  controller node stamped with the controller's clock (stamps strictly increasing, a seq per face), as
  :class:`controller_emu.rtde_face.RtdeFace` and :class:`controller_emu.rws_face.RwsFace` do;
- the vendor link (a dedicated cable next to the controller, :class:`VendorLink`): a fixed one-way latency each way,
  no loss. The Zenoh links on either side of the bridge are the cell's (``LinkFaults``), unchanged.

The gateway therefore learns the whole override path from the bridge's echo (``override_seq`` advances only when
the read-back shows the written value): Zenoh, the bridge's writer, the write latency, the output period or the
poll, and the read latency. Everything is deterministic: the phases of the writer and the reader are drawn from
the run's seed by the caller.
"""

from __future__ import annotations

import heapq
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from controller_bridge.bridge import Bridge, BridgeSettings
from controller_emu.node import ControllerNode, ControllerOutput
from controller_emu.rtde_face import CONTROL_PERIOD_S
from controller_emu.rtde_outputs import output_values
from controller_emu.rws_face import execution_document, jointtarget_document, speedratio_document
from hrc_contract.config import AbbRwsInterfaceConfig, UrRtdeInterfaceConfig
from hrc_contract.messages import JointState, Override, to_payload
from hrc_devices.controllers.abb_rws.client import (
    parse_execution_state,
    parse_joint_target,
    parse_speed_ratio,
    reading_of,
    speed_ratio_pct,
)
from hrc_devices.controllers.registry import VENDORS, bridged_kinds
from hrc_devices.controllers.ur_rtde.client import reading_from_values
from hrc_devices.controllers.vendor import VendorError
from hrc_runtime.clocks import Clocks
from hrc_tools.sim.links import NS_PER_S, SimLink

INTERFACES = ("zenoh", *bridged_kinds())
"""The ``--interface`` choices: the emulator's own Zenoh face (no bridge), or a bridge to the vendor's face."""

BridgedInterface = UrRtdeInterfaceConfig | AbbRwsInterfaceConfig
Payload = tuple[str, bytes]
FloatArray = npt.NDArray[np.float64]

_SOURCES = ("program_model", "target_qd", "qd", "velocity_limits")
"""The ``qd_nominal`` sources of :func:`controller_bridge.bridge.nominal_velocity` (``model_miss`` is not one)."""

_RWS_BASE = "http://controller"
"""The base URL of the simulated RWS documents (their links are not followed)."""

TRUTH_MIN_SPEED_RADPS = 0.05
"""``qd_nominal`` is compared with the program's where the programmed joint speed (norm) is at least this [rad/s]."""

QD_NOMINAL_LOW_RATIO = 0.98
"""A reported programmed speed below this fraction of the true one is counted as low (2 %: the gateway's ratio)."""


@dataclass(frozen=True)
class VendorLink:
    """The dedicated link between the bridge and the controller's vendor interface.

    Attributes:
        latency_s: one-way latency, each way [s]: an RTDE package or slider write takes it once; an RWS request
            takes it twice (request, answer).
    """

    latency_s: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.latency_s) and self.latency_s >= 0.0):
            raise ValueError(f"latency_s = {self.latency_s}; allowed: a finite value >= 0 s")


DEFAULT_VENDOR_LINKS = {"ur_rtde": VendorLink(0.0005), "abb_rws": VendorLink(0.002)}
"""Assumed, not measured: UR 0.5 ms each way (a dedicated Ethernet hop); ABB 2 ms each way, so an RWS request takes
4 ms (RWS's latency is not published and must be measured on the controller; a loaded IRC5 may be much slower)."""


def default_interface(kind: str) -> dict[str, Any]:
    """The cell file's ``[robots.<name>.interface]`` table for ``--interface KIND`` (the shipped cells' values)."""
    if kind == "zenoh":
        return {"kind": "zenoh"}
    if kind not in VENDORS:
        raise ValueError(f"interface {kind!r}; allowed: zenoh, {', '.join(bridged_kinds())}")
    return dict(VENDORS[kind].sim_interface)


# -- the faces' write side -----------------------------------------------------------------------------------------


@dataclass
class _Face:
    """What the controller's vendor face remembers: the value in force and the overrides it made of writes."""

    value: float
    """UR: the slider last accepted; ABB: the speed ratio / 100 (an IRC5 starts at 100 %)."""
    seq: int = 0
    last_stamp_ns: int = -1
    writes: int = 0
    refused: int = 0

    def apply(self, node: ControllerNode, robot: str, value: float, now: Clocks) -> None:
        """A write arrived: the node's override (stamps strictly increasing, seq per face), as the faces do."""
        stamp_ns = max(now.wall_ns, self.last_stamp_ns + 1)
        message = Override(robot=robot, seq=self.seq, stamp_ns=stamp_ns, delta=value)
        reason = node.on_override(to_payload(message), now)
        self.seq += 1
        if reason is not None:
            self.refused += 1
            return
        self.last_stamp_ns = stamp_ns
        self.value = value
        self.writes += 1


# -- the bridged path -----------------------------------------------------------------------------------------------

EventKind = Literal["writer", "apply", "output", "package", "poll", "serve", "reply"]


@dataclass(frozen=True, order=True)
class _Event:
    t_ns: int
    order: int
    kind: EventKind = field(compare=False)
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
        interface: BridgedInterface,
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
        self._override_link = override_link
        self._state_link = state_link
        self._state_key = state_key
        self._clocks = clocks
        self._latency_ns = round((vendor or DEFAULT_VENDOR_LINKS[self.kind]).latency_s * NS_PER_S)
        self._heartbeat_ns = round(settings.heartbeat_s * NS_PER_S)
        if isinstance(interface, UrRtdeInterfaceConfig):
            tick_ns = round(CONTROL_PERIOD_S * NS_PER_S)
            self._read_period_ns = max(1, round(1.0 / (interface.frequency_hz * CONTROL_PERIOD_S))) * tick_ns
            reader_first_ns = (phase_ns[1] // tick_ns) * tick_ns
            self._face = _Face(0.0)
        else:
            self._read_period_ns = round(NS_PER_S / interface.poll_rate_hz)
            reader_first_ns = phase_ns[1]
            self._face = _Face(1.0)
        self._latest: ControllerOutput | None = None
        self._latest_slider = self._face.value  # UR: the slider in force at the latest cycle
        self._sent_cycle: ControllerOutput | None = None  # UR: the cycle the last package carried
        self._queue: list[_Event] = []
        self._order = 0
        self._writer_busy = False  # ABB: the writer waits for its POST's answer
        self._wake_pending = False
        self._connection_free_ns = 0  # ABB: the one HTTP connection is busy until then
        self._poll: dict[str, Any] = {}
        self._latencies_s: list[float] = []
        self.truth = _Truth()
        self._sources_seen: dict[str, int] = {}
        self._push(phase_ns[0] % max(self._heartbeat_ns, 1), "writer")
        self._push(reader_first_ns % max(self._read_period_ns, 1), "poll" if self.kind == "abb_rws" else "output")

    # -- the cell's side ------------------------------------------------------------------------------------------

    def on_cycle(self, output: ControllerOutput) -> None:
        """The controller's latest cycle (the face serves it until the next one), with the slider then in force."""
        self._latest = output
        self._latest_slider = self._face.value

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
            self._handle(event)

    def summary(self) -> dict[str, Any]:
        """The bridge's figures for the run's result (JSON-ready, deterministic)."""
        stats = self.core.stats()
        latencies = self._latencies_s
        return {
            "interface": self.kind,
            "readings": stats.readings,
            "published": stats.published,
            "writes": stats.writes,
            "face_writes": self._face.writes,
            "face_refused": self._face.refused,
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

    # -- events -------------------------------------------------------------------------------------------------

    def _push(self, t_ns: int, kind: EventKind, data: Any = None) -> None:
        self._order += 1
        heapq.heappush(self._queue, _Event(t_ns, self._order, kind, data))

    def _handle(self, event: _Event) -> None:
        t_ns = event.t_ns
        if event.kind == "writer":
            self._write(t_ns)
            self._push(t_ns + self._heartbeat_ns, "writer")
        elif event.kind == "apply":
            self._face.apply(self.node, self.node.robot, event.data, self._clocks(t_ns))
        elif event.kind == "output":
            self._output(t_ns)
            self._push(t_ns + self._read_period_ns, "output")
        elif event.kind == "package":
            reading, truth = event.data
            self._read(reading, truth, t_ns)
        elif event.kind == "poll":
            self._poll = {"due_ns": t_ns + self._read_period_ns}
            self._request("ratio", t_ns)
        elif event.kind == "serve":
            self._serve(event.data, t_ns)
        else:
            self._reply(event.data, t_ns)

    def _write(self, t_ns: int) -> None:
        """The bridge's writer at ``t_ns`` (its heartbeat, or woken by an override), as ``_write_loop`` does."""
        if self._writer_busy:
            self._wake_pending = True
            return
        value = self.core.next_write(self._clocks(t_ns))
        if value is None:
            return
        if self.kind == "ur_rtde":  # a data package: no answer, written as given
            self.core.on_written(value, self._clocks(t_ns))
            self._push(t_ns + self._latency_ns, "apply", value)
            return
        self._writer_busy = True
        self._request("write", t_ns, speed_ratio_pct(value) / 100.0)

    # -- UR: output packages --------------------------------------------------------------------------------------

    def _output(self, t_ns: int) -> None:
        """An output tick: the package of the latest controller cycle, if new, on its way to the bridge."""
        latest = self._latest
        if latest is None or latest is self._sent_cycle:
            return
        self._sent_cycle = latest
        values = dict(output_values(latest, self._latest_slider, latest.cycle_mono_ns / NS_PER_S))
        truth = self.node.trajectory.sample(latest.state.tau_s)[1]
        self._push(t_ns + self._latency_ns, "package", (values, truth))

    # -- ABB: requests on one connection ---------------------------------------------------------------------------

    def _request(self, what: str, want_ns: int, value: float | None = None) -> None:
        """One RWS request: it waits for the connection, is served one latency later and answered one after that."""
        start_ns = max(want_ns, self._connection_free_ns)
        self._connection_free_ns = start_ns + 2 * self._latency_ns
        self._push(start_ns + self._latency_ns, "serve", (what, value))
        self._push(start_ns + 2 * self._latency_ns, "reply", (what, value))

    def _serve(self, request: tuple[str, float | None], t_ns: int) -> None:
        """The controller answers a request with its state at ``t_ns`` (a write takes effect now)."""
        what, value = request
        if what == "write":
            self._face.apply(self.node, self.node.robot, float(value or 0.0), self._clocks(t_ns))
            return
        state = self.node.state if self._latest is None else self._latest.state
        if what == "ratio":
            document = speedratio_document(_RWS_BASE, round(self._face.value * 100))
        elif what == "execution":
            document = execution_document(_RWS_BASE, state.mode)
        else:
            q_rad, truth = self.node.trajectory.sample(state.tau_s)
            self._poll["truth"] = truth
            document = jointtarget_document(_RWS_BASE, tuple(float(q) for q in q_rad))
        self._poll[what] = json.dumps(document).encode()

    def _reply(self, request: tuple[str, float | None], t_ns: int) -> None:
        what, value = request
        if what == "write":  # the 204: the shell calls on_written now, and its writer is free again
            self.core.on_written(float(value or 0.0), self._clocks(t_ns))
            self._writer_busy = False
            if self._wake_pending:
                self._wake_pending = False
                self._write(t_ns)
            return
        following = {"ratio": "execution", "execution": "jointtarget"}
        if what in following:
            self._request(following[what], t_ns)
            return
        poll = self._poll
        self._push(max(poll["due_ns"], t_ns), "poll")
        try:
            ratio_pct = parse_speed_ratio(poll["ratio"])
            execution = parse_execution_state(poll["execution"])
            q_rad = parse_joint_target(poll["jointtarget"], self.node.trajectory.n_joints)
        except VendorError as exc:
            self.core.count_rejected(exc.reason)
            return
        reading = reading_of(ratio_pct, execution, q_rad, self._clocks(t_ns))
        self._publish(self.core.on_reading(reading), poll["truth"], t_ns)

    # -- readings ------------------------------------------------------------------------------------------------

    def _read(self, values: dict[str, object], truth: FloatArray, t_ns: int) -> None:
        """A UR output package arrived: checked by the bridge's RTDE parser, composed by its core."""
        try:
            reading = reading_from_values(values, self._clocks(t_ns))
        except VendorError as exc:
            self.core.count_rejected(exc.reason)
            return
        self._publish(self.core.on_reading(reading), truth, t_ns)

    def _publish(self, state: JointState | None, truth: FloatArray, t_ns: int) -> None:
        """Send the joint state on the link to the gateway; note the read-back latency and the truth."""
        latency_s = self.core.take_latency_max()
        if latency_s is not None:
            self._latencies_s.append(latency_s)
        if state is None:
            return
        self.truth.add(state.qd_nominal, truth, t_ns / NS_PER_S, self._last_source())
        self._state_link.send((self._state_key, to_payload(state)), t_ns)

    def _last_source(self) -> str:
        """The ``qd_nominal`` source of the joint state just composed (the one count that grew)."""
        sources = dict(self.core.stats().qd_nominal_sources)
        grown = [s for s, n in sources.items() if n > self._sources_seen.get(s, 0) and s in _SOURCES]
        self._sources_seen = sources
        return grown[0] if grown else "-"
