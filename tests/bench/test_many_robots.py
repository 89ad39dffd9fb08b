"""bench.many_robots writes a valid cell of N copies of the two-arm cell and a scenario with one person per copy;
bench.controller_host runs several controller emulators in one process."""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import numpy as np
import pytest
import zenoh

from bench.many_robots import SCENARIO, TWO_ARMS, write_cell
from hrc_contract import keys
from hrc_contract.messages import JointState, parse_message
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_endpoint, log_tail, start_program, stop_program, wait_for
from tracker_emu.scenario import load_scenario, scenario_path

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)


def test_eight_robots_and_four_people_fit_the_cell(tmp_path: Path) -> None:
    config = load_cell_config(write_cell(4, tmp_path))
    assert sorted(config.robots) == sorted([f"ur5_{k}" for k in range(1, 5)] + [f"panda_{k}" for k in range(1, 5)])
    ur5_x = sorted(config.robots[f"ur5_{k}"].base_pose_world.xyz[0] for k in range(1, 5))
    assert np.diff(ur5_x).min() >= 6.0  # one copy's person never reaches into the next copy
    scenario = load_scenario(scenario_path(config.scenarios_dir, SCENARIO))
    assert [h.id for h in scenario.humans] == ["p1", "p2", "p3", "p4"]
    assert config.default_scenario == SCENARIO
    lo, hi = config.plausibility.world_min_m, config.plausibility.world_max_m
    xy = np.array([kf.xy_m for h in scenario.humans for kf in h.keyframes])
    assert np.all(xy >= np.array(lo[:2]) + 1.0), "a person's floor position is within 1 m of the world's edge"
    assert np.all(xy <= np.array(hi[:2]) - 1.0), "a person's floor position is within 1 m of the world's edge"
    # The trackers cover every robot, and every person enters and leaves through the covered volume's boundary (a
    # person who vanished inside it would be lost there, not gone, and hold the robots near them).
    low, high = np.array(config.tracking.coverage_min_m[:2]), np.array(config.tracking.coverage_max_m[:2])
    bases = np.array([robot.base_pose_world.xyz[:2] for robot in config.robots.values()])
    assert np.all((bases >= low + 1.0) & (bases <= high - 1.0)), "a robot outside the trackers' view"
    for human in scenario.humans:
        first, last = np.array(human.keyframes[0].xy_m), np.array(human.keyframes[-1].xy_m)
        assert np.any((first < low) | (first > high)), f"{human.id} appears inside the covered volume"
        assert np.any((last < low) | (last > high)), f"{human.id} vanishes inside the covered volume"


@pytest.mark.e2e
def test_one_controller_host_process_runs_several_controllers(tmp_path: Path) -> None:
    """bench.controller_host: both robots of the two-arm cell publish joint states from one process; SIGINT → 0."""
    endpoint = free_endpoint()
    seen: set[str] = set()
    lock = threading.Lock()

    def on_state(sample: zenoh.Sample) -> None:
        with lock:
            seen.add(parse_message(sample.payload.to_bytes(), JointState).robot)

    with zenoh.open(session_config(listen=[endpoint])) as session:
        session.declare_subscriber(keys.robot_state("twoarms", "*"), on_state)
        args = ["--config", str(TWO_ARMS), "--robots", "ur5,panda", "--zenoh-connect", endpoint]
        proc = start_program("bench.controller_host", args, tmp_path / "host.log")
        try:
            wait_for(lambda: seen == {"ur5", "panda"}, 30.0, "joint states of both robots", [proc])
        finally:
            code = stop_program(proc, signal.SIGINT)
    assert code == 0, log_tail(tmp_path / "host.log")
