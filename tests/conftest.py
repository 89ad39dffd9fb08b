"""Shared fixtures of the unit tests: the default cell configuration and its UR5, loaded once."""

from __future__ import annotations

import os

import pytest

from hrc_contract.config import CellConfig
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import PLAIN_TCP_ENV_VAR

# The loopback tests run the programs over plain TCP (development mode; every program they start inherits this);
# test_security_*.py run them with mutual TLS and access control, and drop it from their programs' environment.
os.environ.setdefault(PLAIN_TCP_ENV_VAR, "1")


@pytest.fixture(scope="session")
def cell_config() -> CellConfig:
    """configs/cell.toml as shipped (UR5 on a 0.8 m pedestal, trackers front and side)."""
    return load_cell_config(None)


@pytest.fixture(scope="session")
def ur5(cell_config: CellConfig) -> RobotModel:
    """The UR5 of the default cell, loaded with Pinocchio from example-robot-data."""
    return load_robot_model("ur5", cell_config.robots["ur5"])


def pytest_sessionstart(session: pytest.Session) -> None:
    """Compile the gateway's kernels once (or load them from numba's cache) before any test starts a gateway.

    On a fresh clone every gateway process would otherwise compile them at the same time (~7 s each on
    this 2-core machine), against the end-to-end tests' readiness timeouts.
    """
    from gateway.capsules_json import check_capsules_json
    from gateway.core import SafetyCore
    from gateway.kernels import check_frame_numbers

    config = load_cell_config(None)
    SafetyCore(config, {name: load_robot_model(name, robot) for name, robot in config.robots.items()})
    check_frame_numbers()  # the door's
    check_capsules_json()  # the status's


CELLS_GROUP = "cells"
"""The xdist group of every end-to-end test: they start real cells (fixed loopback faces among them) and judge timing,
so they run one after another on one worker; and of the tests marked ``serial``, which judge real processes, sockets
or Zenoh sessions in real time and held only beside the other worker's unit tests, not beside a cell as well."""

CELLS_MARKERS = ("e2e", "serial")


def pytest_itemcollected(item: pytest.Item) -> None:
    """Group the tests for pytest-xdist's ``--dist loadgroup`` (run-tests.sh: ``-n 2``), as they are collected (xdist
    reads the groups in its ``pytest_collection_modifyitems``).

    The end-to-end tests and those marked ``serial`` form one group: one worker runs them in order, as without xdist,
    and no two cells run at once. Every other test is grouped with its module: a module's fixtures, loopback addresses
    and ports (RTDE's fixed 30004 on an address per module) are used by one worker at a time, beside the other's cells.
    """
    if item.config.pluginmanager.hasplugin("xdist"):
        item.add_marker(pytest.mark.xdist_group(xdist_group(item)))


def xdist_group(item: pytest.Item) -> str:
    """The test's group: :data:`CELLS_GROUP` for the end-to-end and ``serial`` tests, else its module's path."""
    if any(item.get_closest_marker(marker) for marker in CELLS_MARKERS):
        return CELLS_GROUP
    return item.nodeid.split("::", 1)[0]
