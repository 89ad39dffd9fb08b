"""Reference problems with known answers, shared by the tests (as qpsolvers' ``problems.py``): each case is the
input of a computation and, where it was worked out by hand, its answer. Tests import cases from here, never from
each other.

* eq. (15) on a hand-built link (safety-math.md §2–§4): one 0.4 m link translating at 2 m/s toward a point hand,
  with every intermediate value of its rows worked out;
* the UR5 of the default cell at one state (``Q``, ``QD_NOMINAL``) with a far torso and a near hand, fed through
  the gateway's :class:`~gateway.inputs.InputStore` into its :class:`~gateway.core.SafetyCore` like the real
  gateway (:class:`Cell`), and the delay the gateway measures there with fresh data (``FRESH_T_DELAY_S``).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

from gateway.core import RobotDecision, SafetyCore
from gateway.inputs import InputStore
from gateway.kinematics import LinkKinematics
from hrc_contract import keys
from hrc_contract.config import CellConfig, SafetyConfig
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.model import RobotModel
from hrc_runtime.clocks import Clocks

ArrayLike = npt.ArrayLike

# -- building blocks ----------------------------------------------------------------------------------


def moving_links(p_a: ArrayLike, p_b: ArrayLike, v_a: ArrayLike, v_b: ArrayLike) -> LinkKinematics:
    """Links from their end points [m] and end-point velocities [m/s], one row (or one point) per link."""
    return LinkKinematics(*(np.atleast_2d(np.asarray(x, dtype=float)) for x in (p_a, p_b, v_a, v_b)))


def human_capsules(a: ArrayLike, b: ArrayLike, radius: ArrayLike) -> HumanCapsules:
    """Capsules from their end points [m] and radius [m] (one for all, or one each); humans ``h0``, ``h1`` ..."""
    a_world = np.atleast_2d(np.asarray(a, dtype=float))
    b_world = np.atleast_2d(np.asarray(b, dtype=float))
    n = len(a_world)
    radius_m = np.broadcast_to(np.asarray(radius, float), (n,)).copy()
    return HumanCapsules(a_world, b_world, radius_m, tuple(f"h{i}" for i in range(n)), ("c",) * n)


def point_hands(points: ArrayLike, radius: float = 0.05) -> HumanCapsules:
    """Point-like hands (capsules of zero length) at ``points`` [m]."""
    return human_capsules(points, points, radius)


# -- eq. (15) on a hand-built link (safety-math.md §2–§4) ---------------------------------------------

SAFETY = SafetyConfig()
"""K = 1.6 m/s, c = 0.05 m, ISO 13855 close-speed switch off."""
T_BRAKE_LINK_S = 0.3
"""t_b,→i of the link [s]."""
T_BRAKE_MAX_S = 0.5
"""max_i t_b,i [s]."""
T_DELAY_S = 0.1
"""t_delay [s]."""
CLEARANCE_M = 1.01
"""Δ = c + K (t_b,max + t_delay) = 0.05 + 1.6 · 0.6 [m]."""
HORIZON_S = 0.4
"""T = t_b,→i + t_delay [s]."""

LINK_UP = moving_links((0, 0, 0), (0.4, 0, 0), (0, 2, 0), (0, 2, 0))
"""A 0.4 m link on the x axis translating along +y at 2 m/s."""
LINK_RADIUS_M = np.array([0.05])
LINK_T_BRAKE_S = np.array([T_BRAKE_LINK_S])


class KnownRows(NamedTuple):
    """Humans in front of :data:`LINK_UP` and the rows of eq. (15) worked out by hand (one capsule).

    Attributes:
        humans: the capsules.
        distance_m: surface distance d [m].
        f_m2: f = max(0, d − Δ)² [m²].
        e_m2ps: e = (h − r)ᵀ v, the same for every link end × capsule end here [m²/s].
        delta: δ = f / (T e), clipped to [0, 1].
    """

    humans: HumanCapsules
    distance_m: float
    f_m2: float
    e_m2ps: float
    delta: float


HAND_AHEAD = KnownRows(point_hands([(0.2, 2.0, 0.0)]), 1.9, 0.7921, 4.0, 0.4950625)
"""A point hand (radius 0.05) 2 m straight ahead of the link's middle. Centre-line distance 2.0, so
d = 2.0 − 0.05 − 0.05 = 1.9; f = (1.9 − 1.01)² = 0.89² = 0.7921; e = 2.0 · 2 = 4.0 for both link ends
(h − r_a = (0.2, 2, 0), h − r_b = (−0.2, 2, 0)); δ = 0.7921 / (0.4 · 4.0) = 0.4950625."""

# -- the UR5 of the default cell, fed like the real gateway -------------------------------------------

NOW = 1_790_000_000_000_000_000
"""The wall clock of the reference cycle [ns]."""
MS = 1_000_000
"""One millisecond [ns]."""
PERIOD_S = 0.004
"""The gateway's period [s]."""
CYCLE_MS = 4
"""The controller's cycle: one joint state every 4 ms."""
LATENCY_MS = 12
"""Override path: the newest joint state echoes an override sent 12 ms before it."""
MONO0 = 3_000_000_000
"""The gateway's monotonic clock at ``NOW`` [ns]."""

Q = [0.3, -1.2, 1.4, -0.5, 1.2, 0.0]
"""The UR5's joint positions [rad]."""
QD_NOMINAL = [0.6, -0.4, 0.5, 0.3, 0.2, 0.1]
"""Its programmed joint velocities [rad/s]."""

FAR_TORSO = {"name": "torso", "a": [4.0, 4.0, 0.8], "b": [4.0, 4.0, 1.6], "radius": 0.2}
"""A torso ≈ 5 m from the robot: autonomous, δ = 1."""
NEAR_HAND = {"name": "hand_r", "a": [-0.88, 1.39, 1.08], "b": [-0.88, 1.39, 1.08], "radius": 0.05}
"""A hand 1.8 m ahead of tool0 along its programmed velocity at (Q, QD_NOMINAL): 0 < δ < 1 at the default delays."""

FRESH_T_DELAY_S = 0.094
"""t_delay of :class:`Cell` with its default ages: reaction 0.040 + human data 0.030 + joint state 0.004
+ override path 0.012 + controller cycle 0.004 + gateway period 0.004 [s]."""


def at(t_ns: int, wall_step_ns: int = 0) -> Clocks:
    """The gateway's clocks at wall time ``t_ns``, its wall clock stepped by ``wall_step_ns``."""
    return Clocks(t_ns + wall_step_ns, MONO0 + t_ns - NOW)


class Cell:
    """An InputStore and a SafetyCore fed like the real gateway: controller states every 4 ms up to a given age,
    the newest echoing an override sent 12 ms before it; tracker frames with a given age."""

    def __init__(self, config: CellConfig, ur5: RobotModel, delay_aware: bool = True) -> None:
        self.config = config
        self.store = InputStore(config, {"ur5": ur5})
        if not delay_aware:
            safety = config.safety.model_copy(update={"unsafe_ignore_delay_for_tests": True})
            config = config.model_copy(update={"safety": safety})
        self.core = SafetyCore(config, {"ur5": ur5})
        self.joint_seq = 0
        self.last_joint_stamp_ns: int | None = None
        self.override_seq = -1
        self.human_seq = dict.fromkeys(config.trackers, 0)
        self.human_stamp_ns = dict.fromkeys(config.trackers, 0)

    def joint(
        self,
        now_ns: int,
        age_ms: float = 4,
        new_override: bool = True,
        q: Sequence[float] = Q,
        qd_nominal: Sequence[float] = QD_NOMINAL,
    ) -> None:
        newest = now_ns - int(age_ms * MS)
        stamp = newest - CYCLE_MS * MS if self.last_joint_stamp_ns is None else self.last_joint_stamp_ns + CYCLE_MS * MS
        echoed = self.override_seq
        if new_override:  # sent 12 ms before the newest state, which is the first to echo it
            self.override_seq += 1
            self.store.on_override_sent("ur5", self.override_seq, 1.0, at(newest - LATENCY_MS * MS))
        while stamp <= newest:
            if stamp == newest:
                echoed = self.override_seq
            self.joint_seq += 1
            raw = {
                "schema": "hrc.joint_state/1",
                "robot": "ur5",
                "seq": self.joint_seq,
                "stamp_ns": stamp,
                "q": list(q),
                # standing at q (applied override 0, qd 0): a robot moving at qd_nominal would move its q, and the
                # known answers are for the pose q (the door checks q's change against qd: q_motion_inconsistent)
                "qd": [0.0] * len(qd_nominal),
                "qd_nominal": list(qd_nominal),
                "override": 0.0,
                "override_seq": echoed,
                "mode": "running",
            }
            self.store.on_joint_state(keys.robot_state("demo", "ur5"), json.dumps(raw).encode(), at(now_ns))
            self.last_joint_stamp_ns = stamp
            stamp += CYCLE_MS * MS

    def humans(
        self,
        now_ns: int,
        capsules: list[dict[str, Any]],
        age_ms: float = 30,
        trackers: Sequence[str] = ("front", "side"),
    ) -> None:
        for tracker in trackers:
            self.human_seq[tracker] += 1
            # a genuine tracker's stamps only go forward: the newest capture, or just after the previous one
            self.human_stamp_ns[tracker] = max(now_ns - int(age_ms * MS), self.human_stamp_ns[tracker] + 1)
            raw = {
                "schema": "hrc.humans/1",
                "tracker": tracker,
                "seq": self.human_seq[tracker],
                "stamp_ns": self.human_stamp_ns[tracker],
                "humans": [{"id": "h1", "capsules": capsules}] if capsules else [],
            }
            self.store.on_humans(keys.tracker_humans("demo", tracker), json.dumps(raw).encode(), at(now_ns))

    def feed(
        self, now_ns: int, capsules: list[dict[str, Any]], human_age_ms: float = 30, joint_age_ms: float = 4
    ) -> None:
        self.joint(now_ns, joint_age_ms)
        self.humans(now_ns, capsules, human_age_ms)

    def step(self, now_ns: int, wall_step_ns: int = 0) -> RobotDecision:
        now = at(now_ns, wall_step_ns)
        return self.core.step(self.store.snapshot(now), now, PERIOD_S)["ur5"]
