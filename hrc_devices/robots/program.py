"""The controller's pre-planned program: waypoints in a TOML file, time-parameterised into a trajectory.

File format (``configs/programs/<name>.toml``)::

    description = "pick and place"

    [[waypoints]]
    name = "pick"                   # optional label
    q_rad = [0.0, -1.3, 1.6, -1.9, -1.57, 0.0]
    max_speed_radps = 2.0           # cap of the fastest-moving joint on the move INTO this waypoint
    max_accel_radps2 = 6.0          # same, acceleration and deceleration
    dwell_s = 0.3                   # standstill at this waypoint (optional, default 0)

The program is cyclic: it starts at standstill at the first waypoint, visits the others in order and
moves from the last one back to the first. Every move is joint-synchronised: all joints start and arrive
together, on a trapezoidal velocity profile of the fastest-moving joint (triangular when the move is too
short to reach the speed cap). :meth:`Trajectory.sample` is a pure function of the program time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
import numpy.typing as npt
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from hrc_contract.config import ConfigError
from hrc_devices.robots.model import RobotModel
from hrc_runtime.config import one_line, read_toml

FloatArray = npt.NDArray[np.float64]

MIN_MOVE_RAD = 1e-6
"""Consecutive waypoints closer than this (largest joint difference) count as the same point [rad]."""

Finite = Annotated[float, Field(allow_inf_nan=False)]
PositiveFloat = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]
NonNegativeFloat = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]


class _Frozen(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class Waypoint(_Frozen):
    """A joint-space target and the limits of the move into it."""

    name: Annotated[str, Field(max_length=64)] = ""
    q_rad: Annotated[list[Finite], Field(min_length=1, max_length=32)]
    max_speed_radps: PositiveFloat = Field(description="Speed cap of the fastest-moving joint [rad/s].")
    max_accel_radps2: PositiveFloat = Field(description="Acceleration cap of the fastest-moving joint [rad/s²].")
    dwell_s: NonNegativeFloat = Field(0.0, description="Standstill at this waypoint after arriving [s].")


class Program(_Frozen):
    """A cyclic program: the waypoints in order; after the last one it moves back to the first."""

    description: str = ""
    waypoints: Annotated[list[Waypoint], Field(min_length=2)]

    @model_validator(mode="after")
    def _same_joint_count(self) -> Program:
        n = len(self.waypoints[0].q_rad)
        for i, waypoint in enumerate(self.waypoints):
            if len(waypoint.q_rad) != n:
                raise ValueError(
                    f"waypoint {i} has {len(waypoint.q_rad)} joint values, waypoint 0 has {n}; "
                    "allowed: the same number in every waypoint"
                )
        return self


@dataclass(frozen=True, eq=False)
class Segment:
    """One phase of the trajectory: a joint-synchronised move, or a dwell (``distance_rad == 0``).

    The fastest-moving joint travels ``distance_rad`` along the path parameter ``s``; joint positions are
    ``q = q_start_rad + direction * s``, where ``direction = Δq / distance_rad`` has largest magnitude 1.

    Attributes:
        waypoint: index of the waypoint this phase moves into or dwells at.
        t_start_s: program time at which the phase begins [s].
        duration_s: length of the phase [s].
        q_start_rad: joint positions at the start [rad].
        direction: joint displacement per unit of ``s`` (zero for a dwell) [rad/rad].
        distance_rad: travel of the fastest-moving joint [rad].
        speed_radps: peak speed of the fastest-moving joint (the cap, or less if triangular) [rad/s].
        accel_radps2: acceleration and deceleration of the fastest-moving joint [rad/s²].
        t_accel_s: duration of the acceleration (and of the deceleration) [s].
    """

    waypoint: int
    t_start_s: float
    duration_s: float
    q_start_rad: FloatArray
    direction: FloatArray
    distance_rad: float
    speed_radps: float
    accel_radps2: float
    t_accel_s: float

    def path(self, t_local_s: float) -> tuple[float, float]:
        """Path parameter ``s`` [rad] and its rate ``ṡ`` [rad/s] at time ``t_local_s`` into the phase."""
        if self.distance_rad == 0.0:
            return 0.0, 0.0
        t = min(max(t_local_s, 0.0), self.duration_s)
        a, v, t_a = self.accel_radps2, self.speed_radps, self.t_accel_s
        if t < t_a:
            return 0.5 * a * t * t, a * t
        remaining_s = self.duration_s - t
        if remaining_s < t_a:
            return self.distance_rad - 0.5 * a * remaining_s * remaining_s, a * remaining_s
        return 0.5 * a * t_a * t_a + v * (t - t_a), v


@dataclass(frozen=True, eq=False)
class Trajectory:
    """The time-parameterised program, one cycle long; time wraps modulo ``duration_s``.

    Attributes:
        segments: the phases in order; the first starts at 0 at standstill at waypoint 0.
        duration_s: length of one program cycle [s].
        waypoints_rad: joint positions of the waypoints, shape (W, n) [rad].
        arrival_s: program time at which each waypoint is reached, shape (W,) [s] (waypoint 0: 0).
    """

    segments: tuple[Segment, ...]
    duration_s: float
    waypoints_rad: FloatArray
    arrival_s: FloatArray

    @property
    def n_joints(self) -> int:
        return int(self.waypoints_rad.shape[1])

    def sample(self, t_s: float) -> tuple[FloatArray, FloatArray]:
        """Joint positions [rad] and nominal joint velocities (dq/dt at 100 % override) [rad/s] at ``t_s``.

        ``t_s`` is the program time [s]; it wraps modulo :attr:`duration_s`.
        """
        t = math.fmod(t_s, self.duration_s)
        if t < 0.0:
            t += self.duration_s
        index = _segment_index(self.segments, t)
        segment = self.segments[index]
        s, s_dot = segment.path(t - segment.t_start_s)
        q_rad = segment.q_start_rad + segment.direction * s
        qd_nominal_radps = segment.direction * s_dot
        return q_rad, qd_nominal_radps


def _segment_index(segments: tuple[Segment, ...], t_s: float) -> int:
    """Index of the last segment starting at or before ``t_s`` (binary search)."""
    lo, hi = 0, len(segments) - 1
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if segments[mid].t_start_s <= t_s:
            lo = mid
        else:
            hi = mid - 1
    return lo


def _read_only(array: FloatArray) -> FloatArray:
    out = np.array(array, dtype=float)
    out.setflags(write=False)
    return out


def parse_program(raw: dict[str, Any], source: str = "program") -> Program:
    """Validate a program given as a dictionary (the parsed TOML).

    Raises:
        ConfigError: not a valid program; the one-line message names ``source``.
    """
    try:
        return Program.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(one_line(exc, source)) from None


def load_program(path: Path | str) -> Program:
    """Read and validate a program file.

    Raises:
        ConfigError: the file is missing, not TOML, or not a valid program.
    """
    path = Path(path)
    raw = read_toml(path)
    return parse_program(raw, str(path))


def program_waypoints_rad(path: Path | str) -> FloatArray:
    """The joint positions of a program's waypoints (``[[waypoints]] q_rad``), shape (W, n) [rad]: the program file
    read by :func:`load_program`, as the controller reads it.

    Raises:
        ConfigError: see :func:`load_program`.
    """
    return np.array([w.q_rad for w in load_program(path).waypoints], dtype=float)


def _label(index: int, waypoint: Waypoint) -> str:
    return f"waypoint {index} ({waypoint.name!r})" if waypoint.name else f"waypoint {index}"


def _check_against_robot(program: Program, robot: RobotModel) -> None:
    n = robot.n_joints
    lower = np.asarray(robot.model.lowerPositionLimit, dtype=float)
    upper = np.asarray(robot.model.upperPositionLimit, dtype=float)
    for i, waypoint in enumerate(program.waypoints):
        if len(waypoint.q_rad) != n:
            raise ConfigError(
                f"{_label(i, waypoint)} has {len(waypoint.q_rad)} joint values; allowed: {n}, one per joint "
                f"of robot {robot.name!r} ({', '.join(robot.joint_names)})"
            )
        for j, q in enumerate(waypoint.q_rad):
            if not lower[j] <= q <= upper[j]:
                raise ConfigError(
                    f"{_label(i, waypoint)}: {robot.joint_names[j]} = {q} rad is outside its limits; "
                    f"allowed: [{lower[j]:.4f}, {upper[j]:.4f}] rad"
                )


def _move(
    index: int,
    waypoint: Waypoint,
    q_from_rad: FloatArray,
    q_to_rad: FloatArray,
    t_start_s: float,
    robot: RobotModel,
) -> Segment:
    """The synchronised trapezoidal (or triangular) move from ``q_from_rad`` into waypoint ``index``."""
    delta_rad = q_to_rad - q_from_rad
    distance_rad = float(np.max(np.abs(delta_rad)))
    if distance_rad < MIN_MOVE_RAD:
        raise ConfigError(
            f"{_label(index, waypoint)} equals the waypoint before it; allowed: distinct consecutive "
            "waypoints (the first counts as following the last; use dwell_s to wait)"
        )
    direction = delta_rad / distance_rad
    v_cap, a = waypoint.max_speed_radps, waypoint.max_accel_radps2
    # Every joint moves at |direction_j| times the speed of the fastest one.
    joint_speed_radps = v_cap * np.abs(direction)
    over = np.flatnonzero(joint_speed_radps > robot.velocity_limit_radps)
    if over.size:
        j = int(over[0])
        allowed = float(np.min(robot.velocity_limit_radps / np.maximum(np.abs(direction), 1e-12)))
        raise ConfigError(
            f"{_label(index, waypoint)}: max_speed_radps = {v_cap} moves {robot.joint_names[j]} at "
            f"{joint_speed_radps[j]:.3f} rad/s, above its URDF velocity limit {robot.velocity_limit_radps[j]} "
            f"rad/s; allowed: max_speed_radps <= {allowed:.3f} for this move"
        )
    if distance_rad <= v_cap * v_cap / a:
        # Triangular: the cap is not reached before the move must decelerate.
        t_accel_s = math.sqrt(distance_rad / a)
        speed_radps = a * t_accel_s
        duration_s = 2.0 * t_accel_s
    else:
        t_accel_s = v_cap / a
        speed_radps = v_cap
        duration_s = distance_rad / v_cap + v_cap / a
    return Segment(
        waypoint=index,
        t_start_s=t_start_s,
        duration_s=duration_s,
        q_start_rad=_read_only(q_from_rad),
        direction=_read_only(direction),
        distance_rad=distance_rad,
        speed_radps=speed_radps,
        accel_radps2=a,
        t_accel_s=t_accel_s,
    )


def _dwell(index: int, q_rad: FloatArray, t_start_s: float, duration_s: float) -> Segment:
    return Segment(
        waypoint=index,
        t_start_s=t_start_s,
        duration_s=duration_s,
        q_start_rad=_read_only(q_rad),
        direction=_read_only(np.zeros_like(q_rad)),
        distance_rad=0.0,
        speed_radps=0.0,
        accel_radps2=0.0,
        t_accel_s=0.0,
    )


def build_trajectory(program: Program, robot: RobotModel) -> Trajectory:
    """Check a program against the robot and time-parameterise it.

    Phases: dwell at waypoint 0, move into waypoint 1, dwell there, ..., move from the last waypoint
    back into waypoint 0 (with waypoint 0's caps). Dwells of 0 s are left out.

    Raises:
        ConfigError: wrong joint count, a position outside the joint limits, a speed cap that would
            drive a joint beyond its URDF velocity limit, or two equal consecutive waypoints.
    """
    _check_against_robot(program, robot)
    waypoints_rad = np.asarray([w.q_rad for w in program.waypoints], dtype=float)
    count = len(program.waypoints)
    segments: list[Segment] = []
    arrival_s = np.zeros(count)
    t_s = 0.0
    for i in range(count + 1):
        index = i % count
        waypoint = program.waypoints[index]
        if i > 0:
            move = _move(index, waypoint, waypoints_rad[i - 1], waypoints_rad[index], t_s, robot)
            segments.append(move)
            t_s += move.duration_s
            if index == 0:
                break  # back at the start: the dwell at waypoint 0 opens the next cycle
            arrival_s[index] = t_s
        if waypoint.dwell_s > 0.0:
            segments.append(_dwell(index, waypoints_rad[index], t_s, waypoint.dwell_s))
            t_s += waypoint.dwell_s
    return Trajectory(
        segments=tuple(segments),
        duration_s=t_s,
        waypoints_rad=_read_only(waypoints_rad),
        arrival_s=_read_only(arrival_s),
    )


def load_trajectory(path: Path | str, robot: RobotModel) -> Trajectory:
    """Read a program file and time-parameterise it for ``robot``.

    Raises:
        ConfigError: see :func:`load_program` and :func:`build_trajectory`.
    """
    return build_trajectory(load_program(path), robot)
