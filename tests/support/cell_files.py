"""Edited copies of the shipped cell files, for the tests that load (or must refuse) a configuration file.

A copy is edited as text, not written from a configuration model, so that it can hold what no valid model can:
an unknown method, a negative braking time, a broken table.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

from support.paths import DEFAULT_CELL_PATH

CONFIGS = DEFAULT_CELL_PATH.parent

Edit = Callable[[str], str]


def replace_once(old: str, new: str) -> Edit:
    """An edit replacing the first ``old`` with ``new``; it fails the test if ``old`` is not in the file."""

    def edit(text: str) -> str:
        assert old in text, f"{old!r} not in the file: the test is out of date"
        return text.replace(old, new, 1)

    return edit


def write_cell(tmp_path: Path, cell: Edit | None = None, robot: Edit | None = None) -> Path:
    """Copies of configs/cell.toml, robots/ur5.toml, the program and the body regions under tmp_path, edited; the cell's
    ``model =`` points at the edited robot copy."""
    (tmp_path / "robots").mkdir(exist_ok=True)
    (tmp_path / "programs").mkdir(exist_ok=True)
    shutil.copy(CONFIGS / "programs" / "ur5_pick_place.toml", tmp_path / "programs" / "ur5_pick_place.toml")
    shutil.copy(CONFIGS / "body_regions.toml", tmp_path / "body_regions.toml")  # the cell's pfl_body_regions
    robot_text = (CONFIGS / "robots" / "ur5.toml").read_text()
    (tmp_path / "robots" / "ur5_edited.toml").write_text(robot(robot_text) if robot else robot_text)
    cell_text = (CONFIGS / "cell.toml").read_text()
    cell_text = replace_once('model = "robots/ur5.toml"', 'model = "robots/ur5_edited.toml"')(cell_text)
    path = tmp_path / "cell.toml"
    path.write_text(cell(cell_text) if cell else cell_text)
    return path


def zed_cell(tmp_path: Path, ros2_endpoint: str) -> Path:
    """configs/cell_ros2_zed.toml with absolute paths and the ROS 2 session on ``ros2_endpoint``."""
    text = (CONFIGS / "cell_ros2_zed.toml").read_text()
    for old, new in (
        ('model = "robots/', f'model = "{CONFIGS}/robots/'),
        ('program = "programs/', f'program = "{CONFIGS}/programs/'),
        ('scenarios_dir = "scenarios"', f'scenarios_dir = "{CONFIGS}/scenarios"'),
        ('pfl_body_regions = "body_regions.toml"', f'pfl_body_regions = "{CONFIGS}/body_regions.toml"'),
        ('listen = ["tcp/127.0.0.1:7449"]', f'listen = ["{ros2_endpoint}"]'),
    ):
        assert old in text, f"{old!r} not in cell_ros2_zed.toml: the test is out of date"
        text = text.replace(old, new)
    path = tmp_path / "cell_ros2_zed.toml"
    path.write_text(text)
    return path


def open_panda_cell(tmp_path: Path) -> Path:
    """configs/cell_two_arms.toml with absolute paths and the Panda's controller open (``control = "open"``)."""
    text = (CONFIGS / "cell_two_arms.toml").read_text()
    for old, new in (
        ('model = "robots/', f'model = "{CONFIGS}/robots/'),
        ('program = "programs/', f'program = "{CONFIGS}/programs/'),
        ('scenarios_dir = "scenarios"', f'scenarios_dir = "{CONFIGS}/scenarios"'),
        ("[robots.panda.controller]\n", '[robots.panda.controller]\ncontrol = "open"\n'),
    ):
        assert old in text, f"{old!r} not in cell_two_arms.toml: the test is out of date"
        text = text.replace(old, new)
    path = tmp_path / "cell_open_panda.toml"
    path.write_text(text)
    return path
