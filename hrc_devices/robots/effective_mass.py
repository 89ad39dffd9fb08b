"""The robot's effective mass at a contact: the reflected mass of a link point, and a per-link bound (§12).

The mass a point with translational Jacobian J_v (3, n) presents along a unit direction u (Khatib 1995) is

    m_u = 1 / (uᵀ J_v M(q)⁻¹ J_vᵀ u)                                                          (M1)

and its largest value over every direction is the largest eigenvalue of the translational operational-space inertia
Λ = (J_v M⁻¹ J_vᵀ)⁻¹, i.e. 1 / λ_min(J_v M⁻¹ J_vᵀ) (M2). A point that cannot move in some direction (a point of the
first two links of a UR5, which only the first one or two joints move: rank J_v < 3; a singular configuration) has
m_u = ∞ along it: the robot is rigid there. The contact model of ISO/TS 15066 Annex A then reduces to the body
region's own mass (μ = (1/m_H + 1/∞)⁻¹ = m_H): the contact-safe speed of a fixed obstacle, F_max / sqrt(m_H k),
finite. Infinity is the honest cap: a mass bound is never lowered, only raised to ∞.

:func:`link_mass_bounds` computes, once at start-up, per link the largest (M2) over sampled configurations (the
program's joint-space path and a box around it) and sampled points of the link's capsule, times
(1 + :data:`MASS_BOUND_MARGIN`); a link whose largest value is infinite or above :data:`MASS_CAP_KG` gets ∞. The bound
holds where the robot's configuration is inside the sampled box (:meth:`LinkMassBounds.covers`; the override only
scales time along the programmed path, so the robot stays on it); outside it the caller uses ∞.

The payload is a point mass at the tool frame (:func:`with_payload`). Used by the gateway (the bound, constant per
link) and by the auditor (the reflected mass at each contact, along the contact normal): pure Pinocchio, no code of
either.
"""

from __future__ import annotations

import hashlib
import math
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from hrc_devices.robots.model import RobotModel

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

MASS_BOUND_MARGIN = 0.15
"""The per-link bound is the largest sampled value times 1 + this: the margin for the configurations between samples
(the largest value over 20 000 extra random samples of the box exceeds the sampled one by at most 4 % for the UR5;
tests/hrc_devices/robots/test_effective_mass.py holds the bound above 2000 fresh random configurations and
directions)."""
MASS_CAP_KG = 150.0
"""A link whose sampled mass bound exceeds this gets ∞ (the region's own mass decides): near a singularity the bound
grows without limit, and a large finite number would pretend a precision it does not have [kg]."""
BOX_MARGIN_RAD = 0.2
"""The sampled box reaches this far beyond the program's waypoints in every joint [rad]."""
BOX_SAMPLES = 1500
"""Random configurations sampled in the box (seeded: the bound is reproducible)."""
PATH_STEP_RAD = 0.02
"""Largest joint step between two samples of the program's path [rad]."""
SEGMENT_POINTS = 5
"""Points along each link's axis at which the bound is taken (its ends included)."""


def with_payload(model: pin.Model, payload_kg: float, tool_frame_id: int) -> pin.Model:
    """A copy of ``model`` carrying ``payload_kg`` as a point mass at the origin of ``tool_frame_id``."""
    loaded = pin.Model(model)
    if payload_kg > 0.0:
        frame = loaded.frames[tool_frame_id]
        point = pin.Inertia(payload_kg, frame.placement.translation, np.zeros((3, 3)))
        loaded.inertias[frame.parentJoint] = loaded.inertias[frame.parentJoint] + point
    return loaded


def moving_mass_kg(model: pin.Model) -> float:
    """M: the mass of every body a joint moves (the fixed base excluded) [kg]."""
    return float(sum(model.inertias[j].mass for j in range(1, model.njoints)))


def inverse_inertia(model: pin.Model, data: pin.Data, q_rad: FloatArray) -> FloatArray:
    """M(q)⁻¹, symmetric (Pinocchio fills only its upper triangle), shape (n, n) [1/kg, 1/(kg m²)]."""
    pin.computeMinverse(model, data, q_rad)
    return np.asarray(np.triu(data.Minv) + np.triu(data.Minv, 1).T, dtype=float)


def reflected_mass_kg(J_v: FloatArray, M_inv: FloatArray, u: FloatArray) -> float:
    """(M1): the mass a point with translational Jacobian ``J_v`` (3, n) presents along the unit vector ``u`` [kg];
    ∞ where the point cannot move along u."""
    Ju = J_v.T @ u
    inverse = float(Ju @ M_inv @ Ju)
    return 1.0 / inverse if inverse > 1e-12 else math.inf


def largest_reflected_mass_kg(J_v: FloatArray, M_inv: FloatArray) -> FloatArray:
    """(M2): λ_max(Λ) = 1 / λ_min(J_v M⁻¹ J_vᵀ) of each point, ``J_v`` shape (P, 3, n) → (P,) [kg]; ∞ where the
    point cannot move in some direction."""
    A = np.einsum("pin,nm,pjm->pij", J_v, M_inv, J_v)
    smallest = np.linalg.eigvalsh(A)[:, 0]
    scale = np.maximum(np.abs(A).max(axis=(1, 2)), 1e-300)
    with np.errstate(divide="ignore"):
        return np.where(smallest > 1e-9 * scale, 1.0 / np.where(smallest > 0.0, smallest, 1.0), np.inf)


def _skew(o: FloatArray) -> FloatArray:
    return np.array([[0.0, -o[2], o[1]], [o[2], 0.0, -o[0]], [-o[1], o[0], 0.0]])


_SURFACE_SKEWS = np.stack([_skew(o) for o in np.vstack([np.zeros(3), np.eye(3), -np.eye(3)])])
"""[o]× of the axis point and the six unit offsets ± x, ± y, ± z (scaled by the radius), shape (7, 3, 3)."""


def capsule_point_jacobians(
    J_a: FloatArray, J_b: FloatArray, radius_m: float, s: FloatArray | None = None
) -> FloatArray:
    """Translational Jacobians of points of a link's capsule, shape (len(s) · 7, 3, n): at each abscissa s of the
    axis, the axis point and the six surface points ± r along the base axes.

    Args:
        J_a, J_b: the 6 × n LOCAL_WORLD_ALIGNED Jacobians of the segment's end frames (linear rows first).
        radius_m: the capsule's radius [m].
        s: abscissae along the axis a + s (b − a); default :data:`SEGMENT_POINTS` from 0 to 1.
    """
    if s is None:
        s = np.linspace(0.0, 1.0, SEGMENT_POINTS)
    axis = (1.0 - s)[:, None, None] * J_a[None, :3] + s[:, None, None] * J_b[None, :3]  # (S, 3, n)
    # v(p + o) = v(p) + ω × o = v(p) − [o]× J_ω q̇, ω from the body's angular Jacobian (both ends are on it)
    cross = _SURFACE_SKEWS * radius_m @ J_a[3:]  # (7, 3, n)
    points = axis[:, None, :, :] - cross[None, :, :, :]  # (S, 7, 3, n)
    return points.reshape(-1, *axis.shape[1:])


def path_samples(waypoints_rad: FloatArray, step_rad: float = PATH_STEP_RAD) -> FloatArray:
    """Configurations along the program's closed joint-space polyline (its moves are straight lines in joint space),
    no joint moving more than ``step_rad`` between two, shape (N, n) [rad]."""
    samples = []
    for a, b in zip(waypoints_rad, np.roll(waypoints_rad, -1, axis=0), strict=True):
        n = max(1, math.ceil(float(np.abs(b - a).max()) / step_rad))
        samples.append(a[None, :] + np.linspace(0.0, 1.0, n + 1)[:, None] * (b - a)[None, :])
    return np.vstack(samples)


class LinkMassBounds(NamedTuple):
    """The per-link mass bound and where it holds.

    Attributes:
        mass_kg: the largest reflected mass of any point of each link's capsule in any direction over the sampled
            configurations, times 1 + :data:`MASS_BOUND_MARGIN`; ∞ if infinite or above :data:`MASS_CAP_KG`, shape
            (L,) [kg].
        sampled_kg: the same without the margin and cap (∞ where a point could not move in some direction) [kg].
        q_min_rad, q_max_rad: the sampled box [rad].
        configurations: configurations sampled (path and box).
    """

    mass_kg: FloatArray
    sampled_kg: FloatArray
    q_min_rad: FloatArray
    q_max_rad: FloatArray
    configurations: int

    def covers(self, q_rad: FloatArray) -> bool:
        """Whether ``q_rad`` lies in the sampled box (False on nan)."""
        return bool(np.all(q_rad >= self.q_min_rad) and np.all(q_rad <= self.q_max_rad))


def link_mass_bounds(
    robot: RobotModel,
    payload_kg: float,
    waypoints_rad: FloatArray,
    box_samples: int = BOX_SAMPLES,
    seed: int = 15066,
) -> LinkMassBounds:
    """(M2) bounded per link over the program's path and a box around it (once at start-up; ~0.5 s for a UR5).

    Args:
        robot: the robot (its links and their capsule radii).
        payload_kg: the payload, a point mass at the last link's ``frame_b`` [kg].
        waypoints_rad: the program's waypoints, shape (W, n) [rad].
        box_samples: random configurations in the box around the waypoints (± :data:`BOX_MARGIN_RAD`).
        seed: of the box samples.
    """
    model = with_payload(robot.model, payload_kg, robot.frame_b_ids[-1])
    data = model.createData()
    q_min = np.maximum(waypoints_rad.min(axis=0) - BOX_MARGIN_RAD, model.lowerPositionLimit)
    q_max = np.minimum(waypoints_rad.max(axis=0) + BOX_MARGIN_RAD, model.upperPositionLimit)
    rng = np.random.default_rng(seed)
    configurations = np.vstack([path_samples(waypoints_rad), rng.uniform(q_min, q_max, (box_samples, model.nq))])
    sampled = np.zeros(len(robot.link_names))
    frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
    links = list(zip(robot.frame_a_ids, robot.frame_b_ids, robot.link_radius_m.tolist(), strict=True))
    for q in configurations:
        pin.computeJointJacobians(model, data, q)
        M_inv = inverse_inertia(model, data, q)
        jacobians = {f: pin.getFrameJacobian(model, data, f, frame) for f in {f for a, b, _ in links for f in (a, b)}}
        live = [i for i in range(len(links)) if math.isfinite(sampled[i])]
        points = [capsule_point_jacobians(jacobians[links[i][0]], jacobians[links[i][1]], links[i][2]) for i in live]
        if not points:
            break
        masses = largest_reflected_mass_kg(np.concatenate(points), M_inv).reshape(len(live), -1).max(axis=1)
        sampled[live] = np.maximum(sampled[live], masses)
    bound = sampled * (1.0 + MASS_BOUND_MARGIN)
    bound = np.where(bound > MASS_CAP_KG, np.inf, bound)
    return LinkMassBounds(bound, sampled, q_min, q_max, len(configurations))


_BOUNDS: dict[str, LinkMassBounds] = {}


def _bounds_key(robot: RobotModel, payload_kg: float, waypoints_rad: FloatArray) -> str:
    """A digest of everything :func:`link_mass_bounds` depends on (inertias, kinematics, links, payload, program)."""
    model = robot.model
    parts = [
        np.array([[i.mass, *i.lever, *i.inertia.ravel()] for i in model.inertias]),
        np.array([p.homogeneous for p in model.jointPlacements]),
        np.array([f.placement.homogeneous for f in model.frames]),
        np.array([*robot.frame_a_ids, *robot.frame_b_ids], dtype=float),
        robot.link_radius_m,
        np.array([payload_kg, MASS_BOUND_MARGIN, MASS_CAP_KG, BOX_MARGIN_RAD, BOX_SAMPLES, PATH_STEP_RAD]),
        np.asarray(waypoints_rad, dtype=float),
    ]
    digest = hashlib.sha256()
    for part in parts:
        digest.update(np.ascontiguousarray(part, dtype=float).tobytes())
    return digest.hexdigest()


def cached_link_mass_bounds(robot: RobotModel, payload_kg: float, waypoints_rad: FloatArray) -> LinkMassBounds:
    """:func:`link_mass_bounds`, computed once per process for the same robot, payload and program (~1.2 s for a UR5
    on a loaded 2-core machine: a sweep builds the method once per case)."""
    key = _bounds_key(robot, payload_kg, waypoints_rad)
    if key not in _BOUNDS:
        _BOUNDS[key] = link_mass_bounds(robot, payload_kg, waypoints_rad)
    return _BOUNDS[key]
