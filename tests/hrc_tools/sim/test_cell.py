"""The simulated cell: its links, its ground truth, the scenario generator and whole runs on the simulated clock."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from hrc_contract.config import CellConfig, TrackerConfig
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory
from hrc_tools.sim.cell import simulate
from hrc_tools.sim.links import NS_PER_S, LinkFault, LinkFaults, SimLink
from hrc_tools.sim.scenarios import (
    BEARING_LIMIT_RAD,
    DEFAULT_COVERAGE,
    MAX_SPEED_MPS,
    SweepCase,
    generate_case,
    generate_collaborative_case,
)
from hrc_tools.sim.truth import true_humans
from tracker_emu.scenario import HumanScript, Keyframe, Scenario, humans_at
from tracker_emu.sensor import centre_m, inside

# -- links --------------------------------------------------------------------------------------------


def _link(fault: LinkFault, seed: int = 0) -> SimLink[int]:
    return SimLink(fault, np.random.default_rng(seed))


def test_fixed_delay_delivers_in_order_exactly_on_time() -> None:
    link = _link(LinkFault(delay_s=0.05))
    for i in range(5):
        link.send(i, i * 4_000_000)
    assert link.next_arrival_ns() == 50_000_000
    assert link.deliver(49_999_999) == []
    assert link.deliver(50_000_000) == [(50_000_000, 0)]
    assert link.deliver(10 * NS_PER_S) == [(50_000_000 + i * 4_000_000, i) for i in range(1, 5)]
    assert link.next_arrival_ns() is None


def test_in_order_link_delays_with_jitter_but_never_reorders() -> None:
    link = _link(LinkFault(delay_s=0.01, jitter_s=0.02, duplication=0.1), seed=3)
    n = 2000
    for i in range(n):
        link.send(i, i * 1_000_000)
    out = link.deliver(100 * NS_PER_S)
    items = [item for _, item in out]
    assert all(a <= b for a, b in itertools.pairwise(items))  # duplicates next to their original, no overtaking
    assert link.counters.duplicated > 0
    delays = [t - i * 1_000_000 for t, i in out]
    assert min(delays) >= 10_000_000
    assert max(delays) <= 30_000_000
    assert len(set(delays)) > 100  # jittered


def test_loss_duplication_and_reordering_from_jitter() -> None:
    link = _link(LinkFault(delay_s=0.01, jitter_s=0.02, loss=0.2, duplication=0.1, in_order=False), seed=3)
    n = 5000
    for i in range(n):
        link.send(i, i * 1_000_000)
    out = link.deliver(100 * NS_PER_S)
    items = [item for _, item in out]
    assert link.counters.lost == pytest.approx(0.2 * n, rel=0.15)
    assert link.counters.duplicated == pytest.approx(0.1 * 0.8 * n, rel=0.2)
    assert len(items) == n - link.counters.lost + link.counters.duplicated
    assert any(b < a for a, b in itertools.pairwise(items))  # jitter 20 ms > 1 ms spacing: overtaking
    delays = [t - i * 1_000_000 for t, i in out]
    assert min(delays) >= 10_000_000
    assert max(delays) <= 30_000_000
    again = _link(LinkFault(delay_s=0.01, jitter_s=0.02, loss=0.2, duplication=0.1, in_order=False), seed=3)
    for i in range(n):
        again.send(i, i * 1_000_000)
    assert again.deliver(100 * NS_PER_S) == out


@pytest.mark.parametrize(
    "kwargs", [{"delay_s": -0.1}, {"jitter_s": math.inf}, {"loss": 1.0}, {"duplication": -0.5}, {"delay_s": math.nan}]
)
def test_link_fault_rejects_bad_values(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="allowed"):
        LinkFault(**kwargs)


# -- truth and generated scenarios --------------------------------------------------------------------


def test_true_humans_equal_the_scenario_humans() -> None:
    for index in range(6):
        scenario = generate_case(7, index, 10.0, 0.2).scenario
        for t_s in np.linspace(0.0, 10.0, 23):
            expected = humans_at(scenario, float(t_s))
            got = true_humans(scenario, float(t_s))
            caps = [c for h in expected for c in h.capsules]
            assert got.n_capsules == len(caps)
            if caps:
                np.testing.assert_allclose(got.h_a_world, [c.a for c in caps], atol=1e-12)
                np.testing.assert_allclose(got.h_b_world, [c.b for c in caps], atol=1e-12)
                np.testing.assert_allclose(got.radius_m, [c.radius_m for c in caps])
                assert got.human_ids == tuple(h.id for h in expected for _ in h.capsules)
                assert got.capsule_names == tuple(c.name for c in caps)


def _max_speed_mps(human: HumanScript) -> float:
    return max(math.dist(k0.xy_m, k1.xy_m) / (k1.t_s - k0.t_s) for k0, k1 in itertools.pairwise(human.keyframes))


def test_generated_cases_are_valid_varied_and_reproducible() -> None:
    cases = [generate_case(11, i, 10.0, 0.2) for i in range(300)]
    assert generate_case(11, 5, 10.0, 0.2) == cases[5]
    kinds = {p["kind"] for c in cases for p in c.params["people"]}
    assert kinds == {"approach", "cross", "standing"}
    counts = [len(c.scenario.humans) for c in cases]
    assert min(counts) >= 1
    assert max(counts) == 3
    bearings = [math.radians(p["bearing_deg"]) for c in cases for p in c.params["people"] if p["kind"] == "approach"]
    assert max(map(abs, bearings)) <= BEARING_LIMIT_RAD
    assert min(bearings) < -math.radians(90.0)  # sides, not just the front
    assert max(bearings) > math.radians(90.0)
    speeds = [_max_speed_mps(h) for c in cases for h in c.scenario.humans]
    assert max(speeds) <= MAX_SPEED_MPS + 1e-9
    assert max(speeds) > 1.9
    assert any(p.get("reach", 0) > 0 for c in cases for p in c.params["people"])
    assert any(t.drop_probability > 0 for c in cases for t in c.trackers.values())
    assert any(len(c.trackers) == 2 for c in cases)
    beyond = [c for c in cases if c.beyond_budget]
    assert 0.08 < len(beyond) / len(cases) < 0.25
    for case in cases:
        fault = case.links
        if not case.beyond_budget:
            latency = max(t.latency_s for t in case.trackers.values())
            assert latency + fault.tracker_to_gateway.max_delay_s < 0.2
            assert fault.gateway_to_controller.max_delay_s + fault.controller_to_gateway.max_delay_s < 0.2
            assert fault.gateway_to_controller.max_delay_s < 0.1
        else:
            assert max(getattr(fault, p).delay_s for p in vars(fault)) > 0.2


def _covered_at(case: SweepCase, human_id: str, t_s: float) -> bool:
    """Whether the trackers' rule (the body's centre in the covered volume) counts the person as covered at t_s."""
    (human,) = [h for h in humans_at(case.scenario, t_s) if h.id == human_id]
    return inside(DEFAULT_COVERAGE, centre_m(human))


def test_people_enter_and_leave_through_the_coverage_boundary() -> None:
    """Nobody is inside the covered volume at the start and nobody vanishes inside it: a person who stopped being
    reported there would be a lost track for the rest of the run (gateway/tracks.py), and the robot would stay
    stopped. Every person's first keyframe is outside, and so is the last unless the run ends first."""
    cases = [generate_case(11, i, 10.0, 0.2) for i in range(150)]
    cases += [generate_collaborative_case(11, i, 30.0, 0.2) for i in range(40)]
    inside_by_kind: dict[str, int] = {}
    for case in cases:
        for human, person in zip(case.scenario.humans, case.params["people"], strict=True):
            first, last = human.keyframes[0], human.keyframes[-1]
            assert not _covered_at(case, human.id, first.t_s), (case.index, person)
            if last.t_s < case.scenario.duration_s:
                assert not _covered_at(case, human.id, last.t_s), (case.index, person)
            middle_s = (first.t_s + last.t_s) / 2.0
            inside_by_kind[person["kind"]] = inside_by_kind.get(person["kind"], 0) + _covered_at(
                case, human.id, middle_s
            )
    # they do come in: every kind is inside the covered volume half-way through its presence, most of the time
    assert set(inside_by_kind) == {
        "approach",
        "cross",
        "standing",
        "shared_table",
        "walk_by",
        "reach_in",
        "stand_in_path",
    }
    assert all(count > 0 for count in inside_by_kind.values()), inside_by_kind


def test_occlusion_changes_only_the_sensors_view() -> None:
    """With occlusion a case keeps its people, links and simulation seed; its sensors get a pose, line of sight,
    misses and id swaps, and the scene 0-2 fixtures, drawn per case."""
    misses = swaps = fixtures = shelves = 0
    for index in range(60):
        for generate, duration_s in ((generate_case, 10.0), (generate_collaborative_case, 30.0)):
            plain = generate(5, index, duration_s, 0.2)
            occluded = generate(5, index, duration_s, 0.2, occlusion=True)
            assert occluded.scenario.humans == plain.scenario.humans
            assert not plain.scenario.fixtures
            fixtures += len(occluded.scenario.fixtures)
            for fixture in occluded.scenario.fixtures:  # below every sensor: hides people near the robot only
                assert fixture.b_m[2] + fixture.radius_m <= 2.0 + 1e-9
                if fixture.name == "shelf":
                    shelves += 1
                else:
                    assert 0.9 <= math.hypot(*fixture.a_m[:2]) <= 2.2
            assert (occluded.links, occluded.seed) == (plain.links, plain.seed)
            assert occluded.trackers.keys() == plain.trackers.keys()
            for name, tracker in occluded.trackers.items():
                assert tracker.occlusion
                assert tracker.position_m is not None
                assert 2.5 <= math.hypot(*tracker.position_m[:2]) <= 5.0
                assert 2.2 <= tracker.position_m[2] <= 3.0
                same = {"occlusion": False, "position_m": None, "miss_probability": 0.0, "id_swap_probability": 0.0}
                assert tracker.model_copy(update=same) == plain.trackers[name]
                misses += tracker.miss_probability > 0.0
                swaps += tracker.id_swap_probability > 0.0
            assert generate(5, index, duration_s, 0.2, occlusion=True) == occluded
    assert 20 < misses < 130
    assert 20 < swaps < 130
    assert 60 < fixtures < 240
    assert 10 < shelves < 60


# -- whole runs ----------------------------------------------------------------------------------------


def _one_tracker(config: CellConfig, **tracker: float) -> CellConfig:
    raw = config.model_dump()
    raw["trackers"] = {"front": TrackerConfig(**tracker).model_dump()}  # type: ignore[arg-type]
    return CellConfig.model_validate(raw)


def _standing(x_m: float, duration_s: float) -> Scenario:
    keyframes = [Keyframe(t_s=0.0, xy_m=(x_m, 0.0), heading_rad=math.pi)]
    keyframes.append(Keyframe(t_s=duration_s, xy_m=(x_m, 0.0), heading_rad=math.pi))
    return Scenario(
        description="one person standing",
        duration_s=duration_s,
        loop=False,
        humans=[HumanScript(id="h1", keyframes=keyframes)],
    )


EMPTY = Scenario(description="nobody", duration_s=3.0, loop=False)


def test_run_is_deterministic_for_a_seed(cell_config: CellConfig, ur5: RobotModel) -> None:
    config = _one_tracker(cell_config, rate_hz=30.0, noise_std_m=0.02, drop_probability=0.1, latency_s=0.02)
    links = LinkFaults(
        tracker_to_gateway=LinkFault(0.02, 0.01, 0.05, 0.05),
        controller_to_gateway=LinkFault(0.01, 0.01, 0.05, 0.05),
        gateway_to_controller=LinkFault(0.01, 0.01, 0.05, 0.05),
    )
    scenario = _standing(1.6, 1.5)
    first = simulate(config, {"ur5": ur5}, scenario, links, 1.5, seed=4)
    second = simulate(config, {"ur5": ur5}, scenario, links, 1.5, seed=4)
    assert first.to_dict() == second.to_dict()
    other = simulate(config, {"ur5": ur5}, scenario, links, 1.5, seed=5)
    assert other.to_dict() != first.to_dict()
    assert first.audit.cycles == 375  # 1.5 s of 4 ms cycles
    assert first.decisions == 375  # 1.5 s at 250 Hz
    assert first.t_delay_min_s is not None
    assert first.t_delay_min_s > 0.04 + 0.02 + 0.02  # floor + sensor latency + link delay at least


def test_nobody_present_runs_at_full_speed(cell_config: CellConfig, ur5: RobotModel) -> None:
    config = _one_tracker(cell_config, rate_hz=30.0, noise_std_m=0.0, drop_probability=0.0, latency_s=0.0)
    got = simulate(config, {"ur5": ur5}, EMPTY, LinkFaults(), 3.0, seed=1)
    assert got.audit.smallest_margin_m == math.inf
    assert got.audit.violations == 0
    assert got.audit.time_in_zone_s["autonomous"] > 2.5
    # Starts in a protective stop, then ramps up to δ = 1 in accel_time_s (0.5 s).
    assert 0.8 < got.audit.mean_delta_applied < 0.95
    assert got.audit.time_stopped_s < 0.1
    assert got.speedup > 0.0


def test_tracker_delay_beyond_the_data_age_limit_stops_the_robot(cell_config: CellConfig, ur5: RobotModel) -> None:
    config = _one_tracker(cell_config, rate_hz=30.0, noise_std_m=0.0, drop_probability=0.0, latency_s=0.0)
    links = LinkFaults(tracker_to_gateway=LinkFault(delay_s=1.5 * config.safety.max_data_age_s))
    got = simulate(config, {"ur5": ur5}, EMPTY, links, 2.0, seed=1)
    assert got.faults["tracker_stale"] + got.faults.get("tracker_missing", 0) == got.decisions
    assert got.audit.mean_delta_applied == 0.0
    assert got.t_delay_mean_s is None


def test_override_delay_beyond_the_watchdog_stops_the_robot(cell_config: CellConfig, ur5: RobotModel) -> None:
    config = _one_tracker(cell_config, rate_hz=30.0, noise_std_m=0.0, drop_probability=0.0, latency_s=0.0)
    links = LinkFaults(gateway_to_controller=LinkFault(delay_s=0.15))  # watchdog 0.1 s
    got = simulate(config, {"ur5": ur5}, EMPTY, links, 1.0, seed=1)
    assert got.audit.mean_delta_applied == 0.0
    assert got.controller_rejected["stale"] > 0
    assert got.faults["override_path_unconfirmed"] == got.decisions


def test_program_progress_is_the_integral_of_the_applied_override(cell_config: CellConfig, ur5: RobotModel) -> None:
    """The productivity figure: whole program cycles plus the fraction of the unfinished one, which is
    ∫ δ_applied dt over the program's duration (the controller advances its program time by δ dt)."""
    config = _one_tracker(cell_config, rate_hz=30.0, noise_std_m=0.0, drop_probability=0.0, latency_s=0.0)
    duration_s = load_trajectory(config.robots["ur5"].program, ur5).duration_s
    got = simulate(config, {"ur5": ur5}, EMPTY, LinkFaults(), 8.0, seed=2)
    assert got.audit.program_cycles_completed >= 1  # the program wrapped at least once
    assert got.program_progress_cycles > 1.0
    integral_s = got.audit.mean_delta_applied * got.audit.duration_s
    assert got.program_progress_cycles * duration_s == pytest.approx(integral_s, abs=0.01)  # 2.5 cycles of 4 ms


def test_hostile_tracking_keeps_the_late_stamp_within_the_age_budget_and_draws_lone_pairs() -> None:
    """The late tracker's frames are late yet fresh (latency + link's worst delay + one frame + the late stamp within
    the data age limit, unless its link is the one drawn beyond budget), and some cases leave the hidden person and a
    bystander alone, hidden from every sensor, with no tracker merging people or naming parts by kind."""
    max_data_age_s = 0.2
    late = alone = 0
    for index in range(200):
        case = generate_case(3, index, 10.0, max_data_age_s, occlusion=True, hostile_tracking=True)
        drawn = case.params["hostile_tracking"]
        link = case.links.tracker_to_gateway
        for name, tracker in case.trackers.items():
            if tracker.stamp_late_s > 0.0:
                late += 1
                age_s = tracker.latency_s + link.delay_s + link.jitter_s + 1.0 / tracker.rate_hz + tracker.stamp_late_s
                assert age_s <= max_data_age_s or case.params["beyond_budget"] == "tracker_to_gateway", (index, name)
        if drawn.get("alone_with_bystander"):
            alone += 1
            assert {h.id for h in case.scenario.humans} == {"h8", "bystander"}
            shelves = [f for f in case.scenario.fixtures if f.name == "shelf"]
            assert len(shelves) >= len(case.trackers)  # one toward every sensor, whichever side it stands
            assert not any(t.merge_within_m or t.part_names_by_kind for t in case.trackers.values())
    assert late > 100
    assert 10 <= alone <= 45  # an eighth of the cases
