"""The planner layer's productivity in the simulated cell: cycles per hour with the planner off, on, and with the
request (16) alone, for paper 2's two experiments (issue 35; docs/planner.md).

    .venv/bin/python -m bench.planner [--duration 16] [--json out/bench/planner.json]

The open Panda of ``configs/cell_open_panda_planner.toml`` (wide swing across the front), one tracker without noise:

- ``in_swing``: a person walks from 3.5 m to 1.8 m in front of the robot (0.8 s) and stands in the swing;
- ``close``: a person stands at (1.5, −1.2) m, beside the place station, from the start.

Modes: ``off`` (scaling only: the robot creeps or waits), ``on`` (horizon check and request (16)), ``request`` (the
horizon check off: only the request (16) replans). Printed per run: program cycles per hour, violations (auditor),
plans requested and adopted per hour, failures, planning time p50/p99/max (wall clock of the synchronous planner in
the simulated cell, on this machine's load: the simulated robot does not wait for it). A script that prints figures,
not a timed test.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from typing import Any

from hrc_contract.config import CellConfig
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_tools.sim.cell import simulate
from hrc_tools.sim.links import LinkFaults
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

CONFIG = "configs/cell_open_panda_planner.toml"
FACING_ROBOT_RAD = 3.141592653589793
SCENARIOS = {"in_swing": ((3.5, 0.0), (1.8, 0.0)), "close": ((1.5, -1.2), (1.5, -1.2))}
MODES: dict[str, dict[str, Any]] = {
    "off": {"enabled": False},
    "on": {"enabled": True},
    "request": {"enabled": True, "horizon_s": 0.05},
}


def scenario(name: str, duration_s: float) -> Scenario:
    start, stand = SCENARIOS[name]
    keyframes = [
        Keyframe(t_s=0.0, xy_m=start, heading_rad=FACING_ROBOT_RAD),
        Keyframe(t_s=0.8, xy_m=stand, heading_rad=FACING_ROBOT_RAD),
        Keyframe(t_s=duration_s, xy_m=stand, heading_rad=FACING_ROBOT_RAD),
    ]
    return Scenario(
        description=name, duration_s=duration_s, loop=False, humans=[HumanScript(id="h1", keyframes=keyframes)]
    )


def run(name: str, mode: str, duration_s: float) -> dict[str, Any]:
    raw = load_cell_config(CONFIG).model_dump()
    raw["trackers"] = {"front": {"rate_hz": 30.0, "noise_std_m": 0.0, "drop_probability": 0.0, "latency_s": 0.03}}
    raw["planner"] = {**raw["planner"], **MODES[mode]}
    config = CellConfig.model_validate(raw)
    robots = {n: load_robot_model(n, r) for n, r in config.robots.items()}
    started = time.perf_counter()
    result = simulate(
        config, robots, scenario(name, duration_s), LinkFaults(), duration_s, 1, program_start_s={"panda": 0.0}
    )
    per_hour = 3600.0 / duration_s
    stats = result.planner.get("panda", {})
    requests = sum(stats.get("requests", {}).values())
    return {
        "scenario": name,
        "mode": mode,
        "cycles": result.program_progress_cycles,
        "cycles_per_h": result.program_progress_cycles * per_hour,
        "violations": result.audit.violations,
        "plans_requested_per_h": requests * per_hour,
        "plans_adopted_per_h": stats.get("adopted", 0) * per_hour,
        "requests": stats.get("requests", {}),
        "failures": stats.get("failures", {}),
        "planning_p50_s": stats.get("planning_p50_s"),
        "planning_p99_s": stats.get("planning_p99_s"),
        "planning_max_s": stats.get("planning_max_s"),
        "wall_s": time.perf_counter() - started,
    }


def _ms(x: float | None) -> str:
    return "-" if x is None else f"{1000.0 * x:.0f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--duration", type=float, default=16.0, help="simulated time per run [s]")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows here")
    args = parser.parse_args()
    print(f"planner bench: {CONFIG}, {args.duration:.0f} s per run, load average {os.getloadavg()[0]:.2f}")
    print(
        f"{'scenario':10} {'mode':8} {'cycles':>7} {'cycles/h':>9} {'viol':>5} {'req/h':>7} {'adopt/h':>8} "
        f"{'p50 ms':>7} {'p99 ms':>7} {'max ms':>7}  failures"
    )
    rows = []
    for name in SCENARIOS:
        for mode in MODES:
            row = run(name, mode, args.duration)
            rows.append(row)
            print(
                f"{name:10} {mode:8} {row['cycles']:7.2f} {row['cycles_per_h']:9.0f} {row['violations']:5d} "
                f"{row['plans_requested_per_h']:7.0f} {row['plans_adopted_per_h']:8.0f} "
                f"{_ms(row['planning_p50_s']):>7} {_ms(row['planning_p99_s']):>7} {_ms(row['planning_max_s']):>7}  "
                f"{row['failures'] or ''}",
                flush=True,
            )
    print(f"load average at the end {os.getloadavg()[0]:.2f}")
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
