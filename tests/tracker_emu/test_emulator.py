"""The emulator's step function on a simulated clock: rates, latency, stamps, seq, drops, late callers; the covered
volume, occlusion (the shipped scenarios occluded_behind_robot and complementary_views), misses and id swaps, with
the truth complete."""

from __future__ import annotations

import numpy as np
import pytest
from support.paths import REPO_ROOT

from hrc_contract.config import CellConfig, TrackerConfig
from hrc_contract.messages import Humans
from hrc_devices.robots.model import RobotModel
from hrc_runtime.config import load_cell_config
from tracker_emu.body import CAPSULE_NAMES
from tracker_emu.emulator import TrackerEmulator, TruthSampler
from tracker_emu.robot_links import link_capsules
from tracker_emu.scenario import HumanScript, Keyframe, Scenario, humans_at, load_scenario, scenario_path
from tracker_emu.sensor import covered_volume

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


@pytest.fixture(scope="module")
def cell_one_sensor() -> CellConfig:
    return load_cell_config(REPO_ROOT / "configs" / "cell_one_sensor.toml")


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


# -- what the sensors do not see: the covered volume, occlusion, misses, id swaps; the truth sees everything ------

CONFIGS = REPO_ROOT / "configs"


def frames_of(published: list[tuple[float, str, Humans]], tracker: str) -> list[tuple[float, Humans]]:
    """(capture time since the start [s], message) of one tracker."""
    return [((m.stamp_ns - WALL_AT_START_NS) / 1e9, m) for _, name, m in published if name == tracker]


def ids(message: Humans) -> list[str]:
    return [h.id for h in message.humans]


def capsule_names(message: Humans, human_id: str) -> set[str]:
    return {c.name for h in message.humans if h.id == human_id for c in h.capsules}


def exact(config: TrackerConfig) -> TrackerConfig:
    """The sensor without noise and drops (what it sees, not how badly)."""
    return config.model_copy(update={"noise_std_m": 0.0, "drop_probability": 0.0})


def truth_ids(truth: TruthSampler, t_s: float) -> list[str]:
    message = truth.step(START_S + t_s, wall_ns(START_S + t_s))
    assert message is not None
    return ids(message)


def test_nobody_is_reported_outside_the_covered_volume_but_the_truth_has_them() -> None:
    config = load_cell_config(None)
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "walk_in_reach_leave"))
    trackers = {"front": exact(TRACKERS["front"])}
    emulator = TrackerEmulator(scenario, trackers, seed=0, start_s=START_S, coverage=covered_volume(config.tracking))
    front = frames_of(play(emulator, 20.0), "front")
    # h1 walks in from x = 6.0 m at 3.0 s (1.17 m/s): inside ±5.5 m from about 3.43 s, out again after 18.7 s.
    assert all(ids(m) == [] for t, m in front if 3.0 <= t < 3.38)
    assert all(ids(m) == ["h1"] for t, m in front if 3.48 <= t < 18.6)
    assert all(ids(m) == [] for t, m in front if t >= 18.75)
    truth = TruthSampler(scenario, 100.0, start_s=START_S)
    assert truth_ids(truth, 3.1) == ["h1"]


def test_the_only_sensor_loses_the_person_behind_the_cabinet_and_the_truth_keeps_them(
    cell_one_sensor: CellConfig,
) -> None:
    scenario = load_scenario(scenario_path(cell_one_sensor.scenarios_dir, "occluded_behind_robot"))
    trackers = {name: exact(t) for name, t in cell_one_sensor.trackers.items()}
    assert list(trackers) == ["front"]
    assert trackers["front"].occlusion
    emulator = TrackerEmulator(
        scenario, trackers, seed=0, start_s=START_S, coverage=covered_volume(cell_one_sensor.tracking)
    )
    front = frames_of(play(emulator, 20.0), "front")
    seen_s = [t for t, m in front if ids(m) == ["h1"]]
    assert any(1.5 < t < 4.5 for t in seen_s)  # seen walking in
    assert any(12.6 < t < 15.5 for t in seen_s)  # and walking out
    # Lost while beside the robot, reaching towards its pick position (hand within 0.2 m of it).
    assert all(ids(m) == [] for t, m in front if 5.0 <= t <= 12.2)
    truth = TruthSampler(scenario, 100.0, start_s=START_S)
    for t_s in (5.0, 8.0, 12.0):
        assert truth_ids(truth, t_s) == ["h1"]
    (hidden,) = humans_at(scenario, 8.0)
    hand = next(c for c in hidden.capsules if c.name == "hand_r")
    assert float(np.linalg.norm(hand.b - np.array([0.45, -0.35, 1.0]))) < 0.35


def test_two_sensors_see_complementary_parts_of_a_person(cell_config: CellConfig) -> None:
    scenario = load_scenario(scenario_path(cell_config.scenarios_dir, "complementary_views"))
    trackers = {name: exact(t) for name, t in cell_config.trackers.items()}
    assert all(t.occlusion for t in trackers.values())
    emulator = TrackerEmulator(
        scenario, trackers, seed=0, start_s=START_S, coverage=covered_volume(cell_config.tracking)
    )
    published = play(emulator, 12.0)
    front = [m for t, m in frames_of(published, "front") if 6.5 <= t <= 12.0]
    side = [m for t, m in frames_of(published, "side") if 6.5 <= t <= 12.0]
    assert front
    assert side
    for message in front:  # the upper body over the workbench
        assert {"head", "torso", "hand_r"} <= capsule_names(message, "h1")
        assert not {"shin_l", "shin_r"} & capsule_names(message, "h1")
    for message in side:  # the legs below the cabinet
        assert {"shin_l", "shin_r"} <= capsule_names(message, "h1")
        assert not {"head", "torso"} & capsule_names(message, "h1")
    assert capsule_names(front[0], "h1") | capsule_names(side[0], "h1") == set(CAPSULE_NAMES)


def test_the_robots_links_passed_to_step_hide_people(ur5: RobotModel) -> None:
    behind = Scenario(
        description="one person 1.5 m behind the robot",
        duration_s=10.0,
        loop=False,
        humans=[
            HumanScript(
                id="h1",
                keyframes=[
                    Keyframe(t_s=0.0, xy_m=(-1.5, 0.0), heading_rad=0.0),
                    Keyframe(t_s=10.0, xy_m=(-1.5, 0.0), heading_rad=0.0),
                ],
            )
        ],
    )
    near = TrackerConfig(noise_std_m=0.0, occlusion=True, position_m=(0.15, 0.0, 1.3))
    emulator = TrackerEmulator(behind, {"near": near}, seed=0, start_s=START_S)
    assert emulator.occludes
    data = ur5.model.createData()
    raised = link_capsules(ur5, data, np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0]))
    stretched = link_capsules(ur5, data, np.zeros(6))
    seen = []
    now_s = START_S
    for links in (None, raised, stretched, raised):
        assert emulator.capture_due(now_s)
        seen += [ids(m) for _, m in emulator.step(now_s, wall_ns(now_s), links)]
        now_s = emulator.next_event_s()
        assert not emulator.capture_due(now_s - 1e-6)
    assert seen == [["h1"], [], ["h1"], []]


def test_id_swaps_and_misses_in_the_emulator_are_seeded() -> None:
    scenario = load_scenario(scenario_path(SCENARIOS_DIR, "two_people"))
    glitchy = TrackerConfig(noise_std_m=0.0, miss_probability=0.1, id_swap_probability=0.05)

    def run(seed: int) -> tuple[list[Humans], int]:
        emulator = TrackerEmulator(scenario, {"front": glitchy}, seed=seed, start_s=START_S)
        return [m for _, _, m in play(emulator, 20.0)], emulator.counters["front"].id_swaps

    (frames, swaps), (again, swaps_again) = run(1), run(1)
    assert frames == again
    assert swaps == swaps_again
    both = [m for m in frames if len(m.humans) == 2]
    # Two people reported in about 6 s of frames at 30 Hz: about 0.05 × 180 ≈ 9 swaps.
    assert 3 <= swaps <= 20
    assert any(ids(m) == ["h2", "h1"] for m in both)  # swapped: h1's body (listed first) reported as h2
    assert all(len(set(ids(m))) == len(m.humans) for m in frames)
    plain = TrackerEmulator(scenario, {"front": TrackerConfig(noise_std_m=0.0)}, seed=1, start_s=START_S)
    assert sum(len(m.humans) for m in frames) < sum(len(m.humans) for _, _, m in play(plain, 20.0))


# -- what a hostile sweep plays (issue 32): late stamps, renewed ids, late joiners, merged people, names by kind -------


def _two_people() -> Scenario:
    """Two people standing 0.5 m apart for 3 s."""
    return Scenario(
        description="two people side by side",
        duration_s=3.0,
        loop=False,
        humans=[
            HumanScript(id="a", keyframes=[Keyframe(t_s=0.0, xy_m=(1.5, 0.0), heading_rad=np.pi),
                                           Keyframe(t_s=3.0, xy_m=(1.5, 0.0), heading_rad=np.pi)]),
            HumanScript(id="b", keyframes=[Keyframe(t_s=0.0, xy_m=(1.5, 0.5), heading_rad=np.pi),
                                           Keyframe(t_s=3.0, xy_m=(1.5, 0.5), heading_rad=np.pi)]),
        ],
    )  # fmt: skip


def _frames(**faults: object) -> list[tuple[float, Humans]]:
    tracker = TrackerConfig.model_validate({"rate_hz": 10.0, "noise_std_m": 0.0, "latency_s": 0.02, **faults})
    return [
        (t, m) for t, _, m in play(TrackerEmulator(_two_people(), {"front": tracker}, seed=3, start_s=START_S), 2.0)
    ]


def test_a_late_tracker_stamps_its_frames_before_their_capture() -> None:
    on_time, late = _frames(), _frames(stamp_late_s=0.14)
    assert len(on_time) == len(late) > 10
    for (_, a), (_, b) in zip(on_time, late, strict=True):
        assert a.stamp_ns - b.stamp_ns == 140_000_000
        assert a.humans == b.humans


def test_a_tracker_that_renews_ids_gives_someone_a_new_id_for_good() -> None:
    frames = _frames(id_renew_probability=0.3)
    ids = [sorted(h.id for h in m.humans) for _, m in frames]
    assert ids[0] != ids[-1], "renewed at least once in 20 frames at 0.3"
    assert all(len(set(i)) == 2 for i in ids), "two people, two ids, always"
    assert _frames(id_renew_probability=0.0)[-1][1].humans == _frames()[-1][1].humans


def test_a_tracker_that_joins_late_reports_nobody_until_then() -> None:
    frames = _frames(blind_until_s=1.0)
    assert all(m.humans == [] for t, m in frames if t - START_S < 1.0)
    assert all(len(m.humans) == 2 for t, m in frames if t - START_S > 1.1)


def test_a_tracker_that_merges_people_reports_one_with_both_bodies() -> None:
    (_, frame), *_ = _frames(merge_within_m=1.0)
    (merged,) = frame.humans
    assert len(merged.capsules) == 2 * len(CAPSULE_NAMES)


def test_a_tracker_that_names_parts_by_kind_reports_two_parts_with_one_name() -> None:
    (_, frame), *_ = _frames(part_names_by_kind=True)
    names = [c.name for c in frame.humans[0].capsules]
    assert len(set(names)) < len(names)
