"""The randomized sweep: many generated cases on the simulated cell, audited, summed up in one table.

    python -m hrc_tools.sim --scenarios 1000 --seed 0 --workers 2 --duration-s 10 --json sweep.json

Each case (:func:`hrc_tools.sim.scenarios.generate_case`) runs in :func:`hrc_tools.sim.cell.simulate` with the cell's
configuration and that case's trackers and link faults. People enter and leave through the boundary of the covered
volume (``[tracking]``). With ``--occlusion`` the trackers see with line of sight (robot links, other people, low
fixtures), miss people and swap ids, drawn per case (:func:`hrc_tools.sim.scenarios.with_occlusion`): the gateway keeps
whom it
no longer sees as lost tracks, and the auditor, on the truth, must find no violation within K. Two test-only switches
show that the auditor has teeth: ``--unsafe-ignore-delay`` (t_delay = 0) and ``--unsafe-forget-lost`` (a person no
longer reported is forgotten at once; with ``--occlusion`` it violates), each refused unless ``HRC_ALLOW_UNSAFE``
names it. Workers are processes of the ``spawn`` context;
each loads the configuration and the robot models once. The command prints the table (and the first
violating cases with their seed and parameters).

People faster than K. The generator draws walkers up to 2.0 m/s and reaches whose hand moves up to ~2.0 m/s, against
the configured K (1.6 m/s): a case where someone approaches faster than K (:mod:`hrc_tools.sim.human_speed`, from the
scenario's keyframes) is outside the separation-monitoring guarantee, which holds for people no faster than K. The
table gives those cases their own figure (cases, violations, smallest margin while moving, margin lost) beside the
within-K figure. The command exits 1 if any cycle of a within-K case violated, else 0: a violation beyond K is
printed with its margin, never hidden, but it is not a failure of the gateway (it plans with the K it is configured
with; a cell with faster people needs a larger ``human_speed_mps``, see docs/benchmarks.md, "Randomized sweep").
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import multiprocessing
import signal
import sys
import time
from collections import Counter
from collections.abc import Callable, Generator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from hrc_contract.config import CellConfig, ConfigError
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.config import load_cell_config, read_toml, resolve_urdf
from hrc_tools.sim.bridged import INTERFACES, default_interface
from hrc_tools.sim.cell import simulate
from hrc_tools.sim.faulty_planners import FAULTY_PLANNERS
from hrc_tools.sim.human_speed import beyond_k, fastest_approach_mps, robot_bases_xy_m
from hrc_tools.sim.ros2_adapter import with_zed_trackers
from hrc_tools.sim.scenarios import case_of_cell

DEFAULT_DURATION_S = 10.0


@dataclass(frozen=True)
class CaseResult:
    """The outcome of one case (JSON-ready).

    Attributes:
        index, seed: the case's number in the sweep and its simulation seed.
        violations: audited cycles with a violation; contacts_while_moving: those with contact while moving.
        smallest_margin_m: the run's safety margin (None: nobody ever present) [m].
        smallest_margin_moving_m: the smallest margin while the robot moved (None: never) [m].
        min_distance_m: smallest true surface distance (None: nobody ever present) [m].
        first_violation_t_s: when the first violation happened (None: none) [s].
        mean_delta: time-weighted mean δ applied; time_stopped_s: time at δ = 0 [s].
        program_cycles: program cycles completed.
        t_delay_mean_s, t_delay_min_s, t_delay_max_s: the gateway's t_delay (fault-free decisions) [s].
        fault_decisions, decisions: gateway decisions with a fault, and all.
        faults: decisions per fault code.
        beyond_budget: the path with a delay beyond max_data_age_s, None if within budget.
        params: what the generator drew.
        duration_s: simulated time [s]; wall_s: wall-clock time [s].
        fastest_approach_mps: the fastest approach of any person of the case (:mod:`hrc_tools.sim.human_speed`) [m/s].
        beyond_k: someone approaches faster than the K the case ran with (outside the guarantee).
        tracks: the gateway's track changes (``track_lost``, ``released_<cause>``); lost_at_end: tracks still lost
            when the case ended.
        rejected: the gateway's input rejections per topic and reason (``qd_inconsistent``, …).
        bridges: per bridged robot, the controller bridge's figures (:meth:`hrc_tools.sim.bridged.SimBridge.summary`).
    """

    index: int
    seed: int
    violations: int
    contacts_while_moving: int
    smallest_margin_m: float | None
    smallest_margin_moving_m: float | None
    min_distance_m: float | None
    first_violation_t_s: float | None
    mean_delta: float
    time_stopped_s: float
    program_cycles: int
    t_delay_mean_s: float | None
    t_delay_min_s: float | None
    t_delay_max_s: float | None
    fault_decisions: int
    decisions: int
    faults: dict[str, int]
    beyond_budget: str | None
    params: dict[str, Any]
    duration_s: float
    wall_s: float
    fastest_approach_mps: float = 0.0
    beyond_k: bool = False
    tracks: dict[str, int] = dataclasses.field(default_factory=dict)
    lost_at_end: int = 0
    contact_cycles: int = 0
    unacceptable_contacts: int = 0
    contact_speeds_mps: list[float] = dataclasses.field(default_factory=list)
    rejected: dict[str, dict[str, int]] = dataclasses.field(default_factory=dict)
    bridges: dict[str, dict[str, Any]] = dataclasses.field(default_factory=dict)
    plans: dict[str, int] = dataclasses.field(default_factory=dict)
    """The planner layer's plans asked for (``requests``) and taken up (``adopted``), all robots; empty without it."""


@dataclass(frozen=True)
class SpeedGroup:
    """The figures of the cases within K, or of those beyond K.

    Attributes:
        cases: cases in the group; violations: their violating cycles; cases_with_violations: cases with any.
        smallest_margin_moving_m: the smallest margin while the robot moved (None: never) [m], and its case.
        margin_lost_m: how far that margin went below 0 (0: none lost) [m].
        fastest_approach_mps: the fastest approach of a person in the group (None: no case) [m/s].
    """

    cases: int
    violations: int
    cases_with_violations: int
    smallest_margin_moving_m: float | None
    smallest_margin_moving_case: int | None
    margin_lost_m: float
    fastest_approach_mps: float | None
    unacceptable_contacts: int = 0
    cases_with_unacceptable_contacts: int = 0


@dataclass(frozen=True)
class SweepSummary:
    """The table of a sweep.

    Attributes:
        scenarios: cases run.
        violations: audited cycles with a violation, over all cases; cases_with_violations: cases with any.
        contacts_while_moving: cycles with contact while moving, over all cases.
        smallest_margin_m: smallest margin over all cases (None: nobody ever present) [m], and its case.
        smallest_margin_moving_m: smallest margin while the robot moved [m], and its case.
        mean_delta: δ applied, averaged over all simulated time.
        program_cycles: program cycles completed, over all cases.
        beyond_budget: cases with a delay beyond max_data_age_s; beyond_budget_stopped: those in which the
            gateway reported stale (or unconfirmed) data for at least half of its decisions.
        simulated_s: simulated time [s]; wall_s: wall-clock time of the sweep [s].
        human_speed_mps: the K the cases ran with [m/s].
        within_k, beyond_k: the cases whose people approach no faster than K (the guarantee: 0 violations), and
            those where someone approaches faster (outside it).
        interrupted: the sweep was stopped (Ctrl-C) before all its cases ran: the figures cover those done.
        tracks: the gateway's track changes over all cases (``track_lost``, ``released_<cause>``).
        cases_lost_at_end: cases that ended with a lost track (someone the gateway still kept where nobody was seen).
    """

    scenarios: int
    violations: int
    cases_with_violations: int
    contacts_while_moving: int
    smallest_margin_m: float | None
    smallest_margin_case: int | None
    smallest_margin_moving_m: float | None
    smallest_margin_moving_case: int | None
    mean_delta: float
    program_cycles: int
    beyond_budget: int
    beyond_budget_stopped: int
    simulated_s: float
    wall_s: float
    human_speed_mps: float
    within_k: SpeedGroup
    beyond_k: SpeedGroup
    interrupted: bool = False
    tracks: dict[str, int] = dataclasses.field(default_factory=dict)
    cases_lost_at_end: int = 0
    contact_speeds_mps: list[float] = dataclasses.field(default_factory=list)
    plans: dict[str, int] = dataclasses.field(default_factory=dict)
    """The planner layer's plans asked for and taken up over all cases (empty without it)."""


# -- one case (in a worker) ---------------------------------------------------------------------------


@dataclass(frozen=True)
class CellVariant:
    """Changes to the cell of a sweep.

    Attributes:
        unsafe_ignore_delay: TEST ONLY: the gateway ignores the delay (t_delay = 0), to show the auditor's teeth;
            ``apply`` refuses it unless ``HRC_ALLOW_UNSAFE`` names ``unsafe_ignore_delay_for_tests``.
        tight_braking: the gateway assumes for every joint the braking time the controller really has
            (``controller.braking_time_s``) instead of the robot model's, so that no slack in the braking
            model hides a wrong delay handling.
        human_speed_mps: K of the gateway and the auditor, if not the configured one [m/s].
        robot_model: a robot model file (links, braking times) for every robot instead of the cell's, e.g.
            ``configs/robots/ur5_measured.toml`` (the stopping times measured by commissioning).
        method: ``safety.method``, if not the configured one.
        occlusion: the cases' trackers see with line of sight, miss people and swap ids
            (:func:`hrc_tools.sim.scenarios.with_occlusion`); a change of the cases, not of the cell.
        hostile_tracking: the cases that broke the release rule before persons (companions, two trackers with one
            late, renewed ids, late joiners: :func:`hrc_tools.sim.scenarios.with_hostile_tracking`).
        unsafe_forget_lost: TEST ONLY: the gateway forgets a person as soon as no tracker reports them (the classic
            fail-open); ``apply`` refuses it unless ``HRC_ALLOW_UNSAFE`` names ``unsafe_forget_lost_for_tests``.
        interface: every robot's controller interface (``zenoh``, ``ur_rtde``, ``abb_rws``: through the controller
            bridge, :mod:`hrc_tools.sim.bridged`), if not the cell's.
        zed_trackers: the cases' trackers are ZED cameras read through the gateway's ROS 2 adapter
            (:mod:`hrc_tools.sim.ros2_adapter`); a change of the cases, not of the cell.
        zed_body_fitting: those cameras fit hidden keypoints (``enable_body_fitting``); off: hidden keypoints NaN.
        planner_fault: the planner layer's backend fails on purpose (:data:`hrc_tools.sim.faulty_planners.
            FAULTY_PLANNERS`: ``through_the_person``, ``silent``); for a cell with ``[planner] enabled``.
    """

    unsafe_ignore_delay: bool = False
    tight_braking: bool = False
    human_speed_mps: float | None = None
    robot_model: str | None = None
    method: str | None = None
    occlusion: bool = False
    hostile_tracking: bool = False
    unsafe_forget_lost: bool = False
    unsafe_release_by_id: bool = False
    interface: str | None = None
    zed_trackers: bool = False
    zed_body_fitting: bool = False
    planner_fault: str | None = None

    def apply(self, config: CellConfig) -> CellConfig:
        """``config`` with these changes (validated)."""
        raw = config.model_dump()
        safety = raw["safety"]
        if self.unsafe_ignore_delay:
            safety["unsafe_ignore_delay_for_tests"] = True
        if self.unsafe_forget_lost:
            raw["tracking"]["unsafe_forget_lost_for_tests"] = True
        if self.unsafe_release_by_id:
            raw["tracking"]["unsafe_release_by_id_for_tests"] = True
        if self.human_speed_mps is not None:
            safety["human_speed_mps"] = self.human_speed_mps
            safety["human_speed_close_mps"] = max(safety["human_speed_close_mps"], self.human_speed_mps)
        if self.method is not None:
            safety["method"] = self.method
        if self.robot_model is not None:
            model = _read_robot_model(Path(self.robot_model))
            for robot in raw["robots"].values():
                robot["model"] = dict(model)
        if self.tight_braking:
            for robot in raw["robots"].values():
                robot["model"]["braking_time_s"] = [robot["controller"]["braking_time_s"]] * len(
                    robot["model"]["joints"]
                )
        if self.interface is not None:
            for robot in raw["robots"].values():
                robot["interface"] = default_interface(self.interface)
        return CellConfig.model_validate(raw)


def _read_robot_model(path: Path) -> dict[str, Any]:
    """A robot model file as the cell loader reads it (its URDF resolved). Raises ConfigError."""
    model = read_toml(path.resolve())
    if isinstance(model.get("urdf"), str):
        model["urdf"] = str(resolve_urdf(model["urdf"], path.resolve().parent))
    return model


_WORKER: dict[str, Any] = {}


def _init_worker(config_path: str | None, variant: CellVariant) -> None:
    config = variant.apply(load_cell_config(config_path))
    _WORKER["config"] = config
    _WORKER["robots"] = {name: load_robot_model(name, robot) for name, robot in config.robots.items()}
    _WORKER["occlusion"] = variant.occlusion
    _WORKER["hostile_tracking"] = variant.hostile_tracking
    _WORKER["zed_trackers"] = variant.zed_trackers
    _WORKER["zed_body_fitting"] = variant.zed_body_fitting
    _WORKER["planner_fault"] = variant.planner_fault


def run_case(
    config: CellConfig,
    robots: dict[str, RobotModel],
    sweep_seed: int,
    index: int,
    duration_s: float,
    *,
    occlusion: bool = False,
    hostile_tracking: bool = False,
    zed_trackers: bool = False,
    zed_body_fitting: bool = False,
    planner_fault: str | None = None,
) -> CaseResult:
    """Generate case ``index`` of the sweep ``sweep_seed`` (its trackers with line of sight if ``occlusion``, read as
    ZED cameras through the ROS 2 adapter if ``zed_trackers``, fitting hidden keypoints if ``zed_body_fitting``) and
    simulate it; ``planner_fault``: the planner layer's backend fails so (:data:`FAULTY_PLANNERS`)."""
    case = case_of_cell(config, sweep_seed, index, duration_s, occlusion=occlusion, hostile_tracking=hostile_tracking)
    case_config = case.config(config)
    if zed_trackers:
        case_config = with_zed_trackers(case_config, body_fitting=zed_body_fitting)
    backend = None if planner_fault is None else FAULTY_PLANNERS[planner_fault]
    result = simulate(case_config, robots, case.scenario, case.links, duration_s, case.seed, planner_backend=backend)
    plans = Counter[str]()
    for stats in result.planner.values():
        plans["requests"] += sum(stats["requests"].values())
        plans["adopted"] += stats["adopted"]
    audit = result.audit
    approach_mps = fastest_approach_mps(case.scenario, robot_bases_xy_m(config))
    return CaseResult(
        index=index,
        seed=case.seed,
        violations=audit.violations,
        contacts_while_moving=audit.contacts_while_moving,
        smallest_margin_m=_finite(audit.smallest_margin_m),
        smallest_margin_moving_m=_finite(audit.smallest_margin_moving_m),
        min_distance_m=audit.min_distance_m,
        first_violation_t_s=audit.first_violation_t_s,
        mean_delta=audit.mean_delta_applied,
        time_stopped_s=audit.time_stopped_s,
        program_cycles=audit.program_cycles_completed,
        t_delay_mean_s=result.t_delay_mean_s,
        t_delay_min_s=result.t_delay_min_s,
        t_delay_max_s=result.t_delay_max_s,
        fault_decisions=result.fault_decisions,
        decisions=result.decisions,
        faults=dict(result.faults),
        beyond_budget=case.params["beyond_budget"],
        params=case.params,
        duration_s=result.duration_s,
        wall_s=result.wall_s,
        fastest_approach_mps=round(approach_mps, 4),
        beyond_k=beyond_k(approach_mps, config.safety.human_speed_mps),
        tracks=dict(result.tracks),
        lost_at_end=result.lost_at_end,
        contact_cycles=audit.contact_cycles,
        unacceptable_contacts=audit.unacceptable_contacts,
        contact_speeds_mps=[round(v, 4) for v in audit.contact_speeds_mps],
        rejected={topic: dict(reasons) for topic, reasons in result.rejected.items()},
        bridges={name: dict(b) for name, b in result.bridges.items()},
        plans=dict(plans),
    )


def _run_in_worker(task: tuple[int, int, float]) -> CaseResult:
    sweep_seed, index, duration_s = task
    return run_case(
        _WORKER["config"],
        _WORKER["robots"],
        sweep_seed,
        index,
        duration_s,
        occlusion=_WORKER["occlusion"],
        hostile_tracking=_WORKER["hostile_tracking"],
        zed_trackers=_WORKER["zed_trackers"],
        zed_body_fitting=_WORKER["zed_body_fitting"],
        planner_fault=_WORKER["planner_fault"],
    )


def _finite(value: float) -> float | None:
    return value if math.isfinite(value) else None


# -- the sweep ----------------------------------------------------------------------------------------


def iter_sweep(
    scenarios: int,
    seed: int,
    workers: int,
    duration_s: float,
    config_path: str | None = None,
    variant: CellVariant = CellVariant(),
    first_case: int = 0,
) -> Generator[CaseResult, None, None]:
    """Run the cases ``first_case .. first_case + scenarios - 1`` of sweep ``seed``; yields results as they finish
    (any order). A case's scenario depends only on ``seed`` and its number, so a sweep can be run in parts.

    With ``workers`` = 1 everything runs in this process; otherwise in a pool of ``spawn`` processes.
    """
    tasks = [(seed, index, duration_s) for index in range(first_case, first_case + scenarios)]
    if workers <= 1:
        _init_worker(config_path, variant)
        for task in tasks:
            yield _run_in_worker(task)
        return
    context = multiprocessing.get_context("spawn")
    with context.Pool(workers, initializer=_init_worker, initargs=(config_path, variant)) as pool:
        yield from pool.imap_unordered(_run_in_worker, tasks, chunksize=1)


def speed_group(results: list[CaseResult]) -> SpeedGroup:
    """The figures of a group of cases (within K, or beyond it)."""
    moving = [(r.smallest_margin_moving_m, r.index) for r in results if r.smallest_margin_moving_m is not None]
    smallest = min(moving) if moving else None
    return SpeedGroup(
        cases=len(results),
        violations=sum(r.violations for r in results),
        cases_with_violations=sum(1 for r in results if r.violations),
        smallest_margin_moving_m=None if smallest is None else smallest[0],
        smallest_margin_moving_case=None if smallest is None else smallest[1],
        margin_lost_m=max(0.0, -smallest[0]) if smallest is not None else 0.0,
        fastest_approach_mps=max((r.fastest_approach_mps for r in results), default=None),
        unacceptable_contacts=sum(r.unacceptable_contacts for r in results),
        cases_with_unacceptable_contacts=sum(1 for r in results if r.unacceptable_contacts),
    )


def summarize(results: list[CaseResult], wall_s: float, human_speed_mps: float = math.nan) -> SweepSummary:
    """The table of a list of case results (``human_speed_mps``: the K they ran with, for the report) [m/s]."""
    margins = [(r.smallest_margin_m, r.index) for r in results if r.smallest_margin_m is not None]
    moving = [(r.smallest_margin_moving_m, r.index) for r in results if r.smallest_margin_moving_m is not None]
    simulated_s = sum(r.duration_s for r in results)
    stale_codes = ("tracker_stale", "joint_state_stale", "override_path_stale", "override_path_unconfirmed")
    stopped = [
        r
        for r in results
        if r.beyond_budget is not None and max((r.faults.get(c, 0) for c in stale_codes), default=0) * 2 >= r.decisions
    ]
    return SweepSummary(
        scenarios=len(results),
        violations=sum(r.violations for r in results),
        cases_with_violations=sum(1 for r in results if r.violations),
        contacts_while_moving=sum(r.contacts_while_moving for r in results),
        smallest_margin_m=min(margins)[0] if margins else None,
        smallest_margin_case=min(margins)[1] if margins else None,
        smallest_margin_moving_m=min(moving)[0] if moving else None,
        smallest_margin_moving_case=min(moving)[1] if moving else None,
        mean_delta=sum(r.mean_delta * r.duration_s for r in results) / simulated_s if simulated_s else 0.0,
        program_cycles=sum(r.program_cycles for r in results),
        beyond_budget=sum(1 for r in results if r.beyond_budget is not None),
        beyond_budget_stopped=len(stopped),
        simulated_s=simulated_s,
        wall_s=wall_s,
        human_speed_mps=human_speed_mps,
        within_k=speed_group([r for r in results if not r.beyond_k]),
        beyond_k=speed_group([r for r in results if r.beyond_k]),
        tracks=dict(sorted(sum((Counter(r.tracks) for r in results), Counter()).items())),
        cases_lost_at_end=sum(1 for r in results if r.lost_at_end),
        contact_speeds_mps=sorted(v for r in results for v in r.contact_speeds_mps),
        plans=dict(sorted(sum((Counter(r.plans) for r in results), Counter()).items())),
    )


CONTACT_METHODS = ("lucci2020_pfl",)
"""Methods that allow transient contact: judged by the contact criterion (safety-math.md §12)."""


def sweep_exit_code(summary: SweepSummary, contact_criterion: bool = False) -> int:
    """1 if a case within K violated (the gateway's guarantee broken), else 130 if interrupted (Ctrl-C), else 0.

    With ``contact_criterion`` (a method of :data:`CONTACT_METHODS`), "violated" means an unacceptable contact
    (§12): such a method touches by design, so the separation violations are reported beside it, not failures.
    Violations of people faster than K are reported, not failures: the guarantee is stated for the configured K,
    and the generator draws faster people on purpose, to show the margin they cost.
    """
    if summary.within_k.unacceptable_contacts if contact_criterion else summary.within_k.violations:
        return 1
    return 130 if summary.interrupted else 0


def _fmt(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _group_rows(name: str, group: SpeedGroup) -> list[tuple[str, str]]:
    margin = f"{_fmt(group.smallest_margin_moving_m)} (case {group.smallest_margin_moving_case})"
    return [
        (f"{name}: scenarios", str(group.cases)),
        (f"{name}: violations (cycles)", f"{group.violations} in {group.cases_with_violations} scenarios"),
        (f"{name}: smallest margin while moving [m]", margin),
        (f"{name}: margin lost [m]", _fmt(group.margin_lost_m)),
        (f"{name}: fastest approach [m/s]", _fmt(group.fastest_approach_mps, 2)),
        (
            f"{name}: contact criterion (§12): unacceptable contacts (cycles)",
            f"{group.unacceptable_contacts} in {group.cases_with_unacceptable_contacts} scenarios",
        ),
    ]


def contact_speeds_text(speeds_mps: list[float]) -> str:
    """The contacts' onset speeds as a distribution: count, median, 90th percentile, largest [m/s]."""
    if not speeds_mps:
        return "0"
    ordered = sorted(speeds_mps)

    def pct(p: float) -> float:
        return ordered[min(len(ordered) - 1, int(p * len(ordered)))]

    return f"{len(ordered)}: median {pct(0.5):.3f}, p90 {pct(0.9):.3f}, max {ordered[-1]:.3f}"


def _tracks_text(tracks: dict[str, int]) -> str:
    released = ", ".join(f"{k.removeprefix('released_')} {v}" for k, v in tracks.items() if k.startswith("released_"))
    return f"{tracks.get('track_lost', 0)} lost / released: {released or 'none'}"


def format_table(summary: SweepSummary, workers: int) -> str:
    """The sweep's table as text: every case, then the cases within K and those beyond it, apart."""
    speed = summary.simulated_s / summary.wall_s if summary.wall_s > 0 else math.inf
    rows = [
        ("scenarios", str(summary.scenarios)),
        ("violations (cycles)", str(summary.violations)),
        ("scenarios with violations", str(summary.cases_with_violations)),
        ("contacts while moving (cycles)", str(summary.contacts_while_moving)),
        ("smallest margin [m]", f"{_fmt(summary.smallest_margin_m)} (case {summary.smallest_margin_case})"),
        (
            "smallest margin while moving [m]",
            f"{_fmt(summary.smallest_margin_moving_m)} (case {summary.smallest_margin_moving_case})",
        ),
        ("mean δ applied", _fmt(summary.mean_delta)),
        ("program cycles completed", str(summary.program_cycles)),
        (
            "delay beyond max_data_age_s",
            f"{summary.beyond_budget} ({summary.beyond_budget_stopped} stopped on stale data)",
        ),
        ("human speed K [m/s]", f"{summary.human_speed_mps:g}"),
        ("contacts (onsets) / their speed [m/s]", contact_speeds_text(summary.contact_speeds_mps)),
        ("tracks lost / released", _tracks_text(summary.tracks)),
        ("scenarios ending with a lost track", str(summary.cases_lost_at_end)),
        *(
            [("plans asked for / taken up", f"{summary.plans.get('requests', 0)} / {summary.plans.get('adopted', 0)}")]
            if summary.plans
            else []
        ),
        *_group_rows("within K", summary.within_k),
        *_group_rows("faster than K (no guarantee)", summary.beyond_k),
        ("simulated time [s]", f"{summary.simulated_s:.0f}"),
        (
            "wall time [s]",
            f"{summary.wall_s:.1f} ({f'{workers} workers' if workers else 'sum of the parts'}, {speed:.1f}x real time)",
        ),
    ]
    width = max(len(name) for name, _ in rows)
    return "\n".join(f"{name:<{width}}  {value}" for name, value in rows)


def run_sweep(
    scenarios: int,
    seed: int,
    workers: int,
    duration_s: float,
    config_path: str | None = None,
    variant: CellVariant = CellVariant(),
    progress: Callable[[int, CaseResult], None] | None = None,
    first_case: int = 0,
) -> tuple[SweepSummary, list[CaseResult]]:
    """Run a sweep and sum it up; results sorted by case number.

    Ctrl-C (KeyboardInterrupt; the command maps SIGTERM to it too) after some cases ends the sweep there: the
    summary covers the cases done and says ``interrupted`` (a long sweep on a shared machine still gives its figure).
    """
    human_speed_mps = variant.apply(load_cell_config(config_path)).safety.human_speed_mps
    started_s = time.perf_counter()
    results: list[CaseResult] = []
    cases = iter_sweep(scenarios, seed, workers, duration_s, config_path, variant, first_case)
    interrupted = False
    try:
        for result in cases:
            results.append(result)
            if progress is not None:
                progress(len(results), result)
    except KeyboardInterrupt:
        if not results:
            raise
        interrupted = True
    finally:
        cases.close()  # stops the worker pool
    results.sort(key=lambda r: r.index)
    summary = summarize(results, time.perf_counter() - started_s, human_speed_mps)
    return dataclasses.replace(summary, interrupted=interrupted), results


def add_case_arguments(parser: argparse.ArgumentParser, scenarios: int, duration_s: float) -> None:
    """The options of every runner of seeded simulated cases (``hrc-sweep``, ``bench.productivity``): ``--scenarios``,
    ``--seed``, ``--workers``, ``--duration-s``, ``--config``, ``--occlusion``, ``--quiet`` (checked by
    :func:`case_argument_problem`)."""
    parser.add_argument("--scenarios", type=int, default=scenarios, help=f"number of cases (default {scenarios})")
    parser.add_argument("--seed", type=int, default=0, help="seed of the cases (default 0)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (default 2; 1 = in process)")
    parser.add_argument(
        "--duration-s", type=float, default=duration_s, help=f"simulated time per case (default {duration_s})"
    )
    parser.add_argument("--config", default=None, help="cell configuration (default configs/cell.toml)")
    parser.add_argument(
        "--occlusion",
        action="store_true",
        help="the cases' trackers see with line of sight (robot links, other people), miss people and swap ids "
        "(hrc_tools.sim.scenarios.with_occlusion); the same people, links and seeds as without",
    )
    parser.add_argument("--quiet", action="store_true", help="no progress lines")


def case_argument_problem(args: argparse.Namespace) -> str | None:
    """What is wrong with the options of :func:`add_case_arguments`, or None."""
    if args.scenarios < 1 or args.workers < 1 or not args.duration_s > 0.0:
        return "--scenarios and --workers must be >= 1, --duration-s > 0"
    return None


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hrc-sweep", description="Randomized sweep of the simulated cell, audited")
    add_case_arguments(parser, scenarios=1000, duration_s=DEFAULT_DURATION_S)
    parser.add_argument("--json", default=None, metavar="PATH", help="write the summary and every case here")
    parser.add_argument(
        "--unsafe-ignore-delay",
        action="store_true",
        help="TEST ONLY: run the gateway with t_delay = 0, to show the auditor's teeth (refused unless the "
        "environment variable HRC_ALLOW_UNSAFE=unsafe_ignore_delay_for_tests is set)",
    )
    parser.add_argument(
        "--unsafe-forget-lost",
        action="store_true",
        help="TEST ONLY: the gateway forgets a person as soon as no tracker reports them (the classic fail-open), to "
        "show the auditor's teeth (refused unless HRC_ALLOW_UNSAFE=unsafe_forget_lost_for_tests is set)",
    )
    parser.add_argument(
        "--hostile-tracking",
        action="store_true",
        help="the cases that broke the release rule before persons (issue 32), drawn per case "
        "(hrc_tools.sim.scenarios.with_hostile_tracking): a companion behind the first person, two trackers, one "
        "stamping late, renewed ids, a tracker joining late, now and then merged people or parts named by kind; "
        "someone hidden at the robot, a bystander beyond them, and in some cases only those two",
    )
    parser.add_argument(
        "--unsafe-release-by-id",
        action="store_true",
        help="TEST ONLY: the gateway releases a lost person by the rule before issue 32 (the same id within reach, or "
        "any detection away from the entry band that covers them), to show the auditor's teeth (refused unless "
        "HRC_ALLOW_UNSAFE=unsafe_release_by_id_for_tests is set)",
    )
    parser.add_argument(
        "--tight-braking",
        action="store_true",
        help="the gateway assumes the controller's real braking time for every joint (no slack in the braking model)",
    )
    parser.add_argument("--human-speed-mps", type=float, default=None, help="K of the gateway and the auditor [m/s]")
    parser.add_argument(
        "--robot-model",
        default=None,
        metavar="PATH",
        help="every robot's model file (links, braking times) instead of the cell's, e.g. "
        "configs/robots/ur5_measured.toml for the stopping times measured by commissioning",
    )
    parser.add_argument("--method", default=None, help="safety.method of the gateway, if not the cell's")
    parser.add_argument(
        "--interface",
        choices=INTERFACES,
        default=None,
        help="every robot's controller interface: zenoh (the emulator's own face, no bridge), or ur_rtde / abb_rws "
        "through the controller bridge and the emulator's vendor face (default: the cell file's; zenoh in "
        "configs/cell.toml)",
    )
    parser.add_argument(
        "--zed-trackers",
        action="store_true",
        help="the cases' trackers are ZED cameras: every frame goes capsules -> BODY_38 keypoints (NaN where the "
        "sensor cannot see) -> CDR -> the gateway's ROS 2 adapter -> capsules (docs/ros2.md)",
    )
    parser.add_argument(
        "--zed-body-fitting",
        action="store_true",
        help="with --zed-trackers: the cameras fit what they cannot see (the wrapper's enable_body_fitting, BODY_34: "
        "a hidden keypoint is an estimate, not NaN)",
    )
    parser.add_argument(
        "--planner-fault",
        choices=sorted(FAULTY_PLANNERS),
        default=None,
        help="the planner layer fails on purpose (a cell with [planner] enabled): through_the_person (its paths "
        "ignore the people) or silent (it never answers); the scaling layer must bound every command anyway",
    )
    parser.add_argument(
        "--first-case",
        type=int,
        default=0,
        help="run cases N .. N + scenarios - 1 (continue a sweep that was interrupted; see --merge)",
    )
    parser.add_argument(
        "--merge",
        nargs="+",
        default=None,
        metavar="JSON",
        help="run nothing: the table of the cases of these --json files together (same seed, duration and variant)",
    )
    return parser


def _progress_printer(total: int, quiet: bool) -> Callable[[int, CaseResult], None]:
    def progress(done: int, result: CaseResult) -> None:
        if quiet:
            return
        flag = ("  VIOLATION (faster than K)" if result.beyond_k else "  VIOLATION") if result.violations else ""
        print(
            f"[{done}/{total}] case {result.index}: margin {_fmt(result.smallest_margin_m)} m, "
            f"mean δ {result.mean_delta:.2f}, {result.duration_s / result.wall_s:.1f}x{flag}",
            file=sys.stderr,
            flush=True,
        )

    return progress


def _report(args: argparse.Namespace, variant: CellVariant, summary: SweepSummary, results: list[CaseResult]) -> None:
    if args.unsafe_ignore_delay:
        print("UNSAFE: gateway ran with unsafe_ignore_delay_for_tests = true (t_delay = 0)")
    if args.unsafe_forget_lost:
        print("UNSAFE: gateway ran with unsafe_forget_lost_for_tests = true (a person no longer reported is forgotten)")
    if args.unsafe_release_by_id:
        print("UNSAFE: gateway ran with unsafe_release_by_id_for_tests = true (lost people released by others)")
    if args.hostile_tracking:
        print(
            "hostile tracking: companions, two trackers (one late), renewed ids, late joiners, people hidden at the "
            "robot with bystanders (drawn per case)"
        )
    if args.occlusion:
        print("occlusion: the trackers saw with line of sight, missed people and swapped ids (drawn per case)")
    if args.tight_braking:
        print("tight braking: the gateway assumed the controllers' real braking time for every joint")
    if args.human_speed_mps is not None:
        print(f"human speed K = {args.human_speed_mps} m/s")
    if args.robot_model is not None:
        print(f"robot model (braking times): {args.robot_model}")
    if args.interface is not None:
        print(f"interface: {args.interface}")
    if args.zed_trackers:
        fitting = "fitted BODY_34" if args.zed_body_fitting else "BODY_38, hidden keypoints NaN"
        print(f"ZED trackers ({fitting}): every frame went through the ROS 2 adapter (keypoints -> CDR -> capsules)")
    if args.method is not None:
        print(f"method: {args.method}")
    if args.planner_fault is not None:
        print(f"planner fault: {args.planner_fault} (the planner layer failed on purpose in every case)")
    if summary.interrupted:
        print(f"INTERRUPTED: {summary.scenarios} of {args.scenarios} scenarios ran; the table covers those")
    print(format_table(summary, args.workers))
    for r in [r for r in results if r.violations][:20]:
        where = f"faster than K ({r.fastest_approach_mps:.2f} m/s)" if r.beyond_k else "within K"
        print(
            f"violation ({where}): case {r.index} seed {r.seed}: {r.violations} cycles, first at "
            f"{r.first_violation_t_s} s, margin while moving {_fmt(r.smallest_margin_moving_m)} m; "
            f"{json.dumps(r.params)}"
        )
    if summary.beyond_k.violations:
        print(
            f"{summary.beyond_k.violations} violating cycles are of people approaching faster than "
            f"K = {summary.human_speed_mps:g} m/s: outside the separation-monitoring guarantee (the gateway plans with "
            "the configured K); they do not change the exit code. A cell with faster people needs a larger "
            "human_speed_mps."
        )
    if args.json:
        doc = {
            "sweep": {"scenarios": args.scenarios, "seed": args.seed, "duration_s": args.duration_s},
            "variant": asdict(variant),
            "summary": asdict(summary),
            "cases": [asdict(r) for r in results],
        }
        Path(args.json).write_text(json.dumps(doc, indent=1))


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def merge_sweeps(docs: list[dict[str, Any]]) -> tuple[SweepSummary, list[CaseResult]]:
    """The summary of the cases of several sweep JSON documents (``--json``) together.

    Raises:
        ValueError: they differ in seed, case duration or variant, or hold a case twice.
    """
    setups = {json.dumps([d["sweep"]["seed"], d["sweep"]["duration_s"], d["variant"]], sort_keys=True) for d in docs}
    if len(setups) != 1:
        raise ValueError("the sweeps differ in seed, case duration or variant; only parts of one sweep can be merged")
    results = sorted((CaseResult(**case) for d in docs for case in d["cases"]), key=lambda r: r.index)
    indices = [r.index for r in results]
    if len(set(indices)) != len(indices):
        raise ValueError("a case is in more than one file")
    human_speed_mps = docs[0]["summary"].get("human_speed_mps", math.nan)
    return summarize(results, sum(d["summary"]["wall_s"] for d in docs), human_speed_mps), results


def _merge_cli(paths: list[str]) -> None:
    try:
        summary, results = merge_sweeps([json.loads(Path(p).read_text()) for p in paths])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"hrc-sweep: cannot merge {', '.join(paths)}: {exc}", file=sys.stderr)
        sys.exit(2)
    indices = [r.index for r in results]
    print(f"merged {len(paths)} sweep file(s): cases {min(indices)}..{max(indices)}, {len(indices)} in all")
    print(format_table(summary, 0))
    method = json.loads(Path(paths[0]).read_text())["variant"].get("method") or load_cell_config(None).safety.method
    sys.exit(sweep_exit_code(summary, method in CONTACT_METHODS))


def cli(argv: list[str] | None = None) -> None:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.merge:
        _merge_cli(args.merge)
    if args.first_case < 0:
        parser.error("--first-case must be >= 0")
    if args.zed_body_fitting and not args.zed_trackers:
        parser.error("--zed-body-fitting needs --zed-trackers")
    problem = case_argument_problem(args)
    if problem is not None:
        parser.error(problem)
    variant = CellVariant(
        args.unsafe_ignore_delay,
        args.tight_braking,
        args.human_speed_mps,
        args.robot_model,
        args.method,
        occlusion=args.occlusion,
        hostile_tracking=args.hostile_tracking,
        interface=args.interface,
        unsafe_forget_lost=args.unsafe_forget_lost,
        unsafe_release_by_id=args.unsafe_release_by_id,
        zed_trackers=args.zed_trackers,
        zed_body_fitting=args.zed_body_fitting,
        planner_fault=args.planner_fault,
    )
    try:
        applied = variant.apply(load_cell_config(args.config))
    except (ConfigError, ValidationError) as exc:
        reason = " ".join(str(exc).split())
        print(f"hrc-sweep: invalid configuration: {reason}", file=sys.stderr)
        sys.exit(2)
    method = applied.safety.method
    if args.planner_fault is not None and not applied.planner.enabled:
        parser.error(
            f"--planner-fault {args.planner_fault}: the cell {args.config or 'configs/cell.toml'} has no planner "
            "layer; allowed: a cell with [planner] enabled = true (e.g. configs/cell_open_panda_planner.toml)"
        )
    progress = _progress_printer(args.scenarios, args.quiet)
    previous = signal.signal(signal.SIGTERM, _interrupt)  # SIGTERM ends the sweep like Ctrl-C: table of the cases done
    try:
        summary, results = run_sweep(
            args.scenarios, args.seed, args.workers, args.duration_s, args.config, variant, progress, args.first_case
        )
    finally:
        signal.signal(signal.SIGTERM, previous)
    _report(args, variant, summary, results)
    if method in CONTACT_METHODS:
        print(f"exit code: the contact criterion (§12) of {method}; separation violations are reported beside it")
    sys.exit(sweep_exit_code(summary, method in CONTACT_METHODS))


if __name__ == "__main__":
    cli()
