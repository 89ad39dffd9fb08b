"""The gateway's status and REST responses (`docs/contract.md`, "Status" and "REST"), as pydantic models.

One status document is published twice: on the Zenoh key ``hrc/<cell>/gateway/status`` and as the body of
``GET /api/v1/status`` (:class:`GatewayStatus`). The gateway builds it through these models
(``gateway/status.py``), so what it publishes is what they describe; the REST API declares them as its
response models (``/openapi.json``); consumers (the auditor, the tests) parse with
``GatewayStatus.model_validate_json(payload)``. ``python -m hrc_contract.contract`` writes their JSON Schemas
to ``docs/schemas``.

This module imports nothing of the gateway (only the configuration models, for ``GET /api/v1/config``), so
that any consumer can use it alone. A field is only ever added here together with the code that fills it:
the models forbid unknown fields.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from hrc_contract.config import (
    GatewayConfig,
    LinkSegment,
    PlausibilityConfig,
    Pose,
    SafetyConfig,
    StreamsConfig,
    TrackingConfig,
    ZonesConfig,
)
from hrc_contract.vocabulary import ControllerMode, ZoneName

Unit = Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
NonNegative = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
Count = Annotated[int, Field(ge=0)]
FaultCode = Annotated[str, Field(pattern=r"^[a-z0-9_]+$", max_length=64)]
Point = Annotated[list[Finite], Field(min_length=3, max_length=3)]
"""A point of the cell's world frame, ``[x, y, z]`` [m]."""


class _Strict(BaseModel):
    """A part of a response whose shape is fixed: unknown fields are an error, numbers are finite."""

    model_config = ConfigDict(
        extra="forbid", frozen=True, allow_inf_nan=False, json_schema_serialization_defaults_required=True
    )


class Fault(_Strict):
    """An active fault of one robot: δ is 0 while any is active (contract, "Fault codes")."""

    code: FaultCode = Field(description="Machine-readable kind, one of the contract's table of fault codes.")
    reason: str = Field(description="For people: what was seen and what is allowed (e.g. an age and its limit).")


class ClosestPair(_Strict):
    """The human capsule and robot link at ``min_distance_m``."""

    human: str = Field(description="Human id, prefixed with the tracker name (``<tracker>/<id>``).")
    capsule: str = Field(description="Capsule name of that human (e.g. ``hand_r``).")
    link: str = Field(description="Robot link name (``links`` of the robot in ``GET /api/v1/config``).")


class DelayBudgetStatus(_Strict):
    """The parts of ``t_delay_s`` [s] (safety-math.md §5); their sum is ``t_delay_s``."""

    t_reaction_s: NonNegative = Field(description="Configured reaction-time floor (``safety.t_reaction_s``) [s].")
    human_age_s: NonNegative = Field(
        description="Age of the oldest tracker's newest frame; ``max_data_age_s`` for a tracker without data [s]."
    )
    joint_state_age_s: NonNegative = Field(description="Age of the newest joint state [s].")
    override_path_s: NonNegative = Field(
        description="Override path latency, learnt from the ``override_seq`` the controller echoes [s]."
    )
    controller_cycle_s: NonNegative = Field(description="Controller cycle, measured from its joint states [s].")
    gateway_period_s: NonNegative = Field(
        description="Until the gateway's next decision: the longest interval between decisions of the last 10 s, at "
        "least the period, at most the controller's watchdog (it stops on its own after that) [s]."
    )


class ThresholdsStatus(_Strict):
    """Distance thresholds of the zone logic this cycle, surface to surface [m] (safety-math.md §6).

    ``reduce_m`` and ``monitored_m`` grow with the programmed link speed; they are null when not a finite
    number (an absurd programmed speed), which never happens with plausible input.
    """

    protective_m: NonNegative = Field(description="The clearance Δ: at or below it the robot must stand still [m].")
    resume_m: NonNegative = Field(description="A safety exception ends only beyond this [m].")
    reduce_m: NonNegative | None = Field(description="Beyond it eq. (15) allows full speed [m].")
    monitored_m: NonNegative | None = Field(description="The monitored workspace; beyond it: autonomous [m].")


class CapsuleStatus(_Strict):
    """A capsule (a segment swept by a sphere) in the cell's world frame, for drawing the cell."""

    name: str = Field(description="Link name of the robot, or capsule name of a human (e.g. ``hand_r``).")
    a_m: Point = Field(description="First end point of the segment [m].")
    b_m: Point = Field(description="Second end point of the segment [m].")
    radius_m: NonNegative = Field(description="Radius around the segment [m].")


class HumanCapsuleStatus(CapsuleStatus):
    """One capsule of a human in a tracker's newest valid frame."""

    human: str = Field(description="Human id, prefixed with the tracker name (``<tracker>/<id>``).")


class OpenCommandStatus(_Strict):
    """An open robot's joint command of this decision (``controller.control = "open"``; docs/safety-math.md §13)."""

    how: str = Field(
        max_length=64,
        description="``lp13`` (LP (9) then the self-motion of LP (13)), ``lp9`` (LP (13) had no answer) or "
        "``ramp_stop:<why>`` (``commanded``: a fault or a zone at δ = 0; ``lp9_infeasible``; ``lp9_breaks_a_row``; "
        "``capped_infeasible``; ``inputs``: not finite): the stop along the current direction within t_b.",
    )
    self_motion_gap_radps: NonNegative | None = Field(
        description="LP (13)'s objective ‖q̇ − q̇⁰‖_∞: how far the self-motion is from its reference (away from the "
        "nearest people, back to the program's posture); null without LP (13) [rad/s]."
    )
    rows: Count = Field(description="Safety rows (9b) in the LP: those some velocity within the limits could break.")
    rows_dropped: Count = Field(description="Rows left out: no velocity within the limits reaches them.")
    reference_restarts: Count = Field(
        0,
        description="Times since the gateway started that the reference started again from the measured joints: "
        "they were far from every reference sent within the measured round trip (the robot did not follow: a "
        "protective stop, a restart, another program).",
    )
    program_cycles: Finite = Field(
        0.0,
        description="How far the program has come: the program time made good since the gateway started, in cycles "
        "of the program (a detour around people counts as the progress toward its goal).",
    )
    q_rad: list[Finite] = Field(description="The reference position sent for the next cycle [rad].")
    qd_radps: list[Finite] = Field(description="The reference velocity sent [rad/s].")


PLAN_PATH_POINTS_MAX = 64
"""At most this many points of a plan's tool path in the status (the gateway sends 32)."""


class PlanStatus(_Strict):
    """An open robot's planner layer (``[planner] enabled``; docs/planner.md): display only, no decision uses it."""

    following: bool = Field(description="The robot follows a plan around people (false: its program).")
    plan_time_s: NonNegative | None = Field(description="Where it is along the plan; null on the program [s].")
    plan_duration_s: NonNegative | None = Field(description="The plan's length; null on the program [s].")
    path_waypoints: Count | None = Field(description="Waypoints of the planned path; null on the program.")
    reason: str = Field(
        max_length=32, description="Why the current or last plan was asked for: ``horizon``, ``request``, or empty."
    )
    requests: dict[str, Count] = Field(description="Plans asked for since the start, per reason.")
    adopted: Count = Field(description="Plans the robot took up.")
    rejected: Count = Field(description="Plans returned after the robot had passed their join (or for another path).")
    failures: dict[str, Count] = Field(
        description="Requests without a plan, per reason (``no_path``, ``no_timing``, ``goal_invalid``, "
        "``start_invalid``, ``no_join``, ``timeout``, ``error:<exception>``)."
    )
    planning_last_s: NonNegative | None = Field(description="The planner's time for its latest answer [s].")
    planning_total_s: NonNegative = Field(
        0.0, description="The planner's time for all its answers since the start (wall clock) [s]."
    )
    path_tool_m: list[Point] | None = Field(
        None,
        max_length=PLAN_PATH_POINTS_MAX,
        description="The plan followed, as the tool's positions (the end of the last link capsule, world frame) "
        "evenly spaced in plan time from the plan's start (where the robot was when it was asked for) to its end; "
        "null on the program [m].",
    )
    planner_running: bool = Field(
        True, description="The planner can plan (false: its process died and waits for its restart)."
    )
    planner_deaths: Count = Field(0, description="Times the planner's process was found dead since the start.")
    planner_restarts: Count = Field(0, description="Times the planner's process was started again.")
    planner_last_exit: str = Field(
        "",
        max_length=64,
        description="How the last dead planner process ended (``exit code 1``, ``signal SIGKILL``); empty before any.",
    )


class BridgeStatus(_Strict):
    """The controller bridge of a robot whose ``interface`` is ``ur_rtde``, ``abb_rws`` or ``abb_egm``, from the
    statistics it puts on ``hrc/<cell>/robot/<robot>/bridge_stats`` every second. For display only: no decision uses
    it (the gateway measures the override path itself, ``delay_budget_s.override_path_s``)."""

    interface: Literal["ur_rtde", "abb_rws", "abb_egm"] = Field(
        description="The vendor interface (the cell file's ``kind``; ``abb_egm``: an open controller, no read-back)."
    )
    stats_age_s: NonNegative | None = Field(
        description="Age of the bridge's newest statistics; null before any (no bridge heard from) [s]."
    )
    mode: Annotated[str, Field(max_length=32)] | None = Field(description="``mode`` of the bridge's last joint state.")
    readback: Unit | None = Field(
        description="The controller's last read-back of its speed input (UR ``target_speed_fraction``, ABB speed "
        "ratio / 100); null before one."
    )
    readback_latency_s: NonNegative | None = Field(
        description="Write → first read-back showing the new value, the last one the bridge measured [s]."
    )
    readback_latency_max_s: NonNegative | None = Field(
        description="The largest such latency in the bridge's last statistics period (1 s) [s]."
    )
    readings_per_s: NonNegative | None = Field(
        description="Valid read-backs per second (``abb_egm``: the controller's EgmRobot feedbacks) [1/s]."
    )
    rejected: Count = Field(description="Refused read-backs and interface errors since the bridge started.")


class RobotStatus(_Strict):
    """One robot's decision as the status shows it (``robots.<robot>`` of :class:`GatewayStatus`)."""

    zone: ZoneName
    delta: Unit = Field(description="The override δ commanded with ``override_seq``.")
    delta_bound: Unit = Field(
        description="δ allowed by the configured method alone (``safety.method``), before faults and the "
        "safety-exception latch; a bound that is not a number counts as 0, as in the core."
    )
    min_distance_m: Finite | None = Field(
        description="Smallest surface distance robot link ↔ human capsule; null with nobody seen, or when "
        "not a finite number [m]."
    )
    closest: ClosestPair | None = Field(description="The pair at ``min_distance_m``; null with nobody seen.")
    bounded_by: str | None = Field(
        None,
        max_length=80,
        description="What bounded ``delta_bound``, for the methods that say (``lucci2020_pfl``): "
        "``separation:<region>`` (head, or a body part of no region: stop before contact), ``contact:<region>`` "
        "(slow to that region's contact-safe speed), ``clamping:<region>`` (a body part that may be pinned against a "
        "clamping surface: stop before contact) or ``none`` (δ = 1); null for the other methods.",
    )
    t_delay_s: NonNegative = Field(description="The whole delay this decision used: the sum of ``delay_budget_s`` [s].")
    delay_budget_s: DelayBudgetStatus
    clearance_m: NonNegative = Field(description="Δ = c + K (max t_b + t_delay) at the nominal human speed [m].")
    thresholds_m: ThresholdsStatus
    override_seq: Count = Field(description="``seq`` of the override message that carried this δ.")
    data_age_s: dict[str, NonNegative | None] = Field(
        description="Age of the newest valid data of each input at decision time: ``joint_state`` and "
        "``tracker/<tracker>``; null before the first [s]."
    )
    faults: list[Fault] = Field(description="Active faults; δ = 0 and zone ``safety_exception`` while any.")
    controller_mode: ControllerMode | None = Field(description="``mode`` of the newest joint state; null before one.")
    delta_applied: Unit | None = Field(
        description="``override`` of the newest joint state: the δ the controller reports applying (it ramps "
        "toward ``delta`` within its braking time); null before one."
    )
    replan_request: bool = Field(
        description="Eq. (16) of Pupa et al. 2021: δ has stayed below ``safety.replan_delta_below`` for "
        "``safety.replan_after_s`` (never while faulted)."
    )
    links: list[CapsuleStatus] = Field(
        default_factory=list,
        description="The link capsules at the joint positions this decision used (world frame); empty before "
        "the first joint state.",
    )
    bridge: BridgeStatus | None = Field(
        None,
        description="The controller bridge (interface ``ur_rtde``, ``abb_rws`` or ``abb_egm``); null for a controller "
        "that speaks the cell's Zenoh contract itself (interface ``zenoh``).",
    )
    open_command: OpenCommandStatus | None = Field(
        None,
        description="An open robot's joint command (LP (9)/(13)); null for a closed robot (it takes ``delta`` as its "
        "override) and before an open robot's first joint state.",
    )
    plan: PlanStatus | None = Field(
        None, description="An open robot's planner layer (``[planner] enabled``); null otherwise."
    )


class HumanSeen(_Strict):
    """A human in the newest valid frame of one tracker."""

    id: str = Field(description="Human id, prefixed with the tracker name (``<tracker>/<id>``).")
    tracker: str
    capsules: Count = Field(description="Capsules of this human in that frame.")


TrackStateName = Literal["seen", "lost", "released"]
"""A track's state (``gateway.tracks.TrackState``; docs/contract.md "Tracks")."""


class TrackStatus(_Strict):
    """One person as one tracker followed them: seen, lost (never gone) or released, and by what."""

    label: str = Field(description="``<tracker>/<id>``; ``#<n>`` appended when another live track has that label.")
    tracker: str
    human: str = Field(
        description="The id its capsules carry in ``closest`` and ``human_capsules``: ``<tracker>/<id>`` while seen, "
        "``<label> (lost)`` while lost."
    )
    state: TrackStateName
    last_seen_age_s: NonNegative = Field(description="Time since the frame it was last seen in was captured [s].")
    reach_m: NonNegative = Field(
        description="Lost: how far the person may be from where last seen (K × last_seen_age_s); its capsules are "
        "grown by this in every decision. 0 otherwise [m]."
    )
    capsules: Count = Field(description="Capsules of the person as last seen.")
    holds: list[str] = Field(
        description="Robots whose closest person this is while their δ is below 1 (who holds which robot)."
    )
    released_by: str | None = Field(
        description="Released: what released it (redetected by <label>, last seen leaving, reset by an operator)."
    )
    action: str | None = Field(
        description="Lost: what to do, for people (e.g. clear the area and reset); null otherwise."
    )
    person: str = Field(
        "",
        description="The person (``P<n>``) this track is a view of: the tracks of every tracker that are one body "
        '(docs/contract.md "Tracks").',
    )
    held_because: str | None = Field(
        None,
        description="Lost: why no detection released it although one could have been this person (it could as well "
        "be someone else); null otherwise.",
    )


class PersonStatus(_Strict):
    """One body in the cell, whatever trackers see it and whatever ids they give it."""

    label: str = Field(description="``P<n>``, numbered as persons appear.")
    state: Literal["seen", "lost"] = Field(
        description="Seen while any of its tracks is seen; lost when all are (kept, growing at K, until released)."
    )
    tracks: list[str] = Field(description="The labels of its live tracks (seen and lost).")
    lost_tracks: list[str] = Field(
        description="Its lost tracks: parts or views of this body no sensor accounts for now; each holds the robots "
        "it could reach until released."
    )
    held_because: str | None = Field(
        description="Why a detection that could have been this person did not release them; null otherwise."
    )


class InputCounters(_Strict):
    """Messages received per input topic (``robot/<robot>``, ``tracker/<tracker>``), since the gateway started."""

    received: dict[str, Count] = Field(description="Valid messages stored, per topic.")
    rejected: dict[str, dict[str, Count]] = Field(
        description='Rejected messages per topic and reason (contract, "Rejection reasons"). Topics of '
        "unknown robots and trackers are counted too (``robot/<name>``, ``tracker/<name>``)."
    )


class LoopStatus(_Strict):
    """How the gateway's own loop keeps its period (``gateway.rate_hz``), since it started.

    A decision is taken at every tick and, with ``event_driven``, also when a tracker frame arrives (an
    event cycle, between ticks).
    """

    rate_hz: NonNegative = Field(description="Tick rate [Hz].")
    cycles: Count = Field(description="All decisions: ``tick_cycles + event_cycles``.")
    tick_cycles: Count = Field(description="Decisions at the fixed-rate ticks.")
    event_cycles: Count = Field(description="Decisions taken at once when a tracker frame arrived.")
    wakes_served_by_tick: Count = Field(
        description="Tracker frames left to a tick due within ``gateway.event_guard_s``."
    )
    event_driven: bool = Field(description="``gateway.event_driven``.")
    missed_cycles: Count = Field(description="Ticks skipped after an overrun.")
    last_lateness_s: NonNegative = Field(description="Lateness of the last tick [s].")
    compute_max_s: NonNegative = Field(
        description="Longest loop iteration (from waking to going back to sleep: the decision, publishing, hand-offs) "
        "since the previous status [s]."
    )
    event_seqs: list[Count] = Field(
        description="Override seqs of the event cycles since the previous status; complete when as many as "
        "the growth of ``event_cycles`` (capped at 256)."
    )
    tick_periods_s: list[NonNegative] = Field(
        default_factory=list,
        description="Each tick's interval from the previous tick since the previous status, oldest first (at most "
        "256) [s]: the period histogram of the metrics observes each.",
    )
    budget_overruns: Count = Field(
        0,
        description="Decisions that commanded δ > 0 whose next decision started later than the "
        "``delay_budget_s.gateway_period_s`` they counted, since the gateway started (the loop was held up).",
    )
    stalls: dict[str, Count] = Field(
        default_factory=dict,
        description="Ticks later than a period (each made the loop skip ticks), by cause, since the gateway started: "
        "``gc``, ``runqueue`` (runnable, another thread or program ran), ``stolen`` (on none of the thread's clocks "
        "while blocked on nothing but its sleep: the CPU did not run, e.g. the hypervisor's steal), ``phase:<name>`` "
        "(the loop's own work ran past the due time), ``blocked`` (woke late without being runnable: the interpreter "
        "lock or the process stopped), ``kernel`` (woke late, the thread's CPU clock running during its sleep: "
        "kernel time charged to it, e.g. a virtual machine's host); a late wake-up that none of these explains "
        "alone goes to the largest of its run-queue wait, blocked time and CPU time in its sleep if together they "
        "cover half the lateness; else ``unknown``. Each is logged as an event "
        "``loop_stall`` with its figures.",
    )
    missed_by_cause: dict[str, Count] = Field(
        default_factory=dict,
        description="``missed_cycles`` by the cause of the stall that skipped them (they add up to it).",
    )


class GatewayStatus(_Strict):
    """The status document: ``GET /api/v1/status`` and the Zenoh key ``hrc/<cell>/gateway/status``
    (published at ``gateway.status_rate_hz``, 25 Hz by default; the same document on both)."""

    cell: str
    stamp_ns: Count = Field(
        description="When the document was built, right after the decision it shows [ns since the Unix epoch]."
    )
    robots: dict[str, RobotStatus] = Field(description="Every configured robot, by name.")
    humans: list[HumanSeen] = Field(description="The humans of every tracker's newest valid frame.")
    inputs: InputCounters
    loop: LoopStatus
    tracks: list[TrackStatus] = Field(
        default_factory=list,
        description="Every person tracked: seen, lost (kept, growing at K) and the recently released (docs/contract.md "
        '"Tracks").',
    )
    human_capsules: list[HumanCapsuleStatus] = Field(
        default_factory=list, description="The capsules of ``humans`` (world frame), for drawing the cell."
    )
    persons: list[PersonStatus] = Field(
        default_factory=list,
        description="Every person with a live track: the tracks of all trackers that are one body (docs/contract.md "
        '"Tracks").',
    )


EventKind = Literal[
    "start",
    "stop",
    "config_loaded",
    "zone_changed",
    "fault_raised",
    "fault_cleared",
    "track_lost",
    "track_released",
    "loop_stall",
    "plan_adopted",
    "plan_rejected",
    "planner_died",
    "planner_restarted",
]
"""What an :class:`Event` records (contract, "Events")."""


class Event(_Strict):
    """One entry of the gateway's event log (``GET /api/v1/events`` and the JSON Lines file)."""

    seq: Count = Field(description="1, 2, 3, ... in the order the gateway logged them, since it started.")
    stamp_ns: Count = Field(description="When it was logged [ns since the Unix epoch].")
    kind: EventKind
    robot: str | None = Field(default=None, description="The robot it concerns; null for the whole gateway.")
    message: str = Field(description="For people: what happened, with the reason.")
    zone: ZoneName | None = Field(default=None, description="``zone_changed``: the zone entered.")
    previous_zone: ZoneName | None = Field(default=None, description="``zone_changed``: the zone left.")
    code: FaultCode | None = Field(default=None, description="``fault_raised`` / ``fault_cleared``: its code.")
    reason: str | None = Field(default=None, description="``fault_raised``: the fault's reason.")
    config_sha256: str | None = Field(default=None, description="``config_loaded``: hex SHA-256 of the config.")
    track: str | None = Field(default=None, description="``track_lost`` / ``track_released``: the track's label.")
    cause: str | None = Field(
        default=None,
        description="``track_released``: ``redetected``, ``left`` or ``reset`` (the message says by whom); "
        "``loop_stall``: the stall's cause (``loop.stalls``); ``plan_adopted``: why the plan was asked for "
        "(``horizon``, ``request``); ``planner_died``: how its process ended (``signal SIGKILL``, ``exit code 1``).",
    )


class EventsResponse(_Strict):
    """``GET /api/v1/events?since=<seq>``: the events after ``since`` that the server still holds, oldest first."""

    events: list[Event]
    last_seq: Count = Field(description="Seq of the newest event logged (0 before any): the next ``since``.")


class RobotStatusResponse(RobotStatus):
    """``GET /api/v1/robots/{robot}``: one robot's entry of the status, with the document's cell and stamp."""

    cell: str
    stamp_ns: Count = Field(description="``stamp_ns`` of the status document [ns since the Unix epoch].")
    robot: str


class EffectiveRobot(_Strict):
    """A robot as the gateway loaded it: enough to recompute δ."""

    urdf: str = Field(description="Absolute path of the URDF loaded.")
    base_pose_world: Pose = Field(description="Pose of the robot base in the cell's world frame [m, rad].")
    joints: list[str] = Field(description="Joint names, in the order of ``q`` in the joint state.")
    braking_time_s: list[NonNegative] = Field(description="Braking time of each joint, in the order of joints [s].")
    links: list[LinkSegment] = Field(description="Link capsules between two URDF frames (as Pinocchio loads them).")


class EffectiveConfig(_Strict):
    """``GET /api/v1/config``: the effective safety configuration, so that anyone can recompute δ."""

    cell: str
    config_sha256: str = Field(
        pattern=r"^[0-9a-f]{64}$",
        description="Hex SHA-256 of the whole configuration as loaded (referenced files included).",
    )
    trackers: list[str] = Field(description="Configured trackers, sorted.")
    safety: SafetyConfig
    zones: ZonesConfig
    gateway: GatewayConfig
    plausibility: PlausibilityConfig
    streams: StreamsConfig
    tracking: TrackingConfig
    robots: dict[str, EffectiveRobot]


class Health(_Strict):
    """``GET /healthz``: the HTTP process is up (says nothing about the safety loop)."""

    status: Literal["ok"]


class Ready(_Strict):
    """``GET /readyz`` 200: a fresh status without any fault on any robot."""

    ready: Literal[True]


class NotReady(_Strict):
    """Why ``GET /readyz`` answers 503 while the loop runs: the reasons of the active faults."""

    ready: Literal[False]
    faults: dict[str, list[str]] = Field(description="Per faulted robot, the ``reason`` of each active fault.")


class ErrorResponse(_Strict):
    """An error: 404 for an unknown robot (the message names the known ones); 503 when the safety loop
    has not published a status yet, or none for ``STATUS_STALE_AFTER_S`` (1 s)."""

    detail: str


class NotReadyResponse(_Strict):
    """``GET /readyz`` 503: a message when the safety loop publishes no status, else the faults."""

    detail: NotReady | str
