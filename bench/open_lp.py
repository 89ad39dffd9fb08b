"""LP time per cycle for an open robot: LP (9) then LP (13) (gateway/open_control.py), beside paper 1's Table I.

    .venv/bin/python -m bench.open_lp [--samples 3000] [--repeat 1] [--json out/bench/open_lp.json]

The Panda of ``configs/cell_open_panda.toml`` (7 joints) at states along its program, 2 people × 15 capsules at
1.3–2.2 m from its base (so that rows bind and δ varies), the measured-delay rows of eq. (15) at 0.1 s. Timed, each
over the same samples: ``lp9 numpy`` (:func:`gateway.open_control.solve_lp9` on every row that can bind: DAQP on LP
(9) alone), ``lp9+lp13`` (:meth:`gateway.open_kernels.OpenLp.decide`, what the loop runs: the velocity box, the rows
within it, both LPs and the row checks), ``lp9+lp13 numpy`` (:func:`gateway.open_control.decide`, its numpy
reference, timed interleaved with it: the two alternate which goes first, so that the machine's load falls on both
alike; their answers are compared) and ``command`` (:meth:`gateway.open_robot.OpenRobot.command`: Jacobians, task,
rows that can bind, both LPs), with the rows the LPs carried. Paper 1 (CPLEX, Xenomai PC): 245.7 µs mean, 308 µs p95,
370 µs max.
"""

from __future__ import annotations

import argparse
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench._report import Report, Target, default_json_path, print_header, summary, table, targets_table
from bench.compute import human_capsules
from gateway import open_control
from gateway.open_control import Solution
from gateway.open_kernels import OpenLp
from gateway.open_robot import OpenRobot
from gateway.reference.kinematics import link_kinematics
from gateway.reference.separation import build_rows
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.model import load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.config import load_cell_config
from tracker_emu.body import BodyPose

NAME = "open_lp"
CONFIG = "configs/cell_open_panda.toml"
T_DELAY_S = 0.1
TARGET_P99_US = 50.0
PAPER_US = {"mean": 245.7, "p95": 308.0, "max": 370.0}


def _people(rng: np.random.Generator) -> HumanCapsules:
    capsules = []
    ids = []
    for k in range(2):
        angle = rng.uniform(-math.pi, math.pi)
        distance = rng.uniform(1.3, 2.2)
        pose = BodyPose(distance * math.cos(angle), distance * math.sin(angle), heading_rad=angle + math.pi, reach=0.6)
        for c in human_capsules(pose):
            capsules.append(c)
            ids.append(f"p{k}")
    return HumanCapsules(
        np.array([c["a"] for c in capsules], dtype=float),
        np.array([c["b"] for c in capsules], dtype=float),
        np.array([c["radius"] for c in capsules], dtype=float),
        tuple(ids),
        tuple(c["name"] for c in capsules),
    )


def _previous_velocity(
    safety: open_control.SafetyRows,
    task: open_control.Task,
    q: np.ndarray,
    qd_nominal: np.ndarray,
    active: np.ndarray,
    limits: open_control.Limits,
    rng: np.random.Generator,
) -> np.ndarray:
    """The velocity of the cycle before, as the loop has it: LP (9)'s answer at this state with only the velocity and
    position limits as its box (the previous cycle's command satisfied these rows), or, where that has none, a random
    fraction 0.3–1 of the program's velocity (a robot that must slow faster than it can: the ramp stop's path)."""
    qd_prev = float(rng.uniform(0.3, 1.0)) * np.asarray(qd_nominal, dtype=float)
    lower = np.maximum(-limits.qd_max_radps, np.minimum((limits.q_min_rad - q[active]) / 0.004, 0.0))
    upper = np.minimum(limits.qd_max_radps, np.maximum((limits.q_max_rad - q[active]) / 0.004, 0.0))
    steady = open_control.solve_lp9(safety, task, lower, upper)
    if steady is not None:
        qd_prev = np.zeros_like(qd_prev)
        qd_prev[active] = steady[0]
    return qd_prev


def _ratios(reference_us: list[float], compiled_us: list[float]) -> dict[str, float]:
    """How many times longer the reference took: the median of the per-sample ratios, and the ratio of each
    percentile."""
    old, new = np.array(reference_us), np.array(compiled_us)
    ratios = {"per_sample_median": round(float(np.median(old / new)), 2)}
    for q in (50, 95, 99):
        ratios[f"p{q}"] = round(float(np.percentile(old, q) / np.percentile(new, q)), 2)
    return ratios


def _time_both(
    lp: OpenLp, args: tuple[Any, ...], link_names: tuple[str, ...], repeat: int, compiled_first: bool
) -> tuple[dict[str, Solution], dict[str, float], dict[str, float]]:
    """Both decisions on one sample, ``repeat`` times, taking turns at going first: the answers, the first time and
    the least time of each [µs]."""
    cap = open_control.fixed_cap(1.0)
    answers: dict[str, Solution] = {}
    first: dict[str, float] = {}
    least = {"lp9+lp13": math.inf, "lp9+lp13 numpy": math.inf}
    for turn in range(repeat):
        order = ("lp9+lp13", "lp9+lp13 numpy") if compiled_first == (turn % 2 == 0) else ("lp9+lp13 numpy", "lp9+lp13")
        for name in order:
            decide: Callable[..., Solution] = lp.decide if name == "lp9+lp13" else open_control.decide
            t_start = time.perf_counter_ns()
            answers[name] = decide(*args, cap, link_names, 1.0, 0.0)
            took_us = (time.perf_counter_ns() - t_start) / 1e3
            first.setdefault(name, took_us)
            least[name] = min(least[name], took_us)
    return answers, first, least


def run(samples: int, seed: int, repeat: int = 1) -> dict[str, object]:
    config = load_cell_config(CONFIG)
    robot = load_robot_model("panda", config.robots["panda"])
    trajectory = load_trajectory(config.robots["panda"].program, robot)
    data = robot.model.createData()
    rng = np.random.default_rng(seed)
    times: dict[str, list[float]] = {"lp9 numpy": [], "lp9+lp13": [], "lp9+lp13 numpy": [], "command": []}
    lp = OpenLp()
    same = 0
    rows_kept: list[int] = []
    deltas: list[float] = []
    hows: dict[str, int] = {}
    for _ in range(samples):
        tau = float(rng.uniform(0.0, trajectory.duration_s))
        q, qd_nominal = trajectory.sample(tau)
        humans = _people(rng)
        links = link_kinematics(robot, data, q, qd_nominal)
        rows = build_rows(
            links,
            robot.link_radius_m,
            robot.t_brake_link_s,
            float(robot.braking_time_s.max()),
            humans,
            config.safety,
            T_DELAY_S,
        )
        open_robot = OpenRobot(robot, trajectory, 0.004, config.robots["panda"].controller.braking_time_s)
        open_robot.tau_s, open_robot.q_ref_rad = tau, np.array(q)
        open_robot.delta_prev, open_robot.last_mono_ns = 1.0, 0
        open_robot.lp = lp  # one robot's buffers, reused cycle after cycle as in the loop
        # the pieces the LPs take, as the command builds them
        task, _ = open_robot.task(open_robot.q_ref_rad)
        jac_a, jac_b = open_robot.link_jacobians(q)
        safety = open_control.safety_rows(
            jac_a,
            jac_b,
            links.p_a_world,
            links.p_b_world,
            humans.h_a_world,
            humans.h_b_world,
            rows.f_m2,
            rows.horizon_s,
            open_robot.limits.qd_max_radps,
        )
        active = open_robot.active
        open_robot.qd_prev_radps = _previous_velocity(safety, task, q, qd_nominal, active, open_robot.limits, rng)
        qd_prev = open_robot.qd_prev_radps[active]
        lower, upper = open_control.velocity_bounds(qd_prev, q[active], open_robot.limits, 0.004)
        qd_self = open_control.self_motion_reference(task, 1.0, np.zeros(active.size), np.zeros(active.size))

        args = (safety, task, qd_prev, q[active], open_robot.limits, 0.004, qd_self)
        cap = open_control.fixed_cap(1.0)
        t0 = time.perf_counter_ns()
        open_control.solve_lp9(safety, task, lower, upper)
        t1 = time.perf_counter_ns()
        answers, first, least = _time_both(lp, args, robot.link_names, repeat, len(rows_kept) % 2 == 1)
        for name in first:
            times[name].append(first[name])
            if repeat > 1:
                times.setdefault(f"{name} least of {repeat}", []).append(least[name])
        t2 = time.perf_counter_ns()
        open_robot.command(q, open_robot.qd_prev_radps, 0, links, rows, humans, None, None, cap)
        t3 = time.perf_counter_ns()
        times["lp9 numpy"].append((t1 - t0) / 1e3)
        times["command"].append((t3 - t2) / 1e3)
        solution, reference = answers["lp9+lp13"], answers["lp9+lp13 numpy"]
        same += int(
            solution.how == reference.how
            and solution.delta == reference.delta
            and bool(np.array_equal(solution.qd_radps, reference.qd_radps))
        )
        rows_kept.append(safety.f_m2.size)
        deltas.append(solution.delta)
        hows[solution.how] = hows.get(solution.how, 0) + 1
    return {
        "time_us": {k: summary(v, 1.0, 1) for k, v in times.items()},
        "numpy_over_compiled": _ratios(times["lp9+lp13 numpy"], times["lp9+lp13"]),
        "same_answers": f"{same} of {samples}",
        "rows_in_lp": summary(rows_kept, 1.0, 0),
        "rows_of_all_pairs": int(len(robot.link_names) * humans.n_capsules * 4),
        "delta": summary(deltas, 1.0, 3),
        "how": hows,
        "variables": int(active.size + 1),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.open_lp", description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=3000)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="solve each sample this many times (both decisions, interleaved) and also report the least time of each: "
        "the cost without the other work on the machine",
    )
    parser.add_argument("--json", type=Path, default=default_json_path(NAME))
    args = parser.parse_args(argv)
    print_header("open controllers: LP (9) then (13) per cycle (Panda, 7 joints, 2 people × 15 capsules)")
    report = Report(
        NAME,
        {"samples": args.samples, "seed": args.seed, "repeat": args.repeat, "config": CONFIG, "t_delay_s": T_DELAY_S},
    )
    results = run(args.samples, args.seed, args.repeat)
    report.results = results
    times = results["time_us"]
    assert isinstance(times, dict)
    report.targets = [Target("LP (9) + LP (13) p99", times["lp9+lp13"]["p99"], TARGET_P99_US, "µs")]
    report.references = [{"name": "paper 1, Table I (CPLEX, LP (9))", "time_us": PAPER_US}]
    rows = [[k, v["p50"], v["p95"], v["p99"], v["max"], v["mean"]] for k, v in times.items()]
    rows.append(["paper 1 (CPLEX)", "-", PAPER_US["p95"], "-", PAPER_US["max"], PAPER_US["mean"]])
    print(table(["timed", "p50 [µs]", "p95", "p99", "max", "mean"], rows))
    print(
        f"\nlp9+lp13 numpy / lp9+lp13 (interleaved, same samples): {results['numpy_over_compiled']}; the same "
        f"answers (how, δ, q̇ bit for bit): {results['same_answers']}"
    )
    print(
        f"\nrows in the LP: {results['rows_in_lp']} of {results['rows_of_all_pairs']} (rows no velocity within the "
        f"limits can reach are left out); variables {results['variables']}; δ {results['delta']}; {results['how']}"
    )
    print("\n" + targets_table(report.targets))
    report.finish(args.json)
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
