"""The controller emulator's pure functions: override checks, bounded ramps, watchdog, program time, message.

The node that drives them (arrival times, newest wins, counting) is in ``test_controller_node.py``, the two
clocks in ``test_controller_clocks.py``.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import replace

import numpy as np
import pytest

from hrc_contract.config import ConfigError, ControllerConfig
from hrc_contract.messages import JointState, Override, parse_message, to_payload
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import Trajectory, build_trajectory, parse_program
from hrc_devices.robots.time_scaling import (
    MAX_FUTURE_STAMP_S,
    ControllerState,
    apply_override,
    check_braking_time,
    check_override,
    joint_state,
    step,
)
from hrc_runtime.config import load_cell_config

CONFIG = ControllerConfig(cycle_s=0.004, braking_time_s=0.24, accel_time_s=0.5, watchdog_s=0.1)
DT_S = CONFIG.cycle_s
DT_NS = round(DT_S * 1e9)
T0_NS = 1_790_000_000_000_000_000
ROBOT = "ur5"


@pytest.fixture(scope="module")
def robot() -> RobotModel:
    return load_robot_model(ROBOT, load_cell_config(None).robots[ROBOT])


@pytest.fixture(scope="module")
def trajectory(robot: RobotModel) -> Trajectory:
    waypoint = {"max_speed_radps": 1.0, "max_accel_radps2": 4.0}
    program = {
        "waypoints": [
            {"q_rad": [0.0, -1.5, 1.5, -1.5, -1.57, 0.0], "dwell_s": 0.2, **waypoint},
            {"q_rad": [0.5, -1.2, 1.2, -1.5, -1.57, 0.5], **waypoint},
        ]
    }
    return build_trajectory(parse_program(program), robot)  # 1.7 s per cycle


class Sim:
    """Drives the pure functions on simulated clocks: one override per cycle (or none), then a step.

    ``mono_ns`` is the controller's monotonic clock, ``now_ns`` the wall clock (of the controller and of
    the gateway's stamps, here the same).
    """

    def __init__(self, trajectory: Trajectory, state: ControllerState | None = None) -> None:
        self.trajectory = trajectory
        self.state = state or ControllerState()
        self.mono_ns = 0
        self.now_ns = T0_NS
        self.seq = 0
        self.rejected: Counter[str] = Counter()

    def override(self, delta: float, robot: str = ROBOT, stamp_ns: int | None = None) -> str | None:
        message = Override(
            robot=robot, seq=self.seq, stamp_ns=self.now_ns if stamp_ns is None else stamp_ns, delta=delta
        )
        self.seq += 1
        reason = check_override(message, ROBOT, self.state.override_stamp_ns, self.now_ns, CONFIG.watchdog_s)
        if reason is None:
            self.state = apply_override(self.state, message, self.mono_ns)
        else:
            self.rejected[reason] += 1
        return reason

    def tick(self) -> None:
        self.mono_ns += DT_NS
        self.now_ns += DT_NS

    def cycle(self, delta: float | None) -> ControllerState:
        """Advance the clocks by one cycle; send ``delta`` (unless None) and step."""
        self.tick()
        if delta is not None:
            self.override(delta)
        self.state = step(self.state, self.trajectory, CONFIG, self.mono_ns, DT_S)
        return self.state

    def run(self, delta: float | None, cycles: int) -> list[ControllerState]:
        return [self.cycle(delta) for _ in range(cycles)]


def _full_speed(trajectory: Trajectory) -> Sim:
    sim = Sim(trajectory)
    sim.run(1.0, math.ceil(CONFIG.accel_time_s / DT_S) + 2)
    assert sim.state.delta_applied == 1.0
    return sim


# --- start-up and ramps --------------------------------------------------------------------------


def test_starts_in_protective_stop_and_holds_still(trajectory: Trajectory) -> None:
    sim = Sim(trajectory)
    assert sim.state.mode == "protective_stop"
    assert sim.state.delta_applied == 0.0
    states = sim.run(None, 50)
    assert all(s.mode == "protective_stop" and s.delta_applied == 0.0 and s.tau_s == 0.0 for s in states)


def test_ramps_up_in_accel_time(trajectory: Trajectory) -> None:
    sim = Sim(trajectory)
    deltas = [s.delta_applied for s in sim.run(1.0, 200)]
    assert sim.state.mode == "running"
    assert deltas[0] == pytest.approx(DT_S / CONFIG.accel_time_s)
    assert np.all(np.diff(deltas) >= 0.0)
    assert np.max(np.diff(deltas)) <= DT_S / CONFIG.accel_time_s + 1e-12
    cycles_to_full = deltas.index(1.0) + 1
    assert cycles_to_full == pytest.approx(CONFIG.accel_time_s / DT_S, abs=1)


def test_partial_override_is_reached_and_held(trajectory: Trajectory) -> None:
    sim = Sim(trajectory)
    sim.run(0.4, 200)
    assert sim.state.delta_applied == 0.4
    assert sim.state.delta_commanded == 0.4


def test_brakes_within_braking_time_but_not_at_once(trajectory: Trajectory) -> None:
    sim = _full_speed(trajectory)
    deltas = [s.delta_applied for s in sim.run(0.0, 100)]
    assert deltas[0] == pytest.approx(1.0 - DT_S / CONFIG.braking_time_s), "not in a single step"
    assert np.min(np.diff(deltas)) >= -DT_S / CONFIG.braking_time_s - 1e-12
    cycles_to_zero = deltas.index(0.0) + 1
    assert cycles_to_zero * DT_S <= CONFIG.braking_time_s + DT_S
    assert cycles_to_zero * DT_S >= CONFIG.braking_time_s - DT_S
    assert sim.state.mode == "stopped"


def test_program_time_does_not_advance_at_zero_override(trajectory: Trajectory) -> None:
    sim = _full_speed(trajectory)
    sim.run(0.0, 100)
    tau_s = sim.state.tau_s
    sim.run(0.0, 100)
    assert sim.state.mode == "stopped"
    assert sim.state.tau_s == tau_s


def test_program_time_advances_by_mean_override(trajectory: Trajectory) -> None:
    sim = Sim(trajectory)
    sim.cycle(1.0)
    # δ goes 0 → dt/accel_time within the first step: τ advances by the mean times dt.
    assert sim.state.tau_s == pytest.approx(0.5 * (DT_S / CONFIG.accel_time_s) * DT_S)
    full = _full_speed(trajectory)
    tau_s = full.state.tau_s
    full.cycle(1.0)
    assert full.state.tau_s == pytest.approx(tau_s + DT_S)


def test_cycles_completed_increments_on_wrap(trajectory: Trajectory) -> None:
    sim = _full_speed(trajectory)
    sim.state = replace(sim.state, tau_s=trajectory.duration_s - 0.5 * DT_S)
    sim.cycle(1.0)
    assert sim.state.cycles_completed == 1
    assert sim.state.tau_s == pytest.approx(0.5 * DT_S)
    # Two full program cycles later: two more.
    sim.run(1.0, math.ceil(2 * trajectory.duration_s / DT_S))
    assert sim.state.cycles_completed == 3


# --- watchdog ------------------------------------------------------------------------------------


def test_watchdog_stops_and_overrides_resume(trajectory: Trajectory) -> None:
    sim = _full_speed(trajectory)
    silent = sim.run(None, 100)
    expired_at = next(i for i, s in enumerate(silent) if s.mode == "protective_stop")
    silence_s = (expired_at + 1) * DT_S
    assert CONFIG.watchdog_s < silence_s <= CONFIG.watchdog_s + DT_S + 1e-9
    assert all(s.delta_applied == 1.0 for s in silent[:expired_at]), "the last valid override holds until then"
    braking = [s.delta_applied for s in silent[expired_at:]]
    assert braking[0] == pytest.approx(1.0 - DT_S / CONFIG.braking_time_s), "a controlled stop, not a jump"
    assert 0.0 in braking
    assert braking.index(0.0) + 1 <= CONFIG.braking_time_s / DT_S + 1
    assert all(s.mode == "protective_stop" for s in silent[expired_at:])
    # Valid overrides come back: running again, ramping up.
    resumed = sim.run(1.0, 10)
    assert all(s.mode == "running" for s in resumed)
    assert resumed[-1].delta_applied == pytest.approx(10 * DT_S / CONFIG.accel_time_s)


def test_delayed_overrides_keep_it_running_within_watchdog(trajectory: Trajectory) -> None:
    sim = _full_speed(trajectory)
    for _ in range(20):  # one override every 0.096 s: just inside the watchdog
        states = sim.run(None, 23)
        sim.cycle(1.0)
        assert all(s.mode == "running" for s in states)
    assert sim.state.delta_applied == 1.0


# --- acceptance ----------------------------------------------------------------------------------


def test_rejections_are_counted_by_reason(trajectory: Trajectory) -> None:
    sim = _full_speed(trajectory)
    last = sim.state
    now_ns = sim.now_ns
    assert sim.override(0.0, robot="ur10") == "wrong_robot"
    assert sim.override(0.0, stamp_ns=last.override_stamp_ns) == "old_or_repeated"
    assert sim.override(0.0, stamp_ns=last.override_stamp_ns - 1) == "old_or_repeated"
    assert sim.override(0.0, stamp_ns=now_ns + round((MAX_FUTURE_STAMP_S + 0.001) * 1e9)) == "stamp_in_future"
    # Newer than the last accepted but older than the watchdog: stale.
    sim.now_ns += round(0.5 * 1e9)
    assert sim.override(0.0, stamp_ns=sim.now_ns - round(0.2 * 1e9)) == "stale"
    assert sim.override(0.0, stamp_ns=sim.now_ns - round((CONFIG.watchdog_s + 1e-6) * 1e9)) == "stale"
    assert dict(sim.rejected) == {"wrong_robot": 1, "old_or_repeated": 2, "stamp_in_future": 1, "stale": 2}
    # None of them changed the command or the echoed seq.
    assert sim.state.delta_commanded == 1.0
    assert sim.state.override_seq == last.override_seq
    assert sim.state.override_stamp_ns == last.override_stamp_ns


def test_stamps_at_the_limits_are_accepted(trajectory: Trajectory) -> None:
    sim = Sim(trajectory)
    assert sim.override(0.5, stamp_ns=sim.now_ns + round(MAX_FUTURE_STAMP_S * 1e9)) is None
    assert sim.state.delta_commanded == 0.5
    sim.now_ns += round(1e9)
    assert sim.override(0.25, stamp_ns=sim.now_ns - round(CONFIG.watchdog_s * 1e9)) is None
    assert sim.state.delta_commanded == 0.25
    assert sim.state.override_accepted_mono_ns == sim.mono_ns


def test_restarted_gateway_with_seq_from_zero_is_accepted(trajectory: Trajectory) -> None:
    sim = _full_speed(trajectory)
    seq_before = sim.state.override_seq
    assert seq_before > 10
    sim.seq = 0  # the gateway restarted; its stamps are still newer
    sim.cycle(0.5)
    assert sim.state.override_seq == 0
    assert sim.state.delta_commanded == 0.5
    assert not sim.rejected


def test_rejected_overrides_never_raise_speed(trajectory: Trajectory) -> None:
    sim = Sim(trajectory)
    for _ in range(200):
        sim.tick()
        sim.override(1.0, robot="ur10")
        sim.override(1.0, stamp_ns=sim.now_ns - round(1e9))
        sim.override(1.0, stamp_ns=sim.now_ns + round(1e9))
        sim.state = step(sim.state, trajectory, CONFIG, sim.mono_ns, DT_S)
        assert sim.state.delta_applied == 0.0
        assert sim.state.mode == "protective_stop"


def test_seeded_random_commands_keep_delta_bounded(trajectory: Trajectory) -> None:
    rng = np.random.default_rng(7)
    sim = Sim(trajectory)
    previous = 0.0
    for _ in range(3000):
        delta = None if rng.random() < 0.3 else float(rng.choice([0.0, 1.0, rng.random()]))
        state = sim.cycle(delta)
        assert 0.0 <= state.delta_applied <= 1.0
        change = state.delta_applied - previous
        assert -DT_S / CONFIG.braking_time_s - 1e-12 <= change <= DT_S / CONFIG.accel_time_s + 1e-12
        assert 0.0 <= state.tau_s < trajectory.duration_s
        previous = state.delta_applied


# --- the joint state message ---------------------------------------------------------------------


def test_joint_state_message(trajectory: Trajectory) -> None:
    sim = Sim(trajectory)
    first = joint_state(sim.state, trajectory, ROBOT, 0, sim.now_ns)
    assert first.override_seq == -1
    assert first.mode == "protective_stop"
    assert first.qd == [0.0] * 6
    sim.run(0.6, 200)  # into the move
    sim.state = replace(sim.state, tau_s=trajectory.segments[1].t_start_s + 0.3)
    message = joint_state(sim.state, trajectory, ROBOT, 42, sim.now_ns)
    q, qd_nominal = trajectory.sample(sim.state.tau_s)
    assert message.q == q.tolist()
    assert message.qd_nominal == qd_nominal.tolist()
    np.testing.assert_allclose(message.qd, 0.6 * qd_nominal)
    assert np.max(np.abs(message.qd_nominal)) > 0.5
    assert message.override == 0.6
    assert message.override_seq == sim.seq - 1
    assert (message.seq, message.stamp_ns, message.mode) == (42, sim.now_ns, "running")
    assert parse_message(to_payload(message), JointState) == message


def test_braking_time_longer_than_the_gateway_assumes_is_refused(robot: RobotModel) -> None:
    check_braking_time(CONFIG, robot)  # 0.24 s <= 0.244 s of the base link
    with pytest.raises(ConfigError, match=r"braking_time_s = 0.3 s .* link 'base'; allowed: <= 0.244 s"):
        check_braking_time(CONFIG.model_copy(update={"braking_time_s": 0.3}), robot)
