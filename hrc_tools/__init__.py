"""The tools around the cell, one subpackage per command: audit, sim (the one case runner), record (+ replay),
faultinject, cell (the launcher and the process harness), cert, router, reset_track.

The top layer: may import the programs; no program imports it.
"""

__all__ = [
    "audit",
    "cell",
    "cert",
    "faultinject",
    "record",
    "reset_track",
    "router",
    "sim",
]
