"""A sensor's view of the true humans: the covered volume, occlusion, missed people, noise, lost frames, id swaps.

One frame of one sensor, in this order (:func:`measure`; the random draws in this order too, each only when its
probability is above zero, so that a sensor without them draws exactly what it drew before they existed):

1. the whole frame is lost with ``drop_probability`` (one draw);
2. people whose centre (the mean of their capsule end points) lies outside the covered volume are not reported:
   the cell's trackers cover that volume together, and people enter and leave the cell through its boundary;
3. each person left is missed with ``miss_probability`` (one draw per person, whatever else happens to them);
4. with ``occlusion``, each person is reported with only the capsules the sensor sees from ``position_m`` past the
   robots' links, the fixtures and the other people (:mod:`tracker_emu.occlusion`), and not at all when it sees none;
5. every reported end point gets Gaussian noise.

Id swaps (:func:`swap_ids`) act on the reported ids and persist, as a real tracker that confused two people keeps
the confusion. Latency is not modelled here: the process publishes each measured frame ``latency_s`` after its
capture.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from hrc_contract.config import Box, TrackerConfig, TrackingConfig
from hrc_contract.messages import Capsule, Human, Humans
from tracker_emu.body import BodyCapsule
from tracker_emu.occlusion import NO_BLOCKERS, Blockers, occlude
from tracker_emu.scenario import TrackedHuman

FloatArray = npt.NDArray[np.float64]


def centre_m(human: TrackedHuman) -> FloatArray:
    """The mean of a person's capsule end points, world frame [m] (the gateway's track centre)."""
    return np.mean([p for c in human.capsules for p in (c.a, c.b)], axis=0)  # type: ignore[no-any-return]


def covered_volume(tracking: TrackingConfig) -> Box:
    """The volume the cell's trackers cover (``[tracking]`` of the cell file), world frame [m]."""
    return Box(min_m=tracking.coverage_min_m, max_m=tracking.coverage_max_m)


def inside(box: Box, point_m: FloatArray) -> bool:
    """Whether a point lies in the box (faces included) [m]."""
    return all(lo <= x <= hi for x, lo, hi in zip(point_m, box.min_m, box.max_m, strict=True))


def measure(
    humans_true: Sequence[TrackedHuman],
    rng: np.random.Generator,
    tracker: TrackerConfig,
    *,
    coverage: Box | None = None,
    blockers: Blockers = NO_BLOCKERS,
) -> list[TrackedHuman] | None:
    """One sensor frame of the given humans (see the module's docstring for the steps).

    Args:
        humans_true: the humans present at the capture instant, capsules in the world frame [m].
        rng: random generator of this sensor (drop, misses, then noise).
        tracker: the sensor: noise [m], drop and miss probabilities, occlusion and position.
        coverage: the volume the cell's trackers cover, world frame [m]; None = everywhere.
        blockers: what hides people besides the other people, at the capture instant: the robots' link capsules
            and the scenario's fixtures, world frame [m] (with occlusion).

    Returns:
        The measured humans (an empty list when the sensor reports nobody), or None for a dropped frame.
    """
    if rng.random() < tracker.drop_probability:
        return None
    covered = [h for h in humans_true if coverage is None or inside(coverage, centre_m(h))]
    if tracker.miss_probability > 0.0:
        missed = rng.random(len(covered)) < tracker.miss_probability
        covered = [h for h, miss in zip(covered, missed, strict=True) if not miss]
    if tracker.occlusion and tracker.position_m is not None:
        covered = occlude(covered, np.asarray(tracker.position_m, dtype=float), blockers, humans_true)
    if tracker.noise_std_m == 0.0:
        return covered
    measured = []
    for human in covered:
        noise_m = rng.normal(0.0, tracker.noise_std_m, size=(len(human.capsules), 2, 3))
        capsules = tuple(
            BodyCapsule(cap.name, cap.a + noise_m[i, 0], cap.b + noise_m[i, 1], cap.radius_m)
            for i, cap in enumerate(human.capsules)
        )
        measured.append(TrackedHuman(human.id, capsules))
    return measured


def merge_close(humans: Sequence[TrackedHuman], within_m: float) -> list[TrackedHuman]:
    """People whose centres lie within ``within_m`` of an earlier one's, reported as that one (all capsules under its
    id): a tracker that merges people standing together."""
    if within_m <= 0.0 or len(humans) < 2:
        return list(humans)
    groups: list[list[TrackedHuman]] = []
    for human in humans:
        c = centre_m(human)
        group = next((g for g in groups if np.linalg.norm(centre_m(g[0]) - c) <= within_m), None)
        if group is None:
            groups.append([human])
        else:
            group.append(human)
    return [TrackedHuman(g[0].id, tuple(c for h in g for c in h.capsules)) for g in groups]


def names_by_kind(humans: Sequence[TrackedHuman]) -> list[TrackedHuman]:
    """Capsules named by their kind, the side left out (``forearm_l`` → ``forearm``)."""
    return [
        TrackedHuman(
            h.id,
            tuple(BodyCapsule(c.name.removesuffix("_l").removesuffix("_r"), c.a, c.b, c.radius_m) for c in h.capsules),
        )
        for h in humans
    ]


def renew_ids(
    reported: Sequence[TrackedHuman],
    names: Mapping[str, str],
    rng: np.random.Generator,
    probability: float,
    serial: int,
) -> dict[str, str]:
    """The sensor's names for the people after this frame: with ``probability`` each reported person gets a new id
    (``<id>-<serial>``; one draw per person, none when ``probability`` is 0)."""
    new = dict(names)
    if probability == 0.0 or not reported:
        return new
    for human, draw in zip(reported, rng.random(len(reported)), strict=True):
        if draw < probability:
            new[human.id] = f"{human.id}-{serial}"
    return new


def swap_ids(
    reported: Sequence[TrackedHuman], names: Mapping[str, str], rng: np.random.Generator, probability: float
) -> dict[str, str]:
    """The sensor's names for the people after this frame: with ``probability``, two reported people swap ids.

    Args:
        reported: the people of this frame, by their true ids.
        names: the id the sensor gives each true id so far (a true id not in it keeps its own).
        rng: random generator of this sensor (one draw when two or more people are reported, two more on a swap).
        probability: of a swap in this frame.

    Returns:
        The new names (a permutation of the ids: reported ids stay unique).
    """
    new = dict(names)
    if probability == 0.0 or len(reported) < 2 or rng.random() >= probability:
        return new
    i, j = rng.choice(len(reported), size=2, replace=False)
    first, second = reported[int(i)].id, reported[int(j)].id
    new[first], new[second] = names.get(second, second), names.get(first, first)
    return new


def rename(humans: Sequence[TrackedHuman], names: Mapping[str, str]) -> list[TrackedHuman]:
    """The people under the sensor's names for them (:func:`swap_ids`)."""
    return [TrackedHuman(names.get(h.id, h.id), h.capsules) for h in humans]


def humans_message(tracker_name: str, seq: int, stamp_ns: int, humans: Sequence[TrackedHuman]) -> Humans:
    """The contract message (``hrc.humans/1``) of one measured frame.

    Args:
        tracker_name: name of the sensor in the cell.
        seq: frame number of this sensor, +1 per published frame.
        stamp_ns: capture time, nanoseconds since the Unix epoch.
        humans: the measured humans, capsules in the world frame [m].
    """
    return Humans(
        tracker=tracker_name,
        seq=seq,
        stamp_ns=stamp_ns,
        humans=[
            Human(
                id=human.id,
                capsules=[
                    Capsule(
                        name=cap.name,
                        a=(float(cap.a[0]), float(cap.a[1]), float(cap.a[2])),
                        b=(float(cap.b[0]), float(cap.b[1]), float(cap.b[2])),
                        radius=cap.radius_m,
                    )
                    for cap in human.capsules
                ],
            )
            for human in humans
        ],
    )
