"""The randomized sweep: many generated cases on the simulated cell, audited, summed up in one table.

    python -m sim.sweep --scenarios 1000 --seed 0 --workers 2 --duration-s 10 --json sweep.json

Each case (:func:`sim.scenarios.generate_case`) runs in :func:`sim.cell.simulate` with the cell's
configuration and that case's trackers and link faults. Workers are processes of the ``spawn`` context;
each loads the configuration and the robot models once. The command prints the table (and the first
violating cases with their seed and parameters) and exits 1 if any cycle violated, else 0.
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from pydantic import ValidationError

from hrc_common.config import CellConfig, ConfigError, load_cell_config
from hrc_common.robot_model import RobotModel, load_robot_model
from sim.cell import simulate
from sim.scenarios import generate_case

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
    """

    unsafe_ignore_delay: bool = False
    tight_braking: bool = False
    human_speed_mps: float | None = None

    def apply(self, config: CellConfig) -> CellConfig:
        """``config`` with these changes (validated)."""
        raw = config.model_dump()
        safety = raw["safety"]
        if self.unsafe_ignore_delay:
            safety["unsafe_ignore_delay_for_tests"] = True
        if self.human_speed_mps is not None:
            safety["human_speed_mps"] = self.human_speed_mps
            safety["human_speed_close_mps"] = max(safety["human_speed_close_mps"], self.human_speed_mps)
        if self.tight_braking:
            for robot in raw["robots"].values():
                robot["model"]["braking_time_s"] = [robot["controller"]["braking_time_s"]] * len(
                    robot["model"]["joints"]
                )
        return CellConfig.model_validate(raw)


_WORKER: dict[str, Any] = {}


def _init_worker(config_path: str | None, variant: CellVariant) -> None:
    config = variant.apply(load_cell_config(config_path))
    _WORKER["config"] = config
    _WORKER["robots"] = {name: load_robot_model(name, robot) for name, robot in config.robots.items()}


def run_case(
    config: CellConfig, robots: dict[str, RobotModel], sweep_seed: int, index: int, duration_s: float
) -> CaseResult:
    """Generate case ``index`` of the sweep ``sweep_seed`` and simulate it."""
    case = generate_case(
        sweep_seed,
        index,
        duration_s,
        config.safety.max_data_age_s,
        watchdog_s=min(r.controller.watchdog_s for r in config.robots.values()),
    )
    result = simulate(case.config(config), robots, case.scenario, case.links, duration_s, case.seed)
    audit = result.audit
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
    )


def _run_in_worker(task: tuple[int, int, float]) -> CaseResult:
    sweep_seed, index, duration_s = task
    return run_case(_WORKER["config"], _WORKER["robots"], sweep_seed, index, duration_s)


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
) -> Iterator[CaseResult]:
    """Run the cases ``0 .. scenarios-1`` of sweep ``seed``; yields results as they finish (any order).

    With ``workers`` = 1 everything runs in this process; otherwise in a pool of ``spawn`` processes.
    """
    tasks = [(seed, index, duration_s) for index in range(scenarios)]
    if workers <= 1:
        _init_worker(config_path, variant)
        for task in tasks:
            yield _run_in_worker(task)
        return
    context = multiprocessing.get_context("spawn")
    with context.Pool(workers, initializer=_init_worker, initargs=(config_path, variant)) as pool:
        yield from pool.imap_unordered(_run_in_worker, tasks, chunksize=1)


def summarize(results: list[CaseResult], wall_s: float) -> SweepSummary:
    """The table of a list of case results."""
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
    )


def _fmt(value: float | None, digits: int = 3) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def format_table(summary: SweepSummary, workers: int) -> str:
    """The sweep's table as text."""
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
        ("simulated time [s]", f"{summary.simulated_s:.0f}"),
        ("wall time [s]", f"{summary.wall_s:.1f} ({workers} workers, {speed:.1f}x real time)"),
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
) -> tuple[SweepSummary, list[CaseResult]]:
    """Run a sweep and sum it up; results sorted by case number."""
    started_s = time.perf_counter()
    results: list[CaseResult] = []
    for result in iter_sweep(scenarios, seed, workers, duration_s, config_path, variant):
        results.append(result)
        if progress is not None:
            progress(len(results), result)
    results.sort(key=lambda r: r.index)
    return summarize(results, time.perf_counter() - started_s), results


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hrc-sweep", description="Randomized sweep of the simulated cell, audited")
    parser.add_argument("--scenarios", type=int, default=1000, help="number of generated cases (default 1000)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the sweep (default 0)")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (default 2; 1 = in process)")
    parser.add_argument(
        "--duration-s",
        type=float,
        default=DEFAULT_DURATION_S,
        help=f"simulated time per case (default {DEFAULT_DURATION_S})",
    )
    parser.add_argument("--config", default=None, help="cell configuration (default configs/cell.toml)")
    parser.add_argument("--json", default=None, metavar="PATH", help="write the summary and every case here")
    parser.add_argument(
        "--unsafe-ignore-delay",
        action="store_true",
        help="TEST ONLY: run the gateway with t_delay = 0, to show the auditor's teeth (refused unless the "
        "environment variable HRC_ALLOW_UNSAFE=unsafe_ignore_delay_for_tests is set)",
    )
    parser.add_argument(
        "--tight-braking",
        action="store_true",
        help="the gateway assumes the controller's real braking time for every joint (no slack in the braking model)",
    )
    parser.add_argument("--human-speed-mps", type=float, default=None, help="K of the gateway and the auditor [m/s]")
    parser.add_argument("--quiet", action="store_true", help="no progress lines")
    return parser


def _progress_printer(total: int, quiet: bool) -> Callable[[int, CaseResult], None]:
    def progress(done: int, result: CaseResult) -> None:
        if quiet:
            return
        flag = "  VIOLATION" if result.violations else ""
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
    if args.tight_braking:
        print("tight braking: the gateway assumed the controllers' real braking time for every joint")
    if args.human_speed_mps is not None:
        print(f"human speed K = {args.human_speed_mps} m/s")
    print(format_table(summary, args.workers))
    for r in [r for r in results if r.violations][:20]:
        print(
            f"violation: case {r.index} seed {r.seed}: {r.violations} cycles, first at {r.first_violation_t_s} s, "
            f"margin {_fmt(r.smallest_margin_m)} m; {json.dumps(r.params)}"
        )
    if args.json:
        doc = {
            "sweep": {"scenarios": args.scenarios, "seed": args.seed, "duration_s": args.duration_s},
            "variant": asdict(variant),
            "summary": asdict(summary),
            "cases": [asdict(r) for r in results],
        }
        Path(args.json).write_text(json.dumps(doc, indent=1))


def cli(argv: list[str] | None = None) -> None:
    parser = _parser()
    args = parser.parse_args(argv)
    if args.scenarios < 1 or args.workers < 1 or not args.duration_s > 0.0:
        parser.error("--scenarios and --workers must be >= 1, --duration-s > 0")
    variant = CellVariant(args.unsafe_ignore_delay, args.tight_braking, args.human_speed_mps)
    try:
        variant.apply(load_cell_config(args.config))
    except (ConfigError, ValidationError) as exc:
        reason = " ".join(str(exc).split())
        print(f"hrc-sweep: invalid configuration: {reason}", file=sys.stderr)
        sys.exit(2)
    progress = _progress_printer(args.scenarios, args.quiet)
    summary, results = run_sweep(
        args.scenarios, args.seed, args.workers, args.duration_s, args.config, variant, progress
    )
    _report(args, variant, summary, results)
    sys.exit(1 if summary.violations else 0)


if __name__ == "__main__":
    cli()
