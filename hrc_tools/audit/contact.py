"""The auditor's contact criterion (safety-math.md §12): every contact, its speed, and whether it was acceptable.

A method that allows transient contact (``lucci2020_pfl``) is judged, beside the separation checks of §9 (which it
may fail by design: it lets the robot touch), by what the contacts were:

- a **contact** is a link–capsule pair at surface distance ≤ 0 (coal, on the TRUE state) while the robot moves;
- its **speed** is the speed of the link's surface point closest to the capsule (all of it, not only the part toward
  the capsule: a conservative stand-in for the relative speed of ISO/TS 15066 Annex A), from that point's Jacobian;
- its **mass** m_R is the reflected mass of that point along the contact normal, 1 / (nᵀ J M(q)⁻¹ Jᵀ n), computed
  with Pinocchio at the contact's configuration (:class:`ContactMass`, payload as a point mass at the tool; ∞ where
  the point cannot move along n: then μ = m_H), not the simple form M/2 + m_payload;
- it is **acceptable** only if the capsule's body region allows transient contact (never the head, never a capsule
  of no region), the body part is not pinned (it lies farther than the clamp margin from every clamping surface, or
  the link's point does not move toward that surface), and the speed is at most the region's limit
  F_max / sqrt(μ k) (or sqrt(2 E_max / μ)), μ = (1/m_H + 1/m_R)⁻¹.

The limits are computed here from the cell's table, and the mass with the shared Pinocchio geometry of
:mod:`hrc_devices.robots.effective_mass`, with no code of ``gateway`` (the auditor stays independent of what it audits).
No I/O.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from hrc_contract.config import BodyRegion, Box
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.effective_mass import (
    capsule_point_jacobians,
    inverse_inertia,
    largest_reflected_mass_kg,
    reflected_mass_kg,
    with_payload,
)
from hrc_devices.robots.link_motion import LinkMotion
from hrc_devices.robots.model import RobotModel
from hrc_tools.audit.distance import CapsulePairs, CapsuleSet

FloatArray = npt.NDArray[np.float64]

CLAMP_AXIS_SAMPLES = 21
"""Points along a capsule's axis at which the auditor measures its distance to a clamping box."""


class Contact(NamedTuple):
    """One link–capsule pair in contact in one cycle.

    Attributes:
        link: link name; capsule: index into the audited :class:`HumanCapsules`; region: its body region
            (``unknown`` if none lists it).
        speed_mps: speed of the link's surface point closest to the capsule [m/s].
        limit_mps: the region's contact-safe speed for ``mass_kg`` (0: no contact allowed) [m/s].
        clamped: the body part lies within the clamp margin of a clamping surface and the point moves toward it.
        acceptable: transient region, not clamped, speed ≤ limit.
    """

    link: str
    capsule: int
    region: str
    speed_mps: float
    limit_mps: float
    clamped: bool
    acceptable: bool
    mass_kg: float = math.inf
    """The reflected mass of the contact point along the contact normal (∞: rigid along it) [kg]."""


class ContactMass:
    """The reflected mass and the speed of a link's surface point at a contact, from Pinocchio (the robot's URDF with
    the payload as a point mass at the tool). Holds Pinocchio scratch data; one per robot."""

    def __init__(self, robot: RobotModel, payload_kg: float) -> None:
        self.robot = robot
        self.model = with_payload(robot.model, payload_kg, robot.frame_b_ids[-1])
        self.data = self.model.createData()

    def at(
        self, q_rad: FloatArray, qd_radps: FloatArray, link: int, s: float, normal_world: FloatArray
    ) -> tuple[float, float]:
        """(speed [m/s], reflected mass [kg]) of the surface point of link ``link`` at abscissa ``s`` facing the unit
        ``normal_world`` (toward the person); a zero normal (axes touching) takes the largest mass in any direction."""
        model, data, robot = self.model, self.data, self.robot
        pin.computeJointJacobians(model, data, q_rad)
        frame = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        J_a = pin.getFrameJacobian(model, data, robot.frame_a_ids[link], frame)
        J_b = pin.getFrameJacobian(model, data, robot.frame_b_ids[link], frame)
        n_base = np.asarray(robot.R_world_base, dtype=float).T @ normal_world
        # the axis point, then moved r along n on the rigid body: J(p + r n) = J(p) − [r n]× J_ω
        J_axis = capsule_point_jacobians(J_a, J_b, 0.0, np.array([s]))[0]
        o = float(robot.link_radius_m[link]) * n_base
        skew = np.array([[0.0, -o[2], o[1]], [o[2], 0.0, -o[0]], [-o[1], o[0], 0.0]])
        J_point = J_axis - skew @ J_a[3:]
        speed_mps = float(np.linalg.norm(J_point @ qd_radps))
        M_inv = inverse_inertia(model, data, q_rad)
        if float(np.linalg.norm(n_base)) < 0.5:
            return speed_mps, float(largest_reflected_mass_kg(J_point[None], M_inv)[0])
        return speed_mps, reflected_mass_kg(J_point, M_inv, n_base)


class ContactRules(NamedTuple):
    """What the contact criterion needs of the cell (``safety.pfl_*``) and the robot."""

    regions: Mapping[str, BodyRegion]
    clamping_surfaces: Sequence[Box]
    clamp_margin_m: float
    mass: ContactMass
    """The robot's reflected mass at a contact."""


def contact_limit_mps(region: BodyRegion | None, robot_mass_kg: float) -> float:
    """The largest acceptable contact speed of a region [m/s]: 0 for no region or one without transient contact;
    ``robot_mass_kg`` = ∞ gives μ = m_H (a rigid robot)."""
    if region is None or not region.transient:
        return 0.0
    mu = 1.0 / (1.0 / region.mass_kg + 1.0 / robot_mass_kg)
    limits = []
    if region.max_force_n is not None and region.spring_constant_n_per_m is not None:
        limits.append(region.max_force_n / math.sqrt(mu * region.spring_constant_n_per_m))
    if region.max_energy_j is not None:
        limits.append(math.sqrt(2.0 * region.max_energy_j / mu))
    return min(limits)


def _pinned(a: FloatArray, b: FloatArray, radius_m: float, velocity: FloatArray, rules: ContactRules) -> bool:
    """Whether a body part (capsule a–b) lies within the clamp margin of a clamping box that ``velocity`` moves
    toward (or the part is inside the box)."""
    points = a[None, :] + np.linspace(0.0, 1.0, CLAMP_AXIS_SAMPLES)[:, None] * (b - a)[None, :]
    spacing = float(np.linalg.norm(b - a)) / (CLAMP_AXIS_SAMPLES - 1)
    for box in rules.clamping_surfaces:
        nearest = np.clip(points, np.asarray(box.min_m), np.asarray(box.max_m))
        gaps = np.linalg.norm(points - nearest, axis=-1)
        k = int(np.argmin(gaps))
        if gaps[k] - 0.5 * spacing - radius_m > rules.clamp_margin_m:
            continue
        toward = nearest[k] - points[k]
        if float(np.linalg.norm(toward)) <= 1e-9 or float(toward @ velocity) > 0.0:
            return True
    return False


def audit_contacts(
    links: LinkMotion,
    link_radius_m: FloatArray,
    link_names: tuple[str, ...],
    humans: HumanCapsules,
    rules: ContactRules,
    moving_eps_mps: float,
    q_rad: FloatArray,
    qd_radps: FloatArray,
) -> tuple[Contact, ...]:
    """Every contact of one cycle (TRUE link motion at joint positions ``q_rad`` and velocities ``qd_radps``, TRUE
    humans), with its speed, reflected mass and verdict; () with none.

    Only pairs whose distance lower bound is 0 are measured exactly (coal): the others cannot touch.
    """
    if humans.n_capsules == 0 or len(link_names) == 0:
        return ()
    pairs = CapsulePairs(
        CapsuleSet(links.p_a_world, links.p_b_world, link_radius_m),
        CapsuleSet(humans.h_a_world, humans.h_b_world, humans.radius_m),
    )
    candidates = np.argwhere(pairs.lower_bounds_m() <= 0.0)
    contacts = []
    region_of = {name: region for region, spec in rules.regions.items() for name in spec.capsules}
    for i, j in candidates.tolist():
        pair = pairs.exact(i, j)
        if pair.surface_m > 0.0:
            continue
        s = pair.s_first
        axis_velocity = links.v_a_world[i] + s * (links.v_b_world[i] - links.v_a_world[i])
        speed_mps, mass_kg = rules.mass.at(q_rad, qd_radps, i, s, np.asarray(pair.normal, dtype=float))
        speed_mps = max(speed_mps, float(np.linalg.norm(axis_velocity)))
        if speed_mps <= moving_eps_mps:
            continue
        region = region_of.get(humans.capsule_names[j], "unknown")
        limit_mps = contact_limit_mps(rules.regions.get(region), mass_kg)
        clamped = _pinned(humans.h_a_world[j], humans.h_b_world[j], float(humans.radius_m[j]), axis_velocity, rules)
        acceptable = limit_mps > 0.0 and not clamped and speed_mps <= limit_mps
        contacts.append(Contact(link_names[i], j, region, speed_mps, limit_mps, clamped, acceptable, mass_kg))
    return tuple(contacts)
