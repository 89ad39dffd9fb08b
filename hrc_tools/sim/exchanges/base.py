"""What a vendor's simulated exchange is and what it may ask of its bridge (:class:`hrc_tools.sim.bridged.SimBridge`).

An exchange models one vendor's side of the dedicated link on the cell's simulated clock: how a speed write reaches
the controller's face, and how the face's readings reach the bridge (a package pushed every output period, a poll of
requests on one connection ...). The bridge around it is the vendor-independent part: the bridge's core, its writer,
publishing joint states, the figures. One module per vendor in this folder, registered by kind in
:data:`hrc_tools.sim.exchanges.EXCHANGES`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from controller_bridge.bridge import Bridge
from controller_emu.node import ControllerNode, ControllerOutput
from hrc_contract.messages import Override, to_payload
from hrc_devices.controllers.vendor import ControllerReading
from hrc_runtime.clocks import Clocks

__all__ = ["Exchange", "ExchangeFactory", "ExchangeHost", "SimFace", "VendorLink"]

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class VendorLink:
    """The dedicated link between the bridge and the controller's vendor interface.

    Attributes:
        latency_s: one-way latency, each way [s]: a pushed package or a written value takes it once; a request
            takes it twice (request, answer).
    """

    latency_s: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.latency_s) and self.latency_s >= 0.0):
            raise ValueError(f"latency_s = {self.latency_s}; allowed: a finite value >= 0 s")


@dataclass
class SimFace:
    """What the controller's vendor face remembers: the value in force and the overrides it made of writes."""

    value: float
    """The speed input last accepted (a controller starts with its own: UR's slider 0, an IRC5's ratio 100 %)."""
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


class ExchangeHost(Protocol):
    """What an exchange may use of its bridge."""

    core: Bridge
    node: ControllerNode
    face: SimFace
    latest: ControllerOutput | None
    """The controller's latest cycle (None before the first)."""
    latest_value: float
    """The face's value in force at the latest cycle."""

    def clocks(self, t_ns: int) -> Clocks: ...
    def push(self, t_ns: int, kind: str, data: Any = None) -> None:
        """Queue an event of the exchange's own ``kind`` (handed back to :meth:`Exchange.handle` at ``t_ns``)."""

    def written(self, value: float, t_ns: int) -> None:
        """The controller answered the write of ``value`` at ``t_ns``: the bridge's writer is free again."""

    def reading(self, reading: ControllerReading, truth_qd_radps: FloatArray, t_ns: int) -> None:
        """A reading reached the bridge at ``t_ns`` (``truth_qd_radps``: the program's velocity at that point)."""


class Exchange(Protocol):
    """One vendor's exchange over the dedicated link (see the module docstring)."""

    def start(self, reader_phase_ns: int) -> None:
        """Queue the first reading: its phase drawn by the caller from the run's seed [ns]."""

    def write(self, value: float, t_ns: int) -> None:
        """The bridge's writer sends ``value`` at ``t_ns``; call :meth:`ExchangeHost.written` when it is answered."""

    def handle(self, kind: str, data: Any, t_ns: int) -> None:
        """An event this exchange queued is due."""


ExchangeFactory = Callable[[Any, ExchangeHost, VendorLink | None], Exchange]
"""``(interface config, host, link or None for the vendor's default)`` → the exchange."""
