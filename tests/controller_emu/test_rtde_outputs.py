"""The RTDE face's output table and values: known answers from UR's DH parameters, the table against the codec's
types, invariants over seeded random joints, and the pre-built packages against the codec's own encoder."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from support.ur_rtde_cases import (
    UR5_FLANGE_AT_ZERO,
    UR_RTDE_DEFAULT_OUTPUTS,
    rotation_of,
    ur5_flange_in_base,
)

from controller_emu.node import ControllerNode
from controller_emu.rtde_outputs import (
    OUTPUTS,
    ArmModel,
    DataPacker,
    is_read_back,
    joint_acceleration,
    output_values,
    snapshot,
)
from hrc_contract.config import CellConfig, ConfigError, ControllerConfig
from hrc_contract.messages import Override, to_payload
from hrc_devices.controllers.ur_rtde import codec as rtde
from hrc_devices.controllers.ur_rtde.codec import Recipe
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def node(cell_config: CellConfig, ur5: RobotModel) -> ControllerNode:
    trajectory = load_trajectory(cell_config.robots["ur5"].program, ur5)
    return ControllerNode("ur5", trajectory, ControllerConfig(watchdog_s=0.1))


def _at(t_s: float) -> Clocks:
    return Clocks(wall_ns=1_700_000_000_000_000_000 + round(t_s * 1e9), mono_ns=1_000_000_000 + round(t_s * 1e9))


# -- the table ---------------------------------------------------------------------------------------------------------


def test_the_table_serves_exactly_the_codecs_fixed_names() -> None:
    assert set(OUTPUTS) == set(rtde.OUTPUT_TYPES)


def test_every_constant_packs_as_its_type() -> None:
    names = tuple(name for name, out in OUTPUTS.items() if out.source in ("constant", "inputs"))
    recipe = Recipe(1, names, tuple(rtde.OUTPUT_TYPES[n] for n in names))
    values = tuple(OUTPUTS[n].value for n in names)
    assert rtde.decode_data(recipe, rtde.encode_data(recipe, values)) == values
    assert all(OUTPUTS[n].why for n in OUTPUTS)


def test_state_and_model_rows_are_the_names_their_functions_compute(node: ControllerNode, ur5: RobotModel) -> None:
    output = node.cycle(_at(0.0))
    state = {name for name, out in OUTPUTS.items() if out.source == "state"}
    model = {name for name, out in OUTPUTS.items() if out.source == "model"}
    assert set(output_values(output, 0.5, 0.0)) | {"target_qdd"} == state
    assert set(ArmModel(ur5).values((0.0,) * 6, (0.0,) * 6, (0.0,) * 6)) == model


def test_only_registers_are_read_back() -> None:
    assert is_read_back("input_int_register_23")
    assert is_read_back("input_bit_registers0_to_31")
    assert not is_read_back("speed_slider_fraction")
    assert not is_read_back("standard_digital_output")


# -- the model's values ------------------------------------------------------------------------------------------------


def test_tcp_at_zero_is_the_flange_of_urs_dh_parameters(ur5: RobotModel) -> None:
    values = ArmModel(ur5).values((0.0,) * 6, (0.0,) * 6, (0.0,) * 6)
    pose = values["actual_TCP_pose"]
    assert pose[:3] == pytest.approx(UR5_FLANGE_AT_ZERO, abs=1e-9)
    assert rotation_of(pose[3:]) == pytest.approx(ur5_flange_in_base((0.0,) * 6)[:3, :3], abs=1e-9)
    assert values["actual_TCP_speed"] == (0.0,) * 6
    assert values["actual_momentum"] == (0.0,)


def test_at_rest_the_accelerometer_shows_gravity_and_the_moments_hold_the_arm(ur5: RobotModel) -> None:
    q = (0.3, -1.2, 1.4, -0.5, 1.2, 0.4)
    values = ArmModel(ur5).values(q, (0.0,) * 6, (0.0,) * 6)
    R_base_flange = ur5_flange_in_base(q)[:3, :3]  # the base's z is up: the robot stands on the floor
    assert values["actual_tool_accelerometer"] == pytest.approx(R_base_flange.T @ (0.0, 0.0, 9.81), abs=1e-9)
    gravity = pin.computeGeneralizedGravity(ur5.model, ur5.model.createData(), np.asarray(q))
    assert values["target_moment"] == pytest.approx(gravity, abs=1e-9)
    assert values["target_moment"][0] == pytest.approx(0.0, abs=1e-9)  # the base joint's axis is vertical


def test_a_robot_hung_upside_down_feels_gravity_the_other_way(cell_config: CellConfig) -> None:
    config = cell_config.robots["ur5"]
    upright = load_robot_model("ur5", config)
    hung = replace(upright, R_world_base=np.diag([1.0, -1.0, -1.0]))  # turned by π about x
    q = (0.0, -1.57, 0.0, -1.57, 0.0, 0.0)
    down = ArmModel(upright).values(q, (0.0,) * 6, (0.0,) * 6)["actual_tool_accelerometer"]
    up = ArmModel(hung).values(q, (0.0,) * 6, (0.0,) * 6)["actual_tool_accelerometer"]
    assert up == pytest.approx(tuple(-a for a in down), abs=1e-9)


def test_speeds_are_the_derivatives_of_the_poses_over_seeded_random_motions(ur5: RobotModel) -> None:
    arm = ArmModel(ur5)
    rng = np.random.default_rng(34)
    h = 1e-6
    for _ in range(20):
        q, qd = rng.uniform(-3.0, 3.0, 6), rng.uniform(-1.0, 1.0, 6)
        values = arm.values(tuple(q), tuple(qd), (0.0,) * 6)
        ahead, behind = ur5_flange_in_base(q + h * qd), ur5_flange_in_base(q - h * qd)
        linear = (ahead[:3, 3] - behind[:3, 3]) / (2 * h)
        omega_hat = (ahead[:3, :3] - behind[:3, :3]) / (2 * h) @ ur5_flange_in_base(q)[:3, :3].T
        angular = (omega_hat[2, 1], omega_hat[0, 2], omega_hat[1, 0])
        assert values["actual_TCP_speed"] == pytest.approx((*linear, *angular), abs=1e-6)
        assert rotation_of(values["actual_TCP_pose"][3:]) == pytest.approx(ur5_flange_in_base(q)[:3, :3], abs=1e-9)
        elbow_ahead = arm.values(tuple(q + h * qd), (0.0,) * 6, (0.0,) * 6)["elbow_position"]
        elbow_behind = arm.values(tuple(q - h * qd), (0.0,) * 6, (0.0,) * 6)["elbow_position"]
        elbow_rate = (np.asarray(elbow_ahead) - np.asarray(elbow_behind)) / (2 * h)
        assert values["elbow_velocity"] == pytest.approx(elbow_rate, abs=1e-6)
        assert values["actual_momentum"][0] > 0.0


def test_an_arm_without_urs_frames_is_refused() -> None:
    config = load_cell_config(ROOT / "configs" / "cell_two_arms.toml")
    panda = load_robot_model("panda", config.robots["panda"])
    with pytest.raises(ConfigError, match="'base' and 'tool0'"):
        ArmModel(panda)


# -- one cycle's values and the packages ------------------------------------------------------------------------------


def test_target_qdd_is_the_change_of_qd_over_the_cycle(node: ControllerNode) -> None:
    previous = node.cycle(_at(0.0))
    assert joint_acceleration(previous, None) == (0.0,) * 6
    accelerating = 0
    for i in range(1, 100):  # an override every cycle: the robot starts, the override and the program ramp up
        now = _at(0.004 * i)
        assert node.on_override(to_payload(Override(robot="ur5", seq=i, stamp_ns=now.wall_ns, delta=1.0)), now) is None
        output = node.cycle(now)
        expected = (np.asarray(output.joint_state.qd) - np.asarray(previous.joint_state.qd)) / 0.004
        qdd = joint_acceleration(output, previous)
        assert qdd == pytest.approx(expected, abs=1e-9)
        accelerating += any(abs(a) > 1e-3 for a in qdd)
        previous = output
    assert accelerating > 10


def test_the_prebuilt_package_is_what_the_codec_encodes(node: ControllerNode, ur5: RobotModel) -> None:
    output = node.cycle(_at(0.0))
    names = (*UR_RTDE_DEFAULT_OUTPUTS, "input_int_register_23", "output_bit_register_64", "safety_status")
    recipe = Recipe(7, names, tuple(rtde.output_type(n) or "" for n in names))
    packer = DataPacker(recipe)
    assert packer.needs_model
    values = snapshot(output, None, 0.5, 1.25, {"input_int_register_23": (22,)}, ArmModel(ur5))
    natural = tuple(values[n] if len(values[n]) > 1 else values[n][0] for n in names)
    assert packer.pack(values) == rtde.pack_message(rtde.MessageType.DATA_PACKAGE, rtde.encode_data(recipe, natural))
    assert packer.size == 4 + recipe.layout.size
    decoded = dict(zip(names, rtde.decode_data(recipe, packer.pack(values)[3:]), strict=True))
    assert decoded["input_int_register_23"] == 22
    assert decoded["timestamp"] == 1.25
    assert decoded["target_speed_fraction"] == 0.5
    assert not DataPacker(Recipe(1, ("timestamp", "actual_q"), ("DOUBLE", "VECTOR6D"))).needs_model


def test_values_do_not_depend_on_the_model_unless_asked(node: ControllerNode, ur5: RobotModel) -> None:
    output = node.cycle(_at(0.0))
    without = snapshot(output, None, 0.0, 0.0, {}, None)
    with_model = snapshot(output, None, 0.0, 0.0, {}, ArmModel(ur5))
    assert "actual_TCP_pose" not in without
    assert {k: v for k, v in with_model.items() if k in without} == without
    assert math.isfinite(with_model["actual_momentum"][0])
