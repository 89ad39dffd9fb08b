"""The open controller's pure follower: command checks, the law, its velocity, acceleration and position limits,
silence and resumption (controller_emu/open_follower.py), on the Panda of the two-arm cell."""

from __future__ import annotations

import itertools
import math
from collections import Counter
from dataclasses import replace

import numpy as np
import numpy.typing as npt
import pytest
from support.paths import DEFAULT_CELL_PATH

from controller_emu.open_follower import (
    POSITION_GAIN_PER_S,
    FollowerLimits,
    FollowerState,
    apply_command,
    check_command,
    follower_joint_state,
    follower_limits,
    following,
    initial_state,
    step_follower,
)
from hrc_contract.config import ConfigError
from hrc_contract.messages import JointCommand, JointState, MessageError, parse_message, to_payload
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_devices.robots.program import load_trajectory
from hrc_devices.robots.time_scaling import MAX_FUTURE_STAMP_S
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config

ROBOT = "panda"
WATCHDOG_S = 0.1
DT_S = 0.004
DT_NS = 4_000_000
T0_NS = 1_790_000_000_000_000_000
EPS = 1e-9

FloatArray = npt.NDArray[np.float64]


@pytest.fixture(scope="module")
def panda() -> RobotModel:
    config = load_cell_config(DEFAULT_CELL_PATH.parent / "cell_two_arms.toml")
    return load_robot_model(ROBOT, config.robots[ROBOT])


@pytest.fixture(scope="module")
def limits(panda: RobotModel) -> FollowerLimits:
    return follower_limits(panda, WATCHDOG_S)


@pytest.fixture(scope="module")
def q0(panda: RobotModel) -> FloatArray:
    """The first waypoint of the Panda's program: where the open controller starts."""
    config = load_cell_config(DEFAULT_CELL_PATH.parent / "cell_two_arms.toml")
    q, _ = load_trajectory(config.robots[ROBOT].program, panda).sample(0.0)
    return np.asarray(q, dtype=float)


class Sim:
    """Drives the pure functions on simulated clocks: a command per cycle (or none), then a step.

    ``mono_ns`` is the controller's monotonic clock, ``now_ns`` the wall clock (of the controller and of the
    gateway's stamps, here the same).
    """

    def __init__(self, limits: FollowerLimits, q0: FloatArray) -> None:
        self.limits = limits
        self.state = initial_state(q0)
        self.mono_ns = 0
        self.now_ns = T0_NS
        self.seq = 0
        self.rejected: Counter[str] = Counter()
        self.history: list[FollowerState] = [self.state]

    def command(
        self, q: FloatArray, qd: FloatArray, *, robot: str = ROBOT, stamp_ns: int | None = None, seq: int | None = None
    ) -> str | None:
        message = JointCommand(
            robot=robot,
            seq=self.seq if seq is None else seq,
            stamp_ns=self.now_ns if stamp_ns is None else stamp_ns,
            q=[float(v) for v in q],
            qd=[float(v) for v in qd],
            delta=1.0,
        )
        self.seq += 1
        reason = check_command(
            message, ROBOT, self.limits.n_joints, self.state.command_stamp_ns, self.now_ns, self.limits.watchdog_s
        )
        if reason is None:
            self.state = apply_command(self.state, message, Clocks(self.now_ns, self.mono_ns), self.limits)
        else:
            self.rejected[reason] += 1
        return reason

    def step(self, dt_s: float = DT_S) -> FollowerState:
        dt_ns = round(dt_s * 1e9)
        self.mono_ns += dt_ns
        self.now_ns += dt_ns
        self.state = step_follower(self.state, self.limits, dt_s, self.mono_ns)
        self.history.append(self.state)
        return self.state

    def follow(self, reference: list[tuple[FloatArray, FloatArray]]) -> list[FollowerState]:
        """One command per cycle, each the reference for the end of that cycle."""
        out = []
        for q, qd in reference:
            assert self.command(q, qd) is None
            out.append(self.step())
        return out

    def silent(self, cycles: int) -> list[FollowerState]:
        return [self.step() for _ in range(cycles)]


def _assert_within_limits(
    states: list[FollowerState], limits: FollowerLimits, dts_s: list[float] | None = None
) -> None:
    """Velocity, acceleration and position limits at every step, and q moving as the trapezoid of q̇."""
    for i, (before, after) in enumerate(itertools.pairwise(states)):
        dt_s = DT_S if dts_s is None else dts_s[i]
        assert np.all(np.abs(after.qd_radps) <= limits.velocity_limit_radps + EPS), f"step {i}: above v_max"
        assert np.all(np.abs(after.qd_radps - before.qd_radps) <= limits.accel_limit_radps2 * dt_s + EPS), (
            f"step {i}: above the acceleration bound"
        )
        assert np.all(after.q_rad >= limits.q_min_rad - EPS), f"step {i}: below the position limits"
        assert np.all(after.q_rad <= limits.q_max_rad + EPS), f"step {i}: above the position limits"
        np.testing.assert_allclose(
            after.q_rad - before.q_rad, 0.5 * (before.qd_radps + after.qd_radps) * dt_s, atol=1e-12
        )


def _ramp(
    q0: FloatArray, joint: int, speed_radps: float, cycles: int, start: int = 1
) -> list[tuple[FloatArray, FloatArray]]:
    """q_{k+1} of a joint moving at ``speed_radps`` from q0 (a velocity step at the start), the others standing."""
    out = []
    for k in range(start, start + cycles):
        q, qd = q0.copy(), np.zeros_like(q0)
        q[joint] += speed_radps * k * DT_S
        qd[joint] = speed_radps
        out.append((q, qd))
    return out


# --- limits ------------------------------------------------------------------------------------------------


def test_limits_of_the_panda_are_the_urdfs_and_its_braking_times(panda: RobotModel, limits: FollowerLimits) -> None:
    np.testing.assert_array_equal(limits.velocity_limit_radps, panda.velocity_limit_radps)
    np.testing.assert_allclose(limits.accel_limit_radps2, panda.velocity_limit_radps / panda.braking_time_s)
    assert limits.accel_limit_radps2[0] == pytest.approx(2.175 / 0.5)
    np.testing.assert_array_equal(limits.q_min_rad, panda.model.lowerPositionLimit)
    np.testing.assert_array_equal(limits.q_max_rad, panda.model.upperPositionLimit)
    assert (limits.gain_per_s, limits.watchdog_s, limits.n_joints) == (POSITION_GAIN_PER_S, WATCHDOG_S, 9)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"accel_limit_radps2": np.zeros(9)}, "accel_limit_radps2"),
        ({"velocity_limit_radps": np.full(9, np.inf)}, "velocity_limit_radps"),
        ({"q_min_rad": np.full(9, 5.0)}, "q_min <= q_max"),
        ({"q_max_rad": np.ones(3)}, "one value per joint"),
        ({"gain_per_s": 0.0}, "gain_per_s"),
        ({"watchdog_s": math.nan}, "watchdog_s"),
    ],
)
def test_limits_refuse_bad_values_saying_what_is_allowed(limits: FollowerLimits, change: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        replace(limits, **change)


def test_a_joint_without_a_velocity_limit_is_refused_by_name(panda: RobotModel) -> None:
    v = panda.velocity_limit_radps.copy()
    v[3] = 0.0
    with pytest.raises(ConfigError, match=r"panda_joint4.*v_max > 0"):
        follower_limits(replace(panda, velocity_limit_radps=v), WATCHDOG_S)


# --- acceptance -------------------------------------------------------------------------------------------


def test_commands_are_refused_with_their_reason(limits: FollowerLimits, q0: FloatArray) -> None:
    sim = Sim(limits, q0)
    zero = np.zeros(9)
    assert sim.command(q0, zero, robot="ur5") == "wrong_robot"
    assert sim.command(q0[:7], zero[:7]) == "wrong_joint_count"
    assert sim.command(q0, zero, stamp_ns=sim.now_ns - round((WATCHDOG_S + 0.001) * 1e9)) == "stale"
    assert sim.command(q0, zero, stamp_ns=sim.now_ns + round((MAX_FUTURE_STAMP_S + 0.001) * 1e9)) == "stamp_in_future"
    assert sim.state.command_seq == -1, "nothing accepted"
    assert not following(sim.state, sim.mono_ns)
    assert sim.command(q0, zero, seq=50) is None
    assert sim.command(q0, zero, seq=51) == "old_or_repeated", "the same stamp again"
    assert sim.command(q0, zero, stamp_ns=sim.now_ns - 1_000_000, seq=52) == "old_or_repeated", "stamped before"
    sim.step()
    assert sim.command(q0, zero, seq=0) is None, "order by stamp, not seq: a restarted gateway"
    assert sim.state.command_seq == 0
    assert dict(sim.rejected) == {
        "wrong_robot": 1,
        "wrong_joint_count": 1,
        "stale": 1,
        "stamp_in_future": 1,
        "old_or_repeated": 2,
    }


def test_a_command_is_followed_until_it_is_watchdog_old_counting_its_age_at_arrival(
    limits: FollowerLimits, q0: FloatArray
) -> None:
    sim = Sim(limits, q0)
    assert sim.command(q0, np.zeros(9), stamp_ns=sim.now_ns - 90_000_000) is None  # 90 ms old on arrival
    assert sim.step().mode == "running"  # 94 ms
    assert sim.step().mode == "running"  # 98 ms
    assert sim.step().mode == "protective_stop", "102 ms old: no longer followed"


def test_non_finite_values_never_reach_the_follower() -> None:
    payload = to_payload(JointCommand(robot=ROBOT, seq=0, stamp_ns=T0_NS, q=[0.0] * 9, qd=[0.0] * 9, delta=1.0))
    with pytest.raises(MessageError) as caught:
        parse_message(payload.replace(b'"qd":[0.0', b'"qd":[NaN'), JointCommand)
    assert caught.value.reason == "non_finite"


# --- following --------------------------------------------------------------------------------------------


def test_starts_standing_in_a_protective_stop(limits: FollowerLimits, q0: FloatArray) -> None:
    sim = Sim(limits, q0)
    states = sim.silent(20)
    assert all(s.mode == "protective_stop" for s in states)
    np.testing.assert_array_equal(sim.state.q_rad, q0)
    np.testing.assert_array_equal(sim.state.qd_radps, np.zeros(9))


def test_follows_a_smooth_reference_exactly(limits: FollowerLimits, q0: FloatArray) -> None:
    """A reference that accelerates within the bound (2 rad/s² to 1 rad/s on joint 1) is followed with no error:
    the law compares q_{k+1} with where the robot will be, so following exactly leaves nothing to correct."""
    accel, speed = 2.0, 1.0
    sim = Sim(limits, q0)
    reference = []
    for k in range(1, 301):
        t = k * DT_S
        t_acc = speed / accel
        q, qd = q0.copy(), np.zeros(9)
        q[0] += 0.5 * accel * t * t if t <= t_acc else 0.5 * accel * t_acc**2 + speed * (t - t_acc)
        qd[0] = min(accel * t, speed)
        reference.append((q, qd))
    states = sim.follow(reference)
    _assert_within_limits(sim.history, limits)
    errors = [np.max(np.abs(s.q_rad - q)) for s, (q, _) in zip(states, reference, strict=True)]
    assert max(errors) < 5e-4  # the discrete accel-phase rounding only: a trapezoid of a ramp is exact
    assert errors[-1] < 1e-9
    assert sim.state.qd_radps[0] == pytest.approx(speed)


def test_follows_a_ramp_of_references_within_limits(limits: FollowerLimits, q0: FloatArray) -> None:
    """A velocity step of 1.5 rad/s on joint 1 (the references jump into motion): the robot accelerates at its
    bound, falls behind (0.26 rad), catches up through the correction term, overshoots a little (the P-law with a
    saturated acceleration, as EGM's) and then follows the ramp."""
    sim = Sim(limits, q0)
    reference = _ramp(q0, 0, 1.5, 300)
    states = sim.follow(reference)
    _assert_within_limits(sim.history, limits)
    assert states[0].qd_radps[0] == pytest.approx(limits.accel_limit_radps2[0] * DT_S), "at its bound, not at once"
    lag = [q[0] - s.q_rad[0] for s, (q, _) in zip(states, reference, strict=True)]
    assert max(lag) == pytest.approx(0.5 * 1.5**2 / limits.accel_limit_radps2[0], rel=0.05), "lagged by the accel phase"
    assert -0.03 < min(lag) < 0.0, "a small overshoot"
    assert abs(lag[-1]) < 5e-4, "caught up within 1.2 s"
    assert sim.state.qd_radps[0] == pytest.approx(1.5, abs=0.01)
    np.testing.assert_allclose(sim.state.q_rad[1:], q0[1:], atol=1e-12)
    assert all(s.mode == "running" for s in states)


def test_a_reference_above_the_velocity_limit_is_followed_at_the_limit(limits: FollowerLimits, q0: FloatArray) -> None:
    sim = Sim(limits, q0)
    sim.follow(_ramp(q0, 4, 5.0, 150))  # joint 5 of the Panda runs at 2.61 rad/s at most
    _assert_within_limits(sim.history, limits)
    assert sim.state.qd_radps[4] == pytest.approx(limits.velocity_limit_radps[4])


def test_the_position_limits_are_never_crossed(limits: FollowerLimits, q0: FloatArray) -> None:
    """A reference running through joint 4's upper limit (-0.0698 rad) at 2 rad/s: the robot brakes at its bound
    and stops on the limit."""
    sim = Sim(limits, q0)
    sim.follow(_ramp(q0, 3, 2.0, 500))
    _assert_within_limits(sim.history, limits)
    assert sim.state.q_rad[3] == pytest.approx(limits.q_max_rad[3], abs=1e-6)
    assert sim.state.qd_radps[3] == 0.0, "at rest on the limit, not chattering about it"


def test_the_bounds_hold_at_every_step_for_random_references_and_jittered_cycles(
    limits: FollowerLimits, q0: FloatArray
) -> None:
    """Seeded: references anywhere in (and beyond) the limits, velocities up to 3 v_max, cycles of 1-12 ms, some
    without a command, some stale silences."""
    rng = np.random.default_rng(34)
    for _case in range(20):
        sim = Sim(limits, q0)
        dts = []
        for _ in range(300):
            if rng.random() < 0.8:
                span = limits.q_max_rad - limits.q_min_rad
                q = limits.q_min_rad + rng.uniform(-0.1, 1.1, 9) * span
                qd = rng.uniform(-3.0, 3.0, 9) * limits.velocity_limit_radps
                sim.command(q, qd)
            dt = float(rng.uniform(0.001, 0.012))
            dts.append(round(dt * 1e9) / 1e9)
            sim.step(dts[-1])
        _assert_within_limits(sim.history, limits, dts)


def test_a_long_late_cycle_does_not_over_correct(limits: FollowerLimits, q0: FloatArray) -> None:
    """K is capped at 1/Δt: a 90 ms cycle (K Δt would be 1.8) ends between where q̇_ref alone takes the robot and
    the reference, not beyond it."""
    sim = Sim(limits, q0)
    sim.follow(_ramp(q0, 0, 0.5, 200))
    dt_s = 0.09
    qd = np.zeros(9)
    qd[0] = 0.5
    ahead = sim.state.q_rad + qd * dt_s
    sim.command(ahead + 0.01 * (np.arange(9) == 0), qd)
    sim.step(dt_s)
    assert sim.state.mode == "running"
    assert ahead[0] < sim.state.q_rad[0] <= ahead[0] + 0.01


# --- silence and resumption -------------------------------------------------------------------------------


def _at_full_speed(limits: FollowerLimits, q0: FloatArray, joint: int = 0) -> Sim:
    """Joint ``joint`` running at its velocity limit, far from its position limits."""
    start = q0.copy()
    start[joint] = limits.q_min_rad[joint] + 0.05
    sim = Sim(limits, start)
    sim.follow(_ramp(start, joint, float(limits.velocity_limit_radps[joint]), 160))
    assert sim.state.qd_radps[joint] == pytest.approx(limits.velocity_limit_radps[joint])
    return sim


def test_silence_keeps_the_last_velocity_for_the_watchdog_time_then_stops_within_braking_time(
    limits: FollowerLimits, q0: FloatArray, panda: RobotModel
) -> None:
    sim = _at_full_speed(limits, q0)
    v_max, a = limits.velocity_limit_radps[0], limits.accel_limit_radps2[0]
    last_command_mono_ns = sim.mono_ns - DT_NS
    states = sim.silent(round((WATCHDOG_S + panda.braking_time_s[0]) / DT_S) + 5)
    running = [s for s in states if s.mode == "running"]
    assert all(s.qd_radps[0] == pytest.approx(v_max) for s in running), "the last velocity, extrapolated"
    assert len(running) * DT_S == pytest.approx(WATCHDOG_S - DT_S, abs=DT_S)
    stopping = states[len(running) :]
    assert all(s.mode == "protective_stop" for s in stopping)
    speeds = [s.qd_radps[0] for s in stopping]
    np.testing.assert_allclose(np.diff([v_max, *speeds])[: int(v_max / (a * DT_S))], -a * DT_S, rtol=1e-9)
    stopped_at = next(i for i, v in enumerate(speeds) if v == 0.0) + 1
    assert stopped_at * DT_S <= panda.braking_time_s[0] + DT_S, "from v_max to 0 within t_b"
    stopped_mono_ns = sim.mono_ns - (len(stopping) - stopped_at) * DT_NS
    assert (stopped_mono_ns - last_command_mono_ns) / 1e9 <= WATCHDOG_S + panda.braking_time_s[0] + DT_S
    _assert_within_limits(sim.history, limits)
    assert np.all(sim.state.qd_radps == 0.0)


def test_holding_the_reference_converges_on_the_last_one_then_stops_at_the_watchdog(
    limits: FollowerLimits, q0: FloatArray
) -> None:
    """EGM's position mode (the EGM face): silence keeps the last reference without its feed-forward; the robot
    converges on it and stands there, reporting ``running`` until the watchdog, then ``protective_stop``."""
    hold = replace(limits, on_silence="hold_reference")
    sim = Sim(hold, q0)
    reference = _ramp(q0, 0, 0.2, 100)
    sim.follow(reference)
    last_q_ref = reference[-1][0]
    assert sim.state.qd_radps[0] == pytest.approx(0.2, abs=1e-3), "followed with its feed-forward"
    states = sim.silent(round(WATCHDOG_S / DT_S) + 40)
    running = [s for s in states if s.mode == "running"]
    assert len(running) * DT_S == pytest.approx(WATCHDOG_S - DT_S, abs=DT_S)
    assert np.max(np.abs(running[-1].q_rad - last_q_ref)) < 2e-3, "converged on the last reference"
    assert np.all(np.abs(running[-1].qd_radps) < 0.05)
    assert all(s.mode == "protective_stop" for s in states[len(running) :])
    assert np.all(sim.state.qd_radps == 0.0)
    assert np.max(np.abs(sim.state.q_rad - last_q_ref)) < 2e-3, "and stands there"
    _assert_within_limits(sim.history, hold)


def test_holding_the_reference_between_commands_drops_only_that_cycles_feed_forward(
    limits: FollowerLimits, q0: FloatArray
) -> None:
    """One cycle without a command (a late packet) slows the joint by at most a·Δt; the next command restores it."""
    hold = replace(limits, on_silence="hold_reference")
    sim = Sim(hold, q0)
    reference = _ramp(q0, 0, 0.2, 120)
    sim.follow(reference[:100])
    sim.silent(1)
    assert 0.2 - sim.state.qd_radps[0] <= hold.accel_limit_radps2[0] * DT_S + EPS
    sim.follow(reference[101:])
    assert sim.state.qd_radps[0] == pytest.approx(0.2, abs=0.02)
    _assert_within_limits(sim.history, hold)


def _profile(
    q_start: FloatArray, qd_start: float, joint: int, accel_radps2: float, speed_radps: float, cycles: int
) -> list[tuple[FloatArray, FloatArray]]:
    """References q_{k+1}, q̇_{k+1} from a state (``q_start``, ``qd_start`` on ``joint``) whose velocity moves to
    ``speed_radps`` at ``accel_radps2``: what a gateway resuming from the robot's own state would send."""
    out, q, qd = [], q_start.copy(), qd_start
    for _ in range(cycles):
        qd_next = qd + float(np.clip(speed_radps - qd, -accel_radps2 * DT_S, accel_radps2 * DT_S))
        q = q.copy()
        q[joint] += 0.5 * (qd + qd_next) * DT_S
        qd = qd_next
        qd_ref = np.zeros_like(q)
        qd_ref[joint] = qd
        out.append((q, qd_ref))
    return out


def _no_jump(sim: Sim, at: int, limits: FollowerLimits) -> None:
    before, after = sim.history[at], sim.history[at + 1]
    assert np.all(np.abs(after.qd_radps - before.qd_radps) <= limits.accel_limit_radps2 * DT_S + EPS)
    np.testing.assert_allclose(after.q_rad - before.q_rad, 0.5 * (before.qd_radps + after.qd_radps) * DT_S, atol=1e-12)


def test_resumes_from_standstill_where_the_robot_stopped(limits: FollowerLimits, q0: FloatArray) -> None:
    sim = _at_full_speed(limits, q0)
    sim.silent(round((WATCHDOG_S + 0.5) / DT_S) + 10)
    assert sim.state.mode == "protective_stop"
    assert np.all(sim.state.qd_radps == 0.0)
    here = sim.state.q_rad.copy()
    at = len(sim.history) - 1
    states = sim.follow(_profile(here, 0.0, 0, 2.0, -0.3, 200))  # back the way it came, at 0.3 rad/s
    _no_jump(sim, at, limits)
    _assert_within_limits(sim.history, limits)
    assert states[0].mode == "running"
    assert sim.state.qd_radps[0] == pytest.approx(-0.3, abs=1e-6)
    assert abs(sim.state.q_rad[0] - _profile(here, 0.0, 0, 2.0, -0.3, 200)[-1][0][0]) < 1e-3


def test_resumes_while_braking_from_the_robots_own_motion(limits: FollowerLimits, q0: FloatArray) -> None:
    sim = _at_full_speed(limits, q0)
    sim.silent(round(WATCHDOG_S / DT_S) + 15)  # braking: the protective stop has begun
    assert sim.state.mode == "protective_stop"
    assert sim.state.qd_radps[0] > 1.0
    at = len(sim.history) - 1
    reference = _profile(sim.state.q_rad, float(sim.state.qd_radps[0]), 0, 3.0, 0.3, 200)
    states = sim.follow(reference)
    _no_jump(sim, at, limits)
    _assert_within_limits(sim.history, limits)
    assert states[0].mode == "running"
    errors = [abs(s.q_rad[0] - q[0]) for s, (q, _) in zip(states, reference, strict=True)]
    assert max(errors) < 1e-3, "the reference starts where the robot is: nothing to catch up"
    assert sim.state.qd_radps[0] == pytest.approx(0.3, abs=1e-4)


def test_a_zero_step_moves_nothing(limits: FollowerLimits, q0: FloatArray) -> None:
    sim = _at_full_speed(limits, q0)
    before = sim.state
    after = step_follower(before, limits, 0.0, sim.mono_ns)
    np.testing.assert_array_equal(after.q_rad, before.q_rad)
    np.testing.assert_array_equal(after.qd_radps, before.qd_radps)
    assert step_follower(before, limits, -0.01, sim.mono_ns).q_rad is before.q_rad


# --- the joint state --------------------------------------------------------------------------------------


def test_the_joint_state_reports_the_motion_it_has(limits: FollowerLimits, q0: FloatArray) -> None:
    sim = Sim(limits, q0)
    idle = follower_joint_state(sim.state, ROBOT, 0, T0_NS)
    assert (idle.override, idle.override_seq, idle.mode, idle.qd_nominal) == (1.0, -1, "protective_stop", [0.0] * 9)
    sim.follow(_ramp(q0, 1, 0.4, 10))
    running = follower_joint_state(sim.state, ROBOT, 7, sim.now_ns)
    assert isinstance(running, JointState)
    assert (running.override, running.override_seq, running.mode) == (1.0, sim.seq - 1, "running")
    assert running.qd_nominal == running.qd == sim.state.qd_radps.tolist()  # no override: it has what it reports
    assert 0.0 < running.qd[1] <= 0.4  # accelerating toward the ramp's 0.4 rad/s
    assert running.q == sim.state.q_rad.tolist()
    sim.silent(round(WATCHDOG_S / DT_S) + 1)
    stopping = follower_joint_state(sim.state, ROBOT, 8, sim.now_ns)
    assert (stopping.override, stopping.mode) == (1.0, "protective_stop")
    assert stopping.qd_nominal == stopping.qd  # decelerating, as reported
    assert stopping.override_seq == sim.seq - 1, "the last accepted seq stays"
