"""The open bridge's pure core (``controller_bridge/open_bridge.py``): the joint commands it accepts and refuses, the
references it answers with (follow, extrapolate, hold), the joint state it composes from the controller's feedback
(q differenced over the controller's own stamps), the echo; and where the open vendor is and is not offered."""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from support.paths import DEFAULT_CELL_PATH

from controller_bridge.main import main, open_bridge_settings, select_robot
from controller_bridge.open_bridge import OpenBridge, OpenBridgeSettings
from hrc_contract.config import CellConfig, ConfigError
from hrc_contract.messages import JointCommand, to_payload
from hrc_devices.controllers.registry import OPEN_VENDORS, VENDORS, bridged_kinds, open_kinds
from hrc_devices.controllers.vendor import JointFeedback
from hrc_devices.robots.model import load_robot_model
from hrc_runtime.clocks import Clocks
from hrc_runtime.config import load_cell_config
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import SessionOptions
from hrc_tools.cell.launcher import bridged_robots, program_commands
from hrc_tools.sim.bridged import INTERFACES

ROBOT = "panda"
N = 3
WALL0, MONO0 = 1_790_000_000_000_000_000, 5_000_000_000
MS = 1_000_000
EGM_CELL = DEFAULT_CELL_PATH.parent / "cell_open_panda_egm.toml"


def _at(t_s: float) -> Clocks:
    return Clocks(WALL0 + round(t_s * 1e9), MONO0 + round(t_s * 1e9))


def _settings(**changes: float) -> OpenBridgeSettings:
    values = {"watchdog_s": 0.1, "extrapolate_s": 0.012, "cycle_s": 0.004, "velocity_window_s": 0.008}
    values.update(changes)
    return OpenBridgeSettings(robot=ROBOT, n_joints=N, max_diff_gap_s=0.1, **values)


def _command(seq: int, t_s: float, q: list[float], qd: list[float], robot: str = ROBOT) -> bytes:
    stamp_ns = _at(t_s).wall_ns
    return to_payload(JointCommand(robot=robot, seq=seq, stamp_ns=stamp_ns, q=q, qd=qd, delta=1.0))


def _feedback(
    received_s: float,
    q: list[float],
    controller_s: float | None,
    reference: list[float] | None = None,
    following: bool = True,
) -> JointFeedback:
    at = _at(received_s)
    return JointFeedback(
        received_wall_ns=at.wall_ns,
        received_mono_ns=at.mono_ns,
        q_rad=tuple(q),
        reference_rad=None if reference is None else tuple(reference),
        following=following,
        running=True,
        controller_time_s=controller_s,
        state_text="test",
    )


# -- commands ---------------------------------------------------------------------------------------------------


def test_commands_are_checked_as_the_open_emulator_checks_them_and_every_refusal_is_counted() -> None:
    bridge = OpenBridge(_settings())
    assert bridge.reference(_at(0.0)) is None  # nothing sent before the first command
    assert bridge.on_command(b"{not json", _at(0.0)) == "not_json"
    assert bridge.on_command(_command(1, 0.0, [0.0] * N, [0.0] * N, robot="ur5"), _at(0.001)) == "wrong_robot"
    assert bridge.on_command(_command(1, 0.0, [0.0] * 2, [0.0] * 2), _at(0.001)) == "wrong_joint_count"
    assert bridge.on_command(_command(1, 0.0, [0.0] * N, [0.0] * N), _at(0.2)) == "stale"
    assert bridge.on_command(_command(1, 0.1, [0.0] * N, [0.0] * N), _at(0.0)) == "stamp_in_future"
    assert bridge.on_command(_command(5, 1.0, [0.0] * N, [0.0] * N), _at(1.001)) is None
    # order by stamp, never by seq: an older stamp is refused, a restarted gateway's seq 0 with a newer stamp is not
    assert bridge.on_command(_command(6, 0.999, [0.0] * N, [0.0] * N), _at(1.002)) == "old_or_repeated"
    assert bridge.on_command(_command(0, 1.004, [0.0] * N, [0.0] * N), _at(1.005)) is None
    stats = bridge.stats()
    assert stats.commands_accepted == 2
    assert dict(stats.commands_rejected) == {
        "not_json": 1,
        "old_or_repeated": 1,
        "stale": 1,
        "stamp_in_future": 1,
        "wrong_joint_count": 1,
        "wrong_robot": 1,
    }


# -- references -------------------------------------------------------------------------------------------------


def test_a_command_is_followed_then_extrapolated_then_held_without_feed_forward() -> None:
    bridge = OpenBridge(_settings())
    q, qd = [0.1, 0.2, 0.3], [1.0, -1.0, 0.0]
    assert bridge.on_command(_command(7, 0.0, q, qd), _at(0.001)) is None
    first = bridge.reference(_at(0.002))
    assert first is not None
    assert first.how == "follow"
    assert first.seq == 7
    assert first.q_rad == tuple(q)
    assert first.qd_radps == tuple(qd)
    bridge.on_sent(first, _at(0.002))
    second = bridge.reference(_at(0.005))  # no newer command: moved on at its velocity since it arrived
    assert second is not None
    assert second.how == "extrapolate"
    np.testing.assert_allclose(second.q_rad, np.array(q) + np.array(qd) * 0.004, atol=1e-12)
    assert second.qd_radps == tuple(qd)
    bridge.on_sent(second, _at(0.005))
    held = bridge.reference(_at(0.001 + 0.012 + 0.001))  # beyond extrapolate_s: the last reference, no feed-forward
    assert held is not None
    assert held.how == "hold"
    assert held.q_rad == second.q_rad
    assert held.qd_radps == (0.0,) * N
    bridge.on_sent(held, _at(0.014))
    late = bridge.reference(_at(0.5))  # beyond the watchdog: still holding, never moving
    assert late is not None
    assert late.how == "hold"
    assert late.q_rad == second.q_rad
    assert late.qd_radps == (0.0,) * N
    assert bridge.stats().watchdog_expired
    assert bridge.on_command(_command(8, 0.5, [0.0] * N, [0.0] * N), _at(0.5005)) is None
    again = bridge.reference(_at(0.501))
    assert again is not None
    assert again.how == "follow"
    assert again.seq == 8
    assert not bridge.stats().watchdog_expired


def test_a_command_first_answered_after_the_extrapolation_time_is_held_at_its_position() -> None:
    bridge = OpenBridge(_settings())
    assert bridge.on_command(_command(3, 0.0, [0.5] * N, [2.0] * N), _at(0.0)) is None
    held = bridge.reference(_at(0.05))  # the reader was held off for 50 ms: no 50 ms old feed-forward
    assert held is not None
    assert held.how == "hold"
    assert held.q_rad == (0.5,) * N
    assert held.qd_radps == (0.0,) * N


# -- feedback -> joint state -----------------------------------------------------------------------------------


def test_velocity_is_differenced_over_the_controllers_stamps_not_over_bunched_receive_times() -> None:
    """Feedbacks 4 ms apart on the controller's clock, the last five received bunched 0.1 ms apart (a loaded host):
    over receive times the velocity would come out 40 times too high (above any URDF limit); over the controller's
    stamps it is the true 1 rad/s, and the stamps keep the times they were taken."""
    bridge = OpenBridge(_settings())
    states = []
    for k in range(6):
        q = [0.004 * k, 0.0, -0.004 * k]
        received_s = 10.0002 if k == 0 else 10.0205 + 0.0001 * k  # the reader held off 20 ms, then a burst
        states.append(bridge.on_feedback(_feedback(received_s, q, controller_s=100.0 + 0.004 * k)))
    assert states[0] is None
    assert states[1] is None
    published = [s for s in states if s is not None]
    assert len(published) == 4
    for state in published:
        np.testing.assert_allclose(state.qd, [1.0, 0.0, -1.0], atol=1e-9)
        assert state.qd_nominal == state.qd
        assert state.override == 1.0
    # the stamps are the controller's times on the bridge's clock: 4 ms apart, as the motion
    stamps = [s.stamp_ns for s in published]
    assert all(abs(b - a - 4 * MS) <= 10 for a, b in itertools.pairwise(stamps))
    assert bridge.stats().qd_sources == {"controller_time": 4}


def test_without_the_controllers_stamps_the_receive_times_are_used_over_four_cycles() -> None:
    bridge = OpenBridge(_settings())
    states = [bridge.on_feedback(_feedback(0.004 * k, [0.004 * k] * N, controller_s=None)) for k in range(6)]
    assert states[:4] == [None] * 4
    assert states[4] is not None
    np.testing.assert_allclose(states[4].qd, [1.0] * N, atol=1e-6)
    assert bridge.stats().qd_sources == {"receive_time": 2}


def test_hostile_feedback_is_refused_and_counted() -> None:
    bridge = OpenBridge(_settings())
    assert bridge.on_feedback(_feedback(0.0, [0.0] * 2, 1.0)) is None
    assert bridge.on_feedback(_feedback(0.0, [0.0, float("nan"), 0.0], 1.0)) is None
    assert bridge.on_feedback(_feedback(0.0, [0.0] * N, 1.0)) is None  # the first valid one: no velocity yet
    assert bridge.on_feedback(_feedback(0.004, [0.0] * N, 1.0)) is None  # the controller's time did not advance
    assert dict(bridge.stats().rejected) == {"non_finite": 1, "time_backwards": 1, "wrong_joint_count": 1}


def test_the_echo_is_the_newest_reference_the_controller_shows_and_mode_follows_the_watchdog() -> None:
    bridge = OpenBridge(_settings())
    assert bridge.on_command(_command(11, 0.0, [0.1] * N, [0.0] * N), _at(0.0)) is None
    reference = bridge.reference(_at(0.001))
    assert reference is not None
    bridge.on_sent(reference, _at(0.001))
    q = [0.1] * N
    bridge.on_feedback(_feedback(0.002, q, 1.000, reference=[0.0] * N))
    bridge.on_feedback(_feedback(0.006, q, 1.004, reference=[0.0] * N))
    state = bridge.on_feedback(_feedback(0.010, q, 1.008, reference=[0.0] * N))
    assert state is not None
    assert state.override_seq == -1
    state = bridge.on_feedback(_feedback(0.014, q, 1.012, reference=list(reference.q_rad)))
    assert state is not None
    assert state.override_seq == 11
    assert state.mode == "running"
    state = bridge.on_feedback(_feedback(0.2, q, 1.2, reference=list(reference.q_rad)))
    assert state is None  # a gap longer than max_diff_gap_s: the history starts again
    bridge.on_feedback(_feedback(0.204, q, 1.204))
    state = bridge.on_feedback(_feedback(0.208, q, 1.208))
    assert state is not None
    assert state.mode == "protective_stop"


def test_a_repeated_reference_never_confirms_a_command_sent_after_the_feedbacks_stamp() -> None:
    """A standing robot is sent the same q every cycle: the controller showing q confirms the newest command sent
    before its cycle, never one sent after it (the gateway's ``echo_before_send``)."""
    bridge = OpenBridge(_settings())
    q = [0.3] * N
    for k in range(3):  # the history: feedbacks at controller times 1.000, 1.004, 1.008, arriving 0.1 ms later
        bridge.on_feedback(_feedback(0.0001 + 0.004 * k, q, 1.0 + 0.004 * k, reference=[0.0] * N))
    for seq, t_s in ((20, 0.0085), (21, 0.0115), (22, 0.0125)):  # 21 before the cycle at 0.012, 22 after it
        assert bridge.on_command(_command(seq, t_s - 0.0005, q, [0.0] * N), _at(t_s)) is None
        reference = bridge.reference(_at(t_s))
        assert reference is not None
        bridge.on_sent(reference, _at(t_s))
    state = bridge.on_feedback(_feedback(0.0121, q, 1.012, reference=q))  # taken at 0.012, received after 22 left
    assert state is not None
    assert state.override_seq == 21


def test_a_controller_that_does_not_follow_is_reported_in_a_protective_stop() -> None:
    bridge = OpenBridge(_settings())
    assert bridge.on_command(_command(1, 0.0, [0.0] * N, [0.0] * N), _at(0.0)) is None
    states = [bridge.on_feedback(_feedback(0.004 * k, [0.0] * N, 0.004 * k, following=False)) for k in range(4)]
    assert [s.mode for s in states if s is not None] == ["protective_stop"] * 2


def test_settings_refuse_what_cannot_work() -> None:
    with pytest.raises(ValueError, match="extrapolate_s"):
        _settings(extrapolate_s=0.1)
    with pytest.raises(ValueError, match="velocity_window_s"):
        _settings(velocity_window_s=0.2)
    with pytest.raises(ValueError, match="cycle_s"):
        _settings(cycle_s=0.0)


# -- where the open vendor is offered -----------------------------------------------------------------------------


def test_the_open_vendor_is_registered_apart_from_the_closed_ones() -> None:
    assert open_kinds() == ("abb_egm",)
    assert OPEN_VENDORS["abb_egm"].config.model_fields["kind"].annotation.__args__ == ("abb_egm",)
    assert "abb_egm" not in VENDORS
    assert "abb_egm" not in bridged_kinds()
    assert "abb_egm" not in INTERFACES  # hrc-sweep --interface: a closed cell's choices


def _with_interface(config: CellConfig, robot: str, interface: dict[str, object]) -> dict[str, object]:
    raw = config.model_dump()
    raw["robots"][robot]["interface"] = interface
    return raw


def test_the_cell_file_refuses_an_open_interface_for_a_closed_robot_and_the_reverse() -> None:
    closed = load_cell_config()
    with pytest.raises(
        ValueError,
        match=r"'abb_egm' is an open controller's .*control = 'closed'; allowed with control = 'closed': "
        r"zenoh, abb_rws, ur_rtde",
    ):
        CellConfig.model_validate(_with_interface(closed, "ur5", {"kind": "abb_egm"}))
    open_cell = load_cell_config(EGM_CELL)
    for kind, extra in (("ur_rtde", {"host": "127.0.0.2"}), ("abb_rws", {"url": "http://x", "password_env": "P"})):
        with pytest.raises(ValueError, match=rf"'{kind}' is a closed controller's .* allowed with control = 'open'"):
            CellConfig.model_validate(_with_interface(open_cell, ROBOT, {"kind": kind, **extra}))
    with pytest.raises(ValueError, match="extrapolate_s"):
        CellConfig.model_validate(
            _with_interface(open_cell, ROBOT, {"kind": "abb_egm", "extrapolate_s": 0.05, "watchdog_s": 0.05})
        )
    with pytest.raises(ValueError, match="controller_host"):
        CellConfig.model_validate(
            _with_interface(open_cell, ROBOT, {"kind": "abb_egm", "controller_host": "robot.lan"})
        )
    with pytest.raises(ValueError, match=r"longer than controller\.watchdog_s"):
        CellConfig.model_validate(_with_interface(open_cell, ROBOT, {"kind": "abb_egm", "watchdog_s": 0.5}))


def test_the_shipped_egm_cell_runs_the_emulators_egm_face_and_the_bridge() -> None:
    config = load_cell_config(EGM_CELL)
    assert select_robot(config, None) == ROBOT
    assert bridged_robots(config) == [ROBOT]
    commands = program_commands(config, str(EGM_CELL), None, 8080, "tcp/127.0.0.1:7447", ["--insecure-plain-tcp"])
    assert commands[f"controller-{ROBOT}"][-2:] == ["--egm", "127.0.0.1:6510"]
    assert f"bridge-{ROBOT}" in commands
    settings = open_bridge_settings(config, ROBOT, load_robot_model(ROBOT, config.robots[ROBOT]))
    assert (settings.n_joints, settings.velocity_window_s, settings.extrapolate_s) == (9, 0.008, 0.012)
    closed = load_cell_config()
    with pytest.raises(ConfigError, match="not an open one"):
        open_bridge_settings(closed, "ur5", load_robot_model("ur5", closed.robots["ur5"]))


def test_the_bridge_refuses_a_program_model_for_an_open_robot(tmp_path: Path) -> None:
    config = load_cell_config(EGM_CELL)
    with pytest.raises(ConfigError, match="the gateway runs its program, so --program-model has nothing to locate"):
        main(config, ROBOT, [], [], StopEvent(), zenoh_options=SessionOptions(), program_model=tmp_path / "m.json")
