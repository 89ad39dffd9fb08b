"""Known cases of Universal Robots' RTDE, shared by the tests of the emulator's RTDE face.

* ``UR_RTDE_DEFAULT_OUTPUTS``: the output recipe ur-rtde 1.6.5's ``RTDEReceiveInterface(host, 500.0)`` sends without
  a variable list to a controller answering version 5.11.0.0 (captured from its ``O`` message on loopback, in order,
  its trailing comma dropped);
* ``ur5_flange_in_base``: the UR5's tool flange in the controller's base frame from UR's published DH parameters
  (independent of the URDF and of Pinocchio): what a UR5 with no TCP offset reports as ``actual_TCP_pose``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import numpy.typing as npt

UR_RTDE_DEFAULT_OUTPUTS = (
    "timestamp",
    "target_q",
    "target_qd",
    "target_qdd",
    "target_current",
    "target_moment",
    "actual_q",
    "actual_qd",
    "actual_current",
    "joint_control_output",
    "actual_TCP_pose",
    "actual_TCP_speed",
    "actual_TCP_force",
    "target_TCP_pose",
    "target_TCP_speed",
    "actual_digital_input_bits",
    "joint_temperatures",
    "actual_execution_time",
    "robot_mode",
    "joint_mode",
    "safety_mode",
    "actual_tool_accelerometer",
    "speed_scaling",
    "target_speed_fraction",
    "actual_momentum",
    "actual_main_voltage",
    "actual_robot_voltage",
    "actual_robot_current",
    "actual_joint_voltage",
    "actual_digital_output_bits",
    "runtime_state",
    "standard_analog_input0",
    "standard_analog_input1",
    "standard_analog_output0",
    "standard_analog_output1",
    "robot_status_bits",
    "safety_status_bits",
    "ft_raw_wrench",
    "payload",
    "payload_cog",
    "payload_inertia",
    "output_int_register_2",
    *(f"output_int_register_{i}" for i in range(12, 20)),
    *(f"output_double_register_{i}" for i in range(12, 20)),
)

# UR5 (CB3) standard DH parameters as Universal Robots publishes them [m, rad].
UR5_DH_D_M = (0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823)
UR5_DH_A_M = (0.0, -0.425, -0.39225, 0.0, 0.0, 0.0)
UR5_DH_ALPHA_RAD = (math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0)

UR5_FLANGE_AT_ZERO = (-0.81725, -0.19145, -0.005491)
"""The flange's position at q = 0 [m]: (a2 + a3, −(d4 + d6), d1 − d5)."""


def ur5_flange_in_base(q_rad: Sequence[float]) -> npt.NDArray[np.float64]:
    """The flange's homogeneous transform in the base frame at joints ``q_rad`` (standard DH: Rz θ, Tz d, Tx a,
    Rx α per joint)."""
    transform = np.eye(4)
    for theta, d, a, alpha in zip(q_rad, UR5_DH_D_M, UR5_DH_A_M, UR5_DH_ALPHA_RAD, strict=True):
        ct, st, ca, sa = math.cos(theta), math.sin(theta), math.cos(alpha), math.sin(alpha)
        transform = transform @ np.array(
            [[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st], [0.0, sa, ca, d], [0.0, 0.0, 0.0, 1.0]]
        )
    return transform


def rotation_of(rotation_vector: Sequence[float]) -> npt.NDArray[np.float64]:
    """The rotation matrix of a rotation vector (axis × angle [rad], Rodrigues)."""
    r = np.asarray(rotation_vector, dtype=float)
    angle = float(np.linalg.norm(r))
    if angle == 0.0:
        return np.eye(3)
    k = r / angle
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(angle) * cross + (1.0 - math.cos(angle)) * cross @ cross
