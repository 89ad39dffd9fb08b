"""Bad input matrix, end to end: every kind of bad message on every topic is rejected, counted per reason in
the status, crashes nothing and never raises δ."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from typing import Any

import pytest
import zenoh

from hrc_contract import keys
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import Cell, running_cell

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

    def count(self) -> int:
        with self.lock:
            return len(self.docs)


BLOCK = zenoh.CongestionControl.BLOCK
"""The congestion control of every put here. The default, DROP, discards a message whenever the link's queue is
full, e.g. right after one of the 10 MB payloads on a loaded machine: the message after it was lost, its reason
never counted (this test was flaky for that reason)."""

PROBE_AHEAD_NS = 10 * 10**9
"""A gateway probe is stamped this far ahead: rejected as ``stamp_in_future``, a reason the batch does not send."""
CONTROLLER_PROBE = "wrong_robot"
"""The controller's probe is an override for another robot: a rejection the batch does not send either."""

ROBOT_REJECTIONS = {
    "not_json": 1, "wrong_schema": 1, "non_finite": 1, "too_large": 1, "wrong_joint_count": 1, "name_mismatch": 1,
    "invalid": 2,  # unknown field, wrong length
    "stamp_backwards": 1,  # old
}  # fmt: skip
TRACKER_REJECTIONS = {
    "not_json": 1, "wrong_schema": 1, "non_finite": 1, "too_large": 1, "stamp_backwards": 1,
    "invalid": 3,  # unknown field, negative radius, 2001 capsules
}  # fmt: skip
"""What the batch adds to the gateway's rejection counters, by reason (at least: the emulators may add to them)."""
CONTROLLER_REJECTIONS = 6
"""The five bad payloads and δ = 1.5 (the old override may be superseded by a newer one before it is judged)."""

ROUTE_S = 15.0
COUNTED_S = 15.0


def _gateway_rejected(cell: Cell) -> dict[str, dict[str, int]]:
    rejected: dict[str, dict[str, int]] = cell.get("/api/v1/status").json()["inputs"]["rejected"]
    return rejected


def _controller_rejected(emu_stats: list[dict[str, Any]]) -> dict[str, int]:
    return dict(emu_stats[-1]["rejected"]) if emu_stats else {}


def _added(before: dict[str, int], after: dict[str, int]) -> dict[str, int]:
    """The counts that grew from ``before`` to ``after``, by how much."""
    return {reason: n - before.get(reason, 0) for reason, n in after.items() if n > before.get(reason, 0)}


def _short(added: dict[str, int], expected: dict[str, int]) -> dict[str, int]:
    """The reasons counted fewer times than ``expected``, with the count added."""
    return {reason: added.get(reason, 0) for reason, n in expected.items() if added.get(reason, 0) < n}


def _prove_route(cell: Cell, send_probe: Callable[[], None], counted: Callable[[], bool], route: str) -> None:
    """Send a probe until its receiver has counted one. Zenoh drops a put made before the receiver's
    subscription has reached this session, so no sleep proves that a message sent now will arrive."""

    def probe_counted() -> bool:
        if counted():
            return True
        send_probe()
        return False

    cell.wait(probe_counted, ROUTE_S, f"a probe on {route} to be counted")


def test_bad_input_on_every_topic_is_rejected_counted_and_never_raises_delta(tmp_path: Path) -> None:
    statuses = _Statuses()
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        cell.wait_until(lambda s: not s["faults"] and s["delta"] > 0, 25.0, "a moving robot")
        with zenoh.open(session_config(connect=[cell.gateway_endpoint, cell.controller_endpoint])) as session:
            session.declare_subscriber(keys.gateway_status("demo"), statuses.on_sample)
            overrides: list[float] = []  # the gateway's overrides (this test's own bad ones are not JSON or ≠ 0)

            def on_override(sample: zenoh.Sample) -> None:
                with suppress(ValueError, AttributeError, KeyError, TypeError):
                    overrides.append(float(json.loads(sample.payload.to_bytes())["delta"]))

            session.declare_subscriber(keys.robot_override("demo", "ur5"), on_override)
            emu_stats: list[dict[str, Any]] = []
            session.declare_subscriber(
                keys.robot_emu_stats("demo", "ur5"), lambda s: emu_stats.append(json.loads(s.payload.to_bytes()))
            )

            def put(key: str, payload: bytes) -> None:
                session.put(key, payload, congestion_control=BLOCK)

            state_key, humans_key = keys.robot_state("demo", "ur5"), keys.tracker_humans("demo", "front")
            override_key = keys.robot_override("demo", "ur5")
            # Every route, proven before the batch: to this session (something arrived on each subscription) and
            # from it (a probe on the very key was counted; the ghost keys share the gateway's wildcards).
            cell.wait(lambda: bool(overrides) and statuses.count() > 0, ROUTE_S, "overrides and statuses here")
            cell.wait(lambda: bool(emu_stats), ROUTE_S, "the controller's statistics here")
            unprobed, controller_unprobed = _gateway_rejected(cell), _controller_rejected(emu_stats)

            def probes_counted(topic: str) -> int:
                return _added(unprobed.get(topic, {}), _gateway_rejected(cell).get(topic, {})).get("stamp_in_future", 0)

            _prove_route(
                cell,
                lambda: put(state_key, _b(_joint(stamp_ns=NOW_NS() + PROBE_AHEAD_NS))),
                lambda: probes_counted("robot/ur5") > 0,
                state_key,
            )
            _prove_route(
                cell,
                lambda: put(humans_key, _b(_humans(stamp_ns=NOW_NS() + PROBE_AHEAD_NS))),
                lambda: probes_counted("tracker/front") > 0,
                humans_key,
            )
            _prove_route(
                cell,
                lambda: put(override_key, _b(_override(robot="other"))),
                lambda: CONTROLLER_PROBE in _added(controller_unprobed, _controller_rejected(emu_stats)),
                override_key,
            )
            before = _gateway_rejected(cell)
            controller_before = _controller_rejected(emu_stats)
            overrides_before, statuses_before = len(overrides), statuses.count()

            for payload in _bad_payloads(_joint, "qd").values():
                put(state_key, payload)
            put(state_key, _b(_joint(q=[0.0] * 7, qd=[0.0] * 7, qd_nominal=[0.0] * 7)))  # wrong joint count
            put(state_key, _b(_joint(robot="other")))  # name in the message ≠ name in the key
            put(state_key, _b(_joint(stamp_ns=1, seq=0)))  # old
            for payload in _bad_payloads(_humans, None).values():
                put(humans_key, payload)
            negative = _humans()
            negative["humans"][0]["capsules"][0]["radius"] = -0.05
            put(humans_key, _b(negative))
            many = _humans()
            many["humans"][0]["capsules"] = many["humans"][0]["capsules"] * 2001
            put(humans_key, _b(many))  # more capsules than any sensor frame may carry
            put(humans_key, _b(_humans(stamp_ns=1, seq=0)))  # old
            put(keys.robot_state("demo", "ghost"), _b(_joint(robot="ghost")))
            put(keys.tracker_humans("demo", "ghost"), _b(_humans(tracker="ghost")))
            for payload in _bad_payloads(_override, None).values():
                put(override_key, payload)
            put(override_key, _b(_override(delta=1.5)))
            put(override_key, _b(_override(stamp_ns=1)))  # old: stamped before the last accepted override

            def robot_added() -> dict[str, int]:
                return _added(before.get("robot/ur5", {}), _gateway_rejected(cell)["robot/ur5"])

            def tracker_added() -> dict[str, int]:
                return _added(before.get("tracker/front", {}), _gateway_rejected(cell)["tracker/front"])

            def controller_added() -> int:
                added = _added(controller_before, _controller_rejected(emu_stats))
                return sum(n for reason, n in added.items() if reason != CONTROLLER_PROBE)

            def everything_seen() -> bool:
                rejected = _gateway_rejected(cell)
                return (
                    not _short(robot_added(), ROBOT_REJECTIONS)
                    and not _short(tracker_added(), TRACKER_REJECTIONS)
                    and "robot/ghost" in rejected
                    and "tracker/ghost" in rejected
                    and controller_added() >= CONTROLLER_REJECTIONS
                    and 0.0 in overrides[overrides_before:]
                    and statuses.count() - statuses_before > 20
                )

            with suppress(AssertionError):  # the assertions below say what is missing
                cell.wait(everything_seen, COUNTED_S, "every bad input to be counted")
            robot, tracker = robot_added(), tracker_added()
            assert not _short(robot, ROBOT_REJECTIONS), f"added {robot}, before {before}"
            assert not _short(tracker, TRACKER_REJECTIONS), f"added {tracker}, before {before}"
            rejected = _gateway_rejected(cell)
            assert rejected["robot/ghost"] == {"unknown_robot": 1}
            assert rejected["tracker/ghost"] == {"unknown_tracker": 1}
            # The controller counted the bad overrides too and kept running.
            assert controller_added() >= CONTROLLER_REJECTIONS, (
                f"{controller_before} → {_controller_rejected(emu_stats)}"
            )
            # Never above what the math allows, at any moment; and nothing crashed.
            with statuses.lock:
                docs = list(statuses.docs)
            assert len(docs) - statuses_before > 20
            assert all(d["robots"]["ur5"]["delta"] <= d["robots"]["ur5"]["delta_bound"] for d in docs)
            # A bad tracker frame is the newest humans data until the next frame (~33 ms): δ = 0 meanwhile.
            assert 0.0 in overrides[overrides_before:], "bad input must fail closed while it is the newest input"
        cell.wait_until(lambda s: not s["faults"] and s["delta"] > 0, 5.0, "recovery with valid data")
        for name, proc in cell.procs.items():
            assert proc.poll() is None, f"{name} died\n{cell.tail()}"
