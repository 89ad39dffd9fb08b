"""Recording and replay without processes: the MCAP sink, the Foxglove scene, the gateway's own recording.

The gateway node is driven here as the process drives it (payload bytes in, ``cycle(now)`` out), by a small
closed loop: a controller that applies each override and echoes its seq, a hand walking toward the robot
seen by both trackers. Its recording replayed unchanged gives every δ back; with a changed parameter it does
not. A second run feeds the inputs from another thread while the loop cycles on the real clocks, as Zenoh
does: the recorded order still replays exactly.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import support.status_examples as ex
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from gateway import recording
from gateway.events import EventLog
from gateway.main import build_node
from gateway.node import GatewayNode
from gateway.recording import GatewayRecorder, read_gateway_recording
from hrc_contract import keys
from hrc_contract.config import CellConfig, ConfigError
from hrc_contract.messages import Humans, JointState, to_payload
from hrc_contract.status_models import CapsuleStatus, Event, GatewayStatus, PlanStatus
from hrc_runtime.clocks import Clocks, read_clocks
from hrc_runtime.mcap_sink import SUMMARY_METADATA, McapSink, RecordingError, identity, model_channel
from hrc_tools.record import scene
from hrc_tools.record.cell import CellRecorder
from hrc_tools.record.replay import apply_settings, format_replay_report, replay
from hrc_tools.record.topics import SCENE, topic_of

MS = 1_000_000
T0_WALL_NS = 1_790_000_000_000_000_000
T0_MONO_NS = 5_000_000_000
Q = [0.3, -1.2, 1.4, -0.5, 1.2, 0.0]
QD_NOMINAL = [0.6, -0.4, 0.5, 0.3, 0.2, 0.1]
HAND_FROM = np.array([3.5, 1.39, 1.08])
HAND_TO = np.array([-0.88, 1.39, 1.08])


# -- the Foxglove scene --------------------------------------------------------------------------------


def _rotate(q: scene.Quaternion, v: np.ndarray) -> np.ndarray:
    """v rotated by the unit quaternion q (v' = v + 2w (u × v) + 2 u × (u × v), u = (x, y, z))."""
    u = np.array([q.x, q.y, q.z])
    return v + 2.0 * q.w * np.cross(u, v) + 2.0 * np.cross(u, np.cross(u, v))


def test_z_to_turns_the_cylinder_axis_onto_any_direction() -> None:
    rng = np.random.default_rng(7)
    directions = [np.array(d, dtype=float) for d in ((0, 0, 1), (0, 0, -1), (1, 0, 0), (0, 1, 0))]
    directions += [d / np.linalg.norm(d) for d in rng.normal(size=(50, 3))]
    for d in directions:
        q = scene.z_to(d)
        assert math.isclose(q.x**2 + q.y**2 + q.z**2 + q.w**2, 1.0, rel_tol=1e-12)
        np.testing.assert_allclose(_rotate(q, np.array([0.0, 0.0, 1.0])), d, atol=1e-12)


def test_capsule_is_a_cylinder_between_two_spheres_and_a_point_is_one_sphere() -> None:
    color = scene.HUMAN_COLOR
    cylinders, spheres = scene.capsule_primitives((1.0, 0.0, 1.0), (1.0, 0.0, 1.6), 0.1, color)
    assert len(cylinders) == 1
    assert len(spheres) == 2
    c = cylinders[0]
    assert (c.pose.position.x, c.pose.position.y, c.pose.position.z) == (1.0, 0.0, 1.3)
    assert (c.size.x, c.size.y) == (0.2, 0.2)
    assert math.isclose(c.size.z, 0.6)
    assert [(s.pose.position.z, s.size.x) for s in spheres] == [(1.0, 0.2), (1.6, 0.2)]
    cylinders, spheres = scene.capsule_primitives((2.0, 1.0, 1.0), (2.0, 1.0, 1.0), 0.05, color)
    assert cylinders == []
    assert len(spheres) == 1


def test_humans_scene_has_one_entity_per_person_in_the_foxglove_shape() -> None:
    frame = Humans.model_validate(
        {
            "schema": "hrc.humans/1",
            "tracker": "front",
            "seq": 1,
            "stamp_ns": T0_WALL_NS,
            "humans": [
                {"id": "h1", "capsules": [{"name": "torso", "a": [1, 2, 0.8], "b": [1, 2, 1.6], "radius": 0.2}]},
                {"id": "h2", "capsules": [{"name": "hand_r", "a": [3, 2, 1], "b": [3, 2, 1], "radius": 0.05}]},
            ],
        }
    )
    update = scene.humans_scene(frame, T0_WALL_NS + 1_500_000_123)
    doc = json.loads(update.model_dump_json())
    assert [e["id"] for e in doc["entities"]] == ["front/h1", "front/h2"]
    entity = doc["entities"][0]
    assert entity["timestamp"] == {"sec": 1_790_000_001, "nsec": 500_000_123}
    assert entity["frame_id"] == "world"
    # every field the Foxglove schema requires of an entity is there
    for field in ("lifetime", "frame_locked", "metadata", "arrows", "cubes", "spheres", "cylinders", "lines"):
        assert field in entity
    assert (len(entity["cylinders"]), len(entity["spheres"])) == (1, 2)
    FOXGLOVE.validate(doc)


FOXGLOVE = Draft202012Validator(scene.foxglove_schema())
"""Foxglove's own schema of ``foxglove.SceneUpdate`` (vendored from ``@foxglove/schemas``), as a validator."""


def test_the_scene_channel_has_foxglove_s_own_schema_as_vendored() -> None:
    data = scene.foxglove_schema_bytes()
    assert hashlib.sha256(data).hexdigest() == scene.FOXGLOVE_SCHEMA_SHA256, "the vendored file was edited"
    schema = json.loads(data)
    assert schema["title"] == "foxglove.SceneUpdate"
    assert schema["$comment"] == "Generated by https://github.com/foxglove/foxglove-sdk"
    assert scene.FOXGLOVE_SCHEMAS_VERSION in (Path(scene.__file__).parent / "schemas" / "README.md").read_text()
    assert SCENE.schema == schema


def _random_capsule(rng: np.random.Generator, name: str) -> dict[str, object]:
    a = rng.uniform(-8.0, 8.0, 3)
    b = a if rng.random() < 0.3 else a + rng.normal(0.0, 0.5, 3)  # some point capsules (one sphere)
    return {"name": name, "a": a.tolist(), "b": b.tolist(), "radius": float(rng.uniform(0.0, 0.4))}


def test_every_scene_message_is_valid_against_foxglove_s_schema() -> None:
    rng = np.random.default_rng(22)
    for seq in range(50):
        humans = [
            {"id": f"h{i}", "capsules": [_random_capsule(rng, f"c{j}") for j in range(int(rng.integers(1, 6)))]}
            for i in range(int(rng.integers(0, 4)))
        ]
        frame = Humans.model_validate({"tracker": "front", "seq": seq, "stamp_ns": T0_WALL_NS, "humans": humans})
        received_ns = T0_WALL_NS + int(rng.integers(0, 10**12))
        FOXGLOVE.validate(json.loads(scene.humans_scene(frame, received_ns).model_dump_json()))
    for zone in scene.ZONE_COLORS:
        links = [
            CapsuleStatus(name=f"l{i}", a_m=c["a"], b_m=c["b"], radius_m=c["radius"])
            for i, c in enumerate(_random_capsule(rng, "link") for _ in range(6))
        ]
        status = ex.gateway_status(ur5=ex.robot_status(zone=zone, links=links, min_distance_m=1.5))
        FOXGLOVE.validate(json.loads(scene.robots_scene(status, T0_WALL_NS).model_dump_json()))
    for points in (2, 32, 64):  # an open robot following a plan: its path as a line
        path = rng.uniform(-2.0, 2.0, (points, 3)).tolist()
        status = ex.gateway_status(panda=ex.robot_status(plan=plan_status(path)))
        FOXGLOVE.validate(json.loads(scene.robots_scene(status, T0_WALL_NS).model_dump_json()))


def plan_status(path_m: list[list[float]] | None) -> PlanStatus:
    """An open robot's planner layer following a plan whose tool path is ``path_m`` (None: on its program)."""
    return PlanStatus(
        following=path_m is not None,
        plan_time_s=None if path_m is None else 0.2,
        plan_duration_s=None if path_m is None else 1.5,
        path_waypoints=None if path_m is None else 4,
        reason="horizon",
        requests={"horizon": 1},
        adopted=1,
        rejected=0,
        failures={},
        planning_last_s=0.1,
        path_tool_m=path_m,
    )


def test_a_plan_is_a_line_through_the_tool_s_path_and_nothing_on_the_program() -> None:
    path = [[0.5, 0.0, 1.2], [0.4, 0.3, 1.3], [0.0, 0.5, 1.3]]
    status = ex.gateway_status(panda=ex.robot_status(plan=plan_status(path)))
    update = scene.robots_scene(status, T0_WALL_NS)
    [plan] = [e for e in update.entities if e.id == "plan/panda"]
    [line] = plan.lines
    assert line.type == 0  # LINE_STRIP: 0-1, 1-2
    assert [[p.x, p.y, p.z] for p in line.points] == path
    assert plan.frame_id == scene.WORLD_FRAME
    assert {kv.key: kv.value for kv in plan.metadata} == {"reason": "horizon", "points": "3"}
    assert plan.lifetime == scene.duration(scene.ROBOT_LIFETIME_S)  # gone with the plan
    assert {e.id for e in update.entities} == {"plan/panda", "robot/panda"}
    on_program = ex.gateway_status(panda=ex.robot_status(plan=plan_status(None)))
    assert [e.id for e in scene.robots_scene(on_program, T0_WALL_NS).entities] == ["robot/panda"]


# -- the MCAP sink ---------------------------------------------------------------------------------------


def _read(path: Path) -> tuple[dict[str, str], list[tuple[str, int, bytes]], dict[str, dict[str, str]]]:
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        messages = [(c.topic, m.sequence, m.data) for _, c, m in reader.iter_messages(log_time_order=False)]
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    return channels, messages, metadata


def test_sink_writes_json_channels_with_their_schemas(tmp_path: Path) -> None:
    path = tmp_path / "a.mcap"
    channel = model_channel("hrc.gateway_status", GatewayStatus)
    with McapSink(path, metadata={"who": {"cell": "demo"}}) as sink:
        sink.declare("/declared", channel)
        assert sink.offer("/x", channel, 10, identity, b'{"a": 1}')
        assert sink.offer("/x", channel, 20, identity, b'{"a": 2}')
    channels, messages, metadata = _read(path)
    assert channels == {"/declared": "hrc.gateway_status", "/x": "hrc.gateway_status"}
    assert messages == [("/x", 0, b'{"a": 1}'), ("/x", 1, b'{"a": 2}')]
    assert metadata["who"] == {"cell": "demo"}
    assert metadata[SUMMARY_METADATA] == {"records": "2", "dropped": "0", "complete": "true", "error": ""}
    with path.open("rb") as f:
        schema = next(iter(make_reader(f).get_summary().schemas.values()))  # type: ignore[union-attr]
    assert schema.encoding == "jsonschema"
    assert json.loads(schema.data)["title"] == "GatewayStatus"


def test_sink_drops_and_counts_what_does_not_fit_never_blocks(tmp_path: Path) -> None:
    path = tmp_path / "full.mcap"
    channel = model_channel("hrc.gateway_status", GatewayStatus)
    sink = McapSink(path, max_queued=3)  # not started: nothing drains the queue yet
    accepted = [sink.offer("/x", channel, i, identity, b"{}") for i in range(5)]
    assert accepted == [True, True, True, False, False]
    summary = sink.close()
    assert (summary.records, summary.dropped, summary.complete) == (3, 2, False)
    _, messages, metadata = _read(path)
    assert [seq for _, seq, _ in messages] == [0, 1, 2]
    assert metadata[SUMMARY_METADATA]["complete"] == "false"


def test_sink_refuses_a_path_it_cannot_create(tmp_path: Path) -> None:
    (tmp_path / "file").write_text("")
    with pytest.raises(RecordingError, match="cannot create"):
        McapSink(tmp_path / "file" / "x.mcap")


# -- the gateway's own recording, replayed -----------------------------------------------------------------


def _frame(tracker: str, seq: int, t_ns: int, walked: float) -> bytes:
    """A tracker frame of one hand, ``walked`` (0 → 1) of the way from 3.5 m in front of the robot into its reach."""
    hand = HAND_FROM + min(1.0, walked) * (HAND_TO - HAND_FROM)
    capsule = {"name": "hand_r", "a": hand.tolist(), "b": hand.tolist(), "radius": 0.05}
    humans = [{"id": "h1", "capsules": [capsule]}]
    return to_payload(Humans.model_validate({"tracker": tracker, "seq": seq, "stamp_ns": t_ns, "humans": humans}))


class _Loop:
    """The gateway node fed as the process feeds it: joint states every 4 ms applying the last override,
    tracker frames at 30 Hz of a hand walking from 3.5 m toward the robot, a cycle every 4 ms."""

    def __init__(self, node: GatewayNode) -> None:
        self.node = node
        self.state_seq = 0
        self.frame_seq = 0
        self.delta = 0.0
        self.override_seq = -1
        self.q_rad = np.array(Q, dtype=float)
        self.previous_delta = 0.0

    def joint_state(self, t_ns: int) -> bytes:
        self.state_seq += 1
        if self.state_seq > 1:  # q moves as qd says over the 4 ms (the door's q_motion_inconsistent)
            self.q_rad = self.q_rad + 0.5 * (self.previous_delta + self.delta) * np.asarray(QD_NOMINAL) * 0.004
        self.previous_delta = self.delta
        message = JointState(
            robot="ur5",
            seq=self.state_seq,
            stamp_ns=t_ns,
            q=self.q_rad.tolist(),
            qd=[self.delta * v for v in QD_NOMINAL],
            qd_nominal=QD_NOMINAL,
            override=self.delta,
            override_seq=self.override_seq,
            mode="running" if self.delta > 0.0 else "stopped",
        )
        return to_payload(message)

    def frame(self, tracker: str, t_ns: int, walked: float) -> bytes:
        return _frame(tracker, self.frame_seq, t_ns, walked)

    def cycle(self, now: Clocks, period_s: float) -> None:
        cycle = self.node.cycle(now, period_s)
        self.delta, self.override_seq = cycle.overrides["ur5"].delta, cycle.seq


def _clocks(t_ns: int) -> Clocks:
    return Clocks(T0_WALL_NS + t_ns, T0_MONO_NS + t_ns)


def _run_simulated(config: CellConfig, path: Path, duration_ms: int = 3000) -> list[float]:
    """The closed loop on a simulated clock, recorded to ``path``; returns the δ of every cycle."""
    deltas = []
    with GatewayRecorder(path, config) as recorder:
        loop = _Loop(build_node(config, None, recorder))
        for t_ms in range(0, duration_ms, 4):
            t_ns = t_ms * MS
            loop.node.on_message(
                keys.robot_state("demo", "ur5"), loop.joint_state(T0_WALL_NS + t_ns - 2 * MS), _clocks(t_ns)
            )
            if t_ms % 32 == 0:
                loop.frame_seq += 1
                for tracker in sorted(config.trackers):
                    payload = loop.frame(tracker, T0_WALL_NS + t_ns - 20 * MS, t_ms / duration_ms * 1.2)
                    loop.node.on_message(keys.tracker_humans("demo", tracker), payload, _clocks(t_ns + MS))
            if t_ms == 1000:  # a hostile payload: counted, faults the topic, recorded like any input
                loop.node.on_message(keys.tracker_humans("demo", "front"), b"not json", _clocks(t_ns + 2 * MS))
            loop.cycle(_clocks(t_ns + 3 * MS), 0.004)
            deltas.append(loop.delta)
    return deltas


@pytest.fixture(scope="module")
def simulated(cell_config: CellConfig, tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list[float]]:
    path = tmp_path_factory.mktemp("rec") / "gateway.mcap"
    return path, _run_simulated(cell_config, path)


def test_the_recorded_run_goes_through_every_zone_of_delta(simulated: tuple[Path, list[float]]) -> None:
    _, deltas = simulated
    assert max(deltas) == 1.0
    assert 0.0 in deltas
    assert any(0.0 < d < 1.0 for d in deltas), "the hand passes through the reduced-speed region"


def test_recording_reads_back_in_the_order_given(simulated: tuple[Path, list[float]], cell_config: CellConfig) -> None:
    path, deltas = simulated
    recording = read_gateway_recording(path)
    assert recording.complete
    assert recording.config == cell_config
    cycles = [s for s in recording.steps if type(s).__name__ == "CycleRecord"]
    assert [c.deltas["ur5"] for c in cycles] == deltas  # type: ignore[union-attr]
    assert len(recording.steps) == len(deltas) * 2 + 2 * len(range(0, 3000, 32)) + 1


def test_replay_of_an_unchanged_gateway_reproduces_every_delta(simulated: tuple[Path, list[float]]) -> None:
    path, deltas = simulated
    recording = read_gateway_recording(path)
    report = replay(recording, recording.config)
    assert report.identical
    assert report.cycles == len(deltas)
    assert report.robots["ur5"].max_abs_delta <= 1e-9
    assert "IDENTICAL" in format_replay_report(path, recording, [], report)


def test_replay_with_a_changed_parameter_shows_where_delta_differs(simulated: tuple[Path, list[float]]) -> None:
    path, _ = simulated
    recording = read_gateway_recording(path)
    settings = ["safety.human_speed_mps=2.0"]
    report = replay(recording, apply_settings(recording.config, settings))
    ur5 = report.robots["ur5"]
    assert not report.identical
    assert ur5.differing > 0
    assert ur5.first_seq is not None
    assert ur5.max_abs_delta > 0.01
    text = format_replay_report(path, recording, settings, report)
    assert "DIFFERENT" in text
    assert f"first at cycle seq {ur5.first_seq}" in text


@pytest.mark.parametrize(
    ("setting", "says"),
    [
        ("safety.no_such_key=1", "no key 'no_such_key'"),
        ("nosection.x=1", "no section 'nosection'"),
        ("safety.human_speed_mps=-1", "human_speed_mps"),
        ("safety.human_speed_mps", "expected section.key=value"),
    ],
)
def test_bad_settings_are_refused_with_what_is_allowed(cell_config: CellConfig, setting: str, says: str) -> None:
    with pytest.raises(ConfigError, match=says):
        apply_settings(cell_config, [setting])


def test_settings_are_parsed_as_json_or_text(cell_config: CellConfig) -> None:
    changed = apply_settings(cell_config, ["safety.human_speed_mps=2", "zones.thresholds=fixed"])
    assert changed.safety.human_speed_mps == 2.0
    assert changed.zones.thresholds == "fixed"


def test_inputs_from_another_thread_replay_exactly(cell_config: CellConfig, tmp_path: Path) -> None:
    """Inputs arrive on a feeder thread while the loop cycles on the real clocks (as Zenoh callbacks do);
    the recorded order is the order the node saw them in, so the replay decides the same every cycle."""
    path = tmp_path / "threads.mcap"
    with GatewayRecorder(path, cell_config) as recorder:
        loop = _Loop(build_node(cell_config, None, recorder))
        halt = threading.Event()

        def feed() -> None:
            started_ns = time.monotonic_ns()
            while not halt.is_set():
                walked = (time.monotonic_ns() - started_ns) / 1.5e9
                loop.node.on_message(keys.robot_state("demo", "ur5"), loop.joint_state(time.time_ns()), read_clocks())
                loop.frame_seq += 1
                for tracker in sorted(cell_config.trackers):
                    payload = loop.frame(tracker, time.time_ns(), walked)
                    loop.node.on_message(keys.tracker_humans("demo", tracker), payload, read_clocks())
                time.sleep(0.003)  # pacing the feeder, not synchronisation

        feeder = threading.Thread(target=feed)
        feeder.start()
        try:
            end_s = time.monotonic() + 1.5
            while time.monotonic() < end_s:
                loop.cycle(read_clocks(), 0.004)
                time.sleep(0.002)  # pacing the loop
        finally:
            halt.set()
            feeder.join()
    recording = read_gateway_recording(path)
    report = replay(recording, recording.config)
    assert recording.complete
    assert report.cycles > 100
    assert report.inputs > 100
    assert report.identical, format_replay_report(path, recording, [], report)


def test_an_incomplete_recording_is_said_so_in_the_report(simulated: tuple[Path, list[float]]) -> None:
    path, _ = simulated
    recording = read_gateway_recording(path)
    cut = recording._replace(dropped=3, missing_after=[41])
    text = format_replay_report(path, cut, [], replay(cut, cut.config))
    assert "(INCOMPLETE)" in text
    assert "3 message(s) were dropped while recording (first gap after message 41)" in text


# -- the cell recorder (hrc-record) without Zenoh -------------------------------------------------------------


def test_cell_topics_map_to_their_schemas() -> None:
    assert topic_of("demo", "hrc/demo/robot/ur5/state").channel.schema_name == "hrc.joint_state"  # type: ignore[union-attr]
    assert topic_of("demo", "hrc/demo/truth/robot/ur5/state").channel.schema_name == "hrc.joint_state"  # type: ignore[union-attr]
    assert topic_of("demo", "hrc/demo/tracker/front/humans").scene_topic == "/scene/humans/front"  # type: ignore[union-attr]
    assert topic_of("demo", "hrc/demo/gateway/status").scene_topic == "/scene/robots"  # type: ignore[union-attr]
    assert topic_of("demo", "hrc/other/robot/ur5/state") is None
    assert topic_of("demo", "hrc/demo/robot/ur5/emu_stats") is None


def test_cell_recorder_keeps_valid_messages_verbatim_and_hostile_ones_apart(tmp_path: Path) -> None:
    path = tmp_path / "cell.mcap"
    frame = _frame("front", 1, T0_WALL_NS, 0.5)
    with McapSink(path) as sink:
        recorder = CellRecorder(sink, "demo")
        recorder.on_sample("hrc/demo/tracker/front/humans", frame, T0_WALL_NS + 5)
        recorder.on_sample("hrc/demo/robot/ur5/state", b'{"schema": "hrc.joint_state/1", "nan": NaN}', T0_WALL_NS + 6)
        recorder.on_sample("hrc/demo/robot/ur5/emu_stats", b"{}", T0_WALL_NS + 7)
    channels, messages, _ = _read(path)
    assert channels == {
        "/hrc/demo/tracker/front/humans": "hrc.humans",
        "/scene/humans/front": "foxglove.SceneUpdate",
        "/hrc/demo/rejected": "hrc.rejected",
    }
    by_topic = {topic: data for topic, _, data in messages}
    assert by_topic["/hrc/demo/tracker/front/humans"] == frame
    assert json.loads(by_topic["/scene/humans/front"])["entities"][0]["id"] == "front/h1"
    assert json.loads(by_topic["/hrc/demo/rejected"])["key"] == "hrc/demo/robot/ur5/state"
    assert recorder.unknown_keys == 1


def test_recorded_scene_messages_are_valid_against_foxglove_s_schema_in_the_file(tmp_path: Path) -> None:
    path = tmp_path / "cell.mcap"
    status = ex.gateway_status(
        ur5=ex.robot_status(
            links=[CapsuleStatus(name="tool", a_m=(0.0, 0.0, 0.8), b_m=(0.4, 0.1, 1.2), radius_m=0.05)],
            plan=plan_status([[0.4, 0.1, 1.2], [0.3, 0.4, 1.25], [0.0, 0.5, 1.2]]),  # a plan: a line
        )
    )
    lines = 0
    with McapSink(path) as sink:
        recorder = CellRecorder(sink, "demo")
        for i in range(5):
            recorder.on_sample("hrc/demo/tracker/front/humans", _frame("front", i, T0_WALL_NS, i / 4), T0_WALL_NS + i)
            recorder.on_sample("hrc/demo/gateway/status", status.model_dump_json().encode(), T0_WALL_NS + i)
    scene_messages = 0
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=["/scene/humans/front", "/scene/robots"]):
            assert schema is not None
            assert (schema.name, schema.encoding, channel.message_encoding) == (
                "foxglove.SceneUpdate",
                "jsonschema",
                "json",
            )
            assert json.loads(schema.data) == scene.foxglove_schema()
            Draft202012Validator(json.loads(schema.data)).validate(json.loads(message.data))
            scene_messages += 1
            lines += sum(len(e["lines"]) for e in json.loads(message.data)["entities"])
    assert scene_messages == 10
    assert lines == 5  # the plan's line in each status's scene


def test_the_event_log_is_recorded_at_its_arrival_not_before_the_first_message(tmp_path: Path) -> None:
    """The first poll of the gateway's log brings the events since it started, 40 s before: their ``log_time`` is
    the poll's answer, so the file's log times do not go backwards; ``stamp_ns`` keeps when each was logged."""
    path = tmp_path / "cell.mcap"
    started_ns = T0_WALL_NS - 40 * 10**9
    events = EventLog().started(started_ns, "demo", "c" * 64)
    with McapSink(path) as sink:
        recorder = CellRecorder(sink, "demo")
        recorder.on_sample("hrc/demo/tracker/front/humans", _frame("front", 1, T0_WALL_NS, 0.0), T0_WALL_NS)
        recorder.on_events(events, T0_WALL_NS + 500 * MS)
    with path.open("rb") as f:
        records = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(f).iter_messages(log_time_order=False)]
    log_times = [log_time for _, log_time, _ in records]
    assert log_times == sorted(log_times), "log times in file order never go backwards"
    assert min(log_times) == T0_WALL_NS, "the recording starts with its first live message"
    logged = [Event.model_validate_json(data) for topic, _, data in records if topic == "/hrc/demo/gateway/events"]
    assert [e.stamp_ns for e in logged] == [started_ns, started_ns]


def test_a_recording_cut_short_replays_what_was_written(simulated: tuple[Path, list[float]], tmp_path: Path) -> None:
    """A gateway killed while recording leaves no footer: every chunk before the cut still replays exactly."""
    path, deltas = simulated
    cut = tmp_path / "cut.mcap"
    data = path.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])
    recording = read_gateway_recording(cut)
    assert recording.truncated is not None
    assert not recording.complete
    report = replay(recording, recording.config)
    assert 0 < report.cycles < len(deltas)
    assert report.identical
    assert "the file ends before its footer" in format_replay_report(cut, recording, [], report)


def test_a_file_that_is_not_mcap_is_refused(tmp_path: Path) -> None:
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all")
    with pytest.raises(RecordingError, match="not an MCAP file"):
        read_gateway_recording(junk)


def test_the_recorders_writer_runs_under_fifo_at_the_io_priority(
    tmp_path: Path, cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """It takes the interpreter lock for every record: at normal scheduling another program could deschedule it while
    it held the lock, and the loop waited (the 60-minute soak's 'blocked' stalls had the writer waiting for a CPU)."""
    seen: list[tuple[str, int, int]] = []
    real = recording.use_realtime_scheduling

    def spy(priority: int, thread: str, logger: logging.Logger) -> bool:
        ok = real(priority, thread, logger)
        seen.append((threading.current_thread().name, os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))
        return ok

    monkeypatch.setattr(recording, "use_realtime_scheduling", spy)
    recording.GatewayRecorder(tmp_path / "fifo.mcap", cell_config, realtime_priority=4).close()
    assert seen == [("mcap-writer", os.SCHED_FIFO, 4)]
    seen.clear()
    recording.GatewayRecorder(tmp_path / "normal.mcap", cell_config).close()
    assert seen == []  # priority 0: the writer keeps normal scheduling, nothing is asked
