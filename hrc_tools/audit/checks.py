"""The auditor's checks (safety-math.md §9): pure functions of the TRUE robot state and the TRUE humans.

Every controller cycle, with the true joint state and the true human capsules (never what the gateway saw):

1. **contact while moving** — a link–capsule surface distance ≤ 0 while any link end point moves faster
   than ``moving_eps_mps`` (for a rigid segment the fastest point is an end point);
2. **could it still stop in time?** — if a stop were triggered now, the controller would ramp δ from
   δ_applied to 0 in ``t_stop = δ_applied · t_b`` (its linear ramp), each link point would travel
   ``|v_toward| · t_stop / 2`` toward the human and the human would approach at K for ``t_stop``.
   The margin of a link–capsule pair is

       margin = d_true − (|v_toward| · t_stop / 2 + K · t_stop)

   with ``v_toward`` the velocity of the link's closest point projected on the unit vector toward the
   capsule's closest point, counted only when approaching. A cycle violates when any margin < 0.

The smallest margin over a run is the run's safety margin. :class:`AuditAccumulator` folds the cycles
of a run into a frozen :class:`AuditSummary`. No I/O here.

The auditor is independent of what it audits: it uses no code of ``gateway``. Link end points and velocities
come from Pinocchio directly (:mod:`hrc_devices.robots.link_motion`),
surface distances from coal (:mod:`hrc_tools.audit.distance`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.link_motion import LinkMotion, link_motion
from hrc_devices.robots.model import RobotModel
from hrc_tools.audit.bounded import LargestN, largest_in_order
from hrc_tools.audit.contact import Contact
from hrc_tools.audit.distance import CapsulePairs, CapsuleSet

FloatArray = npt.NDArray[np.float64]

MOVING_EPS_MPS = 0.01
"""A robot whose link end points all move slower than this counts as standing still [m/s]."""

UNKNOWN_ZONE = "unknown"
"""Zone label used for cycles fed without a gateway zone."""
MAX_ONSET_SPEEDS = 10_000
"""Contact onset speeds a summary keeps (the fastest; all of them below this); the count of onsets is exact."""


class CycleAudit(NamedTuple):
    """The auditor's verdict on one controller cycle.

    Attributes:
        contact_while_moving: check 1: a surface distance ≤ 0 while the robot moves (> ε).
        margin_m: check 2: min over link–capsule pairs of d_true − (|v_toward| t_stop / 2 + K t_stop);
            +inf with no humans [m].
        violation: ``margin_m < 0`` or ``contact_while_moving``.
        min_distance_m: smallest true surface distance (clamped at 0), None with no humans [m].
        worst_link: link name of the pair with the smallest margin, None with no humans.
        worst_capsule: index (into the audited :class:`HumanCapsules`) of that pair's capsule, None with no humans.
        speed_mps: largest speed of any link end point, None with no humans (not computed) [m/s].
    """

    contact_while_moving: bool
    margin_m: float
    violation: bool
    min_distance_m: float | None
    worst_link: str | None
    worst_capsule: int | None
    speed_mps: float | None


_NO_HUMANS = CycleAudit(False, math.inf, False, None, None, None, None)
"""The verdict of a cycle with no pair to judge (no human capsule)."""


class _PairJudge:
    """The margin of one link–capsule pair from coal's exact distance (check 2 for that pair)."""

    def __init__(self, pairs: CapsulePairs, links: LinkMotion, t_stop_s: float, human_speed_mps: float) -> None:
        self.pairs = pairs
        self._v_a = links.v_a_world.tolist()
        self._v_b = links.v_b_world.tolist()
        self._t_stop_s = t_stop_s
        self._human_m = human_speed_mps * t_stop_s

    def margin_and_distance(self, i: int, j: int) -> tuple[float, float]:
        """(margin [m], surface distance clamped at 0 [m]) of link ``i`` and capsule ``j``."""
        pair = self.pairs.exact(i, j)
        surface_m = max(0.0, pair.surface_m)
        s = pair.s_first
        (vax, vay, vaz), (vbx, vby, vbz) = self._v_a[i], self._v_b[i]
        # The velocity of the link's closest point (exact for a rigid segment: linear along it).
        vx, vy, vz = vax + s * (vbx - vax), vay + s * (vby - vay), vaz + s * (vbz - vaz)
        nx, ny, nz = pair.normal
        if nx == 0.0 and ny == 0.0 and nz == 0.0:
            # Centre lines touching: no direction to project on, count the whole speed as approaching.
            v_toward = math.sqrt(vx * vx + vy * vy + vz * vz)
        else:
            v_toward = max(0.0, vx * nx + vy * ny + vz * nz)
        return surface_m - (v_toward * self._t_stop_s / 2.0 + self._human_m), surface_m


def audit_links(
    links: LinkMotion,
    link_radius_m: FloatArray,
    link_names: tuple[str, ...],
    delta_applied: float,
    controller_braking_time_s: float,
    humans: HumanCapsules,
    human_speed_mps: float,
    moving_eps_mps: float = MOVING_EPS_MPS,
) -> CycleAudit:
    """Both checks of safety-math.md §9 on link segments given directly (see :func:`audit_cycle`).

    The result is the one of evaluating every link–capsule pair with coal; only the pairs that can change it
    are evaluated (branch and bound on lower bounds, ~5 µs per exact pair against ~0.1 µs per bound):

    - Margin: for a pair, ``d ≥ d_low`` (:meth:`CapsulePairs.lower_bounds_m`) and
      ``v_toward ≤ max(|v_a|, |v_b|)`` of its link (the closest point's velocity is a convex combination of
      the end velocities, and a projection is no longer than the vector), so its margin is at least
      ``m_low = d_low − (max(|v_a|, |v_b|) t_stop / 2 + K t_stop)``. Pairs are evaluated in increasing
      ``m_low``; once ``m_low`` exceeds the smallest margin found, that pair and all later ones have a larger
      margin: the smallest margin is exact. Pairs whose ``m_low`` EQUALS it are still evaluated, so that the
      worst pair is, as for a full evaluation, the first in (link, capsule) order among equal margins.
    - Distance: the same in increasing ``d_low`` from the smallest distance of the pairs already evaluated:
      the smallest distance is exact, and so is check 1 (``min d ≤ 0``).
    - Violations: exact, since the smallest margin and distance are. A pair left out has margin > the
      smallest margin, so it could never be the one that violates.

    Args:
        links: true link end points and their TRUE velocities (at the actual joint velocity) [m, m/s].
        link_radius_m: capsule radius of each link, shape (L,) [m].
        link_names: name of each link.
        delta_applied: override the controller applies now, in [0, 1].
        controller_braking_time_s: the controller's δ 1 → 0 ramp time t_b [s].
        humans: true human capsules.
        human_speed_mps: approach speed K of the human [m/s].
        moving_eps_mps: speed below which the robot counts as standing still [m/s].
    """
    if humans.n_capsules == 0 or len(link_names) == 0:
        return _NO_HUMANS
    v_a, v_b = links.v_a_world, links.v_b_world
    end_speed_mps = np.sqrt(np.maximum(np.einsum("lj,lj->l", v_a, v_a), np.einsum("lj,lj->l", v_b, v_b)))  # (L,)
    speed_mps = float(end_speed_mps.max())
    t_stop_s = max(0.0, delta_applied) * controller_braking_time_s

    pairs = CapsulePairs(
        CapsuleSet(links.p_a_world, links.p_b_world, link_radius_m),
        CapsuleSet(humans.h_a_world, humans.h_b_world, humans.radius_m),
    )
    judge = _PairJudge(pairs, links, t_stop_s, human_speed_mps)
    n_capsules = humans.n_capsules
    distance_low = pairs.lower_bounds_m()  # (L, H)
    margin_low = (distance_low - (end_speed_mps * t_stop_s / 2.0 + human_speed_mps * t_stop_s)[:, None]).ravel()

    # Smallest margin: pairs in increasing lower bound until the bound exceeds the smallest margin found.
    margin_low_list = margin_low.tolist()
    margin_m, worst = math.inf, -1
    distances: dict[int, float] = {}  # flat pair index → exact surface distance, of the pairs evaluated
    for k in np.argsort(margin_low, kind="stable").tolist():
        if margin_low_list[k] > margin_m:
            break
        margin, distance = judge.margin_and_distance(*divmod(k, n_capsules))
        distances[k] = distance
        if margin < margin_m or (margin == margin_m and k < worst) or margin != margin:
            margin_m, worst = margin, k
            if margin != margin:  # nan: report it as the worst, as np.argmin would (never from a true state)
                break

    # Smallest distance: the same with the distance's own lower bounds, from the pairs already evaluated.
    min_distance_m = min(distances.values())
    if min_distance_m > 0.0:
        distance_low_flat = distance_low.ravel()
        distance_low_list = distance_low_flat.tolist()
        for k in np.argsort(distance_low_flat, kind="stable").tolist():
            if distance_low_list[k] >= min_distance_m:
                break
            if k not in distances:
                min_distance_m = min(min_distance_m, max(0.0, pairs.exact(*divmod(k, n_capsules)).surface_m))

    i, j = divmod(worst, n_capsules)
    contact = min_distance_m <= 0.0 and speed_mps > moving_eps_mps
    return CycleAudit(
        contact_while_moving=contact,
        margin_m=margin_m,
        violation=contact or margin_m < 0.0,
        min_distance_m=min_distance_m,
        worst_link=link_names[i],
        worst_capsule=j,
        speed_mps=speed_mps,
    )


def audit_cycle(
    robot: RobotModel,
    data: pin.Data,
    q_rad: FloatArray,
    qd_radps: FloatArray,
    delta_applied: float,
    controller_braking_time_s: float,
    humans: HumanCapsules,
    human_speed_mps: float,
    moving_eps_mps: float = MOVING_EPS_MPS,
) -> CycleAudit:
    """Audit one controller cycle against the truth (safety-math.md §9, checks 1 and 2).

    Args:
        robot: the robot model (link frames, radii, base pose).
        data: Pinocchio data of ``robot.model`` (scratch space; one per robot and thread).
        q_rad: TRUE joint positions [rad].
        qd_radps: TRUE actual joint velocities (δ_applied · q̇_nominal for the emulated controller) [rad/s].
        delta_applied: override the controller applies now, in [0, 1].
        controller_braking_time_s: the controller's own δ 1 → 0 time; t_stop = δ_applied · this [s].
        humans: TRUE human capsules (before noise, drops and latency).
        human_speed_mps: approach speed K of the human during the stop [m/s].
        moving_eps_mps: speed below which the robot counts as standing still [m/s].
    """
    if humans.n_capsules == 0:
        return _NO_HUMANS
    links = link_motion(robot, data, np.asarray(q_rad, dtype=float), np.asarray(qd_radps, dtype=float))
    return audit_links(
        links,
        robot.link_radius_m,
        robot.link_names,
        delta_applied,
        controller_braking_time_s,
        humans,
        human_speed_mps,
        moving_eps_mps,
    )


def open_stop_fraction(
    robot: RobotModel, data: pin.Data, q_rad: FloatArray, qd_radps: FloatArray, moving_eps_mps: float = MOVING_EPS_MPS
) -> float:
    """An *open* controller's stop still ahead, as a fraction of its stop time (the ``delta_applied`` of
    :func:`audit_cycle` for a robot that reports no override): it stops every joint at q̇max_j / T_c, so from q̇ its
    stop lasts max_j |q̇_j| / q̇max_j of T_c (docs/safety-math.md §13); 0 when every link end moves slower than
    ``moving_eps_mps`` (the standing robot of check 1: a position loop holding its reference creeps at far less).

    Args:
        robot: the robot model (the URDF's velocity limits, the open controller's q̇max).
        data: Pinocchio data of ``robot.model``.
        q_rad, qd_radps: TRUE joint positions [rad] and velocities [rad/s].
        moving_eps_mps: speed below which the robot counts as standing still [m/s].
    """
    qd = np.asarray(qd_radps, dtype=float)
    fraction = float(np.max(np.abs(qd) / np.asarray(robot.velocity_limit_radps, dtype=float), initial=0.0))
    if fraction > 0.0:
        ends = link_motion(robot, data, np.asarray(q_rad, dtype=float), qd)
        speed_mps = float(np.sqrt(np.maximum((ends.v_a_world**2).sum(1), (ends.v_b_world**2).sum(1)).max()))
        if speed_mps <= moving_eps_mps:
            fraction = 0.0
    return min(fraction, 1.0)


# -- a run's summary ---------------------------------------------------------------------------------


def _finite_or_none(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else value


@dataclass(frozen=True)
class AuditSummary:
    """What the auditor found over a run.

    Attributes:
        cycles: controller cycles audited.
        duration_s: audited time (sum of the cycle durations) [s].
        violations: cycles with a violation (check 1 or check 2).
        contacts_while_moving: cycles with contact while moving (check 1).
        smallest_margin_m: the run's safety margin (+inf if no human was ever present) [m].
        smallest_margin_t_s: when the smallest margin was seen [s], None if never.
        smallest_margin_pair: (link, capsule label) of the smallest margin, None if never.
        smallest_margin_moving_m: the smallest margin of the cycles in which the robot moved (faster than
            ε); a human touching a robot at standstill gives a margin of 0 that is no violation [m].
        first_violation_t_s: time of the first violation [s], None if none.
        min_distance_m: smallest true surface distance seen [m], None if no human was ever present.
        time_in_zone_s: time per gateway zone label [s].
        time_stopped_s: time with δ_applied == 0 [s].
        mean_delta_applied: time-weighted mean of δ_applied.
        program_cycles_completed: program cycles the controller completed (as last reported).
        contact_cycles: cycles with a contact while moving that the contact criterion judged (§12).
        unacceptable_contacts: cycles with a contact the contact criterion does not accept (too fast for the body
            region, at the head or a body part of no region, or clamped): the contact criterion's violations.
        contact_speeds_mps: the speed at the onset of every contact (a link–capsule pair that was not in contact the
            cycle before), in onset order; beyond :data:`MAX_ONSET_SPEEDS` onsets, the fastest of them [m/s].
        contact_onsets: how many contact onsets there were (all of them, kept or not).
        unacceptable_onsets: the onsets among them that were not acceptable.
    """

    cycles: int = 0
    duration_s: float = 0.0
    violations: int = 0
    contacts_while_moving: int = 0
    smallest_margin_m: float = math.inf
    smallest_margin_t_s: float | None = None
    smallest_margin_pair: tuple[str, str] | None = None
    smallest_margin_moving_m: float = math.inf
    first_violation_t_s: float | None = None
    min_distance_m: float | None = None
    time_in_zone_s: MappingProxyType[str, float] = field(default_factory=lambda: MappingProxyType({}))
    time_stopped_s: float = 0.0
    mean_delta_applied: float = 0.0
    program_cycles_completed: int = 0
    contact_cycles: int = 0
    unacceptable_contacts: int = 0
    contact_speeds_mps: tuple[float, ...] = ()
    unacceptable_onsets: int = 0
    contact_onsets: int = 0

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dictionary (an infinite margin becomes None)."""
        return {
            "cycles": self.cycles,
            "duration_s": round(self.duration_s, 6),
            "violations": self.violations,
            "contacts_while_moving": self.contacts_while_moving,
            "smallest_margin_m": _finite_or_none(self.smallest_margin_m),
            "smallest_margin_t_s": self.smallest_margin_t_s,
            "smallest_margin_pair": list(self.smallest_margin_pair) if self.smallest_margin_pair else None,
            "smallest_margin_moving_m": _finite_or_none(self.smallest_margin_moving_m),
            "first_violation_t_s": self.first_violation_t_s,
            "min_distance_m": self.min_distance_m,
            "time_in_zone_s": {k: round(v, 6) for k, v in sorted(self.time_in_zone_s.items())},
            "time_stopped_s": round(self.time_stopped_s, 6),
            "mean_delta_applied": self.mean_delta_applied,
            "program_cycles_completed": self.program_cycles_completed,
            "contact_cycles": self.contact_cycles,
            "unacceptable_contacts": self.unacceptable_contacts,
            "contact_speeds_mps": [round(v, 4) for v in self.contact_speeds_mps],
            "unacceptable_onsets": self.unacceptable_onsets,
            "contact_onsets": self.contact_onsets,
        }

    def to_json(self, indent: int | None = None) -> str:
        """The summary as a JSON document (see :meth:`to_dict`)."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)


class AuditAccumulator:
    """Folds audited cycles into an :class:`AuditSummary` (the mutable builder of a run).

    Its size does not grow with the run: running extremes, sums and counts, one time per zone label and at most
    2 × :data:`MAX_ONSET_SPEEDS` onset speeds (:attr:`n_items_stored` counts what it holds).

    Usage::

        acc = AuditAccumulator()
        for each controller cycle:
            acc.add(audit_cycle(...), t_s=..., dt_s=..., delta_applied=..., zone=..., program_cycles_completed=...)
        summary = acc.summary()
    """

    def __init__(self, moving_eps_mps: float = MOVING_EPS_MPS) -> None:
        self._moving_eps_mps = moving_eps_mps
        self._margin_moving_m = math.inf
        self._cycles = 0
        self._duration_s = 0.0
        self._violations = 0
        self._contacts = 0
        self._margin_m = math.inf
        self._margin_t_s: float | None = None
        self._margin_pair: tuple[str, str] | None = None
        self._first_violation_t_s: float | None = None
        self._min_distance_m: float | None = None
        self._zones: dict[str, float] = {}
        self._stopped_s = 0.0
        self._delta_time = 0.0
        self._program_cycles = 0
        self._contact_cycles = 0
        self._unacceptable = 0
        self._onset_speeds = LargestN(MAX_ONSET_SPEEDS)
        self._unacceptable_onsets = 0
        self._in_contact: frozenset[tuple[str, str]] = frozenset()

    @property
    def n_items_stored(self) -> int:
        """Figures held that a run could make grow: onset speeds, zone labels, pairs in contact now."""
        return self._onset_speeds.n_stored + len(self._zones) + len(self._in_contact)

    def add_contacts(self, contacts: Sequence[Contact], labels: Sequence[str]) -> None:
        """Count one cycle's contacts (:func:`hrc_tools.audit.contact.audit_contacts`); ``labels[k]`` names the capsule
        of ``contacts[k]`` across cycles (e.g. ``h1/hand_r``), so that a contact's onset is told from its
        continuation."""
        pairs = frozenset((c.link, label) for c, label in zip(contacts, labels, strict=True))
        if contacts:
            self._contact_cycles += 1
            if not all(c.acceptable for c in contacts):
                self._unacceptable += 1
        for contact, label in zip(contacts, labels, strict=True):
            if (contact.link, label) not in self._in_contact:
                self._onset_speeds.add(contact.speed_mps)
                self._unacceptable_onsets += not contact.acceptable
        self._in_contact = pairs

    def add(
        self,
        audit: CycleAudit,
        *,
        t_s: float,
        dt_s: float,
        delta_applied: float,
        zone: str | None = None,
        program_cycles_completed: int | None = None,
        capsule_label: str | None = None,
    ) -> None:
        """Count one audited cycle.

        Args:
            audit: the cycle's verdict.
            t_s: time of the cycle (run or wall clock, the caller's choice) [s].
            dt_s: duration this cycle stands for (the controller cycle) [s].
            delta_applied: the applied override this cycle.
            zone: the gateway's zone label for the robot this cycle (None: ``unknown``).
            program_cycles_completed: the controller's cumulative count, if known.
            capsule_label: a readable name of ``audit.worst_capsule`` (e.g. ``h1/hand_r``); default its index.
        """
        self._cycles += 1
        self._duration_s += dt_s
        if audit.violation:
            self._violations += 1
            if self._first_violation_t_s is None:
                self._first_violation_t_s = t_s
        if audit.contact_while_moving:
            self._contacts += 1
        if audit.margin_m < self._margin_m:
            self._margin_m = audit.margin_m
            self._margin_t_s = t_s
            if audit.worst_link is not None:
                label = capsule_label if capsule_label is not None else str(audit.worst_capsule)
                self._margin_pair = (audit.worst_link, label)
        if (
            audit.speed_mps is not None
            and audit.speed_mps > self._moving_eps_mps
            and audit.margin_m < self._margin_moving_m
        ):
            self._margin_moving_m = audit.margin_m
        if audit.min_distance_m is not None and (
            self._min_distance_m is None or audit.min_distance_m < self._min_distance_m
        ):
            self._min_distance_m = audit.min_distance_m
        label = zone if zone is not None else UNKNOWN_ZONE
        self._zones[label] = self._zones.get(label, 0.0) + dt_s
        if delta_applied == 0.0:
            self._stopped_s += dt_s
        self._delta_time += delta_applied * dt_s
        if program_cycles_completed is not None:
            self._program_cycles = max(self._program_cycles, program_cycles_completed)

    def summary(self) -> AuditSummary:
        """The frozen summary of the cycles added so far."""
        return AuditSummary(
            cycles=self._cycles,
            duration_s=self._duration_s,
            violations=self._violations,
            contacts_while_moving=self._contacts,
            smallest_margin_m=self._margin_m,
            smallest_margin_t_s=self._margin_t_s,
            smallest_margin_pair=self._margin_pair,
            smallest_margin_moving_m=self._margin_moving_m,
            first_violation_t_s=self._first_violation_t_s,
            min_distance_m=self._min_distance_m,
            time_in_zone_s=MappingProxyType(dict(self._zones)),
            time_stopped_s=self._stopped_s,
            mean_delta_applied=self._delta_time / self._duration_s if self._duration_s > 0.0 else 0.0,
            program_cycles_completed=self._program_cycles,
            contact_cycles=self._contact_cycles,
            unacceptable_contacts=self._unacceptable,
            contact_speeds_mps=self._onset_speeds.values(),
            unacceptable_onsets=self._unacceptable_onsets,
            contact_onsets=self._onset_speeds.count,
        )


def merge_summaries(summaries: Sequence[AuditSummary]) -> AuditSummary:
    """One summary of several (robots of a run, or runs of a sweep): counts and times add up, the
    smallest margin and distance are the smallest, δ is averaged over time.

    Times of the smallest margin and first violation are those of the summary they come from.
    """
    if not summaries:
        return AuditSummary()
    duration_s = sum(s.duration_s for s in summaries)
    worst = min(summaries, key=lambda s: s.smallest_margin_m)
    zones: dict[str, float] = {}
    for s in summaries:
        for zone, t_s in s.time_in_zone_s.items():
            zones[zone] = zones.get(zone, 0.0) + t_s
    firsts = [s.first_violation_t_s for s in summaries if s.first_violation_t_s is not None]
    distances = [s.min_distance_m for s in summaries if s.min_distance_m is not None]
    return AuditSummary(
        cycles=sum(s.cycles for s in summaries),
        duration_s=duration_s,
        violations=sum(s.violations for s in summaries),
        contacts_while_moving=sum(s.contacts_while_moving for s in summaries),
        smallest_margin_m=worst.smallest_margin_m,
        smallest_margin_t_s=worst.smallest_margin_t_s,
        smallest_margin_pair=worst.smallest_margin_pair,
        smallest_margin_moving_m=min(s.smallest_margin_moving_m for s in summaries),
        first_violation_t_s=min(firsts) if firsts else None,
        min_distance_m=min(distances) if distances else None,
        time_in_zone_s=MappingProxyType(zones),
        time_stopped_s=sum(s.time_stopped_s for s in summaries),
        mean_delta_applied=(
            sum(s.mean_delta_applied * s.duration_s for s in summaries) / duration_s if duration_s > 0.0 else 0.0
        ),
        program_cycles_completed=sum(s.program_cycles_completed for s in summaries),
        contact_cycles=sum(s.contact_cycles for s in summaries),
        unacceptable_contacts=sum(s.unacceptable_contacts for s in summaries),
        contact_speeds_mps=tuple(
            largest_in_order((v for s in summaries for v in s.contact_speeds_mps), MAX_ONSET_SPEEDS)
        ),
        unacceptable_onsets=sum(s.unacceptable_onsets for s in summaries),
        contact_onsets=sum(s.contact_onsets for s in summaries),
    )
