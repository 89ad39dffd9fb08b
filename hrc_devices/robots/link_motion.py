"""The auditor's own link kinematics: end points and velocities of the link segments, from Pinocchio directly.

Independent of the gateway (safety-math.md §9): no code of ``gateway`` is used, only the URDF model that
:class:`hrc_devices.robots.model.RobotModel` loaded. Positions come from forward kinematics
(``data.oMf`` after :func:`pinocchio.updateFramePlacements`), velocities from the frame Jacobians,
``v = J_frame q̇`` with the LOCAL_WORLD_ALIGNED Jacobian (the velocity of the frame's origin in world-aligned
axes, safety-math.md §2); both are then moved from the robot's base frame to the cell's world frame.
"""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from hrc_devices.robots.model import RobotModel

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


class LinkMotion(NamedTuple):
    """End points of every link segment and their velocities, world frame.

    Attributes:
        p_a_world, p_b_world: segment end points (the origins of ``frame_a`` and ``frame_b``), shape (L, 3) [m].
        v_a_world, v_b_world: velocities of those end points, ``J_a q̇`` and ``J_b q̇``, shape (L, 3) [m/s].
    """

    p_a_world: FloatArray
    p_b_world: FloatArray
    v_a_world: FloatArray
    v_b_world: FloatArray


class _FrameLayout(NamedTuple):
    frames: tuple[int, ...]
    """The distinct frames of the link ends (a serial arm's links share them: L + 1 frames for 2 L ends)."""
    end_a: IntArray
    """Row of each link's end a among ``frames``, shape (L,)."""
    end_b: IntArray
    """Row of each link's end b among ``frames``, shape (L,)."""


@lru_cache(maxsize=64)
def _frame_layout(frame_a_ids: tuple[int, ...], frame_b_ids: tuple[int, ...]) -> _FrameLayout:
    frames = tuple(dict.fromkeys(frame_a_ids + frame_b_ids))
    row = {frame: k for k, frame in enumerate(frames)}
    end_a = np.array([row[f] for f in frame_a_ids], dtype=np.intp)
    end_b = np.array([row[f] for f in frame_b_ids], dtype=np.intp)
    end_a.flags.writeable = False
    end_b.flags.writeable = False
    return _FrameLayout(frames, end_a, end_b)


def link_motion(robot: RobotModel, data: pin.Data, q_rad: FloatArray, qd_radps: FloatArray) -> LinkMotion:
    """Positions and velocities of the link end frames for joint positions ``q_rad`` and velocities ``qd_radps``.

    Args:
        robot: the robot model (link frames, base pose).
        data: Pinocchio data of ``robot.model`` (scratch space, overwritten).
        q_rad: joint positions, shape (nq,) [rad].
        qd_radps: joint velocities, shape (nv,) [rad/s].

    Returns:
        The link end points [m] and their velocities [m/s] in the cell's world frame.
    """
    model = robot.model
    pin.computeJointJacobians(model, data, q_rad)  # forward kinematics and the joint Jacobians
    pin.updateFramePlacements(model, data)
    layout = _frame_layout(robot.frame_a_ids, robot.frame_b_ids)
    placements = data.oMf
    p_base = np.array([placements[f].translation for f in layout.frames])  # (F, 3)
    # The translational rows of every frame's Jacobian stacked: (3 F, nv) @ q̇ gives all frame velocities at once.
    jacobians = np.concatenate(
        [pin.getFrameJacobian(model, data, f, pin.LOCAL_WORLD_ALIGNED)[:3] for f in layout.frames]
    )
    v_base = (jacobians @ qd_radps).reshape(-1, 3)  # (F, 3)
    p_world = p_base @ robot.R_world_base.T + robot.p_world_base
    v_world = v_base @ robot.R_world_base.T
    return LinkMotion(p_world[layout.end_a], p_world[layout.end_b], v_world[layout.end_a], v_world[layout.end_b])
