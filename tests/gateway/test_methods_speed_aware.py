"""The speed-aware method (safety-math.md §10): eq. (15) with the stopping time δ t_b, its own safety exception.

Known answers (worked by hand in the comments), the root's defining equality, brute force against a bisection,
monotonicity (δ never rises when a person comes closer or the data gets older), fail-closed on nan, and the
method inside :class:`gateway.core.SafetyCore` with the real UR5.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from support.known_cases import HAND_AHEAD, LINK_RADIUS_M, LINK_UP, MS, NOW, QD_NOMINAL, SAFETY, Cell, Q

from gateway.methods import MethodInput, SpeedAware, Zanchettin2016, build_method
from gateway.reference.kinematics import link_kinematics, link_speed_max_mps
from gateway.reference.separation import build_rows
from gateway.separation import decision_clearance_m, speed_aware_bounds, speed_aware_clearance_m
from gateway.zones import Protection, next_zone, zone_thresholds
from hrc_contract.config import CellConfig, SafetyConfig
from hrc_contract.humans import NO_HUMANS
from hrc_contract.vocabulary import Zone
from hrc_devices.robots.model import RobotModel

K = 1.6
C = 0.05


def one_pair(d: float, e: float, t_b: float, t_delay: float, k: float = K, c: float = C) -> float:
    """The speed-aware bound of one pair with four equal rows e."""
    bounds = speed_aware_bounds(np.array([[d]]), np.full((1, 1, 2, 2), e), np.array([t_b]), t_delay, np.array([[k]]), c)
    return bounds.min_bound


def slack(delta: float, d: float, e: float, t_b: float, t_delay: float, k: float = K, c: float = C) -> float:
    """Right side minus left side of ``δ (δ t_b + t_delay) e ≤ max(0, d − Δ(δ))²`` with the human-alone bound."""
    margin = d - (c + k * (delta * t_b + t_delay))
    if margin < 0.0:
        return margin  # the person alone closes the gap during the stop
    return margin * margin - delta * (delta * t_b + t_delay) * e


def bisect(d: float, e: float, t_b: float, t_delay: float) -> float:
    """The largest δ in [0, 1] with slack ≥ 0, by bisection (the reference of the closed form)."""
    if slack(1.0, d, e, t_b, t_delay) >= 0.0:
        return 1.0
    if slack(0.0, d, e, t_b, t_delay) < 0.0:
        return 0.0
    lo, hi = 0.0, 1.0
    for _ in range(80):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if slack(mid, d, e, t_b, t_delay) >= 0.0 else (lo, mid)
    return lo


# -- known answers --------------------------------------------------------------------------------


def test_known_answer_without_delay_and_margin() -> None:
    # t_delay = 0, c = 0: e t_b δ² ≤ (d − K t_b δ)²  →  δ = d / (sqrt(e t_b) + K t_b)
    # d = 1, e = 2, t_b = 0.5: sqrt(1) = 1, K t_b = 0.8  →  δ = 1 / 1.8
    assert one_pair(1.0, 2.0, 0.5, 0.0, c=0.0) == pytest.approx(1.0 / 1.8, rel=1e-12)


def test_known_answer_moving_away_is_the_human_alone_bound() -> None:
    # e ≤ 0: only δ ≤ (d − c − K t_delay) / (K t_b) = (1 − 0.05 − 0.16) / 0.8 = 0.9875
    assert one_pair(1.0, -3.0, 0.5, 0.1) == pytest.approx(0.9875)
    assert one_pair(1.0, 0.0, 0.5, 0.1) == pytest.approx(0.9875)
    # d = 0.5: (0.5 − 0.21) / 0.8 = 0.3625; within c + K t_delay = 0.21 m: 0
    assert one_pair(0.5, -3.0, 0.5, 0.1) == pytest.approx(0.3625)
    assert one_pair(0.2, -3.0, 0.5, 0.1) == 0.0


def test_hand_ahead_root_satisfies_the_inequality_with_equality() -> None:
    """The hand-built link of known_cases: d = 1.9, e = 4, t_b,→i = 0.3, t_delay = 0.1.

    A = 1.9 − 0.05 − 0.16 = 1.69, B = 0.48, a = 4·0.3 − 0.2304 = 0.9696, b = 0.4 + 2·1.69·0.48 = 2.0224:
    δ = 2 A² / (b + sqrt(b² + 4 a A²)) = 5.7122 / (2.0224 + 3.89454) = 0.96540 (eq. (15) with Δ at t_b = 0.5:
    0.4950625).
    """
    d, e = HAND_AHEAD.distance_m, HAND_AHEAD.e_m2ps
    delta = one_pair(d, e, 0.3, 0.1)
    assert delta == pytest.approx(0.96540, abs=1e-5)
    margin = d - (C + K * (delta * 0.3 + 0.1))
    assert delta * (delta * 0.3 + 0.1) * e == pytest.approx(margin * margin, rel=1e-12)
    assert slack(delta * 1.001, d, e, 0.3, 0.1) < 0.0 < slack(delta * 0.999, d, e, 0.3, 0.1)
    assert delta > HAND_AHEAD.delta


def test_rows_of_the_hand_built_link() -> None:
    """From eq. (15)'s own rows (numpy reference) to the speed-aware bound: the same answer as by hand."""
    rows = build_rows(LINK_UP, LINK_RADIUS_M, np.array([0.3]), 0.5, HAND_AHEAD.humans, SAFETY, 0.1)
    bounds = speed_aware_bounds(rows.surface_distance_m, rows.e_m2ps, np.array([0.3]), 0.1, np.full((1, 1), K), C)
    assert bounds.min_bound == pytest.approx(0.96540, abs=1e-5)
    assert bounds.human_m[0, 0] == pytest.approx((1.9 - 0.21) / 0.48)


def test_static_link_bounds_only_within_c_plus_k_t_delay() -> None:
    """t_b,→i = 0 (no joint moves the link): no human-alone bound beyond c + K t_delay, 0 within."""
    assert one_pair(1.0, -1.0, 0.0, 0.1) == math.inf
    assert one_pair(0.2, -1.0, 0.0, 0.1) == 0.0
    # with e > 0 and t_b = 0 the row is linear: e t_delay δ ≤ A²  →  δ = 0.79² / (2 · 0.1)
    assert one_pair(1.0, 2.0, 0.0, 0.1) == pytest.approx(0.79**2 / 0.2)


# -- brute force and monotonicity ------------------------------------------------------------------


def test_closed_form_equals_bisection_on_random_instances() -> None:
    rng = np.random.default_rng(10)
    for _ in range(2000):
        d = float(rng.uniform(0.0, 3.0))
        e = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.0, 8.0))
        t_b = float(rng.uniform(0.02, 0.6))
        t_delay = float(rng.uniform(0.0, 0.3))
        expected = bisect(d, e, t_b, t_delay)
        got = min(1.0, one_pair(d, e, t_b, t_delay))
        assert got == pytest.approx(expected, abs=1e-9), (d, e, t_b, t_delay)
        if 0.0 < got < 1.0 and e > 0.0:  # the row binds: equality (e ≤ 0: the human-alone bound, margin 0)
            assert slack(got, d, e, t_b, t_delay) == pytest.approx(0.0, abs=1e-9)


def test_never_below_eq15_with_the_same_clearance() -> None:
    """Eq. (15) at δ = 1 is the speed-aware row at δ = 1: every δ eq. (15) allows, the speed-aware rows allow."""
    rng = np.random.default_rng(11)
    for _ in range(500):
        d, e = float(rng.uniform(0.0, 3.0)), float(rng.uniform(0.01, 8.0))
        t_b, t_delay = float(rng.uniform(0.02, 0.6)), float(rng.uniform(0.0, 0.3))
        f = max(0.0, d - (C + K * (t_b + t_delay))) ** 2
        eq15 = min(1.0, f / ((t_b + t_delay) * e))
        assert min(1.0, one_pair(d, e, t_b, t_delay)) >= eq15 - 1e-12


def test_monotone_closer_or_older_never_raises_delta() -> None:
    rng = np.random.default_rng(12)
    distances = np.linspace(3.0, 0.0, 61)
    delays = np.linspace(0.0, 0.4, 41)
    for _ in range(100):
        e, t_b = float(rng.uniform(0.0, 6.0)), float(rng.uniform(0.02, 0.6))
        u, t_delay = float(rng.uniform(0.0, 2.0)), float(rng.uniform(0.0, 0.3))
        at_fixed_e = [one_pair(float(d), e, t_b, t_delay) for d in distances]
        # a point moving straight at the person: e = (d + radii) u shrinks with d
        straight = [one_pair(float(d), (float(d) + 0.1) * u, t_b, t_delay) for d in distances]
        older = [one_pair(1.2, e, t_b, float(t)) for t in delays]
        for series in (at_fixed_e, straight, older):
            assert all(b <= a + 1e-12 for a, b in itertools.pairwise(series))


def test_nobody_seen_is_full_speed(ur5: RobotModel) -> None:
    """No capsule: nothing bounds δ (inf), so δ = 1, as eq. (15) (an infinite bound is not a nan: not 0)."""
    q, qd = np.asarray(Q), np.asarray(QD_NOMINAL)
    links = link_kinematics(ur5, ur5.model.createData(), q, qd)
    rows = build_rows(links, ur5.link_radius_m, ur5.t_brake_link_s, 0.53, NO_HUMANS, SAFETY, 0.1)
    assert speed_aware_bounds(
        rows.surface_distance_m, rows.e_m2ps, ur5.t_brake_link_s, 0.1, rows.f_m2, C
    ).min_bound == (math.inf)
    x = MethodInput(
        ur5, ur5.model.createData(), q, links, rows, NO_HUMANS, qd, 0.1, 1.0, 0.0, 0.004, link_speed_max_mps(links)
    )
    assert SpeedAware(SAFETY).bound(x) == 1.0
    assert Zanchettin2016(SAFETY).bound(x) == 1.0


def test_close_speed_lowers_the_bound_below_half_a_metre() -> None:
    method = SpeedAware(SafetyConfig())
    k = method.human_speed_pair_mps(np.array([[0.49, 0.5, 1.0]]))
    assert k.tolist() == [[2.0, 1.6, 1.6]]  # ISO 13855 close speed on by default for this method only
    assert SafetyConfig().close_speed_below_m == 0.0


def test_nan_anywhere_gives_zero() -> None:
    assert math.isnan(one_pair(math.nan, 1.0, 0.5, 0.1))
    assert math.isnan(one_pair(1.0, math.nan, 0.5, 0.1))
    assert math.isnan(one_pair(1.0, 1.0, 0.5, math.nan))
    bounds = speed_aware_bounds(
        np.array([[1.0, math.nan]]), np.ones((1, 2, 2, 2)), np.array([0.5]), 0.1, np.full((1, 2), K), C
    )
    assert math.isnan(bounds.min_bound)


# -- its own safety exception ----------------------------------------------------------------------


def test_protection_is_delta_at_the_stop_threshold() -> None:
    safety = SafetyConfig()
    protection = SpeedAware(safety).protection(0.53, 0.13)
    # Δ(0.05) = 0.05 + 2.0 (0.05 · 0.53 + 0.13) = 0.363 m (below 0.5 m: ISO 13855's close speed)
    assert protection == Protection(pytest.approx(0.363), 0.05, 0.1)
    assert speed_aware_clearance_m(safety, 0.0, 0.05, 0.53, 0.13) == pytest.approx(0.05 + 1.6 * 0.1565)
    # the shared Δ of the other methods is unchanged: c + K (max t_b + t_delay)
    assert Zanchettin2016(safety).protection(0.53, 0.13) == Protection(decision_clearance_m(safety, 0.53, 0.13))
    for method in ("zanchettin2016", "iso15066", "stop_only"):
        assert build_method(safety.model_copy(update={"method": method}), {}).protection(0.53, 0.13) == Protection(
            pytest.approx(0.05 + 1.6 * 0.66)
        )


def test_exception_follows_the_bound_threshold_and_resumes_with_hysteresis(cell_config: CellConfig) -> None:
    zones = cell_config.zones
    th = zone_thresholds(zones, 1.1, 0.66, 1.0, Protection(0.363, 0.05, 0.1))
    assert (th.protective_m, th.resume_m) == (0.363, pytest.approx(0.513))
    g = Zone.REDUCED_SPEED
    assert next_zone(g, 0.8, 0.2, th, zones) is Zone.REDUCED_SPEED  # inside eq. (15)'s Δ = 1.1 m: still moving
    assert next_zone(g, 0.8, 0.05, th, zones) is Zone.SAFETY_EXCEPTION  # bound at the stop threshold
    assert next_zone(g, 0.36, 0.5, th, zones) is Zone.SAFETY_EXCEPTION  # within the protective distance
    x = Zone.SAFETY_EXCEPTION
    assert next_zone(x, 0.8, 0.09, th, zones) is Zone.SAFETY_EXCEPTION  # bound not yet above 0.1
    assert next_zone(x, 0.5, 0.5, th, zones) is Zone.SAFETY_EXCEPTION  # not yet beyond resume
    assert next_zone(x, 0.8, 0.11, th, zones) is Zone.REDUCED_SPEED


# -- in the gateway's core with the UR5 ------------------------------------------------------------


def hand_ahead_of_tool(ur5: RobotModel, distance_m: float) -> dict[str, object]:
    """A point hand ``distance_m`` from tool0's surface along its programmed velocity (the worst direction)."""
    links = link_kinematics(ur5, ur5.model.createData(), np.asarray(Q), np.asarray(QD_NOMINAL))
    p = links.p_b_world[-1] + (distance_m + 0.07 + 0.05) * links.v_b_world[-1] / np.linalg.norm(links.v_b_world[-1])
    return {"name": "hand_r", "a": p.tolist(), "b": p.tolist(), "radius": 0.05}


def run_core(config: CellConfig, ur5: RobotModel, hand: dict[str, object], cycles: int = 40) -> list[float]:
    cell = Cell(config, ur5)
    now, deltas = NOW, []
    for _ in range(cycles):
        now += 4 * MS
        cell.feed(now, [hand])
        d = cell.step(now)
        assert d.faults == ()
        assert 0.0 <= d.delta <= d.delta_bound <= 1.0
        deltas.append(d.delta)
    return deltas


def test_moves_near_a_person_where_the_shared_latch_stops(cell_config: CellConfig, ur5: RobotModel) -> None:
    """A hand 0.7 m ahead of the tool, inside eq. (15)'s Δ ≈ 1.1 m: eq. (15) holds δ = 0, the new method moves
    at the speed that can still stop in time (its bound, below eq. (15)'s at δ = 1 of a far person)."""
    speed_aware = cell_config.model_copy(
        update={"safety": cell_config.safety.model_copy(update={"method": "zanchettin2016_speed_aware"})}
    )
    hand = hand_ahead_of_tool(ur5, 0.7)
    assert run_core(cell_config, ur5, hand)[-1] == 0.0
    deltas = run_core(speed_aware, ur5, hand)
    assert 0.05 < deltas[-1] < 0.5
    # closer, or within its own protective distance: stopped
    assert run_core(speed_aware, ur5, hand_ahead_of_tool(ur5, 0.3))[-1] == 0.0
