"""Ground truth of the emulators: the tracker's true capsules (no noise, drops or latency) at their own rate,
the controller's true joint state each cycle, on ``truth`` keys that the gateway never subscribes to.
"""

from __future__ import annotations

import signal
import statistics
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest
import zenoh
from support.paths import REPO_ROOT

from hrc_contract import keys
from hrc_contract.config import TrackerConfig
from hrc_contract.messages import Humans, JointState, parse_message
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_endpoint, start_program, stop_all, stop_program, wait_or_fail
from tracker_emu.emulator import TRUTH_TRACKER, TrackerEmulator, TruthSampler
from tracker_emu.scenario import humans_at, load_scenario, scenario_path

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

SCENARIOS_DIR = REPO_ROOT / "configs" / "scenarios"
START_S = 500.0
WALL_AT_START_NS = 1_790_000_000_000_000_000


def _wall_ns(now_s: float) -> int:
    return WALL_AT_START_NS + round((now_s - START_S) * 1e9)


# -- keys ---------------------------------------------------------------------------------------------


def _gateway_subscriptions() -> list[str]:
    """The key expressions the gateway subscribes to (gateway/main.py declares exactly these)."""
    return list(keys.gateway_subscriptions("demo"))


def test_truth_keys_are_never_read_by_the_gateway() -> None:
    subscriptions = _gateway_subscriptions()
    assert set(subscriptions) == {"hrc/demo/robot/*/state", "hrc/demo/tracker/*/humans"}
    truth = [keys.truth_robot_state("demo", "ur5"), keys.truth_humans("demo")]
    for sub in subscriptions:
        for key in truth:
            assert not zenoh.KeyExpr(sub).intersects(key), (sub, key)
    # ... while the keys they mirror are read.
    assert zenoh.KeyExpr(subscriptions[0]).intersects(keys.robot_state("demo", "ur5"))
    assert zenoh.KeyExpr(subscriptions[1]).intersects(keys.tracker_humans("demo", "front"))
    # Nor does the controller's override subscription see them.
    assert not any(zenoh.KeyExpr(keys.robot_override("demo", "ur5")).intersects(k) for k in truth)


# -- the tracker's truth sampler (simulated clock) ----------------------------------------------------


def test_truth_sampler_gives_the_exact_scenario_at_its_rate() -> None:
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "walk_in_reach_leave"))
    truth = TruthSampler(scenario, 100.0, start_s=START_S)
    now_s = START_S
    out: list[tuple[float, Humans]] = []
    while now_s < START_S + 10.0:
        message = truth.step(now_s, _wall_ns(now_s))
        if message is not None:
            out.append((now_s, message))
        now_s = truth.next_event_s()
    assert len(out) == 1000
    assert [m.seq for _, m in out] == list(range(1, 1001))
    for t_s, message in out[::37]:
        assert message.tracker == TRUTH_TRACKER
        assert message.stamp_ns == _wall_ns(t_s)  # stamped at the instant it describes, handed out at once
        expected = humans_at(scenario, t_s - START_S)
        assert [h.id for h in message.humans] == [h.id for h in expected]
        for human, exp in zip(message.humans, expected, strict=True):
            for cap, e in zip(human.capsules, exp.capsules, strict=True):
                assert cap.name == e.name
                assert np.array_equal(cap.a, e.a)  # no noise
                assert np.array_equal(cap.b, e.b)
                assert cap.radius == e.radius_m
    assert any(m.humans for _, m in out)
    assert any(not m.humans for _, m in out)  # nobody at the start: an empty list, still published


def test_truth_sampler_skips_missed_instants_and_is_independent_of_the_sensors() -> None:
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "standing_inside"))
    truth = TruthSampler(scenario, 100.0, start_s=START_S)
    assert truth.step(START_S, _wall_ns(START_S)) is not None
    assert truth.step(START_S + 0.005, _wall_ns(START_S + 0.005)) is None
    late = truth.step(START_S + 0.1, _wall_ns(START_S + 0.1))
    assert late is not None
    assert late.seq == 2
    assert truth.skipped == 9
    assert truth.next_event_s() == pytest.approx(START_S + 0.11)
    # The sensors' noise and drops do not depend on whether truth is sampled (separate generators).
    trackers = {"front": TrackerConfig(rate_hz=30.0, noise_std_m=0.01, drop_probability=0.1, latency_s=0.03)}
    frames = []
    for with_truth in (False, True):
        emulator = TrackerEmulator(scenario, trackers, seed=3, start_s=START_S)
        sampler = TruthSampler(scenario, 100.0, START_S) if with_truth else None
        got = []
        now_s = START_S
        while now_s < START_S + 2.0:
            got += emulator.step(now_s, _wall_ns(now_s))
            if sampler is not None:
                sampler.step(now_s, _wall_ns(now_s))
            now_s = min(emulator.next_event_s(), sampler.next_event_s() if sampler else np.inf)
        frames.append(got)
    assert frames[0] == frames[1]


@pytest.mark.parametrize("rate_hz", [0.0, -1.0, float("nan"), float("inf")])
def test_truth_sampler_rejects_a_bad_rate(rate_hz: float) -> None:
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "standing_inside"))
    with pytest.raises(ValueError, match="truth rate"):
        TruthSampler(scenario, rate_hz, start_s=0.0)


# -- the processes ---------------------------------------------------------------------------------


class _Collector:
    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.by_key: dict[str, list[tuple[int, bytes]]] = defaultdict(list)

    def on_sample(self, sample: zenoh.Sample) -> None:
        now_ns = time.time_ns()
        with self.lock:
            self.by_key[str(sample.key_expr)].append((now_ns, sample.payload.to_bytes()))

    def count(self, key: str) -> int:
        with self.lock:
            return len(self.by_key[key])


def _collect(module: str, args: list[str], tmp_path: Path, want: list[str], seconds: float) -> _Collector:
    endpoint = free_endpoint()
    log_path = tmp_path / "program.log"
    proc = start_program(module, [*args, "--zenoh-listen", endpoint], log_path)
    collector = _Collector()
    try:
        with zenoh.open(session_config(connect=[endpoint])) as session:
            session.declare_subscriber("hrc/**", collector.on_sample)
            wait_or_fail(lambda: all(collector.count(k) for k in want), 20.0, f"{want}", [log_path], [proc])
            time.sleep(seconds)
        assert stop_program(proc, signal.SIGINT) == 0
    finally:
        stop_all([proc])
    return collector


def test_tracker_process_publishes_the_truth_at_its_rate_without_noise_or_latency(tmp_path: Path) -> None:
    truth_key, sensor_key = keys.truth_humans("demo"), keys.tracker_humans("demo", "front")
    got = _collect(
        "tracker_emu", ["--scenario", "standing_inside", "--truth-rate-hz", "50"], tmp_path, [truth_key], 2.0
    )
    truth = [(r, parse_message(p, Humans)) for r, p in got.by_key[truth_key]]
    recv_s = np.array([r for r, _ in truth]) / 1e9
    assert (len(truth) - 1) / (recv_s[-1] - recv_s[0]) == pytest.approx(50.0, rel=0.15)
    ages_s = [(r - m.stamp_ns) / 1e9 for r, m in truth]
    assert statistics.median(ages_s) < 0.005  # published at capture (the sensors wait latency_s = 0.03 s)
    assert all(m.tracker == TRUTH_TRACKER for _, m in truth)
    # A person standing still: the truth never moves, the sensor's view is noisy.
    first = truth[0][1].humans[0].capsules
    assert all(m.humans[0].capsules == first for _, m in truth)
    sensor = [parse_message(p, Humans) for _, p in got.by_key[sensor_key]]
    assert len({s.humans[0].capsules[0].a for s in sensor if s.humans}) > 1
    sensor_ages_s = [(r - parse_message(p, Humans).stamp_ns) / 1e9 for r, p in got.by_key[sensor_key]]
    assert min(sensor_ages_s) >= 0.029


def test_tracker_truth_can_be_switched_off_and_rejects_a_bad_rate(tmp_path: Path) -> None:
    got = _collect(
        "tracker_emu",
        ["--scenario", "standing_inside", "--truth-rate-hz", "0"],
        tmp_path,
        [keys.tracker_humans("demo", "front")],
        0.5,
    )
    assert got.count(keys.truth_humans("demo")) == 0
    result = subprocess.run(
        [sys.executable, "-m", "tracker_emu", "--truth-rate-hz", "-5"],
        capture_output=True,
        text=True,
        timeout=60,
        cwd=REPO_ROOT,
    )
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1
    assert "--truth-rate-hz" in result.stderr


def test_controller_truth_is_its_joint_state_every_cycle(tmp_path: Path) -> None:
    truth_key, state_key = keys.truth_robot_state("demo", "ur5"), keys.robot_state("demo", "ur5")
    got = _collect("controller_emu", [], tmp_path, [truth_key, state_key], 1.0)
    truth = {parse_message(p, JointState).seq: p for _, p in got.by_key[truth_key]}
    state = {parse_message(p, JointState).seq: p for _, p in got.by_key[state_key]}
    common = sorted(set(truth) & set(state))
    assert len(common) > 200  # 250 Hz
    assert all(truth[s] == state[s] for s in common)  # exact at the source: the same message
    assert len(truth) >= 0.95 * (max(truth) - min(truth) + 1)  # one per cycle
