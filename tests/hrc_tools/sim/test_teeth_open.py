"""Teeth for open robots (safety-math.md §13): a delayed approach the auditor flags when the gateway's LPs ignore
the delay (``unsafe_ignore_delay_for_tests``) and that the real gateway passes, on the open Panda of
``configs/cell_open_panda.toml`` (its controller stops in exactly the 0.5 s the rows assume: no slack).

Found by a search over tracker delays 0.1–0.15 s, override delays 0–0.08 s, 1.6–2.0 m/s, bearings 0 / ±40 / ±90°
and program phases 0–3 s: the delay-blind LPs violate only with both links delayed near the data-age limit.
"""

from __future__ import annotations

import pytest

from hrc_contract.config import UNSAFE_ENV_VAR, CellConfig
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_tools.sim.cell import RunResult, simulate
from hrc_tools.sim.links import LinkFault, LinkFaults
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

DURATION_S = 4.0


def head_on(speed_mps: float) -> Scenario:
    """One person walking straight at the robot's base from 3 m to 0.6 m in front of it (+x), then standing."""
    t1 = 0.2 + 2.4 / speed_mps
    keyframes = [
        Keyframe(t_s=0.2, xy_m=(3.0, 0.0), heading_rad=3.141592653589793),
        Keyframe(t_s=t1, xy_m=(0.6, 0.0), heading_rad=3.141592653589793),
        Keyframe(t_s=DURATION_S, xy_m=(0.6, 0.0), heading_rad=3.141592653589793),
    ]
    return Scenario(
        description="head-on approach",
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


def run(config: CellConfig, robots: dict[str, RobotModel]) -> RunResult:
    links = LinkFaults(tracker_to_gateway=LinkFault(delay_s=0.15), gateway_to_controller=LinkFault(delay_s=0.08))
    return simulate(config, robots, head_on(1.6), links, DURATION_S, 1, program_start_s={"panda": 2.0})


def test_open_lps_that_ignore_the_delay_violate_where_the_real_ones_do_not(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_ignore_delay_for_tests")
    blind = run(*open_panda(ignore_delay=True))
    real = run(*open_panda(ignore_delay=False))
    assert blind.audit.violations > 0
    assert real.audit.violations == 0
    assert real.audit.smallest_margin_moving_m > 0.0
    assert real.program_progress_cycles > 0.03  # it moved (a cycle is 5.2 s): the margin is not a standing robot's
