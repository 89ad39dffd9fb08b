"""Teeth of the tracks: with occlusion, a gateway that forgets a person no longer reported (the classic fail-open,
``tracking.unsafe_forget_lost_for_tests``) drives the robot into them, and the real gateway, which keeps them as a
lost track growing at K (gateway/tracks.py), does not (issue 17). The auditor judges the TRUE people, whom the
sensors do not see whole.

The scene: the default cell with one sensor in front of the robot, on the wall at (3.5, 0, 2.2), with line of sight; a
cabinet stands beside the robot's pick side. One person walks in from beyond the covered volume (y = -6 m), stops
beside the robot behind the cabinet, and reaches towards the pick position: seen from the only sensor, the cabinet
and the robot hide them while their hand is at the tool.
"""

from __future__ import annotations

import math

import pytest

from hrc_contract.config import UNSAFE_ENV_VAR, CellConfig
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_tools.sim.cell import RunResult, simulate
from hrc_tools.sim.links import LinkFaults
from hrc_tools.sim.sweep import CellVariant, run_case
from tracker_emu.scenario import Fixture, HumanScript, Keyframe, Scenario

DURATION_S = 8.5
SEED = 1
TAU_S = 0.0
"""Program time at the start [s]: the tool comes round to the pick side while the hidden hand is there."""
NORTH = math.pi / 2.0


def hidden_at_the_tool() -> Scenario:
    """One person walks in from y = -6 m to (0.3, -1.1), hidden behind the cabinet, and reaches towards the pick
    position (the hand at y ≈ -0.37 m, z ≈ 1.1 m) from 5 s on, holding the reach."""
    spot = (0.3, -1.1)
    keyframes = [
        Keyframe(t_s=0.5, xy_m=(0.3, -6.0), heading_rad=NORTH),
        Keyframe(t_s=4.5, xy_m=spot, heading_rad=NORTH),
        Keyframe(t_s=5.0, xy_m=spot, heading_rad=NORTH),
        Keyframe(t_s=6.0, xy_m=spot, heading_rad=NORTH, reach=1.0),
        Keyframe(t_s=DURATION_S, xy_m=spot, heading_rad=NORTH, reach=1.0),
    ]
    return Scenario(
        description="one sensor: a person beside the robot, hidden behind a cabinet and the robot at the tool",
        duration_s=DURATION_S,
        loop=False,
        humans=[HumanScript(id="h1", keyframes=keyframes)],
        fixtures=[Fixture(name="cabinet", a_m=(1.15, -0.65, 0.45), b_m=(1.15, -0.65, 1.6), radius_m=0.45)],
    )


def one_occluding_sensor(base: CellConfig, forget: bool) -> tuple[CellConfig, dict[str, RobotModel]]:
    """The default cell seen by one noiseless 30 Hz sensor with line of sight; forgetting lost people or not."""
    raw = base.model_dump()
    raw["trackers"] = {
        "front": {"rate_hz": 30.0, "noise_std_m": 0.0, "position_m": (3.5, 0.0, 2.2), "occlusion": True},
    }
    config = CellVariant(unsafe_forget_lost=forget).apply(CellConfig.model_validate(raw))
    return config, {name: load_robot_model(name, r) for name, r in config.robots.items()}


def run(base: CellConfig, forget: bool) -> RunResult:
    config, robots = one_occluding_sensor(base, forget)
    return simulate(
        config, robots, hidden_at_the_tool(), LinkFaults(), DURATION_S, SEED, program_start_s={"ur5": TAU_S}
    )


def test_forgetting_a_hidden_person_violates_where_keeping_them_does_not(
    cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_forget_lost_for_tests")  # the test-only setting is refused without
    forgetting = run(cell_config, forget=True)
    assert forgetting.audit.violations > 10, forgetting.to_dict()["audit"]
    assert forgetting.audit.smallest_margin_moving_m < 0.0
    real = run(cell_config, forget=False)
    assert real.audit.violations == 0, real.to_dict()["audit"]
    assert real.audit.smallest_margin_moving_m > 0.1
    # the real gateway is not merely stopped all along: the robot worked before the person came close
    assert real.program_progress_cycles > 0.2


def with_a_bystander_beyond(scenario: Scenario, xy_m: tuple[float, float]) -> Scenario:
    """The scene and a second person who walks in and stands at ``xy_m``, in the sensor's view, for the rest of it."""
    bystander = HumanScript(
        id="h2",
        keyframes=[
            Keyframe(t_s=0.5, xy_m=(xy_m[0], -6.0), heading_rad=NORTH),
            Keyframe(t_s=4.0, xy_m=xy_m, heading_rad=NORTH),
            Keyframe(t_s=DURATION_S, xy_m=xy_m, heading_rad=NORTH),
        ],
    )
    return scenario.model_copy(update={"humans": [*scenario.humans, bystander]})


def test_releasing_a_hidden_person_by_a_bystander_violates_where_persons_do_not(
    cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Issue 32 in the simulated cell, judged by the auditor on the true people: the person hidden at the tool and a
    bystander standing in view 1.9 m farther out. The rule before persons (any detection that could have reached
    the lost body since the loss, away from the entry band) releases the hidden person by the bystander and drives
    the robot into their hand; persons keep them (only evidence about that very person releases them)."""
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_release_by_id_for_tests")
    scenario = with_a_bystander_beyond(hidden_at_the_tool(), (0.3, -3.0))
    raw = one_occluding_sensor(cell_config, forget=False)[0]
    runs = {}
    for by_id in (True, False):
        config = CellVariant(unsafe_release_by_id=by_id).apply(raw)
        robots = {name: load_robot_model(name, r) for name, r in config.robots.items()}
        runs[by_id] = simulate(config, robots, scenario, LinkFaults(), DURATION_S, SEED, program_start_s={"ur5": TAU_S})
    assert runs[True].audit.violations > 10, runs[True].to_dict()["audit"]
    assert runs[True].audit.smallest_margin_moving_m < 0.0
    assert runs[False].audit.violations == 0, runs[False].to_dict()["audit"]
    assert runs[False].program_progress_cycles > 0.2  # it worked before the person hid: not stopped all along


def test_the_forgetting_switch_is_refused_without_the_environment(
    cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(UNSAFE_ENV_VAR, raising=False)
    with pytest.raises(ValueError, match="unsafe_forget_lost_for_tests"):
        CellVariant(unsafe_forget_lost=True).apply(cell_config)


# -- the same teeth in the randomized sweep with occlusion -------------------------------------------------

SWEEP_SEED = 0
SWEEP_CASE = 48
"""Case 48 of sweep 0 with ``--occlusion`` (within K): one person walks in at 0.82 m/s from the front, stops 0.89 m
from the base and reaches in; the only sensor, at (1.5, -3.6, 2.4), loses them behind a shelf 0.7 m from where they
stand (and misses people in 1 % of its frames)."""
SWEEP_DURATION_S = 8.0


def test_the_forgetting_gateway_violates_on_a_sweep_case_where_the_real_one_does_not(
    cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_forget_lost_for_tests")
    real_cell = CellVariant(occlusion=True).apply(cell_config)
    forgetting_cell = CellVariant(occlusion=True, unsafe_forget_lost=True).apply(cell_config)
    robots = {name: load_robot_model(name, r) for name, r in real_cell.robots.items()}
    forgetting = run_case(forgetting_cell, robots, SWEEP_SEED, SWEEP_CASE, SWEEP_DURATION_S, occlusion=True)
    assert not forgetting.beyond_k  # within the guarantee: the violations are the forgetting's
    assert forgetting.violations > 10, forgetting
    assert forgetting.tracks["released_forgotten_unsafe_test_only"] >= 1
    real = run_case(real_cell, robots, SWEEP_SEED, SWEEP_CASE, SWEEP_DURATION_S, occlusion=True)
    assert real.violations == 0, real
    assert real.smallest_margin_moving_m is not None
    assert real.smallest_margin_moving_m > 0.1
    assert real.tracks["track_lost"] >= 1  # the person was lost, kept, and released only when seen again
    assert "released_forgotten_unsafe_test_only" not in real.tracks
    assert real.mean_delta > 0.2  # the robot worked: not merely stopped all along


# -- persons' teeth in the hostile-tracking sweep ----------------------------------------------------------

HOSTILE_CASE = 45
"""Case 45 of sweep 0 with ``--occlusion --hostile-tracking``: the hidden person and a bystander alone in the cell
(``alone_with_bystander``); the hidden one vanishes behind shelves at the robot, the bystander stands in view
farther out."""


def test_releasing_by_id_violates_on_a_hostile_sweep_case_where_persons_do_not(
    cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(UNSAFE_ENV_VAR, "unsafe_release_by_id_for_tests")
    runs = {}
    for by_id in (True, False):
        config = CellVariant(occlusion=True, hostile_tracking=True, unsafe_release_by_id=by_id).apply(cell_config)
        robots = {name: load_robot_model(name, r) for name, r in config.robots.items()}
        runs[by_id] = run_case(config, robots, SWEEP_SEED, HOSTILE_CASE, 10.0, occlusion=True, hostile_tracking=True)
    by_id, persons = runs[True], runs[False]
    assert by_id.params["hostile_tracking"].get("alone_with_bystander"), by_id.params["hostile_tracking"]
    assert not by_id.beyond_k  # within the guarantee: the violations are the rule's
    assert by_id.violations > 10, by_id
    assert persons.violations == 0, persons
    assert persons.tracks["track_lost"] >= 1
    assert persons.mean_delta > 0.1  # the robot worked beside the bystander before the person hid
