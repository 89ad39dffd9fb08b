"""Robot link segments in the world frame: end points and their velocities from Pinocchio."""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from hrc_common.robot_model import RobotModel

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.intp]


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


@lru_cache(maxsize=64)
def _frame_layout(frame_a_ids: tuple[int, ...], frame_b_ids: tuple[int, ...]) -> tuple[tuple[int, ...], IntArray]:
    """The distinct frames of the link ends, and where each link end is in ``[positions; velocities]`` of them.

    Consecutive links share a frame (one link's end b is the next one's end a), so a serial arm has
    L + 1 distinct frames for 2 L link ends.
    """
    frames = tuple(dict.fromkeys(frame_a_ids + frame_b_ids))
    row = {frame: k for k, frame in enumerate(frames)}
    a_rows = [row[f] for f in frame_a_ids]
    b_rows = [row[f] for f in frame_b_ids]
    n = len(frames)
    gather = np.array([a_rows, b_rows, [n + k for k in a_rows], [n + k for k in b_rows]], dtype=np.intp)
    gather.flags.writeable = False
    return frames, gather


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
