"""The tracker emulator as a process over loopback Zenoh: rates, seq, capture stamps, liveliness, exits; occlusion by
the robot whose true joint state it follows."""

from __future__ import annotations

import math
import re
import shutil
import signal
import subprocess
import sys
import time
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import zenoh
from support.paths import REPO_ROOT

from hrc_contract import keys
from hrc_contract.messages import Humans, JointState, parse_message, to_payload
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_endpoint, start_program, stop_all, stop_program, wait_or_fail
from tracker_emu.scenario import available_scenarios

pytestmark = pytest.mark.e2e

LATENCY_S = 0.1
COLLECT_S = 3.0


def cell_with_latency(tmp_path: Path, latency_s: float) -> tuple[Path, str]:
    """A copy of configs/ whose first tracker has the given latency. Returns (cell file, that tracker)."""
    configs = tmp_path / "configs"
    shutil.copytree(REPO_ROOT / "configs", configs)
    cell_path = configs / "cell.toml"
    tracker = next(iter(load_cell_config(cell_path).trackers))
    text, count = re.subn(
        rf"(\[trackers\.{tracker}\][^\[]*?latency_s\s*=\s*)[0-9.eE+-]+",
        rf"\g<1>{latency_s}",
        cell_path.read_text(),
    )
    assert count == 1, "configs/cell.toml: cannot find the latency_s of the first tracker"
    cell_path.write_text(text)
    assert load_cell_config(cell_path).trackers[tracker].latency_s == latency_s
    return cell_path, tracker


def test_publishes_every_tracker_at_its_rate_with_capture_stamps(tmp_path: Path) -> None:
    cell_path, slow_tracker = cell_with_latency(tmp_path, LATENCY_S)
    config = load_cell_config(cell_path)
    endpoint = free_endpoint()
    log_path = tmp_path / "tracker.log"
    proc = start_program(
        "tracker_emu",
        ["--config", str(cell_path), "--scenario", "standing_inside", "--zenoh-listen", endpoint, "--seed", "1"],
        log_path,
    )
    received: list[tuple[int, str, bytes]] = []  # (receive time [ns], key, payload)
    try:
        with zenoh.open(session_config(connect=[endpoint])) as session:
            subscriber = session.declare_subscriber(
                f"hrc/{config.cell}/tracker/*/humans",
                lambda sample: received.append((time.time_ns(), str(sample.key_expr), sample.payload.to_bytes())),
            )
            wait_or_fail(
                lambda: len({key for _, key, _ in received}) == len(config.trackers),
                10.0,
                "a frame of every tracker",
                [log_path],
                [proc],
            )
            collected_from = len(received)
            time.sleep(COLLECT_S)
            alive = [
                str(reply.ok.key_expr)
                for reply in session.liveliness().get(keys.alive(config.cell, "tracker-emu"), timeout=2.0)
                if reply.ok is not None
            ]
            del subscriber
        assert alive == [keys.alive(config.cell, "tracker-emu")]
        assert stop_program(proc, signal.SIGINT, timeout_s=5.0) == 0
    finally:
        stop_all([proc])

    by_tracker: dict[str, list[tuple[int, Humans]]] = defaultdict(list)
    for recv_ns, key, payload in received[collected_from:]:
        message = parse_message(payload, Humans)
        assert key == keys.tracker_humans(config.cell, message.tracker)
        by_tracker[message.tracker].append((recv_ns, message))
    assert set(by_tracker) == set(config.trackers)
    for name, tracker in config.trackers.items():
        frames = by_tracker[name]
        recv_s = np.array([r for r, _ in frames]) / 1e9
        rate_hz = (len(frames) - 1) / (recv_s[-1] - recv_s[0])
        assert rate_hz == pytest.approx(tracker.rate_hz, rel=0.3), name
        seqs = np.array([m.seq for _, m in frames])
        assert np.all(np.diff(seqs) >= 1), name
        assert np.mean(np.diff(seqs) == 1) > 0.95, name  # seq counts published frames, drops included
        ages_s = np.array([(r - m.stamp_ns) / 1e9 for r, m in frames])
        assert np.min(ages_s) >= tracker.latency_s - 0.01, name  # stamped at capture, not at publication
        assert np.median(ages_s) < tracker.latency_s + 0.05, name
        assert all(len(m.humans) == 1 and len(m.humans[0].capsules) >= 13 for _, m in frames), name
    slow_ages_s = [(r - m.stamp_ns) / 1e9 for r, m in by_tracker[slow_tracker]]
    assert min(slow_ages_s) >= 0.09
    log = log_path.read_text()
    assert "playing scenario 'standing_inside'" in log
    assert "stopped;" in log


def _refused(*args: str) -> str:
    """The one line the tracker emulator writes on stderr when it refuses ``args`` (exit code 2)."""
    command = [sys.executable, "-m", "tracker_emu", *args, "--zenoh-listen", "tcp/127.0.0.1:1"]
    result = subprocess.run(command, capture_output=True, text=True, cwd=REPO_ROOT, timeout=30)
    assert result.returncode == 2
    message = result.stderr.strip()
    assert "\n" not in message
    assert message.startswith("hrc-tracker-emu: ")
    return message


def test_unknown_scenario_exits_2_listing_the_scenarios() -> None:
    message = _refused("--scenario", "nope")
    assert "unknown scenario 'nope'" in message
    for name in available_scenarios(REPO_ROOT / "configs" / "scenarios"):
        assert name in message


def test_unknown_tracker_exits_2_listing_the_trackers() -> None:
    message = _refused("--tracker", "nope")
    assert "unknown tracker 'nope'" in message
    for name in load_cell_config(None).trackers:
        assert name in message


BEHIND_ARM_SCENARIO = """description = "one person standing 1.5 m behind the robot"
duration_s = 60.0
loop = true

[[humans]]
id = "h1"

[[humans.keyframes]]
t_s = 0.0
xy_m = [-1.5, 0.0]
heading_rad = 0.0

[[humans.keyframes]]
t_s = 60.0
xy_m = [-1.5, 0.0]
heading_rad = 0.0
"""
NEAR_TRACKER = """[trackers.near]
rate_hz = 30.0
noise_std_m = 0.0
position_m = [0.15, 0.0, 1.3]   # 0.15 m in front of the UR5's arm when it points straight up
occlusion = true
"""
Q_ARM_UP_RAD = [0.0, -math.pi / 2, 0.0, -math.pi / 2, 0.0, 0.0]
Q_ARM_OUT_RAD = [0.0] * 6


def cell_with_a_sensor_by_the_arm(tmp_path: Path) -> Path:
    """A copy of configs/ whose only tracker sees from just in front of the UR5's raised arm, and a scenario
    ``behind_arm`` with a person standing behind the robot. Returns the cell file."""
    configs = tmp_path / "configs"
    shutil.copytree(REPO_ROOT / "configs", configs)
    cell_path = configs / "cell.toml"
    text = cell_path.read_text()
    cell_path.write_text(text[: text.index("[trackers.")] + NEAR_TRACKER)
    (configs / "scenarios" / "behind_arm.toml").write_text(BEHIND_ARM_SCENARIO)
    return cell_path


def truth_state(q_rad: list[float], seq: int) -> bytes:
    zeros = [0.0] * len(q_rad)
    return to_payload(
        JointState(
            robot="ur5",
            seq=seq,
            stamp_ns=time.time_ns(),
            q=q_rad,
            qd=zeros,
            qd_nominal=zeros,
            override=0.0,
            override_seq=-1,
            mode="stopped",
        )
    )


def test_the_running_emulator_hides_a_person_behind_the_robot_it_follows(tmp_path: Path) -> None:
    cell_path = cell_with_a_sensor_by_the_arm(tmp_path)
    config = load_cell_config(cell_path)
    endpoint = free_endpoint()
    log_path = tmp_path / "tracker.log"
    proc = start_program(
        "tracker_emu",
        ["--config", str(cell_path), "--scenario", "behind_arm", "--zenoh-listen", endpoint],
        log_path,
    )
    frames: list[Humans] = []
    seq = 0
    try:
        with zenoh.open(session_config(connect=[endpoint])) as session:
            subscriber = session.declare_subscriber(
                keys.tracker_humans(config.cell, "near"),
                lambda sample: frames.append(parse_message(sample.payload.to_bytes(), Humans)),
            )
            publisher = session.declare_publisher(keys.truth_robot_state(config.cell, "ur5"))

            def newest_ids_after(q_rad: list[float] | None) -> Callable[[], list[str] | None]:
                start = len(frames)

                def newest() -> list[str] | None:
                    nonlocal seq
                    if q_rad is not None:  # the controller emulator publishes its true state every cycle
                        seq += 1
                        publisher.put(truth_state(q_rad, seq))
                    return [h.id for h in frames[-1].humans] if len(frames) > start + 3 else None

                return newest

            # No robot state yet: the robot hides nothing.
            nobody_known = newest_ids_after(None)
            wait_or_fail(lambda: nobody_known() == ["h1"], 10.0, "the person, seen", [log_path], [proc])
            arm_up = newest_ids_after(Q_ARM_UP_RAD)
            wait_or_fail(lambda: arm_up() == [], 10.0, "the person, hidden by the raised arm", [log_path], [proc])
            arm_out = newest_ids_after(Q_ARM_OUT_RAD)
            wait_or_fail(lambda: arm_out() == ["h1"], 10.0, "the person, seen again", [log_path], [proc])
            del subscriber  # (the publisher goes with the session)
        assert stop_program(proc, signal.SIGINT, timeout_s=5.0) == 0
    finally:
        stop_all([proc])
    assert "occlusion from (0.15, 0.0, 1.3)" in log_path.read_text()
