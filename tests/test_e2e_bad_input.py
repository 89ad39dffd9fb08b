"""Bad input matrix, end to end: every kind of bad message on every topic is rejected, counted per reason in
the status, crashes nothing and never raises δ."""

from __future__ import annotations

import json
import threading
import time
from contextlib import suppress
from pathlib import Path
from typing import Any

import pytest
import zenoh
from cellrun import running_cell

from hrc_common import keys
from hrc_common.zenoh_session import session_config

pytestmark = pytest.mark.e2e

NOW_NS = time.time_ns


def _joint(**overrides: Any) -> dict[str, Any]:
    msg: dict[str, Any] = {
        "schema": "hrc.joint_state/1", "robot": "ur5", "seq": 10**9, "stamp_ns": NOW_NS(),
        "q": [0.0] * 6, "qd": [0.0] * 6, "qd_nominal": [0.0] * 6,
        "override": 1.0, "override_seq": 1, "mode": "running",
    }  # fmt: skip
    return {**msg, **overrides}


def _humans(**overrides: Any) -> dict[str, Any]:
    capsule = {"name": "hand_r", "a": [3.0, 0.0, 1.0], "b": [3.0, 0.0, 1.1], "radius": 0.05}
    msg = {"schema": "hrc.humans/1", "tracker": "front", "seq": 10**9, "stamp_ns": NOW_NS(),
           "humans": [{"id": "x", "capsules": [capsule]}]}  # fmt: skip
    return {**msg, **overrides}


def _override(**overrides: Any) -> dict[str, Any]:
    return {"schema": "hrc.override/1", "robot": "ur5", "seq": 10**9, "stamp_ns": NOW_NS(), "delta": 1.0, **overrides}


def _b(doc: dict[str, Any]) -> bytes:
    return json.dumps(doc).encode()


def _bad_payloads(make: Any, array_field: str | None) -> dict[str, bytes]:
    """One payload per kind of bad input, by the reason the receiver must count."""
    bad = {
        "not_json": b"{not json",
        "wrong_schema": _b(make(schema="hrc.something_else/9")),
        "invalid(unknown field)": _b(make(surprise=1)),
        "non_finite": _b(make()).replace(b'"seq": 1000000000', b'"seq": 1000000000, "x": NaN'),
        "too_large": b'{"pad": "' + b"x" * 10_000_000 + b'"}',
    }
    if array_field:
        bad["invalid(wrong length)"] = _b(make(**{array_field: [0.0] * 5}))
    return bad


class _Statuses:
    def __init__(self) -> None:
        self.docs: list[dict[str, Any]] = []
        self.lock = threading.Lock()

    def on_sample(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.docs.append(json.loads(sample.payload.to_bytes()))


def test_bad_input_on_every_topic_is_rejected_counted_and_never_raises_delta(tmp_path: Path) -> None:
    statuses = _Statuses()
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        cell.wait_until(lambda s: not s["faults"] and s["delta"] > 0, 25.0, "a moving robot")
        with zenoh.open(session_config(connect=[cell.gateway_endpoint, cell.controller_endpoint])) as session:
            session.declare_subscriber(keys.gateway_status("demo"), statuses.on_sample)
            overrides: list[float] = []  # the gateway's overrides (this test's own bad ones are not JSON or ≠ 0)

            def on_override(sample: zenoh.Sample) -> None:
                with suppress(ValueError, AttributeError):
                    overrides.append(float(json.loads(sample.payload.to_bytes())["delta"]))

            session.declare_subscriber(keys.robot_override("demo", "ur5"), on_override)
            emu_stats: list[dict[str, Any]] = []
            session.declare_subscriber(
                keys.robot_emu_stats("demo", "ur5"), lambda s: emu_stats.append(json.loads(s.payload.to_bytes()))
            )
            time.sleep(0.5)
            state_key, humans_key = keys.robot_state("demo", "ur5"), keys.tracker_humans("demo", "front")
            sent: dict[str, list[str]] = {"robot/ur5": [], "tracker/front": []}
            for reason, payload in _bad_payloads(_joint, "qd").items():
                session.put(state_key, payload)
                sent["robot/ur5"].append(reason)
            session.put(state_key, _b(_joint(q=[0.0] * 7, qd=[0.0] * 7, qd_nominal=[0.0] * 7)))  # wrong joint count
            session.put(state_key, _b(_joint(robot="other")))  # name in the message ≠ name in the key
            session.put(state_key, _b(_joint(stamp_ns=1, seq=0)))  # old
            for reason, payload in _bad_payloads(_humans, None).items():
                session.put(humans_key, payload)
                sent["tracker/front"].append(reason)
            negative = _humans()
            negative["humans"][0]["capsules"][0]["radius"] = -0.05
            session.put(humans_key, _b(negative))
            many = _humans()
            many["humans"][0]["capsules"] = many["humans"][0]["capsules"] * 2001
            session.put(humans_key, _b(many))  # more capsules than any sensor frame may carry
            session.put(humans_key, _b(_humans(stamp_ns=1, seq=0)))  # old
            session.put(keys.robot_state("demo", "ghost"), _b(_joint(robot="ghost")))
            session.put(keys.tracker_humans("demo", "ghost"), _b(_humans(tracker="ghost")))
            override_key = keys.robot_override("demo", "ur5")
            for payload in _bad_payloads(_override, None).values():
                session.put(override_key, payload)
            session.put(override_key, _b(_override(delta=1.5)))
            session.put(override_key, _b(_override(stamp_ns=1)))  # stale
            time.sleep(1.5)
        status = cell.get("/api/v1/status").json()
        rejected = status["inputs"]["rejected"]
        robot = rejected["robot/ur5"]
        for reason in ("not_json", "wrong_schema", "non_finite", "too_large", "wrong_joint_count", "name_mismatch"):
            assert robot.get(reason, 0) >= 1, (reason, robot)
        assert robot["invalid"] >= 2  # unknown field, wrong length
        assert robot["old_or_repeated"] >= 1
        tracker = rejected["tracker/front"]
        for reason in ("not_json", "wrong_schema", "non_finite", "too_large", "old_or_repeated"):
            assert tracker.get(reason, 0) >= 1, (reason, tracker)
        assert tracker["invalid"] >= 3  # unknown field, negative radius, 2001 capsules
        assert rejected["robot/ghost"] == {"unknown_robot": 1}
        assert rejected["tracker/ghost"] == {"unknown_tracker": 1}
        # The controller counted the bad overrides too and kept running.
        controller_rejected = emu_stats[-1]["rejected"]
        assert sum(controller_rejected.values()) >= 6, controller_rejected  # the stale one may be superseded
        # Never above what the math allows, at any moment; and nothing crashed.
        with statuses.lock:
            docs = list(statuses.docs)
        assert len(docs) > 20
        assert all(d["robots"]["ur5"]["delta"] <= d["robots"]["ur5"]["delta_bound"] for d in docs)
        # A bad tracker frame is the newest humans data until the next frame (~33 ms): δ = 0 meanwhile.
        assert 0.0 in overrides, "bad input must fail closed while it is the newest input"
        cell.wait_until(lambda s: not s["faults"] and s["delta"] > 0, 5.0, "recovery with valid data")
        for name, proc in cell.procs.items():
            assert proc.poll() is None, f"{name} died\n{cell.tail()}"
