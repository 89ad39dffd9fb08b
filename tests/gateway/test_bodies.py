"""The compiled body test (:func:`gateway.bodies.within`) agrees with its numpy reference, and the start-up check
would catch one that does not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from gateway import bodies
from gateway.bodies import check_within, near, near_reference, within, within_reference
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
