"""LP time per cycle for an open robot: LP (9) then LP (13) (gateway/open_control.py), beside paper 1's Table I.

    .venv/bin/python -m bench.open_lp [--samples 3000] [--json out/bench/open_lp.json]

The Panda of ``configs/cell_open_panda.toml`` (7 joints) at states along its program, 2 people × 15 capsules at
1.3–2.2 m from its base (so that rows bind and δ varies), the measured-delay rows of eq. (15) at 0.1 s. Timed, each
over the same samples: ``lp9`` (DAQP on LP (9) alone), ``lp9+lp13`` (:func:`gateway.open_control.decide`: both LPs and
the row checks) and ``command`` (:meth:`gateway.open_robot.OpenRobot.command`: Jacobians, task, rows that can bind,
both LPs), with the rows the LPs carried. Paper 1 (CPLEX, Xenomai PC): 245.7 µs mean, 308 µs p95, 370 µs max.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np

from bench._report import Report, Target, default_json_path, print_header, summary, table, targets_table
from bench.compute import human_capsules
from gateway import open_control
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


def run(samples: int, seed: int) -> dict[str, object]:
    config = load_cell_config(CONFIG)
    robot = load_robot_model("panda", config.robots["panda"])
    trajectory = load_trajectory(config.robots["panda"].program, robot)
    data = robot.model.createData()
    rng = np.random.default_rng(seed)
    times: dict[str, list[float]] = {"lp9": [], "lp9+lp13": [], "command": []}
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
        open_robot.qd_prev_radps = float(rng.uniform(0.3, 1.0)) * np.asarray(qd_nominal)
        open_robot.delta_prev, open_robot.last_mono_ns = 1.0, 0
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
        qd_prev = open_robot.qd_prev_radps[active]
        lower, upper = open_control.velocity_bounds(qd_prev, q[active], open_robot.limits, 0.004)
        qd_self = open_control.self_motion_reference(task, 1.0, np.zeros(active.size), np.zeros(active.size))

        t0 = time.perf_counter_ns()
        open_control.solve_lp9(safety, task, lower, upper)
        t1 = time.perf_counter_ns()
        solution = open_control.decide(
            safety,
            task,
            qd_prev,
            q[active],
            open_robot.limits,
            0.004,
            qd_self,
            open_control.fixed_cap(1.0),
            robot.link_names,
            1.0,
            0.0,
        )
        t2 = time.perf_counter_ns()
        open_robot.command(q, open_robot.qd_prev_radps, 0, links, rows, humans, None, None, open_control.fixed_cap(1.0))
        t3 = time.perf_counter_ns()
        times["lp9"].append((t1 - t0) / 1e3)
        times["lp9+lp13"].append((t2 - t1) / 1e3)
        times["command"].append((t3 - t2) / 1e3)
        rows_kept.append(safety.f_m2.size)
        deltas.append(solution.delta)
        hows[solution.how] = hows.get(solution.how, 0) + 1
    return {
        "time_us": {k: summary(v, 1.0, 1) for k, v in times.items()},
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
    parser.add_argument("--json", type=Path, default=default_json_path(NAME))
    args = parser.parse_args(argv)
    print_header("open controllers: LP (9) then (13) per cycle (Panda, 7 joints, 2 people × 15 capsules)")
    report = Report(NAME, {"samples": args.samples, "seed": args.seed, "config": CONFIG, "t_delay_s": T_DELAY_S})
    results = run(args.samples, args.seed)
    report.results = results
    times = results["time_us"]
    assert isinstance(times, dict)
    report.targets = [Target("LP (9) + LP (13) p99", times["lp9+lp13"]["p99"], TARGET_P99_US, "µs")]
    report.references = [{"name": "paper 1, Table I (CPLEX, LP (9))", "time_us": PAPER_US}]
    rows = [[k, v["p50"], v["p95"], v["p99"], v["max"], v["mean"]] for k, v in times.items()]
    rows.append(["paper 1 (CPLEX)", "-", PAPER_US["p95"], "-", PAPER_US["max"], PAPER_US["mean"]])
    print(table(["timed", "p50 [µs]", "p95", "p99", "max", "mean"], rows))
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
