"""Reaction through each controller interface in one run: the emulator's Zenoh face, UR RTDE and ABB RWS bridges.

The method of :mod:`bench.reaction` (this process is the tracker: samples alternating between a person far away,
δ = 1, and one enclosing the robot, δ = 0; each matched to the first override that reflects it), run once per
interface of the same cell (``configs/cell.toml``, ``cell_ur_rtde.toml``, ``cell_abb_rws.toml``, on addresses of
their own). Per sample:

- **decision**: override ``stamp_ns`` − sample stamp (the gateway's cycle start);
- **applied by the emulator**: the first cycle of the emulator's *ground truth* (``hrc/<cell>/truth/robot/<r>/state``)
  at or after that override whose applied δ moves toward the sample's value (down for the near person, up for the far
  one) − sample stamp. Through a bridge the emulator's ``override_seq`` numbers the vendor writes, not the gateway's
  overrides, so the echo cannot be used; the direction of the ramp can (a sample whose δ the ramp already sits at,
  δ = 0 for a near one, cannot be told and is counted ``at_bound``). For the Zenoh face the echo method of
  :mod:`bench.reaction` is reported too, as a check of this one;
- **read-back latency**: the bridge's own (write → first read-back showing the value, from ``bridge_stats``) and the
  override path the gateway measured from the echoes (``delay_budget_s.override_path_s`` of each status).

    python -m bench.bridge_reaction [--samples 1000] [--rate 250] [--interfaces zenoh,ur_rtde,abb_rws]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import threading
import time
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import zenoh

from bench._report import Report, default_json_path, print_header, summary
from bench.reaction import (
    FORGET_LOST,
    PING_KEY,
    Reaction,
    Recorder,
    RunSettings,
    Sample,
    Sender,
    bench_config,
    latency_table,
    match_reactions,
    open_bench_session,
    recorder_subscribers,
    warm_up,
)
from hrc_contract import keys
from hrc_contract.config import AbbRwsInterfaceConfig, CellConfig, UrRtdeInterfaceConfig
from hrc_devices.controllers.abb_rws import EMULATOR_RWS_PASSWORD
from hrc_runtime.config import load_cell_config
from hrc_tools.cell.launcher import vendor_face_args
from hrc_tools.cell.procs import (
    free_port,
    programs,
    unsafe_test_settings,
    wait_for,
    with_retries,
    write_cell_config,
)

NAME = "bridge_reaction"
REPO_ROOT = Path(__file__).resolve().parents[1]
CELL_FILES = {"zenoh": "cell.toml", "ur_rtde": "cell_ur_rtde.toml", "abb_rws": "cell_abb_rws.toml"}


class TruthSeen(NamedTuple):
    stamp_ns: int
    override: float


class Extra:
    """What this benchmark records beside :class:`bench.reaction.Recorder`: ground truth, bridge stats, path delay."""

    def __init__(self, robot: str) -> None:
        self.robot = robot
        self.truth: list[TruthSeen] = []
        self.readback_latency_s: list[float] = []
        self.override_path_s: list[float] = []
        self._lock = threading.Lock()

    def on_truth(self, sample: zenoh.Sample) -> None:
        msg = json.loads(sample.payload.to_bytes())
        with self._lock:
            self.truth.append(TruthSeen(int(msg["stamp_ns"]), float(msg["override"])))

    def on_bridge_stats(self, sample: zenoh.Sample) -> None:
        doc = json.loads(sample.payload.to_bytes())
        for key in ("readback_latency_s", "readback_latency_max_s"):
            if isinstance(doc.get(key), int | float):
                with self._lock:
                    self.readback_latency_s.append(float(doc[key]))

    def on_status(self, sample: zenoh.Sample) -> None:
        doc = json.loads(sample.payload.to_bytes())
        robot = doc.get("robots", {}).get(self.robot, {})
        path = robot.get("delay_budget_s", {}).get("override_path_s")
        if isinstance(path, int | float) and not robot.get("faults"):
            with self._lock:
                self.override_path_s.append(float(path))


def applied_by_direction(
    samples: list[Sample], reactions: list[Reaction], truth: list[TruthSeen]
) -> tuple[list[int], int]:
    """For each reaction, the first true cycle at or after its override whose applied δ moves toward the sample's
    value, minus the sample's stamp [ns]; and how many could not be told (the ramp already at that bound)."""
    truth = sorted(truth)
    stamps = np.array([t.stamp_ns for t in truth], dtype=np.int64)
    delta = np.array([t.override for t in truth], dtype=float)
    step = np.diff(delta, prepend=delta[:1])
    out: list[int] = []
    at_bound = 0
    for r in reactions:
        sample = samples[r.sample]
        start = int(np.searchsorted(stamps, sample.stamp_ns + r.decision_ns, side="left"))
        if start >= len(stamps):
            continue
        if sample.near and delta[max(start - 1, 0)] <= 0.0:
            at_bound += 1
            continue
        if not sample.near and delta[max(start - 1, 0)] >= 1.0:
            at_bound += 1
            continue
        moving = np.flatnonzero(step[start:] < 0.0) if sample.near else np.flatnonzero(step[start:] > 0.0)
        if moving.size:
            out.append(int(stamps[start + moving[0]]) - sample.stamp_ns)
    return out, at_bound


def interface_config(kind: str, base: CellConfig) -> CellConfig:
    """The cell file of ``kind`` on addresses of its own (a free RWS port; a loopback address of its own for RTDE)."""
    robot = next(iter(base.robots))
    interface = base.robots[robot].interface
    if isinstance(interface, AbbRwsInterfaceConfig):
        interface = interface.model_copy(update={"url": f"http://127.0.0.1:{free_port()}"})
    elif isinstance(interface, UrRtdeInterfaceConfig):
        host = f"127.{random.randint(1, 254)}.{random.randint(0, 255)}.{random.randint(2, 254)}"
        interface = interface.model_copy(update={"host": host})
    robots = {robot: base.robots[robot].model_copy(update={"interface": interface})}
    return base.model_copy(update={"robots": robots})


def run_interface(
    kind: str, settings: RunSettings, work_dir: Path, on_progress: Callable[[int], None] | None = None
) -> dict[str, Any]:
    """One run of the cell through interface ``kind``; the figures [ms]."""
    base = interface_config(kind, load_cell_config(REPO_ROOT / "configs" / CELL_FILES[kind]))
    robot = next(iter(base.robots))
    gw_port, bench_port, http_port = free_port(), free_port(), free_port()
    config = bench_config(base, settings.rate_hz, http_port, settings.event_driven)
    gw_ep, bench_ep = f"tcp/127.0.0.1:{gw_port}", f"tcp/127.0.0.1:{bench_port}"
    with unsafe_test_settings(FORGET_LOST):
        config_path = write_cell_config(config, work_dir / f"cell-{NAME}-{kind}.toml")
        logs = {n: work_dir / "logs" / f"{NAME}-{kind}-{n}.log" for n in ("gateway", "controller", "bridge", "peer")}
        peer_out = work_dir / f"{NAME}-{kind}-oneway.json"
        peer_out.unlink(missing_ok=True)
        cfg = ["--config", str(config_path)]
        face = vendor_face_args(config.robots[robot])
        specs: list[tuple[str, list[str], Path]] = [
            ("gateway", [*cfg, "--zenoh-listen", gw_ep], logs["gateway"]),
            (
                "controller_emu",
                [*cfg, "--robot", robot, "--zenoh-connect", gw_ep, "--zenoh-connect", bench_ep, *face],
                logs["controller"],
            ),
        ]
        if face:
            bridge_args = [*cfg, "--robot", robot, "--zenoh-connect", gw_ep, "--zenoh-connect", bench_ep]
            specs.append(("controller_bridge", bridge_args, logs["bridge"]))
        specs.append(
            ("bench._oneway_peer", ["--connect", bench_ep, "--key", PING_KEY, "--out", str(peer_out)], logs["peer"])
        )
        recorder = Recorder(robot, [], [], [])
        extra = Extra(robot)
        with programs(specs) as procs, open_bench_session(bench_ep, gw_ep) as session:
            cell = config.cell
            subscribers = [
                *recorder_subscribers(session, cell, robot, recorder),
                session.declare_subscriber(keys.gateway_status(cell), extra.on_status),
                session.declare_subscriber(keys.truth_robot_state(cell, robot), extra.on_truth),
                session.declare_subscriber(keys.robot_bridge_stats(cell, robot), extra.on_bridge_stats),
            ]
            sender = Sender.declared(session, cell, settings)
            warm_up(sender, recorder, procs, specs, logs["gateway"], settings)
            first = len(sender.samples)
            marks = (len(extra.override_path_s), len(recorder.statuses))
            on_sent = None if on_progress is None else (lambda sent: on_progress(sent - first))
            sender.send_until(first + settings.samples, None, on_sent=on_sent)
            end = len(sender.samples)
            sender.send_until(None, time.monotonic() + 0.5)
            del subscribers
        wait_for(peer_out.exists, 10.0, "the one-way peer's results", [])
    return analyse(kind, sender.samples, (first, end), recorder, extra, marks, echo=not face)


def analyse(
    kind: str,
    samples: list[Sample],
    window: tuple[int, int],
    recorder: Recorder,
    extra: Extra,
    marks: tuple[int, int],
    echo: bool,
) -> dict[str, Any]:
    """The figures of one interface's run [ms]; ``marks``: the path delays and statuses recorded before measuring."""
    first, end = window
    reactions, _ = match_reactions(samples, recorder.overrides, recorder.states if echo else [])
    measured = [r for r in reactions if first <= r.sample < end]
    applied, at_bound = applied_by_direction(samples, measured, extra.truth)
    echoed = [r.applied_ns for r in measured if r.applied_ns is not None]
    paths_before, statuses_before = marks
    return {
        "interface": kind,
        "samples_sent": end - first,
        "samples_matched": len(measured),
        "decision_ms": summary([r.decision_ns for r in measured], 1e-6, 3),
        "applied_by_emulator_ms": summary(applied, 1e-6, 3),
        "applied_at_bound_not_told": at_bound,
        "applied_by_echo_ms": summary(echoed, 1e-6, 3),
        "bridge_readback_latency_ms": summary(extra.readback_latency_s, 1e3, 3),
        "gateway_override_path_ms": summary(extra.override_path_s[paths_before:], 1e3, 3),
        "faults_in_status": sorted({c for s in recorder.statuses[statuses_before:] for c in s.faults}),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.bridge_reaction", description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=1000, help="measured tracker samples per interface")
    parser.add_argument("--rate", type=float, default=250.0, help="gateway rate [Hz]")
    parser.add_argument("--interval-ms", type=float, default=20.0, help="mean tracker interval [ms]")
    parser.add_argument("--interfaces", default="zenoh,ur_rtde,abb_rws")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--json", type=Path, default=default_json_path(NAME))
    args = parser.parse_args(argv)
    os.environ.setdefault("HRC_RWS_PASSWORD", EMULATOR_RWS_PASSWORD)  # the bridges inherit it (the emulator's)
    kinds = [k.strip() for k in args.interfaces.split(",") if k.strip()]
    print_header("reaction through each controller interface: tracker sample → override applied by the emulator")
    report = Report(
        NAME, {"interfaces": kinds, "samples": args.samples, "rate_hz": args.rate, "interval_ms": args.interval_ms}
    )
    settings = RunSettings(
        rate_hz=args.rate,
        samples=args.samples,
        interval_s=args.interval_ms * 1e-3,
        jitter=0.2,
        warmup_timeout_s=30.0,
        settle_s=1.0,
        seed=args.seed,
    )
    work_dir = args.json.parent
    runs = [with_retries(partial(run_interface, kind, settings, work_dir), kind) for kind in kinds]
    report.results["runs"] = runs
    report.notes = [
        "applied_by_emulator: the emulator's true applied δ starts moving toward the sample's value (ground truth); "
        "applied_by_echo (Zenoh face only): the first joint state echoing the override (bench.reaction's method).",
        "bridge_readback_latency: the bridge's write → first read-back showing the new value (its stats, each second); "
        "gateway_override_path: delay_budget_s.override_path_s of the fault-free statuses.",
        "Figures on a shared 2-core machine are indicative: see load_average.",
    ]
    doc = report.finish(args.json)
    figures = (
        ("→ decision", "decision_ms"),
        ("→ applied by the emulator", "applied_by_emulator_ms"),
        ("→ applied (echo)", "applied_by_echo_ms"),
        ("bridge read-back latency", "bridge_readback_latency_ms"),
        ("gateway override path", "gateway_override_path_ms"),
    )
    print("\n" + latency_table(runs, lambda r: str(r["interface"]), figures))
    for r in runs:
        print(
            f"{r['interface']}: matched {r['samples_matched']}/{r['samples_sent']}, not told (at bound) "
            f"{r['applied_at_bound_not_told']}, faults {r['faults_in_status'] or 'none'}"
        )
    print(f"\nload average start {doc['load_average']['start']} end {doc['load_average']['end']}")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
