"""Teeth with two robots: in the two-arm cell (configs/cell_two_arms.toml, made tight as in test_sim_teeth.py),
a gateway that ignores the delay violates at BOTH robots, and the real gateway at neither.

One person walks at 1.6 m/s (the gateway's K) straight at the UR5 from its left (+y), another at the Panda
from its right (-y), at the same time; one noiseless 30 Hz tracker whose link is delayed by 0.1 s. Tight: the
gateway assumes for every joint the braking time the emulated controllers really have (0.24 s), so that
nothing but the delay handling stands between the gateway and a violation. The program phases (UR5 2.0 s,
Panda 1.0 s) were chosen so that the delay-blind gateway violates at both robots (29 and 30 cycles).
"""

from __future__ import annotations

import math

import pytest
from support.paths import DEFAULT_CELL_PATH

from hrc_contract.config import UNSAFE_ENV_VAR, CellConfig
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_tools.sim.cell import RunResult, simulate
from hrc_tools.sim.links import LinkFault, LinkFaults
from hrc_tools.sim.sweep import CellVariant
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

CONFIG = DEFAULT_CELL_PATH.parent / "cell_two_arms.toml"
DURATION_S = 4.0
SEED = 1
SPEED_MPS = 1.6
TRACKER_DELAY_S = 0.1
PROGRAM_START_S = {"ur5": 2.0, "panda": 1.0}


def approach(
    human: str, base_xy_m: tuple[float, float], bearing_deg: float, stop_m: float = 0.6, start_m: float = 3.0
) -> HumanScript:
    """One person walking at :data:`SPEED_MPS` straight at a robot base along ``bearing_deg``, then standing."""
    bearing = math.radians(bearing_deg)
    (cx, cy), (ux, uy) = base_xy_m, (math.cos(bearing), math.sin(bearing))
    start, stop = (cx + start_m * ux, cy + start_m * uy), (cx + stop_m * ux, cy + stop_m * uy)
    facing = math.atan2(-uy, -ux)
    t_arrive_s = 0.2 + (start_m - stop_m) / SPEED_MPS
    return HumanScript(
        id=human,
        keyframes=[
            Keyframe(t_s=0.2, xy_m=start, heading_rad=facing),
            Keyframe(t_s=t_arrive_s, xy_m=stop, heading_rad=facing),
            Keyframe(t_s=DURATION_S, xy_m=stop, heading_rad=facing),
        ],
    )


def run(ignore_delay: bool) -> RunResult:
    raw = load_cell_config(CONFIG).model_dump()
    raw["trackers"] = {"front": {"rate_hz": 30.0, "noise_std_m": 0.0, "drop_probability": 0.0, "latency_s": 0.0}}
    variant = CellVariant(unsafe_ignore_delay=ignore_delay, tight_braking=True)
    config = variant.apply(CellConfig.model_validate(raw))
    robots: dict[str, RobotModel] = {name: load_robot_model(name, r) for name, r in config.robots.items()}
    ur5_xy, panda_xy = (config.robots[r].base_pose_world.xyz[:2] for r in ("ur5", "panda"))
    scenario = Scenario(
        description="teeth: one person at each robot",
        duration_s=DURATION_S,
        loop=False,
        humans=[
            approach("at_ur5", (ur5_xy[0], ur5_xy[1]), 90.0),
            approach("at_panda", (panda_xy[0], panda_xy[1]), -90.0),
        ],
    )
    links = LinkFaults(tracker_to_gateway=LinkFault(delay_s=TRACKER_DELAY_S))
    return simulate(config, robots, scenario, links, DURATION_S, SEED, program_start_s=PROGRAM_START_S)


def test_ignoring_the_delay_violates_at_both_robots_where_the_real_gateway_does_not(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_ignore_delay_for_tests")  # the test-only setting is refused without
    unsafe = run(ignore_delay=True)
    assert unsafe.t_delay_max_s == 0.0
    for robot in ("ur5", "panda"):
        summary = unsafe.per_robot[robot]
        assert summary.violations > 10, (robot, summary.to_dict())
        assert summary.smallest_margin_m < 0.0
    real = run(ignore_delay=False)
    for robot in ("ur5", "panda"):
        summary = real.per_robot[robot]
        assert summary.violations == 0, (robot, summary.to_dict())
        assert summary.smallest_margin_moving_m > 0.1, (robot, summary.to_dict())
    assert real.t_delay_min_s is not None
    assert real.t_delay_min_s > TRACKER_DELAY_S
