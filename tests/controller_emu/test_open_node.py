"""OpenControllerNode, the open controller's step object: joint command payloads in at their arrival times,
``cycle(now)`` → joint state, mode changes and stats out."""

from __future__ import annotations

import numpy as np
import pytest
from support.paths import DEFAULT_CELL_PATH

from controller_emu.node import ModeChange
from controller_emu.open_follower import FollowerLimits, follower_limits
from controller_emu.open_node import OpenControllerNode
from hrc_contract.config import CellConfig, ControllerConfig
from hrc_contract.messages import JointCommand, JointState, parse_message, to_payload
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config

ROBOT = "panda"
T0_NS = 1_790_000_000_000_000_000
MS_NS = 1_000_000
Q0 = [0.5, 0.2, 0.0, -2.0, 0.0, 2.2, 0.785, 0.03, 0.03]


@pytest.fixture(scope="module")
def two_arms() -> CellConfig:
    return load_cell_config(DEFAULT_CELL_PATH.parent / "cell_two_arms.toml")


@pytest.fixture(scope="module")
def config(two_arms: CellConfig) -> ControllerConfig:
    return two_arms.robots[ROBOT].controller.model_copy(update={"control": "open"})


@pytest.fixture(scope="module")
def limits(two_arms: CellConfig, config: ControllerConfig) -> FollowerLimits:
    return follower_limits(load_robot_model(ROBOT, two_arms.robots[ROBOT]), config.watchdog_s)


@pytest.fixture
def node(limits: FollowerLimits, config: ControllerConfig) -> OpenControllerNode:
    return OpenControllerNode(ROBOT, limits, Q0, config)


def _payload(stamp_ns: int, seq: int = 0, robot: str = ROBOT, dq0: float = 0.0, qd0: float = 0.0) -> bytes:
    q = list(Q0)
    q[0] += dq0
    qd = [qd0] + [0.0] * 8
    return to_payload(JointCommand(robot=robot, seq=seq, stamp_ns=stamp_ns, q=q, qd=qd, delta=1.0))


def _at(t_ns: int) -> Clocks:
    """Simulated time ``t_ns`` on both clocks: monotonic from 0, wall from ``T0_NS``."""
    return Clocks(wall_ns=T0_NS + t_ns, mono_ns=t_ns)


def test_refuses_a_start_outside_the_robot(limits: FollowerLimits, config: ControllerConfig) -> None:
    with pytest.raises(ValueError, match="allowed: 9"):
        OpenControllerNode(ROBOT, limits, Q0[:7], config)
    with pytest.raises(ValueError, match="outside the position limits"):
        OpenControllerNode(ROBOT, limits, [*Q0[:3], 0.5, *Q0[4:]], config)  # joint 4's upper limit is -0.07


def test_bad_payloads_are_counted_by_reason(node: OpenControllerNode) -> None:
    assert node.on_command(b"not json", _at(0)) == "not_json"
    assert node.on_command(b'{"schema": "hrc.override/1"}', _at(0)) == "wrong_schema"
    assert node.on_command(_payload(T0_NS).replace(b'"qd":[0.0', b'"qd":[NaN'), _at(0)) == "non_finite"
    assert node.on_command(_payload(T0_NS, robot="ur5"), _at(0)) == "wrong_robot"
    short = to_payload(JointCommand(robot=ROBOT, seq=0, stamp_ns=T0_NS, q=Q0[:7], qd=[0.0] * 7, delta=1.0))
    assert node.on_command(short, _at(0)) == "wrong_joint_count"
    node.count_rejected("internal_error")
    assert node.on_command(_payload(T0_NS), _at(0)) is None
    assert node.on_command(_payload(T0_NS), _at(0)) == "old_or_repeated"
    stats = node.stats()
    assert dict(stats.rejected) == {
        "internal_error": 1,
        "non_finite": 1,
        "not_json": 1,
        "old_or_repeated": 1,
        "wrong_joint_count": 1,
        "wrong_robot": 1,
        "wrong_schema": 1,
    }
    assert list(stats.rejected) == sorted(stats.rejected)
    assert stats.commands_accepted == 1


def test_the_newest_stamp_wins_whatever_the_arrival_order(node: OpenControllerNode) -> None:
    assert node.on_command(_payload(T0_NS + 2 * MS_NS, seq=8, dq0=0.001), _at(1 * MS_NS)) is None
    assert node.on_command(_payload(T0_NS + 1 * MS_NS, seq=7), _at(2 * MS_NS)) == "old_or_repeated"
    out = node.cycle(_at(4 * MS_NS))
    assert out.state.command_seq == 8
    assert out.joint_state.override_seq == 8


def test_a_command_is_applied_at_the_first_cycle_not_before_its_arrival(node: OpenControllerNode) -> None:
    assert node.on_command(_payload(T0_NS + 5 * MS_NS, seq=3), _at(5 * MS_NS)) is None
    early = node.cycle(_at(4 * MS_NS))  # a cycle whose clock was read before the command arrived
    assert (early.joint_state.mode, early.joint_state.override_seq) == ("protective_stop", -1)
    later = node.cycle(_at(8 * MS_NS))
    assert (later.joint_state.mode, later.joint_state.override_seq) == ("running", 3)


def test_cycles_report_the_joint_state_and_mode_changes(node: OpenControllerNode, config: ControllerConfig) -> None:
    first = node.cycle(_at(0))
    assert first.mode_change is None, "it starts in a protective stop"
    assert isinstance(first.joint_state, JointState)
    assert (first.joint_state.q, first.joint_state.override, first.joint_state.seq) == (Q0, 0.0, 0)
    t_ns = 0
    changes = []
    for k in range(1, 60):
        t_ns = k * 4 * MS_NS
        if k < 30:
            assert node.on_command(_payload(T0_NS + t_ns, seq=k, dq0=0.2 * k * 0.004, qd0=0.2), _at(t_ns)) is None
        out = node.cycle(_at(t_ns))
        if out.mode_change is not None:
            changes.append((k, out.mode_change))
        # what is published parses as the contract's message
        assert parse_message(to_payload(out.joint_state), JointState) == out.joint_state
    assert changes[0] == (1, ModeChange(before="protective_stop", after="running", silent_s=0.0))
    (k_stop, stop), *_ = changes[1:]
    assert stop.after == "protective_stop"
    assert stop.silent_s == pytest.approx(config.watchdog_s, abs=0.0041)
    assert k_stop == 29 + round(config.watchdog_s / config.cycle_s) + 1
    stats = node.stats()
    assert (stats.mode, stats.command_seq, stats.joint_states) == ("protective_stop", 29, 60)
    assert node.state.qd_radps[0] < 0.2, "braking"
    assert np.all(np.asarray(out.joint_state.qd_nominal) == 0.0)
