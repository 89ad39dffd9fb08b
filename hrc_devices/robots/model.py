"""A robot of the cell as Pinocchio loads it from its URDF, checked against its configuration."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from hrc_contract.config import ConfigError, Pose, RobotConfig

RIGIDITY_TOLERANCE_M = 1e-6
"""Largest change of a link segment's length over random configurations for it to count as rigid."""


@dataclass(frozen=True)
class RobotModel:
    """Pinocchio model of one robot with the frames and braking times of its link segments.

    Attributes:
        name: robot name in the cell.
        model: Pinocchio model (joint order = configuration order).
        joint_names: names of the configured joints, in configuration order.
        frame_a_ids, frame_b_ids: Pinocchio frame ids of the segment end points, one per link.
        link_names: configured link names.
        link_radius_m: capsule radius of each link [m].
        t_brake_link_s: largest braking time of the joints that move each link, t_b,→i [s].
        braking_time_s: braking time of each joint [s].
        R_world_base, p_world_base: pose of the robot base in the cell's world frame.
        velocity_limit_radps: joint velocity limits from the URDF [rad/s].
    """

    name: str
    model: pin.Model
    joint_names: tuple[str, ...]
    frame_a_ids: tuple[int, ...]
    frame_b_ids: tuple[int, ...]
    link_names: tuple[str, ...]
    link_radius_m: npt.NDArray[np.float64]
    t_brake_link_s: npt.NDArray[np.float64]
    braking_time_s: npt.NDArray[np.float64]
    R_world_base: npt.NDArray[np.float64]
    p_world_base: npt.NDArray[np.float64]
    velocity_limit_radps: npt.NDArray[np.float64]

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)


def pose_to_rotation_translation(pose: Pose) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    rotation = pin.rpy.rpyToMatrix(*pose.rpy)
    return np.asarray(rotation, dtype=float), np.asarray(pose.xyz, dtype=float)


def _frame_id(model: pin.Model, frame: str, robot: str, link: str) -> int:
    if not model.existFrame(frame):
        frames = ", ".join(f.name for f in model.frames)
        raise ConfigError(f"robot {robot!r}, link {link!r}: frame {frame!r} is not in the URDF; allowed: {frames}")
    return int(model.getFrameId(frame))


def _supporting_joints(model: pin.Model, frame_id: int) -> list[int]:
    """Pinocchio joint ids (>0) that move the given frame."""
    return [int(j) for j in model.supports[model.frames[frame_id].parentJoint] if j > 0]


def _check_rigid(model: pin.Model, robot: str, names: list[str], pairs: list[tuple[int, int]]) -> None:
    data = model.createData()
    lengths = []
    for _ in range(8):
        q = pin.randomConfiguration(model, -np.pi * np.ones(model.nq), np.pi * np.ones(model.nq))
        pin.framesForwardKinematics(model, data, q)
        lengths.append([np.linalg.norm(data.oMf[a].translation - data.oMf[b].translation) for a, b in pairs])
    spread = np.ptp(np.asarray(lengths), axis=0)
    for name, s in zip(names, spread, strict=True):
        if s > RIGIDITY_TOLERANCE_M:
            raise ConfigError(
                f"robot {robot!r}, link {name!r}: frame_a and frame_b are not fixed on one rigid body "
                f"(their distance changes by {s:.3f} m); allowed: two frames of the same body"
            )


def load_robot_model(name: str, config: RobotConfig) -> RobotModel:
    """Load the URDF with Pinocchio and check the configured joints and link frames against it.

    Raises:
        ConfigError: the URDF cannot be parsed, a joint or frame is not in it, or a link segment
            is not rigid.
    """
    try:
        model = pin.buildModelFromUrdf(config.model.urdf)
    except (RuntimeError, ValueError) as exc:
        raise ConfigError(f"robot {name!r}: cannot load URDF {config.model.urdf}: {exc}") from None
    urdf_joints = [model.names[j] for j in range(1, model.njoints)]
    if list(config.model.joints) != urdf_joints or model.nq != model.nv or model.nq != len(urdf_joints):
        raise ConfigError(
            f"robot {name!r}: joints {list(config.model.joints)} do not match the URDF; allowed: "
            f"{urdf_joints} (revolute or prismatic joints, in this order)"
        )
    links = config.model.links
    a_ids = [_frame_id(model, link.frame_a, name, link.name) for link in links]
    b_ids = [_frame_id(model, link.frame_b, name, link.name) for link in links]
    _check_rigid(model, name, [link.name for link in links], list(zip(a_ids, b_ids, strict=True)))
    braking = np.asarray(config.model.braking_time_s, dtype=float)
    t_brake_link = []
    for a, b in zip(a_ids, b_ids, strict=True):
        joints = set(_supporting_joints(model, a)) | set(_supporting_joints(model, b))
        # Joint id j (1-based in Pinocchio) has configuration index j - 1 for a serial arm of 1-DoF joints.
        t_brake_link.append(max((braking[j - 1] for j in joints), default=0.0))
    rotation, translation = pose_to_rotation_translation(config.base_pose_world)
    return RobotModel(
        name=name,
        model=model,
        joint_names=tuple(urdf_joints),
        frame_a_ids=tuple(a_ids),
        frame_b_ids=tuple(b_ids),
        link_names=tuple(link.name for link in links),
        link_radius_m=np.asarray([link.radius_m for link in links], dtype=float),
        t_brake_link_s=np.asarray(t_brake_link, dtype=float),
        braking_time_s=braking,
        R_world_base=rotation,
        p_world_base=translation,
        velocity_limit_radps=np.asarray(model.velocityLimit, dtype=float).copy(),
    )
