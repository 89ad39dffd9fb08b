"""The recorded program model against the emulator's true program.

A cycle is recorded from the real :class:`controller_emu.node.ControllerNode` on a simulated clock (as
``controller_emu/commissioning.py`` drives it) at δ = 0.5 with noise on ``q`` and ``qd``; the robot is then run along
the whole program at δ = 1, 0.5, 0.05 and stopped (δ = 0) at many points, and the located ``qd_nominal`` is compared
with the one the emulator reports (the true programmed velocity). The error figures of the report come from::

    .venv/bin/python tests/controller_bridge/test_program_model.py
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import NamedTuple

import numpy as np
import numpy.typing as npt
import pytest

from controller_bridge import program_model as pm
from controller_bridge.program_model import (
    STATED_TOLERANCE_RADPS,
    STATED_TOLERANCE_RATIO,
    ProgramModel,
    ProgramModelError,
    ProgramSample,
    load_model,
    record_program,
    save_model,
)
from controller_emu.node import ControllerNode
from hrc_contract.config import CellConfig, ControllerConfig
from hrc_contract.messages import JointState, Override, to_payload
from hrc_devices.controllers.vendor import ControllerReading
from hrc_devices.robots.model import load_robot_model
from hrc_devices.robots.program import Trajectory, load_trajectory
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config

FloatArray = npt.NDArray[np.float64]

WALL0_NS = 1_790_000_000_000_000_000
Q_NOISE_RAD = 1e-4
"""Position noise of the read-back (σ per joint) [rad]: pessimistic for UR ``actual_q`` (encoder noise ~1e-5 rad)."""
QD_NOISE_RADPS = 2e-3
"""Velocity noise of the read-back (σ per joint) [rad/s]."""
RECORD_DELTA = 0.5


class Reading(NamedTuple):
    """One emulated read-back: what the bridge would see (noisy) and the truth."""

    t_s: float
    q_rad: FloatArray
    qd_radps: FloatArray
    override: float
    qd_nominal_radps: FloatArray


def _clocks(t_s: float) -> Clocks:
    ns = round(t_s * 1e9)
    return Clocks(WALL0_NS + ns, ns)


def run_emulator(
    trajectory: Trajectory,
    config: ControllerConfig,
    deltas: Iterator[float] | list[float],
    tau0_s: float = 0.0,
    seed: int = 0,
    robot: str = "r",
) -> Iterator[Reading]:
    """Drive a ControllerNode with one commanded δ per cycle; yield each cycle's noisy read-back and the truth."""
    rng = np.random.default_rng(seed)
    node = ControllerNode(robot, trajectory, config, tau0_s)
    dt_s = config.cycle_s
    for k, delta in enumerate(deltas):
        now = _clocks(k * dt_s)
        node.on_override(to_payload(Override(robot=robot, seq=k, stamp_ns=now.wall_ns, delta=delta)), now)
        state: JointState = node.cycle(now).joint_state
        n = len(state.q)
        yield Reading(
            k * dt_s,
            np.asarray(state.q) + rng.normal(0.0, Q_NOISE_RAD, n),
            np.asarray(state.qd) + rng.normal(0.0, QD_NOISE_RADPS, n),
            state.override,
            np.asarray(state.qd_nominal),
        )


def record_emulated(
    trajectory: Trajectory,
    config: ControllerConfig,
    joints: tuple[str, ...],
    cycles: float = 1.3,
    tau0_s: float = 0.7,
    with_qd: bool = True,
    seed: int = 1,
) -> list[ProgramSample]:
    """The samples of a recording at δ = 0.5: ramp up, then ``cycles`` program cycles (the ramp is left out)."""
    ramp = math.ceil(RECORD_DELTA * config.accel_time_s / config.cycle_s) + 2
    count = ramp + math.ceil(cycles * trajectory.duration_s / RECORD_DELTA / config.cycle_s)
    readings = list(run_emulator(trajectory, config, [RECORD_DELTA] * count, tau0_s, seed))[ramp:]
    return [ProgramSample(r.t_s, tuple(r.q_rad), tuple(r.qd_radps) if with_qd else None, r.override) for r in readings]


def stop_and_go(duration_s: float, delta: float, stops: int, config: ControllerConfig) -> list[float]:
    """Commanded δ per cycle: one program cycle at ``delta`` with ``stops`` standstills (δ = 0 for 0.4 s) on the way."""
    run_cycles = math.ceil(duration_s / delta / config.cycle_s)
    per_leg = run_cycles // stops
    still = math.ceil((0.4 + config.braking_time_s) / config.cycle_s)
    deltas: list[float] = []
    for _ in range(stops):
        deltas += [delta] * per_leg + [0.0] * still
    return deltas


class Errors(NamedTuple):
    """Located against true qd_nominal along a run (only where the robot is located), and the unlocated count."""

    abs_radps: FloatArray
    excess: FloatArray
    true_radps: FloatArray
    unlocated: int
    located: int


def track(
    model: ProgramModel, readings: list[Reading], every: int = 1, keep: Callable[[Reading], bool] | None = None
) -> Errors:
    """Locate every ``every``-th reading with continuity; per joint |error| and its excess over the stated tolerance
    (of the readings ``keep`` keeps, if given)."""
    previous: int | None = None
    errors, true, unlocated = [], [], 0
    for r in readings[::every]:
        where = model.locate(r.q_rad, previous, r.qd_radps)
        if where is None:
            unlocated += 1
            previous = None
            continue
        previous = where.index
        if keep is not None and not keep(r):
            continue
        errors.append(np.abs(where.qd_nominal_radps - r.qd_nominal_radps))
        true.append(r.qd_nominal_radps)
    abs_err, truth = np.array(errors), np.abs(np.array(true))
    excess = abs_err - (STATED_TOLERANCE_RADPS + STATED_TOLERANCE_RATIO * truth)
    return Errors(abs_err, excess, truth, unlocated, len(errors))


# -- fixtures --------------------------------------------------------------------------------------------------------


class Robot(NamedTuple):
    name: str
    trajectory: Trajectory
    config: ControllerConfig
    joints: tuple[str, ...]


def _robot(cell: CellConfig, name: str) -> Robot:
    config = cell.robots[name]
    trajectory = load_trajectory(config.program, load_robot_model(name, config))
    return Robot(name, trajectory, config.controller, tuple(config.model.joints))


@pytest.fixture(scope="module")
def ur5(cell_config: CellConfig) -> Robot:
    return _robot(cell_config, "ur5")


@pytest.fixture(scope="module")
def model(ur5: Robot) -> ProgramModel:
    return record_program(record_emulated(ur5.trajectory, ur5.config, ur5.joints), "ur5", ur5.joints, "2026-01-30")


# -- recording -------------------------------------------------------------------------------------------------------


def test_the_recorded_cycle_is_one_program_cycle(ur5: Robot, model: ProgramModel) -> None:
    assert model.duration_s == pytest.approx(ur5.trajectory.duration_s, abs=0.01)
    assert model.scaling == pytest.approx(RECORD_DELTA)
    assert model.noise_rad == pytest.approx(Q_NOISE_RAD, rel=0.3)
    # every path point is on the true program (the velocities: the locating tests below)
    dense = np.array([ur5.trajectory.sample(t)[0] for t in np.arange(0.0, ur5.trajectory.duration_s, 2e-4)])
    for k in range(0, model.n_samples, 97):
        assert np.linalg.norm(dense - model.q_rad[k], axis=1).min() < 5 * Q_NOISE_RAD


def test_half_a_cycle_is_refused(ur5: Robot) -> None:
    samples = record_emulated(ur5.trajectory, ur5.config, ur5.joints, cycles=0.5)
    with pytest.raises(ProgramModelError, match="not one whole program cycle"):
        record_program(samples, "ur5", ur5.joints, "today")


def test_a_recording_with_nan_is_refused(ur5: Robot) -> None:
    samples = record_emulated(ur5.trajectory, ur5.config, ur5.joints)
    k = len(samples) // 3
    samples[k] = samples[k]._replace(q_rad=(math.nan, *samples[k].q_rad[1:]))
    with pytest.raises(ProgramModelError, match=f"sample {k} .*non-finite"):
        record_program(samples, "ur5", ur5.joints, "today")


def test_a_recording_with_a_gap_is_refused(ur5: Robot) -> None:
    samples = record_emulated(ur5.trajectory, ur5.config, ur5.joints)
    del samples[400:420]
    with pytest.raises(ProgramModelError, match=r"gap of 84\.0 ms"):
        record_program(samples, "ur5", ur5.joints, "today")


def test_a_recording_at_a_low_override_is_refused(ur5: Robot) -> None:
    samples = [s._replace(scaling=0.2) for s in record_emulated(ur5.trajectory, ur5.config, ur5.joints)]
    with pytest.raises(ProgramModelError, match=r"override was 0\.200 .* at least 0\.3"):
        record_program(samples, "ur5", ur5.joints, "today")


def test_a_recording_at_a_changing_override_is_refused(ur5: Robot) -> None:
    samples = record_emulated(ur5.trajectory, ur5.config, ur5.joints)
    samples[100] = samples[100]._replace(scaling=0.4)
    with pytest.raises(ProgramModelError, match="steady override"):
        record_program(samples, "ur5", ur5.joints, "today")


def test_a_retraced_move_does_not_close_the_cycle(ur5: Robot) -> None:
    """Started mid-swing, the path passes the start again (swinging back) half a cycle later: not a closure."""
    tau_mid_swing_s = float(ur5.trajectory.segments[4].t_start_s) + 0.3
    samples = record_emulated(ur5.trajectory, ur5.config, ur5.joints, tau0_s=tau_mid_swing_s)
    end = pm.find_cycle_end(np.array([s.q_rad for s in samples]))
    assert end * ur5.config.cycle_s * RECORD_DELTA == pytest.approx(ur5.trajectory.duration_s, abs=0.01)


def test_without_qd_the_velocity_comes_from_q(ur5: Robot) -> None:
    """ABB RWS reports no joint velocity: the derivative of q over program time stands in."""
    samples = record_emulated(ur5.trajectory, ur5.config, ur5.joints, with_qd=False)
    model = record_program(samples, "ur5", ur5.joints, "today")
    assert model.velocity_source == "q_differences"
    readings = list(run_emulator(ur5.trajectory, ur5.config, [1.0] * 2200, seed=5))[200:]
    errors = track(model, readings)
    assert errors.unlocated <= 1
    assert errors.excess.max() <= 0.0


# -- locating --------------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("delta", [1.0, 0.5, 0.05])
def test_qd_nominal_along_the_whole_program(ur5: Robot, model: ProgramModel, delta: float) -> None:
    """One whole cycle (plus the ramp) at δ: the located qd_nominal is within the stated tolerance everywhere."""
    ramp = math.ceil(delta * ur5.config.accel_time_s / ur5.config.cycle_s) + 2
    cycles = ramp + math.ceil(1.02 * ur5.trajectory.duration_s / delta / ur5.config.cycle_s)
    readings = list(run_emulator(ur5.trajectory, ur5.config, [delta] * cycles, tau0_s=2.0, seed=3))
    every = 1 if delta >= 0.5 else 8  # 32 ms apart at δ = 0.05: 1.6 ms of program time
    errors = track(model, readings, every)
    assert errors.unlocated <= 1  # only the cold start may be ambiguous (a retraced stretch at standstill)
    assert errors.excess.max() <= 0.0, f"worst {errors.abs_radps.max():.4f} rad/s"
    # away from the ends of moves (|qd_nominal| ≥ 0.3 rad/s) it is much better than stated
    fast = errors.true_radps >= 0.3
    assert (errors.abs_radps[fast] <= 0.01 + 0.01 * errors.true_radps[fast]).all()


def test_qd_nominal_standing_still_at_many_points(ur5: Robot, model: ProgramModel) -> None:
    """δ = 0 at 24 points of the program, 0.4 s each (100 noisy readings per point): q alone locates the robot."""
    deltas = stop_and_go(ur5.trajectory.duration_s, 0.5, 24, ur5.config)
    readings = list(run_emulator(ur5.trajectory, ur5.config, deltas, tau0_s=0.0, seed=4))
    errors = track(model, readings, keep=_standing)
    assert errors.unlocated <= 1
    assert errors.located > 2000
    assert errors.excess.max() <= 0.0
    still = track(model, readings, keep=lambda r: _standing(r) and np.abs(r.qd_nominal_radps).max() > 0.3)
    assert still.located > 1000  # most stops are mid-move, where the program moves fast
    assert still.excess.max() <= 0.0
    # never zero where the program moves: the fastest joint keeps at least 95 % of its programmed speed
    assert (still.abs_radps.max(axis=1) <= 0.05 * still.true_radps.max(axis=1)).all()


def _standing(r: Reading) -> bool:
    return r.override == 0.0


def test_off_the_program_is_none(model: ProgramModel) -> None:
    q = model.q_rad[500].copy()
    assert model.locate(q, 500) is not None
    q[1] += 3 * model.tolerance_rad
    assert model.locate(q, 500) is None
    assert model.locate(q) is None
    assert model.locate(np.full(6, math.nan)) is None
    assert model.locate(q[:5]) is None


def test_a_retraced_stretch_is_ambiguous_without_continuity(ur5: Robot, model: ProgramModel) -> None:
    """Mid-approach to the pick the path is also mid-retreat (the same line, upward): q alone cannot tell."""
    approach = next(s for s in ur5.trajectory.segments if s.waypoint == 1 and s.distance_rad > 0)  # into "pick"
    tau_s = approach.t_start_s + 0.5 * approach.duration_s
    q, qd_true = ur5.trajectory.sample(tau_s)
    assert model.locate(q) is None  # the two candidates move in opposite directions: refuse to guess
    by_motion = model.locate(q, motion_radps=0.05 * qd_true)  # the measured motion chooses
    assert by_motion is not None
    assert by_motion.index is not None
    assert np.abs(by_motion.qd_nominal_radps - qd_true).max() < 0.02
    retreat = model.locate(q, motion_radps=-0.05 * qd_true)
    assert retreat is not None
    assert np.abs(retreat.qd_nominal_radps + qd_true).max() < 0.02
    # with continuity from a little earlier on the approach, q alone is enough
    earlier = model.locate(ur5.trajectory.sample(tau_s - 0.05)[0], motion_radps=qd_true)
    assert earlier is not None
    tracked = model.locate(q, earlier.index)
    assert tracked is not None
    assert np.abs(tracked.qd_nominal_radps - qd_true).max() < 0.02


def test_parts_that_agree_are_merged_to_the_largest_magnitude() -> None:
    """A figure-eight crosses itself: at the crossing both parts are candidates; they agree in sign, so the larger
    magnitude per joint is taken (the conservative speed for the gateway)."""
    tau = np.linspace(0.0, 2.0, 400, endpoint=False)
    w = 2 * math.pi / 2.0
    q = np.stack((np.sin(w * tau), np.sin(2 * w * tau) * 0.5), axis=1)
    qd = np.stack((w * np.cos(w * tau), w * np.cos(2 * w * tau)), axis=1)
    model = ProgramModel("r", ("a", "b"), 0.5, "today", "qd", tau, 2.0, q, qd, 1e-4)
    # the crossing at τ = 0 (qd = (w, w)) and at τ = 1 (qd = (−w, w)): joint a disagrees, so None, unless the
    # measured motion says which
    assert model.locate([0.0, 0.0]) is None
    chosen = model.locate([0.0, 0.0], motion_radps=np.array([1.0, 0.2]))
    assert chosen is not None
    assert chosen.qd_nominal_radps == pytest.approx([w, w], abs=0.05)
    shifted = ProgramModel("r", ("a", "b"), 0.5, "today", "qd", tau, 2.0, q, np.abs(qd) + 0.1 * tau[:, None], 1e-4)
    merged = shifted.locate([0.0, 0.0])
    assert merged is not None
    assert merged.parts >= 2
    assert merged.index is None
    assert merged.qd_nominal_radps == pytest.approx([w + 0.1, w + 0.1], abs=0.05)  # τ = 1's, the larger


# -- the file and the command ----------------------------------------------------------------------------------------


def test_save_and_load(model: ProgramModel, tmp_path: Path) -> None:
    path = tmp_path / "ur5.json"
    save_model(model, path)
    loaded = load_model(path, "ur5", model.joint_names)
    assert loaded.recorded_at == "2026-01-30"
    assert loaded.scaling == model.scaling
    np.testing.assert_array_equal(loaded.q_rad, model.q_rad)
    np.testing.assert_array_equal(loaded.qd_nominal_radps, model.qd_nominal_radps)
    with pytest.raises(ProgramModelError, match="recorded for robot 'ur5'; allowed: a model of robot 'panda'"):
        load_model(path, "panda")
    with pytest.raises(ProgramModelError, match="has joints"):
        load_model(path, "ur5", model.joint_names[::-1])
    path.write_text(path.read_text().replace('"hrc.program_model/1"', '"hrc.program_model/2"'))
    with pytest.raises(ProgramModelError, match=r"not a hrc\.program_model/1 file"):
        load_model(path)


def test_check_prints_the_summary(model: ProgramModel, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "ur5.json"
    save_model(model, path)
    assert pm.main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "robot 'ur5'" in out
    assert "shoulder_pan_joint" in out
    assert pm.main(["check", str(tmp_path / "missing.json")]) == 2


def test_readings_become_samples() -> None:
    reading = ControllerReading(0, 2_000_000_000, (0.1, 0.2), None, (0.5, -0.5), 0.8, 0.5, True, "")
    (sample,) = pm.samples_from_readings([reading])
    assert sample == ProgramSample(2.0, (0.1, 0.2), (0.5, -0.5), 0.4, True)


def test_record_without_a_vendor_interface_says_so(tmp_path: Path) -> None:
    with pytest.raises(ProgramModelError, match="no vendor interface"):
        pm.record_command(None, "ur5", tmp_path / "x.json", 1.0)


# -- the measurement of the report -----------------------------------------------------------------------------------


def measure(robot: Robot) -> None:
    samples = record_emulated(robot.trajectory, robot.config, robot.joints)
    model = record_program(samples, robot.name, robot.joints, "today")
    print(f"{robot.name}: {model.n_samples} samples, cycle {model.duration_s:.3f} s, noise {model.noise_rad:.2e} rad")
    runs = {}
    for delta in (1.0, 0.5, 0.05):
        ramp = math.ceil(delta * robot.config.accel_time_s / robot.config.cycle_s) + 2
        cycles = ramp + math.ceil(1.02 * robot.trajectory.duration_s / delta / robot.config.cycle_s)
        readings = list(run_emulator(robot.trajectory, robot.config, [delta] * cycles, tau0_s=2.0, seed=3))
        runs[f"δ={delta}"] = track(model, readings, 1 if delta >= 0.5 else 8)
    stops = list(
        run_emulator(
            robot.trajectory, robot.config, stop_and_go(robot.trajectory.duration_s, 0.5, 24, robot.config), seed=4
        )
    )
    runs["δ=0 (24 stops)"] = track(model, stops, keep=_standing)
    for name, e in runs.items():
        flat = e.abs_radps.ravel()
        rel = flat / np.maximum(e.true_radps.ravel(), 1e-9)
        fast = e.true_radps.ravel() >= 0.3
        if not e.located or not fast.any():
            print(f"  {name}: located {e.located}, unlocated {e.unlocated}, none fast")
            continue
        worst = np.unravel_index(np.argmax(e.abs_radps), e.abs_radps.shape)
        print(f"  worst at located #{worst[0]} joint {worst[1]}: true |qd_nominal| {e.true_radps[worst]:.3f}")
        print(
            f"  {name:<16} located {e.located:>5}, unlocated {e.unlocated}: |error| worst {flat.max():.4f} rad/s, "
            f"p99 {np.percentile(flat, 99):.4f} rad/s; "
            f"where |qd_nominal| ≥ 0.3 rad/s worst {flat[fast].max():.4f} rad/s "
            f"({rel[fast].max():.2%}); worst excess over stated {e.excess.max():+.4f}"
        )
    tracked: list[float] = []
    cold: list[float] = []
    index = None
    for r in stops:
        t0 = time.perf_counter()
        where = model.locate(r.q_rad, index, r.qd_radps)
        (cold if index is None else tracked).append(time.perf_counter() - t0)
        index = None if where is None else where.index
    for r in stops[:: len(stops) // 300]:
        t0 = time.perf_counter()
        model.locate(r.q_rad)
        cold.append(time.perf_counter() - t0)
    print(
        f"  locate: median {np.median(tracked) * 1e6:.0f} µs, p99 {np.percentile(tracked, 99) * 1e6:.0f} µs with "
        f"continuity ({len(tracked)} calls); median {np.median(cold) * 1e6:.0f} µs without (N = {model.n_samples})"
    )


if __name__ == "__main__":
    root = Path(__file__).resolve().parents[2]
    for cell_file, names in (("cell.toml", ("ur5",)), ("cell_two_arms.toml", ("panda",))):
        cell = load_cell_config(root / "configs" / cell_file)
        for name in names:
            measure(_robot(cell, name))
    sys.exit(0)
