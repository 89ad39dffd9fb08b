"""The vendors by kind: the one place that lists them (as ``qpsolvers/solvers/__init__.py`` lists its solvers).

    vendor = VENDORS[robot.interface.kind]     # a closed controller's; KeyError: not one (``zenoh``, an open one's)
    interface = vendor.interface(robot.interface, n_joints, os.environ)
    open_vendor = OPEN_VENDORS[robot.interface.kind]   # an open controller's (joint references): ABB EGM
    interface = open_vendor.interface(robot.interface, n_joints)

Two registries, because the two kinds of controller take different inputs: :data:`VENDORS` lists the closed
controllers' speed inputs (what ``hrc-sweep --interface`` and the simulated bridge offer a closed cell),
:data:`OPEN_VENDORS` the open controllers' joint references (only for ``control = "open"``; the cell file refuses
the other pairings).

Adding a vendor: its folder beside ``ur_rtde/`` with a ``VENDOR``, its config class in ``hrc_contract.config``, its
face in ``controller_emu`` (``controller_emu.faces.FACES``), and one line here and one there.
"""

from __future__ import annotations

from typing import Any

from hrc_devices.controllers import abb_egm, abb_rws, ur_rtde
from hrc_devices.controllers.descriptor import OpenVendor, Vendor

__all__ = ["OPEN_VENDORS", "VENDORS", "bridged_kinds", "open_kinds", "register_open_vendor", "register_vendor"]

VENDORS: dict[str, Vendor[Any]] = {}
"""Every closed controller's vendor a bridge can reach, by the cell file's interface ``kind``."""

OPEN_VENDORS: dict[str, OpenVendor[Any]] = {}
"""Every open controller's vendor a bridge can reach, by the cell file's interface ``kind``."""


def register_vendor(vendor: Vendor[Any]) -> None:
    """Add ``vendor`` (a test's fake one too); its kind replaces one of the same name."""
    VENDORS[vendor.kind] = vendor


def bridged_kinds() -> tuple[str, ...]:
    """The closed controllers' interface kinds reached through a bridge, in the order registered."""
    return tuple(VENDORS)


def register_open_vendor(vendor: OpenVendor[Any]) -> None:
    """Add an open controller's ``vendor``; its kind replaces one of the same name."""
    OPEN_VENDORS[vendor.kind] = vendor


def open_kinds() -> tuple[str, ...]:
    """The open controllers' interface kinds reached through a bridge, in the order registered."""
    return tuple(OPEN_VENDORS)


register_vendor(ur_rtde.VENDOR)
register_vendor(abb_rws.VENDOR)
register_open_vendor(abb_egm.VENDOR)
