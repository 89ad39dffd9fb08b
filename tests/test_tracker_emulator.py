"""The emulator's step function on a simulated clock: rates, latency, stamps, seq, drops, late callers."""

from __future__ import annotations

import numpy as np
import pytest

from hrc_common.config import REPO_ROOT, TrackerConfig
from hrc_common.messages import Humans
from tracker_emu.emulator import TrackerEmulator
from tracker_emu.scenario import load_scenario, scenario_path

SCENARIOS_DIR = REPO_ROOT / "configs" / "scenarios"
WALL_AT_START_NS = 1_790_000_000_000_000_000
START_S = 1000.0


def wall_ns(now_s: float) -> int:
    return WALL_AT_START_NS + round((now_s - START_S) * 1e9)


def play(
    emulator: TrackerEmulator, duration_s: float, max_step_s: float | None = None
) -> list[tuple[float, str, Humans]]:
    """Step the emulator from event to event (or at most every ``max_step_s``); returns (time, tracker, message)."""
    out = []
    now_s = START_S
    while now_s < START_S + duration_s:
        for tracker, message in emulator.step(now_s, wall_ns(now_s)):
            out.append((now_s, tracker, message))
        next_s = emulator.next_event_s()
        assert next_s > now_s
        now_s = next_s if max_step_s is None else now_s + max_step_s
    return out


TRACKERS = {
    "front": TrackerConfig(rate_hz=30.0, noise_std_m=0.01, drop_probability=0.0, latency_s=0.03),
    "side": TrackerConfig(rate_hz=20.0, noise_std_m=0.0, drop_probability=0.2, latency_s=0.1),
}


@pytest.fixture
def emulator() -> TrackerEmulator:
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "walk_in_reach_leave"))
    return TrackerEmulator(scenario, TRACKERS, seed=0, start_s=START_S)


def test_each_tracker_publishes_at_its_own_rate_with_its_latency(emulator: TrackerEmulator) -> None:
    published = play(emulator, 10.0)
    for name, config in TRACKERS.items():
        frames = [(t, m) for t, tracker, m in published if tracker == name]
        counters = emulator.counters[name]
        captured = round(10.0 * config.rate_hz)
        assert counters.captured == pytest.approx(captured, abs=1)
        assert counters.published + counters.dropped + 0 <= counters.captured
        assert counters.skipped == 0
        assert len(frames) == counters.published
        assert [m.seq for _, m in frames] == list(range(1, len(frames) + 1))
        assert all(m.tracker == name for _, m in frames)
        for t, m in frames:
            age_s = (wall_ns(t) - m.stamp_ns) / 1e9
            assert age_s == pytest.approx(config.latency_s, abs=1e-6)
        stamps = np.array([m.stamp_ns for _, m in frames])
        periods_s = np.diff(stamps) / 1e9
        assert np.min(periods_s) == pytest.approx(1.0 / config.rate_hz, abs=1e-6)
    assert emulator.counters["front"].dropped == 0
    assert emulator.counters["side"].dropped / emulator.counters["side"].captured == pytest.approx(0.2, abs=0.08)


def test_frames_follow_the_scenario(emulator: TrackerEmulator) -> None:
    published = play(emulator, 12.0)
    front = [(m.stamp_ns - WALL_AT_START_NS) / 1e9 for _, tracker, m in published if tracker == "front"]
    humans = [m.humans for _, tracker, m in published if tracker == "front"]
    for t_s, seen in zip(front, humans, strict=True):
        if t_s < 2.99:
            assert seen == []  # empty frames are published: they are data
        elif 3.01 < t_s < 12.0:
            assert [h.id for h in seen] == ["h1"]
    reach_frames = [h for t, h in zip(front, humans, strict=True) if 10.0 <= t <= 12.0]
    hands = [c for hs in reach_frames for c in hs[0].capsules if c.name == "hand_r"]
    assert hands
    assert all(c.b[0] < 0.75 for c in hands)


def test_a_late_caller_skips_captures_instead_of_bursting(emulator: TrackerEmulator) -> None:
    published = play(emulator, 3.0, max_step_s=0.25)
    counters = emulator.counters["front"]
    # Steps at 0, 0.25, ..., 2.75 s: one capture per step; the other instants of the 30 Hz grid are skipped.
    assert counters.captured == 12
    assert counters.captured + counters.skipped == int(2.75 * 30.0) + 1
    front = [m for _, tracker, m in published if tracker == "front"]
    assert [m.seq for m in front] == list(range(1, len(front) + 1))
    stamps = [m.stamp_ns for m in front]
    assert len(set(stamps)) == len(stamps)


def test_same_seed_same_messages() -> None:
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "two_people"))

    def run(seed: int) -> list[Humans]:
        return [m for _, _, m in play(TrackerEmulator(scenario, TRACKERS, seed=seed, start_s=START_S), 6.0)]

    assert run(3) == run(3)
    assert run(3) != run(4)


def test_a_tracker_stream_does_not_depend_on_the_others() -> None:
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "two_people"))
    alone = play(TrackerEmulator(scenario, {"side": TRACKERS["side"]}, seed=1, start_s=START_S), 5.0)
    together = play(TrackerEmulator(scenario, TRACKERS, seed=1, start_s=START_S), 5.0)
    assert [m for _, _, m in alone] == [m for _, tracker, m in together if tracker == "side"]


def test_loop_index_and_scenario_time(emulator: TrackerEmulator) -> None:
    assert emulator.loop_index(START_S + 29.0) == 0
    assert emulator.loop_index(START_S + 31.0) == 1
    assert emulator.scenario_time_s(START_S + 61.5) == pytest.approx(1.5)


def test_at_least_one_tracker() -> None:
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "standing_inside"))
    with pytest.raises(ValueError, match="at least one tracker"):
        TrackerEmulator(scenario, {}, seed=0, start_s=0.0)
