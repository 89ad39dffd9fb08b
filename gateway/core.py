"""The gateway's core: one step from an input snapshot and a time to one decision per robot.

No I/O, no clock: the caller passes ``now_ns``. Faults (missing, stale or invalid input, an override
path that is not confirmed) force δ = 0 for the robots they concern and put the robot in
``safety_exception``, from which it recovers by the zone rules once the fault has cleared.
"""

from __future__ import annotations

import operator
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from gateway.delay import NS_PER_S, DelayBudget, WindowMax
from gateway.inputs import InputSnapshot, JointSample
from gateway.kernels import RobotKernels, capsule_columns
from gateway.methods import MethodInput, ReplanMonitor, build_method
from gateway.metric import decision_clearance_m
from gateway.zones import Zone, ZoneThresholds, commanded_override, next_zone, zone_thresholds
from hrc_common.config import CellConfig
from hrc_common.humans import NO_HUMANS, HumanCapsules, merge_humans
from hrc_common.robot_model import RobotModel


class Fault(NamedTuple):
    code: str
    reason: str


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


def _age_s(stamp_ns: int | None, now_ns: int) -> float | None:
    if stamp_ns is None:
        return None
    age_s = (now_ns - stamp_ns) / NS_PER_S
    return age_s if age_s > 0.0 else 0.0


class _Merged(NamedTuple):
    """The capsules of all trackers, merged from ``frames``, and their columns for the compiled rows."""

    frames: tuple[HumanCapsules, ...]
    humans: HumanCapsules
    capsules: npt.NDArray[np.float64]


class SafetyCore:
    """Holds the per-robot state between cycles (zone, Pinocchio data) and steps all robots.

    Building it checks each robot's compiled kinematics against Pinocchio and compiles the per-cycle kernels
    (or loads them from numba's cache): :class:`gateway.kernels.RobotKernels`.

    Raises:
        ConfigError: a robot has a joint the compiled kinematics does not support, or they differ from
            Pinocchio's.
    """

    def __init__(self, config: CellConfig, robots: dict[str, RobotModel]) -> None:
        self.config = config
        self.robots = robots
        self._kernels = {name: RobotKernels(robot, config.safety) for name, robot in robots.items()}
        self._data = {name: robot.model.createData() for name, robot in robots.items()}
        self._zones = dict.fromkeys(robots, Zone.SAFETY_EXCEPTION)
        hold_ns = int(config.zones.adaptive_speed_hold_s * NS_PER_S)
        self._speeds = {name: WindowMax(hold_ns) for name in robots}
        self._delay_aware = not config.safety.unsafe_ignore_delay_for_tests
        self._method = build_method(config.safety, robots)
        self._previous_delta = dict.fromkeys(robots, 0.0)
        self._replan = {
            name: ReplanMonitor(config.safety.replan_delta_below, config.safety.replan_after_s) for name in robots
        }
        # The trackers' newest frames and their merge: a frame changes at the tracker's rate (~30 Hz), not the
        # gateway's, so the merge is redone only when one of them is a new object (held here, so no id reuse).
        self._merged = _Merged((), NO_HUMANS, capsule_columns(NO_HUMANS))
        # Input topic names ("robot/<r>", "tracker/<t>"), built once rather than formatted every cycle.
        self._robot_topics = {name: f"robot/{name}" for name in robots}
        self._tracker_topics = {tracker: f"tracker/{tracker}" for tracker in config.trackers}

    def _humans(self, frames: tuple[HumanCapsules, ...]) -> _Merged:
        """``merge_humans(frames)`` and its capsule columns, cached while the frames are the same objects."""
        previous = self._merged.frames
        if len(frames) != len(previous) or not all(map(operator.is_, frames, previous)):
            humans = merge_humans(list(frames))
            self._merged = _Merged(frames, humans, capsule_columns(humans))
        return self._merged

    def step(self, inputs: InputSnapshot, now_ns: int, gateway_period_s: float) -> dict[str, RobotDecision]:
        safety = self.config.safety
        max_age_s = safety.max_data_age_s
        tracker_faults: list[Fault] = []
        tracker_ages: dict[str, float | None] = {}
        human_age_s = -1.0
        frames: list[HumanCapsules] = []
        for tracker, frame in inputs.humans.items():
            if frame is not None:
                frames.append(frame.capsules)
            age = _age_s(frame.stamp_ns if frame else None, now_ns)
            topic = self._tracker_topics.get(tracker) or self._tracker_topics.setdefault(tracker, f"tracker/{tracker}")
            tracker_ages[topic] = age
            age_or_limit_s = max_age_s if age is None else age  # no data yet counts as data at the age limit
            if age_or_limit_s > human_age_s:
                human_age_s = age_or_limit_s
            if frame is None:
                tracker_faults.append(Fault("tracker_missing", f"no valid data from tracker {tracker!r} yet"))
            elif age is not None and age > max_age_s:
                tracker_faults.append(
                    Fault("tracker_stale", f"tracker {tracker!r} data is {age:.3f} s old (limit {max_age_s} s)")
                )
            reason = inputs.invalid.get(topic)
            if reason:
                tracker_faults.append(Fault("tracker_invalid", f"last message of tracker {tracker!r}: {reason}"))
        merged = self._humans(tuple(frames))
        if human_age_s < 0.0:  # no tracker configured
            human_age_s = max_age_s

        decisions = {}
        for name, robot in self.robots.items():
            decisions[name] = self._step_robot(
                name,
                robot,
                inputs,
                now_ns,
                merged,
                human_age_s,
                tracker_faults,
                tracker_ages,
                gateway_period_s,
            )
        return decisions

    def _step_robot(
        self,
        name: str,
        robot: RobotModel,
        inputs: InputSnapshot,
        now_ns: int,
        merged: _Merged,
        human_age_s: float,
        tracker_faults: list[Fault],
        tracker_ages: dict[str, float | None],
        gateway_period_s: float,
    ) -> RobotDecision:
        safety = self.config.safety
        max_age_s = safety.max_data_age_s
        faults = list(tracker_faults)
        joint: JointSample | None = inputs.joint[name]
        joint_age = _age_s(joint.stamp_ns if joint else None, now_ns)
        if joint is None:
            faults.append(Fault("joint_state_missing", f"no valid joint state from robot {name!r} yet"))
        elif joint_age is not None and joint_age > max_age_s:
            faults.append(Fault("joint_state_stale", f"joint state is {joint_age:.3f} s old (limit {max_age_s} s)"))
        reason = inputs.invalid.get(self._robot_topics[name])
        if reason:
            faults.append(Fault("joint_state_invalid", f"last joint state message: {reason}"))

        path = inputs.override_path[name]
        ack_age = _age_s(path.acked_sent_ns, now_ns)
        if path.latency_s is None or ack_age is None:
            faults.append(Fault("override_path_unconfirmed", "the controller has not yet echoed an override"))
        elif ack_age > max_age_s:
            faults.append(
                Fault(
                    "override_path_stale",
                    f"newest override echoed was sent {ack_age:.3f} s ago (limit {max_age_s} s)",
                )
            )

        if self._delay_aware:
            delay = DelayBudget(  # positional (a keyword call costs twice as much): the fields' order
                safety.t_reaction_s,
                human_age_s,
                joint_age if joint_age is not None else max_age_s,
                path.latency_s if path.latency_s is not None else max_age_s,
                path.controller_cycle_s if path.controller_cycle_s is not None else max_age_s,
                gateway_period_s,
            )
        else:  # test-only: shows that the delay terms matter
            delay = DelayBudget(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        t_delay = delay.total_s
        kernels = self._kernels[name]
        t_brake_max = kernels.t_brake_max_s
        clearance = decision_clearance_m(safety, t_brake_max, t_delay)

        delta_bound = 0.0
        min_distance: float | None = None
        closest: ClosestPair | None = None
        speed_mps = 0.0
        humans = merged.humans
        if joint is not None:
            links, speed_mps, rows, (i, j, distance_m) = kernels.cycle(
                joint.q_rad, joint.qd_nominal_radps, merged.capsules, t_delay
            )
            delta_bound = self._method.bound(
                MethodInput(
                    robot,
                    self._data[name],
                    joint.q_rad,
                    links,
                    rows,
                    humans,
                    joint.qd_nominal_radps,
                    t_delay,
                    clearance,
                    self._previous_delta[name],
                    gateway_period_s,
                )
            )
            if i >= 0:  # a capsule is seen
                min_distance = distance_m
                closest = ClosestPair(humans.human_ids[j], humans.capsule_names[j], robot.link_names[i])

        thresholds = zone_thresholds(
            self.config.zones,
            clearance,
            t_brake_max + t_delay,
            self._speeds[name].push(now_ns, speed_mps),  # the adaptive thresholds' held speed
        )
        if faults:
            zone = Zone.SAFETY_EXCEPTION
            delta = 0.0
        else:
            zone = next_zone(self._zones[name], min_distance, delta_bound, thresholds, self.config.zones)
            delta = commanded_override(zone, delta_bound)
        self._zones[name] = zone
        self._previous_delta[name] = delta
        replan = self._replan[name].update(now_ns, delta, faulted=bool(faults))
        ages = {"joint_state": joint_age, **tracker_ages}
        return RobotDecision(  # positional (a keyword call costs twice as much), in the order of the fields
            name,
            zone,
            delta,
            delta_bound,
            min_distance,
            closest,
            delay,
            clearance,
            thresholds,
            tuple(faults),
            ages,
            joint.mode if joint else None,
            replan,
        )
