"""The status document (``GET /api/v1/status`` and ``hrc/<cell>/gateway/status``) and the effective config,
built through the contract's models (:mod:`hrc_contract.status_models`).

Every builder reads the attributes it shows (never ``_asdict()``), so that a field added to a decision does
not change the document until the model has it too. No builder raises for a decision the core can take:
the loop publishes the status between overrides, and a status must never stop the overrides. A number that
is not finite (absurd input) is shown as null where the model allows it.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from typing import Any, NamedTuple

import msgspec
import numpy as np
import numpy.typing as npt
from pydantic import TypeAdapter

from gateway.capsules_json import DIGITS, capsule_table, human_capsules_json
from gateway.core import RobotDecision
from gateway.inputs import InputSnapshot
from gateway.node import GatewayCycle
from gateway.planner_worker import PlanView
from gateway.tracks import NS_PER_S, TrackRecord, TrackState, reach_speed_mps
from hrc_contract.config import CellConfig
from hrc_contract.humans import HumanCapsules
from hrc_contract.status_models import (
    BridgeStatus,
    CapsuleStatus,
    EffectiveConfig,
    EffectiveRobot,
    GatewayStatus,
    HumanCapsuleStatus,
    HumanSeen,
    InputCounters,
    LoopStatus,
    RobotStatus,
    TrackStatus,
)
from hrc_devices.robots.model import RobotModel
from hrc_runtime.rate_loop import RateLoop

LOOP_DIGITS = 6
"""The loop's timing (lateness, compute time) is rounded to this many decimals (1 µs)."""


class StatusJob(NamedTuple):
    """One cycle to show, with what the loop took for it on its own thread (cheap: references and small counts).

    Attributes:
        cycle: the cycle the document shows.
        counters: ``(rejected, received)`` of the input store when the cycle was handed over.
        loop: the loop's own timing then.
        stamp_ns: when it was handed over, right after the decision [ns since the epoch].
    """

    cycle: GatewayCycle
    counters: tuple[dict[str, dict[str, int]], dict[str, int]]
    loop: LoopStatus
    stamp_ns: int


def _rounded(x: float, digits: int = DIGITS) -> float:
    return round(x, digits)


def _finite_or_none(x: float | None, digits: int = DIGITS) -> float | None:
    return None if x is None or not math.isfinite(x) else round(x, digits)


def _unit(x: float) -> float:
    """δ-like values in [0, 1]; not a number counts as 0 (as the core treats a nan bound)."""
    return 0.0 if x != x else round(min(max(x, 0.0), 1.0), DIGITS)


_LINK_CAPSULES: TypeAdapter[list[CapsuleStatus]] = TypeAdapter(list[CapsuleStatus])
_HUMAN_CAPSULES: TypeAdapter[list[HumanCapsuleStatus]] = TypeAdapter(list[HumanCapsuleStatus])


def _capsule_rows(
    a_m: npt.NDArray[np.float64], b_m: npt.NDArray[np.float64], radius_m: npt.NDArray[np.float64]
) -> list[list[float]]:
    """:func:`gateway.capsules_json.capsule_table` as lists, one ``tolist`` for all capsules."""
    return capsule_table(a_m, b_m, radius_m).tolist()  # type: ignore[no-any-return]


def _link_entries(
    decision: RobotDecision, link_names: Sequence[str], link_radius_m: Sequence[float] | npt.NDArray[np.float64]
) -> list[dict[str, Any]]:
    """The fields of :func:`link_capsules`, not yet validated (:func:`robot_status` validates them with its entry)."""
    links = decision.links
    if links is None or len(link_names) != len(links.p_a_world) or len(link_radius_m) != len(link_names):
        return []
    rows = _capsule_rows(links.p_a_world, links.p_b_world, np.asarray(link_radius_m, dtype=float))
    return [
        {"name": name, "a_m": row[0:3], "b_m": row[3:6], "radius_m": row[6]}
        for name, row in zip(link_names, rows, strict=True)
    ]


def link_capsules(
    decision: RobotDecision, link_names: Sequence[str], link_radius_m: Sequence[float] | npt.NDArray[np.float64]
) -> list[CapsuleStatus]:
    """The robot's link capsules at the decision's joint positions (none before a joint state or without names).

    Built as plain values and validated in one call (a model per capsule costs ~6 µs in Python; this ~1 µs).
    """
    return _LINK_CAPSULES.validate_python(_link_entries(decision, link_names, link_radius_m))


VALIDATE_CHUNK = 250
"""Capsules validated per call: one pydantic call holds Python's interpreter lock throughout (4000 capsules at once
held it 11–13 ms, longer than the safety loop's period); between chunks the loop thread can take it."""


def _human_capsule_entries(capsules: HumanCapsules) -> list[dict[str, Any]]:
    """The status's ``human_capsules`` as plain values, their keys in the model's order (finite, rounded)."""
    if not capsules.n_capsules:
        return []
    rows = _capsule_rows(capsules.h_a_world, capsules.h_b_world, capsules.radius_m)
    return [
        {"name": name, "a_m": row[0:3], "b_m": row[3:6], "radius_m": row[6], "human": human}
        for human, name, row in zip(capsules.human_ids, capsules.capsule_names, rows, strict=True)
    ]


def human_capsules(capsules: HumanCapsules) -> list[HumanCapsuleStatus]:
    """The people a decision kept clear of (world frame): every seen capsule and every lost track's, its radius
    grown by the track's reach; for the status's ``human_capsules``. Validated :data:`VALIDATE_CHUNK` at a time."""
    entries = _human_capsule_entries(capsules)
    out: list[HumanCapsuleStatus] = []
    for start in range(0, len(entries), VALIDATE_CHUNK):
        out += _HUMAN_CAPSULES.validate_python(entries[start : start + VALIDATE_CHUNK])
    return out


def track_entries(
    records: Sequence[TrackRecord],
    decisions: Mapping[str, RobotDecision],
    now_mono_ns: int,
    reach_speed_mps: float,
    inputs: InputSnapshot | None = None,
) -> list[dict[str, Any]]:
    """The status's ``tracks``: each track's state, age, reach, which robots it holds and what to do.

    Args:
        inputs: the snapshot of the decisions: a seen track was last seen in its tracker's newest frame.
    """
    seen_ns: dict[str, int] = {}
    for tracker, frame in (inputs.humans if inputs is not None else {}).items():
        if frame is not None:
            seen_ns[tracker] = frame.received_mono_ns - frame.transit_ns
    holding: dict[str, list[str]] = {}
    for name, decision in decisions.items():
        if decision.closest is not None and decision.delta < 1.0:
            holding.setdefault(decision.closest.human, []).append(name)
    entries = []
    for r in records:
        last_ns = seen_ns.get(r.tracker, now_mono_ns) if r.last_seen_mono_ns is None else r.last_seen_mono_ns
        age_s = max(0, now_mono_ns - last_ns) / NS_PER_S
        lost = r.state is TrackState.LOST
        holds = holding.get(r.human, []) if r.state is not TrackState.RELEASED else []
        action = None
        if lost:
            where = f" (holds {', '.join(holds)})" if holds else ""
            action = f"person {r.label} lost {age_s:.1f} s ago{where}: clear the area and reset"
        entries.append(
            {
                "label": r.label,
                "tracker": r.tracker,
                "human": r.human,
                "state": r.state.value,
                "last_seen_age_s": _rounded(age_s),
                "reach_m": _rounded(reach_speed_mps * age_s) if lost else 0.0,
                "capsules": r.capsules,
                "holds": holds,
                "released_by": r.released_by,
                "action": action,
                "person": r.person,
                "held_because": r.held_because,
            }
        )
    return entries


def robot_status(
    decision: RobotDecision,
    override_seq: int,
    link_names: Sequence[str] = (),
    link_radius_m: Sequence[float] | npt.NDArray[np.float64] = (),
    bridge: BridgeStatus | None = None,
) -> RobotStatus:
    """One robot's entry; ``override_seq`` is the seq of the override this decision was sent with.

    Args:
        link_names, link_radius_m: the robot's links (``RobotModel.link_names``, ``link_radius_m`` [m]), in the
            order of the decision's ``links``; without them the entry has no link capsules.
        bridge: the robot's controller bridge as :class:`gateway.bridge_view.BridgeView` shows it (display only).
    """
    closest = decision.closest
    delay = decision.delay
    thresholds = decision.thresholds
    entry = {  # plain values validated in one call: a model built per part costs ~2 µs each in Python
        "zone": decision.zone.value,
        "delta": _unit(decision.delta),
        "delta_bound": _unit(decision.delta_bound),
        "min_distance_m": _finite_or_none(decision.min_distance_m),
        "closest": None
        if closest is None
        else {"human": closest.human, "capsule": closest.capsule, "link": closest.link},
        "bounded_by": decision.bounded_by,
        "t_delay_s": _rounded(delay.total_s),
        "delay_budget_s": {
            "t_reaction_s": _rounded(delay.t_reaction_s),
            "human_age_s": _rounded(delay.human_age_s),
            "joint_state_age_s": _rounded(delay.joint_state_age_s),
            "override_path_s": _rounded(delay.override_path_s),
            "controller_cycle_s": _rounded(delay.controller_cycle_s),
            "gateway_period_s": _rounded(delay.gateway_period_s),
        },
        "clearance_m": _rounded(decision.clearance_m),
        "thresholds_m": {
            "protective_m": _rounded(thresholds.protective_m),
            "resume_m": _rounded(thresholds.resume_m),
            "reduce_m": _finite_or_none(thresholds.reduce_m),
            "monitored_m": _finite_or_none(thresholds.monitored_m),
        },
        "override_seq": override_seq,
        "data_age_s": {k: _finite_or_none(v) for k, v in decision.data_age_s.items()},
        "faults": [{"code": f.code, "reason": f.reason} for f in decision.faults],
        "controller_mode": decision.controller_mode,
        "delta_applied": None if decision.delta_applied is None else _unit(decision.delta_applied),
        "replan_request": decision.replan_request,
        "links": _link_entries(decision, link_names, link_radius_m),
        "bridge": bridge,
        "open_command": _open_command(decision),
        "plan": None if decision.plan is None else _plan(decision.plan),
    }
    return RobotStatus.model_validate(entry)


def _plan(view: PlanView) -> dict[str, object]:
    def time_s(x: float | None) -> float | None:
        return None if x is None or not math.isfinite(x) else max(0.0, _rounded(x))

    return {
        "following": view.following,
        "plan_time_s": time_s(view.plan_time_s),
        "plan_duration_s": time_s(view.plan_duration_s),
        "path_waypoints": view.path_waypoints,
        "reason": view.reason,
        "requests": view.requests,
        "adopted": view.adopted,
        "rejected": view.rejected,
        "failures": view.failures,
        "planning_last_s": time_s(view.planning_last_s),
        "planning_total_s": time_s(view.planning_total_s),
        "path_tool_m": None
        if view.path_tool_world_m is None or not bool(np.all(np.isfinite(view.path_tool_world_m)))
        else [[_rounded(v) for v in p] for p in view.path_tool_world_m.tolist()],
        "planner_running": view.backend.running,
        "planner_deaths": view.backend.deaths,
        "planner_restarts": view.backend.restarts,
        "planner_last_exit": view.backend.last_exit,
    }


def _open_command(decision: RobotDecision) -> dict[str, object] | None:
    command = decision.open_command
    if command is None:
        return None
    gap = command.solution.self_motion_gap_radps
    return {
        "how": command.solution.how,
        "self_motion_gap_radps": None if gap is None or not math.isfinite(gap) else max(0.0, _rounded(gap)),
        "rows": command.rows,
        "rows_dropped": command.rows_dropped,
        "reference_restarts": command.reference_restarts,
        "program_cycles": _rounded(command.program_cycles) if math.isfinite(command.program_cycles) else 0.0,
        "q_rad": [_rounded(v) for v in command.q_rad.tolist()],
        "qd_radps": [_rounded(v) for v in command.qd_radps.tolist()],
    }


def status_document(
    cell: str,
    stamp_ns: int,
    robots: dict[str, RobotStatus],
    humans: Sequence[HumanSeen | Mapping[str, Any]],
    rejected: dict[str, dict[str, int]],
    received: dict[str, int],
    loop: LoopStatus,
    capsules: Sequence[HumanCapsuleStatus] = (),
    tracks: Sequence[TrackStatus | Mapping[str, Any]] = (),
) -> GatewayStatus:
    """The whole document; serialise it with ``doc.model_dump_json()`` (the same bytes on Zenoh and HTTP).

    Args:
        humans: :class:`HumanSeen` entries, or their fields as mappings (validated here).
        capsules: the humans' capsules (:func:`human_capsules`).
        tracks: :class:`TrackStatus` entries, or their fields (:func:`track_entries`).
    """
    return GatewayStatus(
        cell=cell,
        stamp_ns=stamp_ns,
        robots=robots,
        humans=list(humans),
        inputs=InputCounters(received=received, rejected=rejected),
        loop=loop,
        tracks=list(tracks),
        human_capsules=list(capsules),
        persons=person_entries(tracks),
    )


def person_entries(tracks: Sequence[TrackStatus | Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The status's ``persons``: the live tracks grouped by the person they are a view of, in order of appearance."""
    persons: dict[str, dict[str, Any]] = {}
    for entry in tracks:
        t = entry.model_dump() if isinstance(entry, TrackStatus) else entry
        if t["state"] == "released" or not t.get("person"):
            continue
        p = persons.setdefault(
            t["person"], {"label": t["person"], "state": "lost", "tracks": [], "lost_tracks": [], "held_because": None}
        )
        p["tracks"].append(t["label"])
        if t["state"] == "seen":
            p["state"] = "seen"
        else:
            p["lost_tracks"].append(t["label"])
            p["held_because"] = p["held_because"] or t.get("held_because")
    return list(persons.values())


def cycle_status(
    config: CellConfig,
    cycle: GatewayCycle,
    robots: Mapping[str, RobotModel],
    counters: tuple[dict[str, dict[str, int]], dict[str, int]],
    loop: LoopStatus,
    stamp_ns: int,
    bridges: Mapping[str, BridgeStatus] | None = None,
    with_lists: bool = True,
) -> GatewayStatus:
    """The status document of one cycle (what the loop publishes at ``gateway.status_rate_hz``).

    Args:
        cycle: the cycle it shows.
        robots: the robots' models (link names and radii).
        counters: ``(rejected, received)`` of the input store (:meth:`gateway.inputs.InputStore.counters`).
        loop: the loop's own timing (:func:`loop_status`).
        stamp_ns: when the document is built [ns since the epoch].
        bridges: the bridged robots' controller bridges (:meth:`gateway.bridge_view.BridgeView.snapshot`).
        with_lists: False: the lists that grow with the people (:data:`PEOPLE_LISTS`) left empty: the status thread
            serialises them on their own (:func:`people_lists_json`).
    """
    rejected, received = counters
    bridges = bridges or {}
    lists = people_lists(config, cycle) if with_lists else {}
    return status_document(
        config.cell,
        stamp_ns,
        {
            name: robot_status(d, cycle.seq, robots[name].link_names, robots[name].link_radius_m, bridges.get(name))
            for name, d in cycle.decisions.items()
        },
        lists.get("humans", ()),
        rejected,
        received,
        loop,
        human_capsules(cycle.capsules) if with_lists else (),
        lists.get("tracks", ()),
    )


PEOPLE_LISTS = ("humans", "tracks", "human_capsules", "persons")
"""The status's lists that grow with the people in the cell: in a crowd, thousands of entries 25 times a second."""


def people_lists(config: CellConfig, cycle: GatewayCycle) -> dict[str, list[dict[str, Any]]]:
    """The status's ``humans`` and ``tracks`` of one cycle as plain values, their keys in the models' order
    (``persons``: :func:`person_entries` of the tracks; ``human_capsules``: :func:`human_capsules`)."""
    tracks = track_entries(
        cycle.tracks,
        cycle.decisions,
        cycle.now.mono_ns if cycle.now is not None else 0,
        reach_speed_mps(config),
        cycle.inputs,
    )
    return {"humans": humans_summary(cycle.inputs), "tracks": tracks}


def people_lists_json(config: CellConfig, cycle: GatewayCycle) -> dict[str, bytes]:
    """:data:`PEOPLE_LISTS` of one cycle serialised without a model per entry (the values are the gateway's own:
    nothing to validate), for :func:`gateway.main.status_json`: the bytes the models would give (a test holds them to
    it). A crowd's tracks and people as models held the interpreter lock ~2 ms a document."""
    lists = people_lists(config, cycle)
    lists["persons"] = person_entries(lists["tracks"])
    encoded = {key: _LIST_ENCODER.encode(entries) for key, entries in lists.items()}
    return {**encoded, "human_capsules": human_capsules_json(cycle.capsules)}


_LIST_ENCODER = msgspec.json.Encoder()


def humans_summary(inputs: InputSnapshot) -> list[dict[str, Any]]:
    """The status's ``humans``: each human seen, by tracker, with its capsule count."""
    humans: list[dict[str, Any]] = []
    for tracker, frame in inputs.humans.items():
        if frame is None:
            continue
        for human_id, count in Counter(frame.capsules.human_ids).items():
            humans.append({"id": human_id, "tracker": tracker, "capsules": count})
    return humans


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
        tick_periods_s=[_rounded(x, LOOP_DIGITS) for x in rate.take_tick_periods()],
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
        tracking=config.tracking,
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
