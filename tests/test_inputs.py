"""InputStore: newest valid sample per topic, every bad payload counted by reason, never raising, latching."""

from __future__ import annotations

import json

import numpy as np
import pytest

from gateway.inputs import FUTURE_STAMP_TOLERANCE_NS, InputStore, capsules_from_message
from hrc_common import keys
from hrc_common.messages import Humans

CELL = "demo"
NOW = 1_790_000_000_000_000_000
MS = 1_000_000
JOINT_KEY = keys.robot_state(CELL, "ur5")
FRONT_KEY = keys.tracker_humans(CELL, "front")


def js(seq=1, stamp_ns=NOW - 4 * MS, **changes) -> dict:
    raw = {
        "schema": "hrc.joint_state/1",
        "robot": "ur5",
        "seq": seq,
        "stamp_ns": stamp_ns,
        "q": [0.0, -1.2, 1.5, 0.1, 0.2, 0.3],
        "qd": [0.0] * 6,
        "qd_nominal": [0.5] * 6,
        "override": 1.0,
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
def store() -> InputStore:
    return InputStore({"ur5": 6}, ["front", "side"])


def rejected(store: InputStore, topic: str) -> dict[str, int]:
    return store.counters()[0].get(topic, {})


# -- valid data -----------------------------------------------------------------------------------


def test_valid_joint_state_is_stored(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=7)), NOW)
    snap = store.snapshot()
    sample = snap.joint["ur5"]
    assert sample is not None
    assert sample.seq == 7
    assert sample.stamp_ns == NOW - 4 * MS
    np.testing.assert_allclose(sample.q_rad, [0.0, -1.2, 1.5, 0.1, 0.2, 0.3])
    np.testing.assert_allclose(sample.qd_nominal_radps, [0.5] * 6)  # the programmed speed, not qd
    assert sample.mode == "running"
    assert snap.invalid == {}
    assert store.counters() == ({}, {"robot/ur5": 1})


def test_valid_humans_are_flattened_with_tracker_prefixed_ids(store: InputStore) -> None:
    store.on_humans(FRONT_KEY, enc(hm()), NOW)
    frame = store.snapshot().humans["front"]
    assert frame is not None
    assert frame.human_count == 1
    caps = frame.capsules
    assert caps.human_ids == ("front/h1", "front/h1")
    assert caps.capsule_names == ("torso", "hand_r")
    np.testing.assert_allclose(caps.h_a_world, [[2.0, 0.0, 0.9], [1.6, 0.2, 1.1]])
    np.testing.assert_allclose(caps.h_b_world, [[2.0, 0.0, 1.5], [1.6, 0.2, 1.1]])
    np.testing.assert_allclose(caps.radius_m, [0.15, 0.05])
    assert store.snapshot().humans["side"] is None


def test_empty_humans_list_is_data(store: InputStore) -> None:
    store.on_humans(FRONT_KEY, enc(hm(humans=[])), NOW)
    frame = store.snapshot().humans["front"]
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
    ("nan_literal", _replace(js(), b'"override": 1.0', b'"override": NaN'), "non_finite"),
    ("infinity_literal", _replace(js(), b"[0.5, 0.5", b"[Infinity, 0.5"), "non_finite"),
    ("wrong_schema", enc(js(schema="hrc.joint_state/0")), "wrong_schema"),
    ("unknown_field", enc(js(temperature=40.0)), "invalid"),
    ("wrong_lengths", enc(js(qd=[0.0] * 5)), "invalid"),
    ("override_percent", enc(js(override=62.0)), "invalid"),
    ("wrong_joint_count", enc(js(q=[0.0] * 5, qd=[0.0] * 5, qd_nominal=[0.0] * 5)), "wrong_joint_count"),
    ("name_mismatch", enc(js(robot="ur10")), "name_mismatch"),
    ("too_large", b'{"schema": "hrc.joint_state/1", "pad": "' + b"x" * 2_000_000 + b'"}', "too_large"),
    ("stamp_in_future", enc(js(stamp_ns=NOW + FUTURE_STAMP_TOLERANCE_NS + 1)), "stamp_in_future"),
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
]


@pytest.mark.parametrize(("label", "payload", "reason"), JOINT_BAD, ids=[b[0] for b in JOINT_BAD])
def test_bad_joint_state_counted_and_latched(store: InputStore, label, payload, reason) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=1)), NOW)
    store.on_joint_state(JOINT_KEY, payload, NOW)
    assert rejected(store, "robot/ur5") == {reason: 1}
    snap = store.snapshot()
    assert snap.invalid == {"robot/ur5": reason}
    assert snap.joint["ur5"] is not None
    assert snap.joint["ur5"].seq == 1  # the bad message did not replace the stored one
    assert store.counters()[1] == {"robot/ur5": 1}


@pytest.mark.parametrize(("label", "payload", "reason"), HUMANS_BAD, ids=[b[0] for b in HUMANS_BAD])
def test_bad_humans_counted_and_latched(store: InputStore, label, payload, reason) -> None:
    store.on_humans(FRONT_KEY, payload, NOW)
    assert rejected(store, "tracker/front") == {reason: 1}
    snap = store.snapshot()
    assert snap.invalid == {"tracker/front": reason}
    assert snap.humans["front"] is None


def test_overflowing_number_is_rejected_and_latched(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, _replace(js(), b'"override": 1.0', b'"override": 1e999'), NOW)
    store.on_humans(FRONT_KEY, _replace(hm(), b"[2.0, 0.0, 0.9]", b"[1e999, 0.0, 0.9]"), NOW)
    snap = store.snapshot()
    assert snap.joint["ur5"] is None
    assert snap.humans["front"] is None
    assert set(snap.invalid) == {"robot/ur5", "tracker/front"}
    assert sum(rejected(store, "robot/ur5").values()) == 1
    assert sum(rejected(store, "tracker/front").values()) == 1


def test_overflowing_number_counted_as_non_finite(store: InputStore) -> None:
    """Regression: json.loads turns 1e999 into inf without calling parse_constant; it was counted as 'invalid'."""
    store.on_joint_state(JOINT_KEY, _replace(js(), b'"override": 1.0', b'"override": 1e999'), NOW)
    assert rejected(store, "robot/ur5") == {"non_finite": 1}


@pytest.mark.parametrize("kind", ["robot", "tracker"])
def test_deeply_nested_payload_is_counted_not_raised(store: InputStore, kind: str) -> None:
    """Regression: from about 1000 levels (2 kB) json.loads raised RecursionError through parse_message."""
    payload = b"[" * 5_000 + b"]" * 5_000  # 10 kB
    if kind == "robot":
        store.on_joint_state(JOINT_KEY, payload, NOW)
        assert rejected(store, "robot/ur5") == {"not_json": 1}
    else:
        store.on_humans(FRONT_KEY, payload, NOW)
        assert rejected(store, "tracker/front") == {"not_json": 1}


def test_unknown_robot_and_tracker_counted_but_not_latched(store: InputStore) -> None:
    store.on_joint_state(keys.robot_state(CELL, "ghost"), enc(js(robot="ghost")), NOW)
    store.on_humans(keys.tracker_humans(CELL, "back"), enc(hm(tracker="back")), NOW)
    store.on_joint_state("some/other/key", enc(js()), NOW)
    rejected_all, received = store.counters()
    assert rejected_all["robot/ghost"] == {"unknown_robot": 1}
    assert rejected_all["tracker/back"] == {"unknown_tracker": 1}
    assert rejected_all["robot/?"] == {"unknown_robot": 1}
    assert received == {}
    assert store.snapshot().invalid == {}


def test_future_stamp_tolerance_boundary(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW + FUTURE_STAMP_TOLERANCE_NS)), NOW)
    assert store.snapshot().joint["ur5"] is not None
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW + FUTURE_STAMP_TOLERANCE_NS + 1)), NOW)
    assert rejected(store, "robot/ur5") == {"stamp_in_future": 1}


# -- old, repeated, restart -----------------------------------------------------------------------


def test_repeated_and_old_seq_rejected(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=10, stamp_ns=NOW - 4 * MS)), NOW)
    store.on_joint_state(JOINT_KEY, enc(js(seq=10, stamp_ns=NOW - 4 * MS)), NOW)  # exact repeat
    store.on_joint_state(JOINT_KEY, enc(js(seq=9, stamp_ns=NOW - 8 * MS)), NOW)  # older
    store.on_joint_state(JOINT_KEY, enc(js(seq=11, stamp_ns=NOW - 5 * MS)), NOW)  # newer seq, older stamp
    store.on_joint_state(JOINT_KEY, enc(js(seq=3, stamp_ns=NOW - 4 * MS)), NOW)  # lower seq, same stamp
    assert rejected(store, "robot/ur5") == {"old_or_repeated": 4}
    sample = store.snapshot().joint["ur5"]
    assert sample is not None
    assert (sample.seq, sample.stamp_ns) == (10, NOW - 4 * MS)
    for seq, stamp in ((5, NOW - 30 * MS), (5, NOW - 30 * MS), (4, NOW - 60 * MS)):
        store.on_humans(FRONT_KEY, enc(hm(seq=seq, stamp_ns=stamp)), NOW)
    assert rejected(store, "tracker/front") == {"old_or_repeated": 2}
    assert store.snapshot().humans["front"].seq == 5


def test_producer_restart_is_accepted(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=5000, stamp_ns=NOW - 50 * MS)), NOW)
    store.on_joint_state(JOINT_KEY, enc(js(seq=0, stamp_ns=NOW - 4 * MS)), NOW)
    sample = store.snapshot().joint["ur5"]
    assert (sample.seq, sample.stamp_ns) == (0, NOW - 4 * MS)
    store.on_humans(FRONT_KEY, enc(hm(seq=300, stamp_ns=NOW - 90 * MS)), NOW)
    store.on_humans(FRONT_KEY, enc(hm(seq=0, stamp_ns=NOW - 30 * MS)), NOW)
    assert store.snapshot().humans["front"].seq == 0
    assert rejected(store, "robot/ur5") == {}
    assert rejected(store, "tracker/front") == {}


# -- latch ---------------------------------------------------------------------------------------


def test_invalid_latches_until_the_next_valid_message(store: InputStore) -> None:
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 8 * MS)), NOW)
    store.on_joint_state(JOINT_KEY, b"garbage", NOW)
    assert store.snapshot().invalid == {"robot/ur5": "not_json"}
    # a repeat of old valid data does not clear the latch
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 8 * MS)), NOW)
    assert store.snapshot().invalid == {"robot/ur5": "not_json"}
    # the latch shows the newest reason
    store.on_joint_state(JOINT_KEY, enc(js(robot="ur10")), NOW)
    assert store.snapshot().invalid == {"robot/ur5": "name_mismatch"}
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 4 * MS)), NOW)
    assert store.snapshot().invalid == {}
    assert rejected(store, "robot/ur5") == {"not_json": 1, "old_or_repeated": 1, "name_mismatch": 1}
    assert store.counters()[1] == {"robot/ur5": 2}


def test_latch_is_per_topic(store: InputStore) -> None:
    store.on_humans(FRONT_KEY, b"{", NOW)
    store.on_humans(keys.tracker_humans(CELL, "side"), enc(hm(tracker="side")), NOW)
    store.on_joint_state(JOINT_KEY, enc(js()), NOW)
    assert store.snapshot().invalid == {"tracker/front": "not_json"}


def test_count_rejection_from_outside_latches(store: InputStore) -> None:
    store.count_rejection("robot/ur5", "internal_error")
    assert store.snapshot().invalid == {"robot/ur5": "internal_error"}
    assert rejected(store, "robot/ur5") == {"internal_error": 1}


# -- override path through the store ------------------------------------------------------------


def test_override_echo_is_learned(store: InputStore) -> None:
    store.on_override_sent("ur5", 1, NOW - 20 * MS)
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW - 8 * MS, override_seq=1)), NOW)
    store.on_joint_state(JOINT_KEY, enc(js(seq=2, stamp_ns=NOW - 4 * MS, override_seq=1)), NOW)
    path = store.snapshot().override_path["ur5"]
    assert path.latency_s == pytest.approx(0.012)
    assert path.controller_cycle_s == pytest.approx(0.004)
    assert path.acked_sent_ns == NOW - 20 * MS


def test_rejected_states_do_not_teach_the_override_path(store: InputStore) -> None:
    store.on_override_sent("ur5", 1, NOW - 20 * MS)
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, stamp_ns=NOW + 900 * MS, override_seq=1)), NOW)  # future
    store.on_joint_state(JOINT_KEY, enc(js(seq=1, robot="ur10", override_seq=1)), NOW)
    assert store.snapshot().override_path["ur5"].latency_s is None


# -- never raises ---------------------------------------------------------------------------------


def test_random_garbage_and_mutations_never_raise() -> None:
    """Seeded fuzz: random bytes, truncations, byte flips and field swaps of valid payloads."""
    rng = np.random.default_rng(21)
    store = InputStore({"ur5": 6}, ["front", "side"])
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
        store.on_joint_state(JOINT_KEY, payload, NOW)
        store.on_humans(FRONT_KEY, payload, NOW)
        calls += 2
    rejected_all, received = store.counters()
    total = sum(sum(r.values()) for r in rejected_all.values()) + sum(received.values())
    assert total == calls  # every message is either accepted or counted as rejected
    assert sum(rejected_all["robot/ur5"].values()) > 500


# -- waking the loop ------------------------------------------------------------------------------


def test_tracker_changes_wake_the_loop_and_nothing_else_does() -> None:
    calls: list[int] = []
    store = InputStore({"ur5": 6}, ["front", "side"], on_tracker_change=lambda: calls.append(1))
    store.on_humans(FRONT_KEY, enc(hm(seq=1)), NOW)
    assert len(calls) == 1  # a new frame
    store.on_humans(FRONT_KEY, enc(hm(seq=1)), NOW)
    assert len(calls) == 1  # a repeat changes nothing
    store.on_humans(keys.tracker_humans(CELL, "rogue"), enc(hm(seq=2, tracker="rogue")), NOW)
    assert len(calls) == 1  # an unknown tracker is not latched: nothing changed
    store.on_joint_state(JOINT_KEY, enc(js()), NOW)
    assert len(calls) == 1  # joint states do not wake it
    store.on_humans(FRONT_KEY, b"{not json", NOW)
    assert len(calls) == 2  # latched invalid: the robots must stop at once
    assert store.snapshot().invalid == {"tracker/front": "not_json"}
    store.on_humans(FRONT_KEY, enc(hm(seq=2, stamp_ns=NOW + 900 * MS)), NOW)
    assert len(calls) == 3  # stamp in the future: latched too


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
                    for k in range(int(rng.integers(0, 16)))
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
