"""The status document (``GET /api/v1/status`` and ``hrc/<cell>/gateway/status``) and the effective config,
built through the contract's models (:mod:`hrc_common.status_models`).

Every builder reads the attributes it shows (never ``_asdict()``), so that a field added to a decision does
not change the document until the model has it too. No builder raises for a decision the core can take:
the loop publishes the status between overrides, and a status must never stop the overrides. A number that
is not finite (absurd input) is shown as null where the model allows it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

from gateway.core import RobotDecision
from hrc_common.config import CellConfig
from hrc_common.service import RateLoop
from hrc_common.status_models import (
    ClosestPair,
    DelayBudgetStatus,
    EffectiveConfig,
    EffectiveRobot,
    Fault,
    GatewayStatus,
    HumanSeen,
    InputCounters,
    LoopStatus,
    RobotStatus,
    ThresholdsStatus,
)

DIGITS = 4
"""Distances, times and δ are rounded to this many decimals (0.1 mm, 0.1 ms)."""
LOOP_DIGITS = 6
"""The loop's timing (lateness, compute time) is rounded to this many decimals (1 µs)."""


def _rounded(x: float, digits: int = DIGITS) -> float:
    return round(x, digits)


def _finite_or_none(x: float | None, digits: int = DIGITS) -> float | None:
    return None if x is None or not math.isfinite(x) else round(x, digits)


def _unit(x: float) -> float:
    """δ-like values in [0, 1]; not a number counts as 0 (as the core treats a nan bound)."""
    return 0.0 if x != x else round(min(max(x, 0.0), 1.0), DIGITS)


def robot_status(decision: RobotDecision, override_seq: int) -> RobotStatus:
    """One robot's entry; ``override_seq`` is the seq of the override this decision was sent with."""
    closest = decision.closest
    delay = decision.delay
    thresholds = decision.thresholds
    return RobotStatus(
        zone=decision.zone.value,
        delta=_unit(decision.delta),
        delta_bound=_unit(decision.delta_bound),
        min_distance_m=_finite_or_none(decision.min_distance_m),
        closest=None
        if closest is None
        else ClosestPair(human=closest.human, capsule=closest.capsule, link=closest.link),
        t_delay_s=_rounded(delay.total_s),
        delay_budget_s=DelayBudgetStatus(
            t_reaction_s=_rounded(delay.t_reaction_s),
            human_age_s=_rounded(delay.human_age_s),
            joint_state_age_s=_rounded(delay.joint_state_age_s),
            override_path_s=_rounded(delay.override_path_s),
            controller_cycle_s=_rounded(delay.controller_cycle_s),
            gateway_period_s=_rounded(delay.gateway_period_s),
        ),
        clearance_m=_rounded(decision.clearance_m),
        thresholds_m=ThresholdsStatus(
            protective_m=_rounded(thresholds.protective_m),
            resume_m=_rounded(thresholds.resume_m),
            reduce_m=_finite_or_none(thresholds.reduce_m),
            monitored_m=_finite_or_none(thresholds.monitored_m),
        ),
        override_seq=override_seq,
        data_age_s={k: _finite_or_none(v) for k, v in decision.data_age_s.items()},
        faults=[Fault(code=f.code, reason=f.reason) for f in decision.faults],
        controller_mode=decision.controller_mode,
        delta_applied=None if decision.delta_applied is None else _unit(decision.delta_applied),
        replan_request=decision.replan_request,
    )


def status_document(
    cell: str,
    stamp_ns: int,
    robots: dict[str, RobotStatus],
    humans: Sequence[HumanSeen | Mapping[str, Any]],
    rejected: dict[str, dict[str, int]],
    received: dict[str, int],
    loop: LoopStatus,
) -> GatewayStatus:
    """The whole document; serialise it with ``doc.model_dump_json()`` (the same bytes on Zenoh and HTTP).

    Args:
        humans: :class:`HumanSeen` entries, or their fields as mappings (validated here).
    """
    return GatewayStatus(
        cell=cell,
        stamp_ns=stamp_ns,
        robots=robots,
        humans=list(humans),
        inputs=InputCounters(received=received, rejected=rejected),
        loop=loop,
    )


def loop_status(rate: RateLoop, compute_max_s: float, event_driven: bool, event_seqs: list[int]) -> LoopStatus:
    """The ``loop`` block: how the gateway's own loop keeps its period.

    Args:
        rate: the loop's timing: ``tick_cycles`` (fixed-rate ticks), ``event_cycles`` (decisions taken
            when a tracker frame arrived, between ticks), ``wakes_served_by_tick`` (frames left to a
            tick due within ``event_guard_s``), ``missed_cycles`` (ticks skipped after an
            overrun; event cycles are never missed or late), ``last_lateness_s`` (of the last tick);
            ``cycles`` in the block counts all decisions, ticks and event cycles.
        compute_max_s: the longest cycle since the previous status [s].
        event_driven: whether event cycles are enabled (``gateway.event_driven``).
        event_seqs: the override seqs of the event cycles since the previous status (possibly capped:
            complete when as many as the growth of ``event_cycles``).
    """
    return LoopStatus(
        rate_hz=_rounded(1.0 / rate.period_s, LOOP_DIGITS),
        cycles=rate.tick_cycles + rate.event_cycles,
        tick_cycles=rate.tick_cycles,
        event_cycles=rate.event_cycles,
        wakes_served_by_tick=rate.wakes_served_by_tick,
        event_driven=event_driven,
        missed_cycles=rate.missed_cycles,
        last_lateness_s=_rounded(max(rate.last_lateness_s, 0.0), LOOP_DIGITS),
        compute_max_s=_rounded(compute_max_s, LOOP_DIGITS),
        event_seqs=list(event_seqs),
    )


def effective_config(config: CellConfig) -> EffectiveConfig:
    """The safety configuration as loaded, so that anyone can recompute δ (contract, ``GET /api/v1/config``)."""
    return EffectiveConfig(
        cell=config.cell,
        config_sha256=config.sha256(),
        trackers=sorted(config.trackers),
        safety=config.safety,
        zones=config.zones,
        gateway=config.gateway,
        plausibility=config.plausibility,
        streams=config.streams,
        robots={
            name: EffectiveRobot(
                urdf=robot.model.urdf,
                base_pose_world=robot.base_pose_world,
                joints=list(robot.model.joints),
                braking_time_s=list(robot.model.braking_time_s),
                links=list(robot.model.links),
            )
            for name, robot in config.robots.items()
        },
    )
