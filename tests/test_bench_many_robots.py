"""bench.many_robots writes a valid cell of N copies of the two-arm cell and a scenario with one person per copy."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.many_robots import SCENARIO, write_cell
from hrc_common.config import load_cell_config
from tracker_emu.scenario import load_scenario, scenario_path


def test_eight_robots_and_four_people_fit_the_cell(tmp_path: Path) -> None:
    config = load_cell_config(write_cell(4, tmp_path))
    assert sorted(config.robots) == sorted([f"ur5_{k}" for k in range(1, 5)] + [f"panda_{k}" for k in range(1, 5)])
    bases_y = sorted({config.robots[name].base_pose_world.xyz[1] for name in config.robots})
    assert np.diff(bases_y).min() >= 6.0  # one copy's person never reaches into the next copy
    scenario = load_scenario(scenario_path(config.scenarios_dir, SCENARIO))
    assert [h.id for h in scenario.humans] == ["p1", "p2", "p3", "p4"]
    assert config.default_scenario == SCENARIO
    lo, hi = config.plausibility.world_min_m, config.plausibility.world_max_m
    xy = np.array([kf.xy_m for h in scenario.humans for kf in h.keyframes])
    assert np.all(xy >= np.array(lo[:2]) + 1.0), "a person's floor position is within 1 m of the world's edge"
    assert np.all(xy <= np.array(hi[:2]) - 1.0), "a person's floor position is within 1 m of the world's edge"
