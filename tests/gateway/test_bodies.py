"""The compiled body test (:func:`gateway.bodies.within`) agrees with its numpy reference, and the start-up check
would catch one that does not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gateway import bodies
from gateway.bodies import check_within, near, near_reference, random_capsules, within, within_reference
from gateway.kernels import bodies_near, slices_near
from hrc_contract.config import ConfigError
from hrc_contract.humans import HumanCapsules


def _body(rng: np.random.Generator, n: int, spread_m: float) -> HumanCapsules:
    a = rng.uniform(-spread_m, spread_m, (n, 3))
    b = a + rng.uniform(-0.5, 0.5, (n, 3)) * (rng.random((n, 1)) < 0.7)
    return HumanCapsules(a, b, rng.uniform(0.0, 0.3, n), ("h",) * n, ("part",) * n)


def test_the_compiled_body_test_agrees_with_the_reference_on_seeded_bodies() -> None:
    rng = np.random.default_rng(5)
    outcomes = set()
    for _ in range(3000):
        small = _body(rng, int(rng.integers(0, 8)), float(rng.uniform(0.2, 2.0)))
        big = _body(rng, int(rng.integers(0, 16)), float(rng.uniform(0.2, 2.0)))
        grow_m = float(rng.uniform(0.0, 2.0))
        expected = within_reference(small, big, grow_m)
        assert within(small, big, grow_m) == expected
        assert near(small, big, grow_m) == near_reference(small, big, grow_m)
        outcomes.add(expected)
    assert outcomes == {True, False}  # both answers were exercised


def test_a_body_within_itself_and_not_within_a_distant_one() -> None:
    body = _body(np.random.default_rng(1), 15, 0.8)
    far = HumanCapsules(body.h_a_world + 10.0, body.h_b_world + 10.0, body.radius_m, body.human_ids, body.capsule_names)
    assert within(body, body, 0.0)
    assert not within(body, far, 1.0)
    assert within(body, far, 20.0)
    assert not within(body, far, math.inf)  # a non-finite growth proves nothing (the reference's answer too)
    assert not within_reference(body, far, math.inf)
    empty = HumanCapsules(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), (), ())
    assert not within(empty, body, 1.0)
    assert not within(body, empty, 1.0)


def test_a_non_contiguous_or_read_only_body_gives_the_same_answer() -> None:
    """The door's arrays are views of one (H, 7) array (packed frames: read from a buffer): same answer."""
    rows = np.random.default_rng(2).uniform(-1.0, 1.0, (15, 7))
    rows[:, 6] = np.abs(rows[:, 6]) * 0.2
    rows.flags.writeable = False
    view = HumanCapsules(rows[:, 0:3], rows[:, 3:6], rows[:, 6], ("h",) * 15, ("p",) * 15)
    copy = HumanCapsules(*(np.array(x) for x in view[:3]), view.human_ids, view.capsule_names)
    for grow_m in (0.0, 0.3, 1.0):
        assert within(view, view, grow_m) == within(copy, copy, grow_m) == within_reference(view, view, grow_m)


def test_the_start_up_check_catches_a_compiled_test_that_disagrees(monkeypatch: pytest.MonkeyPatch) -> None:
    check_within()
    monkeypatch.setattr(bodies, "within", lambda small, big, grow_m: True)
    with pytest.raises(ConfigError, match="differs from its numpy reference"):
        check_within()


def test_the_pairs_of_a_frame_in_one_call_answer_as_the_reference_pair_by_pair() -> None:
    rng = np.random.default_rng(5)
    people = [random_capsules(rng, ("x",) * int(rng.integers(1, 16)), 1.0) for _ in range(12)]
    rows = np.concatenate((people[0].h_a_world, people[0].h_b_world, people[0].radius_m[:, None]), axis=1)
    people[0] = HumanCapsules(rows[:, 0:3], rows[:, 3:6], rows[:, 6], people[0].human_ids, people[0].capsule_names)
    first, second = rng.integers(0, 12, 200), rng.integers(0, 12, 200)  # people in several pairs, a body with itself
    grow_m = rng.uniform(0.0, 1.5, 200)
    grow_m[:3] = (np.nan, np.inf, -np.inf)
    got = bodies_near(people, first, second, grow_m)
    want = [near_reference(people[i], people[k], g) for i, k, g in zip(first, second, grow_m, strict=True)]
    assert got.tolist() == want
    assert 0 < sum(want) < len(want)
    assert not got[:3].any()  # a grow that is not a number is no answer


def test_the_start_up_check_catches_a_compiled_pairs_test_that_disagrees(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(bodies, "bodies_near", lambda b, first, second, grow_m: np.ones(len(first), dtype=bool))
    with pytest.raises(ConfigError, match="pairs' body test differs"):
        check_within()


@pytest.mark.parametrize(
    ("first", "second", "grow"),
    [([0], [2], [0.1]), ([-1], [0], [0.1]), ([0, 1], [1, 0], [0.1]), ([0, 1], [1], [0.1, 0.2])],
)
def test_pairs_outside_the_bodies_are_refused_not_read(first: list[int], second: list[int], grow: list[float]) -> None:
    people = [random_capsules(np.random.default_rng(k), ("x",) * 3, 1.0) for k in range(2)]
    with pytest.raises(ValueError, match=r"out of range|one per pair"):
        bodies_near(people, np.array(first), np.array(second), np.array(grow))


def _frame(rng: np.random.Generator, n: int) -> HumanCapsules:
    """A tracker frame as the door makes it: three views of one (n, 7) array (no column contiguous)."""
    rows = rng.uniform(-1.0, 1.0, (n, 7))
    rows[:, 6] = rng.uniform(0.0, 0.3, n)
    return HumanCapsules(rows[:, 0:3], rows[:, 3:6], rows[:, 6], ("x",) * n, ("p",) * n)


def test_slices_of_a_frame_read_in_place_answer_as_the_reference_pair_by_pair() -> None:
    rng = np.random.default_rng(11)
    frame = _frame(rng, 60)
    assert not frame.h_a_world.flags.c_contiguous
    starts = rng.integers(0, 60, 20)
    ends = np.minimum(starts + rng.integers(0, 12, 20), 60)  # overlapping slices, some empty
    first, second = rng.integers(0, 20, 300), rng.integers(0, 20, 300)
    grow_m = rng.uniform(0.0, 1.0, 300)
    got = slices_near(frame, starts, ends, first, second, grow_m)

    def body(j: int) -> HumanCapsules:
        s, e = int(starts[j]), int(ends[j])
        return HumanCapsules(frame.h_a_world[s:e], frame.h_b_world[s:e], frame.radius_m[s:e], (), ())

    want = [
        bool(ends[i] > starts[i] and ends[k] > starts[k]) and near_reference(body(i), body(k), g)
        for i, k, g in zip(first, second, grow_m, strict=True)
    ]
    assert got.tolist() == want
    assert 0 < sum(want) < len(want)


@pytest.mark.parametrize(("starts", "ends"), [([0, 4], [3, 9]), ([-1, 0], [2, 3]), ([2, 0], [1, 3])])
def test_slices_outside_the_capsules_are_refused_not_read(starts: list[int], ends: list[int]) -> None:
    frame = _frame(np.random.default_rng(2), 8)
    with pytest.raises(ValueError, match="outside the 8 given"):
        slices_near(frame, np.array(starts), np.array(ends), np.array([0]), np.array([1]), np.array([0.1]))
