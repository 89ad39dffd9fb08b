"""The whole cell on a simulated clock, in one process, with the real pure parts of each program.

- controllers: :class:`controller_emu.node.ControllerNode`, the process's own step object, given each override
  at its arrival time and cycled every ``controller.cycle_s`` (simulated time is its monotonic clock); an open
  controller (``control = "open"``) is :class:`controller_emu.open_node.OpenControllerNode`, given each joint command;
- trackers: :class:`tracker_emu.emulator.TrackerEmulator` playing the scenario (rate, noise, drops, latency);
- gateway: :class:`gateway.node.GatewayNode`, the process's own step object, given every message at its arrival
  time and cycled at ``gateway.rate_hz`` (simulated time on both of its clocks);
- the three paths (tracker → gateway, controller → gateway, gateway → controller) are
  :class:`hrc_tools.sim.links.SimLink`
  carrying the contract's payload bytes, so that every message is serialised and validated;
- a robot whose ``interface`` is ``ur_rtde`` or ``abb_rws`` is reached through the controller bridge's core and
  the emulator's vendor face (:mod:`hrc_tools.sim.bridged`): the two links then end at the bridge;
- the auditor checks every controller cycle the TRUE controller state (no link) against the TRUE humans
  (the scenario, no noise) with :func:`hrc_tools.audit.checks.audit_cycle`.

Time is integer nanoseconds from the start of the run; stamps are ``EPOCH_NS`` + that. Everything random
is seeded: one seed gives one run.
"""

from __future__ import annotations

import math
import time
import zlib
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from controller_bridge.main import bridge_settings
from controller_emu.node import ControllerNode
from controller_emu.open_follower import follower_limits
from controller_emu.open_node import OpenControllerNode
from gateway.core import RobotDecision
from gateway.node import GatewayNode
from gateway.open_robot import OpenRobot
from gateway.planner import JointPlanner
from gateway.planner_worker import PlannerBackend, SimulatedPlanner
from gateway.tracks import TrackEvent
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.messages import to_payload
from hrc_devices.controllers.descriptor import BridgedConfig
from hrc_devices.robots.link_motion import link_motion
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import Trajectory, load_trajectory
from hrc_devices.robots.time_scaling import ControllerState, check_braking_time
from hrc_runtime.clocks import Clocks
from hrc_tools.audit.checks import (
    MOVING_EPS_MPS,
    AuditAccumulator,
    AuditSummary,
    audit_cycle,
    merge_summaries,
    open_stop_fraction,
)
from hrc_tools.audit.contact import ContactMass, ContactRules, audit_contacts
from hrc_tools.sim.bridged import SimBridge
from hrc_tools.sim.links import NS_PER_S, LinkFault, LinkFaults, SimLink
from hrc_tools.sim.ros2_adapter import ZedRoundTrip
from hrc_tools.sim.truth import true_humans
from tracker_emu.emulator import TrackerEmulator
from tracker_emu.robot_links import RobotAt, robots_capsules
from tracker_emu.scenario import Scenario
from tracker_emu.sensor import covered_volume

EPOCH_NS = 1_790_000_000_000_000_000
"""Wall-clock stamp of simulated time 0 [ns since the Unix epoch]."""

Payload = tuple[str, bytes]
FloatArray = npt.NDArray[np.float64]
"""A message on a link: its key expression and its payload bytes."""


@dataclass(frozen=True)
class RunResult:
    """What one simulated run produced.

    Attributes:
        audit: the auditor's summary over all robots.
        per_robot: the auditor's summary per robot.
        t_delay_mean_s, t_delay_min_s, t_delay_max_s: t_delay of the gateway's fault-free decisions
            (None if there was none) [s].
        program_progress_cycles: program cycles run, with the fraction of the unfinished one (all robots):
            the productivity figure, without the rounding of whole cycles in short runs.
        decisions: gateway decisions (robots × gateway cycles).
        fault_decisions: decisions with at least one fault (δ forced to 0).
        faults: decisions per fault code.
        rejected: gateway input rejections per topic and reason.
        controller_rejected: overrides rejected by the controllers, per reason.
        duration_s: simulated time [s].
        wall_s: wall-clock time the run took (not deterministic; left out of :meth:`to_dict`) [s].
        tracks: the gateway's track changes: ``track_lost``, and ``released_<cause>`` per release cause
            (gateway/tracks.py).
        lost_at_end: tracks still lost when the run ended.
        bridges: per bridged robot, the bridge's figures (:meth:`hrc_tools.sim.bridged.SimBridge.summary`).
    """

    audit: AuditSummary
    per_robot: Mapping[str, AuditSummary]
    t_delay_mean_s: float | None
    t_delay_min_s: float | None
    t_delay_max_s: float | None
    program_progress_cycles: float
    decisions: int
    fault_decisions: int
    faults: Mapping[str, int]
    rejected: Mapping[str, Mapping[str, int]]
    controller_rejected: Mapping[str, int]
    duration_s: float
    wall_s: float = field(compare=False)
    tracks: Mapping[str, int] = field(default_factory=dict)
    lost_at_end: int = 0
    bridges: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    planner: Mapping[str, Mapping[str, Any]] = field(default_factory=dict, compare=False)
    """Per open robot with the planner layer on, what it did (:meth:`gateway.planner_worker.ReplannerStats.to_dict`;
    planning times are wall clock: left out of :meth:`to_dict`)."""

    @property
    def speedup(self) -> float:
        """Simulated time per wall-clock time."""
        return self.duration_s / self.wall_s if self.wall_s > 0.0 else math.inf

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary of the deterministic results (no wall time)."""
        return {
            "audit": self.audit.to_dict(),
            "per_robot": {name: s.to_dict() for name, s in self.per_robot.items()},
            "t_delay_mean_s": self.t_delay_mean_s,
            "t_delay_min_s": self.t_delay_min_s,
            "t_delay_max_s": self.t_delay_max_s,
            "program_progress_cycles": self.program_progress_cycles,
            "decisions": self.decisions,
            "fault_decisions": self.fault_decisions,
            "faults": dict(sorted(self.faults.items())),
            "rejected": {t: dict(sorted(r.items())) for t, r in sorted(self.rejected.items())},
            "controller_rejected": dict(sorted(self.controller_rejected.items())),
            "duration_s": self.duration_s,
            "tracks": dict(sorted(self.tracks.items())),
            "lost_at_end": self.lost_at_end,
            "bridges": {name: dict(b) for name, b in sorted(self.bridges.items())},
        }


def _rng(seed: int, *names: str) -> np.random.Generator:
    """A generator fixed by the seed and a name, whatever else draws numbers."""
    return np.random.default_rng([seed, *(zlib.crc32(n.encode()) for n in names)])


class TraceSample(NamedTuple):
    """One audited controller cycle, for a run's time series (``simulate(trace=...)``).

    Attributes:
        t_s: simulated time [s].
        robot: the robot's name.
        q_rad: its true joint positions [rad].
        delta: the δ the gateway last commanded (for an open robot: the δ of its LP).
        min_distance_m: the true smallest surface distance to a person, None with nobody [m].
        zone: the gateway's zone of the robot's last decision.
    """

    t_s: float
    robot: str
    q_rad: FloatArray
    delta: float
    min_distance_m: float | None
    zone: str | None


@dataclass
class _Controller:
    name: str
    robot: RobotModel
    node: ControllerNode | OpenControllerNode
    trajectory: Trajectory
    cycle_ns: int
    tau0_s: float
    data: Any
    state_link: SimLink[Payload]
    override_link: SimLink[Payload]
    accumulator: AuditAccumulator
    braking_time_s: float
    next_ns: int = 0
    zone: str | None = None
    delta_commanded: float = 0.0
    bridge: SimBridge | None = None
    task: OpenRobot | None = None
    """An open robot's task in the gateway (its program time τ): the program's progress."""

    @property
    def state(self) -> ControllerState:
        """A closed controller's state (the program time, δ applied)."""
        assert isinstance(self.node, ControllerNode)
        return self.node.state

    def true_motion(self, moving_eps_mps: float = MOVING_EPS_MPS) -> tuple[FloatArray, FloatArray, float]:
        """The robot's true q [rad], q̇ [rad/s] and the fraction of its stop still ahead: δ applied (closed), or the
        speed fraction max_j |q̇_j| / q̇max_j (open: its stop from there lasts that fraction of the stop time; 0 when
        every link end moves slower than ``moving_eps_mps``, the auditor's standing robot: a position loop holding
        its reference creeps at far less)."""
        if isinstance(self.node, OpenControllerNode):
            state = self.node.state
            return (
                state.q_rad,
                state.qd_radps,
                open_stop_fraction(self.robot, self.data, state.q_rad, state.qd_radps, moving_eps_mps),
            )
        q_rad, qd_nominal_radps = self.trajectory.sample(self.state.tau_s)
        delta_applied = self.state.delta_applied
        return q_rad, delta_applied * qd_nominal_radps, delta_applied

    def cycles_completed(self) -> int:
        """Times the program passed its end since the start (an open robot: by the gateway's program time)."""
        if self.task is not None:
            duration = self.trajectory.duration_s
            return int(self.task.progress_tau_s() // duration) - int(self.tau0_s // duration)
        return self.state.cycles_completed

    def progress_cycles(self) -> float:
        """Program cycles completed since the start, the unfinished one by its fraction (an open robot: the
        gateway's program time)."""
        if self.task is not None:
            return (self.task.progress_tau_s() - self.tau0_s) / self.trajectory.duration_s
        return self.state.cycles_completed + (self.state.tau_s - self.tau0_s) / self.trajectory.duration_s


def _build_controller(
    config: CellConfig,
    name: str,
    robot: RobotModel,
    links: LinkFaults,
    seed: int,
    program_start_s: Mapping[str, float] | None,
) -> _Controller:
    """A robot's controller node (program started at ``program_start_s`` or a seeded phase) and its two links.

    Raises:
        ConfigError: the controller's braking time exceeds the gateway's, or the program is invalid.
    """
    robot_config = config.robots[name]
    check_braking_time(robot_config.controller, robot)
    trajectory = load_trajectory(robot_config.program, robot)
    if program_start_s is not None and name in program_start_s:
        tau0_s = program_start_s[name] % trajectory.duration_s
    else:
        tau0_s = float(_rng(seed, "program-phase", name).uniform(0.0, trajectory.duration_s))
    controller = robot_config.controller
    node: ControllerNode | OpenControllerNode
    if controller.control == "open":
        node = OpenControllerNode(
            name,
            follower_limits(robot, controller.watchdog_s, stop_time_s=controller.braking_time_s),
            trajectory.sample(tau0_s)[0],
            controller,
        )
    else:
        node = ControllerNode(name, trajectory, controller, tau0_s)
    ctrl = _Controller(
        name=name,
        robot=robot,
        node=node,
        trajectory=trajectory,
        braking_time_s=controller.braking_time_s,
        cycle_ns=round(robot_config.controller.cycle_s * NS_PER_S),
        tau0_s=tau0_s,
        data=robot.model.createData(),
        state_link=SimLink(links.controller_to_gateway, _rng(seed, "link-state", name)),
        override_link=SimLink(links.gateway_to_controller, _rng(seed, "link-override", name)),
        accumulator=AuditAccumulator(),
    )
    interface = robot_config.interface
    # the simulated bridges speak to closed controllers; an open one's (abb_egm) runs as its Zenoh face here
    if isinstance(interface, BridgedConfig) and isinstance(node, ControllerNode):
        phases = _rng(seed, "bridge-phase", name).integers(0, NS_PER_S, size=2)
        ctrl.bridge = SimBridge(
            interface,
            bridge_settings(config, name, robot),
            node,
            ctrl.override_link,
            ctrl.state_link,
            keys.robot_state(config.cell, name),
            _clocks,
            (int(phases[0]), int(phases[1])),
        )
    return ctrl


@dataclass
class _GatewayTally:
    """What the run counts of the gateway's decisions."""

    t_delays: list[float] = field(default_factory=list)
    decisions: int = 0
    fault_decisions: int = 0
    faults: Counter[str] = field(default_factory=Counter)
    tracks: Counter[str] = field(default_factory=Counter)

    def count_tracks(self, events: Iterable[TrackEvent]) -> None:
        self.tracks.update(e.kind if e.cause is None else f"released_{e.cause}" for e in events)

    def count(self, decision: RobotDecision) -> None:
        self.decisions += 1
        if decision.faults:
            self.fault_decisions += 1
            self.faults.update({f.code for f in decision.faults})
        else:
            self.t_delays.append(decision.delay.total_s)


class _SimCell:
    """The cell's programs and links on one simulated clock; :meth:`run` advances it event by event."""

    def __init__(
        self,
        config: CellConfig,
        robots: Mapping[str, RobotModel],
        scenario: Scenario,
        links: LinkFaults,
        seed: int,
        program_start_s: Mapping[str, float] | None,
        moving_eps_mps: float,
        trace: Callable[[TraceSample], None] | None = None,
        planner_backend: Callable[[dict[str, JointPlanner]], PlannerBackend] | None = None,
    ) -> None:
        self.config = config
        self.trace = trace
        self.scenario = scenario
        self.moving_eps_mps = moving_eps_mps
        self._contact_masses: dict[str, ContactMass] = {}
        self.gateway = GatewayNode(config, robots, planner_backend=planner_backend or SimulatedPlanner)
        self.gateway_period_ns = round(NS_PER_S / config.gateway.rate_hz)
        self.gateway_next_ns = int(_rng(seed, "gateway-phase").integers(0, self.gateway_period_ns))
        self.controllers = {
            name: _build_controller(config, name, robot, links, seed, program_start_s) for name, robot in robots.items()
        }
        for name, ctrl in self.controllers.items():  # an open robot's program runs in the gateway, from the same phase
            task = self.gateway.core.states[name].open
            if task is not None:
                task.tau_s = ctrl.tau0_s
                ctrl.task = task
        self.tracker_links: dict[str, SimLink[Payload]] = {
            name: SimLink(links.tracker_to_gateway, _rng(seed, "link-tracker", name)) for name in config.trackers
        }
        self.emulator = TrackerEmulator(
            scenario, config.trackers, seed, start_s=0.0, coverage=covered_volume(config.tracking)
        )
        self.tracker_next_ns = _ceil_ns(self.emulator.next_event_s())
        self.truth = (-1, true_humans(scenario, 0.0))
        self.tally = _GatewayTally()
        # Trackers with a ROS 2 input are played as the ZED they are, through the gateway's adapter.
        self.ros2 = ZedRoundTrip(config, self.gateway.inputs.count_rejection)

    def run(self, end_ns: int) -> None:
        """Advance to ``end_ns``: at each event time, trackers, then controllers (audited), then the gateway."""
        while True:
            controller_next_ns = min(c.next_ns for c in self.controllers.values())
            bridges = [c.bridge for c in self.controllers.values() if c.bridge is not None]
            bridge_next_ns = min((b.next_event_ns() for b in bridges), default=end_ns)
            now_ns = min(controller_next_ns, self.gateway_next_ns, self.tracker_next_ns, bridge_next_ns)
            if now_ns >= end_ns:
                return
            if self.tracker_next_ns == now_ns:
                self._tracker_frames(now_ns)
            for bridge in bridges:
                bridge.advance(now_ns)
            for ctrl in self.controllers.values():
                if ctrl.next_ns == now_ns:
                    _controller_cycle(ctrl, self.config, now_ns)
                    self._audit(ctrl, now_ns)
                    ctrl.next_ns += ctrl.cycle_ns
            if self.gateway_next_ns == now_ns:
                self._gateway_cycle(now_ns)
                self.gateway_next_ns += self.gateway_period_ns

    def _tracker_frames(self, now_ns: int) -> None:
        now_s = now_ns / NS_PER_S
        robot_links = (  # the true robots, for the sensors with occlusion
            robots_capsules(RobotAt(c.robot, c.data, c.true_motion()[0]) for c in self.controllers.values())
            if self.emulator.occludes and self.emulator.capture_due(now_s)
            else None
        )
        for tracker, message in self.emulator.step(now_s, EPOCH_NS + now_ns, robot_links):
            key = keys.tracker_humans(self.config.cell, tracker)
            payload = self.ros2.frame(tracker, message, self.emulator.present_ids, _clocks(now_ns))
            if payload is not None:  # None: refused by the adapter, counted and faulted
                self.tracker_links[tracker].send((key, payload), now_ns)
        self.tracker_next_ns = max(now_ns + 1, _ceil_ns(self.emulator.next_event_s()))

    def _audit(self, ctrl: _Controller, now_ns: int) -> None:
        """The auditor on this controller cycle: the TRUE state against the TRUE humans."""
        if self.truth[0] != now_ns:
            self.truth = (now_ns, true_humans(self.scenario, now_ns / NS_PER_S))
        truth = self.truth[1]
        q_rad, qd_radps, delta_applied = ctrl.true_motion(self.moving_eps_mps)
        audit = audit_cycle(
            ctrl.robot,
            ctrl.data,
            q_rad,
            qd_radps,
            delta_applied,
            ctrl.braking_time_s,
            truth,
            self.config.safety.human_speed_mps,
            self.moving_eps_mps,
        )
        if audit.min_distance_m is not None and audit.min_distance_m <= 0.0:  # a contact: the criterion of §12
            contacts = audit_contacts(
                link_motion(ctrl.robot, ctrl.data, q_rad, qd_radps),
                ctrl.robot.link_radius_m,
                ctrl.robot.link_names,
                truth,
                self._contact_rules(ctrl),
                self.moving_eps_mps,
                q_rad,
                qd_radps,
            )
            labels = [f"{truth.human_ids[c.capsule]}/{truth.capsule_names[c.capsule]}" for c in contacts]
            ctrl.accumulator.add_contacts(contacts, labels)
        else:
            ctrl.accumulator.add_contacts((), ())
        if self.trace is not None:
            self.trace(
                TraceSample(now_ns / NS_PER_S, ctrl.name, q_rad, ctrl.delta_commanded, audit.min_distance_m, ctrl.zone)
            )
        worst = audit.worst_capsule
        ctrl.accumulator.add(
            audit,
            t_s=now_ns / NS_PER_S,
            dt_s=ctrl.cycle_ns / NS_PER_S,
            delta_applied=delta_applied,
            zone=ctrl.zone,
            program_cycles_completed=ctrl.cycles_completed(),
            capsule_label=None if worst is None else f"{truth.human_ids[worst]}/{truth.capsule_names[worst]}",
        )

    def _contact_rules(self, ctrl: _Controller) -> ContactRules:
        """The contact criterion's view of the cell for one robot (its reflected mass at each contact, Pinocchio)."""
        safety = self.config.safety
        if ctrl.name not in self._contact_masses:
            self._contact_masses[ctrl.name] = ContactMass(ctrl.robot, safety.pfl_payload_kg)
        return ContactRules(
            safety.pfl_body_regions,
            safety.pfl_clamping_surfaces,
            safety.pfl_clamp_margin_m,
            self._contact_masses[ctrl.name],
        )

    def _gateway_cycle(self, now_ns: int) -> None:
        """The gateway node's cycle, exactly the process's: what arrived, then ``cycle``, then the overrides out."""
        _deliver_to_gateway(self.gateway, self.controllers.values(), self.tracker_links.values(), now_ns)
        cycle = self.gateway.cycle(_clocks(now_ns), self.gateway_period_ns / NS_PER_S)
        self.tally.count_tracks(cycle.track_events)
        for name, decision in cycle.decisions.items():
            self.tally.count(decision)
            ctrl = self.controllers[name]
            ctrl.zone = decision.zone.value
            ctrl.delta_commanded = decision.delta
            message = cycle.overrides.get(name)
            if message is None:  # an open robot before its first joint state: nothing to command from
                continue
            if ctrl.task is not None:
                key = keys.robot_joint_command(self.config.cell, name)
            else:
                key = keys.robot_override(self.config.cell, name)
            ctrl.override_link.send((key, to_payload(message)), now_ns)

    def result(self, end_ns: int, wall_s: float) -> RunResult:
        per_robot = {name: c.accumulator.summary() for name, c in self.controllers.items()}
        controller_rejected: Counter[str] = Counter()
        for c in self.controllers.values():
            controller_rejected.update(c.node.stats().rejected)
        t_delays = self.tally.t_delays
        return RunResult(
            audit=merge_summaries(list(per_robot.values())),
            per_robot=MappingProxyType(per_robot),
            t_delay_mean_s=float(np.mean(t_delays)) if t_delays else None,
            t_delay_min_s=min(t_delays) if t_delays else None,
            t_delay_max_s=max(t_delays) if t_delays else None,
            program_progress_cycles=sum(c.progress_cycles() for c in self.controllers.values()),
            decisions=self.tally.decisions,
            fault_decisions=self.tally.fault_decisions,
            faults=MappingProxyType(dict(self.tally.faults)),
            rejected=MappingProxyType(self.gateway.inputs.counters()[0]),
            controller_rejected=MappingProxyType(dict(controller_rejected)),
            duration_s=end_ns / NS_PER_S,
            wall_s=wall_s,
            tracks=MappingProxyType(dict(self.tally.tracks)),
            lost_at_end=len(self.gateway.core.tracks.lost()),
            bridges=MappingProxyType({n: c.bridge.summary() for n, c in self.controllers.items() if c.bridge}),
            planner=MappingProxyType(
                {
                    name: state.replanner.stats.to_dict()
                    for name, state in self.gateway.core.states.items()
                    if state.replanner is not None
                }
            ),
        )


def simulate(
    config: CellConfig,
    robots: Mapping[str, RobotModel],
    scenario: Scenario,
    links: LinkFaults,
    duration_s: float,
    seed: int,
    *,
    program_start_s: Mapping[str, float] | None = None,
    moving_eps_mps: float = MOVING_EPS_MPS,
    trace: Callable[[TraceSample], None] | None = None,
    planner_backend: Callable[[dict[str, JointPlanner]], PlannerBackend] | None = None,
) -> RunResult:
    """Run the cell for ``duration_s`` of simulated time and audit every controller cycle.

    Args:
        config: the cell (safety, zones, gateway rate, the robots' controllers and programs, the trackers
            with their rate, noise, drops and latency).
        robots: the robot models of ``config.robots``.
        scenario: the scripted humans (scenario time 0 = simulated time 0).
        links: delay, jitter, loss and duplication of the three paths.
        duration_s: simulated time [s].
        seed: seed of everything random (sensor noise and drops, links, the gateway's phase, the program phase).
        program_start_s: program time at which each robot's program starts; default: drawn from the seed [s].
        moving_eps_mps: the auditor's ε for contact while moving [m/s].
        trace: called with every audited controller cycle (a time series; None: nothing kept).
        planner_backend: the planner layer's backend when ``planner.enabled`` (default: the synchronous
            :class:`gateway.planner_worker.SimulatedPlanner`; tests pass faulty ones).

    Returns:
        The auditor's summary and the gateway's figures. The same arguments give the same result.
    """
    started_wall_s = time.perf_counter()
    end_ns = round(duration_s * NS_PER_S)
    cell = _SimCell(config, robots, scenario, links, seed, program_start_s, moving_eps_mps, trace, planner_backend)
    try:
        cell.run(end_ns)
    finally:
        cell.gateway.core.close()
    return cell.result(end_ns, time.perf_counter() - started_wall_s)


def _ceil_ns(t_s: float) -> int:
    """The first integer nanosecond at or after ``t_s`` (so that the emulator sees its event as due)."""
    t_ns = math.ceil(t_s * NS_PER_S)
    return t_ns + 1 if t_ns / NS_PER_S < t_s else t_ns


def _controller_cycle(ctrl: _Controller, config: CellConfig, now_ns: int) -> None:
    """One controller cycle: the overrides that arrived, each at its arrival time, then the node's cycle (through a
    bridge: the bridge took the overrides and gave the node its writes; its face keeps the cycle's state)."""
    if ctrl.bridge is not None:
        assert isinstance(ctrl.node, ControllerNode)  # the bridges speak to closed controllers
        ctrl.bridge.on_cycle(ctrl.node.cycle(_clocks(now_ns)))
        return
    node = ctrl.node
    for arrived_ns, (_, payload) in ctrl.override_link.deliver(now_ns):
        if isinstance(node, OpenControllerNode):
            node.on_command(payload, _clocks(arrived_ns))
        else:
            node.on_override(payload, _clocks(arrived_ns))
    output = node.cycle(_clocks(now_ns))
    ctrl.state_link.send((keys.robot_state(config.cell, ctrl.name), to_payload(output.joint_state)), now_ns)


def _clocks(t_ns: int) -> Clocks:
    """Simulated time ``t_ns`` on both clocks: the wall clock starts at ``EPOCH_NS``, the monotonic one at 0."""
    return Clocks(EPOCH_NS + t_ns, t_ns)


def _deliver_to_gateway(
    node: GatewayNode,
    controllers: Iterable[_Controller],
    tracker_links: Iterable[SimLink[Payload]],
    now_ns: int,
) -> None:
    """Hand every message that has arrived by ``now_ns`` to the gateway, in arrival order, at its arrival time."""
    arrived: list[tuple[int, int, str, bytes]] = []
    sources = [c.state_link for c in controllers] + list(tracker_links)
    for index, link in enumerate(sources):
        arrived.extend((t_ns, index, key, payload) for t_ns, (key, payload) in link.deliver(now_ns))
    arrived.sort(key=lambda m: (m[0], m[1]))  # stable: a link's own order is kept at equal times
    for t_ns, _, key, payload in arrived:
        node.on_message(key, payload, _clocks(t_ns))


__all__ = ["EPOCH_NS", "LinkFault", "LinkFaults", "RunResult", "simulate"]
