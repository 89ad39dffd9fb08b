"""The bridge's RTDE client against the emulator's RTDE face (in this process: the client is pure Python)."""

from __future__ import annotations

import itertools
import math
import socket
import threading
from collections.abc import Iterator

import pytest

from controller_emu.node import ControllerNode
from controller_emu.rtde_face import RtdeFace
from hrc_contract.config import CellConfig, ControllerConfig
from hrc_devices.controllers.ur_rtde import codec as rtde
from hrc_devices.controllers.ur_rtde.client import OUTPUTS, UrRtdeInterface, reading_from_values
from hrc_devices.controllers.vendor import VendorError, VendorInterface
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import Clocks

_HOSTS = itertools.count(10)  # a loopback address per face: port 30004 is fixed


class FakeClock:
    """Clocks moved by the test [ns]."""

    def __init__(self) -> None:
        self.now = Clocks(wall_ns=1_700_000_000_000_000_000, mono_ns=1_000_000_000)

    def __call__(self) -> Clocks:
        return self.now

    def advance(self, dt_s: float) -> Clocks:
        step = round(dt_s * 1e9)
        self.now = Clocks(self.now.wall_ns + step, self.now.mono_ns + step)
        return self.now


@pytest.fixture
def node(cell_config: CellConfig, ur5: RobotModel) -> ControllerNode:
    trajectory = load_trajectory(cell_config.robots["ur5"].program, ur5)
    return ControllerNode("ur5", trajectory, ControllerConfig(watchdog_s=0.1))


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def face(node: ControllerNode, ur5: RobotModel, clock: FakeClock) -> Iterator[RtdeFace]:
    """A face on its own loopback address, sending outputs only when the test ticks it."""
    host = f"127.0.42.{next(_HOSTS)}"
    face = RtdeFace(node, host, model=ur5, paced=False, clock=clock)
    face.on_cycle(node.cycle(clock()))
    with face:
        yield face


def _wait(predicate: object) -> None:
    for _ in range(50_000):
        if predicate():  # type: ignore[operator]
            return
        threading.Event().wait(0.0002)
    raise AssertionError("gave up waiting")


def test_connect_write_and_read_back(face: RtdeFace, node: ControllerNode, clock: FakeClock) -> None:
    interface: VendorInterface = UrRtdeInterface(face.host, frequency_hz=500.0, clock=clock)  # mypy: the protocol
    assert interface.kind == "ur_rtde"
    interface.connect()
    assert interface.write_speed_fraction(0.4) == 0.4
    _wait(lambda: face.stats().slider_writes == 1)
    face.on_cycle(node.cycle(clock.advance(0.004)))
    face.tick()
    reading = interface.read(timeout_s=5.0)
    assert reading.speed_fraction == 0.4
    assert reading.speed_scaling is not None  # ramping up from standstill: combined = the applied override
    assert reading.speed_fraction * reading.speed_scaling == pytest.approx(node.stats().delta_applied)
    assert reading.running
    assert reading.state_text == "runtime_state=2 safety_mode=1 robot_mode=7"
    assert len(reading.q_rad) == 6
    assert reading.target_qd_radps == reading.qd_radps
    assert reading.received_wall_ns == clock.now.wall_ns
    assert node.stats().override_seq == 0
    interface.close()


def test_writes_stopping_is_a_protective_stop(face: RtdeFace, node: ControllerNode, clock: FakeClock) -> None:
    interface = UrRtdeInterface(face.host, frequency_hz=125.0)
    interface.connect()
    interface.write_speed_fraction(0.8)
    _wait(lambda: face.stats().slider_writes == 1)
    for _ in range(40):  # 0.16 s without a write: longer than the 0.1 s watchdog
        face.on_cycle(node.cycle(clock.advance(0.004)))
    face.tick(4)
    reading = interface.read(timeout_s=5.0)
    assert not reading.running
    assert reading.speed_scaling == 0.0
    assert reading.speed_fraction == 0.8
    assert "safety_mode=3" in reading.state_text
    interface.close()


def test_read_returns_the_newest_package(face: RtdeFace, node: ControllerNode, clock: FakeClock) -> None:
    interface = UrRtdeInterface(face.host, frequency_hz=500.0)
    interface.connect()
    for k in range(3):  # three cycles, three packages
        face.on_cycle(node.cycle(clock.advance(0.004)))
        face.tick(2)
        _wait(lambda n=k + 1: face.stats().packages_sent == n)
    interface.write_speed_fraction(0.25)
    _wait(lambda: face.stats().slider_writes == 1)
    face.on_cycle(node.cycle(clock.advance(0.004)))
    face.tick(2)
    _wait(lambda: face.stats().packages_sent == 4)
    assert interface.read(timeout_s=5.0).speed_fraction == 0.25
    with pytest.raises(VendorError) as caught:
        interface.read(timeout_s=0.01)
    assert caught.value.reason == "timeout"
    interface.close()


def test_a_second_bridge_cannot_take_the_slider(face: RtdeFace) -> None:
    first = UrRtdeInterface(face.host)
    first.connect()
    second = UrRtdeInterface(face.host)
    with pytest.raises(VendorError) as caught:
        second.connect()
    assert caught.value.reason == "refused"
    assert "IN_USE" in str(caught.value)
    first.close()


def test_refuses_bad_arguments_and_writes_when_closed(face: RtdeFace) -> None:
    with pytest.raises(ValueError, match="frequency"):
        UrRtdeInterface(face.host, frequency_hz=1000.0)
    interface = UrRtdeInterface(face.host)
    with pytest.raises(VendorError) as caught:
        interface.write_speed_fraction(0.5)
    assert caught.value.reason == "closed"
    interface.connect()
    for bad in (math.nan, -0.1, 1.01):
        with pytest.raises(ValueError, match="speed fraction"):
            interface.write_speed_fraction(bad)
    interface.close()


def test_connect_to_nothing_fails_with_connect() -> None:
    with pytest.raises(VendorError) as caught:
        UrRtdeInterface("127.0.42.250", connect_timeout_s=0.5).connect()
    assert caught.value.reason == "connect"


def _values(**changes: object) -> dict[str, object]:
    values: dict[str, object] = {
        "timestamp": 1.0,
        "actual_q": (0.0,) * 6,
        "actual_qd": (0.0,) * 6,
        "target_q": (0.0,) * 6,
        "target_qd": (0.0,) * 6,
        "speed_scaling": 1.0,
        "target_speed_fraction": 0.5,
        "runtime_state": 2,
        "safety_mode": 1,
        "robot_mode": 7,
    }
    assert set(values) == set(OUTPUTS)
    values.update(changes)
    return values


@pytest.mark.parametrize(
    "changes",
    [
        {"actual_q": (0.0, 0.0, math.nan, 0.0, 0.0, 0.0)},
        {"target_qd": (math.inf,) * 6},
        {"target_speed_fraction": 1.5},
        {"speed_scaling": -0.1},
        {"speed_scaling": math.nan},
        {"runtime_state": 9},
        {"safety_mode": 0},
        {"timestamp": math.inf},
    ],
)
def test_hostile_values_raise_malformed(changes: dict[str, object]) -> None:
    with pytest.raises(VendorError) as caught:
        reading_from_values(_values(**changes), Clocks(1, 1))
    assert caught.value.reason == "malformed"


@pytest.mark.parametrize(
    ("changes", "running"), [({}, True), ({"runtime_state": 4}, False), ({"robot_mode": 5}, False)]
)
def test_running_needs_playing_running_and_normal_safety(changes: dict[str, object], running: bool) -> None:
    assert reading_from_values(_values(**changes), Clocks(1, 1)).running is running


def _serve_once(host: str, reply: bytes) -> threading.Thread:
    """A fake controller on (host, 30004) that answers the first request with ``reply`` and closes."""
    server = socket.create_server((host, 30004))

    def run() -> None:
        with server:
            connection, _ = server.accept()
            with connection:
                connection.recv(4096)
                connection.sendall(reply)

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


@pytest.mark.parametrize(
    ("reply", "reason"),
    [
        (b"\x00\x01\x00\x00", "malformed"),  # size field below the header
        (rtde.pack_message(rtde.MessageType.REQUEST_PROTOCOL_VERSION, b"\x00"), "refused"),
        (rtde.pack_message(rtde.MessageType.REQUEST_PROTOCOL_VERSION, b"\x07"), "malformed"),
        (
            rtde.pack_message(
                rtde.MessageType.TEXT_MESSAGE, rtde.encode_text("go away", "robot", rtde.TextLevel.ERROR)
            ),
            "refused",
        ),
        (b"", "closed"),
    ],
)
def test_hostile_controller_answers_raise_vendor_error(reply: bytes, reason: str) -> None:
    host = f"127.0.42.{200 + len(reply) % 40}"
    thread = _serve_once(host, reply)
    with pytest.raises(VendorError) as caught:
        UrRtdeInterface(host, connect_timeout_s=2.0).connect()
    assert caught.value.reason == reason
    thread.join(timeout=5.0)
