"""The emulator's RWS 1.0 face judged by abb-robot-client (a client this project does not write): set and read the
speed ratio, joint target, execution and controller state with its real Digest handshake; then hostile requests
(bad forms, huge bodies, bad or replayed authorizations, an unfinished request, too many connections) answered with
clear errors while the face keeps serving."""

from __future__ import annotations

import json
import math
import socket
import time
from collections.abc import Callable, Iterator

import numpy as np
import pytest
import requests
from abb_robot_client.rws import RWS, ABBException

from controller_emu.node import ControllerNode
from controller_emu.rws_face import MAX_CONNECTIONS, FormError, RwsFace, parse_speed_ratio_form
from hrc_contract.config import CellConfig
from hrc_devices.controllers.abb_rws.http_digest import Credentials, authorization_header, parse_challenge
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import read_clocks

HOST = "127.0.0.31"
ROBOT = "ur5"
AUTH = requests.auth.HTTPDigestAuth("Default User", "robotics")


@pytest.fixture
def node(cell_config: CellConfig, ur5: RobotModel) -> ControllerNode:
    robot = cell_config.robots[ROBOT]
    return ControllerNode(ROBOT, load_trajectory(robot.program, ur5), robot.controller)


@pytest.fixture
def face(node: ControllerNode) -> Iterator[RwsFace]:
    with RwsFace(node, HOST, 0, request_timeout_s=0.5) as face:
        yield face


@pytest.fixture
def client(face: RwsFace) -> Iterator[RWS]:
    rws = RWS(face.base_url, "Default User", "robotics")
    yield rws
    rws.close()


def _raw(face: RwsFace, data: bytes) -> bytes:
    """Send raw bytes on a fresh connection; everything the face answers until it closes."""
    with socket.create_connection((face.host, face.port), timeout=5.0) as sock:
        sock.sendall(data)
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    return b"".join(chunks)


def test_set_speedratio_is_read_back_and_becomes_the_nodes_override(
    face: RwsFace, client: RWS, node: ControllerNode
) -> None:
    assert client.get_speedratio() == 100.0  # a controller starts at 100 %
    for seq, ratio in enumerate([37, 0, 100, 1, 49]):
        client.set_speedratio(ratio)
        assert client.get_speedratio() == ratio
        output = node.cycle(read_clocks())
        assert output.state.delta_commanded == ratio / 100.0
        assert output.state.override_seq == seq
    stats = face.stats()
    assert (stats.writes, stats.speed_ratio_pct) == (5, 49)
    assert stats.refused == {"challenged": 1}  # one 401 for the whole session: the nonce is reused


def test_wrong_password_is_refused(face: RwsFace) -> None:
    with pytest.raises(ABBException, match="authentication refused"):
        RWS(face.base_url, "Default User", "wrong").set_speedratio(50)
    assert face.stats().writes == 0
    assert face.stats().refused["auth_bad_response"] == 1


def test_joint_target_execution_and_controller_state_follow_the_node(
    face: RwsFace, client: RWS, node: ControllerNode
) -> None:
    output = node.cycle(read_clocks())
    face.on_cycle(output)
    assert output.state.mode == "protective_stop"  # no override yet
    assert client.get_execution_state().ctrlexecstate == "stopped"
    assert client.get_controller_state() == "guardstop"
    client.set_speedratio(50)
    output = node.cycle(read_clocks())
    face.on_cycle(output)
    assert output.state.mode == "running"
    target = client.get_jointtarget()
    # Printed as a RAPID num: 7 significant digits of degrees.
    np.testing.assert_allclose(target.robax, np.degrees(output.joint_state.q), rtol=1e-6, atol=1e-9)
    np.testing.assert_array_equal(target.extax, np.zeros(6))
    assert client.get_execution_state().ctrlexecstate == "running"
    assert client.get_controller_state() == "motoron"


@pytest.mark.parametrize(
    ("body", "message"),
    [
        (b"speed-ratio=50.5", "integer 0..100"),
        (b"speed-ratio=101", "integer 0..100"),
        (b"speed-ratio=-1", "integer 0..100"),
        (b"speed-ratio=", "integer 0..100"),
        (b"speed-ratio=%C2%B2", "integer 0..100"),  # a superscript two: isdigit() but no integer
        (b"speedratio=50", "exactly once"),
        (b"speed-ratio=5&speed-ratio=6", "exactly once"),
        (b"speed-ratio=5&x=1", "exactly once"),
        (b"\xff\xfe", "not form data"),
    ],
)
def test_bad_forms_are_refused_with_400_and_counted(
    face: RwsFace, node: ControllerNode, body: bytes, message: str
) -> None:
    with pytest.raises(FormError, match=message):
        parse_speed_ratio_form(body)
    answer = requests.post(
        f"{face.base_url}/rw/panel/speedratio?action=setspeedratio",
        data=body,
        auth=AUTH,
        headers={"Content-Type": "application/x-www-form-urlencoded"},
        timeout=5.0,
    )
    assert answer.status_code == 400
    assert message in answer.json()["_embedded"]["status"]["msg"]
    assert face.stats().refused["bad_form"] == 1
    assert node.cycle(read_clocks()).state.override_seq == -1  # nothing reached the node


def test_unknown_resources_get_404_in_the_rws_error_shape(face: RwsFace, client: RWS) -> None:
    with pytest.raises(ABBException, match="no resource"):
        client.get_operation_mode()
    with pytest.raises(ABBException, match="no resource"):
        client.get_jointtarget("ROB_2")
    answer = requests.get(f"{face.base_url}/rw/panel/speedratio", auth=AUTH, timeout=5.0)
    assert answer.status_code == 406  # JSON only
    assert face.stats().refused["not_found"] == 2


def test_huge_or_chunked_bodies_are_refused_and_the_face_keeps_serving(face: RwsFace, client: RWS) -> None:
    huge = _raw(
        face,
        b"POST /rw/panel/speedratio?action=setspeedratio HTTP/1.1\r\nHost: x\r\nContent-Length: 1000000000\r\n\r\n"
        + b"speed-ratio=50",
    )
    assert huge.startswith(b"HTTP/1.1 413")
    chunked = _raw(
        face,
        b"POST /rw/panel/speedratio?action=setspeedratio HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n",
    )
    assert chunked.startswith(b"HTTP/1.1 411")
    garbage = _raw(face, b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03" + b"\x00" * 64 + b"\r\n\r\n")
    assert garbage.startswith(b"HTTP/1.1 400")
    client.set_speedratio(20)
    assert client.get_speedratio() == 20
    refused = face.stats().refused
    assert (refused["too_large"], refused["chunked"], refused["http_400"]) == (1, 1, 1)


@pytest.mark.parametrize(
    "header", ["Digest garbage", "Basic RGVmYXVsdCBVc2VyOnJvYm90aWNz", "Digest " + "x=y, " * 1000, "\u00e9"]
)
def test_bad_authorization_headers_get_a_challenge(face: RwsFace, client: RWS, header: str) -> None:
    answer = requests.get(f"{face.base_url}/rw/panel/speedratio?json=1", headers={"Authorization": header}, timeout=5.0)
    assert answer.status_code == 401
    assert parse_challenge(answer.headers["WWW-Authenticate"]).realm == "validusers@robapi.abb"
    assert "malformed Authorization" in answer.json()["_embedded"]["status"]["msg"]
    assert face.stats().refused["auth_malformed"] == 1
    assert client.get_speedratio() == 100


def test_replayed_nonce_count_is_refused(face: RwsFace) -> None:
    uri = "/rw/panel/speedratio?action=setspeedratio&json=1"
    first = requests.get(f"{face.base_url}/rw/panel/speedratio?json=1", timeout=5.0)
    challenge = parse_challenge(first.headers["WWW-Authenticate"])
    header = authorization_header(challenge, Credentials("Default User", "robotics"), "POST", uri, 1, "abc")

    def post(ratio: int) -> requests.Response:
        return requests.post(
            f"{face.base_url}{uri}",
            data=f"speed-ratio={ratio}",
            headers={"Authorization": header, "Content-Type": "application/x-www-form-urlencoded"},
            timeout=5.0,
        )

    assert post(30).status_code == 204
    replayed = post(30)
    assert replayed.status_code == 401
    assert "replay" in replayed.json()["_embedded"]["status"]["msg"]
    assert face.stats().refused["auth_replay"] == 1
    assert face.stats().writes == 1


def test_unfinished_request_times_out_with_408_while_others_are_served(face: RwsFace, client: RWS) -> None:
    with socket.create_connection((face.host, face.port), timeout=5.0) as slow:
        slow.sendall(b"GET /rw/panel/speedratio?json=1 HTTP/1.1\r\nHost: x\r\n")  # never finished
        client.set_speedratio(60)  # served meanwhile
        assert client.get_speedratio() == 60
        answer = b""
        while chunk := slow.recv(65536):
            answer += chunk
    assert answer.startswith(b"HTTP/1.1 408")
    assert "not complete in time" in json.loads(answer.partition(b"\r\n\r\n")[2])["_embedded"]["status"]["msg"]
    assert face.stats().refused["timeout"] == 1


def test_too_many_connections_get_503_and_service_resumes(node: ControllerNode) -> None:
    with RwsFace(node, HOST, 0, request_timeout_s=30.0) as face:
        idle = [socket.create_connection((face.host, face.port), timeout=5.0) for _ in range(MAX_CONNECTIONS)]
        try:
            one_more = _raw(face, b"GET /rw/panel/speedratio?json=1 HTTP/1.1\r\nHost: x\r\n\r\n")
            assert one_more.startswith(b"HTTP/1.1 503")
            assert face.stats().refused["too_many_connections"] == 1
        finally:
            for sock in idle:
                sock.close()
        _wait_for(lambda: face.stats().connections == 0)
        rws = RWS(face.base_url, "Default User", "robotics")
        assert rws.get_speedratio() == 100


def test_jointtarget_prints_seven_significant_digits(face: RwsFace, node: ControllerNode) -> None:
    output = node.cycle(read_clocks())
    face.on_cycle(output)
    answer = requests.get(f"{face.base_url}/rw/motionsystem/mechunits/ROB_1/jointtarget?json=1", auth=AUTH, timeout=5)
    state = answer.json()["_embedded"]["_state"][0]
    assert answer.headers["Content-Type"] == "application/json"
    for i, q_rad in enumerate(output.joint_state.q, start=1):
        assert state[f"rax_{i}"] == format(math.degrees(q_rad), ".7g")


def _wait_for(condition: Callable[[], bool], attempts: int = 500) -> None:
    """Poll ``condition`` every 10 ms until it holds; fail after ``attempts`` (a wait, not a timing assertion)."""
    for _ in range(attempts):
        if condition():
            return
        time.sleep(0.01)
    pytest.fail("condition not reached")


def test_writes_within_one_clock_tick_are_all_applied(node: ControllerNode) -> None:
    frozen = read_clocks()  # every write stamped at the same wall-clock instant
    with RwsFace(node, HOST, 0, clock=lambda: frozen) as face:
        rws = RWS(face.base_url, "Default User", "robotics")
        for ratio in (10, 20, 30):
            rws.set_speedratio(ratio)
        assert face.stats().writes == 3
        assert node.stats().rejected == {}
        assert node.cycle(frozen).state.delta_commanded == 0.3
