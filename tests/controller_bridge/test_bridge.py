"""The bridge's pure core with a fake controller: echo, ramps, quantisation, watchdog, q̇, qd_nominal, hostile input."""

from __future__ import annotations

import heapq
import math
import random
from typing import Any

import numpy as np
import pytest

from controller_bridge.bridge import (
    Bridge,
    BridgeSettings,
    FloatArray,
    quantise,
)
from hrc_contract.config import CellConfig
from hrc_contract.messages import JointState, Override, to_payload
from hrc_devices.controllers.registry import VENDORS
from hrc_devices.controllers.vendor import ControllerReading
from hrc_runtime.clocks import Clocks

LIMITS = (3.0, 3.0, 3.0)
T_B = 0.2
WALL0 = 1_790_000_000_000_000_000
MONO0 = 1_000_000_000
QD_TOL = (0.01, 0.02)  # the gateway's streams.qd_tolerance_radps, qd_tolerance_ratio (defaults)


def settings(
    kind: str = "ur_rtde", watchdog_s: float = 0.1, rise_time_s: float = 1.0, sample_jitter_s: float = 0.0
) -> BridgeSettings:
    return BridgeSettings(
        robot="ur5",
        speed_input=VENDORS[kind].speed_input,
        velocity_limit_radps=LIMITS,
        braking_time_s=T_B,
        watchdog_s=watchdog_s,
        heartbeat_s=0.008,
        rise_time_s=rise_time_s,
        sample_jitter_s=sample_jitter_s,
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
    controller_time_s: float | None = None,
) -> ControllerReading:
    now = at(t_s)
    return ControllerReading(
        now.wall_ns, now.mono_ns, q, qd, target_qd, fraction, scaling, running, "test", controller_time_s
    )


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
    abb = VENDORS["abb_rws"].speed_input
    assert quantise(0.299, abb) == pytest.approx(0.29)
    assert quantise(0.29, abb) == pytest.approx(0.29)  # 0.29 / 0.01 = 28.999…: still 29 %
    assert quantise(0.0099, abb) == 0.0
    assert quantise(1.0, abb) == 1.0


def test_ur_writes_the_slider_as_is_above_its_floor_and_zero_below() -> None:
    ur = VENDORS["ur_rtde"].speed_input
    assert quantise(0.537, ur) == 0.537
    assert quantise(0.009, ur) == 0.0
    assert quantise(float("nan"), ur) == 0.0
    assert quantise(1.5, ur) == 1.0


def test_quantised_value_is_never_above_delta() -> None:
    rng = random.Random(19)
    for kind, speed_input in ((k, v.speed_input) for k, v in VENDORS.items()):
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
        speed_input=VENDORS[kind].speed_input,
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
    floor = VENDORS[kind].speed_input.floor
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


# -- ramps: qd_nominal never below the programmed velocity ------------------------------------------------------------

P = np.array([1.0, -0.5, 0.0])
"""The programmed velocity of the known-answer ramps [rad/s]."""


def not_below(state: JointState, programmed: FloatArray, tolerance_radps: float = 1e-9) -> bool:
    """|qd_nominal| ≥ |p| − tolerance per joint, with p's sign where p is not within the tolerance of 0."""
    nominal = np.asarray(state.qd_nominal)
    magnitude = np.abs(nominal) >= np.abs(programmed) - tolerance_radps
    sign = (np.abs(programmed) <= tolerance_radps) | (np.sign(nominal) == np.sign(programmed))
    return bool((magnitude & sign).all())


def within_limits(state: JointState) -> bool:
    return bool((np.abs(state.qd_nominal) <= np.asarray(LIMITS) * (1 + 1e-9)).all())


def _brake_states(rise_time_s: float) -> list[tuple[JointState, float]]:
    """UR: slider 1 → 0.3 at t = 0.5 s, the read-back shows 0.3 at once; the controller brakes within T_B (at 2/T_B:
    a braking time is a bound, a controller may stop faster)."""
    bridge = Bridge(settings(rise_time_s=rise_time_s))
    out = []
    for k in range(250):
        t = k * 0.004
        applied = 1.0 if t < 0.5 else max(0.3, 1.0 - (t - 0.5) * 2 / T_B)
        qd = tuple(applied * P)
        state = bridge.on_reading(reading(t, 1.0 if t < 0.5 else 0.3, qd=qd, target_qd=qd, controller_time_s=t))
        assert state is not None
        out.append((state, applied))
    return out


@pytest.mark.parametrize("rise_time_s", [0.0, 1.0])
def test_while_the_robot_brakes_behind_the_read_back_qd_nominal_is_never_below_the_programmed_velocity(
    rise_time_s: float,
) -> None:
    """The old rule's envelope assumed braking at exactly 1/t_b: a controller braking faster had ``target_qd / U``
    below the programmed velocity (and on UR's timing the envelope fell below the applied scaling near the end of
    braking: down to 0.27×)."""
    for state, applied in _brake_states(rise_time_s):
        assert state.override <= applied + 1e-9  # a lower bound of the applied scaling
        assert not_below(state, P), (state, applied)
        assert consistent(state)
        assert within_limits(state)


def test_while_braking_behind_the_read_back_qd_nominal_is_the_velocity_over_the_new_value() -> None:
    states = _brake_states(0.0)
    state, applied = states[125 + 5]  # 20 ms into the braking: the robot still at 0.8
    assert applied == pytest.approx(0.8)
    assert state.override == pytest.approx(0.3)
    assert state.qd_nominal == pytest.approx((0.8 / 0.3 * P).tolist())
    assert states[-1][0].qd_nominal == pytest.approx(P.tolist())  # braked: the programmed velocity again


def test_after_a_raise_the_override_stays_at_the_old_value_for_the_rise_time() -> None:
    """ABB: the speed ratio reads 1.0 at once while the robot accelerates from 0.3 over 0.35 s (the old rule's ABB
    finding: ``qd / ratio`` below the programmed velocity while the robot speeds up)."""
    bridge = Bridge(settings("abb_rws", rise_time_s=0.5))
    q = np.zeros(3)
    for k in range(100):
        t = k * 0.02
        applied = 0.3 if t < 1.0 else min(1.0, 0.3 + (t - 1.0) / 0.5)
        q = q + applied * P * 0.02
        state = bridge.on_reading(reading(t, 0.3 if t < 1.0 else 1.0, q=tuple(q), qd=None, scaling=None))
        if state is None:
            continue
        assert not_below(state, P, 1e-6), (t, state)
        assert consistent(state)
        if 1.0 <= t < 1.5:  # within R of the previous reading's time: the old ratio
            assert state.override == pytest.approx(max(0.3, applied * 1.0 / 3.0))  # |v_0| / limit_0 once above
        if t >= 1.6:
            assert state.override == pytest.approx(1.0)
            assert state.qd_nominal == pytest.approx(P.tolist(), abs=1e-6)


def test_qd_nominal_never_exceeds_the_velocity_limits() -> None:
    """The old rule's UR finding: ``target_qd / U`` with U just above ``min_scaling`` while the robot still moved at
    0.9 of its limits (``qd_above_limit``). Here a_lo ≥ max |v_j| / limit_j."""
    bridge = Bridge(settings(rise_time_s=0.0))
    qd = (2.7, -1.0, 0.0)
    state = bridge.on_reading(reading(0.0, 0.05, qd=qd, target_qd=qd, controller_time_s=0.0))
    assert state is not None
    assert state.override == pytest.approx(0.9)
    assert state.qd_nominal == pytest.approx([3.0, -1.0 / 0.9, 0.0])
    assert consistent(state)


def test_a_decrease_written_and_not_yet_read_back_lowers_the_bound_at_once() -> None:
    """ABB: a lower ratio written after the poll read the ratio and before it read q (the robot already braking)."""
    bridge = Bridge(settings("abb_rws", rise_time_s=0.5))
    bridge.on_override(override(0, 0.8, 0.0), at(0.0))
    write(bridge, 0.0)
    for k in range(31):  # 0.6 s at 0.8: the start's history of 0 has left the window
        bridge.on_reading(reading(k * 0.02, 0.8, qd=None, scaling=None))
    bridge.on_override(override(1, 0.2, 0.61), at(0.61))
    assert bridge.next_write(at(0.61)) == pytest.approx(0.2)  # handed out: on_written has not come back yet
    state = bridge.on_reading(reading(0.62, 0.8, q=(0.01, 0.0, 0.0), qd=None, scaling=None))
    assert state is not None
    assert state.override == pytest.approx(0.2)
    assert state.qd_nominal == pytest.approx([2.5, 0.0, 0.0])
    bridge.on_written(0.2, at(0.63))  # written: awaiting its read-back, still in the bound
    state = bridge.on_reading(reading(0.64, 0.8, q=(0.02, 0.0, 0.0), qd=None, scaling=None))
    assert state is not None
    assert state.override == pytest.approx(0.2)


@pytest.mark.parametrize("cause", ["first_reading", "gap", "clock_back", "clock_leap"])
def test_a_history_the_bridge_cannot_vouch_for_counts_as_zero(cause: str) -> None:
    """Before the first reading, after a gap, when the controller's clock goes back or leaps, the controller may be
    accelerating: a_lo is then only the velocity's share of the limits, for R."""
    bridge = Bridge(settings(rise_time_s=0.5))
    qd = (0.6, 0.0, 0.0)
    t0 = 0.0
    if cause != "first_reading":
        for k in range(200):
            bridge.on_reading(reading(k * 0.004, 1.0, qd=qd, target_qd=qd, controller_time_s=k * 0.004))
        t0 = 1.0 if cause == "gap" else 0.8
    clock = {"first_reading": t0, "gap": t0, "clock_back": 0.004, "clock_leap": 100.0}[cause]
    state = bridge.on_reading(reading(t0, 1.0, qd=qd, target_qd=qd, controller_time_s=clock))
    assert state is not None
    assert state.override == pytest.approx(0.2)  # 0.6 / 3.0
    assert state.qd_nominal == pytest.approx([3.0, 0.0, 0.0])
    for k in range(1, 151):
        later = bridge.on_reading(
            reading(t0 + k * 0.004, 1.0, qd=qd, target_qd=qd, controller_time_s=clock + k * 0.004)
        )
        assert later is not None
        assert later.override == pytest.approx(0.2 if k * 0.004 < 0.5 - 1e-9 else 1.0), k


def test_the_window_runs_on_the_controllers_clock_not_on_arrival_times() -> None:
    """RTDE packages whose ``timestamp`` steps 8 ms while they arrive 4 ms apart: the window follows the controller."""
    bridge = Bridge(settings(rise_time_s=0.5))
    qd = (0.3, 0.0, 0.0)

    def package(k: int, fraction: float) -> JointState | None:
        return bridge.on_reading(reading(k * 0.004, fraction, qd=qd, target_qd=qd, controller_time_s=k * 0.008))

    for k in range(125):  # 1 s of controller time at 1.0 (the start's history of 0 has left the window)
        package(k, 1.0)
    package(125, 0.3)
    for k in range(126, 188):  # 0.5 s of controller time (0.25 s of arrivals) later: 0.3 left the window
        state = package(k, 1.0)
        assert state is not None
        assert state.override == pytest.approx(0.3 if (k - 1) * 0.008 - 1.0 < 0.5 - 1e-9 else 1.0), k


def test_with_a_program_model_the_override_is_at_most_the_braking_envelope() -> None:
    bridge = Bridge(settings(), locate=lambda q, qd: P)
    bridge.on_reading(reading(0.0, 1.0, qd=tuple(P)))
    state = bridge.on_reading(reading(0.04, 0.0, qd=tuple(0.9 * P)))
    assert state is not None
    assert state.override == pytest.approx(1.0 - 0.04 / T_B)
    assert state.qd_nominal == pytest.approx(P.tolist())


# -- the property: a behaving controller read with each vendor's timing --------------------------------------------


class _Program:
    """p(τ) = A sin(ω τ + φ) per joint, q(τ) its integral; |p| ≤ 0.95 · limit."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.amplitude = rng.uniform(0.3, 0.95, 3) * np.asarray(LIMITS)
        self.omega = rng.uniform(0.3, 1.0, 3)
        self.phase = rng.uniform(0.0, 2 * math.pi, 3)

    def qd(self, tau_s: float) -> FloatArray:
        return np.asarray(self.amplitude * np.sin(self.omega * tau_s + self.phase), dtype=float)

    def q(self, tau_s: float) -> FloatArray:
        return np.asarray(-self.amplitude / self.omega * np.cos(self.omega * tau_s + self.phase), dtype=float)

    def max_accel_radps2(self) -> float:
        return float(np.max(self.amplitude * self.omega))


class _Cell:
    """A controller that behaves, behind a bridge driven as its shell drives it, read with one vendor's timing.

    The controller runs 4 ms cycles: its applied scaling a moves toward the input in force, down at 1/braking_s
    (braking_s ≤ T_B) and up at 1/accel_s (accel_s ≤ R); the program time advances by a · dt. UR: an output package
    every 2 ms repeating the latest cycle (``target_qd = actual_qd = a · p``, ``speed_scaling × slider`` = a while a
    rises, else the slider), stamped with the package's controller time and received 0.5–2 ms later; a slider write
    takes effect 0.5 ms after it is made. ABB: a poll every 18–26 ms (it waits for writes) reads the ratio, then
    8 ms later q of the latest cycle (no velocities), and the reading arrives 2 ms after that; a POST takes effect
    2 ms after it is handed out and its answer comes 2 ms later (a poll may land in between). Overrides at 250 Hz,
    random δ held 40–600 ms.
    """

    CYCLE_US = 4000

    def __init__(self, kind: str, seed: int, rise_time_s: float) -> None:
        rng = np.random.default_rng(seed)
        self.kind, self.rng = kind, rng
        jitter_s = self.CYCLE_US / 1e6 if kind == "abb_rws" else 0.0  # q of the latest cycle, received 2 ms later
        self.bridge = Bridge(settings(kind, rise_time_s=rise_time_s, sample_jitter_s=jitter_s))
        self.program = _Program(rng)
        self.braking_s = float(rng.uniform(0.05, T_B))
        self.accel_s = float(rng.uniform(0.05, max(rise_time_s, 0.05)))
        self.input, self.a, self.tau = 1.0 if kind == "abb_rws" else 0.0, 0.0, float(rng.uniform(0, 10))
        self.cycle: tuple[float, float, float] = (self.a, self.tau, self.input)  # a, τ, input of the latest cycle
        self.checked: list[tuple[JointState, FloatArray]] = []
        self._events: list[tuple[int, int, str, Any]] = []
        self._order = 0
        self._busy = False  # ABB: a POST awaits its answer

    def run(self, duration_s: float) -> list[tuple[JointState, FloatArray]]:
        """Every joint state and the true programmed velocity at the cycle it shows."""
        rng, us, push = self.rng, 1_000_000, self._push
        push(0, "cycle")
        push(1000, "override")
        push(1500, "heartbeat")
        push(int(rng.integers(0, 2000)) if self.kind == "ur_rtde" else int(rng.integers(0, 20000)), "read")
        delta, hold_until_us, seq = 0.0, 0, 0
        while self._events[0][0] < duration_s * us:
            t_us, _, kind, data = heapq.heappop(self._events)
            t_s = t_us / us
            if kind == "cycle":
                self._cycle()
                push(t_us + self.CYCLE_US, "cycle")
            elif kind == "override":
                if t_us >= hold_until_us:
                    delta = float(rng.choice([0.0, 0.005, 1.0, rng.uniform(), rng.uniform(), rng.uniform()]))
                    hold_until_us = t_us + int(rng.integers(40_000, 600_000))
                assert self.bridge.on_override(override(seq, delta, t_s), at(t_s)) is None
                seq += 1
                self._write(t_us)
                push(t_us + 4000, "override")
            elif kind == "heartbeat":
                self._write(t_us)
                push(t_us + 8000, "heartbeat")
            elif kind == "apply":
                self.input = data
            elif kind == "written":
                self.bridge.on_written(data, at(t_s))
                self._busy = False
            elif kind == "read":
                self._read(t_us)
                push(t_us + (2000 if self.kind == "ur_rtde" else int(rng.integers(18_000, 26_000))), "read")
            elif kind == "ratio":  # ABB: the ratio is read now, q 8 ms later (two more round trips)
                push(t_us + 8000, "q", self.input)
            elif kind == "q":
                _, tau, _ = self.cycle
                push(t_us + 2000, "reading", (tuple(self.program.q(tau)), data, self.program.qd(tau)))
            elif kind == "reading":
                q, ratio, truth = data
                self._publish(reading(t_s, ratio, q=q, qd=None, scaling=None), truth)
            elif kind == "package":
                values, truth = data
                self._publish(reading(t_s, **values), truth)
        return self.checked

    def _push(self, t_us: int, kind: str, data: Any = None) -> None:
        self._order += 1
        heapq.heappush(self._events, (t_us, self._order, kind, data))

    def _cycle(self) -> None:
        dt = self.CYCLE_US / 1e6
        c = self.input
        self.a = max(c, self.a - dt / self.braking_s) if self.a > c else min(c, self.a + dt / self.accel_s)
        self.tau += self.a * dt
        self.cycle = (self.a, self.tau, c)

    def _write(self, t_us: int) -> None:
        """The shell's writer: UR's write is a package (written at once); ABB's POST acts 2 ms later, answers at 4."""
        if self._busy:
            return
        value = self.bridge.next_write(at(t_us / 1e6))
        if value is None:
            return
        if self.kind == "ur_rtde":
            self.bridge.on_written(value, at(t_us / 1e6))
            self._push(t_us + 500, "apply", value)
        else:
            self._busy = True
            self._push(t_us + 2000, "apply", value)
            self._push(t_us + 4000, "written", value)

    def _read(self, t_us: int) -> None:
        if self.kind == "abb_rws":
            self._push(t_us + 2000, "ratio")
            return
        a, tau, slider = self.cycle  # the package repeats the latest 4 ms cycle
        combined = a if a < slider else slider
        p = self.program.qd(tau)
        values = {
            "fraction": slider,
            "scaling": 1.0 if slider <= 0.0 else combined / slider,
            "q": tuple(self.program.q(tau)),
            "qd": tuple(a * p),
            "target_qd": tuple(a * p),
            "controller_time_s": t_us / 1e6,
        }
        self._push(t_us + 500 + int(self.rng.integers(0, 1500)), "package", (values, p))

    def _publish(self, state_reading: ControllerReading, truth: FloatArray) -> None:
        state = self.bridge.on_reading(state_reading)
        if state is not None:
            self.checked.append((state, truth))


def _truth_tolerance_radps(cell: _Cell) -> float:
    """UR: none (``target_qd`` and the read-back come from the same cycle). ABB: q is differenced over the poll, so its
    velocity is the mean since the previous q sample while the truth is the last one: the programmed velocity's
    change over half the longest poll interval, 13 ms (|dp/dτ| ≤ max A ω, τ advancing at most at 1); the sampling
    jitter of q (up to one 4 ms cycle) is the bridge's ``sample_jitter_s``, not a tolerance."""
    if cell.kind == "ur_rtde":
        return 1e-9
    return cell.program.max_accel_radps2() * 0.013


@pytest.mark.parametrize(
    ("kind", "rise_time_s"),
    [("ur_rtde", 1.0), ("ur_rtde", 0.5), ("ur_rtde", 0.0), ("abb_rws", 1.0), ("abb_rws", 0.5)],
)  # R = 0 only on UR: ABB's read-back is the input, not the applied scaling (the cell file refuses it)
def test_a_behaving_controller_read_with_its_vendors_timing_is_never_reported_slower_than_its_program(
    kind: str, rise_time_s: float
) -> None:
    """On every joint state: qd_nominal ≥ the true programmed velocity (− the stated tolerance), the gateway's check
    ``|qd − override · qd_nominal| ≤ 0.01 + 0.02 |qd_nominal|`` holds, and |qd_nominal| ≤ the limits."""
    for seed in range(6):
        cell = _Cell(kind, 100 * seed + len(kind), rise_time_s)
        states = cell.run(6.0)
        assert len(states) > (2000 if kind == "ur_rtde" else 250)
        tolerance = _truth_tolerance_radps(cell)
        moving = 0
        for state, truth in states:
            qd = np.asarray(state.qd)
            assert not_below(state, np.where(qd == 0.0, 0.0, truth), tolerance), (seed, state, truth)
            assert np.all(np.abs(state.qd_nominal) >= np.abs(truth) - tolerance), (seed, state, truth)
            assert consistent(state), (seed, state)
            assert within_limits(state), (seed, state)
            moving += bool(np.any(qd != 0.0))
        assert moving > len(states) // 3  # the property was tested on a moving robot


# -- q differentiation -------------------------------------------------------------------------------------


def test_without_velocities_q_is_differentiated_over_the_sample_times() -> None:
    bridge = Bridge(settings("abb_rws", rise_time_s=0.0))  # the window: the previous reading and this one
    assert bridge.on_reading(reading(0.0, 0.5, q=(0.0, 0.0, 0.0), qd=None, scaling=None)) is None
    state = bridge.on_reading(reading(0.02, 0.5, q=(0.01, -0.004, 0.0), qd=None, scaling=None))
    assert state is not None
    assert state.qd == pytest.approx([0.5, -0.2, 0.0])
    assert state.qd_nominal == pytest.approx([1.0, -0.4, 0.0])  # qd / ratio: ABB offers no target velocity
    assert consistent(state)


def test_a_reading_that_waited_in_the_bridge_does_not_make_the_next_velocity_impossible() -> None:
    """Joint 1 at 0.9 × its limit, sampled every 20 ms; the second reading waited 8 ms in the bridge (received at
    28 ms), so the third, received on time at 40 ms, is 12 ms after it: q's difference over those 12 ms is 1.5 × the
    limit (the gateway's ``qd_above_limit``: a false stop). The bridge differences over the reading before (40 ms):
    0.9 × the limit, consistent, and its window starts there."""
    speed_radps = 0.9 * LIMITS[0]
    bridge = Bridge(settings("abb_rws", rise_time_s=0.0))
    for received_s, sampled_s in ((0.0, 0.0), (0.028, 0.02)):
        bridge.on_reading(reading(received_s, 1.0, q=(speed_radps * sampled_s, 0.0, 0.0), qd=None, scaling=None))
    state = bridge.on_reading(reading(0.04, 1.0, q=(speed_radps * 0.04, 0.0, 0.0), qd=None, scaling=None))
    assert state is not None
    assert state.qd[0] == pytest.approx(speed_radps)  # not 1.5 × the limit
    assert abs(state.qd[0]) <= LIMITS[0]
    assert consistent(state)
    assert within_limits(state)


def test_a_joint_really_beyond_its_limit_is_reported_as_it_is() -> None:
    """Over every earlier reading q moves at 1.5 × the limit: no base makes it possible, and the bridge reports the
    newest interval's velocity (the gateway refuses it) rather than hide it."""
    speed_radps = 1.5 * LIMITS[0]
    bridge = Bridge(settings("abb_rws", rise_time_s=0.0))
    states = [
        bridge.on_reading(reading(t_s, 1.0, q=(speed_radps * t_s, 0.0, 0.0), qd=None, scaling=None))
        for t_s in (0.0, 0.02, 0.04, 0.06)
    ]
    assert states[0] is None
    assert all(s is not None and s.qd[0] == pytest.approx(speed_radps) for s in states[1:])


def test_q_is_not_differentiated_over_a_gap() -> None:
    bridge = Bridge(settings("abb_rws"))
    bridge.on_reading(reading(0.0, 0.5, qd=None, scaling=None))
    assert bridge.on_reading(reading(0.5, 0.5, q=(0.3, 0.0, 0.0), qd=None, scaling=None)) is None


# -- qd_nominal sources ------------------------------------------------------------------------------------


def test_target_qd_over_the_applied_scaling_while_it_is_not_near_zero() -> None:
    bridge = Bridge(settings(rise_time_s=0.0))  # the window: this reading alone
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

    bridge = Bridge(settings(rise_time_s=0.0), locate=locate)
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
    expected = quantise(delta, VENDORS[kind].speed_input)
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
        reductions.append(quantise(delta, VENDORS[kind].speed_input) - sum(settled) / len(settled))
    assert all(-1e-12 <= r <= 0.7 * DITHER[kind] for r in reductions), reductions


# -- the cell file's rise time ---------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("interface", "rise_time_s", "accepted"),
    [
        ({"kind": "abb_rws", "url": "http://127.0.0.3:8081", "password_env": "X"}, 0.5, True),
        ({"kind": "abb_rws", "url": "http://127.0.0.3:8081", "password_env": "X"}, 0.4, False),
        ({"kind": "abb_rws", "url": "http://127.0.0.3:8081", "password_env": "X"}, 0.0, False),
        ({"kind": "ur_rtde", "host": "127.0.0.2"}, 0.0, True),
        ({"kind": "ur_rtde", "host": "127.0.0.2"}, 0.3, False),
    ],
)
def test_the_cell_file_refuses_a_rise_time_shorter_than_the_controllers_ramp(
    cell_config: CellConfig, interface: dict[str, object], rise_time_s: float, accepted: bool
) -> None:
    raw = cell_config.model_dump()
    raw["robots"]["ur5"]["controller"]["accel_time_s"] = 0.5
    raw["robots"]["ur5"]["interface"] = interface | {"rise_time_s": rise_time_s}
    if accepted:
        config = CellConfig.model_validate(raw)
        assert config.robots["ur5"].interface.rise_time_s == rise_time_s  # type: ignore[union-attr]
    else:
        with pytest.raises(ValueError, match=r"rise_time_s = .* shorter than controller.accel_time_s"):
            CellConfig.model_validate(raw)
    raw["robots"]["ur5"]["interface"] = interface
    assert CellConfig.model_validate(raw).robots["ur5"].interface.rise_time_s == 1.0  # type: ignore[union-attr]


def test_the_cell_file_refuses_a_sampling_jitter_below_the_controllers_cycle(cell_config: CellConfig) -> None:
    raw = cell_config.model_dump()
    raw["robots"]["ur5"]["controller"]["cycle_s"] = 0.004
    abb = {"kind": "abb_rws", "url": "http://127.0.0.3:8081", "password_env": "X"}
    raw["robots"]["ur5"]["interface"] = abb | {"sample_jitter_s": 0.002}
    with pytest.raises(ValueError, match=r"sample_jitter_s = 0.002 s is shorter than controller.cycle_s"):
        CellConfig.model_validate(raw)
    raw["robots"]["ur5"]["interface"] = abb
    assert CellConfig.model_validate(raw).robots["ur5"].interface.sample_jitter_s == 0.004  # type: ignore[union-attr]


def test_a_differenced_velocity_is_bounded_with_the_sampling_jitter() -> None:
    """Receipts 20 ms apart, samples maybe 16 ms apart: v = Δq / 16 ms, qd = Δq / 20 ms, override · qd_nominal = qd."""
    bridge = Bridge(settings("abb_rws", rise_time_s=0.0, sample_jitter_s=0.004))
    bridge.on_reading(reading(0.0, 0.5, q=(0.0, 0.0, 0.0), qd=None, scaling=None))
    state = bridge.on_reading(reading(0.02, 0.5, q=(0.01, -0.004, 0.0), qd=None, scaling=None))
    assert state is not None
    assert state.qd == pytest.approx([0.5, -0.2, 0.0])
    assert state.qd_nominal == pytest.approx([1.25, -0.5, 0.0])  # Δq / 16 ms / 0.5
    assert state.override == pytest.approx(0.4)  # 0.5 · 16 / 20
    assert consistent(state)


def test_a_late_reading_keeps_the_time_it_was_taken_and_no_stamp_is_younger_than_its_arrival() -> None:
    from controller_bridge.bridge import StampClock

    ms = 1_000_000
    clock = StampClock()
    assert clock.stamp_ns(100 * ms, 10.000) == 100 * ms  # the first: its arrival
    assert clock.stamp_ns(102_300_000, 10.002) == 102 * ms  # 0.3 ms slower than the first: the first's offset
    # taken 2 ms later, received 9 ms late (the bridge was descheduled): the time it was taken, not near its arrival
    late = clock.stamp_ns(113 * ms, 10.004)
    assert late == 104 * ms
    # the next ones, taken 2 ms apart, arrived bunched right after: 2 ms apart, as taken (the gateway's q_jump)
    after = clock.stamp_ns(113_200_000, 10.006)
    assert after - late == 2 * ms
    assert clock.stamp_ns(113_400_000, 10.008) - after == 2 * ms
    # one that arrives faster than every earlier one: its arrival (never younger than it is), later than the last
    fast = clock.stamp_ns(109_900_000, 10.010)
    assert fast == 109_900_000
    # without the controller's time, after a gap, or when it goes back (a restarted controller): the arrival
    assert clock.stamp_ns(120 * ms, None) == 120 * ms
    assert clock.stamp_ns(125 * ms, 10.012) == 125 * ms
    assert clock.stamp_ns(126 * ms, 11.5) == 126 * ms
    assert clock.stamp_ns(127 * ms, 0.002) == 127 * ms


def test_a_controller_clock_that_nearly_stops_lags_the_stamps_at_most_the_window() -> None:
    """A hostile or broken controller whose time advances 1 µs per 2 ms package: stamps at most the window before
    their arrival (the gateway then finds the joint state stale), never after it."""
    from controller_bridge.bridge import STAMP_WINDOW_S, StampClock

    clock = StampClock()
    window_ns = round(STAMP_WINDOW_S * 1e9)
    for k in range(2000):  # 4 s of arrivals, 2 ms of controller time
        received_ns = 1_000_000_000 + k * 2_000_000
        stamp = clock.stamp_ns(received_ns, 5.0 + k * 1e-6)
        assert received_ns - window_ns <= stamp <= received_ns
    assert received_ns - stamp >= window_ns - 2_000_000  # it does lag: the clock tells nothing


def test_stamps_follow_a_slow_controller_clock_within_the_window_and_never_go_back() -> None:
    """A controller clock 1e-3 slower than the bridge's: stamps lag the arrivals by at most 1e-3 × the window."""
    from controller_bridge.bridge import STAMP_WINDOW_S, StampClock

    clock = StampClock()
    rng = np.random.default_rng(1)
    previous = None
    worst_lag_ns = 0
    for k in range(5000):  # 10 s at 500 Hz
        controller_s = 3.0 + k * 0.002
        taken_ns = 1_000_000_000 + round(k * 0.002 * 1.001 * 1e9)  # the bridge's clock runs 1e-3 faster
        received_ns = taken_ns + 50_000 + int(rng.exponential(300_000))  # 50 µs and a queue
        stamp = clock.stamp_ns(received_ns, controller_s)
        assert stamp <= received_ns
        assert previous is None or stamp > previous
        previous = stamp
        worst_lag_ns = max(worst_lag_ns, taken_ns + 50_000 - stamp)
    assert worst_lag_ns <= 1e-3 * STAMP_WINDOW_S * 1e9 + 100_000


@pytest.mark.parametrize("delta", [0.0, 0.01005])
def test_a_reading_taken_before_an_unprovable_write_does_not_confirm_it(delta: float) -> None:
    """At 0 and at the floor a write repeats the value in force. A reading taken before it (its controller time) but
    received after it shows that value too: it must not confirm the override, or the echo is stamped before the
    gateway sent it (the gateway's ``echo_before_send``, seen under load); the next reading taken after it does."""
    bridge = Bridge(settings())
    controller_s = 100.0  # the controller's clock at t = 0
    for k in range(3):  # the value in force: delta, read back on time (the stamp clock learns the offset)
        bridge.on_override(override(k, delta, 0.004 * k), at(0.004 * k))
        write(bridge, 0.004 * k + 0.0005)
        bridge.on_reading(reading(0.004 * k + 0.002, delta, controller_time_s=controller_s + 0.004 * k + 0.002))
    first_seq = bridge.on_reading(reading(0.0105, delta, controller_time_s=controller_s + 0.0105))
    assert first_seq is not None
    in_force_seq = first_seq.override_seq
    assert bridge.on_override(override(7, delta, 0.020), at(0.020)) is None
    assert write(bridge, 0.021) is not None  # the same value again: unprovable
    taken_before = bridge.on_reading(reading(0.030, delta, controller_time_s=controller_s + 0.015))
    assert taken_before is not None
    assert taken_before.stamp_ns < at(0.021).wall_ns
    assert taken_before.override_seq == in_force_seq, "a reading older than the write confirmed it"
    taken_after = bridge.on_reading(reading(0.032, delta, controller_time_s=controller_s + 0.031))
    assert taken_after is not None
    assert taken_after.override_seq == 7
    assert taken_after.stamp_ns >= at(0.020).wall_ns
