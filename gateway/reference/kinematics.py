"""Link-end kinematics asked of Pinocchio.

The reference of :func:`gateway.kernels.link_kinematics` (the start-up check and the tests).
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from gateway.kinematics import FloatArray, LinkKinematics, _frame_layout
from hrc_devices.robots.model import RobotModel


def link_kinematics(robot: RobotModel, data: pin.Data, q_rad: FloatArray, qd_radps: FloatArray) -> LinkKinematics:
    """Positions and velocities of the link end frames for joint positions ``q_rad`` and velocities ``qd_radps``.

    The velocity of a frame origin is the linear part of its LOCAL_WORLD_ALIGNED spatial velocity,
    i.e. ``J_frame q̇`` with the frame's world-aligned position Jacobian (safety-math.md §2).
    """
    model = robot.model
    pin.forwardKinematics(model, data, q_rad, qd_radps)
    pin.updateFramePlacements(model, data)
    frames, gather = _frame_layout(robot.frame_a_ids, robot.frame_b_ids)
    # Every access to a Pinocchio object from Python costs ~1 µs: each distinct frame is read once, and the
    # base pose is applied to all of them in one product.
    placements = data.oMf
    base = np.array(
        [placements[f].translation for f in frames]
        + [pin.getFrameVelocity(model, data, f, pin.LOCAL_WORLD_ALIGNED).linear for f in frames]
    )  # (2 F, 3): positions, then velocities, base frame
    world = (base @ robot.R_world_base.T)[gather]  # (4, L, 3)
    world[:2] += robot.p_world_base
    return LinkKinematics(world[0], world[1], world[2], world[3])


def link_speed_max_mps(links: LinkKinematics) -> float:
    """The largest speed of a link end point [m/s]: the reference of the speed :func:`gateway.kernels.link_kinematics`
    returns beside the links."""
    return float(max(np.linalg.norm(links.v_a_world, axis=1).max(), np.linalg.norm(links.v_b_world, axis=1).max()))
