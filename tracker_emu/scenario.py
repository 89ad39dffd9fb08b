"""Scripted humans: scenario files (``configs/scenarios/<name>.toml``) and the people they put in the cell.

A scenario lists humans, each with keyframes (time, floor position, heading, reach). A human is present
from its first to its last keyframe; in between, the pose is interpolated linearly (the heading along
the shorter way round). :func:`humans_at` is a pure function of the scenario and the scenario time.

People enter and leave the cell through the boundary of the volume its trackers cover (``[tracking]`` of the
cell file, ±5.5 m by default): the shipped scenarios start and end every person's path outside it (x or
|y| = 6 m), since a person who vanishes inside it is, for the gateway, a person the trackers lost.

A scenario may also place fixtures: static objects (a cabinet, a workbench) as capsules that hide what lies
behind them from sensors with occlusion; nothing else sees them (the gateway and the auditor judge people
and robots only).

File format::

    description = "one person walks in"
    duration_s = 30.0
    loop = true

    [[humans]]
    id = "h1"
    both_arms = false          # optional: both arms reach (default: the right one only)

    [[humans.keyframes]]
    t_s = 3.0
    xy_m = [6.0, 0.0]
    heading_rad = 3.14159
    reach = 0.0                # optional, in [0, 1]

    [[fixtures]]               # optional
    name = "cabinet"
    a_m = [1.0, -0.9, 0.0]     # axis end points, world frame [m]
    b_m = [1.0, -0.9, 2.0]
    radius_m = 0.35
"""

from __future__ import annotations

import bisect
import itertools
import math
from pathlib import Path
from typing import Annotated, NamedTuple

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from hrc_contract.config import ConfigError
from hrc_runtime.config import one_line, read_toml
from tracker_emu.body import BodyCapsule, BodyPose, body_capsules

MAX_WALKING_SPEED_MPS = 3.0
"""Fastest allowed motion of a person between two keyframes [m/s]."""

Finite = Annotated[float, Field(allow_inf_nan=False)]
Point = tuple[Finite, Finite, Finite]


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Keyframe(_Frozen):
    """Pose of a human at one instant of the scenario."""

    t_s: Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
    xy_m: tuple[Finite, Finite]
    heading_rad: Finite
    reach: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] = 0.0


class HumanScript(_Frozen):
    """One scripted person: present from the first to the last keyframe."""

    id: Annotated[str, Field(min_length=1, max_length=64)]
    both_arms: bool = False
    keyframes: Annotated[list[Keyframe], Field(min_length=2)]

    @field_validator("keyframes")
    @classmethod
    def _plausible_motion(cls, keyframes: list[Keyframe]) -> list[Keyframe]:
        for i, (k0, k1) in enumerate(itertools.pairwise(keyframes)):
            if k1.t_s <= k0.t_s:
                raise ValueError(
                    f"keyframe {i + 1} at t_s = {k1.t_s} does not come after keyframe {i} at t_s = {k0.t_s}; "
                    "allowed: strictly increasing times"
                )
            speed_mps = math.dist(k0.xy_m, k1.xy_m) / (k1.t_s - k0.t_s)
            if speed_mps > MAX_WALKING_SPEED_MPS:
                raise ValueError(
                    f"keyframes {i} → {i + 1} (t_s {k0.t_s} → {k1.t_s}) move at {speed_mps:.2f} m/s; "
                    f"allowed: <= {MAX_WALKING_SPEED_MPS} m/s"
                )
        return keyframes

    @property
    def start_s(self) -> float:
        return self.keyframes[0].t_s

    @property
    def end_s(self) -> float:
        return self.keyframes[-1].t_s


class Fixture(_Frozen):
    """A static object of the scene as a capsule: the segment ``a_m``–``b_m`` (world frame) [m] swept by a sphere
    of ``radius_m`` [m]. It only hides what lies behind it from the sensors with occlusion."""

    name: Annotated[str, Field(min_length=1, max_length=64)]
    a_m: Point
    b_m: Point
    radius_m: Annotated[float, Field(gt=0.0, le=2.0, allow_inf_nan=False)]


class Scenario(_Frozen):
    """A scripted scene of the cell; times are scenario times from 0 to ``duration_s`` [s]."""

    description: str
    duration_s: Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
    loop: bool
    humans: list[HumanScript] = Field(default_factory=list)
    fixtures: list[Fixture] = Field(default_factory=list)

    @model_validator(mode="after")
    def _within_duration_and_unique(self) -> Scenario:
        ids = [h.id for h in self.humans]
        duplicates = sorted({i for i in ids if ids.count(i) > 1})
        if duplicates:
            raise ValueError(f"human ids {duplicates} appear more than once; allowed: unique ids")
        for human in self.humans:
            if human.end_s > self.duration_s:
                raise ValueError(
                    f"human {human.id!r}: keyframe at t_s = {human.end_s} is after duration_s = {self.duration_s}; "
                    "allowed: 0 <= t_s <= duration_s"
                )
        return self


class TrackedHuman(NamedTuple):
    """A person in the cell at one instant: its id and body capsules in the world frame."""

    id: str
    capsules: tuple[BodyCapsule, ...]


def _wrap_angle(angle_rad: float) -> float:
    """The angle in [-π, π) [rad]."""
    return (angle_rad + math.pi) % (2.0 * math.pi) - math.pi


def pose_at(human: HumanScript, t_s: float) -> BodyPose | None:
    """Interpolated pose of one human at scenario time ``t_s`` [s], or None outside its presence window."""
    keyframes = human.keyframes
    if not human.start_s <= t_s <= human.end_s:
        return None
    i = min(bisect.bisect_right([k.t_s for k in keyframes], t_s) - 1, len(keyframes) - 2)
    k0, k1 = keyframes[i], keyframes[i + 1]
    s = (t_s - k0.t_s) / (k1.t_s - k0.t_s)
    return BodyPose(
        x_m=k0.xy_m[0] + s * (k1.xy_m[0] - k0.xy_m[0]),
        y_m=k0.xy_m[1] + s * (k1.xy_m[1] - k0.xy_m[1]),
        heading_rad=_wrap_angle(k0.heading_rad + s * _wrap_angle(k1.heading_rad - k0.heading_rad)),
        reach=min(1.0, max(0.0, k0.reach + s * (k1.reach - k0.reach))),
        both_arms=human.both_arms,
    )


def scenario_time(scenario: Scenario, elapsed_s: float) -> float:
    """Scenario time [s] after ``elapsed_s`` of playing: wrapped when the scenario loops."""
    return elapsed_s % scenario.duration_s if scenario.loop else elapsed_s


def humans_at(scenario: Scenario, t_s: float) -> list[TrackedHuman]:
    """The humans present at time ``t_s`` [s] since the scenario started (wrapped when it loops).

    Returns:
        One entry per present human, in file order; an empty list when nobody is there.
    """
    t_s = scenario_time(scenario, t_s)
    present = []
    for human in scenario.humans:
        pose = pose_at(human, t_s)
        if pose is not None:
            present.append(TrackedHuman(human.id, body_capsules(pose)))
    return present


def load_scenario(path: Path | str) -> Scenario:
    """Load and validate a scenario file.

    Raises:
        ConfigError: the file is missing, not TOML, or not a valid scenario (one line, with the file name).
    """
    path = Path(path)
    raw = read_toml(path)
    try:
        return Scenario.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(one_line(exc, path)) from None


def available_scenarios(scenarios_dir: Path | str) -> list[str]:
    """Names of the scenario files in a folder (file names without ``.toml``), sorted."""
    return sorted(p.stem for p in Path(scenarios_dir).glob("*.toml"))


def scenario_path(scenarios_dir: Path | str, name: str) -> Path:
    """The file of the scenario called ``name``.

    Raises:
        ConfigError: no such scenario; the message lists the available ones.
    """
    available = available_scenarios(scenarios_dir)
    if name not in available:
        raise ConfigError(
            f"unknown scenario {name!r}; available in {scenarios_dir}: {', '.join(available) or '(none)'}"
        )
    return Path(scenarios_dir) / f"{name}.toml"
