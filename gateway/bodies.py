"""Bodies as volumes: whether one set of human capsules lies inside another, grown by a distance.

The tracks (``gateway/tracks.py``) decide who is who by these volumes, never by ids or part names (docs/safety-math.md
§11): a detection *could be* a person when one body lies inside the other grown by what the person can move between
their two stamps (:func:`near`); it *covers* a lost body when each capsule of the lost body lies inside its own
capsule of the detection, grown by the lost person's reach (:func:`covers`: one detection part per lost part, so a
view of the legs never stands for a whole person, whatever the reach and whatever the parts are called).

A capsule (segment a–b, radius r) lies inside another grown by g when both its end spheres do: the grown capsule is
convex and a capsule is the convex hull of its end spheres. No state; :func:`within` is compiled
(:func:`gateway.kernels.capsules_within`), :func:`within_reference` is its numpy reference.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from gateway.kernels import bodies_near, capsules_near, capsules_within
from hrc_contract.config import ConfigError
from hrc_contract.humans import HumanCapsules

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


def _point_segment_distance_m(p: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    """Distance of each point ``p`` (n, 3) to each segment ``a``–``b`` (m, 3): an (n, m) array [m]."""
    d = b - a
    dd = (d * d).sum(axis=1)
    rel = p[:, None, :] - a[None, :, :]
    t = (rel * d[None, :, :]).sum(axis=2) / np.where(dd > 0.0, dd, 1.0)[None, :]
    np.clip(t, 0.0, 1.0, out=t)
    off = rel - t[:, :, None] * d[None, :, :]
    return np.sqrt((off * off).sum(axis=2))  # type: ignore[no-any-return]


def inside_matrix(small: HumanCapsules, big: HumanCapsules, grow_m: float) -> BoolArray:
    """Whether capsule i of ``small`` lies inside capsule j of ``big`` grown by ``grow_m`` [m]: an (n, m) array."""
    n = small.n_capsules
    if n == 0 or big.n_capsules == 0 or not np.isfinite(grow_m):
        return np.zeros((n, big.n_capsules), dtype=bool)
    limit = big.radius_m[None, :] + grow_m - small.radius_m[:, None]
    ends = np.concatenate((small.h_a_world, small.h_b_world))
    dist = _point_segment_distance_m(ends, big.h_a_world, big.h_b_world)
    return (dist[:n] <= limit) & (dist[n:] <= limit)


def within_reference(small: HumanCapsules, big: HumanCapsules, grow_m: float) -> bool:
    """Every capsule of ``small`` lies inside some capsule of ``big`` grown by ``grow_m`` [m] (``small`` could be a
    part of the body ``big`` after it moved at most ``grow_m``): numpy, the reference of :func:`within`."""
    if small.n_capsules == 0:
        return False
    return bool(inside_matrix(small, big, grow_m).any(axis=1).all())


def within(small: HumanCapsules, big: HumanCapsules, grow_m: float) -> bool:
    """:func:`within_reference`, compiled (:func:`gateway.kernels.capsules_within`): the tracks ask it for every
    pair of people whose boxes may nest, every frame."""
    return capsules_within(small, big, grow_m)


def near(x: HumanCapsules, y: HumanCapsules, grow_m: float) -> bool:
    """Whether ``x`` and ``y`` could be (parts of) one body, ``grow_m`` apart in motion and noise [m]: one lies inside
    the other grown by ``grow_m`` (compiled: :func:`gateway.kernels.capsules_near`)."""
    return capsules_near(x, y, grow_m)


def near_reference(x: HumanCapsules, y: HumanCapsules, grow_m: float) -> bool:
    """:func:`near` in numpy."""
    return within_reference(x, y, grow_m) or within_reference(y, x, grow_m)


def covers(lost: HumanCapsules, detection: HumanCapsules, grow_m: float) -> bool:
    """Whether each capsule of ``lost`` lies inside its own capsule of ``detection`` grown by ``grow_m`` [m].

    One detection capsule per lost capsule (a bipartite matching): a detection with fewer parts than the lost body
    never covers it, however far the reach has grown, and two lost parts are not explained by one seen part.
    """
    n, m = lost.n_capsules, detection.n_capsules
    if n == 0 or n > m:
        return False
    fits = inside_matrix(lost, detection, grow_m)
    if not fits.any(axis=1).all():
        return False
    return _perfect_matching(fits)


def _perfect_matching(fits: BoolArray) -> bool:
    """Whether every row of ``fits`` can take its own column (Kuhn's augmenting paths; rows ≤ columns ≤ 64)."""
    n, m = fits.shape
    owner = [-1] * m
    options = [np.flatnonzero(fits[i]).tolist() for i in range(n)]

    def augment(i: int, visited: list[bool]) -> bool:
        for j in options[i]:
            if visited[j]:
                continue
            visited[j] = True
            if owner[j] < 0 or augment(owner[j], visited):
                owner[j] = i
                return True
        return False

    # rows with the fewest options first: the usual case (one-to-one, each part near its own) needs no backtracking
    return all(augment(i, [False] * m) for i in sorted(range(n), key=lambda i: len(options[i])))


def random_capsules(rng: np.random.Generator, human_ids: tuple[str, ...], half_span_m: float) -> HumanCapsules:
    """Seeded random capsules for the start-up checks of the compiled code against its references: one per id, end
    points within ±``half_span_m`` [m] (a fifth of them points, a == b), radii 0–0.3 m."""
    n = len(human_ids)
    a = rng.uniform(-half_span_m, half_span_m, (n, 3))
    b = a + rng.uniform(-0.4, 0.4, (n, 3)) * (rng.random((n, 1)) < 0.8)
    return HumanCapsules(a, b, rng.uniform(0.0, 0.3, n), human_ids, ("p",) * n)


CHECK_PAIRS = 64
CHECK_SEED = 20211115


def check_within(seed: int = CHECK_SEED) -> None:
    """Hold the compiled :func:`within`, :func:`near` and :func:`gateway.kernels.bodies_near` to their numpy
    references on seeded random bodies (and compile them, or load them from numba's cache, before the first frame).

    Raises:
        ConfigError: the two disagree on a pair.
    """
    rng = np.random.default_rng(seed)
    pairs: list[HumanCapsules] = []
    grows_m: list[float] = []
    for k in range(CHECK_PAIRS):
        bodies = [random_capsules(rng, ("x",) * n, 1.0) for n in (int(rng.integers(1, 6)), int(rng.integers(1, 16)))]
        grow_m = float(rng.uniform(0.0, 1.5))
        for small, big in (bodies, bodies[::-1]):
            if within(small, big, grow_m) != within_reference(small, big, grow_m):
                raise ConfigError(f"the compiled body test differs from its numpy reference on seeded pair {k}")
        if near(bodies[0], bodies[1], grow_m) != near_reference(bodies[0], bodies[1], grow_m):
            raise ConfigError(f"the compiled body test differs from its numpy reference on seeded pair {k}")
        pairs += bodies
        grows_m.append(grow_m)
    first = np.arange(0, 2 * CHECK_PAIRS, 2)
    batched = bodies_near(pairs, first, first + 1, np.array(grows_m))
    for k, got in enumerate(batched.tolist()):
        if got != near_reference(pairs[2 * k], pairs[2 * k + 1], grows_m[k]):
            raise ConfigError(f"the compiled pairs' body test differs from its numpy reference on seeded pair {k}")
