"""Sustained loop with many robots: ``bench.loop`` on a cell of N copies of the two-arm cell (a UR5 and a Panda
facing each other, ``configs/cell_two_arms.toml``) side by side along x, one person per copy walking the
``two_arms_crossing`` path, every robot with its own controller emulator process.

The world and the volume the trackers cover are widened along x to hold every copy; along y they stay the two-arm
cell's, so that each person enters and leaves through the covered volume's -y face as in the two-arm cell (a person
who vanished inside it would be lost, not gone, and hold the robots near them: docs/contract.md "Tracks").

The default, 4 copies, is 8 robots × 4 people (each person seen by both trackers, so the gateway merges 8
humans). The controller emulators run ``--controllers-per-process`` to a process (``bench.controller_host``; the
issue allows one emulator process to host several controllers). The cell file and the scenario are written to the
output folder; the measurement is ``bench.loop``'s (period of the ticks from the first robot's override stamps,
missed cycles, HTTP load).

    python -m bench.many_robots [--pairs 4] [--duration 60] [--rates 250] [--http-rates 0,200] [--sse-clients 0]
                                [--controllers-per-process 4] [--json out/bench/many_robots.json]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from bench import loop
from bench._report import default_json_path, print_header
from hrc_contract.config import CellConfig
from hrc_runtime.config import load_cell_config
from hrc_tools.cell.procs import write_cell_config
from tracker_emu.scenario import Scenario, load_scenario, scenario_path

NAME = "many_robots"
# bench/ is never installed: it runs from the checkout
TWO_ARMS = Path(__file__).resolve().parents[1] / "configs" / "cell_two_arms.toml"
PERSON_PATH = "two_arms_crossing"
PAIR_SPACING_M = 6.0
"""Distance along x between neighbouring copies of the two-arm cell [m]: each copy (robots and person) spans
x = -1 … 3.2 m, so that one copy's person never reaches into the next copy."""
PERSON_SHIFT_S = 0.5
"""Each copy's person starts this much later than the previous one's [s]: all are in the cell at once."""
SCENARIO = f"{NAME}_people"


def pair_offsets_m(pairs: int) -> list[float]:
    """The x offset of each copy, centred on x = 0 [m]."""
    return [(k - (pairs - 1) / 2) * PAIR_SPACING_M for k in range(pairs)]


def _widened_along_x(low: Any, high: Any, offsets_m: list[float]) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The box ``low``..``high`` stretched along x to hold its copy at each of ``offsets_m`` [m]."""
    return (low[0] + min(offsets_m), *low[1:]), (high[0] + max(offsets_m), *high[1:])


def many_robot_config(two_arms: CellConfig, pairs: int, scenarios_dir: Path) -> CellConfig:
    """``pairs`` copies of the two-arm cell's robots (``ur5_k``, ``panda_k``) shifted along x; the world volume and
    the trackers' covered volume widened along x to hold them and their people; the scenarios read from
    ``scenarios_dir``."""
    raw = two_arms.model_dump()
    beyond_robots_x_m = max(robot["base_pose_world"]["xyz"][0] for robot in raw["robots"].values())
    offsets_m = pair_offsets_m(pairs)
    robots: dict[str, Any] = {}
    for k, dx in enumerate(offsets_m, start=1):
        for name, robot in raw["robots"].items():
            x, y, z = robot["base_pose_world"]["xyz"]
            robots[f"{name}_{k}"] = {**robot, "base_pose_world": {**robot["base_pose_world"], "xyz": (x + dx, y, z)}}
    plausibility, tracking = raw["plausibility"], raw["tracking"]
    plausibility["world_min_m"], plausibility["world_max_m"] = _widened_along_x(
        plausibility["world_min_m"], plausibility["world_max_m"], offsets_m
    )
    tracking["coverage_min_m"], tracking["coverage_max_m"] = _widened_along_x(
        tracking["coverage_min_m"], tracking["coverage_max_m"], offsets_m
    )
    for tracker in raw["trackers"].values():  # a sensor beyond the robots along x (the front one) stays beyond them
        position = tracker.get("position_m")
        if position is not None and position[0] > beyond_robots_x_m:
            tracker["position_m"] = (position[0] + max(offsets_m), *position[1:])
    raw.update(
        robots=robots,
        plausibility=plausibility,
        tracking=tracking,
        scenarios_dir=str(scenarios_dir),
        default_scenario=SCENARIO,
    )
    return CellConfig.model_validate(raw)


def people_scenario(path: Scenario, pairs: int) -> Scenario:
    """One person per copy on ``path``'s first person's keyframes, shifted to that copy and in time."""
    (person,) = path.humans
    humans = []
    for k, dx in enumerate(pair_offsets_m(pairs), start=1):
        keyframes = [
            kf.model_copy(update={"t_s": kf.t_s + (k - 1) * PERSON_SHIFT_S, "xy_m": (kf.xy_m[0] + dx, kf.xy_m[1])})
            for kf in person.keyframes
        ]
        humans.append(person.model_copy(update={"id": f"p{k}", "keyframes": keyframes}))
    duration_s = max(path.duration_s, humans[-1].keyframes[-1].t_s + 1.0)
    scenario = Scenario(
        description=f"{pairs} people, one per copy of the two-arm cell", duration_s=duration_s, loop=True, humans=humans
    )
    return Scenario.model_validate(scenario.model_dump())  # the validators of a scenario file


def scenario_toml(scenario: Scenario) -> str:
    """``scenario`` as a scenario file (``configs/scenarios/*.toml``)."""
    lines = [f"description = {scenario.description!r}", f"duration_s = {scenario.duration_s!r}", "loop = true"]
    for human in scenario.humans:
        lines += ["", "[[humans]]", f"id = {human.id!r}", f"both_arms = {str(human.both_arms).lower()}"]
        for kf in human.keyframes:
            lines += [
                "",
                "[[humans.keyframes]]",
                f"t_s = {kf.t_s!r}",
                f"xy_m = [{kf.xy_m[0]!r}, {kf.xy_m[1]!r}]",
                f"heading_rad = {kf.heading_rad!r}",
                f"reach = {kf.reach!r}",
            ]
    return "\n".join(lines) + "\n"


def write_cell(pairs: int, work_dir: Path) -> Path:
    """Write the many-robot cell and its scenario under ``work_dir``; return the cell file.

    Raises:
        BenchError: the written cell does not load back to the same configuration.
        ConfigError: the written scenario is not valid.
    """
    work_dir = work_dir.resolve()  # the cell file names its scenarios by absolute path
    two_arms = load_cell_config(TWO_ARMS)
    scenarios_dir = work_dir / f"{NAME}-scenarios"
    scenarios_dir.mkdir(parents=True, exist_ok=True)
    people = people_scenario(load_scenario(scenario_path(two_arms.scenarios_dir, PERSON_PATH)), pairs)
    (scenarios_dir / f"{SCENARIO}.toml").write_text(scenario_toml(people))
    if load_scenario(scenarios_dir / f"{SCENARIO}.toml") != people:
        raise ValueError("the written scenario does not load back to the same scenario")
    return write_cell_config(many_robot_config(two_arms, pairs, scenarios_dir), work_dir / f"{NAME}-cell.toml")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.many_robots", description=__doc__.split("\n\n")[0])
    parser.add_argument("--pairs", type=int, default=4, help="copies of the two-arm cell (robots = 2 × pairs)")
    loop.add_matrix_arguments(parser, rates="250", warmup_s=5.0)
    parser.add_argument(
        "--controllers-per-process",
        type=int,
        default=4,
        help="controller emulators hosted by one process (bench.controller_host; 1 = each its own process)",
    )
    parser.add_argument("--json", type=Path, default=default_json_path(NAME), help="where to write the results")
    args = parser.parse_args(argv)
    matrix = loop.matrix_arguments(parser, args)
    if not 1 <= args.pairs <= 16:
        parser.error("--pairs must be 1-16")
    if args.controllers_per_process < 1:
        parser.error("--controllers-per-process must be >= 1")
    print_header(f"sustained loop with {2 * args.pairs} robots × {args.pairs} people: period and missed cycles")
    cell_path = write_cell(args.pairs, args.json.parent)
    report = loop.run(
        matrix.rates_hz,
        matrix.http_rates,
        matrix.duration_s,
        matrix.warmup_s,
        SCENARIO,
        0,
        cell_path,
        args.json.parent,
        load_nice=matrix.load_nice,
        controllers_per_process=args.controllers_per_process,
        sse_clients=matrix.sse_clients,
    )
    report.benchmark = NAME
    report.parameters.update(pairs=args.pairs, robots=2 * args.pairs, people=args.pairs)
    doc = report.finish(args.json)
    loop.print_report(doc)
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
