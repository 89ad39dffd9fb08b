"""The planner layer in the simulated cell (issue 35; paper 2's two experiments), open Panda of
configs/cell_open_panda_planner.toml with its wide swing across the front:

- a person steps into the swing and stays: without the planner the robot creeps past them at the δ the scaling
  allows; with it the horizon check replans around them and the robot makes more of its cycle;
- the same person with the horizon check reduced to nothing: only the request (16) (δ below the threshold for a
  while) replans, and the robot still gets on better than without a planner;
- a planner that ignores the people (its paths go through where they stand) and one that never answers: 0
  violations: the LPs (9)/(13) bound every command whatever the robot follows. Only productivity changes.

Short runs (a few seconds of simulated time each) on one scenario; the figures are the auditor's, not timings.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import pytest

from gateway.planner import JointPlanner
from gateway.planner_worker import PlannerBackend
from hrc_contract.config import CellConfig
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_tools.sim.cell import RunResult, simulate
from hrc_tools.sim.faulty_planners import IgnoresPeople, NeverAnswers
from hrc_tools.sim.links import LinkFaults
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

DURATION_S = 7.0
FACING_ROBOT_RAD = 3.141592653589793


def steps_into_the_swing(duration_s: float) -> Scenario:
    """A person walks from 3.5 m in front of the robot to 1.8 m (0.8 s) and stands there: the straight swing then
    passes within the protective band (the robot slows to δ < 0.2), a tucked one does not."""
    keyframes = [
        Keyframe(t_s=0.0, xy_m=(3.5, 0.0), heading_rad=FACING_ROBOT_RAD),
        Keyframe(t_s=0.8, xy_m=(1.8, 0.0), heading_rad=FACING_ROBOT_RAD),
        Keyframe(t_s=duration_s, xy_m=(1.8, 0.0), heading_rad=FACING_ROBOT_RAD),
    ]
    return Scenario(
        description="a person steps into the swing",
        duration_s=duration_s,
        loop=False,
        humans=[HumanScript(id="h1", keyframes=keyframes)],
    )


def cell(planner: bool, **overrides: Any) -> tuple[CellConfig, dict[str, RobotModel]]:
    raw = load_cell_config("configs/cell_open_panda_planner.toml").model_dump()
    raw["trackers"] = {"front": {"rate_hz": 30.0, "noise_std_m": 0.0, "drop_probability": 0.0, "latency_s": 0.03}}
    # a generous RRT-Connect time limit: the simulated planner is synchronous (simulated time does not pass while it
    # plans), and a seeded search that is not cut short by a loaded machine gives the same plans every run
    raw["planner"] = {**raw["planner"], "enabled": planner, "time_limit_s": 3.0, **overrides}
    config = CellConfig.model_validate(raw)
    return config, {name: load_robot_model(name, r) for name, r in config.robots.items()}


def run(
    planner: bool,
    duration_s: float = DURATION_S,
    backend: Callable[[dict[str, JointPlanner]], PlannerBackend] | None = None,
    **overrides: Any,
) -> RunResult:
    config, robots = cell(planner, **overrides)
    return simulate(
        config,
        robots,
        steps_into_the_swing(duration_s),
        LinkFaults(),
        duration_s,
        1,
        program_start_s={"panda": 0.0},
        planner_backend=backend,
    )


@pytest.fixture(scope="module")
def without_planner() -> RunResult:
    return run(planner=False)


def test_with_the_planner_the_robot_goes_around_the_person_and_makes_more_of_its_cycle(
    without_planner: RunResult,
) -> None:
    with_planner = run(planner=True)
    assert without_planner.audit.violations == 0
    assert with_planner.audit.violations == 0
    stats = with_planner.planner["panda"]
    assert stats["requests"].get("horizon", 0) >= 1
    assert stats["adopted"] >= 1
    assert with_planner.program_progress_cycles > 1.5 * without_planner.program_progress_cycles
    assert without_planner.planner == {}


def test_the_request_16_alone_replans_when_the_person_keeps_the_robot_slow(without_planner: RunResult) -> None:
    request_only = run(planner=True, horizon_s=0.05, horizon_step_s=0.1)  # no configuration ahead is checked
    stats = request_only.planner["panda"]
    assert stats["requests"].get("horizon", 0) == 0
    assert stats["requests"].get("request", 0) >= 1
    assert stats["adopted"] >= 1
    assert request_only.audit.violations == 0
    assert request_only.program_progress_cycles > 1.2 * without_planner.program_progress_cycles


@pytest.mark.parametrize("faulty", [IgnoresPeople, NeverAnswers], ids=["through_the_person", "silent"])
def test_a_faulty_planner_changes_productivity_never_safety(
    faulty: Callable[[dict[str, JointPlanner]], PlannerBackend],
) -> None:
    result = run(planner=True, duration_s=4.0, backend=faulty)
    assert result.audit.violations == 0
    assert sum(result.planner["panda"]["requests"].values()) >= 1
    assert result.audit.smallest_margin_moving_m > 0.0
