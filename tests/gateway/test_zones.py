"""Zone thresholds, the zone state machine and the commanded override (safety-math.md §6)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from gateway.zones import ZoneThresholds, commanded_override, next_zone, zone_thresholds
from hrc_contract.config import ZonesConfig
from hrc_contract.vocabulary import Zone

CONFIG = ZonesConfig()  # hysteresis 0.15 m, resume 0.4 m, monitored ≥ 1.0 m, guard margin 0.5 m, reduce below 0.98
# Fixed thresholds for the state-machine tests: protective 0.3, resume 0.4, reduce 0.8, monitored 1.5 [m].
TH = ZoneThresholds(protective_m=0.3, resume_m=0.4, reduce_m=0.8, monitored_m=1.5)

A, G, R, X = Zone.AUTONOMOUS, Zone.GUARDED_DISTANCE, Zone.REDUCED_SPEED, Zone.SAFETY_EXCEPTION


# -- thresholds ---------------------------------------------------------------------------------


def test_thresholds_known_answer_adaptive() -> None:
    # Δ = 0.5, T = 0.5, v = 2: (d − 0.5)² = d → d² − 2d + 0.25 = 0 → d = 1 + sqrt(0.75) = 1.8660254
    th = zone_thresholds(CONFIG, clearance_m=0.5, horizon_s=0.5, programmed_speed_mps=2.0)
    assert th.reduce_m == pytest.approx(1.0 + math.sqrt(0.75))
    assert (th.reduce_m - 0.5) ** 2 == pytest.approx(0.5 * th.reduce_m * 2.0)  # it solves (d − Δ)² = T d v
    assert th.protective_m == 0.5
    assert th.resume_m == pytest.approx(0.5 + CONFIG.hysteresis_m)  # max(0.4, Δ + hysteresis)
    assert th.monitored_m == pytest.approx(1.0 + math.sqrt(0.75) + 0.5)  # reduce + guard margin > 1.0


def test_thresholds_known_answer_fixed_speed_ignores_the_programmed_speed() -> None:
    fixed = ZonesConfig(thresholds="fixed", fixed_speed_mps=2.0)
    a = zone_thresholds(fixed, clearance_m=0.5, horizon_s=0.5, programmed_speed_mps=0.1)
    b = zone_thresholds(fixed, clearance_m=0.5, horizon_s=0.5, programmed_speed_mps=5.0)
    assert a == b
    assert a.reduce_m == pytest.approx(1.0 + math.sqrt(0.75))


def test_thresholds_at_rest_and_floors() -> None:
    # v = 0: the only root is d = Δ; monitored falls back to its floor; resume to resume_distance_m
    th = zone_thresholds(CONFIG, clearance_m=0.2, horizon_s=0.5, programmed_speed_mps=0.0)
    assert th.reduce_m == pytest.approx(0.2)
    assert th.monitored_m == pytest.approx(1.0)
    assert th.resume_m == pytest.approx(0.4)


def test_thresholds_invariants_random() -> None:
    rng = np.random.default_rng(5)
    for _ in range(300):
        clearance, horizon, speed = rng.uniform(0, 2), rng.uniform(0.01, 1), rng.uniform(0, 3)
        th = zone_thresholds(CONFIG, clearance, horizon, speed)
        assert th.protective_m <= th.reduce_m <= th.monitored_m
        assert th.resume_m > th.protective_m
        assert (th.reduce_m - clearance) ** 2 == pytest.approx(horizon * th.reduce_m * speed, rel=1e-9, abs=1e-12)
        # faster programmed speed → the reduced-speed zone starts farther out
        assert zone_thresholds(CONFIG, clearance, horizon, speed + 0.5).reduce_m > th.reduce_m


# -- state machine ------------------------------------------------------------------------------


def _run(profile, zone=A, thresholds=TH, config=CONFIG):
    zones = []
    for distance, bound in profile:
        zone = next_zone(zone, distance, bound, thresholds, config)
        zones.append(zone)
    return zones


def test_far_near_touching_far_sequence() -> None:
    profile = [
        (3.0, 1.0),  # far, full speed allowed
        (1.2, 1.0),  # inside the monitored workspace, constraints hold at full speed
        (0.6, 0.5),  # closer: eq. (15) slows the robot
        (0.2, 0.0),  # at the protective distance
        (0.0, 0.0),  # touching
        (0.35, 0.3),  # leaving, but still below resume_m: held
        (0.45, 0.6),  # beyond resume_m, bound < 1: reduced speed
        (1.0, 1.0),  # bound back to 1: guarded distance
        (1.52, 1.0),  # just beyond monitored_m but within its hysteresis: still guarded
        (3.0, 1.0),  # far again
    ]
    assert _run(profile) == [A, G, R, X, X, X, R, G, G, A]


def test_distance_oscillating_around_monitored_does_not_chatter() -> None:
    rng = np.random.default_rng(6)
    h = CONFIG.hysteresis_m
    wobble = rng.uniform(-0.98 * h, 0.98 * h, 200)  # less than hysteresis_m
    zones = _run([(TH.monitored_m + w, 1.0) for w in wobble])
    changes = sum(a != b for a, b in itertools.pairwise(zones))
    assert changes == 0 or (changes == 1 and zones[-1] is G)
    # once guarded, it stays guarded
    assert zones[-1] is G


def test_hysteresis_is_needed_for_a_larger_wobble() -> None:
    """Oscillating by more than the hysteresis does switch: the test above would catch a missing hysteresis."""
    above_m = CONFIG.hysteresis_m + 0.01
    zones = _run([(TH.monitored_m - 0.06, 1.0), (TH.monitored_m + above_m, 1.0)] * 3)
    assert zones == [G, A] * 3


def test_delta_oscillating_around_reduced_speed_below_does_not_chatter() -> None:
    # entering reduced speed needs δ < 0.98; leaving it needs δ = 1
    zones = _run([(1.0, 1.0), (1.0, 0.97), (1.0, 0.99), (1.0, 0.975), (1.0, 0.995), (1.0, 1.0), (1.0, 0.985)])
    assert zones == [G, R, R, R, R, G, G]


def test_exception_held_until_resume() -> None:
    zones = _run([(0.25, 0.0), (0.31, 0.2), (0.39, 0.4), (0.399, 1.0), (0.41, 1.0)], zone=G)
    assert zones == [X, X, X, X, G]


def test_exception_when_bound_is_zero_even_beyond_protective() -> None:
    assert next_zone(G, 1.0, 0.0, TH, CONFIG) is X


def test_at_protective_distance_is_exception_even_if_moving_away() -> None:
    assert next_zone(G, TH.protective_m, 1.0, TH, CONFIG) is X


def test_nobody_is_autonomous_from_any_zone() -> None:
    for zone in Zone:
        assert next_zone(zone, None, 1.0, TH, CONFIG) is A
        assert next_zone(zone, None, 0.0, TH, CONFIG) is A


def test_far_but_bounded_is_not_autonomous() -> None:
    # beyond the workspace but δ < 1 (a very fast link): the robot must not be labelled autonomous
    assert next_zone(A, 5.0, 0.5, TH, CONFIG) is R


def test_random_profiles_invariants() -> None:
    """Seeded random walks: exception exactly when required; never exception→autonomous at close range."""
    rng = np.random.default_rng(8)
    for _ in range(50):
        zone = Zone(rng.choice(list(Zone)))
        for _ in range(60):
            distance = None if rng.random() < 0.05 else float(rng.uniform(0.0, 2.5))
            bound = float(rng.choice([0.0, 1.0, rng.uniform(0, 1)]))
            previous = zone
            zone = next_zone(previous, distance, bound, TH, CONFIG)
            if distance is None:
                assert zone is A
                continue
            if distance <= TH.protective_m or bound <= 0.0:
                assert zone is X
            if previous is X and distance < TH.resume_m:
                assert zone is X
            if zone is A:
                assert distance > TH.monitored_m
                assert bound >= 1.0
            if zone is R:
                assert bound < 1.0


# -- commanded override ---------------------------------------------------------------------------


def test_commanded_override_known_answers() -> None:
    assert commanded_override(X, 0.7) == 0.0
    assert commanded_override(R, 0.7) == 0.7
    assert commanded_override(G, 1.0) == 1.0
    assert commanded_override(A, 1.0) == 1.0


def test_commanded_override_never_exceeds_the_bound() -> None:
    rng = np.random.default_rng(9)
    for _ in range(500):
        zone = Zone(rng.choice(list(Zone)))
        bound = float(rng.uniform(0.0, 1.0))
        delta = commanded_override(zone, bound)
        assert 0.0 <= delta <= bound
        if zone is X:
            assert delta == 0.0
