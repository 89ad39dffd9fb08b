"""The status document (``GET /api/v1/status`` and ``hrc/<cell>/gateway/status``) and the effective config."""

from __future__ import annotations

from typing import Any

from gateway.core import RobotDecision
from hrc_common.config import CellConfig
from hrc_common.service import RateLoop


def _round(x: float | None, digits: int = 4) -> float | None:
    return None if x is None else round(x, digits)


def robot_status(decision: RobotDecision, override_seq: int) -> dict[str, Any]:
    """One robot's entry; ``override_seq`` is the seq of the override this decision was sent with."""
    closest = decision.closest
    return {
        "zone": decision.zone.value,
        "delta": round(decision.delta, 4),
        "delta_bound": round(decision.delta_bound, 4),
        "min_distance_m": _round(decision.min_distance_m),
        "closest": None if closest is None else closest._asdict(),
        "t_delay_s": round(decision.delay.total_s, 4),
        "delay_budget_s": {k: round(v, 4) for k, v in decision.delay._asdict().items()},
        "clearance_m": round(decision.clearance_m, 4),
        "thresholds_m": {k: round(v, 4) for k, v in decision.thresholds._asdict().items()},
        "override_seq": override_seq,
        "data_age_s": {k: _round(v) for k, v in decision.data_age_s.items()},
        "faults": [f._asdict() for f in decision.faults],
        "controller_mode": decision.controller_mode,
        "replan_request": decision.replan_request,
    }


def status_document(
    cell: str,
    stamp_ns: int,
    robots: dict[str, dict[str, Any]],
    humans: list[dict[str, Any]],
    rejected: dict[str, dict[str, int]],
    received: dict[str, int],
    loop: dict[str, Any],
) -> dict[str, Any]:
    return {
        "cell": cell,
        "stamp_ns": stamp_ns,
        "robots": robots,
        "humans": humans,
        "inputs": {"received": received, "rejected": rejected},
        "loop": loop,
    }


def loop_status(rate: RateLoop, compute_max_s: float, event_driven: bool, event_seqs: list[int]) -> dict[str, Any]:
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
    return {
        "rate_hz": round(1.0 / rate.period_s, 6),
        "cycles": rate.tick_cycles + rate.event_cycles,
        "tick_cycles": rate.tick_cycles,
        "event_cycles": rate.event_cycles,
        "wakes_served_by_tick": rate.wakes_served_by_tick,
        "event_driven": event_driven,
        "missed_cycles": rate.missed_cycles,
        "last_lateness_s": round(rate.last_lateness_s, 6),
        "compute_max_s": round(compute_max_s, 6),
        "event_seqs": list(event_seqs),
    }


def effective_config(config: CellConfig) -> dict[str, Any]:
    """The safety configuration as loaded, so that anyone can recompute δ (contract, ``GET /api/v1/config``)."""
    return {
        "cell": config.cell,
        "config_sha256": config.sha256(),
        "trackers": sorted(config.trackers),
        "safety": config.safety.model_dump(mode="json"),
        "zones": config.zones.model_dump(mode="json"),
        "gateway": config.gateway.model_dump(mode="json"),
        "robots": {
            name: {
                "urdf": robot.model.urdf,
                "base_pose_world": robot.base_pose_world.model_dump(mode="json"),
                "joints": list(robot.model.joints),
                "braking_time_s": list(robot.model.braking_time_s),
                "links": [link.model_dump(mode="json") for link in robot.model.links],
            }
            for name, robot in config.robots.items()
        },
    }
