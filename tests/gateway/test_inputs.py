"""InputStore: the door of the gateway. Newest valid sample per topic; every bad, implausible, out-of-order or
inconsistent message counted by reason and faulting its topic (held); never raising."""

from __future__ import annotations

import json
from collections.abc import Callable

import numpy as np
import pytest

from gateway import joint_motion
from gateway.inputs import (
    FRAME_BURST,
    FRAME_RATE_FACTOR,
    JUMP_MARGIN_RAD,
    VELOCITY_LIMIT_FACTOR,
    FrameBudget,
    InputStore,
    age_s,
    fault_code,
)
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.humans import capsules_from_message, human_starts, packed_payload
from hrc_contract.messages import Humans, parse_message
from hrc_devices.robots.model import RobotModel
from hrc_runtime.clocks import Clocks

CELL = "demo"
NOW = 1_790_000_000_000_000_000
MONO0 = 5_000_000_000  # the monotonic clock at NOW
MS = 1_000_000
FUTURE_NS = 5 * MS  # streams.max_future_stamp_s of the default cell
HOLD_NS = 500 * MS  # streams.fault_hold_s of the default cell
JOINT_KEY = keys.robot_state(CELL, "ur5")
FRONT_KEY = keys.tracker_humans(CELL, "front")
# A capsule kilometres long whose axis passes a hand's width from a UR5 tool: finite, schema-valid, absurd.
KM_CAPSULE = {"name": "forearm_r", "a": [-3000.0, 0.45, 1.2], "b": [3000.0, 0.45, 1.2], "radius": 0.05}


def at(t_ns: int = NOW, wall_step_ns: int = 0) -> Clocks:
    """The gateway's clocks at wall time ``t_ns`` (monotonic in step), its wall clock stepped by ``wall_step_ns``."""
    return Clocks(t_ns + wall_step_ns, MONO0 + t_ns - NOW)


def js(seq=1, stamp_ns=NOW - 4 * MS, **changes) -> dict:
    raw = {
        "schema": "hrc.joint_state/1",
        "robot": "ur5",
        "seq": seq,
        "stamp_ns": stamp_ns,
        "q": [0.0, -1.2, 1.5, 0.1, 0.2, 0.3],
        "qd": [0.0] * 6,
        "qd_nominal": [0.5] * 6,
        "override": 0.0,
        "override_seq": -1,
        "mode": "running",
    }
    raw.update(changes)
    return raw


def hm(seq=1, stamp_ns=NOW - 30 * MS, tracker="front", **changes) -> dict:
    raw = {
        "schema": "hrc.humans/1",
        "tracker": tracker,
        "seq": seq,
        "stamp_ns": stamp_ns,
        "humans": [
            {
                "id": "h1",
                "capsules": [
                    {"name": "torso", "a": [2.0, 0.0, 0.9], "b": [2.0, 0.0, 1.5], "radius": 0.15},
                    {"name": "hand_r", "a": [1.6, 0.2, 1.1], "b": [1.6, 0.2, 1.1], "radius": 0.05},
                ],
            }
        ],
    }
    raw.update(changes)
    return raw


def enc(raw: dict) -> bytes:
    return json.dumps(raw).encode()


@pytest.fixture
def store(cell_config: CellConfig, ur5: RobotModel) -> InputStore:
    return InputStore(cell_config, {"ur5": ur5})


def rejected(store: InputStore, topic: str) -> dict[str, int]:
    return store.counters()[0].get(topic, {})


def stored_seq(store: InputStore, t_ns: int = NOW) -> int | None:
    """The seq of the joint state the store keeps for the UR5, None without one."""
    sample = store.snapshot(at(t_ns)).joint["ur5"]
    return None if sample is None else sample.seq


def fault_codes(store: InputStore, t_ns: int = NOW) -> dict[str, str]:
    return {topic: f.code for topic, f in store.snapshot(at(t_ns)).faults.items()}


def test_default_cell_limits_are_the_ones_these_tests_assume(cell_config: CellConfig) -> None:
    assert round(cell_config.streams.max_future_stamp_s * 1e9) == FUTURE_NS
    assert round(cell_config.streams.fault_hold_s * 1e9) == HOLD_NS


# -- valid data -----------------------------------------------------------------------------------


def test_valid_joint_state_is_stored(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=7)), at())
    snap = store.snapshot(at())
    sample = snap.joint["ur5"]
    assert sample is not None
    assert sample.seq == 7
    assert sample.stamp_ns == NOW - 4 * MS
    np.testing.assert_allclose(sample.q_rad, [0.0, -1.2, 1.5, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(sample.qd_nominal_radps, [0.5] * 6)  # the programmed speed, not qd
    assert sample.mode == "running"
    assert snap.faults == {}
    assert store.counters() == ({}, {"robot/ur5": 1})


def test_valid_humans_are_flattened_with_tracker_prefixed_ids(store: InputStore) -> None:
    store.on_humans(FRONT_KEY, enc(hm()), at())
    frame = store.snapshot(at()).humans["front"]
    assert frame is not None
    assert frame.human_count == 1
    caps = frame.capsules
    assert caps.human_ids == ("front/h1", "front/h1")
    assert caps.capsule_names == ("torso", "hand_r")
    np.testing.assert_allclose(caps.h_a_world, [[2.0, 0.0, 0.9], [1.6, 0.2, 1.1]])
    np.testing.assert_allclose(caps.h_b_world, [[2.0, 0.0, 1.5], [1.6, 0.2, 1.1]])
    np.testing.assert_allclose(caps.radius_m, [0.15, 0.05])
    assert store.snapshot(at()).humans["side"] is None


def test_empty_humans_list_is_data(store: InputStore) -> None:
    store.on_humans(FRONT_KEY, enc(hm(humans=[])), at())
    frame = store.snapshot(at()).humans["front"]
    assert frame is not None
    assert frame.human_count == 0
    assert frame.capsules.n_capsules == 0
    assert frame.capsules.h_a_world.shape == (0, 3)


# -- every bad payload, counted by reason ---------------------------------------------------------


def _replace(raw: dict, old: bytes, new: bytes) -> bytes:
    payload = enc(raw)
    assert old in payload
    return payload.replace(old, new)


JOINT_BAD: list[tuple[str, bytes, str]] = [
    ("not_json", b"{this is not json", "not_json"),
    ("binary", b"\x00\xff\xfe garbage", "not_json"),
    ("json_array", b"[1, 2, 3]", "not_json"),
    ("nan_literal", _replace(js(), b'"override": 0.0', b'"override": NaN'), "non_finite"),
    ("infinity_literal", _replace(js(), b"[0.5, 0.5", b"[Infinity, 0.5"), "non_finite"),
    ("wrong_schema", enc(js(schema="hrc.joint_state/0")), "wrong_schema"),
    ("unknown_field", enc(js(temperature=40.0)), "invalid"),
    ("wrong_lengths", enc(js(qd=[0.0] * 5)), "invalid"),
    ("override_percent", enc(js(override=62.0)), "invalid"),
    ("wrong_joint_count", enc(js(q=[0.0] * 5, qd=[0.0] * 5, qd_nominal=[0.0] * 5)), "wrong_joint_count"),
    ("name_mismatch", enc(js(robot="ur10")), "name_mismatch"),
    ("too_large", b'{"schema": "hrc.joint_state/1", "pad": "' + b"x" * 2_000_000 + b'"}', "too_large"),
    ("stamp_in_future", enc(js(seq=2, stamp_ns=NOW + FUTURE_NS + 1)), "stamp_in_future"),
    ("q_out_of_limits", enc(js(seq=2, q=[0.0, -1.2, 1.5, 0.1, 0.2, 1e6])), "q_out_of_limits"),
    ("qd_above_limit", enc(js(seq=2, qd_nominal=[50.0] * 6)), "qd_above_limit"),
    ("qd_inconsistent", enc(js(seq=2, qd=[0.0, 0.0, 0.0, 0.0, 0.0, 0.4], qd_nominal=[0.0] * 6)), "qd_inconsistent"),
    ("qd_against_nominal", enc(js(seq=2, qd=[-0.5] * 6, override=1.0)), "qd_inconsistent"),
    ("q_jump", enc(js(seq=2, stamp_ns=NOW - 3 * MS, q=[0.0, -1.2, 1.5, 0.1, 0.2, 0.5])), "q_jump"),
]

HUMANS_BAD: list[tuple[str, bytes, str]] = [
    ("not_json", b"humans!", "not_json"),
    ("nan_literal", _replace(hm(), b"[2.0, 0.0, 0.9]", b"[NaN, 0.0, 0.9]"), "non_finite"),
    ("wrong_schema", enc(hm(schema="hrc.joint_state/1")), "wrong_schema"),
    ("unknown_field", enc(hm(confidence=0.9)), "invalid"),
    ("wrong_lengths", _replace(hm(), b"[2.0, 0.0, 0.9]", b"[2.0, 0.0]"), "invalid"),
    ("negative_radius", _replace(hm(), b'"radius": 0.05', b'"radius": -0.05'), "invalid"),
    ("name_mismatch", enc(hm(tracker="side")), "name_mismatch"),
    ("too_large", b" " * 2_000_000, "too_large"),
    ("stamp_in_future", enc(hm(stamp_ns=NOW + 1_000 * MS)), "stamp_in_future"),
    ("person_without_capsules", enc(hm(humans=[{"id": "h1", "capsules": []}])), "invalid"),
    ("kilometre_capsule", enc(hm(humans=[{"id": "h1", "capsules": [KM_CAPSULE]}])), "outside_world"),
    ("outside_world", _replace(hm(), b"[2.0, 0.0, 0.9]", b"[2.0, 40.0, 0.9]"), "outside_world"),
    ("capsule_too_long", _replace(hm(), b"[2.0, 0.0, 1.5]", b"[2.0, 0.0, 2.5]"), "capsule_too_long"),
    ("radius_too_large", _replace(hm(), b'"radius": 0.15', b'"radius": 1.5'), "radius_too_large"),
]


@pytest.mark.parametrize(("label", "payload", "reason"), JOINT_BAD, ids=[b[0] for b in JOINT_BAD])
def test_bad_joint_state_counted_and_faulted(store: InputStore, label, payload, reason) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=1)), at())
    store.on_joint_state(JOINT_KEY, payload, at())
    assert rejected(store, "robot/ur5") == {reason: 1}
    snap = store.snapshot(at())
    assert snap.faults["robot/ur5"].reason.startswith(reason)
    assert snap.joint["ur5"] is not None
    assert snap.joint["ur5"].seq == 1  # the bad message did not replace the stored one
    assert store.counters()[1] == {"robot/ur5": 1}


@pytest.mark.parametrize(("label", "payload", "reason"), HUMANS_BAD, ids=[b[0] for b in HUMANS_BAD])
def test_bad_humans_counted_and_faulted(store: InputStore, label, payload, reason) -> None:
    store.on_humans(FRONT_KEY, payload, at())
    assert rejected(store, "tracker/front") == {reason: 1}
    snap = store.snapshot(at())
    assert snap.faults["tracker/front"].reason.startswith(reason)
    assert snap.humans["front"] is None


@pytest.mark.parametrize(
    ("reason", "code"),
    [
        ("not_json", "tracker_invalid"),
        ("outside_world", "tracker_implausible"),
        ("stamp_in_future", "tracker_out_of_order"),
    ],
)
def test_fault_codes_name_the_kind_of_problem(store: InputStore, reason: str, code: str) -> None:
    payload = {
        "not_json": b"{",
        "outside_world": enc(hm(humans=[{"id": "h1", "capsules": [KM_CAPSULE]}])),
        "stamp_in_future": enc(hm(stamp_ns=NOW + 10 * MS)),
    }[reason]
    store.on_humans(FRONT_KEY, payload, at())
    assert fault_codes(store) == {"tracker/front": code}


def test_overflowing_number_is_rejected_and_faulted(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, _replace(js(), b'"override": 0.0', b'"override": 1e999'), at())
    store.on_humans(FRONT_KEY, _replace(hm(), b"[2.0, 0.0, 0.9]", b"[1e999, 0.0, 0.9]"), at())
    snap = store.snapshot(at())
    assert snap.joint["ur5"] is None
    assert snap.humans["front"] is None
    assert set(snap.faults) == {"robot/ur5", "tracker/front"}
    assert rejected(store, "robot/ur5") == {"non_finite": 1}  # json.loads makes 1e999 inf without parse_constant
    assert sum(rejected(store, "tracker/front").values()) == 1


@pytest.mark.parametrize("kind", ["robot", "tracker"])
def test_deeply_nested_payload_is_counted_not_raised(store: InputStore, kind: str) -> None:
    """Regression: from about 1000 levels (2 kB) json.loads raised RecursionError through parse_message."""
    payload = b"[" * 5_000 + b"]" * 5_000  # 10 kB
    if kind == "robot":
        store.on_joint_state(JOINT_KEY, payload, at())
        assert rejected(store, "robot/ur5") == {"not_json": 1}
    else:
        store.on_humans(FRONT_KEY, payload, at())
        assert rejected(store, "tracker/front") == {"not_json": 1}


def test_unknown_robot_and_tracker_counted_but_concern_no_robot(store: InputStore) -> None:
    store.on_joint_state(keys.robot_state(CELL, "ghost"), enc(js(robot="ghost")), at())
    store.on_humans(keys.tracker_humans(CELL, "back"), enc(hm(tracker="back")), at())
    store.on_joint_state("some/other/key", enc(js()), at())
    rejected_all, received = store.counters()
    assert rejected_all["robot/ghost"] == {"unknown_robot": 1}
    assert rejected_all["tracker/back"] == {"unknown_tracker": 1}
    assert rejected_all["robot/?"] == {"unknown_robot": 1}
    assert received == {}
    assert store.snapshot(at()).faults == {}


# -- plausibility ---------------------------------------------------------------------------------


def test_plausible_frames_at_the_limits_pass(store: InputStore, cell_config: CellConfig) -> None:
    p = cell_config.plausibility
    low, high = list(p.world_min_m), list(p.world_max_m)
    corner = {"name": "c", "a": low, "b": low, "radius": p.max_capsule_radius_m}
    leg = {"name": "leg", "a": [0.0, 0.0, 0.1], "b": [0.0, 0.0, 0.1 + p.max_capsule_length_m], "radius": 0.08}
    top = {"name": "t", "a": high, "b": high, "radius": 0.0}
    people = [{"id": "h1", "capsules": [corner]}, {"id": "h2", "capsules": [leg]}, {"id": "h3", "capsules": [top]}]
    store.on_humans(FRONT_KEY, enc(hm(humans=people)), at())
    assert store.snapshot(at()).faults == {}
    assert store.snapshot(at()).humans["front"].capsules.n_capsules == 3


def test_a_person_with_no_capsules_is_not_nobody(store: InputStore) -> None:
    """Issue 9, hole 2: right after a person stood at the tool, a frame listing them with no capsule."""
    store.on_humans(FRONT_KEY, enc(hm(seq=1)), at())
    store.on_humans(FRONT_KEY, enc(hm(seq=2, stamp_ns=NOW - 20 * MS, humans=[{"id": "h1", "capsules": []}])), at())
    snap = store.snapshot(at())
    assert snap.faults["tracker/front"].code == "tracker_invalid"
    assert snap.humans["front"].seq == 1  # the person is still where they were seen


# -- order of the stream --------------------------------------------------------------------------


def test_exact_repeat_is_a_duplicate_not_a_fault(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=10, stamp_ns=NOW - 4 * MS)), at())
    store.on_joint_state(JOINT_KEY, enc(js(seq=10, stamp_ns=NOW - 4 * MS)), at())
    store.on_humans(FRONT_KEY, enc(hm(seq=5)), at())
    store.on_humans(FRONT_KEY, enc(hm(seq=5)), at())
    assert rejected(store, "robot/ur5") == {"duplicate": 1}
    assert rejected(store, "tracker/front") == {"duplicate": 1}
    assert store.snapshot(at()).faults == {}


@pytest.mark.parametrize(
    ("seq", "stamp_ns", "reason", "kept"),
    [
        (9, NOW - 8 * MS, "stamp_backwards", 10),  # older
        (11, NOW - 5 * MS, "stamp_backwards", 10),  # newer seq, older stamp
        (3, NOW - 4 * MS, "stamp_backwards", 10),  # lower seq, same stamp
        (10, NOW - 2 * MS, "seq_backwards", 10),  # same seq, newer stamp
        (0, NOW - 1 * MS, "seq_backwards", 0),  # a restart (or a forged seq): newest kept, still a fault
    ],
)
def test_stamps_or_seqs_going_backwards_fault_the_topic(store: InputStore, seq, stamp_ns, reason, kept) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=10, stamp_ns=NOW - 4 * MS)), at())
    store.on_joint_state(JOINT_KEY, enc(js(seq=seq, stamp_ns=stamp_ns)), at())
    assert rejected(store, "robot/ur5") == {reason: 1}
    snap = store.snapshot(at())
    assert snap.faults["robot/ur5"].code == "joint_state_out_of_order"
    assert snap.joint["ur5"].seq == kept


def test_future_stamp_tolerance_boundary(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW + FUTURE_NS)), at())
    assert store.snapshot(at()).joint["ur5"] is not None
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW + FUTURE_NS + 1)), at())
    assert rejected(store, "robot/ur5") == {"stamp_in_future": 1}


def test_forged_future_frames_interleaved_with_genuine_ones_keep_the_robots_stopped(store: InputStore) -> None:
    """Issue 9, hole 3: "nobody here" stamped a few ms ahead, interleaved with genuine frames of a person."""
    for k in range(60):  # 2 s of a 30 Hz tracker, a forged frame after each genuine one
        t = NOW + k * 33 * MS
        store.on_humans(FRONT_KEY, enc(hm(seq=2 * k + 1, stamp_ns=t - 30 * MS)), at(t))
        store.on_humans(FRONT_KEY, enc(hm(seq=2 * k + 2, stamp_ns=t + 4 * MS, humans=[])), at(t + 1 * MS))
        snap = store.snapshot(at(t + 2 * MS))
        if k >= 1:
            assert snap.faults["tracker/front"].code == "tracker_out_of_order", k
    assert rejected(store, "tracker/front")["stamp_backwards"] >= 58


# -- the hold -------------------------------------------------------------------------------------


def test_a_fault_lasts_until_valid_data_came_and_the_hold_passed(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 8 * MS)), at())
    store.on_joint_state(JOINT_KEY, b"garbage", at())
    assert fault_codes(store) == {"robot/ur5": "joint_state_invalid"}
    # valid data after it, but within the hold: still faulted
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW + 10 * MS)), at(NOW + 14 * MS))
    assert fault_codes(store, NOW + 14 * MS) == {"robot/ur5": "joint_state_invalid"}
    # the hold passed, but no valid data since the fault: still faulted
    store.on_joint_state(JOINT_KEY, enc(js(robot="ur10")), at(NOW + 20 * MS))
    assert fault_codes(store, NOW + 20 * MS + HOLD_NS) == {"robot/ur5": "joint_state_invalid"}
    assert store.snapshot(at(NOW + 20 * MS + HOLD_NS)).faults["robot/ur5"].reason.startswith("name_mismatch")
    # valid data after it, and the hold passed: cleared
    store.on_joint_state(JOINT_KEY, enc(js(seq=3, stamp_ns=NOW + 30 * MS)), at(NOW + 34 * MS))
    assert fault_codes(store, NOW + 20 * MS + HOLD_NS - 1) == {"robot/ur5": "joint_state_invalid"}
    assert fault_codes(store, NOW + 20 * MS + HOLD_NS) == {}
    assert rejected(store, "robot/ur5") == {"not_json": 1, "name_mismatch": 1}
    assert store.counters()[1] == {"robot/ur5": 3}


def test_the_hold_runs_on_the_monotonic_clock(store: InputStore) -> None:
    store.on_humans(FRONT_KEY, b"{", at())
    store.on_humans(FRONT_KEY, enc(hm(seq=1, stamp_ns=NOW - 30 * MS)), at(NOW + 1 * MS))
    # a wall-clock step forward of an hour does not end the hold (and is a fault of its own)
    later = at(NOW + 2 * MS, wall_step_ns=3_600_000 * MS)
    assert set(store.snapshot(later).faults) == {"tracker/front"}


def test_faults_are_per_topic(store: InputStore) -> None:
    store.on_humans(FRONT_KEY, b"{", at())
    store.on_humans(keys.tracker_humans(CELL, "side"), enc(hm(tracker="side")), at())
    store.on_joint_state(JOINT_KEY, enc(js()), at())
    assert fault_codes(store) == {"tracker/front": "tracker_invalid"}


def test_count_rejection_from_outside_faults_the_topic(store: InputStore) -> None:
    store.count_rejection("robot/ur5", "internal_error", at())
    assert fault_codes(store) == {"robot/ur5": "joint_state_invalid"}
    assert rejected(store, "robot/ur5") == {"internal_error": 1}


# -- ages and clocks ------------------------------------------------------------------------------


def test_age_is_transit_at_arrival_plus_monotonic_time_since(store: InputStore) -> None:
    store.on_humans(FRONT_KEY, enc(hm(stamp_ns=NOW - 30 * MS)), at())
    frame = store.snapshot(at()).humans["front"]
    assert age_s(frame, at(NOW + 50 * MS).mono_ns) == pytest.approx(0.080)
    # a wall-clock step backwards on this host does not make the frame younger
    assert age_s(frame, at(NOW + 50 * MS, wall_step_ns=-10_000 * MS).mono_ns) == pytest.approx(0.080)


def test_a_wall_clock_step_on_this_host_is_a_fault_for_the_hold(store: InputStore) -> None:
    assert store.snapshot(at()).clock_fault is None
    assert store.snapshot(at(NOW + 4 * MS)).clock_fault is None
    fault = store.snapshot(at(NOW + 8 * MS, wall_step_ns=-2_000 * MS)).clock_fault
    assert fault is not None
    assert fault.code == "clock_step"
    assert "-2.000 s" in fault.reason
    # the clock stays where it stepped: the fault holds, then clears by itself
    assert store.snapshot(at(NOW + 12 * MS, wall_step_ns=-2_000 * MS)).clock_fault is not None
    assert store.snapshot(at(NOW + 8 * MS + HOLD_NS, wall_step_ns=-2_000 * MS)).clock_fault is None


def test_small_clock_drift_is_not_a_step(store: InputStore, cell_config: CellConfig) -> None:
    step_ns = round(cell_config.streams.max_clock_step_s * 1e9)
    store.snapshot(at())
    assert store.snapshot(at(NOW + 4 * MS, wall_step_ns=step_ns)).clock_fault is None


# -- consistency with what was commanded ----------------------------------------------------------


def test_moving_joints_with_zero_nominal_speed_fault_the_robot(store: InputStore) -> None:
    """Issue 9, hole 5: qd_nominal = 0 while qd moves the robot."""
    moving = js(seq=1, qd=[0.0, 0.0, 0.0, 0.0, 0.0, 1.0], qd_nominal=[0.0] * 6, override=1.0)
    store.on_joint_state(JOINT_KEY, enc(moving), at())
    assert fault_codes(store) == {"robot/ur5": "joint_state_inconsistent"}
    assert store.snapshot(at()).joint["ur5"] is None


def test_qd_at_override_times_nominal_is_consistent(store: InputStore) -> None:
    state = js(seq=1, qd=[0.31, -0.25, 0.0, 0.0, 0.0, 0.0], qd_nominal=[0.5, -0.4, 0.0, 0.0, 0.0, 0.0], override=0.6)
    store.on_joint_state(JOINT_KEY, enc(state), at())
    assert store.snapshot(at()).faults == {}


@pytest.mark.parametrize(
    ("qd", "qd_nominal", "override"),
    [
        ([-0.5] * 6, [0.5] * 6, 1.0),  # honest qd toward the person, qd_nominal claiming away (issue 17)
        ([0.0, 0.0, 0.3, 0.0, 0.0, 0.0], [0.0, 0.0, -0.5, 0.0, 0.0, 0.0], 0.6),  # one joint reversed
        ([0.0] * 6, [0.5] * 6, 1.0),  # still while the program says it moves at full speed
    ],
)
def test_qd_other_than_override_times_nominal_faults_the_robot(
    store: InputStore, qd: list[float], qd_nominal: list[float], override: float
) -> None:
    """Sign included: a magnitude check let a reversed qd_nominal through and δ rose from 0.13 to 1."""
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, qd=qd, qd_nominal=qd_nominal, override=override)), at())
    assert fault_codes(store) == {"robot/ur5": "joint_state_inconsistent"}
    assert rejected(store, "robot/ur5") == {"qd_inconsistent": 1}
    assert store.snapshot(at()).joint["ur5"] is None


def test_qd_tolerance_is_absolute_plus_ratio_of_nominal_either_side(store: InputStore, cell_config: CellConfig) -> None:
    streams = cell_config.streams
    nominal = [0.5, -0.5, 2.0, -2.0, 0.0, 0.0]
    room = [streams.qd_tolerance_radps + streams.qd_tolerance_ratio * abs(v) for v in nominal]
    inside = [0.6 * v + 0.999 * r * (-1) ** j for j, (v, r) in enumerate(zip(nominal, room, strict=True))]
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, qd=inside, qd_nominal=nominal, override=0.6)), at())
    assert store.snapshot(at()).faults == {}
    outside = [*inside[:3], -0.6 * 2.0 - 1.001 * room[3], *inside[4:]]
    store.on_joint_state(
        JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 3 * MS, qd=outside, qd_nominal=nominal, override=0.6)), at()
    )
    assert rejected(store, "robot/ur5") == {"qd_inconsistent": 1}


# -- continuity of the joint positions ------------------------------------------------------------

Q0 = [0.0, -1.2, 1.5, 0.1, 0.2, 0.3]


def _moved(joint: int, by_rad: float) -> list[float]:
    q = list(Q0)
    q[joint] += by_rad
    return q


def _allowed_rad(ur5: RobotModel, joint: int, dt_ns: int) -> float:
    """The motion a joint may show in ``dt_ns`` between two stamps: its velocity limit (×1.05) plus the margin."""
    return float(ur5.velocity_limit_radps[joint]) * VELOCITY_LIMIT_FACTOR * dt_ns / 1e9 + JUMP_MARGIN_RAD


def test_a_pose_jump_between_two_states_faults_the_robot(store: InputStore, ur5: RobotModel) -> None:
    """Issue 17: a q that moved farther than the velocity limit allows since the last state (a pose jump)."""
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 8 * MS, q=Q0)), at())
    jump_rad = 1.01 * _allowed_rad(ur5, 2, 4 * MS)
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 4 * MS, q=_moved(2, -jump_rad))), at())
    snap = store.snapshot(at())
    assert snap.faults["robot/ur5"].code == "joint_state_inconsistent"
    assert snap.faults["robot/ur5"].reason.startswith("q_jump: joint 2 moved")
    assert stored_seq(store) == 1  # the jumped pose is not believed
    assert rejected(store, "robot/ur5") == {"q_jump": 1}


def test_motion_within_the_velocity_limit_is_continuous(store: InputStore, ur5: RobotModel) -> None:
    """Every joint at 0.99 of its velocity limit (× 1.05), 4 ms apart, reported as it moves (qd, qd_nominal)."""
    stamp_ns = NOW - 40 * MS
    qd = [0.99 * VELOCITY_LIMIT_FACTOR * float(v) * (-1) ** j for j, v in enumerate(ur5.velocity_limit_radps)]
    moving = {"qd": qd, "qd_nominal": qd, "override": 1.0}
    store.on_override_sent("ur5", 1, 1.0, at(NOW - 60 * MS))  # the gateway let it run at full speed
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=stamp_ns, q=Q0, **moving)), at())
    q = list(Q0)
    for k in range(2, 10):
        q = [v + w * 4e-3 for v, w in zip(q, qd, strict=True)]
        store.on_joint_state(JOINT_KEY, enc(js(seq=k, stamp_ns=stamp_ns + (k - 1) * 4 * MS, q=q, **moving)), at())
    assert store.snapshot(at()).faults == {}
    assert stored_seq(store) == 9


def test_the_allowed_motion_grows_with_the_gap_between_stamps(store: InputStore, ur5: RobotModel) -> None:
    """A state after a long gap (a paused stream) may show the motion of that whole gap."""
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 700 * MS, q=Q0)), at(NOW - 699 * MS))
    moved = 0.99 * _allowed_rad(ur5, 0, 696 * MS)  # about 2.3 rad
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 4 * MS, q=_moved(0, moved))), at())
    assert store.snapshot(at()).faults == {}
    assert stored_seq(store) == 2


def test_the_first_state_may_be_anywhere(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, q=[3.0, -3.0, 3.0, -3.0, 3.0, -3.0])), at())
    assert store.snapshot(at()).faults == {}


def test_a_restarted_controller_is_judged_against_the_newest_state(store: InputStore) -> None:
    """A restart (seq from 0, newer stamp) is a seq_backwards fault, and no pose jump when the robot stood still
    or the restart took long enough; a restart that shows a jump is one."""
    store.on_joint_state(JOINT_KEY, enc(js(seq=500, stamp_ns=NOW - 400 * MS, q=Q0)), at(NOW - 399 * MS))
    store.on_joint_state(JOINT_KEY, enc(js(seq=0, stamp_ns=NOW - 8 * MS, q=_moved(1, 1.0))), at(NOW - 7 * MS))
    assert rejected(store, "robot/ur5") == {"seq_backwards": 1}  # 1 rad in 0.39 s is within the limit
    assert stored_seq(store) == 0
    store.on_joint_state(JOINT_KEY, enc(js(seq=0, stamp_ns=NOW - 4 * MS, q=_moved(1, 2.0))), at())
    assert rejected(store, "robot/ur5") == {"seq_backwards": 1, "q_jump": 1}  # another restart, 1 rad in 4 ms


def test_states_after_a_rejected_jump_are_judged_against_the_last_accepted(store: InputStore) -> None:
    """One forged pose does not become the reference: the genuine states after it are continuous, and the fault
    clears after the hold."""
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 8 * MS, q=Q0)), at())
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 6 * MS, q=_moved(4, 1.5))), at())
    for k in range(3, 6):
        t = NOW + (k - 3) * 4 * MS
        store.on_joint_state(JOINT_KEY, enc(js(seq=k, stamp_ns=t - 4 * MS, q=_moved(4, 0.0002 * k))), at(t))
    assert rejected(store, "robot/ur5") == {"q_jump": 1}
    assert stored_seq(store, NOW + 8 * MS) == 5
    assert fault_codes(store, NOW + 8 * MS) == {"robot/ur5": "joint_state_inconsistent"}
    assert fault_codes(store, NOW + HOLD_NS) == {}


def test_a_repeated_stamp_is_judged_by_the_order_not_as_a_jump(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 4 * MS, q=Q0)), at())
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 4 * MS, q=_moved(0, 2.0))), at())
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 4 * MS, q=Q0)), at())  # a duplicate
    assert rejected(store, "robot/ur5") == {"stamp_backwards": 1, "duplicate": 1}


def _applied(store: InputStore, overrides: list[float], commanded: float) -> None:
    """States 4 ms apart at these applied overrides (qd_nominal 0.5 rad/s), q moving as they say."""
    store.on_override_sent("ur5", 1, commanded, at(NOW - 20 * MS))
    q = np.array(Q0)
    for k, applied in enumerate(overrides):
        t = NOW + 4 * k * MS
        if k:
            q = q + 0.5 * 0.5 * (overrides[k - 1] + applied) * 4e-3  # the trapezoid of qd over the 4 ms
        raw = js(seq=1 + k, stamp_ns=t - 2 * MS, q=q.tolist(), override=applied, override_seq=1, qd=[0.5 * applied] * 6)
        store.on_joint_state(JOINT_KEY, enc(raw), at(t))


def test_an_applied_override_above_the_command_faults_the_robot(store: InputStore) -> None:
    """Issue 9, hole 5/6: the controller moves at δ = 1 (e.g. a forged override) while the gateway commands 0."""
    _applied(store, [0.0, 0.02, 0.05, 0.1], commanded=0.0)
    assert fault_codes(store, NOW + 12 * MS) == {"robot/ur5": "override_not_followed"}
    assert rejected(store, "robot/ur5") == {"override_above_commanded": 2}


def test_one_state_above_the_command_is_not_yet_a_fault(store: InputStore) -> None:
    _applied(store, [0.0, 0.02, 0.0], commanded=0.0)
    assert fault_codes(store, NOW + 8 * MS) == {}


def test_braking_toward_the_command_is_following_it(store: InputStore, ur5: RobotModel) -> None:
    """From δ = 1 the controller may take its braking time to reach 0: a ramp at the planned rate is fine."""
    t_brake_s = float(ur5.t_brake_link_s[ur5.t_brake_link_s > 0].min())
    ramp = [max(0.0, 1.0 - k * 0.004 / t_brake_s) for k in range(80)]
    _applied(store, ramp, commanded=0.0)
    assert fault_codes(store, NOW + 320 * MS) == {}


def test_braking_slower_than_planned_is_not_following(store: InputStore, ur5: RobotModel) -> None:
    t_brake_s = float(ur5.t_brake_link_s[ur5.t_brake_link_s > 0].min())
    too_slow = [max(0.0, 1.0 - k * 0.004 / (1.5 * t_brake_s)) for k in range(80)]
    _applied(store, too_slow, commanded=0.0)
    assert fault_codes(store, NOW + 320 * MS) == {"robot/ur5": "override_not_followed"}


# -- override path through the store ------------------------------------------------------------


def test_override_echo_is_learned(store: InputStore) -> None:
    store.on_override_sent("ur5", 1, 0.0, at(NOW - 20 * MS))
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 8 * MS, override_seq=1)), at())
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 4 * MS, override_seq=1)), at())
    path = store.snapshot(at()).override_path["ur5"]
    assert path.latency_s == pytest.approx(0.012)
    assert path.controller_cycle_s == pytest.approx(0.004)
    assert path.acked_sent_mono_ns == at(NOW - 20 * MS).mono_ns


def test_rejected_states_do_not_teach_the_override_path(store: InputStore) -> None:
    store.on_override_sent("ur5", 1, 0.0, at(NOW - 20 * MS))
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW + 900 * MS, override_seq=1)), at())  # future
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, robot="ur10", override_seq=1)), at())
    assert store.snapshot(at()).override_path["ur5"].latency_s is None


def test_an_echo_stamped_before_its_override_was_sent_is_a_fault(store: InputStore) -> None:
    """Issue 17: an echo stamped before the override it reports was sent is not a latency of 0."""
    store.on_override_sent("ur5", 1, 0.0, at(NOW - 4 * MS))
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 4 * MS - FUTURE_NS - 1, override_seq=1)), at())
    snap = store.snapshot(at())
    assert snap.faults["robot/ur5"].code == "joint_state_inconsistent"
    assert snap.faults["robot/ur5"].reason.startswith("echo_before_send: override_seq 1")
    assert snap.override_path["ur5"] == (None, None, None)  # nothing learned
    assert stored_seq(store) == 1  # the state itself is in order and stored, the robot stopped by the fault
    assert rejected(store, "robot/ur5") == {"echo_before_send": 1}
    # the same seq in the next states, now stamped after the send, does not confirm it either
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW, override_seq=1)), at(NOW + 1 * MS))
    assert store.snapshot(at(NOW + 1 * MS)).override_path["ur5"].latency_s is None


def test_an_echo_within_the_clocks_agreement_is_a_latency_of_zero(store: InputStore) -> None:
    """The controller's clock may be behind the gateway's by streams.max_future_stamp_s."""
    store.on_override_sent("ur5", 1, 0.0, at(NOW - 4 * MS))
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 4 * MS - FUTURE_NS, override_seq=1)), at())
    snap = store.snapshot(at())
    assert snap.faults == {}
    assert snap.override_path["ur5"].latency_s == 0.0
    assert snap.override_path["ur5"].acked_sent_mono_ns == at(NOW - 4 * MS).mono_ns


def test_an_echo_of_a_seq_never_sent_is_a_fault(store: InputStore) -> None:
    """Once the path is confirmed, a seq above every one sent is another sender's (or forged): a fault, and
    the newest confirmed override stays the one this gateway sent."""
    store.on_override_sent("ur5", 1, 0.0, at(NOW - 20 * MS))
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 8 * MS, override_seq=1)), at())
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 4 * MS, override_seq=9)), at())
    snap = store.snapshot(at())
    assert snap.faults["robot/ur5"].code == "joint_state_inconsistent"
    assert snap.faults["robot/ur5"].reason.startswith("echo_never_sent: override_seq 9")
    assert snap.override_path["ur5"].acked_sent_mono_ns == at(NOW - 20 * MS).mono_ns
    assert rejected(store, "robot/ur5") == {"echo_never_sent": 1}


def test_a_seq_reported_before_it_was_sent_never_confirms_it(store: InputStore) -> None:
    """A controller that keeps reporting seq 5 (a previous gateway's, or frozen) while this gateway starts: no
    fault before the first confirmation (a restart looks the same), and no confirmation when this gateway's own
    seq 5 goes out: the controller reported it before it existed."""
    for k in range(1, 8):
        t = NOW + k * 4 * MS
        store.on_override_sent("ur5", k, 0.0, at(t - 2 * MS))
        store.on_joint_state(JOINT_KEY, enc(js(seq=k, stamp_ns=t - 1 * MS, override_seq=5)), at(t))
    snap = store.snapshot(at(NOW + 28 * MS))
    assert snap.faults == {}
    assert snap.override_path["ur5"].latency_s is None  # the core: override_path_unconfirmed, δ = 0
    assert store.counters()[0] == {}


# -- never raises ---------------------------------------------------------------------------------


def test_random_garbage_and_mutations_never_raise(cell_config: CellConfig, ur5: RobotModel) -> None:
    """Seeded fuzz: random bytes, truncations, byte flips and field swaps of valid payloads."""
    rng = np.random.default_rng(21)
    store = InputStore(cell_config, {"ur5": ur5})
    valid = [enc(js()), enc(hm())]
    calls = 0
    for k in range(1500):
        base = valid[k % 2]
        kind = k % 5
        if kind == 0:
            payload = rng.bytes(int(rng.integers(0, 300)))
        elif kind == 1:
            payload = base[: int(rng.integers(0, len(base)))]
        elif kind == 2:
            data = bytearray(base)
            for _ in range(int(rng.integers(1, 6))):
                data[int(rng.integers(len(data)))] = int(rng.integers(0, 256))
            payload = bytes(data)
        elif kind == 3:
            raw = json.loads(base)
            field = str(rng.choice(sorted(raw)))
            raw[field] = [None, -1, 1e308, "x", [], {}, True, 2**70][int(rng.integers(8))]
            payload = enc(raw)
        else:
            payload = base.replace(b"0.", str(rng.choice(["NaN", "-Infinity", "1e999", "-0.", "00."])).encode(), 1)
        store.on_joint_state(JOINT_KEY, payload, at())
        store.on_humans(FRONT_KEY, payload, at())
        calls += 2
    rejected_all, received = store.counters()
    total = sum(sum(r.values()) for r in rejected_all.values()) + sum(received.values())
    assert total == calls  # every message is either accepted or counted as rejected
    assert sum(rejected_all["robot/ur5"].values()) > 500


# -- waking the loop ------------------------------------------------------------------------------


def test_tracker_changes_wake_the_loop_and_nothing_else_does(cell_config: CellConfig, ur5: RobotModel) -> None:
    calls: list[int] = []
    store = InputStore(cell_config, {"ur5": ur5}, on_tracker_change=lambda: calls.append(1))
    store.on_humans(FRONT_KEY, enc(hm(seq=1)), at())
    assert len(calls) == 1  # a new frame
    store.on_humans(FRONT_KEY, enc(hm(seq=1)), at())
    assert len(calls) == 1  # a repeat changes nothing
    store.on_humans(keys.tracker_humans(CELL, "rogue"), enc(hm(seq=2, tracker="rogue")), at())
    assert len(calls) == 1  # an unknown tracker concerns no robot: nothing changed
    store.on_joint_state(JOINT_KEY, enc(js()), at())
    assert len(calls) == 1  # joint states do not wake it
    store.on_humans(FRONT_KEY, b"{not json", at())
    assert len(calls) == 2  # a fault: the robots must stop at once
    assert fault_codes(store) == {"tracker/front": "tracker_invalid"}
    store.on_humans(FRONT_KEY, enc(hm(seq=2, stamp_ns=NOW + 900 * MS)), at())
    assert len(calls) == 3  # stamp in the future: a fault too


def test_flattened_capsules_match_the_message_on_random_frames() -> None:
    rng = np.random.default_rng(5)
    for _ in range(50):
        humans = [
            {
                "id": f"h{i}",
                "capsules": [
                    {
                        "name": f"c{k}",
                        "a": rng.uniform(-3, 3, 3).tolist(),
                        "b": rng.uniform(-3, 3, 3).tolist(),
                        "radius": float(rng.uniform(0, 0.3)),
                    }
                    for k in range(int(rng.integers(1, 16)))
                ],
            }
            for i in range(int(rng.integers(0, 4)))
        ]
        message = Humans.model_validate(hm(humans=humans))
        caps = capsules_from_message("side", message)
        flat = [(f"side/{h['id']}", c) for h in humans for c in h["capsules"]]
        assert caps.human_ids == tuple(hid for hid, _ in flat)
        assert caps.capsule_names == tuple(c["name"] for _, c in flat)
        assert caps.h_a_world.shape == caps.h_b_world.shape == (len(flat), 3)
        assert caps.radius_m.shape == (len(flat),)
        np.testing.assert_array_equal(caps.h_a_world.reshape(-1, 3), np.array([c["a"] for _, c in flat]).reshape(-1, 3))
        np.testing.assert_array_equal(caps.h_b_world.reshape(-1, 3), np.array([c["b"] for _, c in flat]).reshape(-1, 3))
        np.testing.assert_array_equal(caps.radius_m, [c["radius"] for _, c in flat])


# -- what one person may be (issue 32) ------------------------------------------------------------------------------


def _capsule(name: str, x: float, y: float = 0.0) -> dict[str, object]:
    return {"name": name, "a": [x, y, 0.0], "b": [x, y, 0.9], "radius": 0.15}


@pytest.mark.parametrize(
    ("people", "reason"),
    [
        ([{"id": "m", "capsules": [_capsule("legs", 0.0), _capsule("hand", 4.5)]}], "person_too_large"),
        ([{"id": "m", "capsules": [_capsule("arm", 0.0), _capsule("arm", 0.3)]}], "duplicate_part_name"),
        ([{"id": "m", "capsules": [_capsule(f"p{k}", 0.01 * k) for k in range(65)]}], "too_many_parts"),
        (
            [
                {"id": "a", "capsules": [_capsule("legs", 0.0)]},
                {"id": "b", "capsules": [_capsule("legs", 1.0)]},
                {"id": "a", "capsules": [_capsule("torso", 2.0)]},
            ],
            "duplicate_human_id",
        ),
    ],
)
def test_the_door_refuses_what_no_single_body_is(
    store: InputStore, people: list[dict[str, object]], reason: str
) -> None:
    """A tracker that merges people (one 'person' 4.5 m wide), names parts by kind, reports a point cloud as one
    person, or lists one id twice: refused with the reason, and the robots stop (a person one body cannot be would
    otherwise stand for bodies it does not describe)."""
    store.on_humans(FRONT_KEY, enc(hm(humans=people)), at())
    snap = store.snapshot(at())
    assert snap.faults["tracker/front"].code == "tracker_implausible"
    assert snap.faults["tracker/front"].reason.startswith(reason)
    assert store.counters()[0]["tracker/front"] == {reason: 1}


def test_one_body_at_the_limits_passes(store: InputStore, cell_config: CellConfig) -> None:
    """A person lying down with arms overhead (2.4 m) and 64 named parts is one body."""
    parts = [_capsule(f"p{k}", 2.4 * k / 63) for k in range(cell_config.plausibility.max_capsules_per_person)]
    store.on_humans(FRONT_KEY, enc(hm(humans=[{"id": "h1", "capsules": parts}])), at())
    assert store.snapshot(at()).faults == {}


# -- joint states consistent with themselves (issue 32, item 6) ------------------------------------------------

V_RADPS = 0.8
"""The programmed speed of joint 0 in these cases [rad/s] (a UR5 base joint at a brisk pace)."""


def _stream(
    store: InputStore,
    n: int,
    *,
    seq0: int = 1,
    t0_ns: int = NOW,
    q0: float = 0.0,
    override: Callable[[int], float] = lambda k: 1.0,
    report: Callable[[int, float], dict] = lambda k, ov: {},
    period_ns: int = 4 * MS,
) -> float:
    """``n`` states 4 ms apart of a robot whose joint 0 truly moves at ``override(k) · V_RADPS``; ``report(k, ov)``
    changes what the state says (honest by default). The gateway commands full speed. Returns joint 0's q."""
    store.on_override_sent("ur5", 1, 1.0, at(t0_ns - 20 * MS))
    q = q0
    previous = override(0)
    for k in range(n):
        ov = override(k)
        if k:
            q += 0.5 * (previous + ov) * V_RADPS * period_ns / 1e9
        previous = ov
        raw = js(
            seq=seq0 + k,
            stamp_ns=t0_ns + k * period_ns,
            q=[q, -1.2, 1.5, 0.1, 0.2, 0.3],
            qd=[ov * V_RADPS, 0, 0, 0, 0, 0],
            qd_nominal=[V_RADPS, 0, 0, 0, 0, 0],
            override=ov,
            override_seq=1,
        )
        raw.update(report(k, ov))
        store.on_joint_state(JOINT_KEY, enc(raw), at(t0_ns + k * period_ns + MS))
    return q


def _lying_still(k: int, ov: float) -> dict:
    """q advances, qd and qd_nominal say 0 (the reviewer's case)."""
    return {"qd": [0.0] * 6, "qd_nominal": [0.0] * 6}


def _reversed(k: int, ov: float) -> dict:
    """qd_nominal reversed on joint 0 while qd still says where the robot goes."""
    return {"qd_nominal": [-V_RADPS, 0, 0, 0, 0, 0]}


def test_an_honest_moving_robot_is_consistent(store: InputStore) -> None:
    _stream(store, 100, override=lambda k: min(1.0, k / 50))
    assert store.counters()[0] == {}
    assert stored_seq(store, NOW + 400 * MS) == 100


def test_q_advancing_while_qd_and_qd_nominal_say_zero_faults_the_robot(store: InputStore) -> None:
    """Issue 32, item 6: each 4 ms step (3.2 mrad) is within q_jump's limit; the lie shows over a few steps."""
    _stream(store, 5)  # honest, at full speed
    _stream(store, 20, seq0=6, t0_ns=NOW + 20 * MS, q0=0.016, report=_lying_still)
    snap = store.snapshot(at(NOW + 120 * MS))
    assert snap.faults["robot/ur5"].code == "joint_state_inconsistent"
    assert snap.faults["robot/ur5"].reason.startswith("q_motion_inconsistent: joint 0 moved +0.")
    assert "q_jump" not in rejected(store, "robot/ur5")
    assert rejected(store, "robot/ur5")["q_motion_inconsistent"] >= 15
    first = store.snapshot(at(NOW + 20 * MS + 3 * 4 * MS + MS))  # within three lying states
    assert first.faults["robot/ur5"].reason.startswith("q_motion_inconsistent")


def test_a_lying_robot_that_stops_when_stopped_stays_faulted(store: InputStore, ur5: RobotModel) -> None:
    """The lie shows only while the robot moves: stopped by the fault, it is consistent whatever it says, and the
    fault is kept (until joint 0 is seen moving consistently), never cleared by standing for the hold."""
    t_brake_s = float(ur5.t_brake_link_s[ur5.t_brake_link_s > 0].min())
    brake = lambda k: max(0.0, 1.0 - k * 0.004 / t_brake_s)  # noqa: E731
    _stream(store, 5)
    q = _stream(store, 300, seq0=6, t0_ns=NOW + 20 * MS, q0=0.016, override=brake, report=_lying_still)
    for t_ns in (NOW + 500 * MS, NOW + 1200 * MS):
        fault = store.snapshot(at(t_ns)).faults["robot/ur5"]
        assert fault.reason.startswith("q_motion_inconsistent")
    assert fault.reason.endswith("kept until joint(s) 0 are seen moving consistently")
    assert q > 0.016


def test_a_reversed_qd_nominal_stays_faulted_while_the_robot_stands(store: InputStore, ur5: RobotModel) -> None:
    """The reviewer's burst: qd_nominal reversed, caught while the robot moved, consistent while it stood (override
    0, qd 0), cleared after the hold, and δ = 1 came back (the stored state said "moving away")."""
    t_brake_s = float(ur5.t_brake_link_s[ur5.t_brake_link_s > 0].min())
    brake = lambda k: max(0.0, 1.0 - k * 0.004 / t_brake_s)  # noqa: E731
    _stream(store, 5)
    _stream(store, 300, seq0=6, t0_ns=NOW + 20 * MS, q0=0.016, override=brake, report=_reversed)
    assert rejected(store, "robot/ur5")["qd_inconsistent"] > 10
    sample = store.snapshot(at(NOW + 1220 * MS)).joint["ur5"]
    assert sample is not None
    assert sample.override == 0.0  # standing, consistent: accepted
    for t_ns in (NOW + 800 * MS, NOW + 1220 * MS, NOW + 5000 * MS):
        assert fault_codes(store, t_ns) == {"robot/ur5": "joint_state_inconsistent"}


def test_an_honest_robot_recovers_after_one_inconsistent_state(store: InputStore, ur5: RobotModel) -> None:
    """One bad state while moving: the robot brakes consistently (that is the proof), then the hold passes."""
    t_brake_s = float(ur5.t_brake_link_s[ur5.t_brake_link_s > 0].min())
    _stream(store, 5)
    _stream(store, 1, seq0=6, t0_ns=NOW + 20 * MS, q0=0.016, report=_reversed)
    _stream(store, 200, seq0=7, t0_ns=NOW + 24 * MS, q0=0.0192, override=lambda k: max(0.0, 1 - k * 0.004 / t_brake_s))
    assert rejected(store, "robot/ur5") == {"qd_inconsistent": 1}
    assert fault_codes(store, NOW + 21 * MS + HOLD_NS - MS) == {"robot/ur5": "joint_state_inconsistent"}
    assert fault_codes(store, NOW + 21 * MS + HOLD_NS) == {}


def test_a_glitch_on_a_standing_joint_clears_after_the_hold(store: InputStore) -> None:
    """A joint the program does not move reports a velocity once: nothing to prove in motion, the hold clears it."""
    _stream(store, 5, override=lambda k: 0.0)
    _stream(
        store,
        1,
        seq0=6,
        t0_ns=NOW + 20 * MS,
        override=lambda k: 0.0,
        report=lambda k, ov: {"qd": [0.0, 0.3, 0, 0, 0, 0]},
    )
    _stream(store, 200, seq0=7, t0_ns=NOW + 24 * MS, override=lambda k: 0.0)
    assert rejected(store, "robot/ur5") == {"qd_inconsistent": 1}
    assert fault_codes(store, NOW + 21 * MS + HOLD_NS) == {}


def test_a_stream_alternating_honest_and_lying_states_never_clears(store: InputStore) -> None:
    _stream(store, 5)
    q = _stream(
        store, 400, seq0=6, t0_ns=NOW + 20 * MS, q0=0.016, report=lambda k, ov: {} if k % 2 else _reversed(k, ov)
    )
    assert q > 1.0
    assert fault_codes(store, NOW + 20 * MS + 400 * 4 * MS) == {"robot/ur5": "joint_state_inconsistent"}
    assert rejected(store, "robot/ur5") == {"qd_inconsistent": 200}


@pytest.mark.parametrize("seed", range(6))
def test_honest_streams_with_jittered_stamps_and_noise_are_consistent(
    cell_config: CellConfig, ur5: RobotModel, seed: int
) -> None:
    """Invariant: a smooth motion (accelerations up to 10 rad/s²) reported with its velocities, stamped up to 1.5 ms
    off the instant of its q and with 0.4 mrad of position noise, at 4-20 ms between states, is never refused."""
    rng = np.random.default_rng(seed)
    store = InputStore(cell_config, {"ur5": ur5})
    store.on_override_sent("ur5", 1, 1.0, at(NOW - 20 * MS))
    amplitude = rng.uniform(0.1, 0.6, 6)
    omega = rng.uniform(1.0, 4.0, 6)
    phase = rng.uniform(0, 2 * np.pi, 6)
    t_s = 0.0
    assert joint_motion.STAMP_JITTER_S >= 0.0015
    assert joint_motion.Q_NOISE_RAD >= 0.0004
    for k in range(400):
        t_s += float(rng.uniform(0.004, 0.02))
        q = np.array(Q0) + amplitude * np.sin(omega * t_s + phase)
        qd = amplitude * omega * np.cos(omega * t_s + phase)
        stamp_ns = NOW + round((t_s + rng.uniform(-0.0015, 0.0015)) * 1e9)
        raw = js(seq=k + 1, stamp_ns=stamp_ns, q=(q + rng.uniform(-4e-4, 4e-4, 6)).tolist(), qd=qd.tolist(),
                 qd_nominal=qd.tolist(), override=1.0, override_seq=1)  # fmt: skip
        store.on_joint_state(JOINT_KEY, enc(raw), at(stamp_ns + 3 * MS))
    assert store.counters()[0] == {}


@pytest.mark.parametrize("seed", range(6))
def test_a_velocity_reported_other_than_the_motion_is_refused(
    cell_config: CellConfig, ur5: RobotModel, seed: int
) -> None:
    """Invariant: a joint moving at 0.1-3 rad/s whose qd and qd_nominal claim a fraction of that in [-1, 0.5] (a
    reversal, a standstill, half the speed) is refused within 0.25 s, and the fault holds while it goes on."""
    rng = np.random.default_rng(100 + seed)
    store = InputStore(cell_config, {"ur5": ur5})
    store.on_override_sent("ur5", 1, 1.0, at(NOW - 20 * MS))
    joint = int(rng.integers(6))
    speed = float(rng.uniform(0.1, 3.0)) * (1 if rng.random() < 0.5 else -1)
    claim = speed * float(rng.uniform(-1.0, 0.5))
    q = np.array(Q0)
    first_fault_ms = None
    for k in range(150):
        q[joint] += speed * 0.004 if k else 0.0
        qd = [claim if j == joint else 0.0 for j in range(6)]
        raw = js(seq=k + 1, stamp_ns=NOW + k * 4 * MS, q=q.tolist(), qd=qd, qd_nominal=qd, override=1.0, override_seq=1)
        store.on_joint_state(JOINT_KEY, enc(raw), at(NOW + k * 4 * MS + MS))
        if first_fault_ms is None and store.snapshot(at(NOW + k * 4 * MS + MS)).faults:
            first_fault_ms = 4 * k
    assert first_fault_ms is not None, (joint, speed, claim)
    assert first_fault_ms <= 250, (joint, speed, claim, first_fault_ms)
    assert fault_codes(store, NOW + 600 * MS + HOLD_NS) == {"robot/ur5": "joint_state_inconsistent"}


def test_a_state_stamped_before_the_newest_is_judged_by_the_order(store: InputStore) -> None:
    """Error path: the motion check judges only a state after the newest accepted one (the order judges the rest)."""
    _stream(store, 5)
    store.on_joint_state(JOINT_KEY, enc(js(seq=9, stamp_ns=NOW, q=[2.0, -1.2, 1.5, 0.1, 0.2, 0.3])), at(NOW + 30 * MS))
    assert rejected(store, "robot/ur5") == {"stamp_backwards": 1}


def test_the_motion_reason_names_its_fault_kind() -> None:
    assert fault_code("joint_state", "q_motion_inconsistent") == "joint_state_inconsistent"


def test_a_restarted_controller_elsewhere_starts_a_new_chain(store: InputStore) -> None:
    """An emulator restarts its program at another point (seq from 0, q 0.3 rad away after 100 ms, within q_jump):
    a seq_backwards fault for the hold, not a contradiction of motion that would need proof in motion."""
    _stream(store, 30)
    _stream(store, 30, seq0=0, t0_ns=NOW + 216 * MS, q0=0.4)
    assert rejected(store, "robot/ur5") == {"seq_backwards": 1}
    assert fault_codes(store, NOW + 217 * MS + HOLD_NS) == {}


def test_the_kept_fault_shows_its_contradiction_after_a_later_fault(store: InputStore) -> None:
    _stream(store, 5)
    q = _stream(store, 100, seq0=6, t0_ns=NOW + 20 * MS, q0=0.016, report=_lying_still)
    _stream(store, 10, seq0=1, t0_ns=NOW + 440 * MS, q0=q, override=lambda k: 0.0)  # a restart: out of order
    assert fault_codes(store, NOW + 441 * MS) == {"robot/ur5": "joint_state_out_of_order"}
    fault = store.snapshot(at(NOW + 441 * MS + HOLD_NS)).faults["robot/ur5"]  # the restart's hold is over
    assert fault.code == "joint_state_inconsistent"
    assert fault.reason.startswith("q_motion_inconsistent")


def test_a_state_the_order_refuses_is_not_judged_for_its_motion(store: InputStore) -> None:
    """Error path: a forged state stamped 6 ms ahead of its arrival, 20 mrad away from a standing robot (within
    q_jump), is stamp_in_future only; it does not join the chain (its stamp would move the chain's time) nor ask for
    proof in motion (the standing robot could never give it)."""
    q = _stream(store, 5, override=lambda k: 0.0)
    forged = js(seq=10**9, stamp_ns=NOW + 23 * MS, q=[q + 0.02, -1.2, 1.5, 0.1, 0.2, 0.3])
    store.on_joint_state(JOINT_KEY, enc(forged), at(NOW + 17 * MS))
    _stream(store, 5, seq0=6, t0_ns=NOW + 20 * MS, q0=q, override=lambda k: 0.0)
    assert rejected(store, "robot/ur5") == {"stamp_in_future": 1}
    assert fault_codes(store, NOW + 17 * MS + HOLD_NS) == {}


def test_a_frame_budget_gives_its_burst_then_its_rate() -> None:
    budget = FrameBudget.for_rate(30.0)  # 60 frames/s after a burst of FRAME_BURST
    assert [budget.admit(0) for _ in range(FRAME_BURST + 1)] == [True] * FRAME_BURST + [False]
    assert not budget.admit(16 * MS)  # 0.96 of a token earned
    assert budget.admit(17 * MS)
    assert not budget.admit(17 * MS)
    assert not budget.admit(5 * MS)  # a clock running backwards earns nothing
    assert budget.admit(17 * MS + 1000 * MS)  # a second later: the burst again, never more
    assert sum(budget.admit(1017 * MS) for _ in range(3 * FRAME_BURST)) == FRAME_BURST - 1


def test_a_tracker_flooding_valid_frames_has_the_excess_dropped_unparsed_and_no_fault(store: InputStore) -> None:
    """10 kHz of valid frames for 1 s from a 30 Hz tracker: the store takes FRAME_BURST + 2 × 30 of them, counts the
    rest as rate_exceeded, keeps the newest it took and raises no fault (what it kept is fresh)."""
    sent = 10_000
    for k in range(sent):
        t_ns = NOW - 1000 * MS + k * 100_000
        store.on_humans(FRONT_KEY, enc(hm(seq=k + 1, stamp_ns=t_ns - 30 * MS)), at(t_ns))
    dropped = rejected(store, "tracker/front")["rate_exceeded"]
    taken = sent - dropped
    assert FRAME_BURST + FRAME_RATE_FACTOR * 30 - 1 <= taken <= FRAME_BURST + FRAME_RATE_FACTOR * 30 + 1
    snap = store.snapshot(at())
    assert snap.faults == {}
    kept = snap.humans["front"]
    assert kept is not None
    assert kept.seq > sent - 200


def test_a_tracker_at_its_rate_loses_nothing_at_the_door(store: InputStore) -> None:
    for k in range(300):  # 10 s at 30 Hz, each frame 3 ms early or late
        t_ns = NOW - 10_000 * MS + k * 33_333_333 + (3 * MS if k % 2 else -3 * MS)
        store.on_humans(FRONT_KEY, enc(hm(seq=k + 1, stamp_ns=t_ns - 30 * MS)), at(t_ns))
    assert "rate_exceeded" not in rejected(store, "tracker/front")


def test_a_packed_frame_is_stored_as_its_json_would_be_and_judged_alike(
    cell_config: CellConfig, ur5: RobotModel
) -> None:
    """The same frame through the door as JSON and packed: the same stored capsules; the same refusal of a capsule
    outside the cell (the plausibility at the door does not depend on how the frame was written)."""
    stores = {wire: InputStore(cell_config, {"ur5": ur5}) for wire in ("json", "packed")}
    message = parse_message(enc(hm(seq=3)), Humans)
    stores["json"].on_humans(FRONT_KEY, enc(hm(seq=3)), at())
    stores["packed"].on_humans(FRONT_KEY, packed_payload(message), at())
    frames = {wire: store.snapshot(at()).humans["front"] for wire, store in stores.items()}
    assert frames["json"] is not None
    assert frames["packed"] is not None
    assert frames["packed"].seq == frames["json"].seq == 3
    assert frames["packed"].capsules.human_ids == frames["json"].capsules.human_ids
    np.testing.assert_array_equal(frames["packed"].capsules.h_a_world, frames["json"].capsules.h_a_world)
    np.testing.assert_array_equal(frames["packed"].capsules.radius_m, frames["json"].capsules.radius_m)
    starts = tuple(human_starts(frames["json"].capsules))  # carried from the door to the tracks
    assert frames["packed"].human_starts == frames["json"].human_starts == starts

    far = hm(seq=4)
    far["humans"][0]["capsules"][0]["a"] = [2.0, 0.0, 90.0]
    stores["json"].on_humans(FRONT_KEY, enc(far), at())
    stores["packed"].on_humans(FRONT_KEY, packed_payload(parse_message(enc(far), Humans)), at())
    assert rejected(stores["packed"], "tracker/front") == rejected(stores["json"], "tracker/front")
    assert rejected(stores["packed"], "tracker/front") == {"outside_world": 1}
    assert fault_codes(stores["packed"]) == fault_codes(stores["json"]) == {"tracker/front": "tracker_implausible"}
