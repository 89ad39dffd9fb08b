"""How fast scripted people approach (hrc_tools.sim.human_speed):
known answers, then the sweep's generator against K."""

from __future__ import annotations

import math

import pytest

from hrc_contract.config import CellConfig
from hrc_tools.sim.human_speed import (
    approach_speed_mps,
    beyond_k,
    fastest_approach_mps,
    reach_path_m,
    robot_bases_xy_m,
    segment_approach_speed_mps,
)
from hrc_tools.sim.scenarios import generate_case
from tracker_emu.scenario import HumanScript, Keyframe, Scenario

K_MPS = 1.6


def _walk(start: tuple[float, float], end: tuple[float, float], speed_mps: float, reach: float = 0.0) -> HumanScript:
    t1 = 1.0 + math.dist(start, end) / speed_mps
    frames = [Keyframe(t_s=1.0, xy_m=start, heading_rad=0.0), Keyframe(t_s=t1, xy_m=end, heading_rad=0.0)]
    if reach > 0.0:
        frames.append(Keyframe(t_s=t1 + 0.5, xy_m=end, heading_rad=0.0, reach=reach))
    return HumanScript(id="h1", keyframes=frames)


def test_walking_toward_the_robot_counts_at_its_floor_speed() -> None:
    assert approach_speed_mps(_walk((4.0, 0.0), (1.0, 0.0), 2.0)) == pytest.approx(2.0)
    # Crossing in front of the base: closer at the start of the line, so it counts.
    assert approach_speed_mps(_walk((1.0, -3.0), (1.0, 3.0), 1.8)) == pytest.approx(1.8)


def test_walking_away_and_turning_do_not_count() -> None:
    assert approach_speed_mps(_walk((1.0, 0.0), (4.0, 0.0), 2.5)) == 0.0
    turn = HumanScript(
        id="h1",
        keyframes=[
            Keyframe(t_s=0.0, xy_m=(1.0, 0.0), heading_rad=0.0),
            Keyframe(t_s=0.5, xy_m=(1.0, 0.0), heading_rad=3.0),
        ],
    )
    assert approach_speed_mps(turn) == 0.0


def test_a_walk_toward_another_base_counts() -> None:
    away_from_origin = _walk((1.0, 0.0), (4.0, 0.0), 2.0)
    assert approach_speed_mps(away_from_origin, bases_xy_m=((0.0, 0.0), (5.0, 0.0))) == pytest.approx(2.0)


def test_reaching_out_counts_the_hand_path_withdrawing_does_not() -> None:
    hand_m = reach_path_m(0.0, 1.0, both_arms=False)
    assert 0.6 < hand_m < 0.9  # the hand moves ~0.73 m from hanging to fully reached (tracker_emu.body)
    assert reach_path_m(0.0, 1.0, both_arms=True) == pytest.approx(hand_m)
    out = Keyframe(t_s=0.0, xy_m=(1.0, 0.0), heading_rad=math.pi)
    reached = Keyframe(t_s=0.4, xy_m=(1.0, 0.0), heading_rad=math.pi, reach=1.0)
    assert segment_approach_speed_mps(out, reached, both_arms=False) == pytest.approx(hand_m / 0.4)
    assert (
        segment_approach_speed_mps(reached.model_copy(update={"t_s": 0.0}), out.model_copy(update={"t_s": 0.4}), False)
        == 0.0
    )
    # Walking in while reaching: both add up (an upper bound of the fastest body point).
    walking_reach = Keyframe(t_s=1.0, xy_m=(0.0, 1.0), heading_rad=0.0, reach=1.0)
    start = Keyframe(t_s=0.0, xy_m=(0.0, 2.0), heading_rad=0.0)
    assert segment_approach_speed_mps(start, walking_reach, False) == pytest.approx(1.0 + hand_m)


def test_fastest_of_a_scenario_and_the_threshold() -> None:
    slow, fast = _walk((4.0, 0.0), (1.0, 0.0), 1.2), _walk((0.0, 4.0), (0.0, 1.0), 1.9).model_copy(update={"id": "h2"})
    scenario = Scenario(description="two", duration_s=10.0, loop=False, humans=[slow, fast])
    assert fastest_approach_mps(scenario) == pytest.approx(1.9)
    assert fastest_approach_mps(Scenario(description="nobody", duration_s=1.0, loop=False)) == 0.0
    assert not beyond_k(1.6, K_MPS)
    assert not beyond_k(1.6005, K_MPS)  # a keyframe rounded at K stays within it
    assert beyond_k(1.61, K_MPS)


def test_the_sweep_generator_draws_people_on_both_sides_of_k() -> None:
    """The stress generator walks people up to 2.0 m/s: some cases are beyond K = 1.6 m/s, some within; a walker
    drawn faster than K always puts its case beyond K (the scenario's truth agrees with the drawn parameter)."""
    within = beyond = 0
    for index in range(60):
        case = generate_case(0, index, 10.0, 0.2)
        fastest = fastest_approach_mps(case.scenario)
        walked = max((p["speed_mps"] for p in case.params["people"] if p["kind"] in ("approach", "cross")), default=0.0)
        assert fastest >= walked - 1e-3  # the drawn speed is rounded to 1 mm/s
        if walked > K_MPS + 1e-3:
            assert beyond_k(fastest, K_MPS)
        within += not beyond_k(fastest, K_MPS)
        beyond += beyond_k(fastest, K_MPS)
    assert within >= 10
    assert beyond >= 10


def test_robot_bases_of_the_cell(cell_config: CellConfig) -> None:
    assert robot_bases_xy_m(cell_config) == ((0.0, 0.0),)
