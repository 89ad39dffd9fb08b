"""What no tracker frame can be (:func:`hrc_contract.humans.implausible_detail`): the door judges every person of a
frame in a few array operations; the answer, reason and detail, is the one a check capsule by capsule and person by
person gives (the reference below, the door's own code before 2026-12-06), on seeded frames with seeded faults."""

from __future__ import annotations

import itertools
from typing import Any

import numpy as np
import pytest

from gateway import kernels
from hrc_contract.config import PlausibilityConfig
from hrc_contract.humans import HumanCapsules, human_starts, implausible_detail

PLAUSIBILITY = PlausibilityConfig()


def reference_detail(capsules: HumanCapsules, plausibility: PlausibilityConfig) -> tuple[str, str] | None:
    """Capsule by capsule, then person by person: the first fault found, in the contract's order."""
    n = capsules.n_capsules
    if n == 0:
        return None
    low, high = np.asarray(plausibility.world_min_m), np.asarray(plausibility.world_max_m)
    for ends in (capsules.h_a_world, capsules.h_b_world):
        if not ((ends >= low) & (ends <= high)).all():
            return "outside_world", "a capsule end point outside the cell's world volume"
    axis = capsules.h_b_world - capsules.h_a_world
    longest_sq = float(np.einsum("ij,ij->i", axis, axis).max())
    if longest_sq > plausibility.max_capsule_length_m**2:
        length = longest_sq**0.5
        return "capsule_too_long", f"a capsule {length:.2f} m long, at most {plausibility.max_capsule_length_m} m"
    if float(capsules.radius_m.max()) > plausibility.max_capsule_radius_m:
        radius = float(capsules.radius_m.max())
        return "radius_too_large", f"a radius of {radius:.2f} m, at most {plausibility.max_capsule_radius_m} m"
    ids = capsules.human_ids
    starts = [0, *(i for i in range(1, n) if ids[i] != ids[i - 1]), n]
    if len(set(ids)) != len(starts) - 1:
        return "duplicate_human_id", "a human id listed twice in one frame"
    for start, end in itertools.pairwise(starts):
        if end - start > plausibility.max_capsules_per_person:
            return "too_many_parts", (
                f"person {ids[start]!r} has {end - start} capsules, at most {plausibility.max_capsules_per_person}"
            )
        names = capsules.capsule_names[start:end]
        if len(set(names)) != len(names):
            twice = sorted({n for n in names if names.count(n) > 1})
            return "duplicate_part_name", f"person {ids[start]!r} has two capsules named {twice[0]!r}"
        a, b = capsules.h_a_world[start:end], capsules.h_b_world[start:end]
        ends = np.concatenate((a, b))
        extent = float(np.linalg.norm(ends.max(axis=0) - ends.min(axis=0)) + 2.0 * capsules.radius_m[start:end].max())
        if extent > plausibility.max_person_extent_m:
            return "person_too_large", (
                f"person {ids[start]!r} spans {extent:.2f} m, at most {plausibility.max_person_extent_m} m"
            )
    return None


def seeded_frame(rng: np.random.Generator) -> HumanCapsules:
    """A few people of up to 20 parts standing in the cell, then one seeded fault (or none)."""
    ids: list[str] = []
    names: list[str] = []
    rows: list[np.ndarray] = []
    for person in range(int(rng.integers(1, 12))):
        parts = int(rng.integers(1, 20))
        centre = rng.uniform(-2.0, 2.0, 3) * (1.0, 1.0, 0.0) + (0.0, 0.0, 1.0)
        a = centre + rng.uniform(-0.4, 0.4, (parts, 3))
        b = a + rng.uniform(-0.2, 0.2, (parts, 3))
        rows.append(np.concatenate((a, b, rng.uniform(0.02, 0.15, (parts, 1))), axis=1))
        ids += [f"front/p{person}"] * parts
        names += [f"part{k}" for k in range(parts)]
    table = np.concatenate(rows)
    for fault in rng.integers(0, 9, int(rng.integers(0, 4))):  # up to three faults, anywhere
        k = int(rng.integers(len(ids)))
        if fault == 1:  # a part far from its body, in the world (around the most a person may span)
            table[k, [0, 1, 3, 4]] += rng.choice((-1.0, 1.0)) * rng.uniform(1.5, 3.5)
        elif fault == 2:  # an end point out of the world
            table[k, 3 + int(rng.integers(3))] = 40.0
        elif fault == 3:
            table[k, 6] = 0.5
        elif fault == 4 and k and ids[k] == ids[k - 1]:  # a part named twice
            names[k] = names[k - 1]
        elif fault == 5:  # an id again after someone else
            ids[k] = ids[0]
        elif fault == 6:  # too many parts: someone with 70
            ids += [f"front/crowd{k}"] * 70
            names += [f"c{j}" for j in range(70)]
            table = np.concatenate((table, np.tile(table[k : k + 1], (70, 1))))
        elif fault == 7:  # a long capsule
            table[k, 3:6] = table[k, 0:3] + (0.0, 0.0, 1.8)
    return HumanCapsules(table[:, 0:3], table[:, 3:6], table[:, 6], tuple(ids), tuple(names))


@pytest.mark.parametrize("numbers", [None, kernels.frame_numbers], ids=["numpy", "compiled"])
def test_the_door_judges_seeded_frames_as_the_person_by_person_reference(numbers: Any) -> None:
    """With the contract's numbers (numpy) and with the gateway's (compiled, as its door admits frames)."""
    rng = np.random.default_rng(36)
    reasons: set[str | None] = set()
    for _ in range(1500):
        capsules = seeded_frame(rng)
        want = reference_detail(capsules, PLAUSIBILITY)
        assert implausible_detail(capsules, PLAUSIBILITY, numbers) == want
        reasons.add(None if want is None else want[0])
    assert reasons == {
        None,
        "outside_world",
        "capsule_too_long",
        "radius_too_large",
        "duplicate_human_id",
        "too_many_parts",
        "duplicate_part_name",
        "person_too_large",
    }  # every answer was asked for


@pytest.mark.parametrize("n", [0, 1, 2, 7])
def test_where_each_person_starts(n: int) -> None:
    ids = tuple(f"p{k // 3}" for k in range(n))
    capsules = HumanCapsules(np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n), ids, ("x",) * n)
    assert human_starts(capsules) == [0, *(k for k in range(1, n) if ids[k] != ids[k - 1]), n] if n else [0]
