"""Cell configuration: TOML files in ``configs/`` parsed into frozen, validated models.

A cell file (``configs/cell.toml``) names the robots (each pointing to a robot model file and a
program), the trackers with their sensor properties, and the safety, zone and gateway parameters.
Every field carries its unit. Dangerous values refuse to load with a one-line reason that says what
is allowed (:class:`ConfigError`).
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from hrc_common.errors import HrcError
from hrc_common.messages import NAME_PATTERN

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CELL_PATH = REPO_ROOT / "configs" / "cell.toml"

ISO13855_WALKING_SPEED_MPS = 1.6
"""K of ISO 13855 for separations above 0.5 m (Zanchettin et al. 2016, eq. (11))."""

Name = Annotated[str, Field(pattern=NAME_PATTERN, max_length=64)]
PositiveFloat = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class ConfigError(HrcError):
    """The configuration cannot be loaded or is unsafe. The message is one line."""


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


def example_robot_data_dir() -> Path:
    """Folder of the URDFs shipped by the ``example-robot-data`` package (it has no Python module)."""
    import pinocchio  # heavy: imported only when a URDF path must be resolved

    return Path(pinocchio.__file__).resolve().parents[4] / "share" / "example-robot-data" / "robots"


SafetyMethod = Literal["zanchettin2016", "iso15066", "three_zones", "stop_only"]
"""The override methods the gateway can run (safety-math.md §4, §7, §8; ``gateway/methods.py``)."""
SAFETY_METHODS: tuple[str, ...] = get_args(SafetyMethod)


class SafetyConfig(_Frozen):
    """Parameters of the separation criterion (safety-math.md §3–§5) and of the selectable methods (§7–§8)."""

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
    t_reaction_s: NonNegativeFloat = 0.04
    max_data_age_s: PositiveFloat = 0.2
    allow_human_speed_below_iso13855: bool = False
    unsafe_ignore_delay_for_tests: bool = Field(
        False, description="TEST ONLY: t_delay = 0, to show that the delay terms matter. Never in a real cell."
    )
    # -- method "iso15066" (Pupa et al. 2021; safety-math.md §7) -----------------------------------------
    iso15066_human_uncertainty_m: NonNegativeFloat = Field(
        0.0, description="Z_d of ISO/TS 15066: position uncertainty of the operator (sensing) [m]."
    )
    iso15066_robot_uncertainty_m: NonNegativeFloat = Field(
        0.0, description="Z_r of ISO/TS 15066: position uncertainty of the robot [m]."
    )
    iso15066_joint_acceleration_limit_radps2: PositiveFloat = Field(
        10.0,
        description="Joint acceleration limit of QP (12), every joint [rad/s²]; bounds how fast δ may rise.",
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

    @model_validator(mode="after")
    def _three_zones_are_ordered(self) -> SafetyConfig:
        if self.three_zones_slow_below_m <= self.three_zones_stop_below_m:
            raise ValueError(
                f"three_zones_slow_below_m = {self.three_zones_slow_below_m} is not beyond "
                f"three_zones_stop_below_m = {self.three_zones_stop_below_m}; allowed: slow > stop"
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
    adaptive_speed_hold_s: NonNegativeFloat = Field(
        2.0, description="'adaptive' uses the largest programmed link speed of this last stretch of time [s]."
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


class ControllerConfig(_Frozen):
    """The emulated controller's own behaviour (a real controller's is fixed by its vendor)."""

    cycle_s: Annotated[float, Field(ge=0.0005, le=0.1)] = 0.004
    braking_time_s: PositiveFloat = Field(0.24, description="Override 1 → 0 takes at most this long [s].")
    accel_time_s: PositiveFloat = Field(0.5, description="Override 0 → 1 takes at least this long [s].")
    watchdog_s: PositiveFloat = Field(0.1, description="No valid override for this long → protective stop [s].")


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
    braking_time_s: Annotated[list[PositiveFloat], Field(min_length=1)]
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


class RobotConfig(_Frozen):
    model: RobotModelConfig
    base_pose_world: Pose = Pose()
    program: str = Field(description="Absolute path of the program file of the controller emulator.")
    controller: ControllerConfig = ControllerConfig()


class TrackerConfig(_Frozen):
    """Sensor properties; the tracker emulator plays them, the gateway only needs the names."""

    rate_hz: Annotated[float, Field(gt=0.0, le=1000.0)] = 30.0
    noise_std_m: NonNegativeFloat = 0.01
    drop_probability: Annotated[float, Field(ge=0.0, lt=1.0)] = 0.0
    latency_s: NonNegativeFloat = Field(0.0, description="Capture-to-publish latency [s].")


class CellConfig(_Frozen):
    cell: Name
    safety: SafetyConfig = SafetyConfig()
    zones: ZonesConfig = ZonesConfig()
    gateway: GatewayConfig = GatewayConfig()
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

    def sha256(self) -> str:
        """Hex digest of the configuration as loaded (canonical JSON, referenced files included)."""
        canonical = json.dumps(self.model_dump(mode="json"), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(canonical.encode()).hexdigest()


def read_toml(path: Path) -> dict[str, Any]:
    """A TOML file as a dictionary. Raises ConfigError (one line) when missing or not TOML."""
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None


def _resolve(base: Path, relative: str) -> Path:
    return (base / relative).resolve()


def resolve_urdf(urdf: str, config_dir: Path) -> Path:
    """An absolute URDF path: as given, relative to the config folder, or inside example-robot-data."""
    given = Path(urdf)
    candidates = [given] if given.is_absolute() else [config_dir / given, example_robot_data_dir() / given]
    for candidate in candidates:
        if candidate.is_file():
            return candidate.resolve()
    raise ConfigError(
        f"URDF {urdf!r} not found; allowed: an absolute path, a path relative to {config_dir}, "
        f"or a path inside {example_robot_data_dir()}"
    )


def one_line(exc: ValidationError, source: Path | str) -> str:
    """A pydantic validation error as one line: ``source: field: message; ...`` (at most three errors)."""
    parts = []
    for err in exc.errors()[:3]:
        where = ".".join(str(p) for p in err["loc"])
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{where}: {msg}" if where else msg)
    more = f" (and {exc.error_count() - 3} more)" if exc.error_count() > 3 else ""
    return f"{source}: " + "; ".join(parts) + more


def load_cell_config(path: Path | str | None = None) -> CellConfig:
    """Load and validate a cell file and the robot model files and programs it references.

    Raises:
        ConfigError: the file is missing, not TOML, or not a valid, safe configuration.
    """
    cell_path = Path(path) if path is not None else DEFAULT_CELL_PATH
    cell_path = cell_path.resolve()
    raw = read_toml(cell_path)
    config_dir = cell_path.parent
    robots_raw = raw.get("robots", {})
    if not isinstance(robots_raw, dict):
        raise ConfigError(f"{cell_path}: robots must be a table of robot names")
    for name, robot in robots_raw.items():
        if not isinstance(robot, dict):
            raise ConfigError(f"{cell_path}: robots.{name} must be a table")
        model_ref = robot.get("model")
        if isinstance(model_ref, str):
            model_path = _resolve(config_dir, model_ref)
            model = read_toml(model_path)
            if isinstance(model.get("urdf"), str):
                model["urdf"] = str(resolve_urdf(model["urdf"], model_path.parent))
            robot["model"] = model
        program_ref = robot.get("program")
        if isinstance(program_ref, str):
            program_path = _resolve(config_dir, program_ref)
            if not program_path.is_file():
                raise ConfigError(f"{cell_path}: robots.{name}.program: {program_path}: no such file")
            robot["program"] = str(program_path)
    raw["scenarios_dir"] = str(_resolve(config_dir, str(raw.get("scenarios_dir", "scenarios"))))
    try:
        return CellConfig.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(one_line(exc, cell_path)) from None
