"""The open Panda's EGM cell for the end-to-end tests: ``configs/cell_open_panda_egm.toml`` on a UDP port of its own,
what its default scenario shows, and when a recording of it may end."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hrc_contract.config import AbbEgmInterfaceConfig
from hrc_runtime.config import load_cell_config
from hrc_tools.cell.procs import free_udp_port, write_cell_config
from support.paths import REPO_ROOT

CONFIG = REPO_ROOT / "configs" / "cell_open_panda_egm.toml"
ROBOT = "panda"
READY_S = 40.0  # the gateway compiles and checks the Panda's kinematics; a shared machine
SCENARIO_S = 31.0
ZONE_SEQUENCE = ["autonomous", "guarded_distance", "safety_exception", "autonomous"]
"""As the Zenoh-driven open Panda's (tests/e2e/test_open_cell.py): LP (13) keeps δ = 1 by self-motion until the
person reaches the protective distance."""


def egm_cell(tmp_path: Path) -> Path:
    """``configs/cell_open_panda_egm.toml`` with the PC on a UDP port of its own."""
    config = load_cell_config(CONFIG)
    robot = config.robots[ROBOT]
    assert isinstance(robot.interface, AbbEgmInterfaceConfig)
    interface = robot.interface.model_copy(update={"port": free_udp_port()})
    robots = {ROBOT: robot.model_copy(update={"interface": interface})}
    return write_cell_config(config.model_copy(update={"robots": robots}), tmp_path / "cell.toml")


def until_back_to_autonomous(trace: list[dict[str, Any]]) -> bool:
    """The person came to the protective distance and the robot has been autonomous again for 2 s."""
    exceptions = [s["t_s"] for s in trace if s["zone"] == "safety_exception" and s["min_distance_m"] is not None]
    return bool(exceptions) and trace[-1]["zone"] == "autonomous" and trace[-1]["t_s"] - exceptions[-1] > 2.0
