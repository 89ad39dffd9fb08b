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


def test_override_seq_is_confirmed_only_by_a_read_back_showing_the_value() -> None:
    bridge = Bridge(settings())
    bridge.on_override(override(7, 0.4, 0.0), at(0.0))
    write(bridge, 0.001)
    state = bridge.on_reading(reading(0.002, 1.0))  # written, not yet shown
    assert state is not None
    assert state.override_seq == -1
    state = bridge.on_reading(reading(0.004, 0.4))
    assert state is not None
    assert state.override_seq == 7
    assert bridge.stats().readback_latency_s == pytest.approx(0.003)


def test_a_read_back_before_the_write_confirms_nothing() -> None:
    bridge = Bridge(settings())
    bridge.on_override(override(3, 0.4, 0.0), at(0.0))
    state = bridge.on_reading(reading(0.001, 0.4))  # the controller shows 0.4, but the bridge wrote nothing yet
    assert state is not None
    assert state.override_seq == -1
    write(bridge, 0.002)
    state = bridge.on_reading(reading(0.003, 0.4))
    assert state is not None
    assert state.override_seq == 3


def test_the_newest_override_the_read_back_shows_is_confirmed_and_older_ones_never_come_back() -> None:
    bridge = Bridge(settings())
    for seq, delta, t in [(1, 0.5, 0.000), (2, 0.3, 0.002), (3, 0.3, 0.004)]:
        bridge.on_override(override(seq, delta, t), at(t))
        write(bridge, t)
    state = bridge.on_reading(reading(0.005, 0.5))
    assert state is not None
    assert state.override_seq == 1
    state = bridge.on_reading(reading(0.006, 0.3))
    assert state is not None
    assert state.override_seq == 3
    state = bridge.on_reading(reading(0.007, 0.5))  # a stale value showing again confirms nothing older
    assert state is not None
    assert state.override_seq == 3


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
