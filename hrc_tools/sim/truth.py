"""The true human capsules of a scenario at a time, as the auditor's :class:`HumanCapsules`.

Equal to :func:`tracker_emu.scenario.humans_at` (a test checks it), but fast enough to run every 4 ms:
the body in its own frame (:func:`tracker_emu.body.body_capsules_local`, the costly part) only depends
on the reach, so it is cached per reach value, and only the rigid move to the floor pose
(:func:`tracker_emu.body.body_capsules`' last step) is done per call.
"""

from __future__ import annotations

import functools
import math

import numpy as np
import numpy.typing as npt

from hrc_contract.humans import NO_HUMANS, HumanCapsules
from tracker_emu.body import body_capsules_local
from tracker_emu.scenario import Scenario, pose_at, scenario_time

FloatArray = npt.NDArray[np.float64]


@functools.lru_cache(maxsize=4096)
def _local(reach: float, both_arms: bool) -> tuple[FloatArray, FloatArray, FloatArray, tuple[str, ...]]:
    capsules = body_capsules_local(reach, both_arms)
    a = np.array([c.a for c in capsules])
    b = np.array([c.b for c in capsules])
    radius = np.array([c.radius_m for c in capsules])
    return a, b, radius, tuple(c.name for c in capsules)


def true_humans(scenario: Scenario, t_s: float) -> HumanCapsules:
    """The capsules of every human present at time ``t_s`` since the scenario started (wrapped if it loops).

    Human ids are the scenario's ids; capsules in the order of :func:`tracker_emu.scenario.humans_at`.
    """
    t_s = scenario_time(scenario, t_s)
    parts: list[tuple[FloatArray, FloatArray, FloatArray, tuple[str, ...], tuple[str, ...]]] = []
    for human in scenario.humans:
        pose = pose_at(human, t_s)
        if pose is None:
            continue
        a_body, b_body, radius, names = _local(pose.reach, pose.both_arms)
        c, s = math.cos(pose.heading_rad), math.sin(pose.heading_rad)
        R_world_body_T = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        p_world_body = np.array([pose.x_m, pose.y_m, 0.0])
        parts.append(
            (
                a_body @ R_world_body_T + p_world_body,
                b_body @ R_world_body_T + p_world_body,
                radius,
                (human.id,) * len(names),
                names,
            )
        )
    if not parts:
        return NO_HUMANS
    if len(parts) == 1:
        a, b, radius, ids, names = parts[0]
        return HumanCapsules(a, b, radius, ids, names)
    return HumanCapsules(
        np.concatenate([p[0] for p in parts]),
        np.concatenate([p[1] for p in parts]),
        np.concatenate([p[2] for p in parts]),
        tuple(i for p in parts for i in p[3]),
        tuple(n for p in parts for n in p[4]),
    )
