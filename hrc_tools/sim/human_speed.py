"""How fast the scripted people of a scenario really come at the robot, against the configured K.

The separation-monitoring guarantee (eq. 15, the auditor's check, safety-math.md §9) assumes that no part of a
person approaches faster than K (``safety.human_speed_mps``). The sweep's generator draws walkers up to 2.0 m/s
and reaches whose hand moves up to ~2.0 m/s, beyond the configured K = 1.6 m/s, on purpose: those cases are
outside the guarantee and are reported apart (:mod:`hrc_tools.sim.sweep`, :mod:`bench.productivity`).

The speed is read from the scenario's keyframes, the truth the simulation interpolates
(:func:`tracker_emu.scenario.pose_at`): per keyframe segment,

- the floor speed ``|Δxy| / Δt`` if the segment is not walking away from every robot base (along a straight
  line the closing speed toward a point is largest at the segment's start, so the start decides);
- plus, while the reach grows, the fastest body point of the reaching body (the hand: the length of its path,
  sampled along the reach, over Δt).

Walking away, withdrawing an arm and turning in place do not count: they do not bring the person closer.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Sequence

import numpy as np

from hrc_contract.config import CellConfig
from tracker_emu.body import body_capsules_local
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

REACH_SAMPLES = 8
"""Pieces of the hand's path along a reach change (the path is an arc; its chord would be shorter)."""
ORIGIN_XY_M: tuple[tuple[float, float], ...] = ((0.0, 0.0),)
"""The generator's robot base on the floor (hrc_tools.sim.scenarios places people around the origin) [m]."""


@functools.lru_cache(maxsize=4096)
def _body_points(reach: float, both_arms: bool) -> np.ndarray:
    """Every capsule end point of the body at ``reach``, in the body's own frame, shape (2 N, 3) [m]."""
    capsules = body_capsules_local(reach, both_arms)
    return np.array([c.a for c in capsules] + [c.b for c in capsules])


def reach_path_m(reach_from: float, reach_to: float, both_arms: bool) -> float:
    """The longest path any body point travels while the reach goes from ``reach_from`` to ``reach_to`` [m]."""
    reaches = np.linspace(reach_from, reach_to, REACH_SAMPLES + 1)
    points = np.stack([_body_points(float(r), both_arms) for r in reaches])  # (samples, points, 3)
    steps_m = np.linalg.norm(np.diff(points, axis=0), axis=2)  # (samples - 1, points)
    return float(steps_m.sum(axis=0).max())


def _walks_closer(k0: Keyframe, k1: Keyframe, bases_xy_m: Sequence[tuple[float, float]]) -> bool:
    """True if the floor motion from ``k0`` to ``k1`` brings the person closer to some base at its start."""
    vx, vy = k1.xy_m[0] - k0.xy_m[0], k1.xy_m[1] - k0.xy_m[1]
    return any(vx * (bx - k0.xy_m[0]) + vy * (by - k0.xy_m[1]) > 0.0 for bx, by in bases_xy_m)


def segment_approach_speed_mps(
    k0: Keyframe, k1: Keyframe, both_arms: bool, bases_xy_m: Sequence[tuple[float, float]] = ORIGIN_XY_M
) -> float:
    """The fastest approach of any body point between two keyframes (walking toward a base, reaching out) [m/s]."""
    dt_s = k1.t_s - k0.t_s
    walk_mps = math.dist(k0.xy_m, k1.xy_m) / dt_s if _walks_closer(k0, k1, bases_xy_m) else 0.0
    reach_mps = reach_path_m(k0.reach, k1.reach, both_arms) / dt_s if k1.reach > k0.reach else 0.0
    return walk_mps + reach_mps


def approach_speed_mps(human: HumanScript, bases_xy_m: Sequence[tuple[float, float]] = ORIGIN_XY_M) -> float:
    """The fastest approach of one scripted person over the whole script [m/s]."""
    return max(
        segment_approach_speed_mps(k0, k1, human.both_arms, bases_xy_m)
        for k0, k1 in itertools.pairwise(human.keyframes)
    )


def fastest_approach_mps(scenario: Scenario, bases_xy_m: Sequence[tuple[float, float]] = ORIGIN_XY_M) -> float:
    """The fastest approach of any person of ``scenario`` (0 with nobody) [m/s]."""
    return max((approach_speed_mps(h, bases_xy_m) for h in scenario.humans), default=0.0)


def beyond_k(approach_mps: float, human_speed_mps: float) -> bool:
    """True if a person approaching at ``approach_mps`` is faster than K (outside the guarantee).

    A thousandth of a m/s of tolerance keeps a person scripted exactly at K (rounded keyframes) within it.
    """
    return approach_mps > human_speed_mps + 1e-3


def robot_bases_xy_m(config: CellConfig) -> tuple[tuple[float, float], ...]:
    """The floor positions of the cell's robot bases [m]."""
    return tuple((r.base_pose_world.xyz[0], r.base_pose_world.xyz[1]) for r in config.robots.values())
