"""A fake vendor, ``loopback`` (as ros2_control's ``mock_components``): a controller showing at once what was written.

Registered by a test (``monkeypatch.setitem(VENDORS, "loopback", LOOPBACK)``, and for the simulated cell
``monkeypatch.setitem(EXCHANGES, "loopback", LoopbackExchange)``), it must be enough for the bridge core, the bridge's
program, the launcher and the simulated link: no other file names it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from hrc_devices.controllers.descriptor import SpeedInput, Vendor
from hrc_devices.controllers.vendor import ControllerReading, VendorError, VendorInterface
from hrc_runtime.clocks import Clocks, read_clocks
from hrc_tools.sim.exchanges.base import ExchangeHost, VendorLink

LOOPBACK_POLL_NS = 10_000_000
"""The simulated loopback link: a reading every 10 ms, each way instantaneous."""


class LoopbackInterfaceConfig(BaseModel):
    """The loopback vendor's interface config: the bridge's common fields and an address of its own."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["loopback"] = "loopback"
    address: str = "loop"
    watchdog_s: float = 0.1
    read_timeout_s: float = 0.1
    write_rate_hz: float = 100.0
    rise_time_s: float = 1.0


class LoopbackInterface:
    """A controller whose read-back shows the last value written, at joint positions that never change."""

    kind = "loopback"

    def __init__(self, n_joints: int, clock: Callable[[], Clocks] = read_clocks) -> None:
        self.n_joints = n_joints
        self.clock = clock
        self.connected = False
        self.fraction = 1.0
        self.writes: list[float] = []

    def connect(self) -> None:
        self.connected = True

    def write_speed_fraction(self, fraction: float) -> float:
        if not self.connected:
            raise VendorError("closed", "loopback: not connected")
        written = round(fraction, 3)  # a coarse input: never above what was asked
        written = written if written <= fraction else written - 0.001
        self.fraction = max(written, 0.0)
        self.writes.append(self.fraction)
        return self.fraction

    def read(self, timeout_s: float) -> ControllerReading:
        now = self.clock()
        zeros = (0.0,) * self.n_joints
        return ControllerReading(
            now.wall_ns, now.mono_ns, zeros, zeros, None, self.fraction, None, True, "loopback", None
        )

    def close(self) -> None:
        self.connected = False


def _interface(config: LoopbackInterfaceConfig, n_joints: int, environ: Mapping[str, str]) -> VendorInterface:
    return LoopbackInterface(n_joints)


def _environment(config: LoopbackInterfaceConfig, env: dict[str, str]) -> None:
    env.setdefault("HRC_LOOPBACK", config.address)


LOOPBACK = Vendor(
    kind="loopback",
    config=LoopbackInterfaceConfig,
    speed_input=SpeedInput(floor=0.01, step=0.001, stop="0: the loop stands", dither_step=0.001),
    interface=_interface,
    emulator_args=lambda config: ["--loopback", config.address],
    sim_interface={"kind": "loopback"},
    environment=_environment,
    poll_interval_s=lambda config: 0.01,
)


class LoopbackExchange:
    """The loopback vendor over the simulated link: a write reaches the controller's face at once and is answered at
    once; every 10 ms a reading of the controller's latest cycle (q and the speed input, no velocities)."""

    def __init__(self, interface: LoopbackInterfaceConfig, host: ExchangeHost, link: VendorLink | None) -> None:
        self._host = host
        host.face.value = 1.0

    def start(self, reader_phase_ns: int) -> None:
        self._host.push(reader_phase_ns % LOOPBACK_POLL_NS, "read")

    def write(self, value: float, t_ns: int) -> None:
        host = self._host
        host.face.apply(host.node, host.node.robot, value, host.clocks(t_ns))
        host.written(value, t_ns)

    def handle(self, kind: str, data: Any, t_ns: int) -> None:
        host = self._host
        host.push(t_ns + LOOPBACK_POLL_NS, "read")
        state = host.node.state if host.latest is None else host.latest.state
        q_rad, truth = host.node.trajectory.sample(state.tau_s)
        now = host.clocks(t_ns)
        running = state.mode == "running"
        reading = ControllerReading(
            now.wall_ns, now.mono_ns, tuple(float(q) for q in q_rad), None, None, host.face.value, None, running, "loop"
        )
        host.reading(reading, truth, t_ns)
