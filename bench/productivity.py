"""Productivity of every override method on the same seeded scenario suite (issue 4, benchmark 4).

    .venv/bin/python -m bench.productivity --scenarios 40 --seed 0 --workers 2 --duration-s 30

Every case of the suite (:func:`hrc_tools.sim.scenarios.generate_case`: people, trackers, link faults, simulation
seed) runs in :func:`hrc_tools.sim.cell.simulate` once per variant, with the same seed (so the same sensor noise,
drops, link draws, gateway phase and program phase) and the same program:

- ``zanchettin2016``, ``zanchettin2016_speed_aware``, ``iso15066``, ``three_zones``, ``stop_only``:
  ``safety.method`` set, nothing else changed;
- ``zanchettin2016_zero_delay``: eq. (15) with every link delay and jitter 0 and the trackers' latency 0
  (loss and duplication kept): the physical upper bound of the method;
- ``no_human``: the same case with nobody in the cell (same trackers and links): the robot alone.

Per variant: program cycles per hour (program progress over all robots and all simulated time, the
unfinished cycle of each run counted by its fraction), time stopped
(δ_applied = 0) [%], time-weighted mean δ applied, smallest safety margin while the robot moved [m], and
violations (audited cycles). A figure counts only if the variant had 0 violations. The targets are the
ratios of cycles per hour of eq. (15) and of its speed-aware variant: ≥ 1.3 × three_zones, ≥ 2 × stop_only
(issue 4) and ≥ 0.85 × the robot alone (issue 10).

People faster than K: the stress suite draws walkers up to 2.0 m/s against the configured K (1.6 m/s); the report
gives, per variant, the cases where someone approaches faster than K (:mod:`hrc_tools.sim.human_speed`: outside the
separation-monitoring guarantee) apart from those within K: cases, violations, smallest margin while moving and
margin lost. A PNG plot of cycles per hour per method and kind of case, with the robot-alone and zero-delay bounds,
is written next to the JSON (``--plot``); ``--plot-from`` redraws it from earlier results (e.g. both suites).
"""

from __future__ import annotations

import argparse
import json
import math
import multiprocessing
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from bench._progress import Progress
from bench._report import Report, Target, default_json_path, print_header, table
from bench.productivity_plot import PlotError, plot_cycles_per_hour
from hrc_contract.config import CellConfig
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_tools.sim.cell import simulate
from hrc_tools.sim.human_speed import beyond_k, fastest_approach_mps, robot_bases_xy_m
from hrc_tools.sim.links import LinkFault, LinkFaults
from hrc_tools.sim.scenarios import COLLABORATIVE_KINDS, SweepCase, case_of_cell
from hrc_tools.sim.sweep import add_case_arguments, case_argument_problem
from tracker_emu.scenario import Scenario

NAME = "productivity"
METHODS = ("zanchettin2016", "zanchettin2016_speed_aware", "lucci2020_pfl", "iso15066", "three_zones", "stop_only")
CONTACT_METHODS = ("lucci2020_pfl",)
"""Methods that allow transient contact: a figure of theirs counts when the contact criterion found no unacceptable
contact (safety-math.md §12); their separation violations are reported beside it (they touch by design)."""
ZERO_DELAY = "zanchettin2016_zero_delay"
NO_HUMAN = "no_human"
OPEN = "zanchettin2016_open"
"""Every robot behind an open controller (``control = "open"``): LP (9)/(13) with the measured delay (safety-math.md
§13); run on request (``--variants``), e.g. with ``--config configs/cell_open_panda.toml``. Every other variant runs
the robots behind closed controllers. An open robot's "mean δ" is its speed fraction max_j |q̇_j| / q̇max_j."""
VARIANTS = (*METHODS, ZERO_DELAY, NO_HUMAN)
"""Every variant run on every case by default, in table order."""
ALL_VARIANTS = (*METHODS, OPEN, ZERO_DELAY, NO_HUMAN)
"""Every variant that can be asked for, in table order."""
RATIO_TARGETS = (("three_zones", 1.3), ("stop_only", 2.0), (NO_HUMAN, 0.85))
"""The eq. (15) methods must complete at least this many times the cycles per hour of these variants (issues 4, 10:
the baselines, and the robot alone)."""
RATIO_METHODS = ("zanchettin2016", "zanchettin2016_speed_aware", "lucci2020_pfl", OPEN)
"""The methods held to :data:`RATIO_TARGETS`: eq. (15) (default) and eq. (15) with the speed-aware stop."""
SECONDS_PER_HOUR = 3600.0
SUITES = ("stress", "collaborative")
"""``stress``: the sweep's generator
(hrc_tools.sim.scenarios.generate_case); ``collaborative``: the collaborative-station
suite (hrc_tools.sim.scenarios.generate_collaborative_case)."""
CASE_KINDS = ("standing", "approach", "cross")
"""A case is of the first of these kinds that one of its people has (hrc_tools.sim.scenarios): someone standing in the
cell from the start, else someone walking up to the robot, else only people crossing."""


def case_kind(people: Sequence[dict[str, Any]]) -> str:
    """The kind of a case from the kinds of its people (see :data:`CASE_KINDS`); "nobody" if it has none."""
    kinds = {p.get("kind") for p in people}
    return next((k for k in CASE_KINDS if k in kinds), "nobody")


@dataclass(frozen=True)
class AtLeast(Target):
    """A target where larger is better; it passes only if the figures it compares had no violation."""

    counts: bool = True

    @property
    def verdict(self) -> str:
        return "PASS" if self.counts and self.measured >= self.limit else "MISS"

    def as_dict(self) -> dict[str, Any]:
        measured = self.measured if math.isfinite(self.measured) else None
        return {**super().as_dict(), "measured": measured, "comparison": ">=", "counts": self.counts}


@dataclass(frozen=True)
class VariantRun:
    """One variant on one case (JSON-ready).

    Attributes:
        index, seed: the case and its simulation seed.
        variant: the variant's name (see :data:`VARIANTS`).
        beyond_budget: the path whose delay the generator drew beyond max_data_age_s, None if within budget.
        kind: the case's kind (:func:`case_kind`).
        program_cycles: program cycles run, with the fraction of the unfinished one (all robots).
        audited_s: audited controller time (all robots) [s].
        time_stopped_s: time at δ_applied = 0 (all robots) [s].
        mean_delta: time-weighted mean δ applied.
        smallest_margin_moving_m: smallest margin while a robot moved (None: never) [m].
        violations: audited cycles with a violation.
        duration_s: simulated time [s]; wall_s: wall-clock time [s].
        fastest_approach_mps: the fastest approach of a person of the case (:mod:`hrc_tools.sim.human_speed`) [m/s].
        beyond_k: someone in the case approaches faster than the configured K (outside the guarantee).
    """

    index: int
    seed: int
    variant: str
    beyond_budget: str | None
    kind: str
    program_cycles: float
    audited_s: float
    time_stopped_s: float
    mean_delta: float
    smallest_margin_moving_m: float | None
    violations: int
    duration_s: float
    wall_s: float
    fastest_approach_mps: float = 0.0
    beyond_k: bool = False
    unacceptable_contacts: int = 0
    contact_speeds_mps: tuple[float, ...] = ()


# -- one run (in a worker) ----------------------------------------------------------------------------


def with_method(config: CellConfig, method: str) -> CellConfig:
    """``config`` with ``safety.method`` set (validated)."""
    raw = config.model_dump()
    raw["safety"]["method"] = method
    return CellConfig.model_validate(raw)


def with_control(config: CellConfig, control: str) -> CellConfig:
    """``config`` with every robot's controller ``control`` (``"open"`` or ``"closed"``, validated)."""
    raw = config.model_dump()
    for robot in raw["robots"].values():
        robot["controller"]["control"] = control
    return CellConfig.model_validate(raw)


def _zero_delay(links: LinkFaults) -> LinkFaults:
    def zero(fault: LinkFault) -> LinkFault:
        return LinkFault(delay_s=0.0, jitter_s=0.0, loss=fault.loss, duplication=fault.duplication)

    return LinkFaults(
        tracker_to_gateway=zero(links.tracker_to_gateway),
        controller_to_gateway=zero(links.controller_to_gateway),
        gateway_to_controller=zero(links.gateway_to_controller),
    )


def _case(
    config: CellConfig,
    suite_seed: int,
    index: int,
    duration_s: float,
    suite: str = "stress",
    occlusion: bool = False,
) -> SweepCase:
    return case_of_cell(
        config, suite_seed, index, duration_s, collaborative=suite == "collaborative", occlusion=occlusion
    )


def run_variant(
    config: CellConfig,
    robots: dict[str, RobotModel],
    suite_seed: int,
    index: int,
    duration_s: float,
    variant: str,
    suite: str = "stress",
    occlusion: bool = False,
) -> VariantRun:
    """Generate case ``index`` of the suite ``suite_seed`` (of :data:`SUITES`; its trackers with line of sight if
    ``occlusion``) and simulate it with ``variant``."""
    case = _case(config, suite_seed, index, duration_s, suite, occlusion)
    cell = case.config(config)
    scenario = case.scenario
    links = case.links
    if variant != OPEN:  # every other variant is a closed controller's (a cell with open ones is compared so)
        cell = with_control(cell, "closed")
    if variant in METHODS:
        cell = with_method(cell, variant)
    elif variant == ZERO_DELAY:
        raw = with_method(cell, "zanchettin2016").model_dump()
        for tracker in raw["trackers"].values():
            tracker["latency_s"] = 0.0
        cell = CellConfig.model_validate(raw)
        links = _zero_delay(links)
    elif variant == OPEN:
        cell = with_control(with_method(cell, "zanchettin2016"), "open")
    elif variant == NO_HUMAN:
        cell = with_method(cell, "zanchettin2016")
        scenario = Scenario(description=f"{scenario.description}, nobody", duration_s=duration_s, loop=False)
    else:
        raise ValueError(f"unknown variant {variant!r}; allowed: {', '.join(ALL_VARIANTS)}")
    result = simulate(cell, robots, scenario, links, duration_s, case.seed)
    audit = result.audit
    margin = audit.smallest_margin_moving_m
    approach_mps = fastest_approach_mps(case.scenario, robot_bases_xy_m(config))  # the case's people, every variant
    return VariantRun(
        index=index,
        seed=case.seed,
        variant=variant,
        beyond_budget=case.params["beyond_budget"],
        kind=case.params.get("kind") or case_kind(case.params["people"]),
        program_cycles=result.program_progress_cycles,
        audited_s=audit.duration_s,
        time_stopped_s=audit.time_stopped_s,
        mean_delta=audit.mean_delta_applied,
        smallest_margin_moving_m=margin if math.isfinite(margin) else None,
        violations=audit.violations,
        duration_s=result.duration_s,
        wall_s=result.wall_s,
        fastest_approach_mps=round(approach_mps, 4),
        beyond_k=beyond_k(approach_mps, config.safety.human_speed_mps),
        unacceptable_contacts=audit.unacceptable_contacts,
        contact_speeds_mps=tuple(round(v, 4) for v in audit.contact_speeds_mps),
    )


_WORKER: dict[str, Any] = {}


def _init_worker(config_path: str | None) -> None:
    config = load_cell_config(config_path)
    _WORKER["config"] = config
    _WORKER["robots"] = {name: load_robot_model(name, robot) for name, robot in config.robots.items()}


def _run_in_worker(task: tuple[int, int, float, str, str, bool]) -> VariantRun:
    suite_seed, index, duration_s, variant, suite, occlusion = task
    return run_variant(_WORKER["config"], _WORKER["robots"], suite_seed, index, duration_s, variant, suite, occlusion)


def iter_runs(
    scenarios: int,
    seed: int,
    workers: int,
    duration_s: float,
    config_path: str | None = None,
    suite: str = "stress",
    occlusion: bool = False,
    variants: Sequence[str] = VARIANTS,
) -> Iterator[VariantRun]:
    """Every variant (of ``variants``) on cases ``0 .. scenarios-1`` of suite ``seed``; yields runs as they finish
    (any order)."""
    tasks = [(seed, index, duration_s, variant, suite, occlusion) for index in range(scenarios) for variant in variants]
    if workers <= 1:
        _init_worker(config_path)
        for task in tasks:
            yield _run_in_worker(task)
        return
    context = multiprocessing.get_context("spawn")
    with context.Pool(workers, initializer=_init_worker, initargs=(config_path,)) as pool:
        yield from pool.imap_unordered(_run_in_worker, tasks, chunksize=1)


# -- the figures --------------------------------------------------------------------------------------


def aggregate(runs: Sequence[VariantRun]) -> dict[str, Any]:
    """The figures of one variant over its runs."""
    simulated_s = sum(r.duration_s for r in runs)
    audited_s = sum(r.audited_s for r in runs)
    cycles = sum(r.program_cycles for r in runs)
    margins = [r.smallest_margin_moving_m for r in runs if r.smallest_margin_moving_m is not None]
    violations = sum(r.violations for r in runs)
    unacceptable = sum(r.unacceptable_contacts for r in runs)
    by_contact = bool(runs) and all(r.variant in CONTACT_METHODS for r in runs)
    return {
        "runs": len(runs),
        "program_cycles": round(cycles, 3),
        "simulated_s": simulated_s,
        "cycles_per_hour": round(cycles / simulated_s * SECONDS_PER_HOUR, 2) if simulated_s > 0 else None,
        "time_stopped_pct": round(100.0 * sum(r.time_stopped_s for r in runs) / audited_s, 2) if audited_s else None,
        "mean_delta": round(sum(r.mean_delta * r.audited_s for r in runs) / audited_s, 4) if audited_s else None,
        "smallest_margin_moving_m": round(min(margins), 4) if margins else None,
        "violations": violations,
        "cases_with_violations": sum(1 for r in runs if r.violations),
        "unacceptable_contacts": unacceptable,
        "contact_speeds_mps": sorted(v for r in runs for v in r.contact_speeds_mps),
        "counts": unacceptable == 0 if by_contact else violations == 0,
    }


def speed_group(runs: Sequence[VariantRun]) -> dict[str, Any]:
    """Cases, violations, smallest margin while moving and margin lost (how far it went below 0) of some runs."""
    margins = [r.smallest_margin_moving_m for r in runs if r.smallest_margin_moving_m is not None]
    smallest = min(margins) if margins else None
    return {
        "cases": len(runs),
        "violations": sum(r.violations for r in runs),
        "cases_with_violations": sum(1 for r in runs if r.violations),
        "smallest_margin_moving_m": None if smallest is None else round(smallest, 4),
        "margin_lost_m": 0.0 if smallest is None else round(max(0.0, -smallest), 4),
        "fastest_approach_mps": max((r.fastest_approach_mps for r in runs), default=None),
    }


def speed_split(runs: Sequence[VariantRun]) -> dict[str, dict[str, dict[str, Any]]]:
    """Per variant, the cases whose people approach within K and those where someone is faster, apart."""
    return {
        v: {
            "within_k": speed_group([r for r in runs if r.variant == v and not r.beyond_k]),
            "beyond_k": speed_group([r for r in runs if r.variant == v and r.beyond_k]),
        }
        for v in _present(runs)
    }


def _ratio(figures: dict[str, dict[str, Any]], method: str, baseline: str) -> float | None:
    a = figures[method]["cycles_per_hour"]
    b = figures[baseline]["cycles_per_hour"]
    if a is None or b is None:
        return None
    return round(a / b, 3) if b > 0 else None


def ratios(figures: dict[str, dict[str, Any]]) -> list[AtLeast]:
    """The targets: cycles per hour of each of :data:`RATIO_METHODS` over three_zones, stop_only and no_human."""
    targets: list[AtLeast] = []
    for method, (baseline, limit) in ((m, t) for m in RATIO_METHODS for t in RATIO_TARGETS):
        if method not in figures or baseline not in figures:  # a suite without that variant
            continue
        ratio = _ratio(figures, method, baseline)
        counts = bool(figures[method]["counts"] and figures[baseline]["counts"] and ratio is not None)
        targets.append(
            AtLeast(
                name=f"cycles/h {method} / {baseline}",
                measured=ratio if ratio is not None else math.nan,
                limit=limit,
                unit="x",
                counts=counts,
            )
        )
    return targets


def figures_table(figures: dict[str, dict[str, Any]]) -> str:
    rows = []
    for variant, f in figures.items():
        mark = "" if f["counts"] else " *"
        rows.append(
            (
                variant,
                f"{f['cycles_per_hour']:.1f}{mark}" if f["cycles_per_hour"] is not None else "-",
                f"{f['time_stopped_pct']:.1f}" if f["time_stopped_pct"] is not None else "-",
                f"{f['mean_delta']:.3f}" if f["mean_delta"] is not None else "-",
                f"{f['smallest_margin_moving_m']:.3f}" if f["smallest_margin_moving_m"] is not None else "-",
                f["violations"],
                f"{f['program_cycles']:.1f}",
            )
        )
    return table(
        ["variant", "cycles/h", "stopped [%]", "mean δ", "min margin moving [m]", "violations", "cycles"], rows
    )


def ratios_table(targets: Sequence[AtLeast]) -> str:
    return table(
        ["target", "measured", "at least", "verdict"],
        [
            (
                t.name,
                f"{t.measured:.2f}x" if math.isfinite(t.measured) else "-",
                f"{t.limit:.2f}x",
                t.verdict if t.counts else f"{t.verdict} (violations or no figure: does not count)",
            )
            for t in targets
        ],
    )


def _margin_text(value: float | None) -> str:
    return "-" if value is None else f"{value:.3f}"


def speed_split_table(split: dict[str, dict[str, dict[str, Any]]]) -> str:
    """Per variant: the within-K figure (the guarantee) beside the faster-than-K figure (outside it)."""
    rows = []
    for variant, groups in split.items():
        within, beyond = groups["within_k"], groups["beyond_k"]
        rows.append(
            (
                variant,
                within["cases"],
                f"{within['violations']} ({within['cases_with_violations']} cases)",
                _margin_text(within["smallest_margin_moving_m"]),
                beyond["cases"],
                f"{beyond['violations']} ({beyond['cases_with_violations']} cases)",
                _margin_text(beyond["smallest_margin_moving_m"]),
                f"{beyond['margin_lost_m']:.3f}",
            )
        )
    headers = ["variant", "within K: cases", "violations", "min margin moving [m]"]
    headers += ["faster than K: cases", "violations", "min margin moving [m]", "margin lost [m]"]
    return table(headers, rows)


def _by_variant(runs: Sequence[VariantRun], keep: set[int] | None = None) -> dict[str, dict[str, Any]]:
    return {
        v: aggregate([r for r in runs if r.variant == v and (keep is None or r.index in keep)]) for v in _present(runs)
    }


def _present(runs: Sequence[VariantRun]) -> list[str]:
    """The variants that ran, in table order."""
    ran = {r.variant for r in runs}
    return [v for v in ALL_VARIANTS if v in ran]


def _collect(runs: Iterator[VariantRun], total: int, suite: str, quiet: bool) -> list[VariantRun]:
    """The runs as they finish, with a progress line on stderr every ~5 s (none if ``quiet``) and a line per
    violating run."""
    done: list[VariantRun] = []
    if quiet:
        return list(runs)
    with Progress(f"productivity ({suite})", total=total, unit="runs") as progress:
        for r in runs:
            done.append(r)
            if r.violations:
                where = f"faster than K, {r.fastest_approach_mps:.2f} m/s" if r.beyond_k else "within K"
                print(f"VIOLATION: case {r.index} {r.variant} ({where}): {r.violations} cycles", file=sys.stderr)
            progress.update(len(done), note=f"case {r.index} {r.variant}")
    return done


def run(
    scenarios: int,
    seed: int,
    workers: int,
    duration_s: float,
    config_path: str | None,
    quiet: bool = False,
    suite: str = "stress",
    occlusion: bool = False,
    variants: Sequence[str] = VARIANTS,
) -> Report:
    """Run the suite and build the report (figures over all cases and over the cases within budget)."""
    report = Report(
        NAME,
        {
            "scenarios": scenarios,
            "seed": seed,
            "workers": workers,
            "duration_s": duration_s,
            "config": config_path,
            "suite": suite,
            "occlusion": occlusion,
            "variants": list(variants),
        },
    )
    started_s = time.perf_counter()
    runs = _collect(
        iter_runs(scenarios, seed, workers, duration_s, config_path, suite, occlusion, variants),
        scenarios * len(variants),
        suite,
        quiet,
    )
    wall_s = time.perf_counter() - started_s
    runs.sort(key=lambda r: (r.index, ALL_VARIANTS.index(r.variant)))
    within = {r.index for r in runs if r.beyond_budget is None}
    figures = _by_variant(runs)
    figures_within = _by_variant(runs, within)
    by_kind = {}
    for kind in COLLABORATIVE_KINDS if suite == "collaborative" else CASE_KINDS:
        keep = {r.index for r in runs if r.kind == kind and r.beyond_budget is None}
        if keep:
            kind_figures = _by_variant(runs, keep)
            by_kind[kind] = {
                "cases": len(keep),
                "figures": kind_figures,
                "ratios": [t.as_dict() for t in ratios(kind_figures)],
            }
    targets = ratios(figures)
    report.targets.extend(targets)
    report.results = {
        "all_cases": figures,
        "within_budget": {"cases": len(within), "figures": figures_within},
        "ratios_within_budget": [t.as_dict() for t in ratios(figures_within)],
        "within_budget_by_kind": by_kind,
        "human_speed_mps": load_cell_config(config_path).safety.human_speed_mps,
        "speed_split": speed_split(runs),
        "wall_s": round(wall_s, 1),
        "simulated_s": sum(r.duration_s for r in runs),
        "runs": [asdict(r) for r in runs],
    }
    report.notes.extend(
        [
            "Every variant runs every case with the case's seed: same people, sensors, noise, drops, link draws, "
            "gateway phase and program phase.",
            "A figure counts only if its variant had 0 violations (marked * otherwise); a ratio target passes "
            "only if both of its methods had 0 violations.",
            f"{ZERO_DELAY}: every link delay and jitter 0 and tracker latency 0 (loss and duplication kept).",
            f"{NO_HUMAN}: the same case with nobody in the cell (same trackers and links, zanchettin2016); cases "
            "with a delay beyond max_data_age_s stop the robot on stale data even then.",
            "within_budget: the same figures over the cases whose link delays the generator kept within "
            "max_data_age_s (in the others every method stops on stale data).",
            "within_budget_by_kind: the same, per kind of case: 'standing' (someone stands in the cell from the "
            "start), else 'approach' (someone walks up to the robot), else 'cross' (people only cross the cell).",
            "Program cycles are program progress: whole wraps plus the fraction of the unfinished cycle of each "
            "run (one cycle of the shipped program is about 6.4 s at δ = 1).",
            "speed_split: per variant, the cases where someone approaches faster than K "
            "(hrc_tools.sim.human_speed: walking "
            "toward a robot base, plus the hand while reaching) apart from those within K. Faster people are "
            "outside the separation-monitoring guarantee; their violations are reported there, never hidden; "
            "margin_lost_m is how far the smallest margin while moving went below 0.",
        ]
    )
    return report


def print_report(doc: dict[str, Any]) -> None:
    results = doc["results"]
    print(f"\nall {doc['parameters']['scenarios']} cases, {doc['parameters']['duration_s']:g} s each:")
    print(figures_table(results["all_cases"]))
    print("* = violations: the figure does not count")
    print()
    print(ratios_table([_target(t) for t in doc["targets"]]))
    within = results["within_budget"]
    print(f"\ncases with link delays within max_data_age_s ({within['cases']}):")
    print(figures_table(within["figures"]))
    print()
    print(ratios_table([_target(t) for t in results["ratios_within_budget"]]))
    for kind, part in results.get("within_budget_by_kind", {}).items():
        print(f"\nwithin budget, kind {kind!r} ({part['cases']} cases):")
        print(figures_table(part["figures"]))
        print(ratios_table([_target(t) for t in part["ratios"]]))
    if "speed_split" in results:
        print(f"\npeople within K = {results['human_speed_mps']:g} m/s and faster (outside the guarantee), all cases:")
        print(speed_split_table(results["speed_split"]))
    speed = results["simulated_s"] / results["wall_s"] if results["wall_s"] > 0 else math.inf
    print(f"\nwall time {results['wall_s']:.1f} s ({doc['parameters']['workers']} workers, {speed:.1f}x real time)")


def _target(d: dict[str, Any]) -> AtLeast:
    measured = d["measured"]
    return AtLeast(
        name=d["name"],
        measured=math.nan if measured is None else float(measured),
        limit=d["target"],
        unit=d["unit"],
        counts=d["counts"],
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.productivity", description=__doc__.split("\n\n")[0])
    add_case_arguments(parser, scenarios=40, duration_s=30.0)
    parser.add_argument("--json", type=Path, default=default_json_path(NAME), help="where to write the results")
    parser.add_argument("--suite", choices=SUITES, default="stress", help="the case generator (default stress)")
    parser.add_argument(
        "--variants",
        nargs="+",
        choices=ALL_VARIANTS,
        default=list(VARIANTS),
        help=f"run these variants (default all but {OPEN}), e.g. lucci2020_pfl stop_only no_human",
    )
    parser.add_argument(
        "--plot", type=Path, default=None, help="the PNG plot of cycles/h (default: next to the JSON, .png)"
    )
    parser.add_argument(
        "--plot-from",
        type=Path,
        nargs="+",
        default=None,
        metavar="JSON",
        help="run nothing: plot these earlier results, one panel each (e.g. the stress and the collaborative suite)",
    )
    args = parser.parse_args(argv)
    problem = case_argument_problem(args)
    if problem is not None:
        parser.error(problem)
    plot_path = args.plot if args.plot is not None else args.json.with_suffix(".png")
    if args.plot_from:
        return _plot_only(args.plot_from, plot_path)
    occluded = ", occlusion" if args.occlusion else ""
    print_header(f"productivity: every method on the same seeded scenario suite ({args.suite}{occluded})")
    report = run(
        args.scenarios,
        args.seed,
        args.workers,
        args.duration_s,
        args.config,
        args.quiet,
        args.suite,
        args.occlusion,
        args.variants,
    )
    doc = report.finish(args.json)
    print_report(doc)
    print(f"\nwrote {args.json}")
    try:
        print(f"wrote {plot_cycles_per_hour([doc], plot_path)}")
    except PlotError as exc:
        print(f"no plot: {exc}", file=sys.stderr)
    return 0


def _plot_only(sources: Sequence[Path], plot_path: Path) -> int:
    """Plot earlier result files; 2 with a message if one cannot be read or plotted."""
    try:
        docs = [json.loads(p.read_text()) for p in sources]
        print(f"wrote {plot_cycles_per_hour(docs, plot_path)}")
    except (OSError, ValueError, PlotError) as exc:
        print(f"python -m bench.productivity: cannot plot: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
