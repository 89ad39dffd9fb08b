"""The whole cell on a simulated clock, in one process, with the real pure parts of each program.

- controllers: :func:`controller_emu.controller.accept_override` / :func:`~controller_emu.controller.step` /
  :func:`~controller_emu.controller.joint_state` over the robot's program, every ``controller.cycle_s``;
- trackers: :class:`tracker_emu.emulator.TrackerEmulator` playing the scenario (rate, noise, drops, latency);
- gateway: :class:`gateway.inputs.InputStore` + :class:`gateway.core.SafetyCore` stepped at
  ``gateway.rate_hz`` exactly as ``gateway/main.py`` does (overrides stamped and sent, then
  ``on_override_sent``);
- the three paths (tracker → gateway, controller → gateway, gateway → controller) are :class:`sim.links.SimLink`
  carrying the contract's payload bytes, so that every message is serialised and validated;
- the auditor checks every controller cycle the TRUE controller state (no link) against the TRUE humans
  (the scenario, no noise) with :func:`audit.checks.audit_cycle`.

Time is integer nanoseconds from the start of the run; stamps are ``EPOCH_NS`` + that. Everything random
is seeded: one seed gives one run.
"""

from __future__ import annotations

import math
import time
import zlib
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from audit.checks import MOVING_EPS_MPS, AuditAccumulator, AuditSummary, audit_cycle, merge_summaries
from controller_emu.controller import ControllerState, accept_override, check_braking_time, joint_state, step
from controller_emu.program import Trajectory, load_trajectory
from gateway.core import RobotDecision, SafetyCore
from gateway.inputs import InputStore
from hrc_common import keys
from hrc_common.config import CellConfig
from hrc_common.messages import MessageError, Override, parse_message, to_payload
from hrc_common.robot_model import RobotModel
from sim.links import NS_PER_S, LinkFault, LinkFaults, SimLink
from sim.truth import true_humans
from tracker_emu.emulator import TrackerEmulator
from tracker_emu.scenario import Scenario

EPOCH_NS = 1_790_000_000_000_000_000
"""Wall-clock stamp of simulated time 0 [ns since the Unix epoch]."""

Payload = tuple[str, bytes]
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
        }


def _rng(seed: int, *names: str) -> np.random.Generator:
    """A generator fixed by the seed and a name, whatever else draws numbers."""
    return np.random.default_rng([seed, *(zlib.crc32(n.encode()) for n in names)])


@dataclass
class _Controller:
    name: str
    robot: RobotModel
    trajectory: Trajectory
    cycle_ns: int
    state: ControllerState
    tau0_s: float
    data: Any
    state_link: SimLink[Payload]
    override_link: SimLink[Payload]
    accumulator: AuditAccumulator
    next_ns: int = 0
    seq: int = 0
    zone: str | None = None
    parse_rejected: Counter[str] = field(default_factory=Counter)


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

    Returns:
        The auditor's summary and the gateway's figures. The same arguments give the same result.
    """
    started_wall_s = time.perf_counter()
    cell = config.cell
    end_ns = round(duration_s * NS_PER_S)
    store = InputStore({name: r.n_joints for name, r in robots.items()}, sorted(config.trackers))
    core = SafetyCore(config, dict(robots))
    gateway_period_s = 1.0 / config.gateway.rate_hz
    gateway_period_ns = round(gateway_period_s * NS_PER_S)
    gateway_next_ns = int(_rng(seed, "gateway-phase").integers(0, gateway_period_ns))
    gateway_seq = 0

    controllers: dict[str, _Controller] = {}
    for name, robot in robots.items():
        robot_config = config.robots[name]
        check_braking_time(robot_config.controller, robot)
        trajectory = load_trajectory(robot_config.program, robot)
        if program_start_s is not None and name in program_start_s:
            tau0_s = program_start_s[name] % trajectory.duration_s
        else:
            tau0_s = float(_rng(seed, "program-phase", name).uniform(0.0, trajectory.duration_s))
        controllers[name] = _Controller(
            name=name,
            robot=robot,
            trajectory=trajectory,
            cycle_ns=round(robot_config.controller.cycle_s * NS_PER_S),
            state=ControllerState(tau_s=tau0_s),
            tau0_s=tau0_s,
            data=robot.model.createData(),
            state_link=SimLink(links.controller_to_gateway, _rng(seed, "link-state", name)),
            override_link=SimLink(links.gateway_to_controller, _rng(seed, "link-override", name)),
            accumulator=AuditAccumulator(),
        )
    tracker_links: dict[str, SimLink[Payload]] = {
        name: SimLink(links.tracker_to_gateway, _rng(seed, "link-tracker", name)) for name in config.trackers
    }
    emulator = TrackerEmulator(scenario, config.trackers, seed, start_s=0.0)
    tracker_next_ns = _ceil_ns(emulator.next_event_s())

    truth_t_ns = -1
    truth = true_humans(scenario, 0.0)
    t_delays: list[float] = []
    decisions = 0
    fault_decisions = 0
    faults: Counter[str] = Counter()
    human_speed_mps = config.safety.human_speed_mps

    while True:
        controller_next_ns = min(c.next_ns for c in controllers.values())
        now_ns = min(controller_next_ns, gateway_next_ns, tracker_next_ns)
        if now_ns >= end_ns:
            break
        if tracker_next_ns == now_ns:
            for tracker, message in emulator.step(now_ns / NS_PER_S, EPOCH_NS + now_ns):
                tracker_links[tracker].send((keys.tracker_humans(cell, tracker), to_payload(message)), now_ns)
            tracker_next_ns = max(now_ns + 1, _ceil_ns(emulator.next_event_s()))
        for ctrl in controllers.values():
            if ctrl.next_ns != now_ns:
                continue
            _controller_cycle(ctrl, config, now_ns)
            if truth_t_ns != now_ns:
                truth_t_ns = now_ns
                truth = true_humans(scenario, now_ns / NS_PER_S)
            q_rad, qd_nominal_radps = ctrl.trajectory.sample(ctrl.state.tau_s)
            delta_applied = ctrl.state.delta_applied
            audit = audit_cycle(
                ctrl.robot,
                ctrl.data,
                q_rad,
                delta_applied * qd_nominal_radps,
                delta_applied,
                config.robots[ctrl.name].controller.braking_time_s,
                truth,
                human_speed_mps,
                moving_eps_mps,
            )
            worst = audit.worst_capsule
            ctrl.accumulator.add(
                audit,
                t_s=now_ns / NS_PER_S,
                dt_s=ctrl.cycle_ns / NS_PER_S,
                delta_applied=delta_applied,
                zone=ctrl.zone,
                program_cycles_completed=ctrl.state.cycles_completed,
                capsule_label=None if worst is None else f"{truth.human_ids[worst]}/{truth.capsule_names[worst]}",
            )
            ctrl.next_ns += ctrl.cycle_ns
        if gateway_next_ns == now_ns:
            _deliver_to_gateway(store, controllers.values(), tracker_links.values(), now_ns)
            result = core.step(store.snapshot(), EPOCH_NS + now_ns, gateway_period_s)
            gateway_seq += 1
            for name, decision in result.items():
                _count_decision(decision, t_delays, faults)
                decisions += 1
                fault_decisions += bool(decision.faults)
                ctrl = controllers[name]
                ctrl.zone = decision.zone.value
                override = Override(robot=name, seq=gateway_seq, stamp_ns=EPOCH_NS + now_ns, delta=decision.delta)
                ctrl.override_link.send((keys.robot_override(cell, name), to_payload(override)), now_ns)
                store.on_override_sent(name, gateway_seq, EPOCH_NS + now_ns)
            gateway_next_ns += gateway_period_ns

    per_robot = {name: c.accumulator.summary() for name, c in controllers.items()}
    rejected, _ = store.counters()
    controller_rejected: Counter[str] = Counter()
    for c in controllers.values():
        controller_rejected.update(c.state.rejected)
        controller_rejected.update(c.parse_rejected)
    return RunResult(
        audit=merge_summaries(list(per_robot.values())),
        per_robot=MappingProxyType(per_robot),
        t_delay_mean_s=float(np.mean(t_delays)) if t_delays else None,
        t_delay_min_s=min(t_delays) if t_delays else None,
        t_delay_max_s=max(t_delays) if t_delays else None,
        program_progress_cycles=sum(
            c.state.cycles_completed + (c.state.tau_s - c.tau0_s) / c.trajectory.duration_s
            for c in controllers.values()
        ),
        decisions=decisions,
        fault_decisions=fault_decisions,
        faults=MappingProxyType(dict(faults)),
        rejected=MappingProxyType(rejected),
        controller_rejected=MappingProxyType(dict(controller_rejected)),
        duration_s=end_ns / NS_PER_S,
        wall_s=time.perf_counter() - started_wall_s,
    )


def _ceil_ns(t_s: float) -> int:
    """The first integer nanosecond at or after ``t_s`` (so that the emulator sees its event as due)."""
    t_ns = math.ceil(t_s * NS_PER_S)
    return t_ns + 1 if t_ns / NS_PER_S < t_s else t_ns


def _controller_cycle(ctrl: _Controller, config: CellConfig, now_ns: int) -> None:
    """One controller cycle as controller_emu/main.py runs it: newest override, step, publish the state."""
    controller_config = config.robots[ctrl.name].controller
    newest: Override | None = None
    for _, (_, payload) in ctrl.override_link.deliver(now_ns):
        try:
            newest = parse_message(payload, Override)  # the inbox keeps the newest that arrived
        except MessageError as exc:
            ctrl.parse_rejected[exc.reason] += 1
    stamp_ns = EPOCH_NS + now_ns
    if newest is not None:
        ctrl.state, _ = accept_override(ctrl.state, newest, ctrl.name, stamp_ns, controller_config.watchdog_s)
    ctrl.state = step(ctrl.state, ctrl.trajectory, controller_config, stamp_ns * 1e-9, ctrl.cycle_ns / NS_PER_S)
    message = joint_state(ctrl.state, ctrl.trajectory, ctrl.name, ctrl.seq, stamp_ns)
    ctrl.seq += 1
    ctrl.state_link.send((keys.robot_state(config.cell, ctrl.name), to_payload(message)), now_ns)


def _deliver_to_gateway(
    store: InputStore,
    controllers: Iterable[_Controller],
    tracker_links: Iterable[SimLink[Payload]],
    now_ns: int,
) -> None:
    """Hand every message that has arrived by ``now_ns`` to the store, in arrival order, at its arrival time."""
    arrived: list[tuple[int, int, str, bytes]] = []
    sources = [c.state_link for c in controllers] + list(tracker_links)
    for index, link in enumerate(sources):
        arrived.extend((t_ns, index, key, payload) for t_ns, (key, payload) in link.deliver(now_ns))
    arrived.sort(key=lambda m: (m[0], m[1]))  # stable: a link's own order is kept at equal times
    for t_ns, _, key, payload in arrived:
        if keys.name_from_key(key, "tracker") is not None:
            store.on_humans(key, payload, EPOCH_NS + t_ns)
        else:
            store.on_joint_state(key, payload, EPOCH_NS + t_ns)


def _count_decision(decision: RobotDecision, t_delays: list[float], faults: Counter[str]) -> None:
    if decision.faults:
        faults.update({f.code for f in decision.faults})
    else:
        t_delays.append(decision.delay.total_s)


__all__ = ["EPOCH_NS", "LinkFault", "LinkFaults", "RunResult", "simulate"]
