"""Robot link segments in the world frame: end points and their velocities from Pinocchio."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from hrc_common.robot_model import RobotModel

FloatArray = npt.NDArray[np.float64]


class LinkKinematics(NamedTuple):
    """End points of every link segment and their velocities, world frame.

    Attributes:
        p_a_world, p_b_world: segment end points, shape (L, 3) [m].
        v_a_world, v_b_world: end point velocities J_a q̇, J_b q̇, shape (L, 3) [m/s].
    """

    p_a_world: FloatArray
    p_b_world: FloatArray
    v_a_world: FloatArray
    v_b_world: FloatArray


def link_kinematics(robot: RobotModel, data: pin.Data, q_rad: FloatArray, qd_radps: FloatArray) -> LinkKinematics:
    """Positions and velocities of the link end frames for joint positions ``q_rad`` and velocities ``qd_radps``.

    The velocity of a frame origin is the linear part of its LOCAL_WORLD_ALIGNED spatial velocity,
    i.e. ``J_frame q̇`` with the frame's world-aligned position Jacobian (safety-math.md §2).
    """
    model = robot.model
    pin.forwardKinematics(model, data, q_rad, qd_radps)
    pin.updateFramePlacements(model, data)
    n = len(robot.frame_a_ids)
    p = np.empty((2, n, 3))
    v = np.empty((2, n, 3))
    for end, ids in enumerate((robot.frame_a_ids, robot.frame_b_ids)):
        for i, frame_id in enumerate(ids):
            p[end, i] = data.oMf[frame_id].translation
            v[end, i] = pin.getFrameVelocity(model, data, frame_id, pin.LOCAL_WORLD_ALIGNED).linear
    rotation, translation = robot.R_world_base, robot.p_world_base
    p_world = p @ rotation.T + translation
    v_world = v @ rotation.T
    return LinkKinematics(p_world[0], p_world[1], v_world[0], v_world[1])
