"""ABB Externally Guided Motion (EGM) over UDP: the protocol-buffers wire format (:mod:`.wire`) and the joint-mode
messages ``EgmRobot`` / ``EgmSensor`` of ``abb-robot-client``'s ``egm.proto`` (:mod:`.codec`) and the PC's UDP server
(:mod:`.pc`); the controller emulator serves the controller's side (``controller_emu.egm_face``). Not a registered
bridge vendor yet: the bridge's vendor interface is a closed controller's speed input.

EGM is an *open* interface: the controller sends ``EgmRobot`` every 4 ms to the PC's UDP address, the PC answers
the sender with ``EgmSensor`` (joint references [deg], speed references [deg/s]) and the controller follows them.
"""

from __future__ import annotations

from hrc_devices.controllers.abb_egm import codec, pc, wire

__all__ = ["codec", "pc", "wire"]
