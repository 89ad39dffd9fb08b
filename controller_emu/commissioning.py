"""Commissioning: measure a controller's stopping time and distance per joint, write the braking-time profile.

    .venv/bin/python -m controller_emu.commissioning [--config PATH] [--robot ur5] [--margin 0.1] [--write PATH]

The way ISO 10218-1 Annex B measurements are done: from several poses (program times spread over the program)
and several speeds (override 1/3, 2/3 and 1 by default), run the program at that override until the robot moves
steadily, command override 0 (a stop category 1 through the override, the only input of a closed controller),
and record every joint until it stands still. Per joint: the stopping time (from the first controller cycle that
sees the stop command to the joint's standstill, for good) and the stopping distance [rad].

This drives :class:`controller_emu.node.ControllerNode`, the step object the emulator process runs, directly on a
simulated clock (pure and fast: no Zenoh, no wall time). A real controller is measured the same way with its own
recorded joint states; only :func:`run_stop_trial` changes.

The gateway plans a stop from override δ to last δ t_b (safety-math.md §10): the profile's t_b of each joint is
the largest measured ``stop time / δ`` over all poses and speeds, times (1 + margin), rounded up to the
millisecond. The time the command waits for the controller's next cycle is not in the stop time: the gateway's
t_delay counts the controller cycle it measures. The controller emulator and the simulated cell refuse a
controller slower than the profile (:func:`hrc_devices.robots.time_scaling.check_braking_time`).
"""

from __future__ import annotations

import argparse
import math
import re
import sys
import tomllib
from pathlib import Path
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
from pydantic import ValidationError

from controller_emu.node import ControllerNode
from hrc_contract.config import ConfigError, ControllerConfig, RobotConfig, RobotModelConfig
from hrc_contract.errors import HrcError
from hrc_contract.messages import JointState, Override, to_payload
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import Trajectory, load_trajectory
from hrc_devices.robots.time_scaling import check_braking_time
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config, one_line, read_toml, resolve_urdf
from hrc_runtime.locate import find_cell_config

FloatArray = npt.NDArray[np.float64]

WALL0_NS = 1_790_000_000_000_000_000
"""Wall clock of the simulated measurement at its start [ns]."""
STANDSTILL_RADPS = 1e-9
"""A joint slower than this stands still [rad/s]."""
DEFAULT_SPEEDS = (1.0 / 3.0, 2.0 / 3.0, 1.0)
"""Override before the stop, as ISO 10218-1 Annex B's 33 %, 66 % and 100 % of the maximum speed."""
DEFAULT_POSES = 24
"""Stops measured per speed, at program times spread evenly over the program."""
DEFAULT_MARGIN = 0.1
"""The profile's t_b is the largest measured stop time per unit of override times 1 + this."""


class StopTrial(NamedTuple):
    """One stop: override ``speed`` → 0 at program time ``tau0_s``.

    Attributes:
        tau0_s: program time when the stop was commanded [s].
        speed: the override before the stop.
        moving: which joints moved when the stop was commanded.
        stop_time_s: per joint, from the first cycle that saw the stop to its standstill for good [s].
        stop_distance_rad: per joint, the path it travelled meanwhile (sum of |Δq|) [rad].
    """

    tau0_s: float
    speed: float
    moving: npt.NDArray[np.bool_]
    stop_time_s: FloatArray
    stop_distance_rad: FloatArray


class JointProfile(NamedTuple):
    """What the measurements say about one joint.

    Attributes:
        joint: its name.
        stop_time_s: the largest stop time at each speed of ``speeds`` [s] (nan: it never moved at that speed).
        per_override_s: the largest stop time divided by the override before the stop [s].
        distance_rad: the largest stopping distance at the largest speed [rad].
        braking_time_s: the profile's t_b: ``per_override_s`` × (1 + margin), rounded up to 1 ms [s].
        measured: False if the joint never moved in any trial (then the largest of the other joints is used).
    """

    joint: str
    stop_time_s: tuple[float, ...]
    per_override_s: float
    distance_rad: float
    braking_time_s: float
    measured: bool


def _clocks(t_s: float) -> Clocks:
    ns = round(t_s * 1e9)
    return Clocks(WALL0_NS + ns, ns)


def _override(robot: str, seq: int, t_s: float, delta: float) -> bytes:
    return to_payload(Override(robot=robot, seq=seq, stamp_ns=_clocks(t_s).wall_ns, delta=delta))


def _run(node: ControllerNode, robot: str, first_cycle: int, cycles: int, delta: float) -> list[JointState]:
    """Send ``delta`` and run one cycle, ``cycles`` times from cycle number ``first_cycle``; the joint states."""
    dt_s = node.config.cycle_s
    states = []
    for k in range(first_cycle, first_cycle + cycles):
        node.on_override(_override(robot, k, k * dt_s, delta), _clocks(k * dt_s))
        states.append(node.cycle(_clocks(k * dt_s)).joint_state)
    return states


def run_stop_trial(
    robot: str, trajectory: Trajectory, config: ControllerConfig, tau0_s: float, speed: float
) -> StopTrial:
    """Run the program at override ``speed`` until steady, then command 0 and record every joint until still.

    The controller starts early by its ramp to ``speed`` (plus two cycles), so that the stop is commanded at about
    program time ``tau0_s``. Overrides are sent every cycle, as the gateway does, and arrive at the cycle's time.
    Times count from the last joint state at speed (the cycle before the stop command) to the first joint state
    that shows the joint still for good, so a stop of δ t_b measures δ t_b.
    """
    dt_s = config.cycle_s
    ramp_cycles = math.ceil(speed * config.accel_time_s / dt_s) + 2
    start_s = (tau0_s - 0.5 * speed * speed * config.accel_time_s - 2 * dt_s * speed) % trajectory.duration_s
    node = ControllerNode(robot, trajectory, config, min(start_s, math.nextafter(trajectory.duration_s, 0.0)))
    at_speed = _run(node, robot, 0, ramp_cycles, speed)[-1]
    tau_stop_s = node.state.tau_s
    stop_cycles = math.ceil(speed * config.braking_time_s / dt_s) * 4 + 10
    states = _run(node, robot, ramp_cycles, stop_cycles, 0.0)
    q = np.array([at_speed.q] + [m.q for m in states])
    qd = np.abs(np.array([m.qd for m in states]))
    distance = np.abs(np.diff(q, axis=0)).sum(axis=0)
    n = np.arange(1, stop_cycles + 1, dtype=float)[:, None]  # cycles since the last one at speed
    t_still = np.max(np.where(qd > STANDSTILL_RADPS, n + 1.0, 0.0), axis=0) * dt_s
    moving = np.abs(np.asarray(at_speed.qd)) > STANDSTILL_RADPS
    return StopTrial(tau_stop_s, speed, moving, t_still, distance)


def measure(
    robot: str, trajectory: Trajectory, config: ControllerConfig, speeds: tuple[float, ...], poses: int
) -> list[StopTrial]:
    """Stops at ``poses`` program times spread evenly over the program, at each of ``speeds``."""
    taus = [trajectory.duration_s * (k + 0.5) / poses for k in range(poses)]
    return [run_stop_trial(robot, trajectory, config, tau, speed) for speed in speeds for tau in taus]


def _ceil_ms(t_s: float) -> float:
    return math.ceil(round(t_s * 1e3, 6)) / 1e3


def joint_profiles(
    joints: list[str], trials: list[StopTrial], speeds: tuple[float, ...], margin: float
) -> list[JointProfile]:
    """Per joint: the largest stop time at each speed, per unit of override, the distance and the profile's t_b.

    A joint that never moved takes the largest figure of the other joints (the controller stops every joint with
    one override ramp), marked ``measured = False``.

    Raises:
        ConfigError: no joint moved in any trial (nothing was measured).
    """
    times = np.array([t.stop_time_s for t in trials])
    moving = np.array([t.moving for t in trials])
    speed_of = np.array([t.speed for t in trials])
    if not moving.any():
        raise ConfigError("no joint moved in any stop trial: nothing to measure; allowed: a program that moves")
    per_override = np.where(moving, times / speed_of[:, None], 0.0).max(axis=0)
    fallback = float(per_override.max())
    top = speed_of == max(speeds)
    profiles = []
    for j, joint in enumerate(joints):
        measured = bool(moving[:, j].any())
        at_speed = tuple(
            float(times[(speed_of == v) & moving[:, j], j].max())
            if (moving[:, j] & (speed_of == v)).any()
            else math.nan
            for v in speeds
        )
        per = float(per_override[j]) if measured else fallback
        distance = float(max((t.stop_distance_rad[j] for t, m in zip(trials, top, strict=True) if m), default=0.0))
        profiles.append(JointProfile(joint, at_speed, per, distance, _ceil_ms(per * (1.0 + margin)), measured))
    return profiles


def profile_text(manual_text: str, profiles: list[JointProfile], header: str) -> str:
    """The manual profile's text with its braking times (and the comment above them) replaced by the measured ones.

    Raises:
        ConfigError: the manual profile has no ``braking_time_s = [...]`` line.
    """
    values = ", ".join(f"{p.braking_time_s:.3f}" for p in profiles)
    pattern = re.compile(r"(?:^#[^\n]*\n)*^braking_time_s\s*=\s*\[[^\]]*\]", re.MULTILINE)
    if not pattern.search(manual_text):
        raise ConfigError("the manual profile has no braking_time_s = [...] line; allowed: a robot model TOML")
    comment = "".join(f"# {line}\n" if line else "#\n" for line in header.splitlines())
    return pattern.sub(lambda _: f"{comment}braking_time_s = [{values}]", manual_text, count=1)


def report_lines(profiles: list[JointProfile], speeds: tuple[float, ...], manual_s: list[float], margin: float) -> str:
    """The table printed by the command (and written into the profile's comment)."""
    heads = " ".join(f"{f'stop@{v:.0%}':>9}" for v in speeds)
    lines = [f"{'joint':<20} {heads} {'per δ':>7} {'dist@max':>9} {'t_b (+' + f'{margin:.0%}' + ')':>11} {'manual':>7}"]
    for p, manual in zip(profiles, manual_s, strict=True):
        stops = " ".join(f"{t:>8.3f}s" if math.isfinite(t) else f"{'-':>9}" for t in p.stop_time_s)
        note = "" if p.measured else "  (never moved: the largest of the other joints)"
        lines.append(
            f"{p.joint:<20} {stops} {p.per_override_s:>6.3f}s {p.distance_rad:>6.3f}rad "
            f"{p.braking_time_s:>10.3f}s {manual:>6.3f}s{note}"
        )
    return "\n".join(lines)


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m controller_emu.commissioning",
        description="Measure the emulated controller's stopping time and distance per joint (override 1 → 0 from "
        "several speeds and poses, as ISO 10218-1 Annex B) and write the braking-time profile the gateway reads.",
    )
    parser.add_argument("--config", default=None, help="cell configuration (default configs/cell.toml)")
    parser.add_argument("--robot", default=None, help="robot of the cell (default: its first)")
    parser.add_argument(
        "--speeds", type=float, nargs="+", default=list(DEFAULT_SPEEDS), help="overrides before the stop"
    )
    parser.add_argument("--poses", type=int, default=DEFAULT_POSES, help=f"stops per speed (default {DEFAULT_POSES})")
    parser.add_argument(
        "--margin", type=float, default=DEFAULT_MARGIN, help="added to the measured times (0.1 = 10 %%)"
    )
    parser.add_argument("--write", default=None, metavar="PATH", help="write the profile here (a robot model TOML)")
    return parser


class Commissioning(NamedTuple):
    """The outcome of one commissioning run.

    Attributes:
        robot: the robot measured.
        profiles: per joint, what was measured and the profile's t_b.
        table: the printed table.
        text: the measured profile (a robot model TOML), checked with :func:`check_profile`.
        manual: the manual profile it was made from.
    """

    robot: str
    profiles: list[JointProfile]
    table: str
    text: str
    manual: Path


def commission(
    config_path: str | None, robot: str | None, speeds: tuple[float, ...], poses: int, margin: float
) -> Commissioning:
    """Measure one robot of the cell, build its measured profile and check it.

    Raises:
        ConfigError: an invalid cell, robot or argument, or a profile the controller would stop slower than.
    """
    if not speeds or not all(0.0 < v <= 1.0 for v in speeds) or poses < 1 or not 0.0 <= margin <= 1.0:
        raise ConfigError(
            f"speeds {speeds}, poses {poses}, margin {margin}; allowed: speeds in (0, 1], poses >= 1, margin in [0, 1]"
        )
    cell = load_cell_config(config_path)
    name = robot or next(iter(cell.robots))
    if name not in cell.robots:
        raise ConfigError(f"robot {name!r} is not in the cell; allowed: {', '.join(cell.robots)}")
    robot_config = cell.robots[name]
    model = load_robot_model(name, robot_config)
    trials = measure(name, load_trajectory(robot_config.program, model), robot_config.controller, speeds, poses)
    profiles = joint_profiles(list(robot_config.model.joints), trials, speeds, margin)
    table = report_lines(profiles, speeds, list(robot_config.model.braking_time_s), margin)
    manual = manual_profile_path(config_path, name)
    header = (
        "Stopping times MEASURED on the emulated controller (controller_emu/commissioning.py, ControllerNode on a\n"
        f"simulated clock): {poses} poses x overrides {', '.join(f'{v:.2f}' for v in speeds)} -> 0. t_b of a joint = "
        f"largest stop time / override x (1 + {margin}),\nrounded up to 1 ms. The manual (conservative) profile is "
        f"{manual.name}. Regenerate with:\n  .venv/bin/python -m controller_emu.commissioning --write "
        f"configs/robots/{manual.stem}_measured.toml\n\n{table}"
    )
    text = profile_text(manual.read_text(), profiles, header)
    check_profile(text, manual, name, robot_config)
    return Commissioning(name, profiles, table, text, manual)


def manual_profile_path(config_path: str | None, robot: str) -> Path:
    """The robot model file the cell names for ``robot`` (the profile the measured one is written next to)."""
    cell_path = find_cell_config(config_path).resolve()
    model_ref = read_toml(cell_path)["robots"][robot]["model"]
    return (cell_path.parent / str(model_ref)).resolve()


def check_profile(text: str, manual: Path, name: str, robot_config: RobotConfig) -> RobotModel:
    """The robot as the gateway would load it with the profile ``text``, refused if the controller stops slower.

    Raises:
        ConfigError: the profile is not a valid robot model, or the controller's braking time exceeds a link's t_b.
    """
    raw = tomllib.loads(text)
    raw["urdf"] = str(resolve_urdf(str(raw["urdf"]), manual.parent))
    try:
        model_config = RobotModelConfig.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(one_line(exc, "measured profile")) from None
    robot = load_robot_model(name, robot_config.model_copy(update={"model": model_config}))
    check_braking_time(robot_config.controller, robot)
    return robot


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        result = commission(args.config, args.robot, tuple(args.speeds), args.poses, args.margin)
    except HrcError as exc:
        print(f"commissioning: {exc}", file=sys.stderr)
        return 2
    print(f"robot {result.robot}: stop from override δ -> 0, measured; margin {args.margin:.0%}")
    print(result.table)
    if args.write:
        Path(args.write).write_text(result.text)
        print(f"wrote {args.write} (checked: it loads, and the controller stops within every t_b)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
