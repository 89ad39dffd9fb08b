"""An open robot and its gateway in one process, in simulated time: the real GatewayNode (door, tracks, core, LPs)
fed every 4 ms with the joint state of a follower that applies the newest joint command as an open controller does
(EGM's law: speedRef + gain · (reference − position), its acceleration bounded by q̇max / t_b per joint), and with
tracker frames of people standing or walking. For tests of the open mode's behaviour and its rows; the processes,
Zenoh and the emulator's own follower are tested end to end elsewhere."""

from __future__ import annotations

import itertools
import json
from collections.abc import Callable
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from gateway.core import RobotDecision
from gateway.node import GatewayNode
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.humans import NO_HUMANS, HumanCapsules
from hrc_contract.messages import JointCommand, Override
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config

FloatArray = npt.NDArray[np.float64]
MS = 1_000_000
CYCLE_NS = 4 * MS
WALL0_NS = 1_790_000_000_000_000_000
MONO0_NS = 3_000_000_000
FOLLOWER_GAIN_PER_S = 20.0


def clocks(t_ns: int) -> Clocks:
    return Clocks(WALL0_NS + t_ns, MONO0_NS + t_ns)


class Step(NamedTuple):
    """One cycle: the decision, the command sent (None before the first joint state), the measured state."""

    t_s: float
    decision: RobotDecision
    command: JointCommand | None
    q_rad: FloatArray
    qd_radps: FloatArray
    people: HumanCapsules = NO_HUMANS
    """The people the decision kept clear of (seen and lost, grown)."""


class OpenCell:
    """``configs/cell_open_panda.toml`` (or ``config``) with a simulated open controller; ``closed=True``: the same
    robot behind a closed controller (it runs the program and applies the override with its ramps), to compare."""

    def __init__(self, config: CellConfig | None = None, robot_name: str = "panda", closed: bool = False) -> None:
        config = config or load_cell_config("configs/cell_open_panda.toml")
        if closed:
            robot_config = config.robots[robot_name]
            controller = robot_config.controller.model_copy(update={"control": "closed"})
            robots = {**config.robots, robot_name: robot_config.model_copy(update={"controller": controller})}
            config = config.model_copy(update={"robots": robots})
        self.config = config
        self.closed = closed
        self.name = robot_name
        self.robot: RobotModel = load_robot_model(robot_name, self.config.robots[robot_name])
        self.node = GatewayNode(self.config, {robot_name: self.robot})
        trajectory = load_trajectory(self.config.robots[robot_name].program, self.robot)
        self.trajectory = trajectory
        self.tau_s = 0.0
        self.applied = 0.0
        self.override: Override | None = None
        self.q, _ = trajectory.sample(0.0)
        self.q = np.array(self.q, dtype=float)
        self.qd = np.zeros_like(self.q)
        self.qd_nominal = np.zeros_like(self.q)
        self.qd_max = np.asarray(self.robot.velocity_limit_radps, dtype=float)
        self.qdd_max = self.qd_max / np.asarray(self.robot.braking_time_s, dtype=float)
        self.command: JointCommand | None = None
        self.t_ns = 0
        self.joint_seq = 0
        self.human_seq = 0
        self.silent_joint_states = False

    def _follow(self, dt_s: float) -> None:
        if self.closed:
            controller = self.config.robots[self.name].controller
            target = 0.0 if self.override is None else self.override.delta
            step = dt_s / (controller.braking_time_s if target < self.applied else controller.accel_time_s)
            self.applied += float(np.clip(target - self.applied, -step, step))
            self.tau_s += dt_s * self.applied
            q, qd_nominal = self.trajectory.sample(self.tau_s)
            self.q, self.qd, self.qd_nominal = (
                np.array(q),
                self.applied * np.asarray(qd_nominal),
                np.asarray(qd_nominal),
            )
            return
        if self.command is None:
            wish = np.zeros_like(self.q)
        else:
            wish = np.asarray(self.command.qd) + FOLLOWER_GAIN_PER_S * (np.asarray(self.command.q) - self.q)
        wish = np.clip(wish, -self.qd_max, self.qd_max)
        self.qd = self.qd + np.clip(wish - self.qd, -self.qdd_max * dt_s, self.qdd_max * dt_s)
        self.q = self.q + self.qd * dt_s

    def _joint_state(self) -> None:
        self.joint_seq += 1
        if self.closed:
            raw = {
                "schema": "hrc.joint_state/1",
                "robot": self.name,
                "seq": self.joint_seq,
                "stamp_ns": WALL0_NS + self.t_ns,
                "q": self.q.tolist(),
                "qd": self.qd.tolist(),
                "qd_nominal": self.qd_nominal.tolist(),
                "override": self.applied,
                "override_seq": -1 if self.override is None else self.override.seq,
                "mode": "running",
            }
            self.node.on_message(
                keys.robot_state(self.config.cell, self.name), json.dumps(raw).encode(), clocks(self.t_ns + MS)
            )
            return
        raw = {
            "schema": "hrc.joint_state/1",
            "robot": self.name,
            "seq": self.joint_seq,
            "stamp_ns": WALL0_NS + self.t_ns,
            "q": self.q.tolist(),
            "qd": self.qd.tolist(),
            "qd_nominal": self.qd.tolist(),  # an open controller: the velocity it has (override 1 while following)
            "override": 1.0,
            "override_seq": -1 if self.command is None else self.command.seq,
            "mode": "running",
        }
        key = keys.robot_state(self.config.cell, self.name)
        self.node.on_message(key, json.dumps(raw).encode(), clocks(self.t_ns + MS))

    def _humans(self, people: list[dict[str, Any]]) -> None:
        self.human_seq += 1
        for tracker in sorted(self.config.trackers):
            raw = {
                "schema": "hrc.humans/1",
                "tracker": tracker,
                "seq": self.human_seq,
                "stamp_ns": WALL0_NS + self.t_ns - 30 * MS,
                "humans": people,
            }
            key = keys.tracker_humans(self.config.cell, tracker)
            self.node.on_message(key, json.dumps(raw).encode(), clocks(self.t_ns))

    def run(
        self,
        duration_s: float,
        people: Callable[[float], list[dict[str, Any]]] = lambda t: [],
        held_up: Callable[[int], bool] = lambda cycle: False,
    ) -> list[Step]:
        """Run for ``duration_s``: people's frames at 33 ms (``people(t)`` → the humans of the frame), a joint state
        and a decision every 4 ms; the follower applies each command from the next cycle on. ``held_up(n)``: the
        gateway's loop misses the decision of cycle ``n`` (counted from 0 in this run; the controller and the
        trackers go on)."""
        steps = []
        end_ns = self.t_ns + round(duration_s * 1e9)
        next_frame_ns = self.t_ns
        for n in itertools.count():
            if self.t_ns >= end_ns:
                break
            self._follow(CYCLE_NS / 1e9)
            self.t_ns += CYCLE_NS
            if self.t_ns >= next_frame_ns:
                self._humans(people(self.t_ns / 1e9))
                next_frame_ns += 33 * MS
            if not self.silent_joint_states:
                self._joint_state()
            if held_up(n):
                continue
            cycle = self.node.cycle(clocks(self.t_ns + 2 * MS), CYCLE_NS / 1e9)
            message = cycle.overrides.get(self.name)
            if isinstance(message, JointCommand):
                self.command = message
            elif isinstance(message, Override):
                self.override = message
            steps.append(
                Step(
                    self.t_ns / 1e9,
                    cycle.decisions[self.name],
                    message if isinstance(message, JointCommand) else None,
                    self.q.copy(),
                    self.qd.copy(),
                    cycle.capsules,
                )
            )
        return steps


def standing_person(
    at_m: tuple[float, float], reach_to_m: tuple[float, float, float] | None = None
) -> list[dict[str, Any]]:
    """One person standing at ``at_m`` (x, y) [m], one arm reaching to ``reach_to_m`` when given."""
    x, y = at_m
    capsules = [
        {"name": "torso", "a": [x, y, 1.0], "b": [x, y, 1.5], "radius": 0.18},
        {"name": "head", "a": [x, y, 1.65], "b": [x, y, 1.75], "radius": 0.11},
        {"name": "legs", "a": [x, y, 0.1], "b": [x, y, 0.95], "radius": 0.15},
    ]
    if reach_to_m is not None:
        capsules.append({"name": "arm", "a": [x, y, 1.4], "b": list(reach_to_m), "radius": 0.06})
    return [{"id": "p1", "capsules": capsules}]
