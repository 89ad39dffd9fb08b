"""Recording the real default cell and replaying the gateway's own recording (issue 11, "Recording").

One module-wide run: gateway (``--record``), controller emulator, tracker emulator (the default scenario: a
person walks in) and ``hrc-record``, until the gateway has slowed the robot for the approaching person; then
SIGINT to each. The cell recording opens with the ``mcap`` reader with every channel and its schema; the
gateway's recording, replayed by ``hrc-replay``, gives back every δ, and with a changed parameter does not.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from mcap.reader import make_reader
from support.paths import REPO_ROOT

from hrc_contract.status_models import Event, GatewayStatus
from hrc_tools.cell.procs import Cell, free_endpoint, free_port, stop_program

pytestmark = pytest.mark.e2e

START_TIMEOUT_S = 40.0
CELL = "demo"


@dataclass(frozen=True)
class Recorded:
    cell_mcap: Path
    gateway_mcap: Path
    exit_codes: dict[str, int]
    tail: str


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Recorded]:
    tmp = tmp_path_factory.mktemp("recording")
    gw_ep, ctrl_ep, http_port = free_endpoint(), free_endpoint(), free_port()
    cell_mcap, gateway_mcap = tmp / "cell.mcap", tmp / "gateway.mcap"
    commands = {
        "gateway": (
            "gateway",
            ["--zenoh-listen", gw_ep, "--http-port", str(http_port), "--record", str(gateway_mcap)],
        ),
        "recorder": (
            "hrc_tools.record",
            ["--zenoh-connect", gw_ep, "--output", str(cell_mcap), "--events-url", f"http://127.0.0.1:{http_port}"],
        ),
        "controller": ("controller_emu", ["--zenoh-listen", ctrl_ep, "--zenoh-connect", gw_ep]),
        "tracker": ("tracker_emu", ["--zenoh-connect", gw_ep, "--seed", "0"]),
    }
    cell = Cell({}, commands, http_port, gw_ep, ctrl_ep, {name: tmp / f"{name}.log" for name in commands})
    codes: dict[str, int] = {}
    try:
        for name in ("gateway", "controller"):
            cell.start(name)
        # the person walks in 3 s after the tracker starts: not before the gateway hears the controller; the
        # recorder, a Zenoh client of the gateway, needs it listening
        cell.wait_until(lambda s: s["delta_applied"] is not None, START_TIMEOUT_S, "the controller's joint states")
        cell.start("recorder")
        cell.start("tracker")
        cell.wait_until(lambda s: 0.0 < s["delta"] < 1.0, START_TIMEOUT_S, "δ slowed for the approaching person")
        cell.wait_until(lambda s: s["delta"] < 0.5, 10.0, "δ lower as the person comes closer")
        for name in ("recorder", "gateway"):  # SIGINT: each closes its file
            codes[name] = stop_program(cell.procs[name])
        yield Recorded(cell_mcap, gateway_mcap, codes, cell.tail())
    finally:
        for proc in cell.procs.values():
            if proc.poll() is None:
                stop_program(proc)


def _channels(path: Path) -> tuple[dict[str, tuple[str, str, str]], dict[str, list[bytes]]]:
    """topic → (message encoding, schema name, schema encoding); topic → message payloads."""
    with path.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "no summary: the file was not closed"
        channels = {
            c.topic: (c.message_encoding, summary.schemas[c.schema_id].name, summary.schemas[c.schema_id].encoding)
            for c in summary.channels.values()
        }
        messages: dict[str, list[bytes]] = {}
        for _, channel, message in reader.iter_messages():
            messages.setdefault(channel.topic, []).append(message.data)
    return channels, messages


def test_programs_close_their_recordings_on_ctrl_c(recorded: Recorded) -> None:
    assert recorded.exit_codes == {"recorder": 0, "gateway": 0}, recorded.tail


def test_cell_recording_has_every_channel_with_its_schema(recorded: Recorded) -> None:
    channels, messages = _channels(recorded.cell_mcap)
    expected = {
        f"/hrc/{CELL}/robot/ur5/state": "hrc.joint_state",
        f"/hrc/{CELL}/robot/ur5/override": "hrc.override",
        f"/hrc/{CELL}/tracker/front/humans": "hrc.humans",
        f"/hrc/{CELL}/tracker/side/humans": "hrc.humans",
        f"/hrc/{CELL}/gateway/status": "hrc.gateway_status",
        f"/hrc/{CELL}/gateway/events": "hrc.event",
        "/scene/humans/front": "foxglove.SceneUpdate",
        "/scene/robots": "foxglove.SceneUpdate",
    }
    for topic, schema_name in expected.items():
        assert topic in channels, f"{topic} missing; channels: {sorted(channels)}\n{recorded.tail}"
        assert channels[topic] == ("json", schema_name, "jsonschema")
        assert messages.get(topic), f"no message on {topic}"
    for topic, payloads in messages.items():
        for payload in payloads:
            assert isinstance(json.loads(payload), dict), topic
    status = GatewayStatus.model_validate_json(messages[f"/hrc/{CELL}/gateway/status"][-1])
    assert status.robots["ur5"].links, "the status carries the link capsules the scene draws"
    kinds = {Event.model_validate_json(p).kind for p in messages[f"/hrc/{CELL}/gateway/events"]}
    assert "start" in kinds
    scene = [json.loads(p) for p in messages["/scene/humans/front"]]
    assert any(e["id"] == "front/h1" and e["cylinders"] for doc in scene for e in doc["entities"])


def _replay(path: Path, *settings: str) -> subprocess.CompletedProcess[str]:
    args = [sys.executable, "-m", "hrc_tools.record.replay", str(path)]
    for setting in settings:
        args += ["--set", setting]
    return subprocess.run(args, capture_output=True, text=True, cwd=REPO_ROOT, timeout=120, check=False)


def test_gateway_recording_has_its_channels(recorded: Recorded) -> None:
    channels, messages = _channels(recorded.gateway_mcap)
    assert {t: c[1] for t, c in channels.items()} == {
        "/gateway/config": "hrc.cell_config",
        "/gateway/input": "hrc.gateway_input",
        "/gateway/internal_error": "hrc.gateway_internal_error",
        "/gateway/cycle": "hrc.gateway_cycle",
    }
    assert len(messages["/gateway/cycle"]) > 1000  # 250 Hz for several seconds


def test_replaying_the_gateway_reproduces_its_overrides(recorded: Recorded) -> None:
    result = _replay(recorded.gateway_mcap)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "IDENTICAL" in result.stdout
    assert "(INCOMPLETE)" not in result.stdout
    assert "robot ur5:" in result.stdout


def test_replaying_with_a_changed_parameter_shows_the_differences(recorded: Recorded) -> None:
    result = _replay(recorded.gateway_mcap, "safety.human_speed_mps=2.0")
    assert result.returncode == 1, result.stdout + result.stderr
    assert "DIFFERENT" in result.stdout
    assert "changed: safety.human_speed_mps=2.0" in result.stdout
    assert "cycles differ; first at cycle seq" in result.stdout


def test_replay_refuses_a_file_that_is_not_a_gateway_recording(recorded: Recorded, tmp_path: Path) -> None:
    result = _replay(recorded.cell_mcap)
    assert result.returncode == 2
    assert "not a gateway recording" in result.stderr
    (tmp_path / "junk.mcap").write_bytes(b"junk")
    result = _replay(tmp_path / "junk.mcap")
    assert result.returncode == 2
    assert "not an MCAP file" in result.stderr
