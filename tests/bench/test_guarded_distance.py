"""bench.guarded_distance's second experiment: the elbow-out program and the scenario beside the elbow."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

from bench.guarded_distance import CONFIG, with_program
from gateway.reference.kinematics import link_kinematics
from hrc_devices.robots.model import load_robot_model
from hrc_devices.robots.program import load_trajectory, program_waypoints_rad
from hrc_runtime.config import load_cell_config
from tracker_emu.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]


def test_the_elbow_out_program_holds_its_elbow_toward_the_person_and_its_tool_in_front() -> None:
    """The header's forward kinematics, to the millimetre: the tool at y = 0 in front, the elbow out to +y."""
    config = with_program(load_cell_config(ROOT / CONFIG), "panda_elbow_out")
    program = Path(config.robots["panda"].program)
    assert program.name == "panda_elbow_out.toml"
    robot = load_robot_model("panda", config.robots["panda"])
    load_trajectory(program, robot)  # within the URDF's limits, a valid program for this robot
    data = robot.model.createData()
    tool = robot.model.getFrameId("panda_hand_tcp")
    expected_tool = [(0.450, 0.000, 1.050), (0.650, 0.000, 0.950)]
    expected_elbow = [((-0.044, 0.200, 1.374), (0.038, 0.200, 1.388)), ((0.155, 0.234, 1.277), (0.227, 0.200, 1.256))]
    for q, tool_xyz, (link3_xyz, link4_xyz) in zip(
        program_waypoints_rad(program), expected_tool, expected_elbow, strict=True
    ):
        pin.framesForwardKinematics(robot.model, data, q)
        tool_world = robot.R_world_base @ data.oMf[tool].translation + robot.p_world_base
        assert tool_world == pytest.approx(tool_xyz, abs=1e-3)
        links = link_kinematics(robot, data, q, np.zeros_like(q))
        elbow = robot.link_names.index("elbow")  # the capsule panda_link3 – panda_link4
        assert links.p_a_world[elbow] == pytest.approx(link3_xyz, abs=1e-3)
        assert links.p_b_world[elbow] == pytest.approx(link4_xyz, abs=1e-3)


def test_the_person_beside_the_elbow_stands_nearer_the_elbow_than_the_tools_path() -> None:
    scenario = load_scenario(ROOT / "configs/scenarios/beside_elbow.toml")
    (person,) = scenario.humans
    standing = person.keyframes[1].xy_m
    assert standing == person.keyframes[2].xy_m
    elbow_xy, tool_xy = np.array([0.05, 0.22]), np.array([0.55, 0.0])
    assert np.linalg.norm(np.subtract(standing, elbow_xy)) < np.linalg.norm(np.subtract(standing, tool_xy)) - 0.2


def test_an_unknown_program_is_refused_with_the_ones_there_are() -> None:
    with pytest.raises(SystemExit, match="panda_elbow_out"):
        with_program(load_cell_config(ROOT / CONFIG), "nope")
