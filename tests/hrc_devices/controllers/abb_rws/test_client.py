"""AbbRwsInterface, the bridge's RWS 1.0 client: the integer percent rounded down (known answers, then an invariant
over seeded random fractions), then against the emulator's RWS face (write, read-back, q in radians, no velocities,
the running flag, one round trip per steady request), then its failures (wrong password, nothing listening, a
silent controller, a restarted one, hostile answers)."""

from __future__ import annotations

import json
import math
import socket
from collections.abc import Iterator

import numpy as np
import pytest

from controller_emu.node import ControllerNode
from controller_emu.rws_face import RwsFace
from hrc_contract.config import CellConfig
from hrc_devices.controllers.abb_rws.client import (
    AbbRwsInterface,
    parse_execution_state,
    parse_joint_target,
    parse_speed_ratio,
    speed_ratio_pct,
)
from hrc_devices.controllers.vendor import VendorError
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import read_clocks

HOST = "127.0.0.32"
ROBOT = "ur5"


@pytest.fixture
def node(cell_config: CellConfig, ur5: RobotModel) -> ControllerNode:
    robot = cell_config.robots[ROBOT]
    return ControllerNode(ROBOT, load_trajectory(robot.program, ur5), robot.controller)


@pytest.fixture
def face(node: ControllerNode) -> Iterator[RwsFace]:
    with RwsFace(node, HOST, 0) as face:
        yield face


@pytest.fixture
def rws(face: RwsFace) -> Iterator[AbbRwsInterface]:
    interface = AbbRwsInterface(HOST, face.port, timeout_s=5.0)
    interface.connect()
    yield interface
    interface.close()


@pytest.mark.parametrize(
    ("fraction", "pct"),
    [
        (0.499, 49),
        (0.29, 29),  # floor(0.29 * 100) is 28 in floating point
        (0.57, 57),
        (0.0099, 0),
        (0.01, 1),
        (0.0, 0),
        (1.0, 100),
        (0.999999, 99),
        (1.5, 100),
        (-0.2, 0),
        (math.nan, 0),
        (math.inf, 100),
        (-math.inf, 0),
    ],
)
def test_speed_ratio_rounds_down_to_an_integer_percent(fraction: float, pct: int) -> None:
    assert speed_ratio_pct(fraction) == pct


def test_speed_ratio_is_the_largest_percent_not_above_the_fraction() -> None:
    rng = np.random.default_rng(19)
    for fraction in [*rng.uniform(0.0, 1.0, 5000), *(np.arange(101) / 100.0)]:
        pct = speed_ratio_pct(float(fraction))
        assert 0 <= pct <= 100
        assert pct / 100.0 <= fraction
        assert pct == 100 or (pct + 1) / 100.0 > fraction


def test_write_is_read_back_with_q_in_radians_and_no_velocities(
    rws: AbbRwsInterface, face: RwsFace, node: ControllerNode
) -> None:
    assert rws.write_speed_fraction(0.499) == 0.49
    output = node.cycle(read_clocks())
    face.on_cycle(output)
    reading = rws.read(timeout_s=5.0)
    assert reading.speed_fraction == 0.49
    np.testing.assert_allclose(reading.q_rad, output.joint_state.q, rtol=1e-6, atol=1e-9)
    assert len(reading.q_rad) == 6
    assert reading.qd_radps is None
    assert reading.target_qd_radps is None
    assert reading.speed_scaling is None
    assert reading.running
    assert reading.state_text == "ctrlexecstate=running speedratio=49"
    assert output.state.delta_commanded == 0.49


def test_below_one_percent_writes_zero_and_the_program_keeps_running(
    rws: AbbRwsInterface, face: RwsFace, node: ControllerNode
) -> None:
    rws.write_speed_fraction(0.5)
    node.cycle(read_clocks())
    assert rws.write_speed_fraction(0.009) == 0.0
    face.on_cycle(node.cycle(read_clocks()))
    reading = rws.read(timeout_s=5.0)
    assert reading.speed_fraction == 0.0
    assert reading.running  # RAPID runs at speed ratio 0: the robot holds, the program is not stopped
    assert face.stats().speed_ratio_pct == 0


def test_protective_stop_reads_as_not_running(rws: AbbRwsInterface, face: RwsFace, node: ControllerNode) -> None:
    face.on_cycle(node.cycle(read_clocks()))  # no override yet: the node's watchdog holds it stopped
    reading = rws.read(timeout_s=5.0)
    assert not reading.running
    assert reading.state_text.startswith("ctrlexecstate=stopped")


def test_a_steady_write_and_read_cost_one_round_trip_per_request(rws: AbbRwsInterface, face: RwsFace) -> None:
    before = rws.round_trips
    for k in range(20):
        rws.write_speed_fraction(k / 20.0)
        rws.read(timeout_s=5.0)
    assert rws.round_trips - before == 20 * 4  # 1 POST + 3 GETs, never a 401
    assert face.stats().refused == {"challenged": 1}  # the one 401 of connect()


def test_wrong_password_raises_auth(face: RwsFace) -> None:
    with pytest.raises(VendorError) as caught:
        AbbRwsInterface(HOST, face.port, password="wrong", timeout_s=5.0).connect()
    assert caught.value.reason == "auth"


def test_nothing_listening_raises_connect() -> None:
    with socket.socket() as probe:
        probe.bind((HOST, 0))
        port = probe.getsockname()[1]
    with pytest.raises(VendorError) as caught:
        AbbRwsInterface(HOST, port, timeout_s=5.0).connect()
    assert caught.value.reason == "connect"


def test_silent_controller_raises_timeout() -> None:
    with socket.socket() as silent:
        silent.bind((HOST, 0))
        silent.listen(1)  # the kernel accepts the connection; nobody ever answers
        interface = AbbRwsInterface(HOST, silent.getsockname()[1], timeout_s=0.2)
        with pytest.raises(VendorError) as caught:
            interface.read(timeout_s=0.2)
        assert caught.value.reason == "timeout"
        interface.close()


def test_restarted_controller_is_reconnected_and_reauthenticated(node: ControllerNode) -> None:
    first = RwsFace(node, HOST, 0)
    first.start()
    port = first.port
    interface = AbbRwsInterface(HOST, port, timeout_s=5.0)
    interface.connect()
    assert interface.write_speed_fraction(0.3) == 0.3
    first.close()  # drops the kept-alive connection; the new face has a new nonce secret
    with RwsFace(node, HOST, port) as second:
        assert interface.write_speed_fraction(0.4) == 0.4
        assert interface.read(timeout_s=5.0).speed_fraction == 0.4
        assert second.stats().refused == {"auth_bad_nonce": 1}  # the old nonce, refused once, then the new one
    interface.close()


@pytest.mark.parametrize(
    "body",
    [
        b"not json",
        b"[]",
        b'{"_embedded": {"_state": []}}',
        b'{"_embedded": {"_state": [{"_type": "pnl-ctrlstate", "speedratio": "50"}]}}',
        b'{"_embedded": {"_state": [{"_type": "pnl-speedratio", "speedratio": "101"}]}}',
        b'{"_embedded": {"_state": [{"_type": "pnl-speedratio", "speedratio": "50.0"}]}}',
        b'{"_embedded": {"_state": [{"_type": "pnl-speedratio", "speedratio": 50}]}}',
        b'{"_embedded": {"_state": [{"_type": "pnl-speedratio", "speedratio": "-1"}]}}',
    ],
)
def test_malformed_speed_ratio_answers_raise(body: bytes) -> None:
    with pytest.raises(VendorError) as caught:
        parse_speed_ratio(body)
    assert caught.value.reason == "malformed"


@pytest.mark.parametrize("value", ["nan", "inf", "9E+09", "abc", None, "1e400"])
def test_malformed_joint_targets_raise(value: str | None) -> None:
    state = {"_type": "ms-jointtarget", **{f"rax_{i}": "1.5" for i in range(1, 7)}}
    if value is None:
        del state["rax_3"]
    else:
        state["rax_3"] = value
    with pytest.raises(VendorError) as caught:
        parse_joint_target(json.dumps({"_embedded": {"_state": [state]}}).encode(), 6)
    assert caught.value.reason == "malformed"


def test_unknown_execution_state_raises() -> None:
    body = b'{"_embedded": {"_state": [{"_type": "rap-execution", "ctrlexecstate": "paused"}]}}'
    with pytest.raises(VendorError):
        parse_execution_state(body)
