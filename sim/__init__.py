"""The whole cell on a simulated clock, in one process: for sweeps faster than real time.

- :func:`simulate` (``sim.cell``): controllers, trackers, gateway and the three links on one simulated
  clock, audited every controller cycle against the truth; returns a :class:`RunResult`.
- :class:`LinkFault`, :class:`LinkFaults` (``sim.links``): delay, jitter, loss and duplication per path.
- :func:`generate_case` (``sim.scenarios``): seeded random people, sensors and link faults.
- ``python -m sim.sweep`` / ``hrc-sweep`` (``sim.sweep``): the randomized sweep and its table.
"""

from sim.cell import EPOCH_NS, RunResult, simulate
from sim.links import LinkFault, LinkFaults
from sim.scenarios import SweepCase, generate_case

__all__ = ["EPOCH_NS", "LinkFault", "LinkFaults", "RunResult", "SweepCase", "generate_case", "simulate"]
