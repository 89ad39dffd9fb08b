"""The gateway's decision: one input snapshot and a time → one decision per robot.

No I/O, no clock: the caller passes ``now`` (both clocks). Faults (missing, stale, invalid, implausible,
out-of-order or inconsistent input, an override path that is not confirmed, a clock step) force δ = 0 for the
robots they concern and put the robot in ``safety_exception``, from which it recovers by the zone rules once the
fault has cleared. Per robot, everything remembered between cycles is one :class:`RobotState`.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from gateway.delay import NS_PER_S, DelayBudget, OverridePathEstimate, WindowMax
from gateway.inputs import HumanFrame, InputSnapshot, JointSample, TopicFault, age_s
from gateway.kernels import RobotKernels, capsule_columns
from gateway.link_ends import LinkEnds
from gateway.methods import ContactAware, MethodInput, OverrideMethod, ReplanMonitor, build_method
from gateway.open_robot import OpenCommand, OpenRobot, nearest_people
from gateway.planner import JointPlanner
from gateway.planner_worker import PlannerBackend, PlannerHealth, PlanView, ProcessPlanner, Replanner
from gateway.separation import decision_clearance_m, override_from_rows
from gateway.tracks import MAX_LIVE_TRACKS, TrackEvent, TrackRecord, TrackSet
from gateway.zones import ZoneThresholds, commanded_override, next_zone, zone_thresholds
from hrc_contract.config import CellConfig, ConfigError
from hrc_contract.humans import NO_HUMANS, HumanCapsules, merge_humans
from hrc_contract.vocabulary import Zone
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import Clocks

Fault = TopicFault
"""A fault of one decision: ``code`` (machine-readable, listed in docs/contract.md) and ``reason`` (for people)."""


class ClosestPair(NamedTuple):
    human: str
    capsule: str
    link: str


class RobotDecision(NamedTuple):
    """The decision for one robot in one cycle; what the status shows and the override carries.

    Attributes:
        delta: the override to command, in [0, 1].
        delta_bound: δ allowed by the configured method alone this cycle (``safety.method``; eq. (15) by
            default), before faults and the exception latch.
        min_distance_m: smallest surface distance to any human, None with nobody seen [m].
        closest: the pair at ``min_distance_m``.
        delay: the parts of t_delay used [s].
        clearance_m: Δ at the nominal human speed [m].
        data_age_s: age of the newest data of each input at decision time, None if none yet [s].
        controller_mode: mode reported by the controller, None before its first state.
        replan_request: eq. (16) of Pupa et al. 2021: δ has stayed below ``safety.replan_delta_below``
            for ``safety.replan_after_s`` (never while faulted).
        delta_applied: the override the controller reported applying in its newest state, None before one.
        links: the link segments' end points this decision used (world frame) [m]; None before a joint state.
        bounded_by: what bounded ``delta_bound``, for the methods that say (``lucci2020_pfl``: ``separation:<region>``,
            ``contact:<region>``, ``clamping:<region>`` or ``none``; an open robot: ``safety:<link>/<capsule>``,
            ``limits``, ``zone`` or ``none``); None for the others.
        open_command: an open robot's joint command of this decision (LP (9)/(13) or the ramp stop); None for a
            closed robot, and for an open robot before its first joint state (nothing to command from).
        plan: an open robot's planner layer after this decision (``planner.enabled``); None otherwise.
    """

    robot: str
    zone: Zone
    delta: float
    delta_bound: float
    min_distance_m: float | None
    closest: ClosestPair | None
    delay: DelayBudget
    clearance_m: float
    thresholds: ZoneThresholds
    faults: tuple[Fault, ...]
    data_age_s: dict[str, float | None]
    controller_mode: str | None
    replan_request: bool = False
    delta_applied: float | None = None
    links: LinkEnds | None = None
    bounded_by: str | None = None
    open_command: OpenCommand | None = None
    plan: PlanView | None = None


class TrackReset(NamedTuple):
    """An operator's reset, judged at the door (``GatewayNode``): release the lost track ``track`` (``*``: all)."""

    track: str
    operator: str


class HumansView(NamedTuple):
    """What every robot's decision shares in one cycle: the merged capsules, their age and the shared faults.

    Attributes:
        capsules: every person the decision must keep clear of: the capsules of every tracker's newest frame
            (the seen tracks) and of every lost track, radii grown by its reach.
        columns: ``capsules`` as the compiled rows take them.
        age_s: the oldest tracker's data age (a tracker without data counts at the age limit) [s].
        ages_s: per tracker topic, its data age (None without data) [s].
        faults: faults of the trackers and of this host's clock: they concern every robot.
    """

    capsules: HumanCapsules
    columns: npt.NDArray[np.float64]
    age_s: float
    ages_s: dict[str, float | None]
    faults: tuple[Fault, ...]


@dataclass
class RobotState:
    """One robot: its model and compiled kernels, and what its decisions remember between cycles."""

    name: str
    robot: RobotModel
    kernels: RobotKernels
    data: pin.Data
    speed_hold: WindowMax
    replan: ReplanMonitor
    topic: str
    watchdog_s: float
    """The controller stops on its own when it hears no override for this long (``controller.watchdog_s``) [s]."""
    open: OpenRobot | None = None
    """An open robot's task and reference (``controller.control = "open"``); None for a closed one."""
    zone: Zone = Zone.SAFETY_EXCEPTION
    previous_delta: float = 0.0
    replanner: Replanner | None = None
    """An open robot's planner layer (``planner.enabled``); None otherwise."""


def tracker_faults(tracker: str, frame: HumanFrame | None, age: float | None, max_age_s: float) -> list[Fault]:
    """Faults of one tracker's newest data: none yet, or too old."""
    if frame is None:
        return [Fault("tracker_missing", f"no valid data from tracker {tracker!r} yet")]
    if age is not None and age > max_age_s:
        return [Fault("tracker_stale", f"tracker {tracker!r} data is {age:.3f} s old (limit {max_age_s} s)")]
    return []


def joint_faults(robot: str, joint: JointSample | None, age: float | None, max_age_s: float) -> list[Fault]:
    """Faults of one robot's newest joint state: none yet, or too old."""
    if joint is None:
        return [Fault("joint_state_missing", f"no valid joint state from robot {robot!r} yet")]
    if age is not None and age > max_age_s:
        return [Fault("joint_state_stale", f"joint state is {age:.3f} s old (limit {max_age_s} s)")]
    return []


def override_path_faults(path: OverridePathEstimate, now_mono_ns: int, max_age_s: float) -> list[Fault]:
    """Faults of the override path: never echoed, or its newest echo is of an override sent too long ago."""
    if path.latency_s is None or path.acked_sent_mono_ns is None:
        return [Fault("override_path_unconfirmed", "the controller has not yet echoed an override")]
    ack_age_s = (now_mono_ns - path.acked_sent_mono_ns) / NS_PER_S
    if ack_age_s > max_age_s:
        return [
            Fault("override_path_stale", f"newest override echoed was sent {ack_age_s:.3f} s ago (limit {max_age_s} s)")
        ]
    return []


def _until_next_decision_s(gateway_period_s: float, watchdog_s: float) -> float:
    """How long a robot may run on this decision's δ: until the next decision, at most its controller's watchdog
    (after which it stops on its own) [s]. A period that is not a finite number stays so (the core's guard gives δ = 0
    for it)."""
    return min(gateway_period_s, watchdog_s) if math.isfinite(gateway_period_s) else gateway_period_s


OPEN_METHOD = "zanchettin2016"
"""The method an open robot's LPs implement (their rows are eq. (15)'s, §4): a cell with one must select it."""


def _open_robot(config: CellConfig, name: str, robot: RobotModel) -> OpenRobot | None:
    """The open robot's task (its program, which the gateway runs) when its controller is open, else None."""
    robot_config = config.robots.get(name)
    if robot_config is None or robot_config.controller.control != "open":
        return None
    if config.safety.method != OPEN_METHOD:
        raise ConfigError(
            f"robot {name!r} has an open controller, which the gateway drives with LP (9)/(13) on eq. (15)'s rows; "
            f"safety.method = {config.safety.method!r} is for closed controllers; allowed with an open one: "
            f"{OPEN_METHOD!r}"
        )
    return OpenRobot(
        robot,
        load_trajectory(robot_config.program, robot),
        1.0 / config.gateway.rate_hz,
        robot_config.controller.braking_time_s,
    )


class SafetyCore:
    """Steps all robots from an input snapshot; holds one :class:`RobotState` per robot.

    Building it checks each robot's compiled kinematics against Pinocchio and compiles the per-cycle kernels
    (or loads them from numba's cache): :class:`gateway.kernels.RobotKernels`.

    Raises:
        ConfigError: a robot has a joint the compiled kinematics does not support, or they differ from
            Pinocchio's.
    """

    def __init__(
        self,
        config: CellConfig,
        robots: dict[str, RobotModel],
        planner_backend: Callable[[dict[str, JointPlanner]], PlannerBackend] | None = None,
    ) -> None:
        """``planner_backend`` builds the planner layer's backend from the robots' planners when ``planner.enabled``
        (default: :class:`gateway.planner_worker.ProcessPlanner`; the simulated cell passes the synchronous one)."""
        self.config = config
        self.robots = robots
        safety = config.safety
        hold_ns = int(config.zones.adaptive_speed_hold_s * NS_PER_S)
        self.states = {
            name: RobotState(
                name,
                robot,
                RobotKernels(robot, safety),
                robot.model.createData(),
                WindowMax(hold_ns),
                ReplanMonitor(safety.replan_delta_below, safety.replan_after_s),
                f"robot/{name}",
                config.robots[name].controller.watchdog_s,
                _open_robot(config, name, robot),
            )
            for name, robot in robots.items()
        }
        self.planner: PlannerBackend | None = self._planner_layer(planner_backend)
        self._planner_health: PlannerHealth | None = None
        self._delay_aware = not safety.unsafe_ignore_delay_for_tests
        self._method: OverrideMethod = build_method(
            safety, robots, {name: config.robots[name].program for name in robots if name in config.robots}
        )
        # The trackers' newest frames and their merge: a frame changes at the tracker's rate (~30 Hz), not the
        # gateway's, so the merge is redone only when one of them is a new object (held here, so no id reuse).
        self._merged: tuple[tuple[HumanCapsules, ...], HumanCapsules, npt.NDArray[np.float64]] = (
            (),
            NO_HUMANS,
            capsule_columns(NO_HUMANS),
        )
        self._tracker_topics = {tracker: f"tracker/{tracker}" for tracker in config.trackers}
        self.tracks = TrackSet(config)
        self.capsules: HumanCapsules = NO_HUMANS
        """The people the latest step kept clear of: seen and lost (grown) capsules."""
        self.track_events: list[TrackEvent] = []
        """The tracks' changes of the latest step (lost, released), for the event log."""

    def step(
        self,
        inputs: InputSnapshot,
        now: Clocks,
        gateway_period_s: float,
        resets: tuple[TrackReset, ...] = (),
    ) -> dict[str, RobotDecision]:
        """One decision per robot at ``now``; ``gateway_period_s`` bounds the time until the next decision [s] (per
        robot at most its controller's watchdog: a controller that hears no override for that long stops on its own);
        ``resets``: operators' resets of lost tracks received since the previous step."""
        humans = self._humans_view(inputs, now.mono_ns, resets)
        self.capsules = humans.capsules
        if self.planner is not None:  # plans that came back since the last step: adopted before this step's commands
            for outcome in self.planner.poll():
                replanner = self.states[outcome.robot].replanner
                if replanner is not None:
                    replanner.take(outcome, now.mono_ns)
            self._planner_health = self.planner.health()
        return {
            name: self._decide(state, inputs, now, humans, _until_next_decision_s(gateway_period_s, state.watchdog_s))
            for name, state in self.states.items()
        }

    def _planner_layer(
        self, backend: Callable[[dict[str, JointPlanner]], PlannerBackend] | None
    ) -> PlannerBackend | None:
        """The planner layer's replanners (open robots) and backend, when ``planner.enabled``; else None."""
        settings = self.config.planner
        if not settings.enabled:
            return None
        planners: dict[str, JointPlanner] = {}
        for name, state in self.states.items():
            if state.open is None:
                continue
            limits = state.open.limits
            planners[name] = JointPlanner(
                state.robot, state.open.active, limits.qd_max_radps, limits.qdd_max_radps2, settings.time_limit_s
            )
            state.replanner = Replanner(
                name,
                settings,
                self.config.safety.human_speed_mps,
                state.open,
                request_after_s=self.config.safety.replan_after_s,
            )
        if not planners:
            return None
        return (backend or ProcessPlanner)(planners)

    def close(self) -> None:
        """Stop the planner layer's backend (its thread), if any."""
        if self.planner is not None:
            self.planner.close()

    def track_records(self) -> tuple[TrackRecord, ...]:
        """Every track (seen, lost, recently released), for the status."""
        return self.tracks.records()

    def _humans_view(self, inputs: InputSnapshot, now_mono_ns: int, resets: tuple[TrackReset, ...] = ()) -> HumansView:
        max_age_s = self.config.safety.max_data_age_s
        faults: list[Fault] = [] if inputs.clock_fault is None else [inputs.clock_fault]
        ages: dict[str, float | None] = {}
        frames: list[HumanCapsules] = []
        events = self.tracks.update(
            {
                tracker: None
                if frame is None
                else (frame, frame.capsules, frame.received_mono_ns - frame.transit_ns, frame.human_starts)
                for tracker, frame in inputs.humans.items()
            },
            now_mono_ns,
        )
        for reset in resets:
            events += self.tracks.reset(reset.track, reset.operator, now_mono_ns)
        self.track_events = events
        if self.tracks.overflow:
            faults.append(
                Fault(
                    "tracks_overflow",
                    f"{len(self.tracks.live)} people tracked (seen or lost), more than {MAX_LIVE_TRACKS}: "
                    "a tracker reports more people than a cell can hold",
                )
            )
        oldest_s = -1.0
        for tracker, frame in inputs.humans.items():
            topic = self._tracker_topics.get(tracker) or self._tracker_topics.setdefault(tracker, f"tracker/{tracker}")
            age = age_s(frame, now_mono_ns)
            ages[topic] = age
            oldest_s = max(oldest_s, max_age_s if age is None else age)  # no data yet counts as data at the limit
            faults += tracker_faults(tracker, frame, age, max_age_s)
            if topic in inputs.faults:
                faults.append(inputs.faults[topic])
            if frame is not None:
                frames.append(frame.capsules)
        capsules, columns = self._merge(tuple(frames))
        lost = self.tracks.lost_capsules(now_mono_ns)
        if lost.n_capsules:  # grows every cycle: merged and compiled anew while anyone is lost
            capsules = merge_humans([capsules, lost])
            columns = capsule_columns(capsules)
        return HumansView(capsules, columns, max_age_s if oldest_s < 0.0 else oldest_s, ages, tuple(faults))

    def _merge(self, frames: tuple[HumanCapsules, ...]) -> tuple[HumanCapsules, npt.NDArray[np.float64]]:
        """``merge_humans(frames)`` and its capsule columns, cached while the frames are the same objects."""
        previous = self._merged[0]
        if len(frames) != len(previous) or not all(map(operator.is_, frames, previous)):
            humans = merge_humans(list(frames))
            self._merged = (frames, humans, capsule_columns(humans))
        return self._merged[1], self._merged[2]

    def _delay(
        self, joint_age: float | None, path: OverridePathEstimate, humans_age_s: float, period_s: float
    ) -> DelayBudget:
        if not self._delay_aware:  # test-only: shows that the delay terms matter
            return DelayBudget(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        max_age_s = self.config.safety.max_data_age_s
        return DelayBudget(  # positional (a keyword call costs twice as much): the fields' order
            self.config.safety.t_reaction_s,
            humans_age_s,
            max_age_s if joint_age is None else joint_age,
            max_age_s if path.latency_s is None else path.latency_s,
            max_age_s if path.controller_cycle_s is None else path.controller_cycle_s,
            period_s,
        )

    def _decide(
        self, state: RobotState, inputs: InputSnapshot, now: Clocks, humans: HumansView, period_s: float
    ) -> RobotDecision:
        max_age_s = self.config.safety.max_data_age_s
        joint = inputs.joint[state.name]
        joint_age = age_s(joint, now.mono_ns)
        path = inputs.override_path[state.name]
        faults = list(humans.faults)
        faults += joint_faults(state.name, joint, joint_age, max_age_s)
        if state.topic in inputs.faults:
            faults.append(inputs.faults[state.topic])
        faults += override_path_faults(path, now.mono_ns, max_age_s)
        delay = self._delay(joint_age, path, humans.age_s, period_s)
        t_delay_s = delay.total_s
        t_brake_max_s = state.kernels.t_brake_max_s
        clearance = decision_clearance_m(self.config.safety, t_brake_max_s, t_delay_s)
        if state.open is not None:
            return self._decide_open(state, state.open, joint, joint_age, faults, delay, clearance, humans, now)
        delta_bound, min_distance, closest, speed_mps, links = 0.0, None, None, 0.0, None
        if joint is not None:
            delta_bound, min_distance, closest, speed_mps, links = self._bound(
                state, joint, humans, t_delay_s, clearance, period_s
            )
        thresholds = zone_thresholds(
            self.config.zones,
            clearance,
            t_brake_max_s + t_delay_s,
            state.speed_hold.push(now.mono_ns, speed_mps),
            self._method.protection(t_brake_max_s, t_delay_s, clearance),  # each method's own stopping model
        )
        if faults:
            state.zone, delta = Zone.SAFETY_EXCEPTION, 0.0
        else:
            state.zone = next_zone(state.zone, min_distance, delta_bound, thresholds, self.config.zones)
            delta = commanded_override(state.zone, delta_bound)
        state.previous_delta = delta
        return RobotDecision(  # positional (a keyword call costs twice as much), in the order of the fields
            state.name,
            state.zone,
            delta,
            delta_bound,
            min_distance,
            closest,
            delay,
            clearance,
            thresholds,
            tuple(faults),
            {"joint_state": joint_age, **humans.ages_s},
            joint.mode if joint else None,
            state.replan.update(now.mono_ns, delta, faulted=bool(faults)),
            joint.override if joint else None,
            links,
            self._method.bounded_by(state.name) if isinstance(self._method, ContactAware) and joint else None,
        )

    def _decide_open(
        self,
        state: RobotState,
        open_robot: OpenRobot,
        joint: JointSample | None,
        joint_age: float | None,
        faults: list[Fault],
        delay: DelayBudget,
        clearance: float,
        humans: HumansView,
        now: Clocks,
    ) -> RobotDecision:
        """An open robot's decision: LP (9), the zones on its δ*, LP (13) at the zones' δ (docs/safety-math.md §13).

        The rows are eq. (15)'s at the measured joints (the same people, Δ, delay and faults as a closed robot); the
        zones and faults cap δ exactly as for a closed robot (a fault: the ramp stop). Without a joint state there is
        nothing to command from: no command (the controller's watchdog stops it)."""
        t_delay_s = delay.total_s
        t_brake_max_s = state.kernels.t_brake_max_s
        min_distance: float | None = None
        closest: ClosestPair | None = None
        speed_mps, links, command = 0.0, None, None
        chosen = [0.0]  # δ* as the cap saw it
        rows, usable = None, False
        if joint is not None:
            _, qd_program = open_robot.reference_sample()
            kernel_links, speed_mps, rows, (i, j, distance_m), finite = state.kernels.cycle(
                joint.q_rad, np.array(qd_program, dtype=np.float64), humans.columns, t_delay_s
            )
            usable = finite and math.isfinite(t_delay_s + clearance)
            if i >= 0:
                capsules = humans.capsules
                min_distance = distance_m
                closest = ClosestPair(capsules.human_ids[j], capsules.capsule_names[j], state.robot.link_names[i])
        thresholds = zone_thresholds(
            self.config.zones,
            clearance,
            t_brake_max_s + t_delay_s,
            state.speed_hold.push(now.mono_ns, speed_mps if usable else 0.0),
            self._method.protection(t_brake_max_s, t_delay_s, clearance),
        )
        if joint is not None and rows is not None:

            def cap(delta_star: float) -> float:
                chosen[0] = delta_star
                if faults:
                    state.zone = Zone.SAFETY_EXCEPTION
                    return 0.0
                state.zone = next_zone(state.zone, min_distance, delta_star, thresholds, self.config.zones)
                return commanded_override(state.zone, delta_star)

            near_points, near_m = nearest_people(
                kernel_links, humans.capsules, rows.surface_distance_m if usable else None
            )
            command = open_robot.command(
                joint.q_rad,
                joint.override * joint.qd_nominal_radps,
                now.mono_ns,
                kernel_links,
                rows if usable else None,
                humans.capsules,
                near_points,
                near_m,
                cap,
                override_from_rows(rows) if usable else 0.0,
                delay.joint_state_age_s + delay.override_path_s + delay.controller_cycle_s + delay.gateway_period_s,
            )
            links = LinkEnds(kernel_links.p_a_world, kernel_links.p_b_world)
        else:
            state.zone = Zone.SAFETY_EXCEPTION
        # a ramp stop is a commanded stop (δ = 0); its solution's δ only paces the task's time along the stop
        delta = 0.0 if command is None or command.solution.how.startswith("ramp_stop") else command.solution.delta
        state.previous_delta = delta
        request_16 = state.replan.update(now.mono_ns, delta, faulted=bool(faults))
        if state.replanner is not None and self.planner is not None and command is not None:
            state.replanner.cycle(
                now.mono_ns, humans.capsules, request_16, bool(faults), thresholds.resume_m, self.planner
            )
        return RobotDecision(
            state.name,
            state.zone,
            delta,
            min(max(chosen[0], 0.0), 1.0) if chosen[0] == chosen[0] else 0.0,
            min_distance,
            closest,
            delay,
            clearance,
            thresholds,
            tuple(faults),
            {"joint_state": joint_age, **humans.ages_s},
            joint.mode if joint else None,
            request_16,
            joint.override if joint else None,
            links,
            None if command is None else (command.solution.bounded_by or command.solution.how),
            command,
            None if state.replanner is None else state.replanner.view(self._planner_health),
        )

    def _bound(
        self,
        state: RobotState,
        joint: JointSample,
        humans: HumansView,
        t_delay_s: float,
        clearance_m: float,
        period_s: float,
    ) -> tuple[float, float | None, ClosestPair | None, float, LinkEnds]:
        """The method's δ bound, the closest pair and its distance [m], the largest link-end speed [m/s], the links.

        The one guard against numbers that are not finite, for every method: δ = 0 when q, q̇_nominal, a capsule,
        t_delay, Δ, δ_prev or T is not finite (the kernel checks the arrays), or when the method's bound is nan.
        """
        links, speed_mps, rows, (i, j, distance_m), inputs_finite = state.kernels.cycle(
            joint.q_rad, joint.qd_nominal_radps, humans.columns, t_delay_s
        )
        bound = 0.0
        if inputs_finite and math.isfinite(t_delay_s + clearance_m + state.previous_delta + period_s):
            bound = self._method.bound(
                MethodInput(
                    state.robot,
                    state.data,
                    joint.q_rad,
                    links,
                    rows,
                    humans.capsules,
                    joint.qd_nominal_radps,
                    t_delay_s,
                    clearance_m,
                    state.previous_delta,
                    period_s,
                    speed_mps,
                )
            )
            bound = bound if bound == bound else 0.0  # nan never moves a robot
        else:
            speed_mps = 0.0  # not a speed: kept out of the adaptive thresholds' hold window
        ends = LinkEnds(links.p_a_world, links.p_b_world)
        if i < 0:  # nobody seen
            return bound, None, None, speed_mps, ends
        capsules = humans.capsules
        closest = ClosestPair(capsules.human_ids[j], capsules.capsule_names[j], state.robot.link_names[i])
        return bound, distance_m, closest, speed_mps, ends
