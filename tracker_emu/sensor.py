"""A sensor's view of the true humans: Gaussian noise on every capsule end point, and lost frames.

Latency is not modelled here: the process publishes each measured frame ``latency_s`` after its capture.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from hrc_common.config import TrackerConfig
from hrc_common.messages import Capsule, Human, Humans
from tracker_emu.body import BodyCapsule
from tracker_emu.scenario import TrackedHuman


def measure(
    humans_true: Sequence[TrackedHuman], rng: np.random.Generator, tracker: TrackerConfig
) -> list[TrackedHuman] | None:
    """One sensor frame of the given humans.

    Every end point gets independent zero-mean Gaussian noise of ``tracker.noise_std_m`` on each axis;
    radii and names are kept. With probability ``tracker.drop_probability`` the frame is lost.

    Args:
        humans_true: the humans present at the capture instant, capsules in the world frame [m].
        rng: random generator of this sensor (one draw for the drop, then the noise).
        tracker: noise [m] and drop probability of the sensor.

    Returns:
        The measured humans (an empty list when nobody is present), or None for a dropped frame.
    """
    if rng.random() < tracker.drop_probability:
        return None
    if tracker.noise_std_m == 0.0:
        return list(humans_true)
    measured = []
    for human in humans_true:
        noise_m = rng.normal(0.0, tracker.noise_std_m, size=(len(human.capsules), 2, 3))
        capsules = tuple(
            BodyCapsule(cap.name, cap.a + noise_m[i, 0], cap.b + noise_m[i, 1], cap.radius_m)
            for i, cap in enumerate(human.capsules)
        )
        measured.append(TrackedHuman(human.id, capsules))
    return measured


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
