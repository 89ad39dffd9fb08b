"""Cell configuration: TOML files in ``configs/`` parsed into frozen, validated models.

A cell file (``configs/cell.toml``) names the robots (each pointing to a robot model file and a
program), the trackers with their sensor properties, and the safety, zone and gateway parameters.
Every field carries its unit. Dangerous values refuse to load with a one-line reason that says what
is allowed (:class:`ConfigError`)."""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Mapping
from typing import Annotated, Any, ClassVar, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from hrc_contract.errors import HrcError
from hrc_contract.messages import NAME_PATTERN

ISO13855_WALKING_SPEED_MPS = 1.6
"""K of ISO 13855 for separations above 0.5 m (Zanchettin et al. 2016, eq. (11))."""

MAX_GUARD_TIME_S = 1.0
"""Longest time limit that guards safety: data age, controller watchdog, reaction-time floor [s]. A person walks
1.6 m in 1 s; a chain slower than that is no speed-and-separation monitoring, and a larger value is a unit slip
(milliseconds typed as seconds)."""
MIN_BRAKING_TIME_S = 0.02
"""Shortest braking time (full speed to standstill) of a joint or a controller [s]: five 4 ms controller cycles. No
industrial drive stops faster; a smaller value shrinks the clearance K t_b and the braking horizon to nothing."""
MAX_BRAKING_TIME_S = 5.0
"""Longest braking time [s]: beyond the stop of any industrial arm (a UR5 shoulder: 0.53 s); a unit slip."""

UNSAFE_ENV_VAR = "HRC_ALLOW_UNSAFE"
"""Environment variable that must name a test-only setting (comma-separated) for a configuration with it to load."""

Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=64)]
BrakingTime = Annotated[float, Field(ge=MIN_BRAKING_TIME_S, le=MAX_BRAKING_TIME_S, allow_inf_nan=False)]
PositiveFloat = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class ConfigError(HrcError):
    """The configuration cannot be loaded or is unsafe. The message is one line."""


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def unsafe_allowed(setting: str, environ: Mapping[str, str] | None = None) -> bool:
    """True if the environment variable :data:`UNSAFE_ENV_VAR` names ``setting`` (a comma-separated list).

    Args:
        setting: the name of a test-only setting, e.g. ``unsafe_ignore_delay_for_tests``.
        environ: the environment to read; None = this process's (``os.environ``).
    """
    value = (os.environ if environ is None else environ).get(UNSAFE_ENV_VAR, "")
    return setting in {name.strip() for name in value.split(",")}


def refuse_unless_named(value: bool, setting: str, what: str) -> bool:
    """``value`` of a test-only switch: true is refused unless :data:`UNSAFE_ENV_VAR` names ``setting``.

    Raises:
        ValueError: true, and the environment does not name it (the message says what it does and what is allowed).
    """
    if value and not unsafe_allowed(setting):
        raise ValueError(
            f"true is refused: a test-only setting ({what}) that makes the gateway unsafe; allowed: false, "
            f"or true with the environment variable {UNSAFE_ENV_VAR}={setting}"
        )
    return value


SafetyMethod = Literal[
    "zanchettin2016", "iso15066", "three_zones", "stop_only", "zanchettin2016_speed_aware", "lucci2020_pfl"
]
"""The override methods the gateway can run (safety-math.md §4, §7, §8, §10, §12; ``gateway/methods.py``)."""
SAFETY_METHODS: tuple[str, ...] = get_args(SafetyMethod)


class BodyRegion(_Frozen):
    """A body region's biomechanical limits for transient contact (ISO/TS 15066 Annex A; ``configs/body_regions.toml``).

    The contact-safe relative speed is F_max / sqrt(μ k) (force form) and sqrt(2 E_max / μ) (energy form), the
    smaller where both are given, with μ = (1/m_H + 1/m_R)⁻¹ (``gateway/contact.py``, safety-math.md §12). A region
    that is not ``transient`` (the head) has contact-safe speed 0: separation monitoring.
    """

    capsules: Annotated[list[str], Field(min_length=1)] = Field(
        description="The human capsule names of this region (``hand_l``, ``torso``, ...)."
    )
    transient: bool = Field(True, description="Transient contact allowed at all; false = contact-safe speed 0.")
    max_force_n: PositiveFloat | None = Field(None, description="F_max of transient contact [N].")
    spring_constant_n_per_m: PositiveFloat | None = Field(None, description="k of the region [N/m].")
    max_energy_j: PositiveFloat | None = Field(None, description="E_max of transient contact [J].")
    mass_kg: PositiveFloat = Field(description="m_H, the region's effective mass [kg].")

    @model_validator(mode="after")
    def _a_limit(self) -> BodyRegion:
        force = self.max_force_n is not None and self.spring_constant_n_per_m is not None
        if self.transient and not force and self.max_energy_j is None:
            raise ValueError(
                "a transient region needs max_force_n with spring_constant_n_per_m, or max_energy_j; "
                "allowed: one of them, or transient = false"
            )
        return self


class SafetyConfig(_Frozen):
    """Parameters of the separation criterion (safety-math.md §3–§5) and of the selectable methods (§7–§8).

    Time limits that guard safety have an upper bound (a larger value is less safe, or a unit slip). Values for
    which larger is only more cautious (human speeds, clearances, uncertainties, zone distances) have none.
    """

    method: SafetyMethod = Field(
        "zanchettin2016",
        description="How δ is computed: eq. (15) with the measured delay (default), ISO/TS 15066 SSM, "
        "three discrete zones on the tool point, or stop-only.",
    )
    human_speed_mps: PositiveFloat = ISO13855_WALKING_SPEED_MPS
    human_speed_close_mps: PositiveFloat = 2.0
    close_speed_below_m: NonNegativeFloat = Field(
        0.0,
        description="Use human_speed_close_mps when the separation is below this [m]; 0 = off (ISO 13855 uses 0.5).",
    )
    clearance_static_m: NonNegativeFloat = 0.05
    t_reaction_s: Annotated[float, Field(ge=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.04,
        description="Floor of the reaction time; the measured delays are added to it [s]. At most 1 s: the "
        "default cell's whole measured chain is about 0.13 s, and a floor of seconds is a unit slip (ms).",
    )
    max_data_age_s: Annotated[float, Field(gt=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.2,
        description="Older human data, joint state or override echo stops the robot [s]. At most 1 s: a person "
        "walks 1.6 m in that time, so older data no longer describes the cell, and accepting it hides a dead "
        "sensor or link for that long.",
    )
    allow_human_speed_below_iso13855: bool = False
    unsafe_ignore_delay_for_tests: bool = Field(
        False,
        description="TEST ONLY: t_delay = 0, to show that the delay terms matter. Never in a real cell: refused "
        f"unless the environment variable {UNSAFE_ENV_VAR} names it ({UNSAFE_ENV_VAR}=unsafe_ignore_delay_for_tests).",
    )
    # -- method "iso15066" (Pupa et al. 2021; safety-math.md §7) -----------------------------------------
    iso15066_human_uncertainty_m: NonNegativeFloat = Field(
        0.0, description="Z_d of ISO/TS 15066: position uncertainty of the operator (sensing) [m]."
    )
    iso15066_robot_uncertainty_m: NonNegativeFloat = Field(
        0.0, description="Z_r of ISO/TS 15066: position uncertainty of the robot [m]."
    )
    iso15066_joint_acceleration_limit_radps2: Annotated[float, Field(gt=0.0, le=100.0, allow_inf_nan=False)] = Field(
        10.0,
        description="Joint acceleration limit of QP (12), every joint [rad/s²]; bounds how fast δ may rise. At most "
        "100 rad/s²: beyond any industrial arm's joints; a larger value is a unit slip (deg/s²).",
    )
    # -- method "three_zones" (Marvel 2013; safety-math.md §8) -------------------------------------------
    three_zones_tool_frame: str | None = Field(
        None, description="URDF frame of the tool point; None = frame_b of the robot's last link."
    )
    three_zones_stop_below_m: NonNegativeFloat = Field(
        1.0, description="δ = 0 while a human surface is at or below this distance from the tool point [m]."
    )
    three_zones_slow_below_m: PositiveFloat = Field(
        1.8, description="δ = 0.5 at or below this distance (and above the stop distance), else δ = 1 [m]."
    )
    # -- method "stop_only" (safety-math.md §8) ----------------------------------------------------------
    stop_only_robot_speed_mps: PositiveFloat = Field(
        1.5,
        description="Robot speed the stop-only protective zone is sized for: the largest programmed speed of "
        "any link point, assumed toward the human (S_r and S_s of ISO/TS 15066) [m/s].",
    )
    # -- method "zanchettin2016_speed_aware" (eq. (15) with the stopping time δ t_b; safety-math.md §10) ---
    speed_aware_close_speed_below_m: NonNegativeFloat = Field(
        0.5,
        description="This method uses human_speed_close_mps below this separation (ISO 13855: 0.5 m), or below "
        "close_speed_below_m if that is larger [m].",
    )
    speed_aware_stop_below_delta: Annotated[float, Field(ge=0.0, le=0.5)] = Field(
        0.05,
        description="This method's safety exception: the robot is stopped (δ = 0) while its bound is at or below "
        "this, and its protective distance is Δ(δ) = c + K (δ t_b + t_delay) at this δ. At most 0.5.",
    )
    speed_aware_resume_above_delta: Annotated[float, Field(ge=0.0, le=0.5)] = Field(
        0.1,
        description="This method's safety exception ends only once its bound is above this (hysteresis on δ; at "
        "least speed_aware_stop_below_delta). At most 0.5.",
    )
    # -- method "lucci2020_pfl" (separation down to a contact-safe speed; safety-math.md §12) ---------------
    pfl_body_regions: dict[str, BodyRegion] = Field(
        default_factory=dict,
        description="Body regions and their limits; in the cell file a path to a TOML file (configs/body_regions.toml) "
        "whose [regions] the loader reads in. A capsule of no region has contact-safe speed 0.",
    )
    pfl_payload_kg: NonNegativeFloat = Field(0.0, description="m_payload of the simple mass form M/2 + m_payload [kg].")
    pfl_mass_model: Literal["link_bound", "simple"] = Field(
        "link_bound",
        description="m_R of the decision: per link the largest reflected mass over the program's path, every point "
        "and direction, plus a margin (hrc_devices/robots/effective_mass.py, once at start-up). 'simple' "
        "(M/2 + m_payload) "
        f"understates it and is refused unless {UNSAFE_ENV_VAR}=pfl_simple_mass_for_tests (comparison only).",
    )
    pfl_speed_fraction: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.8,
        description="The method plans with this fraction of each region's contact-safe speed: the margin for the "
        "program's speed rising during the slow-down. At most 1.",
    )
    pfl_clamp_margin_m: NonNegativeFloat = Field(
        0.1,
        description="A human capsule within this of a clamping surface, with a link moving toward that surface, "
        "may be clamped: contact-safe speed 0 [m].",
    )
    pfl_clamping_surfaces: list[Box] = Field(
        default_factory=list,
        description="The table, walls, fixtures against which a body part can be pinned, as boxes (world frame) [m].",
    )
    # -- replan request, eq. (16) of Pupa et al. 2021 (every method) --------------------------------------
    replan_delta_below: Annotated[float, Field(ge=0.0, le=1.0)] = Field(
        0.2, description="Request a replan when the commanded δ stays below this for replan_after_s; 0 = never."
    )
    replan_after_s: NonNegativeFloat = Field(
        1.0, description="How long δ must stay below replan_delta_below before a replan is requested [s]."
    )

    @field_validator("method", mode="before")
    @classmethod
    def _known_method(cls, value: object) -> object:
        if value not in SAFETY_METHODS:
            raise ValueError(f"unknown method {value!r}; allowed: {', '.join(SAFETY_METHODS)}")
        return value

    @field_validator("unsafe_ignore_delay_for_tests")
    @classmethod
    def _unsafe_only_when_named(cls, value: bool) -> bool:
        return refuse_unless_named(value, "unsafe_ignore_delay_for_tests", "t_delay = 0")

    @field_validator("pfl_mass_model")
    @classmethod
    def _simple_mass_only_when_named(cls, value: str) -> str:
        refuse_unless_named(value == "simple", "pfl_simple_mass_for_tests", "m_R = M/2 + m_payload, understated")
        return value

    @model_validator(mode="after")
    def _three_zones_are_ordered(self) -> SafetyConfig:
        if self.three_zones_slow_below_m <= self.three_zones_stop_below_m:
            raise ValueError(
                f"three_zones_slow_below_m = {self.three_zones_slow_below_m} is not beyond "
                f"three_zones_stop_below_m = {self.three_zones_stop_below_m}; allowed: slow > stop"
            )
        return self

    @model_validator(mode="after")
    def _speed_aware_hysteresis(self) -> SafetyConfig:
        if self.speed_aware_resume_above_delta < self.speed_aware_stop_below_delta:
            raise ValueError(
                f"speed_aware_resume_above_delta = {self.speed_aware_resume_above_delta} is below "
                f"speed_aware_stop_below_delta = {self.speed_aware_stop_below_delta}; allowed: >= it"
            )
        return self

    @model_validator(mode="after")
    def _human_speed_is_safe(self) -> SafetyConfig:
        if self.human_speed_mps < ISO13855_WALKING_SPEED_MPS and not self.allow_human_speed_below_iso13855:
            raise ValueError(
                f"human_speed_mps = {self.human_speed_mps} is below the ISO 13855 walking speed; allowed: "
                f">= {ISO13855_WALKING_SPEED_MPS}, or set allow_human_speed_below_iso13855 = true"
            )
        if self.human_speed_close_mps < self.human_speed_mps:
            raise ValueError(
                f"human_speed_close_mps = {self.human_speed_close_mps} is below human_speed_mps = "
                f"{self.human_speed_mps}; allowed: >= human_speed_mps"
            )
        return self


class ZonesConfig(_Frozen):
    """Zone thresholds and hysteresis (safety-math.md §6, paper Sec. V-B)."""

    thresholds: Literal["adaptive", "fixed"] = Field(
        "adaptive",
        description="Monitored distance from the current programmed speed, or from fixed_speed_mps.",
    )
    fixed_speed_mps: PositiveFloat = Field(1.5, description="Largest programmed link speed, for 'fixed' [m/s].")
    adaptive_speed_hold_s: Annotated[float, Field(ge=0.0, le=60.0, allow_inf_nan=False)] = Field(
        2.0,
        description="'adaptive' uses the largest programmed link speed of this last stretch of time [s]. At most "
        "60 s: the hold bridges the program's slow stretches between fast moves (a few seconds); a longer one "
        "only keeps a stale peak, and minutes are a unit slip (ms).",
    )
    monitored_distance_min_m: NonNegativeFloat = Field(
        1.0, description="A human closer than this (beyond the clearance) is always 'in the workspace' [m]."
    )
    guard_margin_m: NonNegativeFloat = Field(
        0.5, description="The workspace reaches this far beyond the reduced-speed threshold [m]."
    )
    hysteresis_m: NonNegativeFloat = 0.15
    resume_distance_m: NonNegativeFloat = Field(
        0.4, description="Safety exception is left only beyond max(this, clearance + hysteresis) [m]."
    )

    reduced_speed_below: Annotated[float, Field(gt=0.0, le=1.0)] = Field(
        0.98, description="Enter reduced_speed when δ drops below this; back to guarded at δ = 1."
    )


class PlannerConfig(_Frozen):
    """The planner layer above the scaling (paper 2, Pupa et al. 2021; docs/planner.md): open robots only.

    Safety never depends on it: the LPs (9)/(13) bound every command whatever trajectory the robot follows.
    """

    enabled: bool = Field(False, description="Replan open robots' paths around people (off: they scale and wait).")
    horizon_s: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = Field(
        0.6,
        description="How far ahead the trajectory is checked against the people, every check; shorter than "
        "horizon_step_s: no configuration is checked (only the request (16) replans) [s].",
    )
    horizon_step_s: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.1, description="Spacing of the configurations checked along the horizon [s]."
    )
    check_every_s: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.1, description="How often the horizon is checked (the trackers' rate is enough; not every loop) [s]."
    )
    clearance_m: Annotated[float, Field(ge=0.0, le=2.0, allow_inf_nan=False)] = Field(
        0.05,
        description="Planned paths keep the links this far beyond the zones' resume distance (nearer, the zones hold "
        "the robot at δ = 0) from the people, who are also grown by safety.human_speed_mps times the time until the "
        "robot gets there, up to plan_growth_s (the horizon check) [m].",
    )
    plan_growth_s: Annotated[float, Field(ge=0.0, le=2.0, allow_inf_nan=False)] = Field(
        0.0,
        description="The planner grows the people by safety.human_speed_mps times this on top of clearance_m, so "
        "that a new path passes the horizon check where it starts [s].",
    )
    join_lead_s: Annotated[float, Field(ge=0.0, le=2.0, allow_inf_nan=False)] = Field(
        0.1, description="The new path starts this far ahead on the trajectory (the robot moves while it plans) [s]."
    )
    time_limit_s: Annotated[float, Field(gt=0.0, le=5.0, allow_inf_nan=False)] = Field(
        0.3, description="RRT-Connect's time limit per solve [s]."
    )
    retry_after_s: Annotated[float, Field(gt=0.0, le=60.0, allow_inf_nan=False)] = Field(
        0.5, description="After a failed plan, the same robot asks again no sooner than this [s]."
    )
    seed: Annotated[int, Field(ge=1)] = Field(1, description="OMPL's seed (each request adds its number to it).")


class GatewayConfig(_Frozen):
    """The gateway's loop: fixed-rate ticks, plus a decision at once when a tracker frame arrives."""

    rate_hz: Annotated[float, Field(ge=10.0, le=2000.0)] = 250.0
    status_rate_hz: Annotated[float, Field(gt=0.0, le=100.0)] = 25.0
    http_host: str = "127.0.0.1"
    http_port: Annotated[int, Field(ge=0, le=65535)] = 8080
    event_driven: bool = Field(
        True,
        description="Decide at once when a tracker frame arrives (an event cycle between the fixed-rate "
        "ticks), instead of at the next tick only.",
    )
    min_event_interval_s: Annotated[float, Field(ge=0.0, le=1.0)] = Field(
        0.001,
        description="Event cycles start at least this long apart, so that a flood of tracker messages "
        "cannot starve the loop [s].",
    )
    event_guard_s: Annotated[float, Field(ge=0.0, le=1.0)] = Field(
        0.0002,
        description="No event cycle starts when the next tick is due within this time: the tick serves the "
        "frame instead (a reaction later by at most this), and an event cycle shorter than this cannot "
        "make the tick late. At or above the period (1 / rate_hz) there are no event cycles [s].",
    )
    loop_realtime_priority: Annotated[int, Field(ge=0, le=99)] = Field(
        0,
        description="Linux SCHED_FIFO priority of the safety loop's thread (1-99; needs root or CAP_SYS_NICE; "
        "the gateway starts anyway and logs a warning if it is refused); 0 = normal scheduling.",
    )
    io_realtime_priority: Annotated[int, Field(ge=0, le=98)] = Field(
        0,
        description="Linux SCHED_FIFO priority of the gateway's I/O threads (Zenoh's threads that receive inputs, "
        "the thread that feeds the HTTP child, the status thread, the recorder, the log writer), below "
        "loop_realtime_priority; "
        "0 = normal scheduling. They share Python's interpreter lock with the loop: at normal priority any other "
        "program can deschedule one while it holds the lock, and the loop waits (a priority inversion, seen with many "
        "robots).",
    )

    @model_validator(mode="after")
    def _io_below_the_loop(self) -> GatewayConfig:
        if self.io_realtime_priority and not 0 < self.io_realtime_priority < self.loop_realtime_priority:
            raise ValueError(
                f"io_realtime_priority = {self.io_realtime_priority} with loop_realtime_priority = "
                f"{self.loop_realtime_priority}; allowed: 0 (off), or 1 to loop_realtime_priority - 1 (the loop "
                "must be able to preempt the receiving threads)"
            )
        return self


class ControllerConfig(_Frozen):
    """The emulated controller's own behaviour (a real controller's is fixed by its vendor)."""

    control: Literal["closed", "open"] = Field(
        "closed",
        description='"closed": the controller runs its program and takes only a speed override (hrc.override/1); '
        '"open": it follows joint references streamed every cycle (hrc.joint_command/1, e.g. ABB EGM) and the '
        "gateway runs the program through LP (9)/(13) of paper 1.",
    )

    cycle_s: Annotated[float, Field(ge=0.0005, le=0.1)] = 0.004
    braking_time_s: BrakingTime = Field(
        0.24,
        description="Override 1 → 0 takes at most this long [s]. 0.02–5 s: a real drive's stop (nanoseconds "
        "would hide every delay from the tests); it must not exceed the t_b of any link the gateway assumes.",
    )
    accel_time_s: Annotated[float, Field(ge=MIN_BRAKING_TIME_S, le=10.0, allow_inf_nan=False)] = Field(
        0.5,
        description="Override 0 → 1 takes at least this long [s]. 0.02–10 s: a real drive's ramp; more is a unit slip.",
    )
    watchdog_s: Annotated[float, Field(gt=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.1,
        description="No valid override for this long → protective stop [s]. At most 1 s: until then a silent "
        "gateway leaves the robot running at the last override.",
    )


class LinkSegment(_Frozen):
    """A robot link as a capsule between two URDF frames fixed on the same rigid body."""

    name: Annotated[str, Field(min_length=1, max_length=64)]
    frame_a: str
    frame_b: str
    radius_m: NonNegativeFloat


class RobotModelConfig(_Frozen):
    """A robot model: its URDF, joints, braking times and link capsules (``configs/robots/*.toml``)."""

    urdf: str
    joints: Annotated[list[str], Field(min_length=1)]
    braking_time_s: Annotated[list[BrakingTime], Field(min_length=1)] = Field(
        description="Stopping time of each joint from full speed, in the order of joints [s]; 0.02–5 s each: a "
        "real drive's (the robot's manual, stop category 0 or 1); t_b of eq. (15) and of ISO/TS 15066 S_s."
    )
    links: Annotated[list[LinkSegment], Field(min_length=1)]

    @model_validator(mode="after")
    def _one_braking_time_per_joint(self) -> RobotModelConfig:
        if len(self.braking_time_s) != len(self.joints):
            raise ValueError(
                f"braking_time_s has {len(self.braking_time_s)} values for {len(self.joints)} joints; "
                "allowed: one per joint, in the order of joints"
            )
        return self


class Pose(_Frozen):
    xyz: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)
    rpy: tuple[Finite, Finite, Finite] = (0.0, 0.0, 0.0)


class ZenohInterfaceConfig(_Frozen):
    """The controller speaks the cell's Zenoh contract itself (the emulator's own face): no bridge."""

    kind: Literal["zenoh"] = "zenoh"


class _BridgeInterfaceConfig(_Frozen):
    """What every closed controller's bridge (``controller_bridge``) needs besides its vendor's address."""

    CONTROL: ClassVar[Literal["closed", "open"]] = "closed"
    """The controller this interface serves: a closed one's speed input."""

    watchdog_s: Annotated[float, Field(gt=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.1,
        description="No valid override for this long → the bridge writes 0 itself [s]. A real controller keeps its "
        "speed input forever; at most the robot's controller.watchdog_s (checked) and 1 s.",
    )
    read_timeout_s: Annotated[float, Field(gt=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.1,
        description="No valid read-back for this long → the bridge stops publishing the joint state (the gateway's "
        "staleness check stops the robot) and reconnects [s]. At most 1 s.",
    )
    write_rate_hz: Annotated[float, Field(ge=1.0, le=500.0, allow_inf_nan=False)] = Field(
        125.0,
        description="The speed input is written at least this often, as a heartbeat, and at once on a new override.",
    )
    rise_time_s: Annotated[float, Field(ge=0.0, le=10.0, allow_inf_nan=False)] = Field(
        1.0,
        description="The longest time the controller takes to reach a raised speed input, from 0 to 1 [s]: the "
        "bridge bounds the applied scaling from below by the smallest read-back over this window (qd_nominal = "
        "velocity / that bound, controller_bridge/bridge.py). At least the robot's controller.accel_time_s "
        "(checked); 0 only on ur_rtde, whose read-back speed_scaling × target_speed_fraction shows the applied "
        "scaling while it rises (docs/controllers.md says what to check on the robot first).",
    )


class UrRtdeInterfaceConfig(_BridgeInterfaceConfig):
    """Universal Robots over RTDE (port 30004): the speed slider in, ``target_speed_fraction`` etc. out."""

    kind: Literal["ur_rtde"]
    host: Annotated[str, Field(min_length=1, max_length=253, pattern=r"^[A-Za-z0-9.:_-]+$")] = Field(
        description="The controller's address (IPv4, IPv6 or host name, no port: RTDE's port is 30004)."
    )
    frequency_hz: Literal[125, 500] = Field(500, description="RTDE output frequency: 125 (CB3) or 500 (e-Series) [Hz].")


class AbbRwsInterfaceConfig(_BridgeInterfaceConfig):
    """ABB over Robot Web Services: the speed ratio (integer percent, rounded down), HTTP Digest authentication."""

    kind: Literal["abb_rws"]
    url: Annotated[str, Field(pattern=r"^https?://[^\s/]+(/[^\s]*)?$", max_length=400)] = Field(
        description="Base URL of the controller's RWS, e.g. http://192.168.125.1 (RWS 1.0) or https://… (2.0)."
    )
    user: Annotated[str, Field(min_length=1, max_length=64)] = "Default User"
    password_env: Annotated[str, Field(pattern=r"^[A-Z_][A-Z0-9_]*$", max_length=64)] = Field(
        description="Name of the environment variable holding the RWS password (never the password itself)."
    )
    poll_rate_hz: Annotated[float, Field(gt=0.0, le=250.0, allow_inf_nan=False)] = Field(
        50.0, description="How often the speed ratio and the joint positions are read back [Hz]."
    )
    sample_jitter_s: Annotated[float, Field(ge=0.0, le=0.05, allow_inf_nan=False)] = Field(
        0.004,
        description="How far the controller's sampling of the joint positions may be from the bridge's receive times "
        "(its cycle plus the variation of the request's round trip; measure it) [s]: the differenced velocity is "
        "bounded with it (controller_bridge/bridge.py). At least the robot's controller.cycle_s (checked).",
    )
    write_rate_hz: Annotated[float, Field(ge=1.0, le=100.0, allow_inf_nan=False)] = Field(
        25.0, description="Heartbeat writes of the speed ratio per second (each is an HTTP POST) [Hz]."
    )

    @model_validator(mode="before")
    @classmethod
    def _no_password_here(cls, data: Any) -> Any:
        if isinstance(data, dict) and "password" in data:
            raise ValueError(
                "a password in the cell file is refused; allowed: password_env, the name of an environment "
                "variable that holds it"
            )
        return data


class AbbEgmInterfaceConfig(_Frozen):
    """ABB Externally Guided Motion, joint mode (an *open* controller, ``control = "open"``): the bridge is EGM's PC,
    a UDP server the controller sends ``EgmRobot`` to every cycle; it answers with the gateway's joint references
    (``controller_bridge/open_bridge.py``)."""

    CONTROL: ClassVar[Literal["closed", "open"]] = "open"
    """The controller this interface serves: an open one's joint references."""

    kind: Literal["abb_egm"]
    host: Annotated[str, Field(min_length=1, max_length=253, pattern=r"^[A-Za-z0-9.:_-]+$")] = Field(
        "0.0.0.0",
        description="The address the bridge (EGM's PC) listens on for the controller's EgmRobot datagrams (the "
        "UCDevice's remote address; 0.0.0.0: every address).",
    )
    port: Annotated[int, Field(ge=1, le=65535)] = Field(
        6510,
        description="The UDP port the controller sends to (the UCDevice's remote port; 6510 is abb-robot-client's).",
    )
    controller_host: Annotated[str, Field(pattern=r"^[0-9]{1,3}(\.[0-9]{1,3}){3}$")] | None = Field(
        None,
        description="The controller's IPv4 address: EgmRobot datagrams from any other host are refused and counted "
        "(foreign_sender), so nobody else's datagram becomes the robot's joint state or gets its references. None: "
        "any sender (then only the dedicated link keeps others out).",
    )
    watchdog_s: Annotated[float, Field(gt=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.1,
        description="A joint command older than this (its stamp, then the bridge's monotonic clock) is not followed: "
        "the bridge holds the last position reference without feed-forward [s]. At most the robot's "
        "controller.watchdog_s (checked) and 1 s.",
    )
    extrapolate_s: Annotated[float, Field(ge=0.0, le=0.05, allow_inf_nan=False)] = Field(
        0.012,
        description="Between joint commands, the last reference is moved on at its velocity for at most this long "
        "after the command's arrival (the gateway's and the controller's 4 ms cycles drift against each other); "
        "beyond it the reference is held without feed-forward [s]. At most 0.05 s and the watchdog.",
    )
    read_timeout_s: Annotated[float, Field(gt=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.1,
        description="No valid EgmRobot for this long → nothing is published (the gateway's staleness check stops the "
        "robot) and the socket is opened again [s]. At most 1 s.",
    )

    @model_validator(mode="after")
    def _extrapolation_within_the_watchdog(self) -> AbbEgmInterfaceConfig:
        if self.extrapolate_s >= self.watchdog_s:
            raise ValueError(
                f"extrapolate_s = {self.extrapolate_s} s is not shorter than watchdog_s = {self.watchdog_s} s; "
                "allowed: < watchdog_s"
            )
        return self


ControllerInterfaceConfig = Annotated[
    ZenohInterfaceConfig | UrRtdeInterfaceConfig | AbbRwsInterfaceConfig | AbbEgmInterfaceConfig,
    Field(discriminator="kind"),
]
"""How the cell reaches a robot's controller: ``zenoh`` (default), ``ur_rtde`` or ``abb_rws`` (a bridge to a closed
controller's speed input), ``abb_egm`` (a bridge to an open controller's joint references)."""


def interface_kinds(control: Literal["closed", "open"]) -> tuple[str, ...]:
    """The bridged interface kinds that serve a controller of ``control`` (each class's ``CONTROL``), sorted."""
    classes: tuple[type[Any], ...] = (UrRtdeInterfaceConfig, AbbRwsInterfaceConfig, AbbEgmInterfaceConfig)
    return tuple(sorted(c.model_fields["kind"].annotation.__args__[0] for c in classes if control == c.CONTROL))


class RobotConfig(_Frozen):
    model: RobotModelConfig
    base_pose_world: Pose = Pose()
    program: str = Field(description="Absolute path of the program file of the controller emulator.")
    controller: ControllerConfig = ControllerConfig()
    interface: ControllerInterfaceConfig = ZenohInterfaceConfig()

    @model_validator(mode="after")
    def _interface_fits_the_controller(self) -> RobotConfig:
        needs = getattr(type(self.interface), "CONTROL", None)
        control = self.controller.control
        if needs is None or control == needs:
            return self
        what = "joint references" if needs == "open" else "a speed input"
        raise ValueError(
            f"interface kind {self.interface.kind!r} is {'an' if needs == 'open' else 'a'} {needs} controller's "
            f"({what}), but controller.control = {control!r}; allowed with control = {control!r}: zenoh, "
            f"{', '.join(interface_kinds(control))}"
        )

    @model_validator(mode="after")
    def _bridge_watchdog_within_the_controllers(self) -> RobotConfig:
        interface = self.interface
        if (
            isinstance(interface, _BridgeInterfaceConfig | AbbEgmInterfaceConfig)
            and interface.watchdog_s > self.controller.watchdog_s
        ):
            raise ValueError(
                f"interface.watchdog_s = {interface.watchdog_s} s is longer than controller.watchdog_s = "
                f"{self.controller.watchdog_s} s; allowed: <= it"
            )
        return self

    @model_validator(mode="after")
    def _bridge_rise_time_covers_the_controllers(self) -> RobotConfig:
        interface = self.interface
        if not isinstance(interface, _BridgeInterfaceConfig):
            return self
        if isinstance(interface, AbbRwsInterfaceConfig) and interface.sample_jitter_s < self.controller.cycle_s:
            raise ValueError(
                f"interface.sample_jitter_s = {interface.sample_jitter_s} s is shorter than controller.cycle_s = "
                f"{self.controller.cycle_s} s (q is sampled once a cycle); allowed: >= it"
            )
        if interface.rise_time_s == 0.0 and isinstance(interface, UrRtdeInterfaceConfig):
            return self  # the read-back shows the applied scaling while it rises
        if interface.rise_time_s < self.controller.accel_time_s:
            raise ValueError(
                f"interface.rise_time_s = {interface.rise_time_s} s is shorter than controller.accel_time_s = "
                f"{self.controller.accel_time_s} s (the controller's ramp to a raised speed input); allowed: >= it, "
                "or 0 on ur_rtde"
            )
        return self


class TrackerConfig(_Frozen):
    """Sensor properties; the tracker emulator plays them, the gateway only needs the names."""

    rate_hz: Annotated[float, Field(gt=0.0, le=1000.0)] = 30.0
    wire: Literal["json", "packed"] = Field(
        "json",
        description="How the tracker's frames are written: JSON (hrc.humans/1) or packed (hrc.humans_packed/1, a "
        "MessagePack map with each person's capsules as one binary array: for trackers with many capsules). The "
        "gateway takes either on the same key; the tracker emulator writes this one.",
    )
    noise_std_m: NonNegativeFloat = 0.01
    drop_probability: Annotated[float, Field(ge=0.0, lt=1.0)] = 0.0
    latency_s: Annotated[float, Field(ge=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.0,
        description="Capture-to-publish latency [s]. At most 1 s: a frame older than that is stale whatever the age "
        "limit (safety.max_data_age_s is at most 1 s), and the emulator would hold every frame of the meantime.",
    )
    position_m: tuple[Finite, Finite, Finite] | None = Field(
        None, description="Where the sensor sees from, world frame [m]; required with occlusion."
    )
    occlusion: bool = Field(
        False,
        description="The emulated sensor reports only what it sees from position_m: a body capsule whose line of "
        "sight is blocked by the robots' links, the scenario's fixtures and other people is left out, a person with "
        "none visible is not reported (tracker_emu/occlusion.py).",
    )
    miss_probability: Annotated[float, Field(ge=0.0, lt=1.0)] = Field(
        0.0, description="Probability that the emulated sensor misses a person in a frame (each person, each frame)."
    )
    id_swap_probability: Annotated[float, Field(ge=0.0, lt=1.0)] = Field(
        0.0,
        description="Probability per frame that two people the emulated sensor reports exchange their ids, "
        "from that frame on.",
    )
    stamp_late_s: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.0,
        description="The emulated sensor stamps each frame this much before its capture (a tracker whose stamps lag "
        "its images) [s]: its people look this much older, and another tracker's view of them this much newer.",
    )
    id_renew_probability: Annotated[float, Field(ge=0.0, lt=1.0)] = Field(
        0.0,
        description="Probability per frame and person that the emulated sensor gives someone it follows a new id, "
        "from that frame on (a tracker re-identifying a person).",
    )
    blind_until_s: NonNegativeFloat = Field(
        0.0,
        description="The emulated sensor reports nobody until this scenario time [s] (a tracker that joins late: its "
        "first view of people others follow).",
    )
    merge_within_m: NonNegativeFloat = Field(
        0.0,
        description="The emulated sensor reports people whose centres are within this of each other as one person, "
        "all their capsules under one id (a tracker that merges people) [m]; 0 = never.",
    )
    part_names_by_kind: bool = Field(
        False,
        description="The emulated sensor names capsules by kind, without their side (two capsules named 'forearm').",
    )
    ros2: Ros2TrackerInput | None = Field(
        None,
        description="The tracker is a ROS 2 body tracker read over rmw_zenoh (gateway/ros2_trackers.py): its "
        "skeletons become capsules at the gateway. None: it publishes hrc.humans/1 on the cell's Zenoh.",
    )

    @model_validator(mode="after")
    def _occlusion_needs_a_position(self) -> TrackerConfig:
        if self.occlusion and self.position_m is None:
            raise ValueError(
                "occlusion = true needs the sensor's position_m; allowed: occlusion = false, or a position"
            )
        return self


Vector3 = tuple[Finite, Finite, Finite]

MAX_WORLD_EXTENT_M = 100.0
"""Widest a cell's world volume may be along each axis [m]: more is a unit slip (mm)."""


class PlausibilityConfig(_Frozen):
    """What a tracker may report, checked at the door (gateway): where capsules may be and how big they may be."""

    world_min_m: Vector3 = Field(
        (-7.0, -7.0, -0.2),
        description="Lower corner of the cell's volume in the world frame; every capsule end point lies inside "
        "[m]. The default reaches beyond where the shipped scenarios and the sweep's people appear (6.1 m).",
    )
    world_max_m: Vector3 = Field((7.0, 7.0, 2.6), description="Upper corner of the cell's volume [m].")
    max_capsule_length_m: Annotated[float, Field(gt=0.0, le=2.5, allow_inf_nan=False)] = Field(
        1.0,
        description="Longest human capsule (a leg, the torso) [m]. At most 2.5 m: no body part is longer than a "
        "person is tall; a longer 'capsule' is not a person.",
    )
    max_capsule_radius_m: Annotated[float, Field(gt=0.0, le=1.0, allow_inf_nan=False)] = Field(
        0.35, description="Largest human capsule radius [m]. At most 1 m: no body part is thicker than 2 m."
    )
    max_person_extent_m: Annotated[float, Field(gt=0.0, le=3.5, allow_inf_nan=False)] = Field(
        3.0,
        description="Largest extent of one reported person: the diagonal of the box around their capsules plus "
        "twice their largest radius [m]. A person lying down with arms overhead spans ~2.8 m; a larger 'person' is "
        "several people merged (or not a person) and is refused: its centre or parts would stand for bodies it "
        "does not describe. At most 3.5 m.",
    )
    max_capsules_per_person: Annotated[int, Field(ge=1, le=256)] = Field(
        64,
        description="Most capsules one reported person may have (a body model with more parts than this is a "
        "point cloud, not a person). At most 256.",
    )

    @model_validator(mode="after")
    def _world_is_a_volume(self) -> PlausibilityConfig:
        for axis, lo, hi in zip("xyz", self.world_min_m, self.world_max_m, strict=True):
            if not lo < hi:
                raise ValueError(
                    f"world_min_m {axis} = {lo} is not below world_max_m {axis} = {hi}; allowed: min < max per axis"
                )
            if hi - lo > MAX_WORLD_EXTENT_M:
                raise ValueError(
                    f"the world volume is {hi - lo} m wide along {axis}; allowed: at most {MAX_WORLD_EXTENT_M} m"
                )
        return self


class StreamsConfig(_Frozen):
    """How the gateway judges the order and timing of each input stream (stamps, sequence numbers, clocks)
    and whether the reported joint rates and override agree with what was commanded.

    Every tolerance has an upper bound: a looser one lets a wrong stamp, a clock step or a controller that runs
    faster than commanded pass unnoticed.
    """

    max_future_stamp_s: Annotated[float, Field(ge=0.0, le=0.05, allow_inf_nan=False)] = Field(
        0.005,
        description="A stamp ahead of the receiver's clock by more is rejected [s]. At most 0.05 s: a stamp from "
        "the future shortens the measured age, so the delay budget would be understated by up to this.",
    )
    fault_hold_s: Annotated[float, Field(ge=0.1, le=10.0, allow_inf_nan=False)] = Field(
        0.5,
        description="A stream fault (stamps or seqs backwards, clock step) keeps δ = 0 this long after its last "
        "occurrence [s]. At least 0.1 s: every stream (≥ 10 Hz) delivers a fresh sample before δ may rise again, "
        "and a fault that recurs every few cycles keeps the robot stopped. At most 10 s: one glitch should not stop "
        "the cell for longer than a stream needs to show it is sound; more is a unit slip (ms).",
    )
    max_clock_step_s: Annotated[float, Field(ge=0.001, le=0.05, allow_inf_nan=False)] = Field(
        0.02,
        description="The gateway's wall clock moving against its monotonic clock by more is a clock step (a "
        "fault) [s]. 0.001–0.05 s: a smaller step goes unnoticed and shifts every measured age by up to this "
        "much; reading two clocks and NTP slewing (≤ 0.5 ms/s) must not count as a step.",
    )
    qd_tolerance_radps: Annotated[float, Field(ge=0.0, le=0.1, allow_inf_nan=False)] = Field(
        0.01,
        description="Reported q̇ may differ from override · q̇_nominal (per joint, sign included) by this plus "
        "qd_tolerance_ratio · |q̇_nominal| "
        "before it is a fault [rad/s]. At most 0.1 rad/s (0.1 m/s at 1 m reach) of unnoticed extra speed.",
    )
    qd_tolerance_ratio: Annotated[float, Field(ge=0.0, le=0.1, allow_inf_nan=False)] = Field(
        0.02, description="See qd_tolerance_radps [1]. At most 0.1: a joint 10 % faster than commanded is a fault."
    )
    override_tolerance: Annotated[float, Field(ge=0.0, le=0.02, allow_inf_nan=False)] = Field(
        0.001,
        description="An applied override above the commanded one (beyond the braking ramp) by more is a fault [1]. "
        "At most 0.02: two steps of a controller that rounds its override to whole percent.",
    )


class Box(_Frozen):
    """An axis-aligned box in the world frame [m]."""

    min_m: Vector3
    max_m: Vector3

    @model_validator(mode="after")
    def _is_a_volume(self) -> Box:
        for axis, lo, hi in zip("xyz", self.min_m, self.max_m, strict=True):
            if not lo < hi:
                raise ValueError(f"min_m {axis} = {lo} is not below max_m {axis} = {hi}; allowed: min < max per axis")
        return self


NOISE_SIGMAS = 3.0
"""A tracker's position error is this many times its ``noise_std_m``: in the tracks' match margin, and against the
static clearance (the gateway's start-up warnings)."""
MATCH_MARGIN_MAX_M = 0.5
"""The most a detection may be matched beyond a track's reach [m]: ``tracking.association_margin_m`` plus
:data:`NOISE_SIGMAS` times the noise of each of the two trackers compared. A looser match lets one person's detection
release another's track."""


class TrackingConfig(_Frozen):
    """People as tracks (``gateway/tracks.py``, docs/contract.md "Tracks"): what the trackers cover, where people
    may leave, and how a track is matched. A person no longer seen is *lost*, never gone: only a detection within
    their reachable set, leaving through the coverage boundary, or an operator's reset releases them."""

    coverage_min_m: Vector3 = Field(
        (-5.5, -5.5, -0.2),
        description="Lower corner of the volume the cell's trackers cover together (world frame) [m]. People enter "
        "and leave only through its boundary; a person lost inside it stays (lost) until released.",
    )
    coverage_max_m: Vector3 = Field((5.5, 5.5, 2.6), description="Upper corner of the covered volume [m].")
    exit_band_m: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)] = Field(
        0.4,
        description="A track last seen with its centre within this of a side face of the covered volume, moving out "
        "through that face, has left [m]. At most 2 m: deeper inside, a person who is lost has not left.",
    )
    exit_speed_min_mps: Annotated[float, Field(ge=0.1, le=2.0, allow_inf_nan=False)] = Field(
        0.2,
        description="Outward speed of the track's centre (over its last observations) above which it counts as "
        "moving out [m/s]; noise of a standing person stays below it. At least 0.1 m/s: a person standing in the "
        "exit band (or stepping in) is not leaving, and a lost one there has not left.",
    )
    exit_zones: list[Box] = Field(
        default_factory=list,
        description="Doors and walkways (boxes): when given, a person leaves only through them; empty = anywhere "
        "on the side faces of the covered volume.",
    )
    association_margin_m: Annotated[float, Field(ge=0.0, le=MATCH_MARGIN_MAX_M, allow_inf_nan=False)] = Field(
        0.1,
        description="Added to a track's reach when matching a detection to it: the tracker's stated position "
        "uncertainty beyond 3 × noise_std_m [m]. At most 0.5 m: a looser match lets one person's detection "
        "release another's track.",
    )
    unsafe_forget_lost_for_tests: bool = Field(
        False,
        description="TEST ONLY: a person no longer seen is forgotten at once (the classic fail-open), to show that "
        f"the sweep's auditor catches it. Refused unless {UNSAFE_ENV_VAR} names it.",
    )

    unsafe_release_by_id_for_tests: bool = Field(
        False,
        description="TEST ONLY: the release rule before issue 32: a lost track is continued by its tracker's same id "
        "within reach, and any detection away from the entry band that covers it releases it, whoever it is (one "
        "person stands in for another), to show that the sweep's auditor catches it. Refused unless "
        f"{UNSAFE_ENV_VAR} names it.",
    )

    @field_validator("unsafe_forget_lost_for_tests")
    @classmethod
    def _unsafe_only_when_named(cls, value: bool) -> bool:
        return refuse_unless_named(value, "unsafe_forget_lost_for_tests", "lost people are forgotten")

    @field_validator("unsafe_release_by_id_for_tests")
    @classmethod
    def _unsafe_release_only_when_named(cls, value: bool) -> bool:
        return refuse_unless_named(value, "unsafe_release_by_id_for_tests", "lost people are released by others")

    @model_validator(mode="after")
    def _coverage_is_a_volume(self) -> TrackingConfig:
        Box(min_m=self.coverage_min_m, max_m=self.coverage_max_m)  # raises with the axis that is not a volume
        return self


Ros2Distro = Literal["humble", "jazzy", "kilted"]
"""ROS 2 distributions whose rmw_zenoh key form the gateway speaks: Humble's keys end in ``TypeHashNotSupported``,
the later ones in ``RIHS01_<sha256>`` (docs/ros2.md)."""
ROS2_NAME_PATTERN = r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$"


class Ros2Config(_Frozen):
    """The gateway's ROS 2 face over rmw_zenoh (``gateway/ros2_face.py``, docs/ros2.md): off unless enabled.

    It publishes what the status shows, on a Zenoh session of its own (its own endpoints, certificate CN ``ros2``
    with TLS, under the ROS 2 session's access control), and reads only the topics of the cell's ROS 2 trackers
    (``trackers.<name>.ros2``), which go through the same door as native trackers (``gateway/ros2_trackers.py``).
    """

    enabled: bool = False
    domain_id: Annotated[int, Field(ge=0, le=232)] = Field(0, description="ROS_DOMAIN_ID of the ROS 2 side.")
    distro: Ros2Distro = Field("jazzy", description="Key form and message definitions: humble, jazzy, kilted.")
    namespace: Annotated[str, Field(pattern=r"^(/?|" + ROS2_NAME_PATTERN[1:-1] + ")$")] = Field(
        "", description="ROS namespace of the gateway's node and topics ('' = none)."
    )
    node_name: Annotated[str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*$")] = "hrc_gateway"
    speed_override_topic: Annotated[str, Field(pattern=ROS2_NAME_PATTERN)] = Field(
        "speed_override",
        description="Per robot, under <robot>/: std_msgs/Float64, the commanded δ in [0, 1] (not percent).",
    )
    joint_states_topic: Annotated[str, Field(pattern=ROS2_NAME_PATTERN)] = Field(
        "joint_states", description="Per robot, under <robot>/: sensor_msgs/JointState as the gateway last used it."
    )
    diagnostics_topic: Annotated[str, Field(pattern=ROS2_NAME_PATTERN)] = Field(
        "diagnostics", description="diagnostic_msgs/DiagnosticArray: one status per robot (zone, δ, faults)."
    )
    markers_topic: Annotated[str, Field(pattern=ROS2_NAME_PATTERN)] = Field(
        "hrc_markers", description="visualization_msgs/MarkerArray: robot and human capsules coloured by zone."
    )
    frame_id: Annotated[str, Field(min_length=1, max_length=256)] = Field(
        "world", description="frame_id of the markers and joint states: the cell's world frame."
    )
    publish_rate_hz: Annotated[float, Field(gt=0.0, le=100.0)] = Field(
        10.0, description="At most this many rounds of messages per second (never above gateway.status_rate_hz)."
    )
    mode: Literal["peer", "client"] = "peer"
    listen: list[str] = Field(default_factory=list, description="Zenoh endpoints the ROS 2 session listens on.")
    connect: list[str] = Field(
        default_factory=list, description='Zenoh endpoints it connects to, e.g. rmw_zenohd: ["tcp/127.0.0.1:7447"].'
    )

    @model_validator(mode="after")
    def _reachable(self) -> Ros2Config:
        if self.enabled and not (self.listen or self.connect):
            raise ValueError(
                "enabled without endpoints; allowed: listen and/or connect, e.g. connect = "
                '["tcp/127.0.0.1:7447"] for the rmw_zenohd router of the host'
            )
        return self


Ros2TrackerFormat = Literal["zed_objects", "k4abt_markers", "ros4hri_bodies"]
"""What a ROS 2 body tracker publishes: ``zed_msgs/ObjectsStamped`` (ZED body tracking), the Azure Kinect
driver's ``visualization_msgs/MarkerArray`` (``hrc_devices/trackers/ros2_people.py``), or ROS4HRI bodies (REP 155: the
tracked list, per body ``sensor_msgs/JointState`` of the human model and its ``body_<id>`` frame on /tf;
``hrc_devices/trackers/ros4hri_body.py``)."""
MAX_ROS4HRI_BODY_HEIGHT_M = 1.87
"""Tallest ROS4HRI human model [m]: the P95 stature of ``hrc_devices/trackers/skeletons.py``; a taller model's segments
outgrow the reach spheres that stand for a body part whose joint is missing."""
MAX_SKELETON_CAPSULE_RADIUS_M = 2.0
"""Largest radius a skeleton tracker's capsules may be allowed [m]: the contract's ``Capsule.radius`` limit."""


class Ros2TrackerInput(_Frozen):
    """A body tracker of the cell read over ROS 2 (``[ros2]``'s session, distro and domain): its keypoints become
    the gateway's capsules (``hrc_devices/trackers/skeletons.py``), then one ``hrc.humans/1`` frame through the same
    door.

    Plausibility: a part the tracker did not see becomes a sphere reaching as far as it can be (a foot unseen down
    to the pelvis: 1.55 m, P95) plus the uncertainty, which the cell's ``max_capsule_radius_m`` (at most 1 m, sized
    for seen body parts) would refuse (δ = 0 whenever a hand is hidden). A large capsule only lowers δ; so the door
    judges this tracker's capsules against its own radius and length limits instead, within the cell's volume.
    """

    format: Ros2TrackerFormat
    topic: Annotated[str, Field(pattern=ROS2_NAME_PATTERN)] = Field(
        description="The tracker's topic, e.g. /zed/zed_node/body_trk/skeletons (relative: under [ros2] namespace)."
    )
    frame_id: Annotated[str, Field(min_length=1, max_length=256)] | None = Field(
        None, description="The header.frame_id the tracker must use (another is refused, wrong_frame); None: any."
    )
    sensor_pose_world: Pose = Field(
        Pose(), description="Pose of the messages' frame in the cell's world frame (xyz [m], rpy [rad])."
    )
    uncertainty_m: Annotated[float, Field(ge=0.0, le=0.5, allow_inf_nan=False)] = Field(
        0.05,
        description="The tracker's stated keypoint uncertainty (e.g. 3σ), added to every capsule radius [m]. At most "
        "0.5 m: a tracker less certain than that does not place a hand.",
    )
    max_capsule_radius_m: Annotated[float, Field(gt=0.0, le=MAX_SKELETON_CAPSULE_RADIUS_M, allow_inf_nan=False)] = (
        Field(MAX_SKELETON_CAPSULE_RADIUS_M, description="Largest capsule radius of this tracker at the door [m].")
    )
    max_capsule_length_m: Annotated[float, Field(gt=0.0, le=2.5, allow_inf_nan=False)] = Field(
        2.5,
        description="Longest capsule of this tracker at the door [m] (a part enclosed with where it was last seen).",
    )
    # -- format "zed_objects" only: how the camera is set up (the tracker emulator and the sweep play it) ----------
    enable_body_fitting: bool = Field(
        False,
        description="zed_objects: the ZED wrapper's body_tracking.enable_body_fitting (its default: false). On, the "
        "SDK fits a skeleton and publishes an estimate for keypoints it cannot see; off, those are NaN. The gateway "
        "cannot tell a fitted keypoint from a seen one (zed_msgs has no per-keypoint confidence): docs/ros2.md.",
    )
    # -- format "ros4hri_bodies" only (topic: the tracked list, e.g. /humans/bodies/tracked) --------------------
    tf_topic: Annotated[str, Field(pattern=ROS2_NAME_PATTERN)] = Field(
        "/tf", description="ros4hri_bodies: where the body_<id> frames are broadcast (tf2_msgs/TFMessage)."
    )
    body_height_m: Annotated[float, Field(ge=1.0, le=MAX_ROS4HRI_BODY_HEIGHT_M, allow_inf_nan=False)] | None = Field(
        None,
        description="ros4hri_bodies: height of the human model the joint states drive [m]; None: the P95 stature "
        "(1.87 m). hri_fullbody builds its model at the template's default 1.65 m.",
    )
    max_body_age_s: Annotated[float, Field(gt=0.0, le=MAX_GUARD_TIME_S, allow_inf_nan=False)] = Field(
        0.2,
        description="ros4hri_bodies: a tracked body whose joint states or body frame are older than this at the "
        "tracked list's stamp is lost (left out of the frame, not gone) [s]. At most 1 s, as any data age.",
    )


class CellConfig(_Frozen):
    cell: Name
    safety: SafetyConfig = SafetyConfig()
    zones: ZonesConfig = ZonesConfig()
    gateway: GatewayConfig = GatewayConfig()
    plausibility: PlausibilityConfig = PlausibilityConfig()
    streams: StreamsConfig = StreamsConfig()
    tracking: TrackingConfig = TrackingConfig()
    ros2: Ros2Config = Ros2Config()
    planner: PlannerConfig = PlannerConfig()
    robots: dict[Name, RobotConfig]
    trackers: dict[Name, TrackerConfig]
    default_scenario: str = "walk_in_reach_leave"
    scenarios_dir: str = Field(description="Absolute path of the folder of scenario files.")

    @field_validator("robots", "trackers")
    @classmethod
    def _not_empty(cls, value: dict[str, Any]) -> dict[str, Any]:
        if not value:
            raise ValueError("at least one entry is required")
        return value

    @model_validator(mode="after")
    def _match_margin_within_its_cap(self) -> CellConfig:
        """The widest match the tracks make, ``association_margin_m`` + 3σ + 3σ of the noisiest tracker against itself,
        within :data:`MATCH_MARGIN_MAX_M`: a tracker's stated noise must not loosen the cap on the margin."""
        noisiest = max(self.trackers, key=lambda name: self.trackers[name].noise_std_m)
        sigma_m = self.trackers[noisiest].noise_std_m
        widest_m = self.tracking.association_margin_m + 2 * NOISE_SIGMAS * sigma_m
        if widest_m > MATCH_MARGIN_MAX_M:
            raise ValueError(
                f"trackers.{noisiest}.noise_std_m = {sigma_m} m: the tracks match its detections within "
                f"tracking.association_margin_m + 3 × {sigma_m} + 3 × {sigma_m} = {widest_m:.3f} m, more than "
                f"{MATCH_MARGIN_MAX_M} m (a looser match lets one person's detection release another's track); "
                f"allowed: association_margin_m + 6 × noise_std_m <= {MATCH_MARGIN_MAX_M} m"
            )
        return self

    @model_validator(mode="after")
    def _robots_inside_the_covered_volume(self) -> CellConfig:
        """Every robot's base inside the trackers' covered volume, and not where people leave it: within
        ``tracking.exit_band_m`` of a side face (inside an exit zone, where the cell declares them), a person lost
        beside the robot could be taken as having left (the tracks' rule (b))."""
        tracking = self.tracking
        band_m = tracking.exit_band_m
        for name, robot in self.robots.items():
            xyz = robot.base_pose_world.xyz
            where = f"robots.{name}.base_pose_world {xyz}"
            in_exit_zone = not tracking.exit_zones or any(
                all(zone.min_m[k] <= xyz[k] <= zone.max_m[k] for k in range(3)) for zone in tracking.exit_zones
            )
            for axis, label in ((0, "x"), (1, "y")):
                low_m, high_m = tracking.coverage_min_m[axis], tracking.coverage_max_m[axis]
                if not low_m < xyz[axis] < high_m:
                    raise ValueError(
                        f"{where}: outside the trackers' covered volume ({label} from {low_m} to {high_m} m, "
                        "tracking.coverage_min_m/max_m): nobody near it would be seen; allowed: inside it"
                    )
                in_band = xyz[axis] - low_m <= band_m or high_m - xyz[axis] <= band_m
                if in_band and in_exit_zone:
                    raise ValueError(
                        f"{where}: within tracking.exit_band_m = {band_m} m of the covered volume's {label} face "
                        f"({label} from {low_m} to {high_m} m), where people leave: a person lost beside the robot "
                        f"could be taken as having left; allowed: {low_m + band_m} < {label} < {high_m - band_m} m, "
                        "or outside every exit zone"
                    )
        return self

    @model_validator(mode="after")
    def _ros2_trackers_need_ros2(self) -> CellConfig:
        readers = [name for name, tracker in self.trackers.items() if tracker.ros2 is not None]
        if readers and not self.ros2.enabled:
            raise ValueError(
                f"tracker(s) {', '.join(readers)} read ROS 2 but [ros2] is not enabled; allowed: [ros2] enabled = "
                "true with its endpoints, or no ros2 input"
            )
        return self

    def tracker_plausibility(self, tracker: str) -> PlausibilityConfig:
        """What the door allows ``tracker``: the cell's limits, a ROS 2 skeleton tracker's own radius and length (its
        reach spheres stand for hidden limbs, so one person may span their diameter more than the cell allows)."""
        ros2 = self.trackers[tracker].ros2
        if ros2 is None:
            return self.plausibility
        extra_m = 2.0 * max(0.0, ros2.max_capsule_radius_m - self.plausibility.max_capsule_radius_m)
        limits = {
            "max_capsule_radius_m": ros2.max_capsule_radius_m,
            "max_capsule_length_m": ros2.max_capsule_length_m,
            "max_person_extent_m": self.plausibility.max_person_extent_m + extra_m,
        }
        return self.plausibility.model_copy(update=limits)

    def sha256(self) -> str:
        """Hex digest of the configuration as loaded (canonical JSON, referenced files included)."""
        canonical = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()
