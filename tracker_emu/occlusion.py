"""Line of sight: which body capsules a sensor sees past the robots' links, the fixtures and the other people.

A capsule counts as **visible** when the sight line from the sensor's position to at least one of three points of
its axis (its two ends and its middle) passes through no blocker capsule, i.e. when that segment's distance to every
blocker's axis is at least the blocker's radius (nothing is inflated). The blockers of a person are the robots' link
capsules, the scenario's fixtures and every capsule of the *other* people present (a body does not hide itself: a
camera sees its front or its back, and a skeleton tracker infers the rest). Sight lines end on the axis, not on the
surface facing the sensor, so a capsule is slightly easier to hide than the limb it stands for: the emulator errs
towards losing people. There is no field of view: a sensor sees all round.

A person reported with only the capsules a sensor sees is how two sensors see complementary parts of one body.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt

from hrc_devices.robots.segments import segment_distances
from tracker_emu.scenario import Fixture, TrackedHuman

FloatArray = npt.NDArray[np.float64]

SAMPLES_PER_CAPSULE = 3
"""Points of a capsule's axis the sensor looks at: end ``a``, the middle, end ``b``."""


class Blockers(NamedTuple):
    """Capsules that hide what lies behind them, world frame.

    Attributes:
        a_world, b_world: axis end points, shape (B, 3) [m].
        radius_m: radii, shape (B,) [m].
    """

    a_world: FloatArray
    b_world: FloatArray
    radius_m: FloatArray

    @property
    def n_capsules(self) -> int:
        return len(self.radius_m)


NO_BLOCKERS = Blockers(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))


def join_blockers(parts: Sequence[Blockers]) -> Blockers:
    """All capsules of several blocker sets in one."""
    parts = [p for p in parts if p.n_capsules]
    if not parts:
        return NO_BLOCKERS
    if len(parts) == 1:
        return parts[0]
    return Blockers(
        np.concatenate([p.a_world for p in parts]),
        np.concatenate([p.b_world for p in parts]),
        np.concatenate([p.radius_m for p in parts]),
    )


def fixture_blockers(fixtures: Sequence[Fixture]) -> Blockers:
    """A scenario's fixtures as blockers."""
    return Blockers(
        np.array([f.a_m for f in fixtures], dtype=float).reshape(-1, 3),
        np.array([f.b_m for f in fixtures], dtype=float).reshape(-1, 3),
        np.array([f.radius_m for f in fixtures], dtype=float),
    )


def human_blockers(human: TrackedHuman) -> Blockers:
    """The capsules of one person as blockers (for the other people)."""
    return Blockers(
        np.array([c.a for c in human.capsules]).reshape(-1, 3),
        np.array([c.b for c in human.capsules]).reshape(-1, 3),
        np.array([c.radius_m for c in human.capsules], dtype=float),
    )


def sample_points(human: TrackedHuman) -> FloatArray:
    """The points a sensor looks at, :data:`SAMPLES_PER_CAPSULE` per capsule: shape (C, 3, 3) [m]."""
    a = np.array([c.a for c in human.capsules]).reshape(-1, 3)
    b = np.array([c.b for c in human.capsules]).reshape(-1, 3)
    return np.stack((a, (a + b) / 2.0, b), axis=1)


def _blocked(sensor_m: FloatArray, points_m: FloatArray, blockers: Blockers) -> npt.NDArray[np.bool_]:
    """Whether blocker ``j`` cuts the sight line from the sensor to point ``i``: shape (P, B)."""
    sensor = np.broadcast_to(np.asarray(sensor_m, dtype=float), points_m.shape)
    # The sight segments are the "links" of segment_distances: distances of shape (P, B).
    distance_m = segment_distances(sensor, points_m, blockers.a_world, blockers.b_world).distance_m
    return np.asarray(distance_m < blockers.radius_m[None, :], dtype=bool)


def _visible(blocked: npt.NDArray[np.bool_]) -> npt.NDArray[np.bool_]:
    """Per capsule, whether any of its sample points is in sight, from the (3 C, B) blocked matrix."""
    point_in_sight = ~blocked.any(axis=1)
    return np.asarray(point_in_sight.reshape(-1, SAMPLES_PER_CAPSULE).any(axis=1), dtype=bool)


def visible_capsules(sensor_m: FloatArray, human: TrackedHuman, blockers: Blockers) -> npt.NDArray[np.bool_]:
    """Which capsules of ``human`` the sensor at ``sensor_m`` sees past ``blockers``.

    Args:
        sensor_m: the sensor's position, world frame, shape (3,) [m].
        human: the person, capsules in the world frame [m].
        blockers: what may stand in the way (not the person's own capsules) [m].

    Returns:
        One flag per capsule of ``human``, in its order: True when at least one of its sample points is in sight.
    """
    if blockers.n_capsules == 0:
        return np.ones(len(human.capsules), dtype=bool)
    return _visible(_blocked(sensor_m, sample_points(human).reshape(-1, 3), blockers))


def occlude(
    humans: Sequence[TrackedHuman], sensor_m: FloatArray, blockers: Blockers, present: Sequence[TrackedHuman]
) -> list[TrackedHuman]:
    """What a sensor at ``sensor_m`` sees of ``humans``: each person with only their visible capsules.

    Args:
        humans: the people to look at, capsules in the world frame [m].
        sensor_m: the sensor's position, world frame, shape (3,) [m].
        blockers: what hides people besides the other people: the robots' link capsules at the capture instant
            and the fixtures [m].
        present: everybody in the cell at the capture instant (they block the view of the others, whether the
            sensor reports them or not) [m].

    Returns:
        The people of ``humans`` with at least one visible capsule, in their order, each with its visible capsules
        only (in their order).
    """
    if not humans:
        return []
    bodies = [human_blockers(h) for h in present]
    everything = join_blockers([blockers, *bodies])
    if everything.n_capsules == 0:
        return list(humans)
    # Who each blocker belongs to: -1 for robots and fixtures, else the index of the person in ``present``.
    owner = np.concatenate(
        [np.full(blockers.n_capsules, -1), *(np.full(b.n_capsules, i) for i, b in enumerate(bodies))]
    )
    index = {h.id: i for i, h in enumerate(present)}
    # One distance computation for every sight line of every person against every blocker.
    blocked = _blocked(sensor_m, np.concatenate([sample_points(h).reshape(-1, 3) for h in humans]), everything)
    seen = []
    row = 0
    for human in humans:
        rows = SAMPLES_PER_CAPSULE * len(human.capsules)
        own = owner == index.get(human.id, -2)  # a body does not hide itself
        visible = _visible(blocked[row : row + rows] & ~own[None, :])
        row += rows
        if visible.all():
            seen.append(human)
        elif visible.any():
            seen.append(TrackedHuman(human.id, tuple(c for c, v in zip(human.capsules, visible, strict=True) if v)))
    return seen
