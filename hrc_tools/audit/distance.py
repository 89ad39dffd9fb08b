"""The auditor's own capsule distances: exact ones with coal, and cheap lower bounds that rule pairs out.

Independent of the gateway (safety-math.md §9): the surface distance of a link–capsule pair is coal's
capsule–capsule distance (``coal.distance`` of two ``coal.Capsule``), not the gateway's segment code.

Two kinds of answers, both for a pair (capsule ``i`` of a first set, capsule ``j`` of a second set):

- :meth:`CapsulePairs.lower_bounds_m`: for ALL pairs at once (numpy), a lower bound of the surface distance
  (clamped at 0): each capsule's axis midpoint against the other's axis segment, less the half-length
  (see there). It is lowered by :data:`LOWER_BOUND_SLACK_M`, far above the rounding of either computation,
  so that a pair the bound rules out is ruled out for the exact value as coal computes it, too.
- :meth:`CapsulePairs.exact`: for ONE pair, coal's signed surface distance, the closest point on the first
  capsule's axis (as an abscissa along it) and the unit direction from there to the closest point of the
  second capsule's axis. Building a pair's shapes and asking coal costs ~5–10 µs per pair from Python
  (~0.1 µs per pair for the bounds), which is why the lower bounds exist: :mod:`hrc_tools.audit.checks` asks for the
  few pairs that can matter.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import coal
import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

LOWER_BOUND_SLACK_M = 1e-9
"""Subtracted from every lower bound, so that rounding (~1e-15 m at the scale of a cell) can never rule out a
pair whose exact distance is below the bound [m]."""

Vector = tuple[float, float, float]


class PairDistance(NamedTuple):
    """coal's answer for one capsule pair.

    Attributes:
        surface_m: signed surface distance: centre-line distance minus both radii, negative when the capsules
            overlap [m].
        s_first: abscissa in [0, 1] along the first capsule's axis ``a + s (b − a)`` of its closest point.
        normal: unit vector from that point to the closest point of the second capsule's axis;
            (0, 0, 0) when the two axes touch (no direction).
    """

    surface_m: float
    s_first: float
    normal: Vector


def _rotation_z_to(ux: float, uy: float, uz: float) -> FloatArray:
    """A rotation whose z axis is the unit vector ``u`` (Duff et al., "Building an orthonormal basis,
    revisited", JCGT 2017: continuous everywhere except across uz = 0's sign, no division by ~0)."""
    sign = math.copysign(1.0, uz)
    k = -1.0 / (sign + uz)
    b = ux * uy * k
    return np.array(
        [
            [1.0 + sign * ux * ux * k, b, ux],
            [sign * b, sign + uy * uy * k, uy],
            [-sign * ux, -uy, uz],
        ]
    )


def _point_segment_distances(
    points: FloatArray, a_world: FloatArray, axis: FloatArray, length2: FloatArray
) -> FloatArray:
    """Distance of every point (P, 3) to every segment ``a + s axis``, s ∈ [0, 1] (S segments; ``length2`` their
    squared lengths, 1 where 0), shape (S, P) [m]."""
    # At 7 × 40 pairs the cost is the number of numpy calls: products over the coordinate axis are batched
    # matrix products (einsum and np.clip cost several times more here).
    offset = points[None, :, :] - a_world[:, None, :]  # (S, P, 3)
    s = (offset @ axis[:, :, None])[:, :, 0]
    s /= length2[:, None]
    np.maximum(s, 0.0, out=s)
    np.minimum(s, 1.0, out=s)
    offset -= s[:, :, None] * axis[:, None, :]
    distance2: FloatArray = (offset[:, :, None, :] @ offset[:, :, :, None])[:, :, 0, 0]
    return np.sqrt(distance2, out=distance2)


class CapsuleSet:
    """N capsules given by their axis end points and radii, with coal shapes made on demand.

    coal's capsule is centred on its local origin with its axis along local z (``coal.Capsule(radius, lz)``,
    ``lz`` the full axis length): each capsule's placement is the axis midpoint and a rotation taking z to
    the axis direction.

    Args:
        a_world, b_world: axis end points, shape (N, 3) [m].
        radius_m: radii, shape (N,) [m].
    """

    def __init__(self, a_world: FloatArray, b_world: FloatArray, radius_m: FloatArray) -> None:
        self.a_world = np.asarray(a_world, dtype=float)
        self.b_world = np.asarray(b_world, dtype=float)
        self.radius_m = np.asarray(radius_m, dtype=float)
        axis = self.b_world - self.a_world
        self.axis = axis
        length2 = (axis[:, None, :] @ axis[:, :, None])[:, 0, 0]
        self.length_m = np.sqrt(length2)
        self.length2_or_1 = np.where(length2 > 0.0, length2, 1.0)
        """Squared axis lengths, 1 for a sphere (so that ``s = (p − a)·axis / this`` is 0 there) [m²]."""
        self.centre_world = 0.5 * (self.a_world + self.b_world)
        self.half_length_m = 0.5 * self.length_m
        self._shapes: list[tuple[coal.Capsule, coal.Transform3s] | None] = [None] * len(self.radius_m)

    def __len__(self) -> int:
        return len(self.radius_m)

    def shape(self, k: int) -> tuple[coal.Capsule, coal.Transform3s]:
        """coal's capsule ``k`` and its placement in the world (made at the first call)."""
        made = self._shapes[k]
        if made is None:
            length_m = float(self.length_m[k])
            if length_m > 0.0:
                ux, uy, uz = (self.axis[k] / length_m).tolist()
                rotation = _rotation_z_to(ux, uy, uz)
            else:
                rotation = np.eye(3)  # a sphere: any axis
            made = (coal.Capsule(float(self.radius_m[k]), length_m), coal.Transform3s(rotation, self.centre_world[k]))
            self._shapes[k] = made
        return made


class CapsulePairs:
    """Distances between the capsules of ``first`` and those of ``second``: lower bounds for all pairs at once,
    exact ones with coal pair by pair (see the module's docstring)."""

    def __init__(self, first: CapsuleSet, second: CapsuleSet) -> None:
        self.first = first
        self.second = second
        self._request = coal.DistanceRequest()
        self._result = coal.DistanceResult()
        self._first_a = first.a_world.tolist()
        self._first_axis = first.axis.tolist()
        self._first_length2 = first.length2_or_1.tolist()
        self._first_radius = first.radius_m.tolist()

    def lower_bounds_m(self) -> FloatArray:
        """A lower bound of the surface distance clamped at 0, ``max(0, d)``, of every pair, shape (N1, N2) [m].

        Every point of capsule ``j``'s axis lies within its half-length ``h_j`` of the axis midpoint ``c_j``, and
        the distance to a set changes no faster than the point moves, so the axes are at least
        ``dist(c_j, axis_i) − h_j`` apart; the same with the roles swapped; the larger of the two, minus both
        radii, bounds the surface distance from below. It is never looser than the bounding spheres'
        ``‖c_i − c_j‖ − (h_i + r_i) − (h_j + r_j)``, since ``dist(c_j, axis_i) ≥ ‖c_i − c_j‖ − h_i``.
        """
        first, second = self.first, self.second
        axes_apart: FloatArray = np.maximum(
            _point_segment_distances(second.centre_world, first.a_world, first.axis, first.length2_or_1)
            - second.half_length_m[None, :],
            _point_segment_distances(first.centre_world, second.a_world, second.axis, second.length2_or_1).T
            - first.half_length_m[:, None],
        )
        axes_apart -= first.radius_m[:, None]
        axes_apart -= second.radius_m[None, :]
        axes_apart -= LOWER_BOUND_SLACK_M
        np.maximum(axes_apart, 0.0, out=axes_apart)
        return axes_apart

    def exact(self, i: int, j: int) -> PairDistance:
        """coal's distance between capsule ``i`` of the first set and capsule ``j`` of the second."""
        shape_i, placement_i = self.first.shape(i)
        shape_j, placement_j = self.second.shape(j)
        result = self._result
        result.clear()
        surface_m = float(coal.distance(shape_i, placement_i, shape_j, placement_j, self._request, result))
        # coal's witness points are on the surfaces, ``radius · normal`` away from the axes' closest points
        # (normal from the first to the second; zero when the axes touch). The abscissa is the projection of
        # the first axis's closest point on the axis (for a sphere, axis 0 and squared length 1: s = 0).
        nx, ny, nz = result.normal.tolist()
        wx, wy, wz = result.getNearestPoint1().tolist()
        radius = self._first_radius[i]
        ax, ay, az = self._first_a[i]
        dx, dy, dz = self._first_axis[i]
        along = (wx - radius * nx - ax) * dx + (wy - radius * ny - ay) * dy + (wz - radius * nz - az) * dz
        s = min(max(along / self._first_length2[i], 0.0), 1.0)
        return PairDistance(surface_m, s, (nx, ny, nz))
