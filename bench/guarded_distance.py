"""Paper 1's "guarded distance" (Fig. 9): an open Panda steps aside with its elbow where a closed one can only slow.

    .venv/bin/python -m bench.guarded_distance [--seed 1] [--plot out/bench/guarded_distance.png]
    .venv/bin/python -m bench.guarded_distance --scenario beside_elbow --program panda_elbow_out

One scenario (default ``configs/scenarios/behind_elbow.toml``: a person walks up behind the robot on its elbow's side
and stands 1.5 m from the base axis for 8.5 s, the Panda's pick and place; or ``beside_elbow`` with the program
``panda_elbow_out``: the elbow held out toward a person standing beside the robot) in the simulated cell
(:func:`hrc_tools.sim.cell.simulate`: the real gateway node, tracker emulator and controller nodes, audited every
cycle), the same seed twice: the Panda of
``configs/cell_open_panda.toml`` behind its open controller (LP (9)/(13)), and the same Panda behind a closed
controller (eq. (15), the override). Per run: program cycles completed, mean δ and the share of time at δ = 1 while
the person stands, the smallest true distance, the elbow's displacement and the auditor's violations; a plot of δ,
the smallest distance and the elbow's position over time (like the paper's Fig. 9) when matplotlib is installed.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from bench._report import Report, default_json_path, print_header, table
from gateway.reference.kinematics import link_kinematics
from hrc_contract.config import CellConfig
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_tools.sim.cell import TraceSample, simulate
from hrc_tools.sim.links import LinkFaults
from tracker_emu.scenario import load_scenario

NAME = "guarded_distance"
CONFIG = "configs/cell_open_panda.toml"
SCENARIO = "behind_elbow"
PROGRAM = "panda_pick_place"
STANDING_S = (6.5, 15.0)
"""When the person stands near the robot [s] (the keyframes of both scenarios)."""
ELBOW_LINK = "elbow"
"""The Panda link whose first end (``panda_link3``) is the elbow of the plot."""


def with_control(config: CellConfig, control: str) -> CellConfig:
    robots = {
        name: robot.model_copy(update={"controller": robot.controller.model_copy(update={"control": control})})
        for name, robot in config.robots.items()
    }
    return config.model_copy(update={"robots": robots})


def with_program(config: CellConfig, program: str) -> CellConfig:
    """The cell with the Panda running ``configs/programs/<program>.toml``."""
    path = Path(config.robots["panda"].program).parent / f"{program}.toml"
    if not path.is_file():
        raise SystemExit(f"no program {path}; allowed: {sorted(p.stem for p in path.parent.glob('*.toml'))}")
    robots = {**config.robots, "panda": config.robots["panda"].model_copy(update={"program": str(path)})}
    return config.model_copy(update={"robots": robots})


def run_one(config: CellConfig, seed: int, scenario_name: str) -> tuple[dict[str, Any], list[TraceSample]]:
    robots = {name: load_robot_model(name, r) for name, r in config.robots.items()}
    path = Path(config.scenarios_dir) / f"{scenario_name}.toml"
    if not path.is_file():
        raise SystemExit(f"no scenario {path}; allowed: {sorted(p.stem for p in path.parent.glob('*.toml'))}")
    scenario = load_scenario(path)
    samples: list[TraceSample] = []
    result = simulate(
        config,
        robots,
        scenario,
        LinkFaults(),
        scenario.duration_s,
        seed,
        program_start_s={"panda": 0.0},
        trace=samples.append,
    )
    robot = robots["panda"]
    data = robot.model.createData()
    elbow = robot.link_names.index(ELBOW_LINK)
    start = link_kinematics(robot, data, samples[0].q_rad, np.zeros_like(samples[0].q_rad)).p_a_world[elbow]
    standing = [s for s in samples if STANDING_S[0] <= s.t_s <= STANDING_S[1]]
    moved = [
        float(np.linalg.norm(link_kinematics(robot, data, s.q_rad, np.zeros_like(s.q_rad)).p_a_world[elbow] - start))
        for s in standing[::25]
    ]
    deltas = np.array([s.delta for s in standing])
    figures = {
        "program_cycles": round(result.program_progress_cycles, 3),
        "delta_mean_standing": round(float(deltas.mean()), 3),
        "share_at_delta_1_standing": round(float((deltas > 1.0 - 1e-6).mean()), 3),
        "min_distance_m": None if result.audit.min_distance_m is None else round(result.audit.min_distance_m, 3),
        "elbow_moved_max_m": round(max(moved), 3),
        "violations": result.audit.violations,
        "smallest_margin_moving_m": result.audit.smallest_margin_moving_m,
    }
    return figures, samples


def plot(runs: dict[str, list[TraceSample]], config: CellConfig, path: Path) -> str | None:
    """δ, the smallest distance and the elbow's height over time for each run; None, or why no plot was drawn."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return "matplotlib is not installed (pip install -e '.[bench]')"
    robot = load_robot_model("panda", config.robots["panda"])
    data = robot.model.createData()
    elbow = robot.link_names.index(ELBOW_LINK)
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(8, 7))
    for label, samples in runs.items():
        kept = samples[::5]
        t = [s.t_s for s in kept]
        axes[0].plot(t, [s.delta for s in kept], label=label)
        axes[1].plot(t, [np.nan if s.min_distance_m is None else s.min_distance_m for s in kept], label=label)
        axes[2].plot(
            t,
            [link_kinematics(robot, data, s.q_rad, np.zeros_like(s.q_rad)).p_a_world[elbow][1] for s in kept],
            label=label,
        )
    axes[0].set_ylabel("δ")
    axes[1].set_ylabel("min distance [m]")
    axes[2].set_ylabel("elbow y [m]")
    axes[2].set_xlabel("t [s]")
    for ax in axes:
        ax.axvspan(*STANDING_S, color="0.9")
        ax.legend(loc="best")
    fig.suptitle("guarded distance: a person stands behind the Panda (shaded), open vs closed controller")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.guarded_distance", description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=default_json_path(NAME))
    parser.add_argument("--plot", type=Path, default=None, help="write the plot here (PNG)")
    parser.add_argument("--scenario", default=SCENARIO, help=f"configs/scenarios/<name>.toml (default {SCENARIO})")
    parser.add_argument("--program", default=PROGRAM, help=f"configs/programs/<name>.toml (default {PROGRAM})")
    args = parser.parse_args(argv)
    print_header("guarded distance: an open Panda (LP (9)/(13)) against a closed one, same scenario and seed")
    base = with_program(load_cell_config(CONFIG), args.program)
    report = Report(
        NAME,
        {
            "seed": args.seed,
            "config": CONFIG,
            "scenario": args.scenario,
            "program": args.program,
            "standing_s": STANDING_S,
        },
    )
    traces: dict[str, list[TraceSample]] = {}
    for control in ("open", "closed"):
        figures, samples = run_one(with_control(base, control), args.seed, args.scenario)
        report.results[control] = figures
        traces[control] = samples
    keys = list(report.results["open"])
    rows = [[k, report.results["open"][k], report.results["closed"][k]] for k in keys]
    print(table(["figure", "open", "closed"], rows))
    ratio = report.results["open"]["program_cycles"] / max(report.results["closed"]["program_cycles"], 1e-9)
    report.results["cycles_open_over_closed"] = round(ratio, 3)
    print(f"\nprogram cycles, open / closed: {ratio:.3f}")
    if args.plot is not None:
        why = plot(traces, base, args.plot)
        print(f"plot: {args.plot}" if why is None else f"no plot: {why}")
    report.finish(args.json)
    print(f"wrote {args.json}")
    return 0 if all(report.results[c]["violations"] == 0 for c in ("open", "closed")) else 1


if __name__ == "__main__":
    raise SystemExit(main())
