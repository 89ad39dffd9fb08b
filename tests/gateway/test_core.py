"""SafetyCore.step with the real UR5 and InputStore-fed messages: decisions, faults, recovery, delay, clocks."""

from __future__ import annotations

import json
from collections import Counter

import numpy as np
import pinocchio as pin
import pytest
from support.known_cases import CYCLE_MS, FAR_TORSO, MS, NEAR_HAND, NOW, QD_NOMINAL, Cell, Q, at

from gateway.core import RobotDecision
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.vocabulary import Zone
from hrc_devices.robots.model import RobotModel

HOLD_MS = 500  # streams.fault_hold_s of the default cell


@pytest.fixture
def cell(cell_config: CellConfig, ur5: RobotModel) -> Cell:
    return Cell(cell_config, ur5)


def codes(decision: RobotDecision) -> set[str]:
    return {f.code for f in decision.faults}


def assert_stopped(decision: RobotDecision, code: str) -> None:
    assert code in codes(decision)
    assert decision.delta == 0.0
    assert decision.zone is Zone.SAFETY_EXCEPTION
    assert all(f.reason for f in decision.faults)


# -- fresh data ---------------------------------------------------------------------------------


def test_far_human_full_speed_with_known_delay(cell: Cell) -> None:
    cell.feed(NOW, [FAR_TORSO])
    d = cell.step(NOW)
    assert d.faults == ()
    assert d.zone is Zone.AUTONOMOUS
    assert d.delta == 1.0
    assert d.delta_bound == 1.0
    assert d.min_distance_m is not None
    assert d.min_distance_m > 4.0
    assert d.closest is not None
    assert d.closest.capsule == "torso"
    # t_delay = reaction 0.040 + human age 0.030 + joint age 0.004 + override path 0.012 + cycle 0.004 + period 0.004
    assert d.delay.t_reaction_s == pytest.approx(0.04)
    assert d.delay.human_age_s == pytest.approx(0.030)
    assert d.delay.joint_state_age_s == pytest.approx(0.004)
    assert d.delay.override_path_s == pytest.approx(0.012)
    assert d.delay.controller_cycle_s == pytest.approx(0.004)
    assert d.delay.gateway_period_s == pytest.approx(0.004)
    assert d.delay.total_s == pytest.approx(0.094)
    # Δ = c + K (max t_b + t_delay) = 0.05 + 1.6 (0.530 + 0.094)
    assert d.clearance_m == pytest.approx(0.05 + 1.6 * 0.624)
    assert d.thresholds.protective_m == pytest.approx(d.clearance_m)
    assert d.data_age_s == pytest.approx({"joint_state": 0.004, "tracker/front": 0.03, "tracker/side": 0.03})
    assert d.controller_mode == "running"


def test_nobody_seen_is_autonomous(cell: Cell) -> None:
    cell.feed(NOW, [])
    d = cell.step(NOW)
    assert d.faults == ()
    assert (d.zone, d.delta, d.min_distance_m, d.closest) == (Zone.AUTONOMOUS, 1.0, None, None)


def test_closest_pair_and_distance_known_answer(cell: Cell, ur5: RobotModel) -> None:
    """A point hand 0.5 m beyond tool0 on the tool axis: surface distance 0.5 − 0.07 − 0.05 = 0.38 m to 'tool'."""
    data = ur5.model.createData()
    pin.framesForwardKinematics(ur5.model, data, np.array(Q))
    wrist_3 = data.oMf[ur5.model.getFrameId("wrist_3_link")].translation + ur5.p_world_base
    tool0 = data.oMf[ur5.model.getFrameId("tool0")].translation + ur5.p_world_base
    axis = (tool0 - wrist_3) / np.linalg.norm(tool0 - wrist_3)
    hand = (tool0 + 0.5 * axis).tolist()
    cell.joint(NOW)
    cell.humans(NOW, [{"name": "hand_l", "a": hand, "b": hand, "radius": 0.05}], trackers=("front",))
    cell.humans(NOW, [], trackers=("side",))
    d = cell.step(NOW)
    assert d.faults == ()
    assert d.min_distance_m == pytest.approx(0.38)
    assert d.closest == ("front/h1", "hand_l", "tool")
    # 0.38 m is well inside Δ ≈ 1.05 m: standstill
    assert d.zone is Zone.SAFETY_EXCEPTION
    assert d.delta == 0.0


def test_each_new_tracker_frame_is_seen_at_once(cell: Cell) -> None:
    """The merge of the trackers' frames is kept between cycles (frames come at 30 Hz): a new frame from one
    tracker replaces its capsules in the very next decision, and the other tracker's stay."""
    cell.feed(NOW, [FAR_TORSO])
    far = cell.step(NOW)
    cell.joint(NOW + 4 * MS)  # no new frame
    again = cell.step(NOW + 4 * MS)
    assert (again.min_distance_m, again.closest) == (far.min_distance_m, far.closest)
    cell.joint(NOW + 8 * MS)
    cell.humans(NOW + 8 * MS, [NEAR_HAND], trackers=("front",))
    near = cell.step(NOW + 8 * MS)
    assert near.closest is not None
    assert (near.closest.human, near.closest.capsule) == ("front/h1", "hand_r")
    assert near.min_distance_m is not None
    assert far.min_distance_m is not None
    assert near.min_distance_m < far.min_distance_m
    cell.joint(NOW + 12 * MS)
    cell.humans(NOW + 12 * MS, [], trackers=("front",))  # the hand is no longer reported: lost, never gone
    gone = cell.step(NOW + 12 * MS)
    assert gone.closest is not None
    assert gone.closest.human.endswith(" (lost)")
    assert gone.closest.capsule == "hand_r"
    assert gone.min_distance_m is not None
    assert gone.min_distance_m < near.min_distance_m  # its reach has grown since it was last seen


def test_near_human_reduces_speed(cell: Cell) -> None:
    cell.feed(NOW, [NEAR_HAND])
    d = cell.step(NOW)
    assert d.faults == ()
    assert 0.0 < d.delta_bound < 1.0
    assert d.zone is Zone.REDUCED_SPEED
    assert d.delta == d.delta_bound


# -- faults -------------------------------------------------------------------------------------


def test_missing_tracker(cell: Cell, cell_config: CellConfig) -> None:
    cell.joint(NOW)
    cell.humans(NOW, [FAR_TORSO], trackers=("front",))
    d = cell.step(NOW)
    assert_stopped(d, "tracker_missing")
    assert codes(d) == {"tracker_missing"}
    assert "side" in d.faults[0].reason
    assert d.delta_bound == 1.0  # the rows alone would allow full speed: the fault decides
    assert d.delay.human_age_s == pytest.approx(cell_config.safety.max_data_age_s)  # unknown age → the limit
    assert d.data_age_s["tracker/side"] is None


def test_stale_tracker(cell: Cell) -> None:
    cell.feed(NOW, [FAR_TORSO], human_age_ms=250)
    d = cell.step(NOW)
    assert_stopped(d, "tracker_stale")
    assert codes(d) == {"tracker_stale"}


def test_missing_joint_state(cell: Cell) -> None:
    cell.humans(NOW, [FAR_TORSO])
    d = cell.step(NOW)
    assert_stopped(d, "joint_state_missing")
    assert d.controller_mode is None
    assert d.min_distance_m is None


def test_stale_joint_state(cell: Cell) -> None:
    cell.feed(NOW, [FAR_TORSO], joint_age_ms=300)
    d = cell.step(NOW)
    assert_stopped(d, "joint_state_stale")
    # the override echoed with that old state is stale too; nothing else may be reported
    assert codes(d) <= {"joint_state_stale", "override_path_stale"}


def test_invalid_joint_state_latch(cell: Cell) -> None:
    cell.feed(NOW, [FAR_TORSO])
    cell.store.on_joint_state(keys.robot_state("demo", "ur5"), b'{"schema": "hrc.joint_state/1", "q": [NaN]}', at(NOW))
    d = cell.step(NOW)
    assert_stopped(d, "joint_state_invalid")
    assert codes(d) == {"joint_state_invalid"}
    assert "non_finite" in d.faults[0].reason


def test_invalid_tracker_latch(cell: Cell) -> None:
    cell.feed(NOW, [FAR_TORSO])
    cell.store.on_humans(keys.tracker_humans("demo", "side"), b"not json", at(NOW))
    d = cell.step(NOW)
    assert_stopped(d, "tracker_invalid")
    assert codes(d) == {"tracker_invalid"}


def test_override_path_unconfirmed(cell: Cell) -> None:
    cell.joint(NOW, new_override=False)  # the controller has never echoed an override
    cell.humans(NOW, [FAR_TORSO])
    d = cell.step(NOW)
    assert_stopped(d, "override_path_unconfirmed")
    assert codes(d) == {"override_path_unconfirmed"}
    assert d.delay.override_path_s == pytest.approx(0.2)  # unknown latency → max_data_age_s


def test_override_path_stale(cell: Cell) -> None:
    cell.feed(NOW, [FAR_TORSO])
    later = NOW + 300 * MS
    cell.joint(later, new_override=False)  # fresh states, but they still echo the override of 0.3 s ago
    cell.humans(later, [FAR_TORSO])
    d = cell.step(later)
    assert_stopped(d, "override_path_stale")
    assert codes(d) == {"override_path_stale"}


def test_fault_clears_and_robot_recovers(cell: Cell) -> None:
    cell.feed(NOW, [FAR_TORSO])
    assert cell.step(NOW).zone is Zone.AUTONOMOUS
    cell.store.on_humans(keys.tracker_humans("demo", "front"), b"{", at(NOW))
    assert_stopped(cell.step(NOW), "tracker_invalid")
    t1 = NOW + 20 * MS
    cell.feed(t1, [FAR_TORSO])
    assert_stopped(cell.step(t1), "tracker_invalid")  # valid data again, but within the hold
    t2 = NOW + HOLD_MS * MS
    cell.feed(t2, [FAR_TORSO])
    d = cell.step(t2)
    assert d.faults == ()
    assert (d.zone, d.delta) == (Zone.AUTONOMOUS, 1.0)


def test_recovery_follows_the_zone_rules(cell: Cell) -> None:
    """After a fault the robot resumes through the zones: a nearby human gives reduced speed, not full speed."""
    cell.feed(NOW, [NEAR_HAND], joint_age_ms=300)
    assert_stopped(cell.step(NOW), "joint_state_stale")
    t1 = NOW + 20 * MS
    cell.feed(t1, [NEAR_HAND])
    d = cell.step(t1)
    assert d.faults == ()
    assert d.zone is Zone.REDUCED_SPEED
    assert 0.0 < d.delta < 1.0


# -- delay ----------------------------------------------------------------------------------------


def test_older_human_data_gives_larger_delay_and_no_larger_delta(cell_config: CellConfig, ur5: RobotModel) -> None:
    ages_ms = [10, 40, 70, 100, 130, 160, 190]
    decisions = []
    for age in ages_ms:
        cell = Cell(cell_config, ur5)
        cell.feed(NOW, [NEAR_HAND], human_age_ms=age)
        decisions.append(cell.step(NOW))
    for d in decisions:
        assert d.faults == ()
    t_delay = np.array([d.delay.total_s for d in decisions])
    np.testing.assert_allclose(np.diff(t_delay), np.diff(ages_ms) / 1000.0)  # the age enters t_delay 1:1
    bounds = np.array([d.delta_bound for d in decisions])
    assert (np.diff(bounds) <= 1e-12).all()
    assert bounds[0] > bounds[-1]  # and it matters here
    assert (np.array([d.delta for d in decisions]) <= bounds).all()


def test_older_joint_state_gives_larger_delay(cell_config: CellConfig, ur5: RobotModel) -> None:
    results = []
    for age in (4, 50, 120):
        cell = Cell(cell_config, ur5)
        cell.feed(NOW, [NEAR_HAND], joint_age_ms=age)
        results.append(cell.step(NOW))
    assert [d.faults for d in results] == [(), (), ()]
    assert np.diff([d.delay.total_s for d in results]) == pytest.approx([0.046, 0.070])
    assert results[0].delta_bound >= results[1].delta_bound >= results[2].delta_bound
    assert results[0].delta_bound > results[2].delta_bound


def test_delay_unaware_core_uses_zero_delay(cell_config: CellConfig, ur5: RobotModel) -> None:
    aware, unaware = Cell(cell_config, ur5), Cell(cell_config, ur5, delay_aware=False)
    for cell in (aware, unaware):
        cell.feed(NOW, [NEAR_HAND], human_age_ms=100)
    d_aware, d_unaware = aware.step(NOW), unaware.step(NOW)
    assert d_unaware.delay.total_s == 0.0
    assert all(v == 0.0 for v in d_unaware.delay)
    assert d_unaware.clearance_m == pytest.approx(0.05 + 1.6 * 0.53)
    assert d_aware.delay.total_s == pytest.approx(0.164)
    assert d_unaware.delta_bound > d_aware.delta_bound  # ignoring the delay lets the robot go faster


def test_decision_is_deterministic(cell_config: CellConfig, ur5: RobotModel) -> None:
    a, b = Cell(cell_config, ur5), Cell(cell_config, ur5)
    for cell in (a, b):
        cell.feed(NOW, [NEAR_HAND, FAR_TORSO])
    assert a.step(NOW) == b.step(NOW)


def test_random_inputs_invariants(cell_config: CellConfig, ur5: RobotModel) -> None:
    """Seeded random joint states, humans and ages: δ ∈ [0, 1], δ ≤ bound, δ = 0 with any fault."""
    rng = np.random.default_rng(31)
    cell = Cell(cell_config, ur5)
    seen: Counter[tuple[bool, Zone]] = Counter()
    now = NOW
    q_rad = rng.uniform(-np.pi, np.pi, 6)
    for _ in range(80):
        now += 20 * MS
        # a standing robot (Cell reports qd 0): its q within the door's position noise of the first pose (a
        # larger step is q_motion_inconsistent; the poses' variety is the first draw's)
        q = (q_rad + rng.uniform(-0.0008, 0.0008, 6)).tolist()
        qd = rng.uniform(-2.0, 2.0, 6).tolist()
        capsules = []
        body_m = rng.uniform([-2.0, -2.0, 0.5], [2.0, 2.0, 1.5])  # one person: parts within a body's extent
        for k in range(int(rng.integers(0, 4))):
            a = body_m + rng.uniform(-0.5, 0.5, 3)
            b = a + rng.uniform(-0.3, 0.3, 3)
            capsules.append({"name": f"c{k}", "a": a.tolist(), "b": b.tolist(), "radius": float(rng.uniform(0, 0.15))})
        sent = cell.joint_seq
        cell.joint(now, age_ms=float(rng.uniform(1, 260)), q=q, qd_nominal=qd)
        assert cell.joint_seq >= sent
        cell.humans(now, capsules, age_ms=float(rng.uniform(1, 260)))
        d = cell.step(now)
        assert 0.0 <= d.delta <= d.delta_bound <= 1.0
        seen[(bool(d.faults), d.zone)] += 1
        if d.faults:
            assert d.delta == 0.0
            assert d.zone is Zone.SAFETY_EXCEPTION
        if d.zone is Zone.SAFETY_EXCEPTION:
            assert d.delta == 0.0
        assert d.delay.total_s >= cell_config.safety.t_reaction_s
    assert seen[(True, Zone.SAFETY_EXCEPTION)] >= 10
    assert sum(n for (fault, _), n in seen.items() if not fault) >= 20


def test_adaptive_thresholds_hold_the_peak_programmed_speed(cell_config: CellConfig, ur5: RobotModel) -> None:
    """'adaptive' thresholds use the largest programmed speed of the last adaptive_speed_hold_s (2 s here)."""
    fast, slow = [2 * v for v in QD_NOMINAL], [0.1 * v for v in QD_NOMINAL]
    assert cell_config.zones.thresholds == "adaptive"
    assert cell_config.zones.adaptive_speed_hold_s == pytest.approx(2.0)

    def reduce_m(cell: Cell, now_ns: int, qd_nominal: list[float]) -> float:
        cell.joint(now_ns, q=Q, qd_nominal=qd_nominal)
        cell.humans(now_ns, [FAR_TORSO])
        d = cell.step(now_ns)
        assert d.faults == ()
        return d.thresholds.reduce_m

    reference_fast = reduce_m(Cell(cell_config, ur5), NOW, fast)
    reference_slow = reduce_m(Cell(cell_config, ur5), NOW, slow)
    assert reference_fast > reference_slow
    cell = Cell(cell_config, ur5)
    assert reduce_m(cell, NOW, fast) == pytest.approx(reference_fast)
    assert reduce_m(cell, NOW + 1_000 * MS, slow) == pytest.approx(reference_fast)  # held
    assert reduce_m(cell, NOW + 3_100 * MS, slow) == pytest.approx(reference_slow)  # released after 2 s


# -- hostile and broken input (issue 9) -----------------------------------------------------------


def _tool_point(ur5: RobotModel) -> np.ndarray:
    """tool0 of the UR5 at Q, in the world frame [m]."""
    data = ur5.model.createData()
    pin.framesForwardKinematics(ur5.model, data, np.array(Q))
    return ur5.R_world_base @ data.oMf[ur5.model.getFrameId("tool0")].translation + ur5.p_world_base


def test_a_kilometre_long_capsule_next_to_the_tool_stops_the_robot(cell: Cell, ur5: RobotModel) -> None:
    """Issue 9, hole 1: a capsule of absurd length whose axis passes a hand's width from the tool."""
    tool = _tool_point(ur5)
    for half_length_m in (1e3, 1e5, 1e8):
        a = (tool + np.array([-half_length_m, 0.1, 0.0])).tolist()
        b = (tool + np.array([half_length_m, 0.1, 0.0])).tolist()
        cell.feed(NOW, [{"name": "forearm_r", "a": a, "b": b, "radius": 0.03}])
        d = cell.step(NOW)
        assert_stopped(d, "tracker_implausible")


def test_a_person_who_loses_their_capsules_does_not_become_nobody(cell: Cell, ur5: RobotModel) -> None:
    """Issue 9, hole 2: a person at the tool, then the same person listed with an empty capsule list."""
    tool = _tool_point(ur5).tolist()
    cell.feed(NOW, [{"name": "hand_r", "a": tool, "b": tool, "radius": 0.05}])
    assert cell.step(NOW).delta == 0.0  # at the tool: safety exception
    t1 = NOW + 30 * MS
    raw = {
        "schema": "hrc.humans/1",
        "tracker": "front",
        "seq": 100,
        "stamp_ns": t1 - 30 * MS + 1,
        "humans": [{"id": "h1", "capsules": []}],
    }
    cell.store.on_humans(keys.tracker_humans("demo", "front"), json.dumps(raw).encode(), at(t1))
    cell.joint(t1)
    d = cell.step(t1)
    assert_stopped(d, "tracker_invalid")
    assert d.min_distance_m is not None  # the person is still where they were last seen
    assert d.min_distance_m < 0.1


def test_a_wall_clock_step_on_the_gateway_host_stops_every_robot(cell: Cell) -> None:
    """Issue 9, hole 3: a step backwards used to freeze the view (negative ages clamped to 0)."""
    cell.feed(NOW, [FAR_TORSO])
    assert cell.step(NOW).delta == 1.0
    t1 = NOW + 4 * MS
    d = cell.step(t1, wall_step_ns=-5_000 * MS)
    assert_stopped(d, "clock_step")
    # the stored samples keep ageing on the monotonic clock, whatever the wall clock says
    t2 = NOW + 300 * MS
    d = cell.step(t2, wall_step_ns=-5_000 * MS)
    assert {"clock_step", "joint_state_stale", "tracker_stale"} <= codes(d)


def test_a_forged_nominal_velocity_of_zero_while_moving_stops_the_robot(cell: Cell) -> None:
    """Issue 9, hole 5: qd_nominal = 0 but qd moves the robot: the state is inconsistent, not slow."""
    cell.feed(NOW, [NEAR_HAND])
    stamp = cell.last_joint_stamp_ns + CYCLE_MS * MS
    raw = {
        "schema": "hrc.joint_state/1",
        "robot": "ur5",
        "seq": cell.joint_seq + 1,
        "stamp_ns": stamp,
        "q": Q,
        "qd": QD_NOMINAL,
        "qd_nominal": [0.0] * 6,
        "override": 1.0,
        "override_seq": cell.override_seq,
        "mode": "running",
    }
    cell.store.on_joint_state(keys.robot_state("demo", "ur5"), json.dumps(raw).encode(), at(stamp + MS))
    assert_stopped(cell.step(stamp + MS), "joint_state_inconsistent")


def test_the_time_to_the_next_decision_is_budgeted_at_most_the_controllers_watchdog(cell: Cell) -> None:
    """After a long hold-up (say the gateway was frozen for 1 s) the loop budgets its worst recent interval, but a
    controller that hears no override for its watchdog time stops on its own: no robot runs longer on an old δ."""
    cell.feed(NOW, [NEAR_HAND])
    now = at(NOW)
    watchdog_s = cell.config.robots["ur5"].controller.watchdog_s
    held = cell.core.step(cell.store.snapshot(now), now, 1.0)["ur5"]
    assert held.delay.gateway_period_s == pytest.approx(watchdog_s)
    short = cell.core.step(cell.store.snapshot(now), now, 0.004)["ur5"]
    assert short.delay.gateway_period_s == pytest.approx(0.004)
    assert short.delta_bound >= held.delta_bound
