"""The methods inside SafetyCore: selection from the TOML file, each method's decision with the real UR5,
faults that stop every method, the replan request in the status."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from support.cell_files import replace_once, write_cell
from support.known_cases import FAR_TORSO, FRESH_T_DELAY_S, MS, NEAR_HAND, NOW, PERIOD_S, QD_NOMINAL, Cell, Q, at

from gateway import iso15066
from gateway.core import SafetyCore
from gateway.inputs import InputSnapshot
from gateway.reference import iso15066 as reference_iso15066
from gateway.reference.kinematics import link_kinematics
from gateway.reference.separation import build_rows
from gateway.separation import override_from_rows
from gateway.status import robot_status
from hrc_contract import keys
from hrc_contract.config import SAFETY_METHODS, CellConfig, ConfigError
from hrc_contract.humans import HumanCapsules, merge_humans
from hrc_contract.vocabulary import Zone
from hrc_devices.robots.model import RobotModel, load_robot_model
from hrc_runtime.config import load_cell_config


def with_safety(config: CellConfig, **fields: object) -> CellConfig:
    return config.model_copy(update={"safety": config.safety.model_copy(update=fields)})


def method_cell(config: CellConfig, ur5: RobotModel, method: str, **fields: object) -> Cell:
    return Cell(with_safety(config, method=method, **fields), ur5)


def tool0_world(ur5: RobotModel, q: list[float]) -> np.ndarray:
    data = ur5.model.createData()
    pin.framesForwardKinematics(ur5.model, data, np.asarray(q))
    return np.asarray(ur5.R_world_base @ data.oMf[ur5.model.getFrameId("tool0")].translation + ur5.p_world_base)


def hand_beyond_tool(ur5: RobotModel, distance_m: float) -> dict[str, object]:
    """A point hand (radius 0.05) on the horizontal ray from the base through tool0, ``distance_m`` from tool0's
    surface: every other link is farther from it than the tool point."""
    tool = tool0_world(ur5, Q)
    ray = tool - ur5.p_world_base
    ray[2] = 0.0
    ray /= np.linalg.norm(ray)
    p = tool + (distance_m + 0.05) * ray
    return {"name": "hand_r", "a": p.tolist(), "b": p.tolist(), "radius": 0.05}


# -- selection from the configuration file -------------------------------------------------------


@pytest.mark.parametrize("method", SAFETY_METHODS)
def test_method_selected_from_toml(tmp_path: Path, method: str, ur5: RobotModel) -> None:
    path = write_cell(tmp_path, cell=replace_once('method = "zanchettin2016"', f'method = "{method}"'))
    config = load_cell_config(path)
    assert config.safety.method == method
    core = SafetyCore(config, {"ur5": load_robot_model("ur5", config.robots["ur5"])})
    assert core._method.name == method


def test_method_parameters_from_toml(tmp_path: Path) -> None:
    extra = (
        'method = "three_zones"\n'
        'three_zones_tool_frame = "wrist_3_link"\n'
        "three_zones_stop_below_m = 0.6\n"
        "three_zones_slow_below_m = 1.2\n"
        "iso15066_human_uncertainty_m = 0.1\n"
        "iso15066_robot_uncertainty_m = 0.02\n"
        "iso15066_joint_acceleration_limit_radps2 = 6.0\n"
        "replan_delta_below = 0.3\n"
        "replan_after_s = 2.0\n"
    )
    config = load_cell_config(write_cell(tmp_path, cell=replace_once('method = "zanchettin2016"\n', extra)))
    s = config.safety
    assert (s.method, s.three_zones_tool_frame, s.three_zones_stop_below_m, s.three_zones_slow_below_m) == (
        "three_zones",
        "wrist_3_link",
        0.6,
        1.2,
    )
    assert (s.iso15066_human_uncertainty_m, s.iso15066_robot_uncertainty_m) == (0.1, 0.02)
    assert (s.iso15066_joint_acceleration_limit_radps2, s.replan_delta_below, s.replan_after_s) == (6.0, 0.3, 2.0)


def test_default_method_and_parameters(cell_config: CellConfig) -> None:
    s = cell_config.safety
    assert s.method == "zanchettin2016"
    assert (s.iso15066_human_uncertainty_m, s.iso15066_robot_uncertainty_m) == (0.0, 0.0)
    assert s.iso15066_joint_acceleration_limit_radps2 == 10.0
    assert (s.three_zones_tool_frame, s.three_zones_stop_below_m, s.three_zones_slow_below_m) == (None, 1.0, 1.8)
    assert (s.replan_delta_below, s.replan_after_s) == (0.2, 1.0)


def test_invalid_method_refuses_to_load_listing_the_methods(tmp_path: Path) -> None:
    path = write_cell(tmp_path, cell=replace_once('method = "zanchettin2016"', 'method = "iso10218"'))
    with pytest.raises(ConfigError) as info:
        load_cell_config(path)
    message = str(info.value)
    assert "\n" not in message
    assert "safety.method" in message
    assert "unknown method 'iso10218'; allowed: zanchettin2016, iso15066, three_zones, stop_only" in message


def test_three_zones_slow_not_beyond_stop_refuses_to_load(tmp_path: Path) -> None:
    extra = 'method = "three_zones"\nthree_zones_stop_below_m = 1.5\nthree_zones_slow_below_m = 1.0\n'
    path = write_cell(tmp_path, cell=replace_once('method = "zanchettin2016"\n', extra))
    with pytest.raises(ConfigError, match="allowed: slow > stop"):
        load_cell_config(path)


def test_unknown_tool_frame_refuses_at_start(cell_config: CellConfig, ur5: RobotModel) -> None:
    config = with_safety(cell_config, method="three_zones", three_zones_tool_frame="tcp")
    with pytest.raises(ConfigError, match=r"'tcp' is not a frame of robot 'ur5'; allowed: .*tool0"):
        SafetyCore(config, {"ur5": ur5})


# -- every method stops on a fault ---------------------------------------------------------------


def warmed_up(config: CellConfig, ur5: RobotModel, method: str) -> tuple[Cell, int]:
    """A cell at full speed with a far human (so that the method itself allows δ = 1), and its time."""
    cell = method_cell(config, ur5, method)
    now = NOW
    for _ in range(30):
        now += 4 * MS
        cell.feed(now, [FAR_TORSO])
        d = cell.step(now)
    assert d.faults == ()
    assert d.delta == 1.0
    return cell, now


FAULTS = ["tracker_stale", "joint_state_stale", "tracker_missing", "override_path_unconfirmed", "joint_state_invalid"]


@pytest.mark.parametrize("method", SAFETY_METHODS)
@pytest.mark.parametrize("code", FAULTS)
def test_every_method_gives_zero_on_a_fault(cell_config: CellConfig, ur5: RobotModel, method: str, code: str) -> None:
    if code in ("tracker_missing", "override_path_unconfirmed"):
        cell, now = method_cell(cell_config, ur5, method), NOW
    else:
        cell, now = warmed_up(cell_config, ur5, method)
    now += 250 * MS
    if code == "tracker_stale":
        cell.joint(now)
    elif code == "joint_state_stale":
        cell.humans(now, [FAR_TORSO])
    elif code == "tracker_missing":
        cell.joint(now)
        cell.humans(now, [FAR_TORSO], trackers=("front",))
    elif code == "override_path_unconfirmed":
        cell.joint(now, new_override=False)
        cell.humans(now, [FAR_TORSO])
    else:
        cell.feed(now, [FAR_TORSO])
        bad = b'{"schema": "hrc.joint_state/1", "robot": "ur5"}'
        cell.store.on_joint_state(keys.robot_state("demo", "ur5"), bad, at(now))
    d = cell.step(now)
    assert code in {f.code for f in d.faults}
    assert d.delta == 0.0
    assert d.zone is Zone.SAFETY_EXCEPTION
    assert d.replan_request is False
    assert 0.0 <= d.delta_bound <= 1.0


def _with(values: np.ndarray, index: int, bad: float) -> np.ndarray:
    out = np.array(values, dtype=float)
    out.flat[index] = bad
    return out


def _non_finite_snapshot(inputs: InputSnapshot, case: str) -> InputSnapshot:
    """``inputs`` with one number of ``case`` made nan or inf (behind the input door, which rejects them)."""
    joint, front, side = inputs.joint["ur5"], inputs.humans["front"], inputs.humans["side"]
    assert joint is not None
    assert front is not None
    assert side is not None
    if case.startswith("q "):
        joint = joint._replace(q_rad=_with(joint.q_rad, 2 if case == "q nan" else 4, BAD[case]))
    elif case == "qd nan":
        joint = joint._replace(qd_nominal_radps=_with(joint.qd_nominal_radps, 5, math.nan))
    elif case == "human end point nan":
        front = front._replace(capsules=front.capsules._replace(h_b_world=_with(front.capsules.h_b_world, 1, math.nan)))
    elif case == "second human inf":
        side = side._replace(capsules=side.capsules._replace(h_a_world=_with(side.capsules.h_a_world, 0, math.inf)))
    return inputs._replace(joint={"ur5": joint}, humans={"front": front, "side": side})


BAD = {"t_delay nan": math.nan, "t_delay inf": math.inf, "q nan": math.nan, "q inf": math.inf}
NON_FINITE_CASES = [*BAD, "qd nan", "previous δ nan", "human end point nan", "second human inf"]


@pytest.mark.parametrize("method", SAFETY_METHODS)
@pytest.mark.parametrize("case", NON_FINITE_CASES)
def test_every_method_gives_zero_on_a_non_finite_input(
    cell_config: CellConfig, ur5: RobotModel, method: str, case: str
) -> None:
    """The core's one guard, for every method: a nan or inf in q, q̇_nominal, a capsule end point, t_delay (here
    through the gateway period) or δ_prev gives δ = 0 where the same numbers finite give δ = 1."""
    cell, now = warmed_up(cell_config, ur5, method)
    now += 4 * MS
    cell.feed(now, [FAR_TORSO])
    clocks = at(now)
    inputs = cell.store.snapshot(clocks)
    assert cell.core.step(inputs, clocks, PERIOD_S)["ur5"].delta == 1.0  # the same decision with numbers
    period_s = BAD[case] if case.startswith("t_delay") else PERIOD_S
    if case == "previous δ nan":
        cell.core.states["ur5"].previous_delta = math.nan
    with np.errstate(invalid="ignore", over="ignore"):
        d = cell.core.step(_non_finite_snapshot(inputs, case), clocks, period_s)["ur5"]
    assert (d.delta_bound, d.delta) == (0.0, 0.0)


@pytest.mark.parametrize("method", SAFETY_METHODS)
def test_every_method_keeps_the_invariants(cell_config: CellConfig, ur5: RobotModel, method: str) -> None:
    """Seeded random states and humans: δ ∈ [0, 1], δ ≤ bound, δ = 0 with a fault or a human within the method's
    protective distance (Δ, or the speed-aware method's Δ at its stop threshold)."""
    rng = np.random.default_rng(4)
    cell = method_cell(cell_config, ur5, method)
    now = NOW
    for _ in range(60):
        now += 20 * MS
        capsules = []
        for k in range(int(rng.integers(0, 3))):
            a = rng.uniform([-2.5, -2.5, 0.0], [2.5, 2.5, 2.0])
            capsules.append({"name": f"c{k}", "a": a.tolist(), "b": (a + 0.2).tolist(), "radius": 0.1})
        cell.joint(now, age_ms=float(rng.uniform(1, 230)), q=rng.uniform(-3, 3, 6).tolist())
        cell.humans(now, capsules, age_ms=float(rng.uniform(1, 230)))
        d = cell.step(now)
        assert 0.0 <= d.delta <= d.delta_bound <= 1.0
        if d.faults or (d.min_distance_m is not None and d.min_distance_m <= d.thresholds.protective_m):
            assert d.delta == 0.0


# -- each method's decision with the UR5 ---------------------------------------------------------


def test_zanchettin2016_is_the_default_and_unchanged(ur5: RobotModel, cell_config: CellConfig) -> None:
    cell = Cell(cell_config, ur5)
    cell.feed(NOW, [NEAR_HAND])
    d = cell.step(NOW)
    links = link_kinematics(ur5, ur5.model.createData(), np.asarray(Q), np.asarray(QD_NOMINAL))
    capsule = HumanCapsules(
        np.array([NEAR_HAND["a"]]), np.array([NEAR_HAND["b"]]), np.array([0.05]), ("h",), ("hand_r",)
    )
    doubled = merge_humans([capsule, capsule])  # the hand as both trackers see it
    rows = build_rows(links, ur5.link_radius_m, ur5.t_brake_link_s, 0.53, doubled, cell_config.safety, FRESH_T_DELAY_S)
    assert 0.0 < d.delta_bound < 1.0
    assert d.delta_bound == pytest.approx(override_from_rows(rows))
    assert d.delta == d.delta_bound


def test_iso15066_ramps_delta_at_the_joint_acceleration_limit(cell_config: CellConfig, ur5: RobotModel) -> None:
    """Far human: only the acceleration row binds; δ rises by T q̈_max / max|q̇_nom| = 0.004 · 10 / 0.6 a cycle."""
    cell = method_cell(cell_config, ur5, "iso15066")
    step = PERIOD_S * 10.0 / max(abs(v) for v in QD_NOMINAL)
    now, deltas = NOW, []
    for _ in range(20):
        now += 4 * MS
        cell.feed(now, [FAR_TORSO])
        deltas.append(cell.step(now).delta)
    expected = [min(1.0, (k + 1) * step) for k in range(20)]
    assert deltas == pytest.approx(expected)


def test_iso15066_near_hand_known_bound(cell_config: CellConfig, ur5: RobotModel) -> None:
    """Without the acceleration row, δ_bound is the ISO/TS 15066 bound of the rows with the decision's delay."""
    cell = method_cell(cell_config, ur5, "iso15066", iso15066_joint_acceleration_limit_radps2=1e6)
    links = link_kinematics(ur5, ur5.model.createData(), np.asarray(Q), np.asarray(QD_NOMINAL))
    # a hand 1.3 m ahead of tool0 along its programmed velocity (0.46 m/s there)
    p_hand = links.p_b_world[-1] + 1.3 * links.v_b_world[-1] / np.linalg.norm(links.v_b_world[-1])
    cell.feed(NOW, [{"name": "hand_r", "a": p_hand.tolist(), "b": p_hand.tolist(), "radius": 0.05}])
    d = cell.step(NOW)
    humans = HumanCapsules(p_hand[None, :], p_hand[None, :], np.array([0.05]), ("h",), ("x",))
    rows = iso15066.iso_rows(links, ur5.link_radius_m, ur5.t_brake_link_s, humans, cell.config.safety, FRESH_T_DELAY_S)
    expected = float(rows.bound.min())
    assert 0.0 < expected < 1.0
    assert d.delta_bound == pytest.approx(expected)
    # the binding point obeys S_p(δ v) = S with a_s = v / t_b
    i, j, k = np.unravel_index(int(np.argmin(rows.bound)), rows.bound.shape)
    v = rows.v_toward_mps[i, j, k]
    s_p = reference_iso15066.protective_distance_m(
        d.delta_bound * v, 1.6, FRESH_T_DELAY_S, v / ur5.t_brake_link_s[i], cell_config.safety.clearance_static_m
    )
    assert float(s_p) == pytest.approx(rows.separation_m[i, j])


def test_three_zones_on_the_tool_point(cell_config: CellConfig, ur5: RobotModel) -> None:
    cell = method_cell(cell_config, ur5, "three_zones")
    now = NOW
    for distance_m, expected in ((5.0, 1.0), (1.79, 0.5), (1.81, 1.0), (1.5, 0.5), (0.95, 0.0)):
        now += 4 * MS
        cell.feed(now, [hand_beyond_tool(ur5, distance_m)])
        d = cell.step(now)
        assert d.faults == ()
        assert d.delta_bound == expected, distance_m
        if expected == 0.5:
            assert d.min_distance_m is not None
            assert d.min_distance_m > d.thresholds.resume_m  # the common zones do not interfere
            assert d.zone is Zone.REDUCED_SPEED
            assert d.delta == 0.5
        if expected == 0.0:
            assert d.delta == 0.0


def test_stop_only_at_the_protective_separation_distance(cell_config: CellConfig, ur5: RobotModel) -> None:
    cell = method_cell(cell_config, ur5, "stop_only")
    now = NOW
    cell.feed(now, [])
    assert cell.step(now).delta_bound == 1.0  # nobody
    # S_p = K (T_r + t_b) + v (T_r + t_b / 2) + c with v = stop_only_robot_speed_mps = 1.5 m/s, t_b = 0.53 s
    s_p = 1.6 * (FRESH_T_DELAY_S + 0.53) + 1.5 * (FRESH_T_DELAY_S + 0.265) + 0.05
    assert s_p == pytest.approx(1.5869)
    tool_radius_m = 0.07
    for offset_m, expected in ((0.3, 1.0), (0.01, 1.0), (-0.01, 0.0), (-0.5, 0.0)):
        now += 4 * MS
        cell.feed(now, [hand_beyond_tool(ur5, s_p + tool_radius_m + offset_m)])
        d = cell.step(now)
        assert d.min_distance_m == pytest.approx(s_p + offset_m)  # the tool capsule is the nearest
        assert d.delta_bound == expected
        if expected == 0.0:
            assert d.delta == 0.0


# -- eq. (16) in the status ------------------------------------------------------------------------


NEAR_STOP = {"name": "hand_r", "a": [-0.5, 1.0, 1.08], "b": [-0.5, 1.0, 1.08], "radius": 0.05}


@pytest.mark.parametrize(
    ("method", "near"), [("iso15066", NEAR_STOP), ("zanchettin2016", NEAR_STOP), ("zanchettin2016", NEAR_HAND)]
)
def test_replan_request_in_the_status(
    cell_config: CellConfig, ur5: RobotModel, method: str, near: dict[str, object]
) -> None:
    cell = method_cell(cell_config, ur5, method, replan_delta_below=0.9, replan_after_s=0.1)
    now, flags = NOW, []
    for _ in range(40):
        now += 4 * MS
        cell.feed(now, [near])
        d = cell.step(now)
        assert d.faults == ()
        assert d.delta < 0.9
        flags.append(robot_status(d, 1).replan_request)
    # 0.1 s at 4 ms a cycle: raised from the 26th decision below the threshold on (first at t = 0)
    assert flags == [False] * 25 + [True] * 15
