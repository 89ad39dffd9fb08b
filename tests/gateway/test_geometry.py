"""segment_distances: hand-computed known answers, then a seeded comparison against coal capsules of radius 0.

Every test runs on both implementations: the numpy one (hrc_devices.robots.segments: the reference, and what the ISO/TS
15066 method and the auditor use) and the compiled one of the gateway's loop (gateway.kernels).
"""

from __future__ import annotations

import coal
import numpy as np
import pinocchio as pin
import pytest

from gateway import kernels
from hrc_devices.robots import segments as reference_geometry

IMPLEMENTATIONS = {"numpy": reference_geometry.segment_distances, "compiled": kernels.segment_distances}


@pytest.fixture(params=sorted(IMPLEMENTATIONS))
def segment_distances(request: pytest.FixtureRequest):
    return IMPLEMENTATIONS[request.param]


def _one(segment_distances, a, b, c, d):
    """Distance, s and t of a single link segment [a, b] against a single capsule segment [c, d]."""
    arrays = [np.asarray(x, dtype=float)[None, :] for x in (a, b, c, d)]
    res = segment_distances(*arrays)
    return float(res.distance_m[0, 0]), float(res.s_link[0, 0]), float(res.t_capsule[0, 0])


def _coal_segment(a, b):
    """A coal capsule of radius 0 covering the segment [a, b] (coal's capsule is centred on its local z)."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    axis = b - a
    length = float(np.linalg.norm(axis))
    rotation = (
        np.eye(3) if length == 0.0 else pin.Quaternion.FromTwoVectors(np.array([0.0, 0.0, 1.0]), axis / length).matrix()
    )
    return coal.Capsule(0.0, length), coal.Transform3s(rotation, 0.5 * (a + b))


def _coal_distance(a, b, c, d):
    g1, t1 = _coal_segment(a, b)
    g2, t2 = _coal_segment(c, d)
    result = coal.DistanceResult()
    distance = coal.distance(g1, t1, g2, t2, coal.DistanceRequest(), result)
    return distance, np.array(result.getNearestPoint1()), np.array(result.getNearestPoint2())


# -- known answers ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("a", "b", "c", "d", "distance", "s", "t"),
    [
        # crossing at their midpoints
        ((-1, 0, 0), (1, 0, 0), (0, -1, 0), (0, 1, 0), 0.0, 0.5, 0.5),
        # skew, perpendicular, 2 m apart along z, closest at both midpoints
        ((-1, 0, 0), (1, 0, 0), (0, -1, 2), (0, 1, 2), 2.0, 0.5, 0.5),
        # skew with the link clamped at its end b: (1,0,0) to (2,0,1)
        ((0, 0, 0), (1, 0, 0), (2, -1, 1), (2, 1, 1), np.sqrt(2.0), 1.0, 0.5),
        # the capsule points away from the link: clamped at its end a, (0,0,0) to (0,0,3)
        ((-1, 0, 0), (1, 0, 0), (0, 0, 3), (0, 0, 5), 3.0, 0.5, 0.0),
        # T-shaped touch: the capsule's end a lies on the link
        ((0, 0, 0), (2, 0, 0), (1, 0, 0), (1, 1, 0), 0.0, 0.5, 0.0),
        # end-to-end touch
        ((0, 0, 0), (1, 0, 0), (1, 0, 0), (1, 2, 0), 0.0, 1.0, 0.0),
        # point link against point capsule: a 3-4-5 triangle
        ((0, 0, 0), (0, 0, 0), (3, 4, 0), (3, 4, 0), 5.0, 0.0, 0.0),
        # point link above the middle of a capsule segment
        ((0, 0, 0), (0, 0, 0), (-1, 2, 0), (1, 2, 0), 2.0, 0.0, 0.5),
        # point link beyond the capsule's end b
        ((4, 0, 0), (4, 0, 0), (0, 0, 0), (1, 0, 0), 3.0, 0.0, 1.0),
        # point capsule above the middle of the link
        ((0, 0, 0), (2, 0, 0), (1, 1, 0), (1, 1, 0), 1.0, 0.5, 0.0),
        # point capsule beyond the link's end b
        ((0, 0, 0), (2, 0, 0), (3, 1, 0), (3, 1, 0), np.sqrt(2.0), 1.0, 0.0),
        # point capsule before the link's end a
        ((0, 0, 0), (2, 0, 0), (-3, 0, 4), (-3, 0, 4), 5.0, 0.0, 0.0),
        # both degenerate and coincident
        ((1, 2, 3), (1, 2, 3), (1, 2, 3), (1, 2, 3), 0.0, 0.0, 0.0),
    ],
)
def test_known_answers(segment_distances, a, b, c, d, distance, s, t) -> None:
    got_distance, got_s, got_t = _one(segment_distances, a, b, c, d)
    assert got_distance == pytest.approx(distance, abs=1e-12)
    assert got_s == pytest.approx(s, abs=1e-12)
    assert got_t == pytest.approx(t, abs=1e-12)


@pytest.mark.parametrize(
    ("c", "d", "distance"),
    [
        ((0.5, 1, 0), (1.5, 1, 0), 1.0),  # parallel, overlapping in x: 1 m apart
        ((1.5, 1, 0), (0.5, 1, 0), 1.0),  # anti-parallel, overlapping
        ((2, 1, 0), (3, 1, 0), np.sqrt(2.0)),  # parallel, disjoint: (1,0,0) to (2,1,0)
        ((-3, 0, 1), (-2, 0, 1), np.sqrt(5.0)),  # parallel, before the link: (0,0,0) to (-2,0,1)
        ((0.5, 0, 0), (3, 0, 0), 0.0),  # collinear and overlapping
        ((2, 0, 0), (3, 0, 0), 1.0),  # collinear, disjoint
    ],
)
def test_parallel_segments(segment_distances, c, d, distance) -> None:
    """Parallel pairs have no unique closest points: only the distance and the closest points' gap are fixed."""
    a, b = np.array([0.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0])
    got_distance, s, t = _one(segment_distances, a, b, c, d)
    assert got_distance == pytest.approx(distance, abs=1e-12)
    assert 0.0 <= s <= 1.0
    assert 0.0 <= t <= 1.0
    gap = (a + s * (b - a)) - (np.asarray(c, float) + t * (np.asarray(d, float) - np.asarray(c, float)))
    assert np.linalg.norm(gap) == pytest.approx(distance, abs=1e-12)


def test_shapes_are_links_by_capsules(segment_distances) -> None:
    """Links along axis 0, capsules along axis 1: every entry equals the single-pair answer."""
    p_a = np.array([[0.0, 0, 0], [0, 0, 1], [5, 5, 5]])
    p_b = np.array([[1.0, 0, 0], [0, 0, 1], [5, 6, 5]])
    h_a = np.array([[0.0, 2, 0], [3, 4, 0]])
    h_b = np.array([[1.0, 2, 0], [3, 4, 0]])
    res = segment_distances(p_a, p_b, h_a, h_b)
    assert res.distance_m.shape == (3, 2)
    assert res.s_link.shape == (3, 2)
    assert res.t_capsule.shape == (3, 2)
    for i in range(3):
        for j in range(2):
            assert res.distance_m[i, j] == pytest.approx(
                _one(segment_distances, p_a[i], p_b[i], h_a[j], h_b[j])[0], abs=1e-12
            )
    assert res.distance_m[0, 0] == pytest.approx(2.0)
    assert res.distance_m[1, 1] == pytest.approx(np.sqrt(9 + 16 + 1))


def test_no_capsules_gives_empty_result(segment_distances) -> None:
    res = segment_distances(np.zeros((2, 3)), np.ones((2, 3)), np.zeros((0, 3)), np.zeros((0, 3)))
    assert res.distance_m.shape == (2, 0)


# -- seeded random comparison against coal ------------------------------------------------------


def test_random_segments_match_coal(segment_distances) -> None:
    rng = np.random.default_rng(20240601)
    for _ in range(400):
        a, b, c, d = rng.uniform(-1.0, 1.0, size=(4, 3))
        expected, near_link, near_capsule = _coal_distance(a, b, c, d)
        got, s, t = _one(segment_distances, a, b, c, d)
        assert got == pytest.approx(expected, abs=1e-9)
        # generic random segments have unique closest points: s and t must point at coal's
        np.testing.assert_allclose(a + s * (b - a), near_link, atol=1e-7)
        np.testing.assert_allclose(c + t * (d - c), near_capsule, atol=1e-7)


def test_nearly_parallel_pair_known_answer(segment_distances) -> None:
    """Regression: an absolute parallel threshold (a·e − b² ≤ 1e-12) once returned 0.1 here (s = 0)."""
    # The capsule descends 5e-7 m per metre toward the link: closest at the link's end b, 0.1 − 2.5e-7 m.
    distance, s, _ = _one(segment_distances, (0, 0, 0), (1, 0, 0), (0.5, 0.1, 0), (1.5, 0.1 - 5e-7, 0))
    assert distance == pytest.approx(0.1 - 2.5e-7, abs=1e-9)
    assert s == pytest.approx(1.0, abs=1e-6)


def test_random_nearly_parallel_and_degenerate_segments_match_coal(segment_distances) -> None:
    """Nearly parallel (tilt 1e-6–1e-2 rad), exactly parallel and degenerate pairs match coal to 1e-9."""
    rng = np.random.default_rng(7)
    for k in range(400):
        a, b = rng.uniform(-1.0, 1.0, size=(2, 3))
        kind = k % 4
        if kind == 0:  # nearly parallel: a shifted copy of the link, slightly tilted
            shift = rng.uniform(-0.5, 0.5, 3)
            c, d = a + shift, b + shift + rng.normal(0.0, 10 ** rng.uniform(-6, -2), 3)
        elif kind == 1:  # exactly parallel, possibly reversed
            shift = rng.uniform(-0.5, 0.5, 3)
            c, d = (b + shift, a + shift) if rng.random() < 0.5 else (a + shift, b + shift)
        elif kind == 2:  # capsule is a point
            c = d = rng.uniform(-1.0, 1.0, 3)
        else:  # link is a point
            b = a.copy()
            c, d = rng.uniform(-1.0, 1.0, size=(2, 3))
        expected, _, _ = _coal_distance(a, b, c, d)
        got, s, t = _one(segment_distances, a, b, c, d)
        assert got == pytest.approx(expected, abs=1e-9), (kind, a, b, c, d)
        assert 0.0 <= s <= 1.0
        assert 0.0 <= t <= 1.0


def _brute_force_distance(a, b, c, d) -> float:
    """Independent reference: ternary search over the link abscissa of the (convex) point-to-segment distance."""

    def point_to_capsule(p):
        u = d - c
        t = float(np.clip(np.dot(p - c, u) / np.dot(u, u), 0.0, 1.0))
        return float(np.linalg.norm(p - (c + t * u)))

    lo, hi = 0.0, 1.0
    for _ in range(100):  # (2/3)^100 ≈ 2e-18
        m1, m2 = lo + (hi - lo) / 3, hi - (hi - lo) / 3
        if point_to_capsule(a + m1 * (b - a)) < point_to_capsule(a + m2 * (b - a)):
            hi = m2
        else:
            lo = m1
    return min(point_to_capsule(a + lo * (b - a)), point_to_capsule(a), point_to_capsule(b))


def test_almost_parallel_pairs_within_the_documented_bound(segment_distances) -> None:
    """Below a tilt of about 1e-7 rad the pair is treated as parallel; geometry.py documents the remaining error
    as at most 1e-7 × the segment length. coal is no reference here: it deviates by up to ~5e-7 × length itself."""
    rng = np.random.default_rng(17)
    for _ in range(150):
        a, b = rng.uniform(-1.0, 1.0, size=(2, 3))
        shift = rng.uniform(-0.5, 0.5, 3)
        c, d = a + shift, b + shift + rng.normal(0.0, 10 ** rng.uniform(-12, -5), 3)
        length = max(np.linalg.norm(b - a), np.linalg.norm(d - c))
        got, _, _ = _one(segment_distances, a, b, c, d)
        assert abs(got - _brute_force_distance(a, b, c, d)) <= 1e-7 * length + 1e-12


def test_random_invariants_symmetry_and_rigid_motion(segment_distances) -> None:
    """dist(A, B) = dist(B, A), and a rigid motion of both segments leaves the distance unchanged."""
    rng = np.random.default_rng(11)
    for _ in range(200):
        a, b, c, d = rng.uniform(-1.0, 1.0, size=(4, 3))
        distance, s, t = _one(segment_distances, a, b, c, d)
        swapped, _, _ = _one(segment_distances, c, d, a, b)
        assert swapped == pytest.approx(distance, abs=1e-12)
        rotation = pin.exp3(rng.normal(size=3))
        shift = rng.uniform(-3.0, 3.0, 3)
        moved, _, _ = _one(segment_distances, *(rotation @ x + shift for x in (a, b, c, d)))
        assert moved == pytest.approx(distance, abs=1e-9)
        # the reported closest points really are that far apart
        gap = (a + s * (b - a)) - (c + t * (d - c))
        assert np.linalg.norm(gap) == pytest.approx(distance, abs=1e-12)
