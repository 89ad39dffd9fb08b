"""The baseline methods' math: ISO/TS 15066 SSM and QP (12) in closed form, three zones, stop-only, eq. (16).

Known answers first (computed by hand here: neither ISO/TS 15066's SSM clause nor Pupa et al. 2021 give
worked numbers in the text available to us), then brute-force checks over seeded random instances.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
import pytest
from pydantic import ValidationError
from support.known_cases import SAFETY, Q, moving_links, point_hands

from gateway import iso15066
from gateway.kinematics import LinkKinematics
from gateway.methods import (
    REDUCED_DELTA,
    MethodInput,
    ReplanMonitor,
    StopOnly,
    ThreeZones,
    build_method,
    finite_or_zero,
    point_surface_distance_m,
    stop_only_distance_m,
    three_zones_override,
)
from gateway.reference import iso15066 as reference_iso15066
from gateway.reference.kinematics import link_kinematics, link_speed_max_mps
from gateway.reference.separation import build_rows
from hrc_contract.config import SAFETY_METHODS, ConfigError, SafetyConfig
from hrc_contract.humans import HumanCapsules
from hrc_devices.robots.model import RobotModel

POINT_2M = point_hands([(2, 0, 0)], 0.0)
"""A point (radius 0) on the x axis, 2 m from the origin."""

# -- v_r,max of ISO/TS 15066 (safety-math.md §7) ----------------------------------------------------


def test_v_r_max_known_answer() -> None:
    # v_h = 1.6, T_r = 0.1, a_s = 2, B = 1.6: sqrt(2.56 + 0.04 + 6.4) − 1.6 − 0.2 = 3 − 1.8 = 1.2
    assert float(iso15066.v_r_max_mps(1.6, 1.6, 0.1, 2.0)) == pytest.approx(1.2)
    # and back: S_h = 1.6 (0.1 + 0.6) = 1.12, S_r = 0.12, S_s = 1.44 / 4 = 0.36 → 1.6
    assert float(reference_iso15066.protective_distance_m(1.2, 1.6, 0.1, 2.0)) == pytest.approx(1.6)
    # v_h = 2, T_r = 0.5, a_s = 4, B = 3.5: sqrt(4 + 4 + 28) − 2 − 2 = 2; S_p = 2·1 + 1 + 0.5 = 3.5
    assert float(iso15066.v_r_max_mps(3.5, 2.0, 0.5, 4.0)) == pytest.approx(2.0)
    assert float(reference_iso15066.protective_distance_m(2.0, 2.0, 0.5, 4.0)) == pytest.approx(3.5)


def test_v_r_max_subtracts_c_and_uncertainties() -> None:
    # S = 1.8 with C = 0.05, Z_d = 0.1, Z_r = 0.05 is B = 1.6 of the first known answer
    assert float(iso15066.v_r_max_mps(1.8, 1.6, 0.1, 2.0, 0.05, 0.1, 0.05)) == pytest.approx(1.2)
    assert float(reference_iso15066.protective_distance_m(1.2, 1.6, 0.1, 2.0, 0.05, 0.1, 0.05)) == pytest.approx(1.8)


@pytest.mark.parametrize("b_minus_vh_tr", [0.0, -1e-9, -0.3, -5.0])
def test_v_r_max_is_zero_when_the_human_alone_closes_the_gap(b_minus_vh_tr: float) -> None:
    v_h, t_r, c = 1.6, 0.2, 0.05
    separation = v_h * t_r + c + b_minus_vh_tr  # B = S − C ≤ v_h T_r
    for a_s in (0.1, 2.0, 50.0):
        assert float(iso15066.v_r_max_mps(separation, v_h, t_r, a_s, c)) == 0.0


def test_v_r_max_solves_s_p_equals_s_brute_force() -> None:
    """S_p(v_r,max) = S, and v_r,max is the largest speed of a fine grid with S_p(v) ≤ S."""
    rng = np.random.default_rng(15066)
    grid = np.linspace(0.0, 15.0, 300_001)  # step 5e-5 m/s
    for _ in range(40):
        v_h = rng.uniform(1.6, 2.5)
        t_r = rng.uniform(0.0, 0.5)
        a_s = rng.uniform(0.3, 20.0)
        c, z_d, z_r = rng.uniform(0.0, 0.2, 3)
        separation = rng.uniform(0.0, 4.0)
        v = float(iso15066.v_r_max_mps(separation, v_h, t_r, a_s, c, z_d, z_r))
        ok = reference_iso15066.protective_distance_m(grid, v_h, t_r, a_s, c, z_d, z_r) <= separation
        assert v < grid[-1]
        if v > 0.0:
            assert float(reference_iso15066.protective_distance_m(v, v_h, t_r, a_s, c, z_d, z_r)) == pytest.approx(
                separation
            )
            assert grid[ok].max() == pytest.approx(v, abs=5e-5)
        else:  # not even v = 0 keeps S_p ≤ S: B ≤ v_h T_r
            assert separation - c - z_d - z_r <= v_h * t_r + 1e-12
            assert not ok[1:].any()


# -- δ of one point with a_s = v / t_b (the controller's stop) ---------------------------------------


def test_delta_max_is_v_r_max_over_v() -> None:
    rng = np.random.default_rng(7)
    v = rng.uniform(0.01, 3.0, 200)
    separation = rng.uniform(0.0, 4.0, 200)
    t_r = rng.uniform(0.0, 0.4, 200)
    t_b = rng.uniform(0.05, 0.6, 200)
    delta = iso15066.delta_max(v, separation, 1.6, t_r, t_b, 0.05)
    assert delta == pytest.approx(iso15066.v_r_max_mps(separation, 1.6, t_r, v / t_b, 0.05) / v, rel=1e-9, abs=1e-12)


def test_delta_max_known_answer_and_stop_time() -> None:
    # v = 2 m/s, t_b = 0.5 s → a_s = 4; v_h = 2, T_r = 0.5, B = 3.5 → v_r,max = 2 → δ = 1; T_s = δ t_b = 0.5
    assert float(iso15066.delta_max(2.0, 3.5, 2.0, 0.5, 0.5)) == pytest.approx(1.0)
    # the same point at twice the programmed speed may use half of it
    v_max = float(iso15066.v_r_max_mps(3.5, 2.0, 0.5, 8.0))
    assert float(iso15066.delta_max(4.0, 3.5, 2.0, 0.5, 0.5)) == pytest.approx(v_max / 4.0)


def test_delta_max_edges() -> None:
    assert float(iso15066.delta_max(0.0, 1.0, 1.6, 0.1, 0.5)) == math.inf  # not approaching
    assert float(iso15066.delta_max(-1.0, 1.0, 1.6, 0.1, 0.5)) == math.inf  # moving away
    assert float(iso15066.delta_max(1.0, 0.16, 1.6, 0.1, 0.5)) == 0.0  # B = v_h T_r
    # v → 0: finite, the limit (B − v_h T_r) / (v_h t_b) · (1 / v) · v … = v_r,max / v stays finite
    small = float(iso15066.delta_max(1e-12, 1.0, 1.6, 0.1, 0.5))
    assert small == pytest.approx((1.0 - 0.16) / (1.6 * 0.5), rel=1e-6)


def test_delta_max_brute_force_over_delta() -> None:
    """The largest δ of a grid with S_p(δ v; a_s = v/t_b) ≤ S."""
    rng = np.random.default_rng(12)
    grid = np.linspace(0.0, 20.0, 400_001)  # step 5e-5
    for _ in range(30):
        v, t_b = rng.uniform(0.05, 3.0), rng.uniform(0.05, 0.6)
        v_h, t_r, separation = rng.uniform(1.6, 2.0), rng.uniform(0.0, 0.3), rng.uniform(0.3, 3.0)
        delta = float(iso15066.delta_max(v, separation, v_h, t_r, t_b))
        ok = reference_iso15066.protective_distance_m(grid * v, v_h, t_r, v / t_b) <= separation
        assert delta < grid[-1]
        if delta > 0.0:
            assert grid[ok].max() == pytest.approx(delta, abs=5e-5)


# -- ISO rows: the points and their speeds toward the human ----------------------------------------


def test_rows_translating_link_straight_at_a_point() -> None:
    links = moving_links((0, 0, 0), (0.1, 0, 0), (1, 0, 0), (1, 0, 0))
    humans = point_hands([(1.0, 0.0, 0.0)], 0.05)
    rows = iso15066.iso_rows(links, np.array([0.05]), np.array([0.5]), humans, SAFETY, 0.1)
    assert rows.separation_m[0, 0] == pytest.approx(1.0 - 0.1 - 0.05 - 0.05)
    assert rows.v_toward_mps[0, 0] == pytest.approx([1.0, 1.0, 1.0])
    # v = 1 m/s, t_b = 0.5 s → a_s = 2 m/s²; v_h = 1.6, T_r = 0.1, B = 0.8 − C = 0.75:
    # v_r,max = sqrt(2.56 + 0.04 + 3.0) − 1.6 − 0.2 = sqrt(5.6) − 1.8 ≈ 0.566, and δ = v_r,max / v
    expected = math.sqrt(5.6) - 1.8
    assert rows.bound[0, 0] == pytest.approx([expected] * 3)
    assert iso15066.override(rows, math.inf) == pytest.approx(expected)


@pytest.mark.parametrize("velocity", [(0, 1, 0), (0, 0, -1), (-1, 0, 0)])
def test_rows_sideways_or_away_bound_nothing(velocity: tuple[float, float, float]) -> None:
    links = moving_links((0, 0, 0), (0.1, 0, 0), velocity, velocity)
    rows = iso15066.iso_rows(links, np.array([0.05]), np.array([0.5]), POINT_2M, SAFETY, 0.1)
    assert np.all(rows.v_toward_mps <= 1e-12)
    assert np.all(np.isinf(rows.bound))
    assert iso15066.override(rows, math.inf) == 1.0


def test_rows_rotating_link_end_points_and_closest_point() -> None:
    # a link from the origin (fixed) to (1, 0, 0) turning about z: v_b = (0, 1, 0); a point at (0.5, 1, 0)
    links = moving_links((0, 0, 0), (1, 0, 0), (0, 0, 0), (0, 1, 0))
    rows = iso15066.iso_rows(links, np.array([0.0]), np.array([0.5]), point_hands([(0.5, 1, 0)], 0.0), SAFETY, 0.1)
    # end a: still; end b: (0, 1, 0)·(−0.5, 1, 0)/√1.25; closest point (0.5, 0, 0) moves at 0.5 straight at it
    assert rows.v_toward_mps[0, 0] == pytest.approx([0.0, 1.0 / math.sqrt(1.25), 0.5])
    assert rows.separation_m[0, 0] == pytest.approx(1.0)
    assert rows.bound[0, 0, 0] == math.inf


def test_rows_use_the_close_human_speed_below_its_distance() -> None:
    safety = SafetyConfig(close_speed_below_m=0.5)
    links = moving_links((0, 0, 0), (0.1, 0, 0), (1, 0, 0), (1, 0, 0))
    near = iso15066.iso_rows(links, np.array([0.0]), np.array([0.5]), point_hands([(0.5, 0, 0)], 0.0), safety, 0.1)
    far = iso15066.iso_rows(links, np.array([0.0]), np.array([0.5]), point_hands([(0.7, 0, 0)], 0.0), safety, 0.1)
    assert near.v_h_mps[0, 0] == 2.0
    assert far.v_h_mps[0, 0] == 1.6


# -- QP (12) in closed form against a brute-force scan of δ -----------------------------------------


def test_joint_limit_bound_known_answer() -> None:
    qd = np.array([2.0, -1.0, 0.0])
    limit = np.array([3.15, 3.15, 3.15])
    # velocity: 3.15 / 2 = 1.575; acceleration: 0.3 + 0.004 · 10 / 2 = 0.32
    assert iso15066.joint_limit_bound(qd, limit, 10.0, 0.3, 0.004) == pytest.approx(0.32)
    assert iso15066.joint_limit_bound(qd, limit, 1e6, 0.3, 0.004) == pytest.approx(1.575)
    assert iso15066.joint_limit_bound(np.zeros(3), limit, 10.0, 0.0, 0.004) == math.inf
    no_limits = np.array([0.0, math.inf, 0.1])  # none for the moving joints; joint 3 does not move
    assert iso15066.joint_limit_bound(qd, no_limits, 10.0, 0.0, 0.004) == pytest.approx(0.004 * 10.0 / 2.0)


def _random_instance(rng: np.random.Generator) -> tuple[iso15066.Iso15066Rows, dict[str, object]]:
    n_links, n_capsules = 3, 2
    p_a = rng.uniform(-0.5, 0.5, (n_links, 3))
    p_b = p_a + rng.normal(0.0, 0.3, (n_links, 3))
    omega, v0 = rng.normal(0.0, 1.5, (n_links, 3)), rng.normal(0.0, 0.8, (n_links, 3))
    v_a, v_b = v0, v0 + np.cross(omega, p_b - p_a)  # rigid links
    links = LinkKinematics(p_a, p_b, v_a, v_b)
    relaxed = rng.uniform() < 0.2  # humans far away, slow joints: nothing but δ ≤ 1 binds
    h_a = rng.uniform(-2.0, 2.0, (n_capsules, 3)) + (20.0 if relaxed else 0.0)
    humans = HumanCapsules(
        h_a, h_a + rng.normal(0.0, 0.3, (n_capsules, 3)), rng.uniform(0.0, 0.15, n_capsules), ("a", "b"), ("x", "y")
    )
    safety = SafetyConfig(
        iso15066_human_uncertainty_m=rng.uniform(0.0, 0.1), iso15066_robot_uncertainty_m=rng.uniform(0.0, 0.05)
    )
    t_b = rng.uniform(0.1, 0.6, n_links)
    t_r = rng.uniform(0.02, 0.3)
    rows = iso15066.iso_rows(links, rng.uniform(0.0, 0.08, n_links), t_b, humans, safety, t_r)
    params = {
        "qd": rng.normal(0.0, 0.05 if relaxed else 1.5, 6),
        "vlim": rng.uniform(0.5, 3.2, 6),
        "alim": float(rng.uniform(1.0, 40.0)),
        "prev": float(rng.uniform(0.0, 1.0)),
        "period": float(rng.uniform(0.002, 0.02)),
        "t_b": t_b,
        "t_r": t_r,
        "margin": safety.clearance_static_m + safety.iso15066_human_uncertainty_m + safety.iso15066_robot_uncertainty_m,
    }
    return rows, params


def test_qp_closed_form_against_a_brute_force_scan_of_delta() -> None:
    """max δ subject to every row of QP (12) written out: δ v_k ≤ v_r,max,k, |δ q̇_nom| ≤ q̇_max,
    (δ − δ_prev) |q̇_nom| ≤ q̈_max T, 0 ≤ δ ≤ 1 — scanned on a grid, compared with the closed form."""
    rng = np.random.default_rng(2021)
    grid = np.linspace(0.0, 1.0, 20_001)  # step 5e-5
    active = {"iso": 0, "velocity": 0, "acceleration": 0, "one": 0}
    for _ in range(200):
        rows, p = _random_instance(rng)
        qd, vlim = np.asarray(p["qd"]), np.asarray(p["vlim"])
        alim, prev, period = float(p["alim"]), float(p["prev"]), float(p["period"])  # type: ignore[arg-type]
        closed = iso15066.override(rows, iso15066.joint_limit_bound(qd, vlim, alim, prev, period))

        v = rows.v_toward_mps  # (L, H, 3)
        t_b = np.asarray(p["t_b"])[:, None, None]
        approaching = v > 0.0
        a_s = np.where(approaching, v, 1.0) / t_b
        v_max = iso15066.v_r_max_mps(rows.separation_m[..., None], rows.v_h_mps[..., None], p["t_r"], a_s, p["margin"])  # type: ignore[arg-type]
        iso_ok = np.all((grid[:, None] * v[approaching][None, :]) <= v_max[approaching][None, :] * (1 + 1e-12), axis=1)
        vel_ok = np.all(np.abs(grid[:, None] * qd[None, :]) <= vlim[None, :], axis=1)
        acc_ok = np.all((grid[:, None] - prev) * np.abs(qd)[None, :] <= alim * period, axis=1)
        feasible = grid[iso_ok & vel_ok & acc_ok]
        assert feasible.size, "δ = 0 is always feasible"
        assert closed == pytest.approx(feasible.max(), abs=5e-5)

        bounds = {
            "iso": float(rows.bound.min()) if rows.bound.size else math.inf,
            "velocity": float((vlim / np.abs(qd)).min()),
            "acceleration": prev + period * alim / float(np.abs(qd).max()),
            "one": 1.0,
        }
        active[min(bounds, key=lambda k: bounds[k])] += 1
    assert all(n >= 5 for n in active.values()), active  # every kind of row decided some instances


# -- three zones and stop-only ---------------------------------------------------------------------


def test_three_zones_thresholds() -> None:
    assert three_zones_override(0.0, 1.0, 1.8) == 0.0
    assert three_zones_override(1.0, 1.0, 1.8) == 0.0  # at the stop distance: stop
    assert three_zones_override(1.0 + 1e-9, 1.0, 1.8) == REDUCED_DELTA == 0.5
    assert three_zones_override(1.8, 1.0, 1.8) == 0.5
    assert three_zones_override(1.8 + 1e-9, 1.0, 1.8) == 1.0
    assert three_zones_override(math.inf, 1.0, 1.8) == 1.0


def test_three_zones_defaults_are_iso_protective_distances() -> None:
    """The documented derivation of the defaults (gateway/methods.py): S_p of the tool at 1.5 and 0.75 m/s."""
    t_b, t_r, v_h, c, v = 0.53, 0.15, 1.6, 0.05, 1.5
    full = float(reference_iso15066.protective_distance_m(v, v_h, t_r, v / t_b, c))
    half = float(reference_iso15066.protective_distance_m(v / 2, v_h, t_r, v / t_b, c))  # a_s = v/t_b: T_s = t_b / 2
    assert full == pytest.approx(1.76, abs=0.005)
    assert half == pytest.approx(0.93, abs=0.005)
    assert half <= SAFETY.three_zones_stop_below_m < full <= SAFETY.three_zones_slow_below_m


def test_point_surface_distance() -> None:
    humans = HumanCapsules(
        np.array([[1.0, 0.0, 0.0], [0.0, 3.0, -1.0]]),
        np.array([[1.0, 0.0, 2.0], [0.0, 3.0, 1.0]]),
        np.array([0.2, 0.1]),
        ("a", "b"),
        ("torso", "arm"),
    )
    assert point_surface_distance_m(np.array([0.0, 0.0, 1.0]), humans) == pytest.approx(0.8)
    assert point_surface_distance_m(np.array([1.0, 0.0, 3.0]), humans) == pytest.approx(0.8)  # beyond the end
    assert point_surface_distance_m(np.array([1.0, 0.1, 1.0]), humans) == 0.0  # inside
    empty = HumanCapsules(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), (), ())
    assert point_surface_distance_m(np.zeros(3), empty) == math.inf


def test_three_zones_tool_point_default_and_configured(ur5: RobotModel) -> None:
    q = np.array(Q)
    data = ur5.model.createData()
    links = link_kinematics(ur5, data, q, np.zeros(6))
    pin.framesForwardKinematics(ur5.model, data, q)
    scratch = ur5.model.createData()  # the method runs its own kinematics
    tool0 = ur5.R_world_base @ data.oMf[ur5.model.getFrameId("tool0")].translation + ur5.p_world_base
    wrist = ur5.R_world_base @ data.oMf[ur5.model.getFrameId("wrist_2_link")].translation + ur5.p_world_base
    from gateway.methods import MethodInput
    from gateway.reference.separation import build_rows
    from hrc_contract.humans import NO_HUMANS

    rows = build_rows(links, ur5.link_radius_m, ur5.t_brake_link_s, 0.53, NO_HUMANS, SAFETY, 0.1)
    x = MethodInput(
        ur5, scratch, q, links, rows, NO_HUMANS, np.zeros(6), 0.1, 1.0, 0.0, 0.004, link_speed_max_mps(links)
    )
    assert ThreeZones(SAFETY, {"ur5": ur5}).tool_point_world(x) == pytest.approx(tool0)
    at_wrist = ThreeZones(SafetyConfig(three_zones_tool_frame="wrist_2_link"), {"ur5": ur5})
    assert at_wrist.tool_point_world(x) == pytest.approx(wrist)


def test_three_zones_unknown_tool_frame_refuses_with_the_frames(ur5: RobotModel) -> None:
    with pytest.raises(ConfigError, match=r"three_zones_tool_frame = 'flange'.*allowed: .*tool0"):
        ThreeZones(SafetyConfig(three_zones_tool_frame="flange"), {"ur5": ur5})


# -- eq. (16): the replan request ------------------------------------------------------------------


def test_replan_request_after_delta_stayed_low() -> None:
    ms = 1_000_000
    monitor = ReplanMonitor(delta_below=0.2, after_s=0.5)
    assert not monitor.update(0, 0.1, faulted=False)
    assert not monitor.update(499 * ms, 0.19, faulted=False)
    assert monitor.update(500 * ms, 0.0, faulted=False)
    assert monitor.update(900 * ms, 0.1, faulted=False)
    assert not monitor.update(904 * ms, 0.2, faulted=False)  # at the threshold: not below; the wait restarts
    assert not monitor.update(908 * ms, 0.1, faulted=False)
    assert monitor.update(1408 * ms, 0.1, faulted=False)
    assert not monitor.update(1412 * ms, 0.0, faulted=True)  # a fault clears it
    assert not monitor.update(1416 * ms, 0.0, faulted=False)


def test_replan_threshold_zero_never_requests() -> None:
    monitor = ReplanMonitor(delta_below=0.0, after_s=0.0)
    assert not any(monitor.update(k, 0.0, faulted=False) for k in range(10))


# -- configuration ---------------------------------------------------------------------------------


def test_methods_are_listed() -> None:
    assert SAFETY_METHODS == (
        "zanchettin2016",
        "iso15066",
        "three_zones",
        "stop_only",
        "zanchettin2016_speed_aware",
        "lucci2020_pfl",
    )
    for method in SAFETY_METHODS:
        assert SafetyConfig(method=method).method == method  # type: ignore[arg-type]


def test_unknown_method_lists_the_allowed_names() -> None:
    with pytest.raises(ValidationError, match="unknown method 'iso13855'; allowed: zanchettin2016, iso15066, "):
        SafetyConfig(method="iso13855")  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"three_zones_stop_below_m": 1.5, "three_zones_slow_below_m": 1.5}, "allowed: slow > stop"),
        ({"three_zones_stop_below_m": -0.1}, "greater than or equal to 0"),
        ({"iso15066_human_uncertainty_m": -0.01}, "greater than or equal to 0"),
        ({"iso15066_joint_acceleration_limit_radps2": 0.0}, "greater than 0"),
        ({"replan_delta_below": 1.5}, "less than or equal to 1"),
        ({"replan_after_s": float("nan")}, "finite"),
    ],
)
def test_method_parameters_are_validated(fields: dict[str, float], message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        SafetyConfig(**fields)  # type: ignore[arg-type]


# -- fail closed: a nan or inf in a decision gives δ = 0 for every method ------------------------------------


def test_iso_override_with_a_nan_row_is_zero() -> None:
    links = moving_links((0, 0, 0), (0.1, 0, 0), (0, 1, 0), (0, 1, 0))  # sideways: every bound inf, δ = 1
    rows = iso15066.iso_rows(links, np.array([0.05]), np.array([0.5]), POINT_2M, SAFETY, 0.1)
    assert iso15066.override(rows, math.inf) == 1.0
    bound = rows.bound.copy()
    bound[0, 0, 1] = math.nan  # min(1.0, nan) is 1.0 in Python: the hole this closes
    assert iso15066.override(rows._replace(bound=bound), math.inf) == 0.0
    for field in ("separation_m", "v_toward_mps", "v_h_mps"):
        for bad in (math.nan, math.inf):
            data = getattr(rows, field).copy()
            data.flat[0] = bad
            assert iso15066.override(rows._replace(**{field: data}), math.inf) == 0.0, (field, bad)
    assert iso15066.override(rows, math.nan) == 0.0


def test_iso_rows_from_a_nan_input_give_zero() -> None:
    """A nan delay reaches the bound of an approaching point; a nan human reaches the separation. (A nan delay
    with nothing approaching leaves no trace in the rows: the core's input guard catches it, for every method:
    tests/test_methods_core.py.)"""
    toward = moving_links((0, 0, 0), (0.1, 0, 0), (0.1, 0, 0), (0.1, 0, 0))  # slow, 1.85 m away: δ = 1 with numbers
    t_b = np.array([0.5])
    assert iso15066.override(iso15066.iso_rows(toward, t_b / 10, t_b, POINT_2M, SAFETY, 0.1), 9.0) == 1
    rows = iso15066.iso_rows(toward, t_b / 10, t_b, POINT_2M, SAFETY, math.nan)
    assert iso15066.override(rows, math.inf) == 0.0
    sideways = moving_links((0, 0, 0), (0.1, 0, 0), (0, 1, 0), (0, 1, 0))
    rows = iso15066.iso_rows(sideways, t_b / 10, t_b, point_hands([(2, math.nan, 0)], 0.0), SAFETY, 0.1)
    assert iso15066.override(rows, math.inf) == 0.0


@pytest.mark.parametrize(
    ("qd", "limit", "previous", "period"),
    [
        ([math.nan, 0.0, 0.0], [3.15] * 3, 1.0, 0.004),  # a nan joint counted as "not moving" gave +inf
        ([math.inf, 0.0, 0.0], [3.15] * 3, 1.0, 0.004),
        ([0.1, 0.0, 0.0], [math.nan, 3.15, 3.15], 1.0, 0.004),
        ([0.1, 0.0, 0.0], [3.15] * 3, math.nan, 0.004),
        ([0.1, 0.0, 0.0], [3.15] * 3, 1.0, math.inf),
    ],
)
def test_joint_limit_bound_with_a_non_finite_input_is_zero(
    qd: list[float], limit: list[float], previous: float, period: float
) -> None:
    assert iso15066.joint_limit_bound(np.array([0.1, 0.0, 0.0]), np.full(3, 3.15), 10.0, 1.0, 0.004) > 1.0
    assert iso15066.joint_limit_bound(np.array(qd), np.array(limit), 10.0, previous, period) == 0.0


def test_three_zones_nan_distance_stops() -> None:
    assert three_zones_override(math.nan, 1.0, 1.8) == 0.0  # was 1.0: both comparisons with nan are False


def test_finite_or_zero() -> None:
    assert finite_or_zero(0.3) == 0.3
    assert finite_or_zero(-0.1) == 0.0
    assert finite_or_zero(1.7) == 1.0
    for bad in (math.nan, math.inf, -math.inf):
        assert finite_or_zero(bad) == 0.0


FAR_HUMAN = HumanCapsules(
    np.array([[4.0, 3.0, 0.2]]), np.array([[4.0, 3.0, 1.6]]), np.array([0.2]), ("far",), ("torso",)
)
"""A person 5 m from the robot's base: every method allows full speed."""
Q_MOVING = np.array(Q)
QD_MOVING = np.array([0.6, -0.4, 0.5, 0.3, -0.2, 0.4])


def decision(ur5: RobotModel, **bad: object) -> MethodInput:
    """A decision of the UR5 built the way the gateway builds it (rows from the same q, q̇ and humans),
    with the given fields replaced before the rows are built (q_rad, qd_nominal_radps, humans, t_delay_s)."""
    q = np.asarray(bad.get("q_rad", Q_MOVING), dtype=float)
    qd = np.asarray(bad.get("qd_nominal_radps", QD_MOVING), dtype=float)
    humans = bad.get("humans", FAR_HUMAN)
    assert isinstance(humans, HumanCapsules)
    t_delay = float(bad.get("t_delay_s", 0.12))  # type: ignore[arg-type]
    links = link_kinematics(ur5, ur5.model.createData(), q, qd)
    t_b = float(ur5.braking_time_s.max())
    rows = build_rows(links, ur5.link_radius_m, ur5.t_brake_link_s, t_b, humans, SAFETY, t_delay)
    clearance = SAFETY.clearance_static_m + SAFETY.human_speed_mps * (t_b + t_delay)
    previous = float(bad.get("previous_delta", 1.0))  # type: ignore[arg-type]
    return MethodInput(
        ur5,
        ur5.model.createData(),
        q,
        links,
        rows,
        humans,
        qd,
        t_delay,
        clearance,
        previous,
        0.004,
        link_speed_max_mps(links),
    )


def _with_nan(values: np.ndarray, index: int) -> np.ndarray:
    out = np.array(values, dtype=float)
    out.flat[index] = math.nan
    return out


@pytest.mark.parametrize("method", SAFETY_METHODS)
def test_every_method_gives_zero_on_a_nan_row(ur5: RobotModel, method: str) -> None:
    """A nan in the eq. (15) rows the methods read (bounds, surface distances): δ = 0, never 1."""
    chosen = build_method(SafetyConfig(method=method), {"ur5": ur5})  # type: ignore[arg-type]
    x = decision(ur5)
    rows = x.rows._replace(
        bound=_with_nan(x.rows.bound, 3),
        min_bound=math.nan,
        surface_distance_m=_with_nan(x.rows.surface_distance_m, 2),
    )
    humans = x.humans._replace(h_a_world=_with_nan(x.humans.h_a_world, 0))  # the capsule the rows were built from
    assert chosen.bound(x) == 1.0
    assert chosen.bound(x._replace(rows=rows, humans=humans)) == 0.0


def test_stop_only_nan_distance_or_limit_stops(ur5: RobotModel) -> None:
    stop_only = StopOnly(SAFETY)
    x = decision(ur5)
    assert stop_only.bound(x) == 1.0
    nan_row = x._replace(rows=x.rows._replace(surface_distance_m=_with_nan(x.rows.surface_distance_m, 0)))
    assert stop_only.bound(nan_row) == 0.0  # was 1.0: nan <= limit is False
    inf_rows = x._replace(rows=x.rows._replace(surface_distance_m=np.full_like(x.rows.surface_distance_m, math.inf)))
    assert stop_only.bound(inf_rows) == 0.0


def test_stop_only_sizes_its_zone_for_the_programmed_speed_where_that_is_faster(ur5: RobotModel) -> None:
    """The zone is sized for ``stop_only_robot_speed_mps``, a floor: a program whose links move faster than that now
    gets the zone of its own speed (an undersized zone would let it drive at someone it cannot stop before)."""
    person = HumanCapsules(
        np.array([[2.2, 0.0, 0.2]]), np.array([[2.2, 0.0, 1.6]]), np.array([0.2]), ("near",), ("torso",)
    )
    x = decision(ur5, humans=person, qd_nominal_radps=QD_MOVING * 2.0)
    fastest_mps = x.link_speed_max_mps
    nearest_m = float(x.rows.surface_distance_m.min())
    t_b = float(ur5.braking_time_s.max())
    slow = SAFETY.model_copy(update={"method": "stop_only", "stop_only_robot_speed_mps": 0.1})
    # the person is beyond the zone sized for 0.1 m/s and within the zone of the links' own speed
    assert (
        stop_only_distance_m(slow, x.t_delay_s, t_b)
        < nearest_m
        < stop_only_distance_m(slow, x.t_delay_s, t_b, fastest_mps)
    )
    assert StopOnly(slow).bound(x) == 0.0
    sized = slow.model_copy(update={"stop_only_robot_speed_mps": fastest_mps / 2})  # slower than the zone's floor
    still_beyond = x._replace(rows=x.rows._replace(surface_distance_m=x.rows.surface_distance_m + 10.0))
    assert StopOnly(sized).bound(still_beyond) == 1.0
    standing = decision(ur5, humans=person, qd_nominal_radps=np.zeros(6))  # not moving: the floor alone
    assert StopOnly(slow).bound(standing) == 1.0
    for absurd in (math.nan, math.inf):  # a speed that is not a number sizes no zone: the robot stops
        assert StopOnly(slow).bound(standing._replace(link_speed_max_mps=absurd)) == 0.0
