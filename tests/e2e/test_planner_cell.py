"""End to end, the planner layer: configs/cell_open_panda_planner.toml (the open Panda's wide swing, the planner in
its own process) with the real gateway, controller emulator and tracker emulator over loopback Zenoh, a person
standing in the swing (scenario ``standing_inside``).

- Plans around the person are asked for, adopted and shown: the status (``robots.panda.plan``: following, the
  tool's path), the events (``plan_adopted``); δ never above the LPs' bound, faults only late data (failed closed).
- The planner's process killed: the gateway counts the death, starts it again and shows both in the status and the
  events; the robot goes on under the LPs meanwhile (δ within its bound).

Paper 2's two experiments apart and the planner off, each in a cell of its own, are ``test_planner_experiments.py``'s
(a module of their own, so that this module's cell has stopped before theirs start).
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from support.planner_cell import CONFIG, READY_S, ROBOT, above_bound

from hrc_contract.status_models import EventsResponse
from hrc_tools.cell.procs import Cell, late_data_only, load_scale, record, running_cell

pytestmark = pytest.mark.e2e

PLAN_S = 15.0
"""A plan is adopted within this of a running robot on an idle machine (the swing meets the person every few
seconds; docs/planner.md: 13 adopted in 65 s) [s]."""


def _adopted(trace: list[dict[str, Any]]) -> bool:
    """A plan adopted, and the robot seen following one (the first may be done before the recording starts)."""
    plans = [s["plan"] for s in trace if s["plan"] is not None]
    return any(p["adopted"] > 0 for p in plans) and any(p["following"] for p in plans)


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
    assert not above_bound(trace)
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
    assert not above_bound(trace)
    assert late_data_only(trace) == [], "faults other than late data, or δ > 0 with a fault"
    print(f"planner restarted {restart_s:.2f} s after SIGKILL (first backoff step 0.5 s)")
