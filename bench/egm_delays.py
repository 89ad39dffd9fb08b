"""The delay sweep through ABB EGM: the open Panda's real cell with one slow link at a time, audited.

    .venv/bin/python -m bench.egm_delays [--delays-s 0.02 0.06 0.1 0.3] [--links tracker robot] [--json PATH]

Each row is one run of ``configs/cell_open_panda_egm.toml`` as ``hrc-cell`` runs it (gateway, ``hrc-controller-emu
--egm``, ``hrc-controller-bridge`` as EGM's PC, tracker, default scenario ``walk_in_reach_leave``), with
``hrc-fault-relay`` delaying one link by the row's delay in each direction:

- ``tracker``: the tracker's frames to the gateway;
- ``robot``: the bridge's link to the gateway (joint states in, joint commands out: the delay counts twice in a
  round trip).

``hrc-audit`` reads the truth straight from the emulator and the tracker (never through the relay) and judges every
controller cycle (docs/safety-math.md §9; an open robot by its speed fraction). A run lasts until the person has come
and gone (or ``--run-s``). Per row: violations, smallest margin while moving, smallest true distance, the parts of
t_delay the gateway measured, the zones seen, the faults shown (late data is the expected fault beyond
``max_data_age_s`` = 0.2 s: then the robot must be stopped), the largest δ while a fault was shown, and the reference
restarts (the robot did not follow). Exit 1 on a violation. Figures: docs/benchmarks.md ("Open controllers").
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

from bench._progress import Progress
from bench._report import Report, default_json_path, print_header, table
from hrc_contract.config import AbbEgmInterfaceConfig
from hrc_runtime.config import load_cell_config
from hrc_tools.cell.procs import (
    collapse,
    free_endpoint,
    free_udp_port,
    load_scale,
    record,
    running_cell,
    start_program,
    stop_program,
    wait_or_fail,
    write_cell_config,
)

NAME = "egm_delays"
CONFIG = "configs/cell_open_panda_egm.toml"
ROBOT = "panda"
LINKS = ("tracker", "robot")
DELAYS_S = (0.02, 0.06, 0.1, 0.3)
READY_S = 60.0
RUN_S = 45.0
RULES = {"tracker": "hrc/*/tracker/**:delay={}", "robot": "hrc/*/robot/**:delay={}"}


def _cell_file(folder: Path, udp_port: int) -> Path:
    config = load_cell_config(CONFIG)
    robot = config.robots[ROBOT]
    assert isinstance(robot.interface, AbbEgmInterfaceConfig)
    robots = {ROBOT: robot.model_copy(update={"interface": robot.interface.model_copy(update={"port": udp_port})})}
    return write_cell_config(config.model_copy(update={"robots": robots}), folder / "cell.toml")


def _came_and_went(trace: list[dict[str, Any]]) -> bool:
    near = [s["t_s"] for s in trace if s["min_distance_m"] is not None and s["min_distance_m"] < 1.0]
    return bool(near) and trace[-1]["min_distance_m"] is None and trace[-1]["t_s"] - near[-1] > 2.0


def run_one(link: str, delay_s: float, udp_port: int, run_s: float) -> dict[str, Any]:
    """One audited run of the EGM cell with ``link`` delayed by ``delay_s`` each way."""
    with tempfile.TemporaryDirectory(prefix="egm-delays-") as tmp:
        folder = Path(tmp)
        config = _cell_file(folder, udp_port)
        relay = ["--forward", "hrc/**", "--rule", RULES[link].format(delay_s)]
        tracker_ep = free_endpoint()
        audit_log, audit_json = folder / "audit.log", folder / "audit.json"
        with running_cell(
            folder,
            config=config,
            controller_relay=relay if link == "robot" else None,
            tracker_relay=relay if link == "tracker" else None,
            trackers=[["--zenoh-listen", tracker_ep]],
        ) as cell:
            cell.wait(lambda: cell.robot(ROBOT) is not None, READY_S * load_scale(), "the gateway's API")
            endpoints = (cell.gateway_endpoint, cell.controller_endpoint, tracker_ep)
            audit = start_program(
                "hrc_tools.audit",
                [
                    *("--config", str(config)),
                    *(a for ep in endpoints for a in ("--zenoh-connect", ep)),
                    *("--json", str(audit_json)),
                ],
                audit_log,
            )
            try:
                wait_or_fail(
                    lambda: "auditing cell" in audit_log.read_text(errors="replace"),
                    30.0 * load_scale(),
                    "'auditing cell' in the auditor's log",
                    [audit_log],
                    [audit],
                )
                trace = record(cell, run_s * load_scale(), ROBOT, until=_came_and_went)
            finally:
                stop_program(audit)
        report = json.loads(audit_json.read_text())["robots"][ROBOT] if audit_json.exists() else None
    if report is None:
        raise RuntimeError(f"the auditor wrote no report for {link} {delay_s} s")
    faults = Counter(f["code"] for s in trace for f in s["faults"])
    fresh = [s for s in trace if not s["faults"]]

    def median_part(part: str) -> float | None:
        values = sorted(s["delay_budget_s"][part] for s in fresh)
        return round(values[len(values) // 2], 3) if values else None

    restarts = [s["open_command"]["reference_restarts"] for s in trace if s.get("open_command")]
    return {
        "link": link,
        "delay_s": delay_s,
        "violations": int(report["violations"]),
        "contacts_while_moving": int(report["contacts_while_moving"]),
        "margin_moving_m": report.get("smallest_margin_moving_m"),
        "min_distance_m": report["min_distance_m"],
        "t_delay_s_p50": round(sorted(s["t_delay_s"] for s in fresh)[len(fresh) // 2], 3) if fresh else None,
        "override_path_s_p50": median_part("override_path_s"),
        "joint_state_age_s_p50": median_part("joint_state_age_s"),
        "human_age_s_p50": median_part("human_age_s"),
        "zones": collapse([s["zone"] for s in trace]),
        "faults": dict(faults),
        "max_delta_with_fault": max((s["delta"] for s in trace if s["faults"]), default=None),
        "delta_above_bound": sum(1 for s in trace if s["delta"] > s["delta_bound"] + 1e-9),
        "reference_restarts": (restarts[-1] - restarts[0]) if restarts else None,
        "statuses": len(trace),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.egm_delays", description=__doc__.splitlines()[0])
    parser.add_argument("--delays-s", type=float, nargs="+", default=list(DELAYS_S), metavar="S")
    parser.add_argument("--links", nargs="+", choices=LINKS, default=list(LINKS))
    parser.add_argument("--run-s", type=float, default=RUN_S, help=f"longest run per row (default {RUN_S} s)")
    parser.add_argument("--json", type=Path, default=default_json_path(NAME))
    args = parser.parse_args(argv)
    if any(not (0.0 <= d <= 5.0) for d in args.delays_s):
        parser.error(f"--delays-s {args.delays_s}; allowed: 0–5 s each")
    print_header(f"the delay sweep through EGM ({CONFIG}): one slow link at a time, audited")
    report = Report(NAME, {"config": CONFIG, "delays_s": args.delays_s, "links": args.links, "run_s": args.run_s})
    rows: list[dict[str, Any]] = []
    plan = [(link, d) for link in args.links for d in args.delays_s]
    with Progress(NAME, total=len(plan), unit="runs") as progress:
        for k, (link, delay_s) in enumerate(plan):
            started = time.monotonic()
            rows.append(run_one(link, delay_s, free_udp_port(), args.run_s))
            progress.message(
                f"{link} {delay_s:g} s: {rows[-1]['violations']} violations ({time.monotonic() - started:.0f} s)"
            )
            progress.update(k + 1)
    headers = [
        "link",
        "delay [s]",
        "violations",
        "margin moving [m]",
        "min distance [m]",
        "t_delay p50 [s]",
        "override path p50",
        "state age p50",
        "human age p50",
        "faults",
        "max δ with fault",
        "δ > bound",
        "restarts",
    ]
    print(
        table(
            headers,
            [
                [
                    r["link"],
                    r["delay_s"],
                    r["violations"],
                    r["margin_moving_m"],
                    r["min_distance_m"],
                    r["t_delay_s_p50"],
                    r["override_path_s_p50"],
                    r["joint_state_age_s_p50"],
                    r["human_age_s_p50"],
                    ", ".join(f"{k} {v}" for k, v in sorted(r["faults"].items())) or "-",
                    r["max_delta_with_fault"],
                    r["delta_above_bound"],
                    r["reference_restarts"],
                ]
                for r in rows
            ],
        )
    )
    report.results["runs"] = rows
    total = sum(r["violations"] for r in rows)
    report.results["violations"] = total
    report.finish(args.json)
    print(f"\nviolations in all runs: {total}; wrote {args.json}")
    return 1 if total else 0


if __name__ == "__main__":
    raise SystemExit(main())
