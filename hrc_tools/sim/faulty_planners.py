"""Planners that fail on purpose, for the simulated cell (``hrc-sweep --planner-fault``, the tests): the planner layer
may change productivity, never the bound (docs/planner.md). Each is a
:class:`gateway.planner_worker.PlannerBackend` made from the robots' planners, as the cell's default backend is."""

from __future__ import annotations

from collections.abc import Callable

from gateway.planner import JointPlanner, PlanOutcome, PlanRequest
from gateway.planner_worker import PlannerBackend, PlannerHealth, SimulatedPlanner
from hrc_contract.humans import NO_HUMANS


class IgnoresPeople(SimulatedPlanner):
    """Plans as if nobody were there: its paths go straight through where the people stand."""

    def submit(self, request: PlanRequest) -> bool:
        return super().submit(request._replace(humans=NO_HUMANS, clearance_m=0.0))


class NeverAnswers:
    """Takes every request and never answers (a hung planner that says it runs)."""

    def __init__(self, planners: dict[str, JointPlanner]) -> None:
        self.taken = 0

    def submit(self, request: PlanRequest) -> bool:
        self.taken += 1
        return True

    def poll(self) -> list[PlanOutcome]:
        return []

    def health(self) -> PlannerHealth:
        return PlannerHealth()  # it says it runs: the replanner finds out by the time-out

    def close(self) -> None:
        pass


FAULTY_PLANNERS: dict[str, Callable[[dict[str, JointPlanner]], PlannerBackend]] = {
    "through_the_person": IgnoresPeople,
    "silent": NeverAnswers,
}
"""The planner faults by name (``hrc-sweep --planner-fault NAME``)."""
