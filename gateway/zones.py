"""Zones of one robot and their state machine (Zanchettin et al. 2016, Sec. IV-B, Fig. 7; Sec. V-B).

The zone is a label and a latch: it never raises δ. In ``safety_exception`` the commanded δ is held
at 0 until the separation is safe again (automatic recovery, no acknowledgement)."""

from __future__ import annotations

import math
from typing import NamedTuple

from hrc_contract.config import ZonesConfig
from hrc_contract.vocabulary import Zone


class ZoneThresholds(NamedTuple):
    """Distance thresholds of one decision, all surface-to-surface [m].

    Attributes:
        protective_m: the clearance Δ; at or below it the robot must stand still.
        resume_m: a safety exception ends only beyond this.
        reduce_m: beyond it, a link point moving straight at the human at the reference speed
            satisfies eq. (15) at full speed (rule (1) applied to the metric).
        monitored_m: the monitored workspace; beyond it (plus hysteresis) the robot is autonomous.
    """

    protective_m: float
    resume_m: float
    reduce_m: float
    monitored_m: float
    stop_below_delta: float = 0.0
    resume_above_delta: float = 0.0


class Protection(NamedTuple):
    """The safety exception of one method's stopping model (each :class:`gateway.methods.OverrideMethod` says).

    Attributes:
        protective_m: at or below this separation the robot must stand still [m].
        stop_below_delta: a bound at or below this also starts a safety exception (0: only a bound of 0 does).
        resume_above_delta: a safety exception ends only with a bound above this (and beyond ``resume_m``).
    """

    protective_m: float
    stop_below_delta: float = 0.0
    resume_above_delta: float = 0.0


def zone_thresholds(
    config: ZonesConfig,
    clearance_m: float,
    horizon_s: float,
    programmed_speed_mps: float,
    protection: Protection | None = None,
) -> ZoneThresholds:
    """Thresholds from the clearance Δ, the horizon T = t_b + t_delay, the link speed and the method's protection.

    ``reduce_m`` solves (d − Δ)² = T d v, the row of a point at distance d moving straight at the
    human with speed v: d = Δ + Tv/2 + sqrt((Δ + Tv/2)² − Δ²). With ``thresholds = "fixed"`` v is
    ``fixed_speed_mps``; with ``"adaptive"`` it is the current programmed speed ``programmed_speed_mps``.
    The protective and resume distances come from ``protection`` (the method's stopping model), Δ without one.
    """
    protection = Protection(clearance_m) if protection is None else protection
    speed = config.fixed_speed_mps if config.thresholds == "fixed" else programmed_speed_mps
    half = clearance_m + 0.5 * horizon_s * speed
    reduce = half + math.sqrt(max(0.0, half * half - clearance_m * clearance_m))
    protective_m, stop_below_delta, resume_above_delta = protection
    return ZoneThresholds(  # positional (a keyword call costs twice as much), in the order of the fields
        protective_m,
        max(config.resume_distance_m, protective_m + config.hysteresis_m),
        reduce,
        max(config.monitored_distance_min_m, reduce + config.guard_margin_m),
        stop_below_delta,
        resume_above_delta,
    )


def next_zone(
    zone: Zone,
    min_distance_m: float | None,
    delta_bound: float,
    thresholds: ZoneThresholds,
    config: ZonesConfig,
) -> Zone:
    """The zone after one decision.

    A safety exception starts at or below the method's protective distance, or with a bound at or below its
    ``stop_below_delta`` (0 for the methods that share Δ); it ends beyond ``resume_m`` with a bound above
    ``resume_above_delta``.

    Args:
        zone: the zone of the previous decision.
        min_distance_m: smallest surface distance to any human, None when nobody is seen [m].
        delta_bound: δ allowed by the method this cycle (eq. (15) by default).
        thresholds: this cycle's thresholds.
        config: hysteresis and the reduced-speed level.
    """
    if min_distance_m is None:
        return Zone.AUTONOMOUS
    if min_distance_m <= thresholds.protective_m or delta_bound <= thresholds.stop_below_delta or delta_bound <= 0.0:
        return Zone.SAFETY_EXCEPTION
    if zone is Zone.SAFETY_EXCEPTION and (
        min_distance_m < thresholds.resume_m or delta_bound <= thresholds.resume_above_delta
    ):
        return Zone.SAFETY_EXCEPTION
    leave_at_m = thresholds.monitored_m + (config.hysteresis_m if zone is not Zone.AUTONOMOUS else 0.0)
    if min_distance_m > leave_at_m and delta_bound >= 1.0:
        return Zone.AUTONOMOUS
    if zone is Zone.REDUCED_SPEED:
        return Zone.GUARDED_DISTANCE if delta_bound >= 1.0 else Zone.REDUCED_SPEED
    return Zone.REDUCED_SPEED if delta_bound < config.reduced_speed_below else Zone.GUARDED_DISTANCE


def commanded_override(zone: Zone, delta_bound: float) -> float:
    """δ to command: the bound of eq. (15), held at 0 during a safety exception. Never above the bound."""
    return 0.0 if zone is Zone.SAFETY_EXCEPTION else delta_bound
