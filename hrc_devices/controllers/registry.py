"""The vendors by kind: the one place that lists them (as ``qpsolvers/solvers/__init__.py`` lists its solvers).

    vendor = VENDORS[robot.interface.kind]     # KeyError: the robot needs no bridge (``zenoh``)
    interface = vendor.interface(robot.interface, n_joints, os.environ)

Adding a vendor: its folder beside ``ur_rtde/`` with a ``VENDOR``, its config class in ``hrc_contract.config``, its
face in ``controller_emu`` (``controller_emu.faces.FACES``), and one line here and one there.
"""

from __future__ import annotations

from typing import Any

from hrc_devices.controllers import abb_rws, ur_rtde
from hrc_devices.controllers.descriptor import Vendor

__all__ = ["VENDORS", "bridged_kinds", "register_vendor"]

VENDORS: dict[str, Vendor[Any]] = {}
"""Every vendor a bridge can reach, by the cell file's interface ``kind``."""


def register_vendor(vendor: Vendor[Any]) -> None:
    """Add ``vendor`` (a test's fake one too); its kind replaces one of the same name."""
    VENDORS[vendor.kind] = vendor


def bridged_kinds() -> tuple[str, ...]:
    """The interface kinds reached through a bridge, in the order registered."""
    return tuple(VENDORS)


register_vendor(ur_rtde.VENDOR)
register_vendor(abb_rws.VENDOR)
