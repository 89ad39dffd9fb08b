"""Shared fixtures of the unit tests: the default cell configuration and its UR5, loaded once."""

from __future__ import annotations

import pytest

from hrc_common.config import CellConfig, load_cell_config
from hrc_common.robot_model import RobotModel, load_robot_model


@pytest.fixture(scope="session")
def cell_config() -> CellConfig:
    """configs/cell.toml as shipped (UR5 on a 0.8 m pedestal, trackers front and side)."""
    return load_cell_config(None)


@pytest.fixture(scope="session")
def ur5(cell_config: CellConfig) -> RobotModel:
    """The UR5 of the default cell, loaded with Pinocchio from example-robot-data."""
    return load_robot_model("ur5", cell_config.robots["ur5"])
