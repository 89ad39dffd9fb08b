"""The robots as the tracker emulator's sensors see them: link capsules from the true joint positions.

The link end points come from the auditor's forward kinematics
(:func:`hrc_devices.robots.link_motion.link_motion`, Pinocchio on
the URDF the cell names), the radii from the robot model; no gateway code. The process learns the joint positions
from the controller emulators' ground truth (``hrc/<cell>/truth/robot/<robot>/state``, :class:`RobotPoses`); the
simulated cell passes its controllers' true positions.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable, Mapping
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from hrc_contract import keys
from hrc_contract.messages import JointState, MessageError, parse_message
from hrc_devices.robots.link_motion import link_motion
from hrc_devices.robots.model import RobotModel
from tracker_emu.occlusion import Blockers, join_blockers

FloatArray = npt.NDArray[np.float64]


class RobotAt(NamedTuple):
    """A robot at one configuration: its model, Pinocchio scratch data and joint positions [rad]."""

    robot: RobotModel
    data: Any
    q_rad: FloatArray


def link_capsules(robot: RobotModel, data: Any, q_rad: FloatArray) -> Blockers:
    """The link capsules of one robot at joint positions ``q_rad`` [rad], world frame [m].

    Args:
        robot: the robot model (link frames and radii, base pose).
        data: Pinocchio data of ``robot.model`` (scratch space, overwritten).
        q_rad: joint positions, shape (nq,) [rad].
    """
    q = np.asarray(q_rad, dtype=float)
    motion = link_motion(robot, data, q, np.zeros(robot.model.nv))
    return Blockers(motion.p_a_world, motion.p_b_world, np.asarray(robot.link_radius_m, dtype=float))


def robots_capsules(robots: Iterable[RobotAt]) -> Blockers:
    """The link capsules of several robots in one set, world frame [m]."""
    return join_blockers([link_capsules(r.robot, r.data, r.q_rad) for r in robots])


class RobotPoses:
    """The newest true joint positions of each robot of the cell, as the truth joint states deliver them.

    Zenoh callbacks call :meth:`on_truth_state` (validate and store); the emulator's loop reads :meth:`capsules`.
    A message that is not a valid joint state of a robot of the cell, or older than the one kept, is counted in
    ``rejected`` and ignored. A robot whose state never arrived is not in the picture (it hides nothing).

    Args:
        cell: the cell's name.
        robots: the cell's robot models, by name.
    """

    def __init__(self, cell: str, robots: Mapping[str, RobotModel]) -> None:
        self._cell = cell
        self._robots = dict(robots)
        self._data = {name: robot.model.createData() for name, robot in robots.items()}
        self._lock = threading.Lock()
        self._latest: dict[str, tuple[int, FloatArray]] = {}
        self.rejected: dict[str, int] = {}

    def _reject(self, reason: str) -> None:
        with self._lock:
            self.rejected[reason] = self.rejected.get(reason, 0) + 1

    def on_truth_state(self, key: str, payload: bytes) -> None:
        """Keep the joint positions of a truth joint state (``hrc/<cell>/truth/robot/<robot>/state``)."""
        robot = keys.name_from_key(key.replace("/truth/", "/", 1), "robot")
        try:
            message = parse_message(payload, JointState)
        except MessageError as exc:
            self._reject(exc.reason)
            return
        if robot not in self._robots or message.robot != robot:
            self._reject("unknown_robot")
            return
        if len(message.q) != self._robots[robot].n_joints:
            self._reject("wrong_length")
            return
        q_rad = np.asarray(message.q, dtype=float)
        with self._lock:
            kept = self._latest.get(robot)
            if kept is not None and message.stamp_ns <= kept[0]:
                self.rejected["old_or_repeated"] = self.rejected.get("old_or_repeated", 0) + 1
                return
            self._latest[robot] = (message.stamp_ns, q_rad)

    def known(self) -> tuple[str, ...]:
        """The robots whose joint positions have arrived."""
        with self._lock:
            return tuple(self._latest)

    def capsules(self) -> Blockers:
        """The link capsules of every robot at its newest known joint positions, world frame [m]."""
        with self._lock:
            latest = {name: q for name, (_, q) in self._latest.items()}
        return robots_capsules(RobotAt(self._robots[n], self._data[n], q) for n, q in latest.items())
