"""Known status documents (``hrc_contract.status_models``) for the tests that feed or parse a gateway status.

One module, so that the REST tests, the fuzzer, the auditor's tests and the contract tests all use documents
that the models accept, and a change of the models shows up in one place.
"""

from __future__ import annotations

from typing import Any

from hrc_contract.status_models import (
    ClosestPair,
    DelayBudgetStatus,
    Fault,
    GatewayStatus,
    InputCounters,
    LoopStatus,
    RobotStatus,
    ThresholdsStatus,
)

STAMP_NS = 1_790_000_000_000_000_000

DELAY = DelayBudgetStatus(
    t_reaction_s=0.04,
    human_age_s=0.03,
    joint_state_age_s=0.004,
    override_path_s=0.012,
    controller_cycle_s=0.004,
    gateway_period_s=0.004,
)
"""A delay budget of the default cell: 94 ms in all."""

THRESHOLDS = ThresholdsStatus(protective_m=1.0484, resume_m=1.0984, reduce_m=1.9, monitored_m=2.4)

STALE_TRACKER = Fault(code="tracker_stale", reason="tracker 'front' data is 0.300 s old (limit 0.2 s)")


def robot_status(faults: list[Fault] | None = None, delta: float = 1.0, **fields: Any) -> RobotStatus:
    """One robot's entry: autonomous at ``delta`` without faults, in a safety exception at δ = 0 with them.

    ``fields`` replace any other field (e.g. ``zone="reduced_speed"``, ``min_distance_m=1.2``).
    """
    values: dict[str, Any] = {
        "zone": "safety_exception" if faults else "autonomous",
        "delta": 0.0 if faults else delta,
        "delta_bound": 0.0 if faults else delta,
        "min_distance_m": None,
        "closest": None,
        "t_delay_s": 0.098,
        "delay_budget_s": DELAY,
        "clearance_m": 1.0484,
        "thresholds_m": THRESHOLDS,
        "override_seq": 17,
        "data_age_s": {"joint_state": 0.004, "tracker/front": 0.03},
        "faults": faults or [],
        "controller_mode": "running",
        "delta_applied": 0.0 if faults else delta,
        "replan_request": False,
    }
    values.update(fields)
    return RobotStatus(**values)


def near_robot_status(delta: float = 0.62) -> RobotStatus:
    """A robot slowed down by a person 1.23 m away (hand to tool)."""
    return robot_status(
        delta=delta,
        zone="reduced_speed",
        min_distance_m=1.2346,
        closest=ClosestPair(human="front/h1", capsule="hand_r", link="tool"),
    )


def loop_status(cycles: int = 1000) -> LoopStatus:
    """The loop block of a gateway that has kept its period (250 Hz, no event cycles)."""
    return LoopStatus(
        rate_hz=250.0,
        cycles=cycles,
        tick_cycles=cycles,
        event_cycles=0,
        wakes_served_by_tick=0,
        event_driven=True,
        missed_cycles=0,
        last_lateness_s=0.00005,
        compute_max_s=0.0002,
        event_seqs=[],
    )


def gateway_status(stamp_ns: int = STAMP_NS, **robots: RobotStatus) -> GatewayStatus:
    """A status document of cell ``demo`` with the given robots (default: one autonomous ``ur5``)."""
    return GatewayStatus(
        cell="demo",
        stamp_ns=stamp_ns,
        robots=robots or {"ur5": robot_status()},
        humans=[],
        inputs=InputCounters(received={"robot/ur5": 250, "tracker/front": 30}, rejected={}),
        loop=loop_status(),
    )
