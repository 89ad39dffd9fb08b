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

from gateway.geometry import segment_distances
from gateway.kinematics import LinkKinematics, link_kinematics
from hrc_common.humans import HumanCapsules
from hrc_common.robot_model import RobotModel

FloatArray = npt.NDArray[np.float64]

MOVING_EPS_MPS = 0.01
"""A robot whose link end points all move slower than this counts as standing still [m/s]."""

UNKNOWN_ZONE = "unknown"
"""Zone label used for cycles fed without a gateway zone."""


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


def audit_links(
    links: LinkKinematics,
    link_radius_m: FloatArray,
    link_names: tuple[str, ...],
    delta_applied: float,
    controller_braking_time_s: float,
    humans: HumanCapsules,
    human_speed_mps: float,
    moving_eps_mps: float = MOVING_EPS_MPS,
) -> CycleAudit:
    """Both checks of safety-math.md §9 on link segments given directly (see :func:`audit_cycle`).

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
    if humans.n_capsules == 0:
        return CycleAudit(False, math.inf, False, None, None, None, None)
    speed2 = np.maximum(
        np.einsum("lj,lj->l", links.v_a_world, links.v_a_world), np.einsum("lj,lj->l", links.v_b_world, links.v_b_world)
    )
    speed_mps = math.sqrt(float(speed2.max())) if speed2.size else 0.0

    seg = segment_distances(links.p_a_world, links.p_b_world, humans.h_a_world, humans.h_b_world)
    surface_m = np.maximum(0.0, seg.distance_m - link_radius_m[:, None] - humans.radius_m[None, :])  # (L, H)

    # Closest points and the velocity of the link's closest point (exact for a rigid segment).
    s = seg.s_link[..., None]  # (L, H, 1)
    t = seg.t_capsule[..., None]
    p_link = links.p_a_world[:, None, :] + s * (links.p_b_world - links.p_a_world)[:, None, :]
    p_capsule = humans.h_a_world[None, :, :] + t * (humans.h_b_world - humans.h_a_world)[None, :, :]
    v_link = links.v_a_world[:, None, :] + s * (links.v_b_world - links.v_a_world)[:, None, :]
    along = np.einsum("lhj,lhj->lh", v_link, p_capsule - p_link)  # v · (capsule point − link point)
    centre_m = seg.distance_m  # = |capsule point − link point|
    apart = centre_m > 0.0
    v_toward = np.maximum(0.0, along) / np.where(apart, centre_m, 1.0)
    if not apart.all():
        # Centre lines touching: no direction to project on, count the whole speed as approaching.
        v_toward = np.where(apart, v_toward, np.sqrt(np.einsum("lhj,lhj->lh", v_link, v_link)))

    t_stop_s = max(0.0, delta_applied) * controller_braking_time_s
    margin = surface_m - (v_toward * t_stop_s / 2.0 + human_speed_mps * t_stop_s)
    i, j = np.unravel_index(int(np.argmin(margin)), margin.shape)
    margin_m = float(margin[i, j])
    contact = bool(surface_m.min() <= 0.0) and speed_mps > moving_eps_mps
    return CycleAudit(
        contact_while_moving=contact,
        margin_m=margin_m,
        violation=contact or margin_m < 0.0,
        min_distance_m=float(surface_m.min()),
        worst_link=link_names[int(i)],
        worst_capsule=int(j),
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
        return CycleAudit(False, math.inf, False, None, None, None, None)
    links = link_kinematics(robot, data, np.asarray(q_rad, dtype=float), np.asarray(qd_radps, dtype=float))
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
        }

    def to_json(self, indent: int | None = None) -> str:
        """The summary as a JSON document (see :meth:`to_dict`)."""
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)


class AuditAccumulator:
    """Folds audited cycles into an :class:`AuditSummary` (the mutable builder of a run).

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
    )
