"""Universal Robots RTDE over the simulated link: output packages pushed, the speed slider written as given.

On the face's 2 ms control ticks, every output period (2 ms at 500 Hz, 8 ms at 125 Hz), a package of the controller's
latest cycle if it is new (one per cycle), stamped with the cycle's time, built by the face's own function
(:func:`controller_emu.rtde_outputs.output_values`) and checked by the bridge's own parser
(:func:`hrc_devices.controllers.ur_rtde.client.reading_from_values`): ``target_speed_fraction`` shows a slider write
in the first package of the first cycle after it, and ``speed_scaling × target_speed_fraction`` the applied override
while it ramps up. A slider write is a data package: no answer, written as given, applied one latency later.
"""

from __future__ import annotations

from typing import Any

from controller_emu.rtde_face import CONTROL_PERIOD_S
from controller_emu.rtde_outputs import output_values
from hrc_contract.config import UrRtdeInterfaceConfig
from hrc_devices.controllers.ur_rtde.client import reading_from_values
from hrc_devices.controllers.vendor import VendorError
from hrc_tools.sim.exchanges.base import ExchangeHost, VendorLink
from hrc_tools.sim.links import NS_PER_S

__all__ = ["DEFAULT_LINK", "RtdeExchange"]

DEFAULT_LINK = VendorLink(0.0005)
"""Assumed, not measured: 0.5 ms each way (a dedicated Ethernet hop)."""


class RtdeExchange:
    """RTDE between a bridge and the emulated controller's face (the module docstring)."""

    def __init__(self, interface: UrRtdeInterfaceConfig, host: ExchangeHost, link: VendorLink | None) -> None:
        self._host = host
        self._latency_ns = round((link or DEFAULT_LINK).latency_s * NS_PER_S)
        self._tick_ns = round(CONTROL_PERIOD_S * NS_PER_S)
        self._period_ns = max(1, round(1.0 / (interface.frequency_hz * CONTROL_PERIOD_S))) * self._tick_ns
        self._sent_cycle: object | None = None  # the cycle the last package carried
        host.face.value = 0.0  # the slider a controller starts with, until the bridge writes one

    def start(self, reader_phase_ns: int) -> None:
        first_ns = (reader_phase_ns // self._tick_ns) * self._tick_ns
        self._host.push(first_ns % max(self._period_ns, 1), "output")

    def write(self, value: float, t_ns: int) -> None:
        self._host.written(value, t_ns)
        self._host.push(t_ns + self._latency_ns, "apply", value)

    def handle(self, kind: str, data: Any, t_ns: int) -> None:
        host = self._host
        if kind == "apply":
            host.face.apply(host.node, host.node.robot, data, host.clocks(t_ns))
        elif kind == "output":
            self._output(t_ns)
            host.push(t_ns + self._period_ns, "output")
        else:  # a package arrived: checked by the bridge's RTDE parser
            values, truth = data
            try:
                reading = reading_from_values(values, host.clocks(t_ns))
            except VendorError as exc:
                host.core.count_rejected(exc.reason)
                return
            host.reading(reading, truth, t_ns)

    def _output(self, t_ns: int) -> None:
        """An output tick: the package of the latest controller cycle, if new, on its way to the bridge."""
        latest = self._host.latest
        if latest is None or latest is self._sent_cycle:
            return
        self._sent_cycle = latest
        values = dict(output_values(latest, self._host.latest_value, latest.cycle_mono_ns / NS_PER_S))
        truth = self._host.node.trajectory.sample(latest.state.tau_s)[1]
        self._host.push(t_ns + self._latency_ns, "package", (values, truth))
