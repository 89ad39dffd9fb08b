"""ControllerNode, the step object the process and the simulated cell both drive: overrides in at their
arrival times, ``cycle(now)`` → joint state, mode changes and stats out."""

from __future__ import annotations

import threading

import pytest

from controller_emu.node import ControllerNode, ModeChange
from hrc_contract.config import CellConfig, ControllerConfig
from hrc_contract.messages import JointState, Override, parse_message, to_payload
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import Trajectory, load_trajectory
from hrc_runtime.clocks import Clocks

ROBOT = "ur5"
T0_NS = 1_790_000_000_000_000_000
MS_NS = 1_000_000


@pytest.fixture
def config(cell_config: CellConfig) -> ControllerConfig:
    return cell_config.robots[ROBOT].controller


@pytest.fixture
def trajectory(cell_config: CellConfig, ur5: RobotModel) -> Trajectory:
    return load_trajectory(cell_config.robots[ROBOT].program, ur5)


@pytest.fixture
def node(trajectory: Trajectory, config: ControllerConfig) -> ControllerNode:
    return ControllerNode(ROBOT, trajectory, config)


def _payload(delta: float, stamp_ns: int, seq: int = 0, robot: str = ROBOT) -> bytes:
    return to_payload(Override(robot=robot, seq=seq, stamp_ns=stamp_ns, delta=delta))


def _at(t_ns: int) -> Clocks:
    """Simulated time ``t_ns`` on both clocks: monotonic from 0, wall from ``T0_NS``."""
    return Clocks(wall_ns=T0_NS + t_ns, mono_ns=t_ns)


def _cycle_ns(config: ControllerConfig) -> int:
    return round(config.cycle_s * 1e9)


def test_bad_payloads_are_counted_by_reason(node: ControllerNode) -> None:
    assert node.on_override(b"not json", _at(0)) == "not_json"
    assert node.on_override(b'{"schema": "hrc.override/2"}', _at(0)) == "wrong_schema"
    assert node.on_override(_payload(1.0, T0_NS, robot="ur10"), _at(0)) == "wrong_robot"
    node.count_rejected("internal_error")
    assert node.on_override(_payload(1.0, T0_NS), _at(0)) is None
    assert node.on_override(_payload(1.0, T0_NS), _at(0)) == "old_or_repeated"
    rejected = node.stats().rejected
    assert dict(rejected) == {
        "internal_error": 1,
        "not_json": 1,
        "old_or_repeated": 1,
        "wrong_robot": 1,
        "wrong_schema": 1,
    }
    assert list(rejected) == sorted(rejected), "sorted by reason, as the stats line shows them"


def test_the_newest_stamp_wins_whatever_the_arrival_order(node: ControllerNode) -> None:
    """Two overrides arrive within one cycle, the newer first: the older one is rejected and does not
    displace the newer (the newest *stamp* is applied, once)."""
    assert (
        node.on_override(_payload(0.6, T0_NS + 2 * MS_NS, seq=8), Clocks(wall_ns=T0_NS + 2 * MS_NS, mono_ns=1 * MS_NS))
        is None
    )
    assert (
        node.on_override(_payload(0.3, T0_NS + 1 * MS_NS, seq=7), Clocks(wall_ns=T0_NS + 3 * MS_NS, mono_ns=2 * MS_NS))
        == "old_or_repeated"
    )
    out = node.cycle(_at(4 * MS_NS))
    assert (out.state.delta_commanded, out.state.override_seq) == (0.6, 8)
    assert out.joint_state.override_seq == 8
    assert out.state.override_accepted_mono_ns == 1 * MS_NS, "accepted when it arrived, not at the cycle"


def test_an_override_that_arrived_after_the_cycles_time_waits_for_the_next_cycle(node: ControllerNode) -> None:
    """The cycle's thread read its clock at 4 ms and was held off the CPU; an override the gateway decided at 6 ms
    arrived at 7 ms, before the cycle took it. Reported in the state stamped 4 ms, it would be an echo from before
    its own send (the gateway's ``echo_before_send``): the next cycle applies it."""
    assert node.on_override(_payload(0.5, T0_NS + 6 * MS_NS, seq=3), _at(7 * MS_NS)) is None
    held = node.cycle(_at(4 * MS_NS))
    assert held.joint_state.override_seq == -1
    assert held.joint_state.stamp_ns == T0_NS + 4 * MS_NS
    applied = node.cycle(_at(8 * MS_NS))
    assert (applied.joint_state.override_seq, applied.state.delta_commanded) == (3, 0.5)
    assert applied.joint_state.stamp_ns >= T0_NS + 6 * MS_NS  # never stamped before the gateway sent it


def test_an_override_that_arrived_in_time_is_applied_though_a_newer_one_came_after_the_cycles_time(
    node: ControllerNode,
) -> None:
    """Seq 4 arrived at 3 ms, seq 5 at 9 ms; the cycle at 8 ms applies seq 4 (not nothing: the newer one must not
    push out the one that was there), the cycle at 12 ms seq 5."""
    assert node.on_override(_payload(0.4, T0_NS + 2 * MS_NS, seq=4), _at(3 * MS_NS)) is None
    assert node.on_override(_payload(0.7, T0_NS + 8 * MS_NS, seq=5), _at(9 * MS_NS)) is None
    assert node.cycle(_at(8 * MS_NS)).joint_state.override_seq == 4
    assert node.cycle(_at(12 * MS_NS)).joint_state.override_seq == 5


def test_the_watchdog_counts_from_arrival(node: ControllerNode, config: ControllerConfig) -> None:
    arrival_ns = 1 * MS_NS
    assert node.on_override(_payload(1.0, T0_NS), Clocks(wall_ns=T0_NS, mono_ns=arrival_ns)) is None
    step_ns = _cycle_ns(config)
    now_ns = 0
    modes = []
    while now_ns <= arrival_ns + round(config.watchdog_s * 1e9) + 2 * step_ns:
        now_ns += step_ns
        modes.append((now_ns, node.cycle(_at(now_ns)).state.mode))
    first_stop_ns = next(t for t, m in modes if m == "protective_stop")
    assert all(m == "running" for t, m in modes if t < first_stop_ns)
    assert config.watchdog_s < (first_stop_ns - arrival_ns) / 1e9 <= config.watchdog_s + config.cycle_s


def test_cycle_reports_the_joint_state_and_mode_changes(node: ControllerNode, config: ControllerConfig) -> None:
    step_ns = _cycle_ns(config)
    first = node.cycle(_at(step_ns))
    assert first.mode_change is None, "it starts in a protective stop"
    assert (first.joint_state.seq, first.joint_state.stamp_ns, first.joint_state.mode) == (
        0,
        T0_NS + step_ns,
        "protective_stop",
    )
    node.on_override(_payload(1.0, T0_NS + 2 * step_ns, seq=3), _at(2 * step_ns))
    resumed = node.cycle(_at(2 * step_ns))
    assert resumed.mode_change == ModeChange(before="protective_stop", after="running", silent_s=0.0)
    assert (resumed.joint_state.seq, resumed.joint_state.override_seq) == (1, 3)
    assert resumed.joint_state.override == resumed.state.delta_applied > 0.0
    assert parse_message(to_payload(resumed.joint_state), JointState) == resumed.joint_state
    assert node.cycle(_at(3 * step_ns)).mode_change is None
    t_ns = 4 * step_ns
    change = None
    while change is None:  # δ = 0 commanded every cycle until the robot stands still
        node.on_override(_payload(0.0, T0_NS + t_ns), _at(t_ns))
        change = node.cycle(_at(t_ns)).mode_change
        t_ns += step_ns
    assert (change.before, change.after) == ("running", "stopped"), "δ ramped to 0 before the watchdog"
    while change.after != "protective_stop":
        change = node.cycle(_at(t_ns)).mode_change or change
        t_ns += step_ns
    assert change.before == "stopped"
    assert change.silent_s is not None
    assert config.watchdog_s < change.silent_s <= config.watchdog_s + config.cycle_s
    stats = node.stats()
    assert stats.mode == "protective_stop"
    assert stats.joint_states == t_ns // step_ns - 1
    assert stats.override_seq == 0


def test_the_step_time_is_measured_on_the_monotonic_clock(trajectory: Trajectory, config: ControllerConfig) -> None:
    """The first cycle steps ``cycle_s``; a late cycle steps the time since the previous one."""
    node = ControllerNode(ROBOT, trajectory, config, tau0_s=1.0)
    step_ns = _cycle_ns(config)
    t_ns = 0
    while node.state.delta_applied < 1.0:
        node.on_override(_payload(1.0, T0_NS + t_ns), _at(t_ns))
        t_ns += step_ns
        node.cycle(_at(t_ns))
    before_s = node.state.tau_s
    assert before_s + 3 * config.cycle_s < trajectory.duration_s, "no wrap in this test"
    node.on_override(_payload(1.0, T0_NS + t_ns), _at(t_ns))
    t_ns += 3 * step_ns  # two cycles late
    after_s = node.cycle(_at(t_ns)).state.tau_s
    assert after_s - before_s == pytest.approx(3 * config.cycle_s, rel=1e-9)

    fresh = ControllerNode(ROBOT, trajectory, config, tau0_s=1.0)
    fresh.on_override(_payload(1.0, T0_NS), Clocks(wall_ns=T0_NS, mono_ns=123 * step_ns))
    first = fresh.cycle(Clocks(wall_ns=T0_NS, mono_ns=124 * step_ns))  # whatever the clock reads at the first cycle
    assert first.state.delta_applied == pytest.approx(config.cycle_s / config.accel_time_s)


def test_a_start_outside_the_program_is_refused(trajectory: Trajectory, config: ControllerConfig) -> None:
    with pytest.raises(ValueError, match=r"tau0_s = -0.1 s; allowed: \[0, "):
        ControllerNode(ROBOT, trajectory, config, tau0_s=-0.1)
    with pytest.raises(ValueError, match="the program's duration"):
        ControllerNode(ROBOT, trajectory, config, tau0_s=trajectory.duration_s)


def test_overrides_from_another_thread_are_taken_whole(node: ControllerNode, config: ControllerConfig) -> None:
    """The subscriber's thread calls on_override while the loop cycles: no override is lost or torn, and
    after the sender is done the next cycle applies its last one."""
    n = 2000

    def sender() -> None:
        for i in range(n):
            node.on_override(_payload(i / n, T0_NS + i, seq=i), Clocks(wall_ns=T0_NS + i, mono_ns=0))

    thread = threading.Thread(target=sender)
    thread.start()
    t_ns = 0
    while thread.is_alive():
        t_ns += 1
        out = node.cycle(_at(t_ns))
        assert out.state.delta_commanded == pytest.approx(out.state.override_seq / n) or out.state.override_seq == -1
    thread.join()
    last = node.cycle(_at(t_ns + 1))
    assert (last.state.override_seq, last.state.delta_commanded) == (n - 1, (n - 1) / n)
    assert not node.stats().rejected
