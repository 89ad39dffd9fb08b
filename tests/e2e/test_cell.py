"""End to end: the three real programs over loopback Zenoh, watched through the real REST API."""

from __future__ import annotations

import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh
from support.paths import REPO_ROOT

from hrc_contract import keys
from hrc_contract.messages import JointState, parse_message
from hrc_contract.status_models import EffectiveConfig, GatewayStatus
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import (
    collapse,
    is_subsequence,
    load_scale,
    record,
    running_cell,
    scenario_window_s,
    stop_program,
    write_cell_config,
)

pytestmark = pytest.mark.e2e

SCENARIO_S = 31.0  # walk_in_reach_leave: nobody, walk in, reach in, leave, nobody
ZONE_SEQUENCE = ["autonomous", "guarded_distance", "reduced_speed", "safety_exception", "autonomous"]


def _cell_config_with_tracker_latency(tmp_path: Path, extra_latency_s: float) -> Path:
    """A copy of the default cell whose trackers publish ``extra_latency_s`` later than by default."""
    text = (REPO_ROOT / "configs" / "cell.toml").read_text()
    lines = []
    for line in text.splitlines():
        if line.startswith("latency_s"):
            nominal_s = float(line.split("=")[1].split("#")[0])
            line = f"latency_s = {nominal_s + extra_latency_s}"
        lines.append(line)
    text = "\n".join(lines).replace('model = "robots/', f'model = "{REPO_ROOT}/configs/robots/')
    text = text.replace('program = "programs/', f'program = "{REPO_ROOT}/configs/programs/')
    text = text.replace('scenarios_dir = "scenarios"', f'scenarios_dir = "{REPO_ROOT}/configs/scenarios"')
    text = text.replace('pfl_body_regions = "', f'pfl_body_regions = "{REPO_ROOT}/configs/')
    path = tmp_path / "cell.toml"
    path.write_text(text)
    return path


def _back_to_autonomous_for(hold_s: float) -> Callable[[list[dict[str, Any]]], bool]:
    """Stop recording once the robot has been autonomous for ``hold_s`` after the person made a safety exception
    (not one from a transient fault of a loaded machine: that would end the recording before the approach)."""

    def done(trace: list[dict[str, Any]]) -> bool:
        exceptions = [
            s["t_s"]
            for s in trace
            if s["zone"] == "safety_exception" and not s["faults"] and s["min_distance_m"] is not None
        ]
        if not exceptions or trace[-1]["zone"] != "autonomous":
            return False
        since = [s for s in trace if s["t_s"] > exceptions[-1] and s["zone"] != "autonomous"]
        last_busy = since[-1]["t_s"] if since else exceptions[-1]
        return trace[-1]["t_s"] - last_busy > hold_s

    return done


def _run_scenario(tmp_path: Path, config: Path | None) -> list[dict[str, Any]]:
    with running_cell(tmp_path, config=config) as cell:
        cell.wait_until(lambda s: s["zone"] == "autonomous" and not s["faults"], 20.0, "a fault-free autonomous cell")
        trace = record(cell, scenario_window_s(SCENARIO_S), until=_back_to_autonomous_for(2.0))
        for name, proc in (("gateway", cell.gateway), ("controller", cell.controller), ("tracker", cell.tracker)):
            assert proc.poll() is None, f"{name} died during the run\n{cell.tail()}"
    return trace


@pytest.fixture(scope="module")
def nominal_trace(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    return _run_scenario(tmp_path_factory.mktemp("nominal"), None)


@pytest.fixture(scope="module")
def delayed_trace(tmp_path_factory: pytest.TempPathFactory) -> list[dict[str, Any]]:
    tmp = tmp_path_factory.mktemp("delayed")
    return _run_scenario(tmp, _cell_config_with_tracker_latency(tmp, 0.1))


def test_zone_sequence_as_the_human_comes_and_goes(nominal_trace: list[dict[str, Any]]) -> None:
    zones = collapse([s["zone"] for s in nominal_trace])
    assert is_subsequence(ZONE_SEQUENCE, zones), zones


def test_delta_falls_on_approach_and_returns_to_one(nominal_trace: list[dict[str, Any]]) -> None:
    present = [s for s in nominal_trace if s["min_distance_m"] is not None]
    assert present, "nobody was ever seen"
    far = [s["delta"] for s in present if s["min_distance_m"] > 3.0]
    near = [s["delta"] for s in present if s["min_distance_m"] < 1.0]
    assert far
    assert near
    assert statistics.mean(near) < 0.05 < 0.9 < statistics.mean(far)
    closest = min(present, key=lambda s: s["min_distance_m"])
    assert closest["zone"] == "safety_exception"
    assert closest["delta"] == 0.0
    assert closest["closest"]["human"].endswith("h1")
    after = [s for s in nominal_trace if s["t_s"] > closest["t_s"] and s["zone"] == "autonomous"]
    assert after
    assert all(s["delta"] == 1.0 for s in after[-5:])
    # The gateway never commanded more than the math allowed, and nothing faulted.
    assert all(s["delta"] <= s["delta_bound"] + 1e-9 for s in nominal_trace)
    assert not [s for s in nominal_trace if s["faults"]]


def test_injected_tracker_delay_raises_t_delay_and_lowers_delta(
    nominal_trace: list[dict[str, Any]], delayed_trace: list[dict[str, Any]]
) -> None:
    def human_age(trace: list[dict[str, Any]]) -> float:
        return statistics.median(s["delay_budget_s"]["human_age_s"] for s in trace)

    def t_delay(trace: list[dict[str, Any]]) -> float:
        return statistics.median(s["t_delay_s"] for s in trace)

    assert human_age(delayed_trace) > human_age(nominal_trace) + 0.08  # the injected 0.1 s reaches the budget
    # t_delay is the sum of the budget's parts, the frame age among them; its other parts (joint-state age, the
    # loop's interval) vary with the machine's load between the two runs (CI of stop 19: medians +0.053 s only, with
    # the frame age +0.08 s or more), so the sums are compared without the injected margin.
    for trace in (nominal_trace, delayed_trace):
        assert all(s["t_delay_s"] >= s["delay_budget_s"]["human_age_s"] - 1e-9 for s in trace)
    assert t_delay(delayed_trace) > t_delay(nominal_trace)
    # Larger delay → larger clearance → the robot is stopped from farther away.
    clearance = {
        name: statistics.median(s["clearance_m"] for s in tr)
        for name, tr in (("nominal", nominal_trace), ("delayed", delayed_trace))
    }
    assert clearance["delayed"] > clearance["nominal"]
    # That a larger delay gives no larger δ at the same geometry is tested where the geometry is the same
    # (tests/gateway/test_core.py, test_older_human_data_gives_larger_delay_and_no_larger_delta). Between these two
    # runs it is not: eq. (15) divides by the robot's speed toward the person, which depends on where the program
    # was when the person came, and that depends on the start-up (the mean δ at the same distances, once ~0.55
    # against ~0.75, was 0.72 against 0.75 in the CI run of stop 19, and failed this test).


def test_garbage_on_every_topic_is_counted_and_survived(tmp_path: Path) -> None:
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        cell.wait_until(lambda s: not s["faults"], 20.0, "a fault-free cell")
        garbage = [b"not json", b'{"schema": "hrc.humans/1", "x": NaN}', b"[1, 2]", b"{}", b"\xff\xfe"]
        with zenoh.open(session_config(connect=[cell.gateway_endpoint])) as session:
            time.sleep(0.5)
            for key in (
                keys.robot_state("demo", "ur5"),
                keys.tracker_humans("demo", "front"),
                keys.robot_state("demo", "ghost"),
                keys.tracker_humans("demo", "ghost"),
            ):
                for payload in garbage:
                    session.put(key, payload)
            time.sleep(0.5)
        status = cell.get("/api/v1/status").json()
        rejected = status["inputs"]["rejected"]
        assert sum(rejected["robot/ur5"].values()) >= len(garbage)
        assert sum(rejected["tracker/front"].values()) >= len(garbage)
        assert rejected["robot/ghost"] == {"unknown_robot": len(garbage)}
        assert rejected["tracker/ghost"] == {"unknown_tracker": len(garbage)}
        assert rejected["robot/ur5"]["not_json"] >= 2
        assert rejected["robot/ur5"]["non_finite"] >= 1
        # Valid data resumes: the faults clear by themselves and the programs are alive.
        cell.wait_until(lambda s: not s["faults"], 5.0, "faults to clear after the garbage")
        assert cell.gateway.poll() is None
        assert cell.controller.poll() is None


def test_controller_stops_on_its_own_when_the_gateway_is_killed(tmp_path: Path) -> None:
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        cell.wait_until(lambda s: s["controller_mode"] == "running" and s["delta"] > 0, 20.0, "a moving robot")
        states: list[JointState] = []
        with zenoh.open(session_config(connect=[cell.controller_endpoint])) as session:
            session.declare_subscriber(
                keys.robot_state("demo", "ur5"),
                lambda sample: states.append(parse_message(sample.payload.to_bytes(), JointState)),
            )
            time.sleep(0.5)
            assert states
            assert states[-1].mode == "running"
            cell.gateway.send_signal(signal.SIGKILL)
            cell.gateway.wait(5)
            killed_ns = time.time_ns()
            time.sleep(1.5)
        after = [s for s in states if s.stamp_ns > killed_ns]
        stopped = [s for s in after if s.mode == "protective_stop" and s.override == 0.0]
        assert stopped, f"no protective stop after the gateway died; modes: {collapse([s.mode for s in after])}"
        assert (stopped[0].stamp_ns - killed_ns) / 1e9 < 0.6  # watchdog 0.1 s + braking 0.24 s + margin
        assert all(abs(v) < 1e-12 for v in stopped[-1].qd)
        # The HTTP child went with its parent.
        deadline = time.monotonic() + 5.0 * load_scale()
        while time.monotonic() < deadline:
            try:
                cell.get("/healthz")
            except Exception:
                break
            time.sleep(0.1)
        else:
            pytest.fail("the HTTP server outlived the killed gateway")


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_every_program_exits_cleanly_on_signal(tmp_path: Path, sig: int) -> None:
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        cell.wait_until(lambda s: not s["faults"], 20.0, "a fault-free cell")
        codes = {
            name: stop_program(proc, sig)
            for name, proc in (("tracker", cell.tracker), ("controller", cell.controller), ("gateway", cell.gateway))
        }
    assert codes == {"tracker": 0, "controller": 0, "gateway": 0}, cell.tail()


def test_gateway_refuses_an_unsafe_config_with_one_line(tmp_path: Path) -> None:
    config = _cell_config_with_tracker_latency(tmp_path, 0.0)
    config.write_text(config.read_text().replace("human_speed_mps = 1.6", "human_speed_mps = 1.2"))
    result = subprocess.run(
        [sys.executable, "-m", "gateway", "--config", str(config)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "human_speed_mps" in lines[0], result.stderr
    assert "1.6" in lines[0], result.stderr


def test_status_is_also_published_on_zenoh(tmp_path: Path) -> None:
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        cell.wait_until(lambda s: not s["faults"], 20.0, "a fault-free cell")
        payloads: list[bytes] = []
        with zenoh.open(session_config(connect=[cell.gateway_endpoint])) as session:
            session.declare_subscriber(keys.gateway_status("demo"), lambda s: payloads.append(s.payload.to_bytes()))
            time.sleep(1.0)
        assert len(payloads) >= 10  # 25 Hz
        docs = [GatewayStatus.model_validate_json(p) for p in payloads]  # every one is the contract's document
        assert docs[-1].robots["ur5"].zone in {"guarded_distance", "reduced_speed", "safety_exception"}
        assert docs[-1].loop.cycles > docs[0].loop.cycles
        served = GatewayStatus.model_validate_json(cell.get("/api/v1/status").content)
        assert served.stamp_ns >= docs[0].stamp_ns
        config = EffectiveConfig.model_validate_json(cell.get("/api/v1/config").content)
        assert len(config.config_sha256) == 64
        assert config.robots["ur5"].urdf.endswith("ur5_robot.urdf")


def test_packed_tracker_frames_run_the_cell_end_to_end(tmp_path: Path) -> None:
    """The tracker emulator writes every tracker's frames packed (``wire = "packed"``, hrc.humans_packed/1); the
    gateway admits them on the same keys: the person standing inside is seen by every tracker, nothing is refused,
    and a broken packed frame is counted and survived like broken JSON."""
    config = load_cell_config(None)
    packed = {name: t.model_copy(update={"wire": "packed"}) for name, t in config.trackers.items()}
    path = write_cell_config(config.model_copy(update={"trackers": packed}), tmp_path / "cell.toml")
    with running_cell(tmp_path, config=path, scenario="standing_inside") as cell:
        cell.wait_until(lambda s: not s["faults"] and s["min_distance_m"] is not None, 20.0, "a person seen, no fault")
        status = cell.get("/api/v1/status").json()
        for name in config.trackers:
            assert status["inputs"]["received"][f"tracker/{name}"] > 0
            assert f"tracker/{name}" not in status["inputs"]["rejected"]
        assert {h["tracker"] for h in status["humans"]} == set(config.trackers)
        with zenoh.open(session_config(connect=[cell.gateway_endpoint])) as session:
            time.sleep(0.5)
            session.put(keys.tracker_humans(config.cell, "front"), b"\x81\xa6schema")  # a packed map cut short
            time.sleep(0.5)
        rejected = cell.get("/api/v1/status").json()["inputs"]["rejected"]
        assert rejected["tracker/front"] == {"not_msgpack": 1}
        cell.wait_until(lambda s: not s["faults"], 5.0, "the fault to clear after the broken frame")
        assert cell.gateway.poll() is None
