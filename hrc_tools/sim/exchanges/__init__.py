"""The vendors' exchanges over the simulated link, by the cell file's interface ``kind`` (one module per vendor, as
:data:`hrc_devices.controllers.registry.VENDORS` lists the vendors):

    exchange = EXCHANGES[interface.kind](interface, bridge, link)

Adding a vendor to the simulated cell: its module here with an exchange (:class:`.base.Exchange`) and one line below.
"""

from __future__ import annotations

from hrc_tools.sim.exchanges import abb_rws, ur_rtde
from hrc_tools.sim.exchanges.base import ExchangeFactory

__all__ = ["EXCHANGES", "abb_rws", "base", "register_exchange", "ur_rtde"]

EXCHANGES: dict[str, ExchangeFactory] = {}
"""Every vendor the simulated cell can put behind a bridge, by interface kind."""


def register_exchange(kind: str, factory: ExchangeFactory) -> None:
    """Add a vendor's exchange (a test's fake one too); its kind replaces one of the same name."""
    EXCHANGES[kind] = factory


register_exchange("ur_rtde", ur_rtde.RtdeExchange)
register_exchange("abb_rws", abb_rws.RwsExchange)
