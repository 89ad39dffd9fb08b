"""What the planner cell's end-to-end modules share (tests/e2e/test_planner_cell.py, test_planner_experiments.py)."""

from __future__ import annotations

from typing import Any

from support.paths import REPO_ROOT

CONFIG = REPO_ROOT / "configs" / "cell_open_panda_planner.toml"
ROBOT = "panda"
READY_S = 40.0
"""The gateway compiles and checks the Panda's kinematics and starts the planner's process; a shared machine."""


def above_bound(trace: list[dict[str, Any]]) -> list[float]:
    """The times at which δ exceeded the LPs' bound (none expected)."""
    return [s["t_s"] for s in trace if s["delta"] > s["delta_bound"] + 1e-9]
