"""The override methods the gateway can run, selected by ``safety.method`` (safety-math.md §4, §7, §8).

Each method reduces one decision of one robot (kinematics, eq. (15) rows, humans, the measured delay)
to one δ bound in [0, 1]. Faults, zones and the safety-exception latch are applied after it by
:class:`gateway.core.SafetyCore`, the same for every method, so no method can command δ > 0 on a fault.

- ``zanchettin2016`` — eq. (15) with the measured delay (:mod:`gateway.separation`), the default.
- ``iso15066`` — ISO/TS 15066 speed and separation monitoring with the joint limits, QP (12) of
  Pupa et al. 2021 in closed form (:mod:`gateway.iso15066`).
- ``three_zones`` — Marvel 2013: δ = 0 / 0.5 / 1 from the distance of the tool point to the nearest
  human surface (``three_zones_stop_below_m``, ``three_zones_slow_below_m``), the tool point only.
- ``zanchettin2016_speed_aware`` — eq. (15) with the stopping time δ t_b of a controller that ramps the
  override down at a bounded rate (safety-math.md §10): a slowed robot stops sooner, so it may come closer.
  Its safety exception follows its own stopping model (:meth:`SpeedAware.protection`).
- ``lucci2020_pfl`` — speed and separation monitoring down to a contact-safe speed (Lucci et al., RA-L 2020;
  safety-math.md §12): the same form with the stop ending at each body region's contact-safe speed
  (:mod:`gateway.contact`, ISO/TS 15066 Annex A) instead of 0; the head, a body part that may be pinned against a
  clamping surface and a capsule of no region keep speed 0 (separation). Off unless the cell selects it.
- ``stop_only`` — δ = 0 while any human surface is within the protective separation distance of any
  link, else 1. The zone is sized as a laser-scanner field would be: ISO/TS 15066 S_p (safety-math.md §7)
  for a robot point moving straight at the human at ``stop_only_robot_speed_mps``, with T_r the measured
  delay and a stop in t_b: S_p = K (T_r + t_b) + v (T_r + t_b / 2) + c (1.6 m in the default cell).

Default three-zone thresholds (``configs/cell.toml``): the ISO/TS 15066 protective distance S_p of a tool
moving straight at the human, with v_h = 1.6 m/s, T_r = 0.15 s (the default cell's measured chain,
≈ 0.13 s, rounded up), the UR5's worst braking time t_b = 0.53 s (T_s = δ t_b), C = 0.05 m, and the
largest programmed link speed 1.5 m/s (``zones.fixed_speed_mps``; the shipped program peaks at 1.27 m/s):
at δ = 1 S_p = 1.6·0.68 + 1.5·0.15 + 1.5·0.53/2 + 0.05 = 1.76 m → slow below 1.8 m; at δ = 0.5
S_p = 1.6·0.415 + 0.75·0.15 + 0.75·0.265/2 + 0.05 = 0.93 m → stop below 1.0 m.

Every decision fails closed on a number that is not finite, in two layers. A decision whose scalars (t_delay,
Δ, δ_prev, T), joint state (q, q̇_nominal) or capsule end points are not finite gets δ = 0 from
:class:`gateway.core.SafetyCore`, once per decision for every method (the input door already rejects non-finite
messages; this guard holds the line behind it). Each method's reduction is written so that a nan in the rows or
distances it reads ends at 0, never at 1 (:func:`finite_or_zero`): in Python ``min(1.0, nan)`` is 1.0 and every
comparison with nan is False.

Eq. (16) of Pupa et al. 2021, the replan request, is :class:`ReplanMonitor`: the status flag is raised
while the commanded δ has stayed below ``replan_delta_below`` for ``replan_after_s``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import NamedTuple, Protocol

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from gateway import iso15066
from gateway.contact import (
    NO_REGION,
    ContactBounds,
    RegionTable,
    box_arrays,
    clamped_pairs,
    contact_bounds,
    contact_delta,
    link_joint_mask,
    link_surface_speed_mps,
    simple_robot_mass_kg,
)
from gateway.delay import NS_PER_S
from gateway.kinematics import LinkKinematics
from gateway.separation import (
    ConstraintRows,
    decision_clearance_m,
    human_speed_at_mps,
    override_from_rows,
    speed_aware_bounds,
    speed_aware_clearance_m,
)
from gateway.zones import Protection
from hrc_contract.config import ConfigError, SafetyConfig
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.effective_mass import LinkMassBounds, cached_link_mass_bounds
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import program_waypoints_rad

FloatArray = npt.NDArray[np.float64]

REDUCED_DELTA = 0.5
"""δ of the middle zone of ``three_zones`` (Marvel 2013)."""


class MethodInput(NamedTuple):
    """One decision of one robot, as every method sees it.

    Attributes:
        robot: the robot's model.
        data: its Pinocchio data (scratch space; a method that needs frames runs its own kinematics).
        q_rad: joint positions of this decision [rad].
        links: link end points and velocities at the programmed speed [m, m/s].
        rows: the eq. (15) rows of this decision (surface distances included); valid during this call only (the
            robot's compiled kernels write the next cycle's rows into the same arrays).
        humans: all human capsules seen.
        qd_nominal_radps: programmed joint velocity at 100 % override [rad/s].
        t_delay_s: the measured delay of the whole chain [s].
        clearance_m: the protective distance Δ of this decision [m].
        previous_delta: δ commanded in the previous cycle (after faults and zones).
        period_s: the gateway period [s].
        link_speed_max_mps: the largest speed of a link end point at the programmed speed (of ``links``) [m/s]; no
            point of a link is faster than its faster end.
    """

    robot: RobotModel
    data: pin.Data
    q_rad: FloatArray
    links: LinkKinematics
    rows: ConstraintRows
    humans: HumanCapsules
    qd_nominal_radps: FloatArray
    t_delay_s: float
    clearance_m: float
    previous_delta: float
    period_s: float
    link_speed_max_mps: float


class OverrideMethod(Protocol):
    """A method: one decision → one δ bound in [0, 1], and the safety exception of its stopping model."""

    name: str

    def bound(self, x: MethodInput) -> float: ...

    def protection(self, t_brake_max_s: float, t_delay_s: float, clearance_m: float | None = None) -> Protection:
        """The protective distance (and δ thresholds) of this decision's safety exception; ``clearance_m`` is the
        decision's Δ of :func:`gateway.separation.decision_clearance_m` when the caller has it [m]."""
        ...


class SharedClearance:
    """The safety exception at the paper's Δ = c + K (max t_b + t_delay) (eq. (11)–(12)), for the methods that
    share it."""

    safety: SafetyConfig

    def protection(self, t_brake_max_s: float, t_delay_s: float, clearance_m: float | None = None) -> Protection:
        """Δ of :func:`gateway.separation.decision_clearance_m` (``clearance_m`` when given: the core has it already),
        δ = 0 only on a bound of 0."""
        if clearance_m is None:
            clearance_m = decision_clearance_m(self.safety, t_brake_max_s, t_delay_s)
        return Protection(clearance_m)


def finite_or_zero(delta: float) -> float:
    """δ clipped to [0, 1]; 0 when it is nan or infinite (fail closed: ``min(1.0, nan)`` is 1.0 in Python)."""
    return min(max(delta, 0.0), 1.0) if math.isfinite(delta) else 0.0


class Zanchettin2016(SharedClearance):
    """Eq. (15) with the measured delay: the minimum of the row bounds (safety-math.md §4)."""

    name = "zanchettin2016"

    def __init__(self, safety: SafetyConfig) -> None:
        self.safety = safety

    def bound(self, x: MethodInput) -> float:
        return override_from_rows(x.rows)  # already in [0, 1], and 0 for a nan bound


class Iso15066(SharedClearance):
    """ISO/TS 15066 SSM with the joint limits: QP (12) of Pupa et al. 2021 in closed form (safety-math.md §7)."""

    name = "iso15066"

    def __init__(self, safety: SafetyConfig) -> None:
        self.safety = safety

    def bound(self, x: MethodInput) -> float:
        rows = iso15066.iso_rows(
            x.links, x.robot.link_radius_m, x.robot.t_brake_link_s, x.humans, self.safety, x.t_delay_s
        )
        joints = iso15066.joint_limit_bound(
            x.qd_nominal_radps,
            x.robot.velocity_limit_radps,
            self.safety.iso15066_joint_acceleration_limit_radps2,
            x.previous_delta,
            x.period_s,
        )
        return finite_or_zero(iso15066.override(rows, joints))


def point_surface_distance_m(p_world: FloatArray, humans: HumanCapsules) -> float:
    """Distance of a point to the nearest human capsule surface, inf with nobody seen [m]."""
    if not humans.n_capsules:
        return float("inf")
    d = humans.h_b_world - humans.h_a_world
    length2 = (d * d).sum(-1)
    safe = np.where(length2 > 1e-12, length2, 1.0)
    t = np.where(length2 > 1e-12, np.clip(((p_world - humans.h_a_world) * d).sum(-1) / safe, 0.0, 1.0), 0.0)
    axis = np.linalg.norm(humans.h_a_world + t[:, None] * d - p_world, axis=-1)
    return float(np.maximum(0.0, axis - humans.radius_m).min())


def three_zones_override(distance_m: float, stop_below_m: float, slow_below_m: float) -> float:
    """Marvel 2013: 0 at or below ``stop_below_m``, 0.5 at or below ``slow_below_m``, else 1; 0 for a nan
    distance (every comparison with nan is False, so only "beyond" raises δ)."""
    if distance_m > slow_below_m:
        return 1.0
    if distance_m > stop_below_m:
        return REDUCED_DELTA
    return 0.0


class ThreeZones(SharedClearance):
    """Three discrete zones on the tool point only (Marvel 2013; safety-math.md §8).

    The tool point is ``three_zones_tool_frame`` of each robot's URDF, or the ``frame_b`` of its last link.
    """

    name = "three_zones"

    def __init__(self, safety: SafetyConfig, robots: dict[str, RobotModel]) -> None:
        self.safety = safety
        self._tool_frame_id: dict[str, int | None] = {}
        frame = safety.three_zones_tool_frame
        for name, robot in robots.items():
            if frame is None:
                self._tool_frame_id[name] = None
            elif robot.model.existFrame(frame):
                self._tool_frame_id[name] = int(robot.model.getFrameId(frame))
            else:
                frames = ", ".join(f.name for f in robot.model.frames)
                raise ConfigError(
                    f"safety.three_zones_tool_frame = {frame!r} is not a frame of robot {name!r}; allowed: {frames}"
                )

    def tool_point_world(self, x: MethodInput) -> FloatArray:
        """The tool point in the world frame [m]."""
        frame_id = self._tool_frame_id[x.robot.name]
        if frame_id is None:
            return np.asarray(x.links.p_b_world[-1], dtype=float)
        pin.framesForwardKinematics(x.robot.model, x.data, x.q_rad)
        p_base = np.asarray(x.data.oMf[frame_id].translation, dtype=float)
        return np.asarray(x.robot.R_world_base @ p_base + x.robot.p_world_base, dtype=float)

    def bound(self, x: MethodInput) -> float:
        if not x.humans.n_capsules:
            return 1.0
        distance = point_surface_distance_m(self.tool_point_world(x), x.humans)
        if not math.isfinite(distance):  # with someone seen, an infinite distance is not a measurement
            return 0.0
        return three_zones_override(
            distance, self.safety.three_zones_stop_below_m, self.safety.three_zones_slow_below_m
        )


def stop_only_distance_m(
    safety: SafetyConfig, t_delay_s: float, t_brake_s: float, robot_speed_mps: float | None = None
) -> float:
    """ISO/TS 15066 S_p of a robot point moving straight at the human at ``robot_speed_mps`` (default
    ``stop_only_robot_speed_mps``) [m].

    S_p = K (T_r + T_s) + v T_r + v² / (2 a_s) + C with T_r = t_delay, a_s = v / t_b (so T_s = t_b and the
    braking distance is v t_b / 2) and C = ``clearance_static_m`` (safety-math.md §7).
    """
    v = safety.stop_only_robot_speed_mps if robot_speed_mps is None else robot_speed_mps
    robot_m = v * (t_delay_s + 0.5 * t_brake_s) + safety.clearance_static_m
    far = safety.human_speed_mps * (t_delay_s + t_brake_s) + robot_m
    return human_speed_at_mps(safety, far) * (t_delay_s + t_brake_s) + robot_m


class StopOnly(SharedClearance):
    """δ = 0 while any human is within the protective separation distance of any link, else 1 (§8)."""

    name = "stop_only"

    def __init__(self, safety: SafetyConfig) -> None:
        self.safety = safety

    def bound(self, x: MethodInput) -> float:
        d = x.rows.surface_distance_m
        if not d.size:
            return 1.0
        # sized for the configured speed, or the robot's own programmed speed now where that is faster (a program
        # faster than the zone was sized for must not walk into an undersized zone); nan stays nan: δ = 0 below
        sized_mps = self.safety.stop_only_robot_speed_mps
        speed_mps = sized_mps if x.link_speed_max_mps <= sized_mps else x.link_speed_max_mps
        limit_m = stop_only_distance_m(self.safety, x.t_delay_s, float(x.robot.braking_time_s.max()), speed_mps)
        nearest_m = float(d.min())  # nan if any distance is nan
        # Only a finite distance beyond a finite limit lets the robot move: nan compares False, inf is no distance.
        return 1.0 if math.isfinite(nearest_m) and math.isfinite(limit_m) and nearest_m > limit_m else 0.0


class SpeedAware:
    """Eq. (15) with the speed-aware stopping time δ t_b,→i (safety-math.md §10), the paper's own form.

    Per row ``δ (δ t_b,→i + t_delay) e ≤ max(0, d − Δ(δ))²`` with Δ(δ) = c + K (δ t_b,→i + t_delay), and per pair
    the human-alone bound δ ≤ (d − c − K t_delay) / (K t_b,→i): :func:`gateway.separation.speed_aware_bounds`. K is
    ISO 13855's close speed below ``speed_aware_close_speed_below_m`` (0.5 m). At δ = 1 the rows are eq. (15)'s
    with the per-link t_b,→i in Δ.

    It holds only for a controller that ramps the override down at least as fast as 1 → 0 in the planned t_b
    (``check_braking_time`` refuses a slower one) and follows the commanded override (the door's
    ``override_not_followed``). Its safety exception is its own: the robot is stopped while the bound is at or
    below ``speed_aware_stop_below_delta`` or the separation is within Δ at that δ, and resumes beyond that
    distance plus hysteresis once the bound is above ``speed_aware_resume_above_delta``.
    """

    name = "zanchettin2016_speed_aware"

    def __init__(self, safety: SafetyConfig) -> None:
        self.safety = safety
        self.close_speed_below_m = max(safety.close_speed_below_m, safety.speed_aware_close_speed_below_m)

    def human_speed_pair_mps(self, surface_distance_m: FloatArray) -> FloatArray:
        """K of every pair: the close speed below ``close_speed_below_m`` (ISO 13855), else the walking speed."""
        safety = self.safety
        return np.where(
            surface_distance_m < self.close_speed_below_m, safety.human_speed_close_mps, safety.human_speed_mps
        )

    def bound(self, x: MethodInput) -> float:
        d = x.rows.surface_distance_m
        bounds = speed_aware_bounds(
            d,
            x.rows.e_m2ps,
            x.robot.t_brake_link_s,
            x.t_delay_s,
            self.human_speed_pair_mps(d),
            self.safety.clearance_static_m,
        )
        lowest = bounds.min_bound  # inf when nothing bounds δ (nobody seen): δ = 1; nan: 0
        return 0.0 if lowest != lowest else min(max(lowest, 0.0), 1.0)

    def protection(self, t_brake_max_s: float, t_delay_s: float, clearance_m: float | None = None) -> Protection:
        """Δ(δ) at δ = ``speed_aware_stop_below_delta`` with the largest t_b (every link within it has a human-alone
        bound at or below that δ), and the method's δ thresholds (the decision's Δ ``clearance_m`` is not this
        method's)."""
        safety = self.safety
        delta = safety.speed_aware_stop_below_delta
        protective_m = speed_aware_clearance_m(safety, self.close_speed_below_m, delta, t_brake_max_s, t_delay_s)
        return Protection(protective_m, delta, safety.speed_aware_resume_above_delta)


class ContactAware(SpeedAware):
    """Speed and separation monitoring down to a contact-safe speed (Lucci et al. 2020; safety-math.md §12).

    Per pair, δ_c = f v_c / s_i (f = ``pfl_speed_fraction``, v_c the capsule's region speed for the link's effective
    mass, s_i the link's largest programmed point speed) is always allowed, and above it
    :func:`gateway.contact.contact_bounds`: the slow-down from δ to δ_c must end before the person reaches the link,
    in the rows and in the pair bound d ≥ Δ_c(δ). v_c = 0 (separation, exactly :class:`SpeedAware`'s bound) for the
    head, a capsule of no region, and a pair that may pin the capsule against a clamping surface
    (:func:`gateway.contact.clamped_pairs`).

    The effective mass (``pfl_mass_model = "link_bound"``): per link a constant, the largest reflected mass of any
    point of its capsule in any direction over the program's path and a box around it, plus a margin
    (:func:`hrc_devices.robots.effective_mass.link_mass_bounds`, once at start-up); ∞ (μ = m_H) for a link with a rigid
    direction, for every link while the robot is outside the sampled box, and for a robot without a program.
    ``"simple"`` (M/2 + m_payload; test-only, it understates the mass) is the documented comparison. Its safety
    exception: :class:`SpeedAware`'s δ thresholds, at no distance (contact is allowed): a bound at or below
    ``speed_aware_stop_below_delta`` stops the robot, as does any contact (d ≤ 0).

    After each :meth:`bound`, :meth:`bounded_by` names what bounded δ for that robot: ``separation:<region>``,
    ``clamping:<region>``, ``contact:<region>``, or ``none`` (δ = 1).
    """

    name = "lucci2020_pfl"

    def __init__(
        self, safety: SafetyConfig, robots: dict[str, RobotModel], programs: Mapping[str, str] | None = None
    ) -> None:
        """Raises: ConfigError: a robot's program cannot be read (its waypoints bound the effective mass)."""
        super().__init__(safety)
        self.regions = RegionTable(safety.pfl_body_regions)
        self._box_min_m, self._box_max_m = box_arrays(safety.pfl_clamping_surfaces)
        self._simple_kg = {name: simple_robot_mass_kg(r.model, safety.pfl_payload_kg) for name, r in robots.items()}
        self._joint_mask = {name: link_joint_mask(r.model, r.frame_a_ids, r.frame_b_ids) for name, r in robots.items()}
        self.mass_bounds: dict[str, LinkMassBounds] = {}
        for name, robot in robots.items():
            program = (programs or {}).get(name)
            if program is None:
                continue
            try:
                waypoints = program_waypoints_rad(program)
            except ConfigError as exc:
                raise ConfigError(f"robot {name!r}: program {program!r} unreadable (effective mass): {exc}") from exc
            self.mass_bounds[name] = cached_link_mass_bounds(robot, safety.pfl_payload_kg, waypoints)
        self._bounded_by: dict[str, str] = {}

    def bounded_by(self, robot: str) -> str | None:
        """What bounded δ in the robot's latest decision; None before one."""
        return self._bounded_by.get(robot)

    def link_masses_kg(self, x: MethodInput) -> FloatArray:
        """m_R of every link of this decision [kg]: the start-up bound (∞ outside its box, or with no program)."""
        n_links = len(x.robot.link_names)
        if self.safety.pfl_mass_model == "simple":
            return np.full(n_links, self._simple_kg[x.robot.name])
        bounds = self.mass_bounds.get(x.robot.name)
        if bounds is None or not bounds.covers(x.q_rad):
            return np.full(n_links, math.inf)
        return bounds.mass_kg

    def bound(self, x: MethodInput) -> float:
        d = x.rows.surface_distance_m
        links = x.links
        speeds = self.regions.speeds_mps(x.humans.capsule_names, self.link_masses_kg(x))
        clamped = clamped_pairs(
            links.v_a_world, links.v_b_world, x.humans, self._box_min_m, self._box_max_m, self.safety.pfl_clamp_margin_m
        )
        contact_mps = np.where(clamped, 0.0, self.safety.pfl_speed_fraction * speeds)
        link_speed_mps = link_surface_speed_mps(
            links.v_a_world, links.v_b_world, x.qd_nominal_radps, self._joint_mask[x.robot.name], x.robot.link_radius_m
        )
        bounds = contact_bounds(
            d,
            x.rows.e_m2ps,
            x.robot.t_brake_link_s,
            x.t_delay_s,
            self.human_speed_pair_mps(d),
            self.safety.clearance_static_m,
            contact_delta(contact_mps, link_speed_mps),
        )
        lowest = bounds.min_bound
        delta = 0.0 if lowest != lowest else min(max(lowest, 0.0), 1.0)
        self._bounded_by[x.robot.name] = self._what_bounded(bounds, clamped, x.humans.capsule_names, delta)
        return delta

    def _what_bounded(
        self, bounds: ContactBounds, clamped: npt.NDArray[np.bool_], names: tuple[str, ...], delta: float
    ) -> str:
        """The label of the pair whose bound is the smallest (``none`` at δ = 1; ``separation`` on a nan)."""
        if delta >= 1.0 or not names:
            return "none"
        per_pair = np.minimum(bounds.human, bounds.row.reshape(*bounds.human.shape, 4).min(axis=-1))
        if np.isnan(per_pair).any():
            return "separation"
        i, j = np.unravel_index(int(np.argmin(per_pair)), per_pair.shape)
        region = self.regions.region_names(names)[j]
        if clamped[i, j]:
            return f"clamping:{region}"
        spec = self.regions.regions.get(region)
        if region == NO_REGION or spec is None or not spec.transient or bounds.delta_contact[i, j] <= 0.0:
            return f"separation:{region}"
        return f"contact:{region}"

    def protection(self, t_brake_max_s: float, t_delay_s: float, clearance_m: float | None = None) -> Protection:
        """No protective distance beyond contact (d ≤ 0 stops the robot: contact is detected, then the stop); the δ
        thresholds of :class:`SpeedAware`."""
        safety = self.safety
        return Protection(0.0, safety.speed_aware_stop_below_delta, safety.speed_aware_resume_above_delta)


def build_method(
    safety: SafetyConfig, robots: dict[str, RobotModel], programs: Mapping[str, str] | None = None
) -> OverrideMethod:
    """The method named by ``safety.method``, checked against the robots (``programs``: each robot's program file,
    whose path bounds ``lucci2020_pfl``'s effective mass; without one, that robot's links count as rigid, m_R = ∞).

    Raises:
        ConfigError: ``three_zones_tool_frame`` is not a frame of every robot; a program cannot be read.
    """
    if safety.method == "iso15066":
        return Iso15066(safety)
    if safety.method == "three_zones":
        return ThreeZones(safety, robots)
    if safety.method == "stop_only":
        return StopOnly(safety)
    if safety.method == "zanchettin2016_speed_aware":
        return SpeedAware(safety)
    if safety.method == "lucci2020_pfl":
        return ContactAware(safety, robots, programs)
    return Zanchettin2016(safety)


class ReplanMonitor:
    """Eq. (16) of Pupa et al. 2021: request a replan once δ has stayed below a threshold for a while.

    A faulted decision clears the request and restarts the wait: replanning cannot help while the
    gateway cannot see, and the request is about a robot that people keep slow, not one that is blind.
    """

    def __init__(self, delta_below: float, after_s: float) -> None:
        self.delta_below = delta_below
        self._after_ns = int(after_s * NS_PER_S)
        self._below_since_ns: int | None = None

    def update(self, now_ns: int, delta: float, faulted: bool) -> bool:
        """Record the commanded δ of a decision at ``now_ns``; True while a replan is requested."""
        if faulted or delta >= self.delta_below:
            self._below_since_ns = None
            return False
        if self._below_since_ns is None:
            self._below_since_ns = now_ns
        return now_ns - self._below_since_ns >= self._after_ns
