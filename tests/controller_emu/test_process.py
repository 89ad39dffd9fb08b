"""The controller emulator as a process over loopback Zenoh: the test plays the gateway."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import zenoh
from support.paths import REPO_ROOT
from support.recorder import Recorder

from hrc_contract import keys
from hrc_contract.messages import JointState, Override, parse_message, to_payload
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import Program, free_endpoint, load_scale, start_program, stop_all, wait_or_fail

pytestmark = pytest.mark.e2e

CELL, ROBOT = "demo", "ur5"
OVERRIDE_PERIOD_S = 0.004

GARBAGE = [
    b"not json at all",
    b'{"schema": "hrc.override/1", "robot": "ur5", "seq": 1, "stamp_ns": 1, "delta": NaN}',
    b'{"schema": "hrc.override/1", "robot": "ur5", "seq": 1, "stamp_ns": 1, "delta": 0.5, "extra": 1}',
    b'{"schema": "hrc.override/2", "robot": "ur5", "seq": 1, "stamp_ns": 1, "delta": 0.5}',
    b'{"schema": "hrc.override/1", "robot": "ur5", "seq": 1, "stamp_ns": 1, "delta": 1.5}',
    b"[1, 2, 3]",
    b"\xff\xfe",
]


WATCHDOG_S = 0.1  # configs/cell.toml's controller


def _at_full_speed(state: JointState | None) -> bool:
    return state is not None and state.mode == "running" and state.override == 1.0


def _running_stretches(states: list[JointState]) -> list[list[JointState]]:
    """The runs of consecutive states in mode ``running``."""
    stretches: list[list[JointState]] = [[]]
    for state in states:
        if state.mode == "running":
            stretches[-1].append(state)
        elif stretches[-1]:
            stretches.append([])
    return [s for s in stretches if s]


def _watchdog_stops(states: list[JointState]) -> list[float]:
    """Per change from ``running`` to ``protective_stop``: the longest the override in force can then have been the
    newest [s]: from the stamp of the last state before its seq was first reported (it was accepted after that
    cycle, or that cycle would have applied it) to the stop's stamp. The watchdog must not fire before this is
    longer than its time."""
    silences = []
    for k in range(1, len(states)):
        if states[k].mode == "protective_stop" and states[k - 1].mode == "running":
            first = k - 1
            while first > 0 and states[first - 1].override_seq == states[k - 1].override_seq:
                first -= 1
            if first > 0:
                silences.append((states[k].stamp_ns - states[first - 1].stamp_ns) / 1e9)
    return silences


@pytest.fixture
def controller(tmp_path: Path) -> Iterator[tuple[Program, str, Path]]:
    endpoint = free_endpoint()
    log_path = tmp_path / "controller.log"
    proc = start_program("controller_emu", ["--zenoh-listen", endpoint], log_path)
    try:
        yield proc, endpoint, log_path
    finally:
        stop_all([proc])


def test_controller_follows_overrides_and_stops_on_its_own(
    controller: tuple[Program, str, Path],
) -> None:
    proc, endpoint, log_path = controller
    states = Recorder(lambda payload: parse_message(payload, JointState))
    stats = Recorder(json.loads)
    with zenoh.open(session_config(connect=[endpoint])) as session:
        state_sub = session.declare_subscriber(keys.robot_state(CELL, ROBOT), states.on_sample)
        stats_sub = session.declare_subscriber(keys.robot_emu_stats(CELL, ROBOT), stats.on_sample)
        pub = session.declare_publisher(keys.robot_override(CELL, ROBOT), express=True)

        # Before any override: joint states flow, the robot is in a protective stop.
        wait_or_fail(lambda: len(states.items()) >= 10, 15.0, "joint states", [log_path])
        first: JointState = states.latest()
        assert (first.mode, first.override, first.override_seq) == ("protective_stop", 0.0, -1)
        alive = list(session.liveliness().get(keys.alive(CELL, f"controller-{ROBOT}"), timeout=2.0))
        assert [str(reply.ok.key_expr) for reply in alive if reply.ok is not None] == [
            keys.alive(CELL, f"controller-{ROBOT}")
        ]

        # Play the gateway at ~250 Hz for 1.2 s (δ = 1), with garbage and another robot's commands mixed in; longer
        # if the robot has not reached δ = 1 by then (a busy machine may hold this sender beyond the watchdog).
        n_before = len(states.items())
        seq = 0
        start_s = time.monotonic()
        end_s = start_s + 1.2
        while time.monotonic() < end_s or (
            not _at_full_speed(states.latest()) and time.monotonic() < start_s + 1.2 + 5.0 * load_scale()
        ):
            pub.put(to_payload(Override(robot=ROBOT, seq=seq, stamp_ns=time.time_ns(), delta=1.0)))
            if seq % 20 == 10:
                pub.put(GARBAGE[(seq // 20) % len(GARBAGE)])
            if seq % 50 == 25:
                pub.put(to_payload(Override(robot="ur10", seq=seq, stamp_ns=time.time_ns(), delta=1.0)))
            seq += 1
            time.sleep(OVERRIDE_PERIOD_S)
        last_sent_s = time.monotonic()
        running: JointState = states.latest()
        assert running.mode == "running"
        assert running.override == 1.0, "0.5 s of acceleration are over"
        assert seq - 50 <= running.override_seq < seq, "override_seq echoes a recently sent seq"
        sent = states.items()[n_before:]
        for silence_s in _watchdog_stops(sent):  # only where no override came for the watchdog's time
            assert silence_s >= WATCHDOG_S - 0.001, f"a protective stop after at most {silence_s:.3f} s without one"
        for stretch in _running_stretches(sent):
            overrides = [s.override for s in stretch]
            assert overrides == sorted(overrides), "the override only rises while δ = 1 is commanded"
        window = [s for s in sent if s.mode == "running"]
        assert window[0].override < 0.1
        assert all(s.override_seq < seq for s in window)
        assert any(max(abs(v) for v in s.qd) > 0.0 for s in window), "the robot moves"

        # It stops on its own when the overrides stop: watchdog, then a controlled stop.
        took_s = wait_or_fail(lambda: states.latest().mode == "protective_stop", 1.0, "protective stop", [log_path])
        assert took_s + (time.monotonic() - last_sent_s) < 1.0
        wait_or_fail(lambda: states.latest().override == 0.0, 1.0, "standstill", [log_path])

        # The garbage was survived and counted by reason.
        def garbage_counted() -> bool:
            latest = stats.latest()
            return latest is not None and {"not_json", "non_finite", "invalid", "wrong_schema"} <= set(
                latest["rejected"]
            )

        wait_or_fail(garbage_counted, 3.0, "rejections in emu_stats", [log_path])
        doc = stats.latest()
        assert doc["robot"] == ROBOT
        assert doc["rejected"]["wrong_robot"] >= 1
        assert set(doc) == {"robot", "cycles_completed", "mode", "override", "rejected", "missed_cycles"}
        assert proc.poll() is None
        del state_sub, stats_sub

    proc.send_signal(signal.SIGINT)
    assert proc.wait(5.0) == 0
    log = log_path.read_text()
    assert "protective stop: no valid override for" in log
    assert "program cycles completed" in log
    assert "Traceback" not in log


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--robot", "nope"], "unknown robot 'nope'; allowed: ur5"),
        (["--config", "{bad}"], "robots: Field required"),
        (["--zenoh-listen", "tcp/127.0.0.1:notaport"], "cannot open a Zenoh session"),
        (
            ["--egm", "127.0.0.1:6510", "--zenoh-listen", "tcp/127.0.0.1:7999"],
            "robot 'ur5' has a closed controller (control = 'closed'): --egm serves an open one",
        ),
        (["--egm", "nohost"], "--egm 'nohost'; expected HOST:PORT"),
    ],
)
def test_invalid_configuration_exits_2_with_one_line(tmp_path: Path, args: list[str], expected: str) -> None:
    bad = tmp_path / "cell.toml"
    bad.write_text('cell = "demo"\n')
    args = [str(bad) if a == "{bad}" else a for a in args]
    result = subprocess.run(
        [sys.executable, "-m", "controller_emu", *args],
        capture_output=True,
        cwd=REPO_ROOT,
        timeout=30,
        check=False,
    )
    # plain TCP (the test harness's) is logged as a WARNING first; the reason is one line of its own
    lines = [line for line in result.stderr.decode().splitlines() if " WARNING INSECURE " not in line]
    assert result.returncode == 2
    assert len(lines) == 1
    assert lines[0].startswith("hrc-controller-emu: ")
    assert expected in lines[0]


def test_sigterm_exits_0(controller: tuple[Program, str, Path]) -> None:
    proc, _, log_path = controller
    wait_or_fail(lambda: "waiting for overrides" in log_path.read_text(), 15.0, "start-up", [log_path])
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(5.0) == 0
    assert "program cycles completed" in log_path.read_text()
