"""Robot link segments in the world frame: end points and their velocities.

:func:`link_kinematics` asks Pinocchio (the reference; the auditor uses it). :func:`kinematic_chain` extracts,
once at start-up, the flat description of the same chain that the compiled kinematics of
:mod:`gateway.kernels` runs on every cycle, which is checked against Pinocchio before the gateway starts."""

from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hrc_contract.config import ConfigError
from hrc_devices.robots.model import RobotModel

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


# -- the chain as flat arrays, for the compiled forward kinematics (gateway.kernels) -----------------

FIXED = 0
REVOLUTE = 1
PRISMATIC = 2

_SUPPORTED_JOINTS: dict[str, tuple[int, tuple[float, float, float] | None]] = {
    # Pinocchio joint model → (kind, axis in the joint frame; None: the model's own axis)
    "JointModelRX": (REVOLUTE, (1.0, 0.0, 0.0)),
    "JointModelRY": (REVOLUTE, (0.0, 1.0, 0.0)),
    "JointModelRZ": (REVOLUTE, (0.0, 0.0, 1.0)),
    "JointModelRevoluteUnaligned": (REVOLUTE, None),
    "JointModelPX": (PRISMATIC, (1.0, 0.0, 0.0)),
    "JointModelPY": (PRISMATIC, (0.0, 1.0, 0.0)),
    "JointModelPZ": (PRISMATIC, (0.0, 0.0, 1.0)),
    "JointModelPrismaticUnaligned": (PRISMATIC, None),
}


class KinematicChain(NamedTuple):
    """One robot's kinematic tree and link-end frames as flat arrays (extracted once from the Pinocchio model).

    Index 0 of the joint arrays is Pinocchio's universe joint, which here carries the robot's base pose, so
    that everything the compiled kinematics returns is in the world frame.

    Attributes:
        parent: parent joint of each joint, shape (J,); -1 for the universe.
        kind: ``FIXED`` (the universe), ``REVOLUTE`` or ``PRISMATIC``, shape (J,).
        index_v: index of each joint in q and q̇, shape (J,); -1 for the universe.
        R_parent_joint: rotation of each joint's placement in its parent joint's frame (``model.jointPlacements``),
            shape (J, 3, 3); the universe's is R_world_base.
        p_parent_joint: translation of that placement, shape (J, 3) [m]; the universe's is p_world_base.
        axis_joint: unit axis of each joint in its own frame, shape (J, 3).
        frame_joint: joint each distinct link-end frame is fixed to, shape (F,).
        p_joint_frame: origin of each distinct link-end frame in its joint's frame, shape (F, 3) [m].
        link_end_frame: index into the distinct frames of each link's end a and end b, shape (L, 2).
    """

    parent: IntArray
    kind: IntArray
    index_v: IntArray
    R_parent_joint: FloatArray
    p_parent_joint: FloatArray
    axis_joint: FloatArray
    frame_joint: IntArray
    p_joint_frame: FloatArray
    link_end_frame: IntArray


def _joint_kind_and_axis(robot: RobotModel, joint_id: int) -> tuple[int, FloatArray]:
    joint = robot.model.joints[joint_id]
    shortname = str(joint.shortname())
    if shortname not in _SUPPORTED_JOINTS:
        raise ConfigError(
            f"robot {robot.name!r}: joint {robot.model.names[joint_id]!r} is a {shortname}, which the gateway's "
            f"kinematics does not support; allowed: {', '.join(_SUPPORTED_JOINTS)}"
        )
    kind, axis = _SUPPORTED_JOINTS[shortname]
    axis_joint = np.asarray(joint.extract().axis if axis is None else axis, dtype=float)
    norm = float(np.linalg.norm(axis_joint))
    if not abs(norm - 1.0) < 1e-12:
        raise ConfigError(
            f"robot {robot.name!r}: joint {robot.model.names[joint_id]!r} has an axis of norm {norm}; "
            "allowed: unit axes"
        )
    return kind, axis_joint


def kinematic_chain(robot: RobotModel) -> KinematicChain:
    """The chain of ``robot`` for :func:`gateway.kernels.link_kinematics` (start-up only).

    Raises:
        ConfigError: a joint is not a 1-DoF revolute or prismatic joint (about x, y, z or an unaligned axis).
    """
    model = robot.model
    n_joints = int(model.njoints)
    parent = np.full(n_joints, -1, dtype=np.intp)
    kind = np.full(n_joints, FIXED, dtype=np.intp)
    index_v = np.full(n_joints, -1, dtype=np.intp)
    R_parent_joint = np.empty((n_joints, 3, 3))
    p_parent_joint = np.empty((n_joints, 3))
    axis_joint = np.zeros((n_joints, 3))
    R_parent_joint[0] = robot.R_world_base
    p_parent_joint[0] = robot.p_world_base
    for j in range(1, n_joints):
        kind[j], axis_joint[j] = _joint_kind_and_axis(robot, j)
        parent[j] = int(model.parents[j])
        index_v[j] = int(model.joints[j].idx_v)
        placement = model.jointPlacements[j]
        R_parent_joint[j] = placement.rotation
        p_parent_joint[j] = placement.translation
    frames, _ = _frame_layout(robot.frame_a_ids, robot.frame_b_ids)
    row = {frame: k for k, frame in enumerate(frames)}
    return KinematicChain(
        parent=parent,
        kind=kind,
        index_v=index_v,
        R_parent_joint=R_parent_joint,
        p_parent_joint=p_parent_joint,
        axis_joint=axis_joint,
        frame_joint=np.array([int(model.frames[f].parentJoint) for f in frames], dtype=np.intp),
        p_joint_frame=np.array([np.asarray(model.frames[f].placement.translation) for f in frames]).reshape(-1, 3),
        link_end_frame=np.array(
            [[row[a], row[b]] for a, b in zip(robot.frame_a_ids, robot.frame_b_ids, strict=True)], dtype=np.intp
        ).reshape(-1, 2),
    )
