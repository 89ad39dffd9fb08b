"""The whole cell on a simulated clock, in one process: for sweeps faster than real time.

- :func:`simulate` (``hrc_tools.sim.cell``): controllers, trackers, gateway and the three links on one simulated
  clock, audited every controller cycle against the truth; returns a :class:`RunResult`.
- :class:`LinkFault`, :class:`LinkFaults` (``hrc_tools.sim.links``): delay, jitter, loss and duplication per path.
- :func:`generate_case` (``hrc_tools.sim.scenarios``): seeded random people, sensors and link faults.
- ``hrc_tools.sim.faulty_planners``: planners that answer through the person or never (``hrc-sweep --planner-fault``).
- ``python -m hrc_tools.sim`` / ``hrc-sweep`` (``hrc_tools.sim.sweep``): the randomized sweep and its table.
"""

from hrc_tools.sim.cell import EPOCH_NS, RunResult, simulate
from hrc_tools.sim.links import LinkFault, LinkFaults
from hrc_tools.sim.scenarios import SweepCase, generate_case

__all__ = [
    "EPOCH_NS",
    "LinkFault",
    "LinkFaults",
    "RunResult",
    "SweepCase",
    "bridged",
    "cell",
    "exchanges",
    "faulty_planners",
    "generate_case",
    "human_speed",
    "links",
    "ros2_adapter",
    "scenarios",
    "simulate",
    "sweep",
    "truth",
]
