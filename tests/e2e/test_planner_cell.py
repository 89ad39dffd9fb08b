"""End to end, the planner layer: configs/cell_open_panda_planner.toml (the open Panda's wide swing, the planner in
its own process) with the real gateway, controller emulator and tracker emulator over loopback Zenoh, a person
standing in the swing (scenario ``standing_inside``).

- Plans around the person are asked for, adopted and shown: the status (``robots.panda.plan``: following, the
  tool's path), the events (``plan_adopted``); δ never above the LPs' bound, faults only late data (failed closed).
- The planner's process killed: the gateway counts the death, starts it again and shows both in the status and the
  events; the robot goes on under the LPs meanwhile (δ within its bound).
- Paper 2's two experiments apart, each in a cell of its own where a person steps into the swing once the cell runs:
  the horizon check alone (no request (16): its threshold at 0) and the request (16) alone (no configuration ahead
  checked); and the planner off, where the robot waits (stands at δ = 0 while the person stays). The productivity
  comparison is ``bench.planner``'s (a figure, not a timed assertion).
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from support.paths import REPO_ROOT

from hrc_contract.status_models import EventsResponse
from hrc_runtime.config import load_cell_config
from hrc_tools.cell.procs import Cell, late_data_only, load_scale, record, running_cell, write_cell_config

pytestmark = pytest.mark.e2e

CONFIG = REPO_ROOT / "configs" / "cell_open_panda_planner.toml"
ROBOT = "panda"
READY_S = 40.0
"""The gateway compiles and checks the Panda's kinematics and starts the planner's process; a shared machine."""
PLAN_S = 15.0
"""A plan is adopted within this of a running robot on an idle machine (the swing meets the person every few
seconds; docs/planner.md: 13 adopted in 65 s) [s]."""


def _adopted(trace: list[dict[str, Any]]) -> bool:
    """A plan adopted, and the robot seen following one (the first may be done before the recording starts)."""
    plans = [s["plan"] for s in trace if s["plan"] is not None]
    return any(p["adopted"] > 0 for p in plans) and any(p["following"] for p in plans)


def _within_bound(trace: list[dict[str, Any]]) -> list[float]:
    """The times at which δ exceeded the LPs' bound (none expected)."""
    return [s["t_s"] for s in trace if s["delta"] > s["delta_bound"] + 1e-9]


def _planner_pid(gateway_pid: int) -> int:
    """The gateway's planner process: its child running ``multiprocessing.spawn.spawn_main`` (Linux ``/proc``; not
    multiprocessing's resource tracker)."""
    children = []
    for task in Path(f"/proc/{gateway_pid}/task").iterdir():
        children += [int(pid) for pid in (task / "children").read_text().split()]
    planners = [pid for pid in children if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes()]
    assert len(planners) == 1, f"planner processes among the gateway's children {children}: {planners}"
    return planners[0]


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    """One cell for the module's tests (a start-up is most of an end-to-end test's time on a loaded machine)."""
    with running_cell(tmp_path_factory.mktemp("planner"), config=CONFIG, scenario="standing_inside") as cell:
        cell.wait_until(
            lambda s: s["controller_mode"] == "running" and not s["faults"] and s["plan"] is not None,
            READY_S,
            "a running open robot with its planner layer",
            ROBOT,
        )
        yield cell


def test_plans_around_a_person_standing_in_the_path_are_adopted_and_delta_stays_within_its_bound(cell: Cell) -> None:
    trace = record(cell, PLAN_S * load_scale(), ROBOT, until=_adopted)
    for name in ("gateway", "controller", "tracker"):
        assert cell.procs[name].poll() is None, f"{name} died during the run\n{cell.tail()}"
    events = EventsResponse.model_validate_json(cell.get("/api/v1/events").content).events
    assert _adopted(trace), f"no plan adopted in {trace[-1]['t_s']:.1f} s: {trace[-1]['plan']}\n{cell.tail()}"
    first = next(s for s in trace if s["plan"]["adopted"] > 0)
    assert first["min_distance_m"] is not None, "the person stands in the cell while the robot replans"
    plan = first["plan"]
    assert plan["requests"], plan
    assert plan["reason"] in ("horizon", "request")
    assert plan["planning_last_s"] is not None
    assert plan["planning_total_s"] > 0.0
    following = [s["plan"] for s in trace if s["plan"]["following"]]
    assert following, "the robot follows the plan"
    assert all(len(p["path_tool_m"]) == 32 for p in following), "the plan's tool path is shown while it is followed"
    adopted = [e for e in events if e.kind == "plan_adopted"]
    assert adopted, [e.kind for e in events]
    assert adopted[0].robot == ROBOT
    assert adopted[0].cause in ("horizon", "request")
    assert not _within_bound(trace)
    assert late_data_only(trace) == [], "faults other than late data, or δ > 0 with a fault"


def test_a_killed_planner_process_is_counted_and_started_again_while_the_lps_bound_every_command(cell: Cell) -> None:
    first = _planner_pid(cell.gateway.pid)
    killed: list[tuple[int, float]] = []  # (statuses before the kill, when)

    def kill_then_restarted(trace: list[dict[str, Any]]) -> bool:
        if not trace:
            return False
        if not killed:  # killed once the statuses are recorded: the recording sees the planner down
            os.kill(first, signal.SIGKILL)
            killed.append((len(trace), time.monotonic()))
            return False
        return bool(trace[-1]["plan"]["planner_restarts"] >= 1)

    trace = record(cell, 10.0 * load_scale(), ROBOT, until=kill_then_restarted)
    assert killed, "no status recorded"
    restart_s = time.monotonic() - killed[0][1]
    assert cell.gateway.poll() is None, f"the gateway died with its planner\n{cell.tail()}"
    assert kill_then_restarted(trace), f"no restart in {restart_s:.1f} s: {trace[-1]['plan']}\n{cell.tail()}"
    again = _planner_pid(cell.gateway.pid)
    events = EventsResponse.model_validate_json(cell.get("/api/v1/events").content).events
    logged = [(e.kind, e.cause) for e in events if e.kind.startswith("planner_")]
    assert logged == [("planner_died", "signal SIGKILL"), ("planner_restarted", None)], logged
    before, after = trace[: killed[0][0]], trace[killed[0][0] :]
    assert all(s["plan"]["planner_running"] and s["plan"]["planner_deaths"] == 0 for s in before)
    plan = trace[-1]["plan"]
    assert (plan["planner_deaths"], plan["planner_restarts"], plan["planner_last_exit"]) == (1, 1, "signal SIGKILL")
    assert after[0]["plan"]["adopted"] <= plan["adopted"]  # its counts survive the restart
    assert plan["planner_running"]
    assert again != first
    down = [s for s in after if not s["plan"]["planner_running"]]
    assert down, "the status showed the planner down until its restart"
    assert not _within_bound(trace)
    assert late_data_only(trace) == [], "faults other than late data, or δ > 0 with a fault"
    print(f"planner restarted {restart_s:.2f} s after SIGKILL (first backoff step 0.5 s)")


IN_THE_SWING = "steps_into_the_swing"
STEP_IN_S = 25.0
"""The person steps into the swing this long after the cell starts: the planner's process is up by then (it imports
OMPL and TOPP-RA; seconds on a loaded machine). A person already there when the robot starts can meet it before its
planner answers: the robot crept on, then stood in a protective stop that no plan can lift (seen on a loaded
host) [s]."""
IN_THE_SWING_TOML = f"""
description = "a person walks in from 5 m and stands 1.8 m in front of the robot, in its wide swing, from then on"
duration_s = 600.0
loop = false

[[humans]]
id = "h1"

[[humans.keyframes]]
t_s = 0.0
xy_m = [5.0, 3.5]
heading_rad = 3.8

[[humans.keyframes]]
t_s = {STEP_IN_S}
xy_m = [5.0, 3.5]
heading_rad = 3.8

[[humans.keyframes]]
t_s = {STEP_IN_S + 4.0}
xy_m = [1.8, 0.0]
heading_rad = 3.141592653589793

[[humans.keyframes]]
t_s = 600.0
xy_m = [1.8, 0.0]
heading_rad = 3.141592653589793
"""
"""Paper 2's set-up (tests/hrc_tools/sim/test_planner_cell.py): the straight swing passes within the protective band
(the robot slows to δ < 0.2 there), a tucked one does not. The walk in is at 1.1 m/s (within K)."""
ARRIVED_M = 2.0
"""The person counts as arrived once this near the robot (the recording starts then) [m]."""

COMPARE_S = 25.0
"""Each run records this long once the person has arrived (a few swings past them) [s]."""
WAITING_S = 5.0
"""Without a planner the robot stands at least this long at the end of the recording (measured: δ = 0 from 12 s of
25 on) [s]."""


def _planner_cell(tmp_path: Path, replan_delta_below: float | None = None, **planner: Any) -> Path:
    """The planner cell with ``[planner]`` (and the request (16)'s threshold, ``safety.replan_delta_below``) changed
    so."""
    config = load_cell_config(CONFIG)
    scenarios = tmp_path / "scenarios"
    scenarios.mkdir(parents=True, exist_ok=True)
    (scenarios / f"{IN_THE_SWING}.toml").write_text(IN_THE_SWING_TOML)
    update: dict[str, Any] = {
        "planner": config.planner.model_copy(update=planner),
        "scenarios_dir": str(scenarios),
    }
    if replan_delta_below is not None:
        update["safety"] = config.safety.model_copy(update={"replan_delta_below": replan_delta_below})
    return write_cell_config(config.model_copy(update=update), tmp_path / "cell.toml")


def _run_for(tmp_path: Path, config: Path, duration_s: float) -> list[dict[str, Any]]:
    """Run the cell in ``config`` until the person has walked in, then record ``duration_s``."""
    with running_cell(tmp_path, config=config, scenario=IN_THE_SWING) as cell:
        cell.wait_until(
            lambda s: s["controller_mode"] == "running" and not s["faults"] and s["open_command"] is not None,
            READY_S * load_scale(),
            "a running open robot",
            ROBOT,
        )
        cell.wait_until(
            lambda s: s["min_distance_m"] is not None and s["min_distance_m"] < ARRIVED_M,
            (STEP_IN_S + 10.0) * load_scale(),
            "the person in the swing",
            ROBOT,
        )
        trace = record(cell, duration_s, ROBOT)
        for name in ("gateway", "controller", "tracker"):
            assert cell.procs[name].poll() is None, f"{name} died during the run\n{cell.tail()}"
    assert not _within_bound(trace)
    assert late_data_only(trace) == [], "faults other than late data, or δ > 0 with a fault"
    return trace


def _progress_cycles(trace: list[dict[str, Any]]) -> float:
    cycles = [s["open_command"]["program_cycles"] for s in trace if s["open_command"] is not None]
    return float(cycles[-1] - cycles[0])


@pytest.mark.parametrize(
    ("experiment", "planner", "reason"),
    [
        ("horizon", {"replan_delta_below": 0.0}, "horizon"),
        ("request_16", {"horizon_s": 0.05, "horizon_step_s": 0.1}, "request"),
    ],
    ids=["horizon_check", "request_16"],
)
def test_each_of_the_papers_experiments_replans_on_its_own(
    tmp_path: Path, experiment: str, planner: dict[str, float], reason: str
) -> None:
    trace = _run_for(tmp_path, _planner_cell(tmp_path, **planner), COMPARE_S)
    plan = trace[-1]["plan"]
    assert plan["adopted"] >= 1, (experiment, plan)
    assert set(plan["requests"]) == {reason}, (experiment, plan["requests"])


def test_with_the_planner_off_the_robot_waits(tmp_path: Path) -> None:
    """Paper 2's comparison, its qualitative half: without the planner the robot creeps towards the person and then
    stands (δ = 0) for as long as they stay. How much more of its program the robot makes with the planner is a
    productivity figure, measured by ``bench.planner`` (docs/planner.md), not asserted here: on a loaded 2-core host
    the planner's answer time and so the figure vary (CI's runs: 0.061 vs 0.075 with the person there from the start;
    0.36 vs 0.39 beside ``bench.cpu_hog``; 0.88 vs 0.38 at load 2–5)."""
    off = _run_for(tmp_path, _planner_cell(tmp_path, enabled=False), COMPARE_S)
    assert all(s["plan"] is None for s in off), "no planner layer when it is off"
    end_s = off[-1]["t_s"]
    last = [s for s in off if s["t_s"] >= end_s - WAITING_S]
    assert all(s["delta"] == 0.0 for s in last), [(s["t_s"], s["zone"], s["delta"]) for s in last if s["delta"] > 0]
    nearest_m = last[-1]["min_distance_m"]
    assert nearest_m is not None
    assert nearest_m < ARRIVED_M, "the person still there"
    print(f"program cycles in {COMPARE_S} s beside the person, planner off: {_progress_cycles(off):.2f}")
