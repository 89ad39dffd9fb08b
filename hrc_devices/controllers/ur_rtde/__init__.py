"""Universal Robots over RTDE: the wire codec (:mod:`.codec`) and the bridge's client (:mod:`.client`); the
controller emulator serves the face (``controller_emu.rtde_face``)."""

from __future__ import annotations

from collections.abc import Mapping

from hrc_contract.config import UrRtdeInterfaceConfig
from hrc_devices.controllers.descriptor import SpeedInput, Vendor
from hrc_devices.controllers.ur_rtde.client import UrRtdeInterface
from hrc_devices.controllers.vendor import VendorInterface

__all__ = ["VENDOR", "client", "codec"]

SPEED_INPUT = SpeedInput(
    floor=0.01,
    step=None,
    stop="speed slider 0.0: the robot stands still (some versions then end in a protective stop, the safe "
    "side); the ROS 2 driver refuses values below 0.01, and anything between is a crawl, not a stop",
    dither_step=1e-4,
)


def _interface(config: UrRtdeInterfaceConfig, n_joints: int, environ: Mapping[str, str]) -> VendorInterface:
    return UrRtdeInterface(config.host, frequency_hz=float(config.frequency_hz))


def _emulator_args(config: UrRtdeInterfaceConfig) -> list[str]:
    return ["--rtde", config.host]


VENDOR = Vendor(
    kind="ur_rtde",
    config=UrRtdeInterfaceConfig,
    speed_input=SPEED_INPUT,
    interface=_interface,
    emulator_args=_emulator_args,
    sim_interface={"kind": "ur_rtde", "host": "127.0.0.2"},
)
