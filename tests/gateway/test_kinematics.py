"""The chain extracted from Pinocchio for the compiled kinematics: its layout on the UR5, known answers of the
compiled link kinematics, and its velocities against finite differences (the Pinocchio comparison is in
test_kernels.py)."""

from __future__ import annotations

import numpy as np
import pytest

from gateway import kernels
from gateway.kinematics import REVOLUTE, kinematic_chain
from hrc_devices.robots.model import RobotModel


def test_ur5_chain_layout(ur5: RobotModel) -> None:
    """A serial arm of six revolute joints; 7 links over 8 distinct frames (consecutive links share one)."""
    chain = kinematic_chain(ur5)
    assert chain.parent.tolist() == [-1, 0, 1, 2, 3, 4, 5]
    assert chain.kind.tolist() == [0] + [REVOLUTE] * 6
    assert chain.index_v.tolist() == [-1, 0, 1, 2, 3, 4, 5]
    # joint 0 (the universe) carries the base pose
    np.testing.assert_array_equal(chain.R_parent_joint[0], ur5.R_world_base)
    np.testing.assert_array_equal(chain.p_parent_joint[0], ur5.p_world_base)
    # shoulder_pan about z, shoulder_lift about y (UR5 URDF)
    np.testing.assert_array_equal(chain.axis_joint[1:3], [[0, 0, 1], [0, 1, 0]])
    assert chain.link_end_frame.shape == (7, 2)
    assert len(chain.frame_joint) == 8
    np.testing.assert_array_equal(chain.link_end_frame[1:, 0], chain.link_end_frame[:-1, 1])
    for array in chain:
        assert array.flags.c_contiguous
        assert array.flags.writeable


def test_ur5_zero_configuration_known_answer(ur5: RobotModel) -> None:
    """At q = 0 the UR5 is stretched along +x on its 0.8 m pedestal (DH: a2 = 0.425, a3 = 0.39225, d1 = 0.089159,
    d4 = 0.10915, d5 = 0.09465, d6 = 0.0823). Turning the base at 1 rad/s moves tool0 at ω × r."""
    links, speed_mps = kernels.link_kinematics(kinematic_chain(ur5), np.zeros(6), np.array([1.0, 0, 0, 0, 0, 0]))
    np.testing.assert_allclose(links.p_a_world[0], [0, 0, 0.8], atol=1e-12)
    tool0 = np.array([0.81725, 0.10915 + 0.0823, 0.8 + 0.089159 - 0.09465])
    np.testing.assert_allclose(links.p_b_world[-1], tool0, atol=1e-9)
    np.testing.assert_allclose(links.v_b_world[-1], [-tool0[1], tool0[0], 0.0], atol=1e-9)
    np.testing.assert_allclose(links.v_a_world[0], 0.0, atol=1e-12)
    assert speed_mps == pytest.approx(np.hypot(tool0[0], tool0[1]), abs=1e-9)


def test_compiled_velocities_equal_finite_differences(ur5: RobotModel) -> None:
    chain = kinematic_chain(ur5)
    rng = np.random.default_rng(31)
    h = 1e-6
    for _ in range(25):
        q, qd = rng.uniform(-np.pi, np.pi, 6), rng.uniform(-2.0, 2.0, 6)
        links, _ = kernels.link_kinematics(chain, q, qd)
        plus, _ = kernels.link_kinematics(chain, q + h * qd, np.zeros(6))
        minus, _ = kernels.link_kinematics(chain, q - h * qd, np.zeros(6))
        np.testing.assert_allclose(links.v_a_world, (plus.p_a_world - minus.p_a_world) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(links.v_b_world, (plus.p_b_world - minus.p_b_world) / (2 * h), atol=1e-7)
