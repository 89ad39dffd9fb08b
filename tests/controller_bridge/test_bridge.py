"""The bridge's pure core with a fake controller: echo, ramps, quantisation, watchdog, q̇, qd_nominal, hostile input."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest

from controller_bridge.bridge import (
    SPEED_INPUTS,
    Bridge,
    BridgeSettings,
    FloatArray,
    quantise,
)
from controller_bridge.vendor import ControllerReading
from hrc_contract.messages import JointState, Override, to_payload
from hrc_runtime.clocks import Clocks

LIMITS = (3.0, 3.0, 3.0)
T_B = 0.2
WALL0 = 1_790_000_000_000_000_000
MONO0 = 1_000_000_000
QD_TOL = (0.01, 0.02)  # the gateway's streams.qd_tolerance_radps, qd_tolerance_ratio (defaults)


def settings(kind: str = "ur_rtde", watchdog_s: float = 0.1) -> BridgeSettings:
    return BridgeSettings(
        robot="ur5",
        speed_input=SPEED_INPUTS[kind],
        velocity_limit_radps=LIMITS,
        braking_time_s=T_B,
        watchdog_s=watchdog_s,
        heartbeat_s=0.008,
    )


def at(t_s: float) -> Clocks:
    return Clocks(WALL0 + round(t_s * 1e9), MONO0 + round(t_s * 1e9))


def override(seq: int, delta: float, t_s: float, robot: str = "ur5") -> bytes:
    return to_payload(Override(robot=robot, seq=seq, stamp_ns=at(t_s).wall_ns, delta=delta))


def reading(
    t_s: float,
    fraction: float,
    *,
    q: tuple[float, ...] = (0.0, 0.0, 0.0),
    qd: tuple[float, ...] | None = (0.0, 0.0, 0.0),
    target_qd: tuple[float, ...] | None = None,
    scaling: float | None = 1.0,
    running: bool = True,
) -> ControllerReading:
    now = at(t_s)
    return ControllerReading(now.wall_ns, now.mono_ns, q, qd, target_qd, fraction, scaling, running, "test")


def write(bridge: Bridge, t_s: float) -> float | None:
    value = bridge.next_write(at(t_s))
    if value is not None:
        bridge.on_written(value, at(t_s))
    return value


def consistent(state: JointState) -> bool:
    """The gateway's qd check (gateway/inputs.py): |qd − override · qd_nominal| ≤ abs + ratio · |qd_nominal|."""
    qd, nominal = np.asarray(state.qd), np.asarray(state.qd_nominal)
    return bool((np.abs(qd - state.override * nominal) <= QD_TOL[0] + QD_TOL[1] * np.abs(nominal)).all())


# -- quantisation -------------------------------------------------------------------------------------


def test_abb_rounds_down_to_whole_percent_and_stops_below_one_percent() -> None:
    abb = SPEED_INPUTS["abb_rws"]
    assert quantise(0.299, abb) == pytest.approx(0.29)
    assert quantise(0.29, abb) == pytest.approx(0.29)  # 0.29 / 0.01 = 28.999…: still 29 %
    assert quantise(0.0099, abb) == 0.0
    assert quantise(1.0, abb) == 1.0


def test_ur_writes_the_slider_as_is_above_its_floor_and_zero_below() -> None:
    ur = SPEED_INPUTS["ur_rtde"]
    assert quantise(0.537, ur) == 0.537
    assert quantise(0.009, ur) == 0.0
    assert quantise(float("nan"), ur) == 0.0
    assert quantise(1.5, ur) == 1.0


def test_quantised_value_is_never_above_delta() -> None:
    rng = random.Random(19)
    for kind, speed_input in SPEED_INPUTS.items():
        for _ in range(5000):
            delta = rng.random()
            value = quantise(delta, speed_input)
            assert value <= delta, (kind, delta, value)
            assert value == 0.0 or value >= speed_input.floor


# -- overrides, writes and the watchdog ---------------------------------------------------------------


def test_an_override_is_written_at_once_then_as_a_heartbeat() -> None:
    bridge = Bridge(settings("abb_rws"))
    assert bridge.on_override(override(1, 0.567, 0.0), at(0.001)) is None
    assert write(bridge, 0.002) == pytest.approx(0.56)
    assert write(bridge, 0.004) is None  # written, heartbeat not due
    assert write(bridge, 0.011) == pytest.approx(0.56)


def test_the_bridge_writes_zero_itself_when_overrides_stop() -> None:
    bridge = Bridge(settings(watchdog_s=0.1))
    bridge.on_override(override(1, 0.8, 0.0), at(0.0))
    assert write(bridge, 0.05) == 0.8
    assert write(bridge, 0.099) == 0.8  # the heartbeat
    assert not bridge.stats().watchdog_expired
    assert write(bridge, 0.101) == 0.0
    assert bridge.stats().watchdog_expired


def test_before_any_override_the_bridge_writes_zero() -> None:
    assert write(Bridge(settings()), 0.0) == 0.0


@pytest.mark.parametrize(
    ("payload", "now_s", "reason"),
    [
        (override(1, 0.5, 0.0, robot="ur10"), 0.0, "wrong_robot"),
        (override(1, 0.5, 0.0), 0.2, "stale"),
        (override(1, 0.5, 0.1), 0.0, "stamp_in_future"),
        (b"{", 0.0, "not_json"),
    ],
)
def test_invalid_overrides_are_refused_and_counted(payload: bytes, now_s: float, reason: str) -> None:
    bridge = Bridge(settings())
    assert bridge.on_override(payload, at(now_s)) == reason
    assert bridge.stats().overrides_rejected == {reason: 1}
    assert write(bridge, now_s) == 0.0


def test_an_older_override_never_replaces_a_newer_one() -> None:
    bridge = Bridge(settings())
    bridge.on_override(override(2, 0.1, 0.010), at(0.011))
    assert bridge.on_override(override(1, 0.9, 0.005), at(0.012)) == "old_or_repeated"
    assert write(bridge, 0.013) == 0.1


# -- the echo ---------------------------------------------------------------------------------------------


def _in_force(bridge: Bridge, fraction: float, t_s: float = 0.0) -> None:
    """The controller shows ``fraction`` (the bridge's first reading)."""
    assert bridge.on_reading(reading(t_s, fraction)) is not None


def test_override_seq_is_confirmed_only_by_a_read_back_showing_the_value() -> None:
    bridge = Bridge(settings())
    _in_force(bridge, 1.0)
    bridge.on_override(override(7, 0.4, 0.0), at(0.0))
    assert write(bridge, 0.001) == 0.4
    state = bridge.on_reading(reading(0.002, 1.0))  # written, not yet shown
    assert state is not None
    assert state.override_seq == -1
    state = bridge.on_reading(reading(0.004, 0.4))
    assert state is not None
    assert state.override_seq == 7
    assert bridge.stats().readback_latency_s == pytest.approx(0.003)


def test_a_read_back_before_the_write_confirms_nothing() -> None:
    bridge = Bridge(settings())
    _in_force(bridge, 1.0)
    bridge.on_override(override(3, 0.4, 0.0), at(0.0))
    state = bridge.on_reading(reading(0.001, 0.4))  # the controller shows 0.4, but the bridge wrote nothing yet
    assert state is not None
    assert state.override_seq == -1
    assert write(bridge, 0.002) == pytest.approx(0.4 - 1e-4)  # 0.4 is in force: a value that proves the write
    state = bridge.on_reading(reading(0.003, 0.4))
    assert state is not None
    assert state.override_seq == -1
    state = bridge.on_reading(reading(0.004, 0.4 - 1e-4))
    assert state is not None
    assert state.override_seq == 3


def test_a_decrease_is_written_at_once_and_supersedes_the_write_awaited_before_it() -> None:
    bridge = Bridge(settings())
    _in_force(bridge, 1.0)
    bridge.on_override(override(1, 0.5, 0.001), at(0.001))
    assert write(bridge, 0.001) == 0.5
    bridge.on_override(override(2, 0.3, 0.002), at(0.002))
    assert write(bridge, 0.002) == 0.3  # lower than 0.5, whose read-back is awaited: at once
    assert bridge.stats().awaiting == 2
    state = bridge.on_reading(reading(0.003, 0.5))
    assert state is not None
    assert state.override_seq == 1
    state = bridge.on_reading(reading(0.004, 0.3))
    assert state is not None
    assert state.override_seq == 2
    assert bridge.stats().awaiting == 0
    state = bridge.on_reading(reading(0.005, 0.5))  # a stale value showing again confirms nothing
    assert state is not None
    assert state.override_seq == 2


def test_a_raise_waits_for_the_read_back_while_the_heartbeat_repeats_the_last_value() -> None:
    bridge = Bridge(settings())  # heartbeat 8 ms
    _in_force(bridge, 1.0)
    bridge.on_override(override(1, 0.3, 0.001), at(0.001))
    assert write(bridge, 0.001) == 0.3
    bridge.on_override(override(2, 0.6, 0.002), at(0.002))
    assert write(bridge, 0.002) is None  # 0.3 not yet read back, heartbeat not due
    assert write(bridge, 0.009) == 0.3  # the heartbeat: the last value again, not a new write
    assert bridge.stats().awaiting == 1
    state = bridge.on_reading(reading(0.010, 0.3))
    assert state is not None
    assert state.override_seq == 1
    assert bridge.stats().readback_latency_s == pytest.approx(0.009)  # from the first write of 0.3
    assert write(bridge, 0.011) == 0.6
    state = bridge.on_reading(reading(0.012, 0.6))
    assert state is not None
    assert state.override_seq == 2


def test_a_steady_delta_alternates_between_its_value_and_one_dither_step_below() -> None:
    bridge = Bridge(settings("abb_rws"))
    _in_force(bridge, 1.0)
    written = []
    for k in range(6):
        t = 0.001 + 0.004 * k
        bridge.on_override(override(k, 0.567, t), at(t))
        value = write(bridge, t + 0.001)
        assert value is not None
        written.append(round(value, 6))
        state = bridge.on_reading(reading(t + 0.002, value))
        assert state is not None
        assert state.override_seq == k
    assert written == [0.56, 0.55, 0.56, 0.55, 0.56, 0.55]
    assert bridge.stats().dithered == 3


# -- every write provable: a fake controller behind a slow link ---------------------------------------------------


TICK_S = 0.001
DITHER = {"ur_rtde": 1e-4, "abb_rws": 0.01}
"""Each vendor's dither step d (``SpeedInput.dither_step``) [1]."""


class _Link:
    """A fake controller behind a vendor link with a one-way delay (deterministic, on integer ticks of 1 ms).

    Writes reach the controller ``link_ticks`` after they were made and take effect in order; every ``period_ticks``
    the controller samples its speed input and the reading reaches the bridge ``link_ticks`` later. The controller
    remembers, for the value in force, when the write that *changed* it to that value was made (the truth an echo
    claims).
    """

    def __init__(self, bridge: Bridge, link_ticks: int, period_ticks: int, heartbeat_ticks: int) -> None:
        self.bridge = bridge
        self.link_ticks, self.period_ticks, self.heartbeat_ticks = link_ticks, period_ticks, heartbeat_ticks
        self.value, self.set_by_write_at = 1.0, -1.0
        self.to_controller: list[tuple[int, float, float]] = []  # (arrival tick, value, written at [s])
        self.to_bridge: list[tuple[int, float, float]] = []  # (arrival tick, value shown, set by the write at [s])
        self.accepted_s: dict[int, float] = {}
        self.newest: tuple[float, float] | None = None  # (δ, accepted at [s]) of the newest override
        self.writes: list[tuple[float, float, float]] = []  # (t [s], value written, allowed: δ or 0 [s])
        self.echoes: list[tuple[int, float, float, float, float]] = []
        """(seq, confirmed at, accepted at, set by the write at [s], the value the confirming reading showed)."""
        self.seq = 0
        self.in_force: list[float] = []  # the controller's value at each tick

    def send(self, k: int, delta: float) -> None:
        t = k * TICK_S
        assert self.bridge.on_override(override(self.seq, delta, t), at(t)) is None
        self.accepted_s[self.seq] = t
        self.newest = (delta, t)
        self.seq += 1

    def step(self, k: int, wake: bool) -> None:
        """One tick: the writer (on a wake or its heartbeat), the controller, the readings."""
        t = k * TICK_S
        if wake or k % self.heartbeat_ticks == 0:
            value = self.bridge.next_write(at(t))
            if value is not None:
                self.bridge.on_written(value, at(t))
                self.to_controller.append((k + self.link_ticks, value, t))
                self.writes.append((t, value, self._allowed(t)))
        while self.to_controller and self.to_controller[0][0] <= k:
            _, value, written_s = self.to_controller.pop(0)
            if value != self.value:
                self.value, self.set_by_write_at = value, written_s
        self.in_force.append(self.value)
        if k % self.period_ticks == 0:
            self.to_bridge.append((k + self.link_ticks, self.value, self.set_by_write_at))
        while self.to_bridge and self.to_bridge[0][0] <= k:
            _, shown, set_at = self.to_bridge.pop(0)
            before = self.bridge.stats().override_seq
            state = self.bridge.on_reading(reading(t, shown))
            if state is not None and state.override_seq != before:
                seq = state.override_seq
                self.echoes.append((seq, t, self.accepted_s[seq], set_at, shown))

    def _allowed(self, t: float) -> float:
        if self.newest is None or at(t).mono_ns - at(self.newest[1]).mono_ns > self.bridge.settings.watchdog_s * 1e9:
            return 0.0
        return self.newest[0]

    def run(self, deltas: list[float | None], every_ticks: int = 4) -> None:
        """One override every ``every_ticks`` with ``deltas[i]`` (None: the gateway is silent then)."""
        for k in range(len(deltas) * every_ticks):
            delta = deltas[k // every_ticks] if k % every_ticks == 0 else None
            if delta is not None:
                self.send(k, delta)
            self.step(k, wake=delta is not None)


def _slow_link(kind: str, link_s: float) -> _Link:
    period = 2 if kind == "ur_rtde" else 20  # RTDE's 500 Hz, ABB polled at 50 Hz
    heartbeat = 8 if kind == "ur_rtde" else 40
    bridge_settings = BridgeSettings(
        robot="ur5",
        speed_input=SPEED_INPUTS[kind],
        velocity_limit_radps=LIMITS,
        braking_time_s=T_B,
        watchdog_s=0.1,
        heartbeat_s=heartbeat * TICK_S,
    )
    return _Link(Bridge(bridge_settings), round(link_s / TICK_S), period, heartbeat)


@pytest.mark.parametrize("kind", ["ur_rtde", "abb_rws"])
def test_with_a_steady_delta_every_echo_proves_the_slow_link(kind: str) -> None:
    """0.3 s each way: every override is confirmed by a reading of a value written after it was accepted, so the
    echo's latency (what the gateway measures) carries both ways of the link. The old rule confirmed a steady δ by
    the next reading: 2 ms (RTDE) or 20 ms (RWS) after it arrived."""
    link_s = 0.3
    sim = _slow_link(kind, link_s)
    sim.run([0.55] * 1000)  # 4 s at the gateway's 250 Hz
    steady = [e for e in sim.echoes if e[2] > 1.0]
    assert len(steady) >= 3, sim.echoes
    for seq, confirmed_s, accepted_s, set_by_write_at_s, _ in steady:
        assert set_by_write_at_s >= accepted_s, f"seq {seq} confirmed by a value in force before it arrived"
        assert confirmed_s - accepted_s >= 2 * link_s - 1e-9, (seq, confirmed_s - accepted_s)
    latency = sim.bridge.stats().readback_latency_s
    assert latency is not None
    assert latency >= 2 * link_s - 1e-9


@pytest.mark.parametrize("kind", ["ur_rtde", "abb_rws"])
def test_a_write_is_never_above_delta_and_every_echo_is_proven_above_the_floor(kind: str) -> None:
    """Seeded random δ sequences (steps, ramps, zeros, the floor, silences) over random links."""
    rng = random.Random(1919 + len(kind))
    floor = SPEED_INPUTS[kind].floor
    for _ in range(12):
        sim = _slow_link(kind, rng.choice([0.0, 0.003, 0.02, 0.1]))
        deltas: list[float | None] = []
        while len(deltas) < 400:
            choice = rng.random()
            held = rng.choice([0.0, floor, floor + 0.004, 1.0, rng.random(), rng.random()])
            if choice < 0.1:
                deltas += [None] * rng.randint(1, 40)  # the gateway silent (the watchdog at 25 overrides)
            elif choice < 0.3:  # a ramp
                deltas += [min(1.0, max(0.0, held + 0.002 * i * rng.choice([-1, 1]))) for i in range(40)]
            else:
                deltas += [held] * rng.randint(1, 60)
        sim.run(deltas)
        assert sim.writes
        for t, value, allowed in sim.writes:
            assert value <= allowed + 1e-12, (t, value, allowed)
        for seq, confirmed_s, accepted_s, set_by_write_at_s, shown in sim.echoes:
            if shown >= floor + DITHER[kind] - 1e-9:  # at the floor: the old rule (proves nothing)
                assert set_by_write_at_s >= accepted_s, (seq, confirmed_s, accepted_s, set_by_write_at_s)


# -- ramps ------------------------------------------------------------------------------------------------


def _ramp_states(readback_lags: bool) -> list[tuple[JointState, float]]:
    """Slider 1 → 0.3 at t = 0; the controller brakes at 1/T_B; programmed velocity p on joint 0.

    ``readback_lags`` False: the read-back shows the commanded 0.3 at once (the applied speed lags it).
    """
    p = np.array([1.0, -0.5, 0.0])
    bridge = Bridge(settings())
    out = []
    applied = 1.0
    for k in range(100):
        t = k * 0.004
        applied = max(0.3, 1.0 - t / T_B)
        shown = applied if readback_lags else 0.3
        qd = tuple(applied * p)
        state = bridge.on_reading(reading(t, shown if k else 1.0, qd=qd, target_qd=qd, q=(0.0, 0.0, 0.0)))
        assert state is not None
        out.append((state, applied))
    return out


@pytest.mark.parametrize("readback_lags", [False, True])
def test_during_a_ramp_the_override_is_never_below_the_applied_one_and_the_state_is_consistent(
    readback_lags: bool,
) -> None:
    for state, applied in _ramp_states(readback_lags):
        assert state.override >= applied - 1e-9
        assert consistent(state)
        assert np.allclose(state.qd_nominal, [1.0, -0.5, 0.0], atol=1e-6)  # the envelope is the robot's ramp here


def test_the_envelope_lets_the_override_fall_no_faster_than_the_braking_time() -> None:
    bridge = Bridge(settings())
    bridge.on_reading(reading(0.0, 1.0, target_qd=(0.0, 0.0, 0.0)))
    state = bridge.on_reading(reading(0.04, 0.0, target_qd=(0.0, 0.0, 0.0)))
    assert state is not None
    assert state.override == pytest.approx(1.0 - 0.04 / T_B)


# -- q differentiation -------------------------------------------------------------------------------------


def test_without_velocities_q_is_differentiated_over_the_sample_times() -> None:
    bridge = Bridge(settings("abb_rws"))
    assert bridge.on_reading(reading(0.0, 0.5, q=(0.0, 0.0, 0.0), qd=None, scaling=None)) is None
    state = bridge.on_reading(reading(0.02, 0.5, q=(0.01, -0.004, 0.0), qd=None, scaling=None))
    assert state is not None
    assert state.qd == pytest.approx([0.5, -0.2, 0.0])
    assert state.qd_nominal == pytest.approx([1.0, -0.4, 0.0])  # qd / ratio: ABB offers no target velocity
    assert consistent(state)


def test_q_is_not_differentiated_over_a_gap() -> None:
    bridge = Bridge(settings("abb_rws"))
    bridge.on_reading(reading(0.0, 0.5, qd=None, scaling=None))
    assert bridge.on_reading(reading(0.5, 0.5, q=(0.3, 0.0, 0.0), qd=None, scaling=None)) is None


# -- qd_nominal sources ------------------------------------------------------------------------------------


def test_target_qd_over_the_applied_scaling_while_it_is_not_near_zero() -> None:
    bridge = Bridge(settings())
    state = bridge.on_reading(reading(0.0, 0.5, qd=(0.2, 0.0, 0.0), target_qd=(0.2, 0.0, 0.0), scaling=0.8))
    assert state is not None
    assert state.qd_nominal == pytest.approx([0.5, 0.0, 0.0])
    assert state.override == pytest.approx(0.4)
    assert bridge.stats().qd_nominal_sources == {"target_qd": 1}


def test_near_zero_scaling_reports_the_velocity_limits_with_the_sign_of_the_motion_never_zero() -> None:
    bridge = Bridge(settings())
    state = bridge.on_reading(reading(0.0, 0.01, qd=(0.001, -0.002, 0.0), target_qd=(0.001, -0.002, 0.0)))
    assert state is not None
    assert state.qd_nominal == pytest.approx([3.0, -3.0, 3.0])
    assert consistent(state)
    assert bridge.stats().qd_nominal_sources == {"velocity_limits": 1}


def test_the_program_model_comes_first_and_gives_the_velocity_at_delta_zero() -> None:
    programmed = np.array([0.8, 0.0, -0.4])

    def locate(q: FloatArray, qd: FloatArray) -> FloatArray | None:
        return programmed if q[0] < 1.0 else None

    bridge = Bridge(settings(), locate=locate)
    state = bridge.on_reading(reading(0.0, 0.0, qd=(0.0, 0.0, 0.0), target_qd=(0.0, 0.0, 0.0)))
    assert state is not None
    assert state.qd_nominal == pytest.approx(programmed.tolist())
    assert consistent(state)
    state = bridge.on_reading(reading(0.004, 0.5, q=(1.5, 0.0, 0.0), qd=(0.4, 0, 0), target_qd=(0.4, 0, 0)))
    assert state is not None
    assert state.qd_nominal == pytest.approx([0.8, 0.0, 0.0])  # off the model: target_qd
    assert bridge.stats().qd_nominal_sources == {"program_model": 1, "model_miss": 1, "target_qd": 1}


def test_with_the_program_model_the_override_is_the_ratio_measured_along_it() -> None:
    programmed = np.array([1.0, -0.5, 0.0])
    bridge = Bridge(settings(), locate=lambda q, qd: programmed)
    bridge.on_reading(reading(0.0, 1.0, qd=tuple(programmed)))
    # the read-back runs ahead: shows 0.3, the robot still moves at 0.9 (braking slower than shown, faster than t_b)
    state = bridge.on_reading(reading(0.004, 0.3, qd=tuple(0.9 * programmed)))
    assert state is not None
    assert state.override == pytest.approx(0.9)
    assert consistent(state)


def test_a_stopped_program_reports_override_zero_and_protective_stop() -> None:
    bridge = Bridge(settings())
    state = bridge.on_reading(reading(0.0, 1.0, target_qd=(0.0, 0.0, 0.0), running=False))
    assert state is not None
    assert state.override == 0.0
    assert state.mode == "protective_stop"
    assert all(v != 0.0 for v in state.qd_nominal)


# -- hostile readings --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("bad", "reason"),
    [
        (reading(0.01, 0.5, q=(0.0, 0.0)), "wrong_joint_count"),
        (reading(0.01, 0.5, q=(math.nan, 0.0, 0.0)), "non_finite"),
        (reading(0.01, 0.5, qd=(0.0, math.inf, 0.0)), "non_finite"),
        (reading(0.01, 1.2), "out_of_range"),
        (reading(0.01, 0.5, scaling=-0.1), "out_of_range"),
        (reading(-0.01, 0.5), "time_backwards"),
    ],
)
def test_hostile_readings_are_refused_and_counted(bad: ControllerReading, reason: str) -> None:
    bridge = Bridge(settings())
    assert bridge.on_reading(reading(0.0, 0.5)) is not None
    assert bridge.on_reading(bad) is None
    assert bridge.stats().rejected == {reason: 1}
    assert bridge.stats().published == 1


def test_interface_errors_are_counted_by_reason() -> None:
    bridge = Bridge(settings())
    bridge.count_rejected("timeout")
    bridge.count_rejected("timeout")
    bridge.count_rejected("malformed")
    assert bridge.stats().rejected == {"malformed": 1, "timeout": 2}


@pytest.mark.parametrize(
    ("kind", "delta"), [("abb_rws", 0.015), ("ur_rtde", 0.01005), ("ur_rtde", 0.0), ("abb_rws", 0.0)]
)
def test_at_the_floor_and_at_zero_the_bridge_writes_delta_and_still_confirms(kind: str, delta: float) -> None:
    """No lower value to dither to (below the floor is the vendor's stop): the write repeats the value in force and
    the next reading confirms it (the old rule; the robot crawls or stands, the next raise is measured)."""
    sim = _slow_link(kind, 0.02)
    sim.run([delta] * 250)
    expected = quantise(delta, SPEED_INPUTS[kind])
    assert {round(value, 9) for _, value, _ in sim.writes} == {round(expected, 9)}
    assert sim.echoes, "overrides at the floor are still confirmed"
    assert sim.echoes[-1][0] >= 240
    assert sim.bridge.stats().unprovable > 0


@pytest.mark.parametrize("kind", ["ur_rtde", "abb_rws"])
def test_the_dither_costs_about_half_a_step_of_speed(kind: str) -> None:
    """Stop-and-wait over a fast link (1 ms each way): with a steady δ the controller alternates between quantise(δ)
    and one dither step below; the mean reduction (time-weighted, against quantise(δ)) stays within 0.7 d."""
    rng = random.Random(7)
    reductions = []
    for _ in range(5):
        delta = rng.uniform(0.1, 1.0)
        sim = _slow_link(kind, 0.001)
        sim.run([delta] * 500)
        settled = sim.in_force[200:]
        reductions.append(quantise(delta, SPEED_INPUTS[kind]) - sum(settled) / len(settled))
    assert all(-1e-12 <= r <= 0.7 * DITHER[kind] for r in reductions), reductions
