"""Teeth for open robots (safety-math.md §13): a delayed approach the auditor flags when the gateway's LPs ignore
the delay (``unsafe_ignore_delay_for_tests``) and that the real gateway passes, on the open Panda of
``configs/cell_open_panda.toml`` (its controller stops in exactly the 0.5 s the rows assume: no slack).

Found by a search (2026-12-05, after LP (13) got its half percent of room): at K = 1.6 m/s, bearings 0 / ±20 / ±40°,
tracker delays 0.15 / 0.19 s, override delays 0.08 / 0.1 s and program phases 0–4.5 s (200 cases), the delay-blind
LPs violate in two: both below. (The case used before, head-on from the program's 2.0 s, no longer violates: the
room leaves the rows some slack.) The delay-blind LPs violate only with both links delayed near the data-age limit.
"""

from __future__ import annotations

import math

import pytest

from hrc_contract.config import UNSAFE_ENV_VAR, CellConfig
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_tools.sim.cell import RunResult, simulate
from hrc_tools.sim.links import LinkFault, LinkFaults
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

DURATION_S = 4.0


def approach(speed_mps: float, bearing_deg: float) -> Scenario:
    """One person walking straight at the robot's base from 3 m to 0.6 m from it, along the bearing (0° = +x, in front
    of it), then standing."""
    bearing = math.radians(bearing_deg)
    start = (3.0 * math.cos(bearing), 3.0 * math.sin(bearing))
    end = (0.6 * math.cos(bearing), 0.6 * math.sin(bearing))
    heading = bearing + math.pi
    t1 = 0.2 + 2.4 / speed_mps
    keyframes = [
        Keyframe(t_s=0.2, xy_m=start, heading_rad=heading),
        Keyframe(t_s=t1, xy_m=end, heading_rad=heading),
        Keyframe(t_s=DURATION_S, xy_m=end, heading_rad=heading),
    ]
    return Scenario(
        description="an approach",
        duration_s=DURATION_S,
        loop=False,
        humans=[HumanScript(id="h1", keyframes=keyframes)],
    )


def open_panda(ignore_delay: bool) -> tuple[CellConfig, dict[str, RobotModel]]:
    raw = load_cell_config("configs/cell_open_panda.toml").model_dump()
    raw["trackers"] = {"front": {"rate_hz": 30.0, "noise_std_m": 0.0, "drop_probability": 0.0, "latency_s": 0.0}}
    raw["safety"]["unsafe_ignore_delay_for_tests"] = ignore_delay
    config = CellConfig.model_validate(raw)
    return config, {name: load_robot_model(name, r) for name, r in config.robots.items()}


def run(config: CellConfig, robots: dict[str, RobotModel], bearing_deg: float, program_start_s: float) -> RunResult:
    links = LinkFaults(tracker_to_gateway=LinkFault(delay_s=0.15), gateway_to_controller=LinkFault(delay_s=0.08))
    scenario = approach(1.6, bearing_deg)
    return simulate(config, robots, scenario, links, DURATION_S, 1, program_start_s={"panda": program_start_s})


@pytest.mark.parametrize(("bearing_deg", "program_start_s"), [(20.0, 1.5), (-20.0, 4.5)])
def test_open_lps_that_ignore_the_delay_violate_where_the_real_ones_do_not(
    monkeypatch: pytest.MonkeyPatch, bearing_deg: float, program_start_s: float
) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_ignore_delay_for_tests")
    blind = run(*open_panda(ignore_delay=True), bearing_deg, program_start_s)
    real = run(*open_panda(ignore_delay=False), bearing_deg, program_start_s)
    assert blind.audit.violations > 0
    assert real.audit.violations == 0
    assert real.audit.smallest_margin_moving_m > 0.0
    assert real.program_progress_cycles > 0.03  # it moved (a cycle is 5.2 s): the margin is not a standing robot's
