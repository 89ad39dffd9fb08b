"""ABB Externally Guided Motion (EGM) over UDP: the protocol-buffers wire format (:mod:`.wire`), the joint-mode
messages ``EgmRobot`` / ``EgmSensor`` of ``abb-robot-client``'s ``egm.proto`` (:mod:`.codec`), the PC's UDP server
(:mod:`.pc`) and the bridge's open vendor interface over it (:mod:`.interface`); the controller emulator serves the
controller's side (``controller_emu.egm_face``). Registered as an *open* vendor
(:data:`hrc_devices.controllers.registry.OPEN_VENDORS`): only for ``control = "open"``.

EGM is an *open* interface: the controller sends ``EgmRobot`` every 4 ms to the PC's UDP address, the PC answers
the sender with ``EgmSensor`` (joint references [deg], speed references [deg/s]) and the controller follows them.
"""

from __future__ import annotations

from hrc_contract.config import AbbEgmInterfaceConfig
from hrc_devices.controllers.abb_egm import codec, interface, pc, wire
from hrc_devices.controllers.abb_egm.interface import EgmInterface
from hrc_devices.controllers.descriptor import OpenVendor
from hrc_devices.controllers.vendor import OpenVendorInterface

__all__ = ["VENDOR", "codec", "interface", "pc", "wire"]

LOOPBACK_WHEN_ANY = "127.0.0.1"
"""Where the emulator sends its ``EgmRobot`` when the PC listens on every address (``0.0.0.0``)."""


def _interface(config: AbbEgmInterfaceConfig, n_joints: int) -> OpenVendorInterface:
    return EgmInterface(config.host, config.port, n_joints, config.controller_host)


def _emulator_args(config: AbbEgmInterfaceConfig) -> list[str]:
    host = LOOPBACK_WHEN_ANY if config.host in ("0.0.0.0", "") else config.host
    return ["--egm", f"{host}:{config.port}"]


VENDOR = OpenVendor(
    kind="abb_egm",
    config=AbbEgmInterfaceConfig,
    interface=_interface,
    emulator_args=_emulator_args,
    velocity_source="q differenced over the controller's feedBack.time (its own stamps), over at least half a cycle",
)
