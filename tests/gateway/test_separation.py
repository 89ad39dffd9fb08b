"""The constraint rows and δ of eq. (15) (safety-math.md §2–§4), and the link kinematics they are built from.

Known answers first (hand-built LinkKinematics, numbers worked out in the comments), then Pinocchio
velocities against finite differences on the real UR5, then invariants over seeded random configurations.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from support.known_cases import (
    CLEARANCE_M,
    HAND_AHEAD,
    HORIZON_S,
    LINK_RADIUS_M,
    LINK_T_BRAKE_S,
    LINK_UP,
    SAFETY,
    T_BRAKE_MAX_S,
    T_DELAY_S,
    human_capsules,
    moving_links,
    point_hands,
)

from gateway import kernels
from gateway.kinematics import LinkKinematics
from gateway.reference import separation as reference_separation
from gateway.reference.kinematics import link_kinematics
from gateway.separation import ConstraintRows, clearance_m, decision_clearance_m, override_from_rows
from hrc_contract.config import SafetyConfig
from hrc_contract.humans import NO_HUMANS, HumanCapsules
from hrc_devices.robots.model import RobotModel

# Every test of the rows runs on both implementations: the numpy reference and the compiled rows of the loop.
IMPLEMENTATIONS = {"numpy": reference_separation.build_rows, "compiled": kernels.build_rows}


@pytest.fixture(params=sorted(IMPLEMENTATIONS))
def build_rows(request: pytest.FixtureRequest):
    return IMPLEMENTATIONS[request.param]


def _rows(
    build_rows,
    links=LINK_UP,
    humans=None,
    safety=SAFETY,
    t_delay=T_DELAY_S,
    radius=LINK_RADIUS_M,
    t_brake=LINK_T_BRAKE_S,
):
    return build_rows(links, radius, t_brake, T_BRAKE_MAX_S, humans, safety, t_delay)


# -- known answers --------------------------------------------------------------------------------


def test_clearance_known_answer() -> None:
    assert pytest.approx(0.05 + 1.6 * (0.5 + 0.1)) == CLEARANCE_M
    got = clearance_m(SAFETY, np.array([0.1, 3.0]), T_BRAKE_MAX_S, T_DELAY_S)
    np.testing.assert_allclose(got, [CLEARANCE_M, CLEARANCE_M])


def test_single_link_moving_straight_at_a_point_hand(build_rows) -> None:
    # known_cases.HAND_AHEAD: d = 1.9, f = 0.7921, e = 4.0 for every row, δ = 0.7921 / (0.4 · 4.0) = 0.4950625
    case = HAND_AHEAD
    rows = _rows(build_rows, humans=case.humans)
    assert rows.surface_distance_m[0, 0] == pytest.approx(case.distance_m)
    assert rows.clearance_m[0, 0] == pytest.approx(CLEARANCE_M)
    assert rows.f_m2[0, 0] == pytest.approx(case.f_m2)
    np.testing.assert_allclose(rows.e_m2ps[0, 0], np.full((2, 2), case.e_m2ps))
    np.testing.assert_allclose(rows.horizon_s, [HORIZON_S])
    np.testing.assert_allclose(rows.bound[0, 0], np.full((2, 2), case.delta))
    assert override_from_rows(rows) == pytest.approx(case.delta)


def test_rotating_link_and_capsule_hand_corners(build_rows) -> None:
    """Rows are indexed [link, capsule, link end, capsule end]; the farther capsule end decides."""
    # link rotating about its end a (v_a = 0, v_b = (0, 2, 0)); forearm capsule from (0.4, 1.5, 0) to (0.4, 1.8, 0),
    # radius 0.1: centre-line distance 1.5 (r_b to h_a), d = 1.5 − 0.05 − 0.1 = 1.35, f = (1.35 − 1.01)² = 0.1156
    # e: end a → 0 (not moving); end b → (0, 1.5, 0)·(0, 2, 0) = 3.0 and (0, 1.8, 0)·(0, 2, 0) = 3.6
    # δ = 0.1156 / (0.4 · 3.6) = 0.080277…
    links = moving_links((0, 0, 0), (0.4, 0, 0), (0, 0, 0), (0, 2, 0))
    rows = _rows(build_rows, links=links, humans=human_capsules([(0.4, 1.5, 0)], [(0.4, 1.8, 0)], 0.1))
    assert rows.surface_distance_m[0, 0] == pytest.approx(1.35)
    assert rows.f_m2[0, 0] == pytest.approx(0.1156)
    np.testing.assert_allclose(rows.e_m2ps[0, 0], [[0.0, 0.0], [3.0, 3.6]], atol=1e-12)
    assert np.isinf(rows.bound[0, 0, 0]).all()
    np.testing.assert_allclose(rows.bound[0, 0, 1], [0.1156 / 1.2, 0.1156 / 1.44])
    assert override_from_rows(rows) == pytest.approx(0.1156 / 1.44)


def test_horizon_uses_each_links_braking_time(build_rows) -> None:
    # Two copies of the link, t_b,→i = 0.3 and 0.6 s: bounds 0.7921 / (0.4 · 4) and 0.7921 / (0.7 · 4).
    # Δ uses t_b,max = 0.5 for both, so f is the same.
    links = moving_links(*(np.repeat(np.atleast_2d(x), 2, axis=0) for x in LINK_UP))
    rows = _rows(
        build_rows,
        links=links,
        humans=HAND_AHEAD.humans,
        radius=np.array([0.05, 0.05]),
        t_brake=np.array([0.3, 0.6]),
    )
    np.testing.assert_allclose(rows.horizon_s, [0.4, 0.7])
    np.testing.assert_allclose(rows.f_m2[:, 0], [0.7921, 0.7921])
    assert override_from_rows(rows) == pytest.approx(0.7921 / 2.8)


def test_nearer_human_decides(build_rows) -> None:
    """δ is the MINIMUM of the bounds; paper 1's "max" would let the farther human decide."""
    # farther: (0.2, 2.3, 0): d = 2.2, f = 1.19² = 1.4161, e = 2.3 · 2 = 4.6, bound = 1.4161 / 1.84 = 0.76962…
    # nearer: HAND_AHEAD at (0.2, 2.0, 0): bound 0.4950625
    rows = _rows(build_rows, humans=point_hands([(0.2, 2.3, 0.0), (0.2, 2.0, 0.0)]))
    np.testing.assert_allclose(rows.bound[0, 0], np.full((2, 2), 1.4161 / 1.84))
    np.testing.assert_allclose(rows.bound[0, 1], np.full((2, 2), HAND_AHEAD.delta))
    delta = override_from_rows(rows)
    assert delta == pytest.approx(HAND_AHEAD.delta)
    assert delta != pytest.approx(1.4161 / 1.84)  # what a max-of-bounds implementation would return


def test_clamp_then_square(build_rows) -> None:
    # hand at (0.2, 0.8, 0): d = 0.7 < Δ = 1.01 while approaching (e = 1.6 > 0).
    # Right: f = max(0, 0.7 − 1.01)² = 0 → δ = 0.
    # Squaring first would give f = 0.31² = 0.0961 and δ = 0.0961 / (0.4 · 1.6) = 0.15.
    rows = _rows(build_rows, humans=point_hands([(0.2, 0.8, 0.0)]))
    assert rows.surface_distance_m[0, 0] == pytest.approx(0.7)
    assert rows.f_m2[0, 0] == 0.0
    np.testing.assert_allclose(rows.e_m2ps[0, 0], np.full((2, 2), 1.6))
    assert override_from_rows(rows) == 0.0


def test_touching_while_approaching_gives_zero(build_rows) -> None:
    # centre-line distance 0.05 < sum of radii 0.1: d = 0 (clamped), f = 0, e = 0.05 · 2 = 0.1 > 0 → δ = 0
    rows = _rows(build_rows, humans=point_hands([(0.2, 0.05, 0.0)]))
    assert rows.surface_distance_m[0, 0] == 0.0
    assert rows.f_m2[0, 0] == 0.0
    assert override_from_rows(rows) == 0.0


def test_retreating_link_is_not_slowed_even_when_close(build_rows) -> None:
    # same hand at 0.7 m (inside Δ), link moving at −y: e = 0.8 · (−2) = −1.6 ≤ 0 for every row → no bound
    retreating = moving_links((0, 0, 0), (0.4, 0, 0), (0, -2, 0), (0, -2, 0))
    rows = _rows(build_rows, links=retreating, humans=point_hands([(0.2, 0.8, 0.0)]))
    assert rows.f_m2[0, 0] == 0.0
    assert (rows.e_m2ps < 0).all()
    assert np.isinf(rows.bound).all()
    assert override_from_rows(rows) == 1.0


def test_sideways_link_is_not_bounded(build_rows) -> None:
    # link moving along z, hand in the x–y plane: e = (h − r)ᵀ v = 0 for every row
    sideways = moving_links((0, 0, 0), (0.4, 0, 0), (0, 0, 2), (0, 0, 2))
    rows = _rows(build_rows, links=sideways, humans=point_hands([(0.2, 0.8, 0.0)]))
    np.testing.assert_allclose(rows.e_m2ps, 0.0, atol=1e-15)
    assert override_from_rows(rows) == 1.0


def test_axial_translation_is_bounded_by_the_leading_end(build_rows) -> None:
    # link sliding along +x at 1 m/s, hand above its middle at 2 m: e_a = 0.2 · 1 = 0.2 > 0, e_b = −0.2 ≤ 0
    # δ = 0.7921 / (0.4 · 0.2) = 9.9 → clipped to 1; with 10 m/s: 0.7921 / (0.4 · 2) = 0.990125
    sliding = moving_links((0, 0, 0), (0.4, 0, 0), (10, 0, 0), (10, 0, 0))
    rows = _rows(build_rows, links=sliding, humans=point_hands([(0.2, 2.0, 0.0)]))
    np.testing.assert_allclose(rows.e_m2ps[0, 0], [[2.0, 2.0], [-2.0, -2.0]])
    assert override_from_rows(rows) == pytest.approx(0.990125)


def test_no_humans_gives_full_speed(build_rows) -> None:
    rows = _rows(build_rows, humans=NO_HUMANS)
    assert rows.bound.shape == (1, 0, 2, 2)
    assert override_from_rows(rows) == 1.0


def test_iso13855_close_speed_switch_raises_the_clearance_below_the_threshold(build_rows) -> None:
    iso = SafetyConfig(close_speed_below_m=0.5, human_speed_close_mps=2.0)
    # below 0.5 m: Δ = 0.05 + 2.0 · 0.6 = 1.25; at or above: 1.01 as without the switch
    np.testing.assert_allclose(clearance_m(iso, np.array([0.3, 0.499, 0.5, 1.9]), 0.5, 0.1), [1.25, 1.25, 1.01, 1.01])
    np.testing.assert_allclose(clearance_m(SAFETY, np.array([0.3, 1.9]), 0.5, 0.1), [1.01, 1.01])
    # the decision's Δ (plain floats in the core): at K, or at the close speed where that falls below the threshold
    for safety in (iso, SAFETY):
        far = clearance_m(safety, np.array([np.inf]), 0.5, 0.1)
        assert decision_clearance_m(safety, 0.5, 0.1) == float(clearance_m(safety, far, 0.5, 0.1)[0])
    fast = SafetyConfig(close_speed_below_m=0.5)  # Δ at K = 0.05 + 1.6 · 0.15 = 0.29 m < 0.5 m: K close applies
    assert decision_clearance_m(fast, 0.05, 0.1) == pytest.approx(0.05 + 2.0 * 0.15)
    rows = _rows(build_rows, humans=point_hands([(0.2, 0.4, 0.0), (0.2, 2.0, 0.0)]), safety=iso)
    # the first hand is at d = 0.3 m, the second at 1.9 m
    np.testing.assert_allclose(rows.clearance_m[0], [1.25, 1.01])
    assert override_from_rows(rows) == 0.0


def test_iso13855_switch_changes_delta_below_the_threshold(build_rows) -> None:
    # A fast-braking setup where the switch matters for δ: Δ = 0.05 + K · 0.1 with t_b,max = 0.05, t_delay = 0.05.
    # hand at d = 0.4: K = 1.6 → Δ = 0.21, f = 0.19² = 0.0361; K = 2.0 → Δ = 0.25, f = 0.15² = 0.0225.
    # e = 0.5 · 2 = 1.0 (centre-line 0.5), T = 0.3 + 0.05 = 0.35: δ = 0.0361 / 0.35 and 0.0225 / 0.35.
    iso = SafetyConfig(close_speed_below_m=0.5)
    humans = point_hands([(0.2, 0.5, 0.0)])
    off = build_rows(LINK_UP, LINK_RADIUS_M, LINK_T_BRAKE_S, 0.05, humans, SAFETY, 0.05)
    on = build_rows(LINK_UP, LINK_RADIUS_M, LINK_T_BRAKE_S, 0.05, humans, iso, 0.05)
    assert override_from_rows(off) == pytest.approx(0.0361 / 0.35)
    assert override_from_rows(on) == pytest.approx(0.0225 / 0.35)


def test_closer_can_legitimately_raise_delta_for_a_spinning_sliding_link(build_rows) -> None:
    """Why the 'human comes closer' invariant below needs care (safety-math.md §4 taken literally).

    A 4 m link from (0,0,0) to (4,0,0) slides along −x while it spins about its middle (rigid:
    (r_b − r_a)ᵀ(v_b − v_a) = (4,0,0)ᵀ(0,−20,0) = 0): v_a = (−10, 10, 0), v_b = (−10, −10, 0).
    A point hand (radius 0) at (2, y, 0): d = y, e_a = (2, y)ᵀ(−10, 10) = 10 (y − 2), e_b = −10 (y − 2) ≤ 0.
    With Δ = 1.01 and T = 0.6 (t_b,→i = 0.5): δ(y) = (y − 1.01)² / (6 (y − 2)), which DEcreases in y on (2, 2.99).
    y = 2.9: δ = 1.89² / 5.4 = 0.661500; y = 2.4 (closer): δ = 1.39² / 2.4 = 0.805042 — larger.
    The bound f / (T e) depends on (h − r)ᵀ v, which shrinks faster than f here.
    """
    links = moving_links((0, 0, 0), (4, 0, 0), (-10, 10, 0), (-10, -10, 0))
    deltas = []
    for y in (2.9, 2.4):
        rows = build_rows(links, np.zeros(1), np.array([0.5]), 0.5, point_hands([(2, y, 0)], 0.0), SAFETY, 0.1)
        deltas.append(override_from_rows(rows))
    assert deltas[0] == pytest.approx(1.89**2 / 5.4)
    assert deltas[1] == pytest.approx(1.39**2 / 2.4)
    assert deltas[1] > deltas[0]


# -- link kinematics on the real UR5 -----------------------------------------------------------


def test_ur5_zero_configuration_known_answer(ur5: RobotModel) -> None:
    """At q = 0 the UR5 is stretched along +x (DH: a2 = 0.425, a3 = 0.39225, d4 = 0.10915, d5 = 0.09465,
    d6 = 0.0823, d1 = 0.089159), on its 0.8 m pedestal. Turning the base at 1 rad/s moves tool0 at ω × r."""
    data = ur5.model.createData()
    qd = np.array([1.0, 0, 0, 0, 0, 0])
    links = link_kinematics(ur5, data, np.zeros(6), qd)
    assert ur5.link_names[-1] == "tool"
    np.testing.assert_allclose(links.p_a_world[0], [0, 0, 0.8], atol=1e-12)
    tool0 = np.array([0.81725, 0.10915 + 0.0823, 0.8 + 0.089159 - 0.09465])
    np.testing.assert_allclose(links.p_b_world[-1], tool0, atol=1e-9)
    np.testing.assert_allclose(links.v_b_world[-1], [-tool0[1], tool0[0], 0.0], atol=1e-9)
    # the base link's two end points lie on the base axis: they do not move
    np.testing.assert_allclose(links.v_a_world[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(links.v_b_world[0], 0.0, atol=1e-12)


def _random_state(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    return rng.uniform(-np.pi, np.pi, 6), rng.uniform(-2.0, 2.0, 6)


def test_velocities_equal_finite_differences(ur5: RobotModel) -> None:
    rng = np.random.default_rng(3)
    data = ur5.model.createData()
    h = 1e-6
    for _ in range(25):
        q, qd = _random_state(rng)
        links = link_kinematics(ur5, data, q, qd)
        plus = link_kinematics(ur5, data, q + h * qd, np.zeros(6))
        minus = link_kinematics(ur5, data, q - h * qd, np.zeros(6))
        v_a_fd = (plus.p_a_world - minus.p_a_world) / (2 * h)
        v_b_fd = (plus.p_b_world - minus.p_b_world) / (2 * h)
        np.testing.assert_allclose(links.v_a_world, v_a_fd, atol=1e-7)
        np.testing.assert_allclose(links.v_b_world, v_b_fd, atol=1e-7)
        # the segments are rigid: (r_b − r_a)ᵀ(v_b − v_a) = 0 (safety-math.md §2)
        rigid = ((links.p_b_world - links.p_a_world) * (links.v_b_world - links.v_a_world)).sum(-1)
        np.testing.assert_allclose(rigid, 0.0, atol=1e-9)


def test_rows_e_equal_finite_difference_projection(build_rows, ur5: RobotModel) -> None:
    """e[i, j, k, m] = (h_m − r_k)ᵀ v_k with v_k from finite differences of the end-point positions."""
    rng = np.random.default_rng(4)
    data = ur5.model.createData()
    h = 1e-6
    for _ in range(15):
        q, qd = _random_state(rng)
        humans = _random_humans(rng, 3)
        links = link_kinematics(ur5, data, q, qd)
        rows = build_rows(
            links, ur5.link_radius_m, ur5.t_brake_link_s, float(ur5.braking_time_s.max()), humans, SAFETY, 0.1
        )
        plus = link_kinematics(ur5, data, q + h * qd, np.zeros(6))
        minus = link_kinematics(ur5, data, q - h * qd, np.zeros(6))
        ends = ((links.p_a_world, plus.p_a_world, minus.p_a_world), (links.p_b_world, plus.p_b_world, minus.p_b_world))
        for i in range(len(ur5.link_names)):
            for j in range(humans.n_capsules):
                for k, (r, p_plus, p_minus) in enumerate(ends):
                    v_fd = (p_plus[i] - p_minus[i]) / (2 * h)
                    for m, h_end in enumerate((humans.h_a_world[j], humans.h_b_world[j])):
                        assert rows.e_m2ps[i, j, k, m] == pytest.approx(float((h_end - r[i]) @ v_fd), abs=1e-6)


# -- invariants over seeded random configurations -----------------------------------------------


def _random_humans(rng: np.random.Generator, n: int) -> HumanCapsules:
    """n capsules around the UR5 (base at (0, 0, 0.8)): centres 0.5–5 m from the base axis, 0–2 m high, up to
    0.6 m long (Δ is about 1–1.5 m, so near, mid and far cases all occur)."""
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n)
    reach = rng.uniform(0.5, 5.0, n)
    centre = np.column_stack((reach * np.cos(azimuth), reach * np.sin(azimuth), rng.uniform(0.0, 2.0, n)))
    half = rng.normal(size=(n, 3))
    half *= (rng.uniform(0.0, 0.3, n) / np.linalg.norm(half, axis=1))[:, None]
    half[rng.random(n) < 0.2] = 0.0  # some point obstacles
    return HumanCapsules(
        centre - half, centre + half, rng.uniform(0.0, 0.15, n), tuple(f"h{i}" for i in range(n)), ("c",) * n
    )


def _subset(humans: HumanCapsules, index) -> HumanCapsules:
    index = np.asarray(index, dtype=int)
    return HumanCapsules(
        humans.h_a_world[index],
        humans.h_b_world[index],
        humans.radius_m[index],
        tuple(humans.human_ids[i] for i in index),
        tuple(humans.capsule_names[i] for i in index),
    )


def _delta(
    build_rows, ur5: RobotModel, links: LinkKinematics, humans: HumanCapsules, safety: SafetyConfig, t_delay: float
):
    rows = build_rows(
        links, ur5.link_radius_m, ur5.t_brake_link_s, float(ur5.braking_time_s.max()), humans, safety, t_delay
    )
    return override_from_rows(rows)


SAFETY_VARIANTS = (SAFETY, SafetyConfig(close_speed_below_m=0.5), SafetyConfig(clearance_static_m=0.0))
N_CASES = 240


def _cases(ur5: RobotModel, seed: int):
    """Random UR5 states at up to 2.5 rad/s per joint, 1–3 random capsules, a random delay, a safety variant."""
    rng = np.random.default_rng(seed)
    data = ur5.model.createData()
    for k in range(N_CASES):
        q = rng.uniform(-np.pi, np.pi, 6)
        qd = rng.uniform(-2.5, 2.5, 6)
        links = link_kinematics(ur5, data, q, qd)
        yield rng, links, _random_humans(rng, int(rng.integers(1, 4))), SAFETY_VARIANTS[k % 3], rng.uniform(0, 0.3)


def test_delta_in_unit_interval_and_not_trivial(build_rows, ur5: RobotModel) -> None:
    deltas = [
        _delta(build_rows, ur5, links, humans, safety, t_delay)
        for _, links, humans, safety, t_delay in _cases(ur5, 100)
    ]
    deltas = np.array(deltas)
    assert ((deltas >= 0.0) & (deltas <= 1.0)).all()
    # the random cases cover all three regimes, so the invariants below have teeth
    assert (deltas == 0.0).sum() >= 10
    assert (deltas == 1.0).sum() >= 10
    assert ((deltas > 0.0) & (deltas < 1.0)).sum() >= 40


def test_delta_does_not_rise_when_the_delay_grows(build_rows, ur5: RobotModel) -> None:
    strictly_lower = 0
    for rng, links, humans, safety, t_delay in _cases(ur5, 101):
        before = _delta(build_rows, ur5, links, humans, safety, t_delay)
        after = _delta(build_rows, ur5, links, humans, safety, t_delay + rng.uniform(0.001, 0.2))
        assert after <= before + 1e-12
        strictly_lower += after < before
    assert strictly_lower >= 40


def test_adding_capsules_or_humans_never_raises_delta(build_rows, ur5: RobotModel) -> None:
    """More capsules = more rows; every row is an upper bound, so δ can only go down."""
    strictly_lower = 0
    for rng, links, humans, safety, t_delay in _cases(ur5, 102):
        extra = _random_humans(rng, int(rng.integers(1, 4)))
        everyone = _subset(humans, range(humans.n_capsules))  # copy
        everyone = HumanCapsules(
            np.concatenate([everyone.h_a_world, extra.h_a_world]),
            np.concatenate([everyone.h_b_world, extra.h_b_world]),
            np.concatenate([everyone.radius_m, extra.radius_m]),
            everyone.human_ids + tuple(f"x{i}" for i in range(extra.n_capsules)),
            everyone.capsule_names + extra.capsule_names,
        )
        alone = _delta(build_rows, ur5, links, humans, safety, t_delay)
        together = _delta(build_rows, ur5, links, everyone, safety, t_delay)
        assert together <= alone + 1e-12
        assert together == pytest.approx(min(alone, _delta(build_rows, ur5, links, extra, safety, t_delay)), abs=1e-12)
        strictly_lower += together < alone
        # and the order of the capsules does not matter
        shuffled = _subset(everyone, rng.permutation(everyone.n_capsules))
        assert _delta(build_rows, ur5, links, shuffled, safety, t_delay) == pytest.approx(together, abs=1e-12)
    assert strictly_lower >= 20


def test_delta_does_not_rise_when_a_human_comes_closer_to_a_point_like_link(build_rows, ur5: RobotModel) -> None:
    """Moving closer, in the form for which safety-math.md §4 guarantees it.

    A naive "move the capsule toward the robot" can legitimately raise δ (see
    test_closer_can_legitimately_raise_delta_for_a_spinning_sliding_link): the bound f / (T e) also depends
    on (h − r)ᵀ v. For a point-like link r (r_a = r_b, here a UR5 link end point with its true velocity) and
    a homothety of every capsule toward r by λ ∈ (0, 1]: the centre-line distance becomes λD and every
    e becomes λe (sign kept), so each bound becomes max(0, λD − c)² / (T λ e), increasing in λ for λD > c
    (derivative ∝ (λD − c)(λD + c)) and 0 below; with the ISO switch, Δ can only jump up as d falls.
    So δ never rises as λ falls.
    """
    strictly_lower = 0
    for rng, links, humans, safety, t_delay in _cases(ur5, 103):
        i = int(rng.integers(len(ur5.link_names)))
        end = int(rng.integers(2))
        r = (links.p_a_world, links.p_b_world)[end][i]
        v = (links.v_a_world, links.v_b_world)[end][i]
        point_link = moving_links(r, r, v, v)
        radius, t_brake = ur5.link_radius_m[i : i + 1], ur5.t_brake_link_s[i : i + 1]
        t_brake_max = float(ur5.braking_time_s.max())
        lam = rng.uniform(0.2, 1.0, humans.n_capsules)[:, None]
        closer = humans._replace(h_a_world=r + lam * (humans.h_a_world - r), h_b_world=r + lam * (humans.h_b_world - r))
        before, after = (
            override_from_rows(build_rows(point_link, radius, t_brake, t_brake_max, h, safety, t_delay))
            for h in (humans, closer)
        )
        assert after <= before + 1e-12
        strictly_lower += after < before
    assert strictly_lower >= 20


def test_a_bound_that_is_not_a_number_stops_the_robot() -> None:
    rows = ConstraintRows(*(np.zeros(0),) * 6, min_bound=math.nan)
    assert override_from_rows(rows) == 0.0
    assert override_from_rows(rows._replace(min_bound=-3.0)) == 0.0
    assert override_from_rows(rows._replace(min_bound=math.inf)) == 1.0
