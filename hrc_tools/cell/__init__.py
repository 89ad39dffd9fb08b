"""``hrc-cell``: the whole cell on one machine (:mod:`hrc_tools.cell.launcher`), and the harness that starts and stops
the programs as processes (:mod:`hrc_tools.cell.procs`).
"""

__all__ = [
    "launcher",
    "procs",
]
