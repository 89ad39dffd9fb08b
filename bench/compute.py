"""Compute per cycle: ``InputStore.snapshot`` + ``SafetyCore.step`` (kinematics, distances, rows, δ, zones).

The store is fed the way the gateway's Zenoh callbacks feed it (JSON payloads through ``on_joint_state``
and ``on_humans``, outside the timed region): every cycle a fresh joint state per robot that echoes the
previous override (override path confirmed), a tracker frame every 8 cycles (31 Hz), all data fresh.
The clock is simulated (4 ms per cycle) so that the decisions are those of a running gateway; only
the cost of the call is measured, with ``time.perf_counter_ns``.

Reference workload: the UR5 of ``configs/cell.toml`` and 2 humans × 15 capsules (one per tracker).
Then the growth with humans (1…10, one robot) and robots (1…8 copies of the UR5 at other base poses,
2 humans), and where the time goes (an instrumented pass that wraps the functions ``SafetyCore`` calls).

    python -m bench.compute [--cycles 10000] [--scale-cycles 2000] [--workload 8 4] [--json out/bench/compute.json]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

import gateway.methods
from bench._progress import Progress
from bench._report import Report, Target, default_json_path, print_header, summary, table, targets_table
from gateway import kernels
from gateway.core import RobotDecision, SafetyCore
from gateway.inputs import InputStore
from gateway.kernels import RobotKernels
from hrc_contract import keys
from hrc_contract.config import CellConfig, Pose
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config
from tracker_emu.body import BodyPose, body_capsules

NAME = "compute"
CYCLE_NS = 4_000_000
PERIOD_S = CYCLE_NS / 1e9
HUMAN_EVERY_CYCLES = 8
"""A tracker frame every 8 gateway cycles: 31 Hz at 250 Hz, like the cell's 30 Hz trackers."""
JOINT_AGE_NS = 1_000_000
HUMAN_AGE_NS = 30_000_000
OVERRIDE_PATH_NS = 8_000_000
CAPSULES_PER_HUMAN = 15
HUMAN_RING_MAX_M = 4.8
"""People walk at most this far (+0.9 m) from the robots' centre: inside the default cell's ±7 m volume with their
reach (beyond it every frame is rejected as ``outside_world`` and the cycle computes no rows)."""

Q0_RAD = np.array([0.3, -1.2, 1.4, -0.5, 1.2, 0.0])

TARGET_P50_US = 15.0
TARGET_P99_US = 40.0
TARGET_MAX_US = 150.0
"""Issue 36's targets for the reference workload (the earlier 40 / 100 µs were met at p50 only)."""
REFERENCES = [
    {
        "name": "Zanchettin et al. 2016 (paper 1), LP per cycle",
        "mean_us": 245.7,
        "p95_us": 308.0,
        "max_us": 370.0,
    },
    {"name": "a C++ reachability shield", "mean_us": 21.0, "max_us": 98.0},
]

COMPILED_CALL = "kinematics, distances and rows (one compiled call)"
BREAKDOWN_PARTS = {
    # label: (owner, attribute) of the function SafetyCore calls, wrapped with a timer in the instrumented pass
    COMPILED_CALL: (RobotKernels, "cycle"),
    "δ from rows": (gateway.methods, "override_from_rows"),
}
"""Kinematics, distances and rows are one compiled call per robot; the instrumented pass shows its parts by
timing the compiled kinematics and segment distances of the same inputs apart, outside the cycle."""


# -- the workload ----------------------------------------------------------------------------------


def human_capsules(pose: BodyPose) -> list[dict[str, Any]]:
    """15 capsules of one person: the tracker emulator's 13 plus neck and shoulder girdle [m]."""
    body = {c.name: c for c in body_capsules(pose)}
    capsules = [{"name": c.name, "a": c.a.tolist(), "b": c.b.tolist(), "radius": c.radius_m} for c in body.values()]
    capsules.append({"name": "neck", "a": body["torso"].b.tolist(), "b": body["head"].a.tolist(), "radius": 0.07})
    capsules.append(
        {"name": "shoulders", "a": body["upper_arm_l"].a.tolist(), "b": body["upper_arm_r"].a.tolist(), "radius": 0.08}
    )
    return capsules


def robot_copies(config: CellConfig, n_robots: int) -> CellConfig:
    """The cell with ``n_robots`` copies of its first robot on a 2 m grid centred on the origin (one robot stays
    at the origin), each turned by another yaw."""
    first = next(iter(config.robots.values()))
    robots = {}
    x0_m, y0_m = float(min(n_robots, 4) - 1), float((n_robots - 1) // 4)  # the grid's centre, 4 robots a row
    for k in range(n_robots):
        pose = Pose(xyz=(2.0 * (k % 4) - x0_m, 2.0 * (k // 4) - y0_m, 0.8), rpy=(0.0, 0.0, 0.7 * k))
        robots["ur5" if k == 0 else f"ur5_{k}"] = first.model_copy(update={"base_pose_world": pose})
    return config.model_copy(update={"robots": robots})


@dataclass(frozen=True)
class Workload:
    n_robots: int
    n_humans: int

    @property
    def label(self) -> str:
        return f"{self.n_robots} robot(s), {self.n_humans} human(s) × {CAPSULES_PER_HUMAN} capsules"


class Rig:
    """A SafetyCore and its InputStore, fed like the gateway's callbacks feed them."""

    def __init__(self, config: CellConfig, robots: dict[str, RobotModel], n_humans: int, start_ns: int) -> None:
        self.config = config
        self.robots = robots
        self.trackers = sorted(config.trackers)
        self.store = InputStore(config, robots)
        self.core = SafetyCore(config, robots)
        self.n_humans = n_humans
        self.start_ns = start_ns
        self.cycle = 0
        self.frame_cycles = np.zeros(0, dtype=bool)
        """Per timed cycle of the last :meth:`run`: whether it took new tracker frames (the tracks' update)."""
        self.joint_seq = 0
        self.human_seq = 0
        self.override_seq = 0
        bases = np.array([r.p_world_base for r in robots.values()])
        self.centre = bases.mean(axis=0)
        self.spread_m = float(np.linalg.norm(bases[:, :2] - self.centre[:2], axis=1).max())
        self.callback_ns: dict[str, list[int]] = defaultdict(list)
        self.zones: Counter[str] = Counter()
        self.faults: Counter[str] = Counter()
        self.deltas: list[float] = []

    @property
    def now_ns(self) -> int:
        return self.start_ns + self.cycle * CYCLE_NS

    def at(self, now_ns: int) -> Clocks:
        """``now_ns`` on both clocks (the monotonic one starts with the rig)."""
        return Clocks(now_ns, now_ns - self.start_ns)

    def _timed_callback(self, kind: str, call: Callable[[], None]) -> None:
        started = time.perf_counter_ns()
        call()
        self.callback_ns[kind].append(time.perf_counter_ns() - started)

    def _feed_joints(self, now_ns: int) -> None:
        t_s = self.cycle * PERIOD_S
        for k, name in enumerate(self.robots):
            phase = 0.25 * 2 * math.pi * t_s + k
            q = Q0_RAD + 0.4 * np.sin(phase + np.arange(6))
            # q's own rate, so that the state agrees with itself (the door's q_motion_inconsistent)
            qd = 0.4 * 0.25 * 2 * math.pi * np.cos(phase + np.arange(6)) / 0.8
            self.joint_seq += 1
            raw = {
                "schema": "hrc.joint_state/1",
                "robot": name,
                "seq": self.joint_seq,
                "stamp_ns": now_ns - JOINT_AGE_NS,
                "q": q.tolist(),
                "qd": (0.8 * qd).tolist(),
                "qd_nominal": qd.tolist(),
                "override": 0.8,  # qd = override · qd_nominal (sign included) or the state is inconsistent
                "override_seq": self.override_seq,
                "mode": "running",
            }
            payload = json.dumps(raw).encode()
            key = keys.robot_state(self.config.cell, name)
            self._timed_callback("on_joint_state", partial(self.store.on_joint_state, key, payload, self.at(now_ns)))

    def _feed_humans(self, now_ns: int) -> None:
        t_s = self.cycle * PERIOD_S
        per_tracker: dict[str, list[dict[str, Any]]] = {t: [] for t in self.trackers}
        for i in range(self.n_humans):
            angle = 2 * math.pi * i / max(1, self.n_humans) + 0.3
            # beyond the robots, but inside the cell's volume: a person outside it is rejected at the door
            radius = min(self.spread_m + 2.3, HUMAN_RING_MAX_M) + 0.4 * (i % 3) + 0.1 * math.sin(t_s + i)
            x, y = self.centre[0] + radius * math.cos(angle), self.centre[1] + radius * math.sin(angle)
            pose = BodyPose(x, y, heading_rad=angle + math.pi, reach=(i % 3) / 2)
            per_tracker[self.trackers[i % len(self.trackers)]].append(
                {"id": f"h{i + 1}", "capsules": human_capsules(pose)}
            )
        self.human_seq += 1
        for tracker, humans in per_tracker.items():
            raw = {
                "schema": "hrc.humans/1",
                "tracker": tracker,
                "seq": self.human_seq,
                "stamp_ns": now_ns - HUMAN_AGE_NS,
                "humans": humans,
            }
            payload = json.dumps(raw).encode()
            key = keys.tracker_humans(self.config.cell, tracker)
            self._timed_callback("on_humans", partial(self.store.on_humans, key, payload, self.at(now_ns)))

    def feed(self) -> int:
        """Deliver this cycle's messages; returns the cycle's time [ns since epoch]."""
        now_ns = self.now_ns
        self._feed_joints(now_ns)
        if self.cycle % HUMAN_EVERY_CYCLES == 0:
            self._feed_humans(now_ns)
        return now_ns

    def step(self, now_ns: int) -> tuple[int, dict[str, RobotDecision]]:
        """One timed cycle (snapshot + step), then the overrides 'sent' as the gateway records them."""
        started = time.perf_counter_ns()
        now = self.at(now_ns)
        decisions = self.core.step(self.store.snapshot(now), now, PERIOD_S)
        elapsed = time.perf_counter_ns() - started
        self.override_seq += 1
        for name in decisions:
            self.store.on_override_sent(name, self.override_seq, 1.0, self.at(now_ns - OVERRIDE_PATH_NS))
        for d in decisions.values():
            self.zones[str(d.zone)] += 1
            self.faults.update(f.code for f in d.faults)
            self.deltas.append(d.delta)
        self.cycle += 1
        return elapsed, decisions

    def run(self, cycles: int, warmup: int) -> np.ndarray:
        """Per-cycle compute times [ns] of ``cycles`` cycles after ``warmup`` untimed ones."""
        for _ in range(warmup):
            self.step(self.feed())
        self.zones.clear()
        self.faults.clear()
        self.deltas.clear()
        self.callback_ns.clear()
        times = np.empty(cycles, dtype=np.int64)
        self.frame_cycles = np.zeros(cycles, dtype=bool)
        for k in range(cycles):
            self.frame_cycles[k] = self.cycle % HUMAN_EVERY_CYCLES == 0  # this cycle takes new tracker frames
            times[k], _ = self.step(self.feed())
        return times

    def sanity(self) -> dict[str, Any]:
        """What the decisions were: zones, faults (none expected: data fresh, path confirmed), δ."""
        return {
            "zones": dict(self.zones),
            "faults": dict(self.faults),
            "delta_mean": round(float(np.mean(self.deltas)), 3) if self.deltas else None,
            "capsules_per_cycle": self.n_humans * CAPSULES_PER_HUMAN,
        }


def build_rig(base: CellConfig, workload: Workload) -> Rig:
    config = robot_copies(base, workload.n_robots)
    robots = {name: load_robot_model(name, rc) for name, rc in config.robots.items()}
    return Rig(config, robots, workload.n_humans, time.time_ns())


# -- instrumented pass ------------------------------------------------------------------------------


@contextmanager
def timed_functions(parts: dict[str, tuple[Any, str]], spent_ns: dict[str, int]) -> Iterator[list[str]]:
    """Wrap ``module.attribute`` of each part with a timer adding to ``spent_ns[label]``; restored on exit.

    Yields the labels that could be wrapped (a function that no longer exists is left out).
    """
    originals: list[tuple[Any, str, Any]] = []
    wrapped = []
    try:
        for label, (module, attribute) in parts.items():
            function = getattr(module, attribute, None)
            if function is None:
                continue

            def timer(*args: Any, _f: Any = function, _label: str = label, **kwargs: Any) -> Any:
                started = time.perf_counter_ns()
                try:
                    return _f(*args, **kwargs)
                finally:
                    spent_ns[_label] += time.perf_counter_ns() - started

            originals.append((module, attribute, function))
            setattr(module, attribute, timer)
            wrapped.append(label)
        yield wrapped
    finally:
        for module, attribute, function in reversed(originals):
            setattr(module, attribute, function)


def _parts_apart_ns(calls: list[tuple[Any, ...]]) -> tuple[int, int]:
    """Time of the compiled kinematics and segment distances of the inputs of the ``RobotKernels.cycle`` calls
    ``calls`` (robot kernels, q, q̇, capsules, t_delay), each a call of its own."""
    kinematics_ns = distances_ns = 0
    for robot_kernels, q, qd, capsules, _ in calls:
        started = time.perf_counter_ns()
        links, _ = kernels.link_kinematics(robot_kernels.chain, q, qd)
        kinematics_ns += time.perf_counter_ns() - started
        h_a, h_b = np.ascontiguousarray(capsules[0:3].T), np.ascontiguousarray(capsules[3:6].T)
        started = time.perf_counter_ns()
        kernels.segment_distances(links.p_a_world, links.p_b_world, h_a, h_b)
        distances_ns += time.perf_counter_ns() - started
    return kinematics_ns, distances_ns


def breakdown(rig: Rig, cycles: int) -> dict[str, Any]:
    """Where the time of a cycle goes: snapshot, the wrapped functions, and the rest of ``step``."""
    spent: dict[str, int] = defaultdict(int)
    per_cycle: dict[str, list[int]] = defaultdict(list)
    cycle_calls: list[tuple[Any, ...]] = []
    point = np.zeros((1, 3))
    kernels.segment_distances(point, point, point, point)  # compiled (or loaded from the cache) before the pass
    with timed_functions(BREAKDOWN_PARTS, spent) as wrapped:
        timed_cycle = RobotKernels.cycle

        def recording_cycle(self: RobotKernels, *args: Any) -> Any:
            cycle_calls.append((self, *args))  # outside the timer: in "rest of step"
            return timed_cycle(self, *args)

        RobotKernels.cycle = recording_cycle  # type: ignore[method-assign,assignment]
        try:
            for _ in range(cycles):
                now_ns = rig.feed()
                spent.clear()
                cycle_calls.clear()
                started = time.perf_counter_ns()
                now = rig.at(now_ns)
                snapshot = rig.store.snapshot(now)
                taken = time.perf_counter_ns()
                decisions = rig.core.step(snapshot, now, PERIOD_S)
                done = time.perf_counter_ns()
                rig.override_seq += 1
                for name in decisions:
                    rig.store.on_override_sent(name, rig.override_seq, 1.0, rig.at(now_ns - OVERRIDE_PATH_NS))
                rig.cycle += 1
                per_cycle["snapshot"].append(taken - started)
                per_cycle["step"].append(done - taken)
                for label in wrapped:
                    per_cycle[label].append(spent[label])
                kinematics_ns, distances_ns = _parts_apart_ns(cycle_calls)
                per_cycle["kinematics"].append(kinematics_ns)
                per_cycle["distances"].append(distances_ns)
        finally:
            RobotKernels.cycle = timed_cycle  # type: ignore[method-assign]
    parts: dict[str, np.ndarray] = {k: np.asarray(v, dtype=float) for k, v in per_cycle.items()}
    total = parts["snapshot"] + parts["step"]
    rest = parts["step"].copy()
    for label in (COMPILED_CALL, "δ from rows"):
        if label in parts:
            rest -= parts[label]
    if COMPILED_CALL in parts:
        parts["rows without distances"] = parts[COMPILED_CALL] - parts["kinematics"] - parts["distances"]
    parts["rest of step (faults, delay, merge, zones, decision)"] = rest
    parts["total (snapshot + step)"] = total
    order = [
        "snapshot",
        COMPILED_CALL,
        "kinematics",
        "distances",
        "rows without distances",
        "δ from rows",
        "rest of step (faults, delay, merge, zones, decision)",
        "total (snapshot + step)",
    ]
    mean_total = float(total.mean())
    return {
        label: {
            **summary(parts[label], 1e-3),
            "share_of_mean": round(float(parts[label].mean()) / mean_total, 3),
        }
        for label in order
        if label in parts
    }


# -- the benchmark --------------------------------------------------------------------------------


def _scale(
    base: CellConfig, workloads: list[Workload], cycles: int, warmup: int, progress: Progress | None = None
) -> list[dict[str, Any]]:
    points = []
    for workload in workloads:
        if progress is not None:
            progress.update(progress.done, f"scaling: {workload.label}")
        rig = build_rig(base, workload)
        times = rig.run(cycles, warmup)
        if progress is not None:
            progress.advance(cycles + warmup)
        points.append(
            {
                "robots": workload.n_robots,
                "humans": workload.n_humans,
                "capsules": workload.n_humans * CAPSULES_PER_HUMAN,
                "compute_us": summary(times, 1e-3),
                "sanity": rig.sanity(),
            }
        )
    return points


def _slope_us(points: list[dict[str, Any]], key: str) -> float | None:
    if len(points) < 2:
        return None
    x = [p[key] for p in points]
    y = [p["compute_us"]["p50"] for p in points]
    return round(float(np.polyfit(x, y, 1)[0]), 1)


def run(
    cycles: int,
    scale_cycles: int,
    warmup: int,
    max_humans: int,
    max_robots: int,
    breakdown_cycles: int,
    config_path: Path | None,
    workloads: list[tuple[int, int]] | None = None,
) -> Report:
    """Measure and return the report (not yet written); ``workloads`` (robots, humans) are measured as the
    reference workload is (``cycles`` cycles each), e.g. (8, 4)."""
    base = load_cell_config(config_path)
    report = Report(
        NAME,
        {
            "cycles": cycles,
            "scale_cycles": scale_cycles,
            "warmup_cycles": warmup,
            "breakdown_cycles": breakdown_cycles,
            "config": str(config_path) if config_path else "configs/cell.toml",
            "reference_workload": Workload(1, 2).label,
            "simulated_cycle_s": PERIOD_S,
            "human_frame_every_cycles": HUMAN_EVERY_CYCLES,
            "clock": "time.perf_counter_ns around InputStore.snapshot() + SafetyCore.step(); gc enabled",
        },
    )
    report.references = REFERENCES

    # Progress in cycles, updated between the timed passes only (never inside one).
    total_cycles = cycles + breakdown_cycles + (max_humans + max_robots + 1) * warmup
    with Progress(NAME, total_cycles + (max_humans + max_robots) * scale_cycles, "cycles") as progress:
        progress.update(0, "reference workload")
        rig = build_rig(base, Workload(1, 2))
        times = rig.run(cycles, warmup)
        progress.update(cycles + warmup, "breakdown")
        reference = summary(times, 1e-3)
        callbacks = {kind: summary(v, 1e-3) for kind, v in rig.callback_ns.items()}
        report.results["reference"] = {
            "workload": Workload(1, 2).label,
            "compute_us": reference,
            "compute_us_by_frame": {
                "with_new_tracker_frames": summary(times[rig.frame_cycles], 1e-3),
                "without": summary(times[~rig.frame_cycles], 1e-3),
            },
            "sanity": rig.sanity(),
            "callbacks_us_not_in_cycle": callbacks,
        }
        report.results["breakdown_us"] = breakdown(rig, breakdown_cycles)
        progress.advance(breakdown_cycles)
        humans = _scale(base, [Workload(1, h) for h in range(1, max_humans + 1)], scale_cycles, warmup, progress)
        robots = _scale(base, [Workload(r, 2) for r in range(1, max_robots + 1)], scale_cycles, warmup, progress)
    report.results["scaling_humans"] = {"points": humans, "p50_us_per_human": _slope_us(humans, "humans")}
    report.results["scaling_robots"] = {"points": robots, "p50_us_per_robot": _slope_us(robots, "robots")}
    report.results["workloads"] = _scale(base, [Workload(r, h) for r, h in workloads or []], cycles, warmup)
    report.targets = [
        Target("compute p50 (reference workload)", reference["p50"], TARGET_P50_US, "µs"),
        Target("compute p99 (reference workload)", reference["p99"], TARGET_P99_US, "µs"),
        Target("compute max (reference workload)", reference["max"], TARGET_MAX_US, "µs"),
    ]
    report.notes = [
        "Figures on a shared 2-core machine are indicative: see load_average.",
        "The breakdown comes from a separate, instrumented pass (each wrapped call adds ~0.2 µs of timer); "
        "its parts are per-cycle sums over robots. Kinematics, distances and rows are one compiled call per robot: "
        "its 'kinematics' and 'distances' are the compiled kinematics and segment distances of the same inputs, "
        "each timed as a call of its own outside the cycle (with its own call overhead, and warm caches), so the "
        "split is approximate; 'rows without distances' is the rest of the call.",
        "Callbacks (JSON parsing and validation of incoming messages) run on Zenoh threads, not in the cycle, "
        "but take CPU time from the same 2 cores.",
    ]
    return report


def _part_label(part: str) -> str:
    """Parts of the compiled call are shown under it (their times are measured apart: see the notes)."""
    if part in ("kinematics", "distances"):
        return f"  {part} (timed apart)"
    if part == "rows without distances":
        return f"  {part}"
    return part


def _points_table(points: list[dict[str, Any]]) -> str:
    """Workload points (:func:`_scale`) as a table: size, p50, p99, max [µs] and the faults (none expected)."""
    return table(
        ["robots", "humans", "capsules", "p50", "p99", "max", "faults"],
        [
            [
                p["robots"],
                p["humans"],
                p["capsules"],
                p["compute_us"]["p50"],
                p["compute_us"]["p99"],
                p["compute_us"]["max"],
                sum(p["sanity"]["faults"].values()),
            ]
            for p in points
        ],
    )


def print_report(doc: dict[str, Any]) -> None:
    results = doc["results"]
    ref = results["reference"]
    c = ref["compute_us"]
    print(f"\nreference workload: {ref['workload']}; {c['n']} cycles; zones {ref['sanity']['zones']}")
    print(f"faults: {ref['sanity']['faults'] or 'none'}; mean δ {ref['sanity']['delta_mean']}")
    rows: list[list[object]] = [
        ["hrc-gateway (Python, numba kernels)", c["mean"], c["p50"], c["p95"], c["p99"], c["max"]]
    ]
    rows += [[r["name"], r.get("mean_us"), None, r.get("p95_us"), None, r.get("max_us")] for r in doc["references"]]
    print(table(["compute per cycle [µs]", "mean", "p50", "p95", "p99", "max"], rows))
    by_frame = ref.get("compute_us_by_frame")
    if by_frame:
        print(f"\nthe same cycles, split (tracker frames arrive every {HUMAN_EVERY_CYCLES} cycles) [µs]")
        print(
            table(
                ["cycles", "n", "mean", "p50", "p95", "p99", "max"],
                [
                    [
                        name.replace("_", " "),
                        v["n"],
                        v.get("mean"),
                        v.get("p50"),
                        v.get("p95"),
                        v.get("p99"),
                        v.get("max"),
                    ]
                    for name, v in by_frame.items()
                ],
            )
        )
    print("\n" + targets_table([Target.from_dict(t) for t in doc["targets"]]))
    print("\nwhere the time goes (instrumented pass) [µs]")
    print(
        table(
            ["part", "mean", "p50", "p99", "share of mean"],
            [
                [_part_label(k), v["mean"], v["p50"], v["p99"], f"{100 * v['share_of_mean']:.0f} %"]
                for k, v in results["breakdown_us"].items()
            ],
        )
    )
    cb = ref["callbacks_us_not_in_cycle"]
    print("callbacks, per message, not in the cycle [µs]: " + ", ".join(f"{k} p50 {v['p50']}" for k, v in cb.items()))
    for key, unit in (("scaling_humans", "human"), ("scaling_robots", "robot")):
        scaling = results[key]
        print(f"\ngrowth with {unit}s [µs]  (p50 slope: {scaling[f'p50_us_per_{unit}']} µs per {unit})")
        print(_points_table(scaling["points"]))
    if results.get("workloads"):
        print(f"\nother workloads (--workload), {doc['parameters']['cycles']} cycles each [µs]")
        print(_points_table(results["workloads"]))
    load = doc["load_average"]
    print(f"\nload average start {load['start']} end {load['end']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.compute", description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=10_000, help="timed cycles of the reference workload")
    parser.add_argument("--scale-cycles", type=int, default=2_000, help="timed cycles per scaling point")
    parser.add_argument("--breakdown-cycles", type=int, default=3_000, help="cycles of the instrumented pass")
    parser.add_argument("--warmup", type=int, default=200, help="untimed cycles before each measurement")
    parser.add_argument("--max-humans", type=int, default=10)
    parser.add_argument("--max-robots", type=int, default=8)
    parser.add_argument(
        "--workload",
        type=int,
        nargs=2,
        action="append",
        metavar=("ROBOTS", "HUMANS"),
        help="also measure this many robots and humans as the reference workload is (repeatable), e.g. 8 4",
    )
    parser.add_argument("--config", type=Path, default=None, help="cell configuration (default configs/cell.toml)")
    parser.add_argument("--json", type=Path, default=default_json_path(NAME), help="where to write the results")
    args = parser.parse_args(argv)
    print_header("compute per cycle: InputStore.snapshot + SafetyCore.step")
    report = run(
        args.cycles,
        args.scale_cycles,
        args.warmup,
        args.max_humans,
        args.max_robots,
        args.breakdown_cycles,
        args.config,
        [(robots, humans) for robots, humans in args.workload or []],
    )
    doc = report.finish(args.json)
    print_report(doc)
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
