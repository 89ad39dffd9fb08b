"""The emulator's RTDE face, judged by ur-rtde (the client the field uses) and by raw, hostile sockets.

ur-rtde's Python bindings hold the GIL while they wait for the controller, so the face it talks to runs in a
child process (:data:`_SERVER`); the raw-socket tests run the face in this process with ``paced=False`` and send
each output tick themselves, so they count packages without reading a clock.
"""

from __future__ import annotations

import json
import math
import select
import socket
import statistics
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from support.ur_rtde_cases import UR_RTDE_DEFAULT_OUTPUTS, rotation_of, ur5_flange_in_base

from controller_emu.node import ControllerNode
from controller_emu.rtde_face import RtdeFace
from controller_emu.rtde_outputs import output_values
from hrc_contract.config import CellConfig, ControllerConfig
from hrc_devices.controllers.ur_rtde import codec as rtde
from hrc_devices.controllers.ur_rtde.codec import MessageType, Recipe
from hrc_devices.robots.model import RobotModel
from hrc_devices.robots.program import load_trajectory
from hrc_runtime.clocks import Clocks
from hrc_tools.cell.procs import load_scale

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

OUTPUTS = [
    "timestamp",
    "actual_q",
    "actual_qd",
    "target_q",
    "target_qd",
    "speed_scaling",
    "target_speed_fraction",
    "runtime_state",
    "safety_mode",
    "robot_mode",
]
ROOT = Path(__file__).resolve().parents[2]
CYCLE_S = ControllerConfig().cycle_s
"""The emulated controller's cycle [s] (the child below runs at it)."""

_SERVER = r"""
import json, sys, threading
from controller_emu.node import ControllerNode
from hrc_devices.robots.program import load_trajectory
from controller_emu.rtde_face import RtdeFace
from hrc_contract.config import ControllerConfig
from hrc_runtime.clocks import read_clocks
from hrc_runtime.config import load_cell_config
from hrc_devices.robots.model import load_robot_model

robot = load_cell_config(None).robots["ur5"]
model = load_robot_model("ur5", robot)
trajectory = load_trajectory(robot.program, model)
node = ControllerNode("ur5", trajectory, ControllerConfig(watchdog_s=1.0))
face = RtdeFace(node, sys.argv[1], model=model)
stop = threading.Event()

def loop():
    while not stop.wait(node.config.cycle_s):
        face.on_cycle(node.cycle(read_clocks()))

face.on_cycle(node.cycle(read_clocks()))
face.start()
threading.Thread(target=loop, daemon=True).start()
print("ready", flush=True)
sys.stdin.readline()
stats = face.stats()
print(json.dumps({"slider_writes": stats.slider_writes, "errors": dict(stats.errors)}), flush=True)
stop.set()
face.close()
"""


# -- ur-rtde against the face in a child process ---------------------------------------------------------------------


@pytest.fixture
def face_process(request: pytest.FixtureRequest) -> Iterator[tuple[str, subprocess.Popen[str]]]:
    host: str = request.param
    process = subprocess.Popen(
        [sys.executable, "-c", _SERVER, host], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=ROOT
    )
    assert process.stdout is not None
    assert process.stdout.readline().strip() == "ready"
    yield host, process
    if process.poll() is None:
        process.kill()
        process.wait()


def _wait_for(predicate: object, what: str, timeout_s: float = 10.0) -> None:
    """Poll ``predicate`` until true; the default deadline only stops a broken test, it asserts nothing about speed."""
    deadline = time.monotonic() + timeout_s * load_scale()
    while not predicate():  # type: ignore[operator]
        if time.monotonic() > deadline:
            raise AssertionError(f"gave up waiting for {what}")
        time.sleep(0.0002)


@pytest.mark.parametrize(
    ("face_process", "frequency_hz"), [("127.0.41.11", 500.0), ("127.0.41.12", 125.0)], indirect=["face_process"]
)
def test_ur_rtde_reads_back_the_slider_within_two_output_periods(
    face_process: tuple[str, subprocess.Popen[str]], frequency_hz: float
) -> None:
    """``setSpeedSlider(x)`` → ``getTargetSpeedFraction()`` shows x; ``getSpeedScalingCombined()`` the applied
    override ramping up to it.

    Counted in output periods from the controller's own timestamps (the package seen before the write to the
    package that shows x). The median must be <= 2; single writes may take longer when this shared machine
    deschedules the polling test (the polling, not the face, adds those periods; the deterministic bound is
    :func:`test_a_slider_write_is_in_the_next_package_at_every_frequency`).
    """
    import rtde_io
    import rtde_receive

    host, process = face_process
    receive = rtde_receive.RTDEReceiveInterface(host, frequency_hz, OUTPUTS)
    io = rtde_io.RTDEIOInterface(host)
    io.setSpeedSlider(0.3)
    _wait_for(lambda: receive.getSpeedScaling() == 1.0 and receive.getRuntimeState() == rtde.RUNTIME_PLAYING, "run")
    periods = []
    for i in range(40):
        fraction = 0.2 + 0.015 * i
        before_s = receive.getTimestamp()
        assert io.setSpeedSlider(fraction)
        _wait_for(lambda f=fraction: receive.getTargetSpeedFraction() == f, f"read-back of {fraction}")
        periods.append(round((receive.getTimestamp() - before_s) * frequency_hz))
        # the slider rises: the combined scaling is the applied override, ramping up to it, never above
        assert 0.0 < receive.getSpeedScalingCombined() <= fraction + 1e-9
    _wait_for(lambda: receive.getSpeedScalingCombined() == pytest.approx(fraction), "the ramp reaching the slider")
    assert receive.getSafetyMode() == rtde.SAFETY_NORMAL
    assert receive.getRobotMode() == rtde.ROBOT_MODE_RUNNING
    # the write is in the first cycle after it (the emulator's 4 ms), then in that cycle's package (one period)
    assert statistics.median(periods) <= 2 + CYCLE_S * frequency_hz, periods
    io.disconnect()
    receive.disconnect()
    assert process.stdin is not None
    assert process.stdout is not None
    process.stdin.write("stats\n")
    process.stdin.flush()
    stats = json.loads(process.stdout.readline())
    assert stats["slider_writes"] == 41
    assert stats["errors"] == {}


def _pose_consistent(receive: object) -> tuple[list[float], list[float]]:
    """``getActualQ()`` and ``getActualTCPPose()`` of one package: the pose read between two equal joint reads (the
    getters read the client's latest package one at a time; a moving robot changes q with every package)."""
    for _ in range(1000):
        q_before = receive.getActualQ()  # type: ignore[attr-defined]
        pose = receive.getActualTCPPose()  # type: ignore[attr-defined]
        if receive.getActualQ() == q_before:  # type: ignore[attr-defined]
            return q_before, pose
    raise AssertionError("never read q and the pose of one package")


def _assert_pose_is_the_dh_flange(q: list[float], pose: list[float]) -> None:
    flange = ur5_flange_in_base(q)
    assert pose[:3] == pytest.approx(flange[:3, 3], abs=1e-9)
    assert rotation_of(pose[3:]) == pytest.approx(flange[:3, :3], abs=1e-9)


@pytest.mark.parametrize("face_process", ["127.0.41.13"], indirect=True)
def test_ur_rtde_default_recipe_reads_the_emulator_and_the_slider_is_read_back(
    face_process: tuple[str, subprocess.Popen[str]], cell_config: CellConfig, ur5: RobotModel
) -> None:
    """``RTDEReceiveInterface(host, 500.0)`` without a variable list (ur-rtde's default recipe: every output a 5.11
    controller has, 58 with registers) connects; the joints are the program's, the TCP pose the flange of UR's DH
    parameters at those joints; ``setSpeedSlider(0.5)`` is read back and the robot runs."""
    import rtde_io
    import rtde_receive

    host, process = face_process
    receive = rtde_receive.RTDEReceiveInterface(host, 500.0)
    assert receive.isConnected()
    # no slider write yet: held at the program's start by the watchdog (a protective stop), the slider at 0
    start_q = load_trajectory(cell_config.robots["ur5"].program, ur5).sample(0.0)[0]
    assert receive.getActualQ() == pytest.approx(start_q, abs=1e-12)
    assert receive.getTargetQ() == receive.getActualQ()
    assert (receive.getTargetSpeedFraction(), receive.getSpeedScaling()) == (0.0, 0.0)
    assert receive.getSafetyMode() == rtde.SAFETY_PROTECTIVE_STOP
    assert receive.getRuntimeState() == rtde.RUNTIME_PAUSED
    assert receive.getRobotMode() == rtde.ROBOT_MODE_RUNNING
    _assert_pose_is_the_dh_flange(*_pose_consistent(receive))
    assert receive.getActualTCPSpeed() == [0.0] * 6
    assert math.dist(receive.getActualToolAccelerometer(), (0.0, 0.0, 0.0)) == pytest.approx(9.81)
    assert receive.getJointTemperatures() == [25.0] * 6  # a stated constant (rtde_outputs.OUTPUTS)
    assert receive.getPayload() == 0.0
    assert receive.getOutputIntRegister(12) == 0

    io = rtde_io.RTDEIOInterface(host)
    assert io.setSpeedSlider(0.5)
    _wait_for(lambda: receive.getTargetSpeedFraction() == 0.5, "the slider's read-back", timeout_s=1.0)
    _wait_for(lambda: receive.getSpeedScaling() == 1.0, "the ramp reaching the slider")  # 0.5 / accel_time 0.5 s
    assert receive.getSpeedScalingCombined() == 0.5
    assert (receive.getSafetyMode(), receive.getRuntimeState()) == (rtde.SAFETY_NORMAL, rtde.RUNTIME_PLAYING)
    _wait_for(lambda: receive.getActualQ() != pytest.approx(start_q, abs=1e-6), "the robot moving")
    for _ in range(20):  # moving: every package's pose is the flange at its joints
        _assert_pose_is_the_dh_flange(*_pose_consistent(receive))
        time.sleep(0.003)
    io.disconnect()
    receive.disconnect()
    assert process.stdin is not None
    assert process.stdout is not None
    process.stdin.write("stats\n")
    process.stdin.flush()
    assert json.loads(process.stdout.readline())["errors"] == {}


# -- raw clients against the face in this process --------------------------------------------------------------------


class FakeClock:
    """The clocks the face stamps slider writes with, moved by the test [ns]."""

    def __init__(self) -> None:
        self.now = Clocks(wall_ns=1_700_000_000_000_000_000, mono_ns=1_000_000_000)

    def __call__(self) -> Clocks:
        return self.now

    def advance(self, dt_s: float) -> Clocks:
        step = round(dt_s * 1e9)
        self.now = Clocks(self.now.wall_ns + step, self.now.mono_ns + step)
        return self.now


class RawClient:
    """A minimal RTDE client on a plain socket: what a hostile or a careful client sends, byte for byte."""

    def __init__(self, host: str) -> None:
        self.sock = socket.create_connection((host, 30004), timeout=5.0)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # as RTDE clients do (no Nagle wait)
        self.buffer = bytearray()

    def send(self, message_type: int, payload: bytes = b"") -> None:
        self.sock.sendall(struct.pack(">HB", 3 + len(payload), message_type) + payload)

    def receive(self) -> rtde.Message:
        """The next message (5 s at most, else the test is broken)."""
        deadline = time.monotonic() + 5.0 * load_scale()
        while True:
            messages = rtde.take_messages(self.buffer)
            if messages:
                self.buffer[:0] = b"".join(rtde.pack_message(m.type_code, m.payload) for m in messages[1:])
                return messages[0]
            readable, _, _ = select.select([self.sock], [], [], max(0.0, deadline - time.monotonic()))
            assert readable, "no message from the face"
            data = self.sock.recv(65536)
            if not data:
                raise ConnectionError("closed by the face")
            self.buffer += data

    def request(self, message_type: int, payload: bytes = b"") -> bytes:
        self.send(message_type, payload)
        reply = self.receive()
        assert reply.type_code == message_type
        return reply.payload

    def handshake(self, frequency_hz: float = 500.0, outputs: list[str] = OUTPUTS) -> Recipe:
        assert rtde.decode_accepted(self.request(MessageType.REQUEST_PROTOCOL_VERSION, b"\x00\x02"))
        recipe_id, types = rtde.decode_setup_reply(
            self.request(MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS, rtde.encode_output_setup(frequency_hz, outputs))
        )
        return Recipe(recipe_id, tuple(outputs), types)

    def closed(self) -> bool:
        """True once the face has closed the connection (reads what is left first)."""
        try:
            while True:
                self.receive()
        except ConnectionError:
            return True

    def close(self) -> None:
        self.sock.close()


@pytest.fixture
def node(cell_config: CellConfig, ur5: RobotModel) -> ControllerNode:
    trajectory = load_trajectory(cell_config.robots["ur5"].program, ur5)
    return ControllerNode("ur5", trajectory, ControllerConfig(watchdog_s=0.1))


def _face(node: ControllerNode, model: RobotModel, host: str, clock: FakeClock) -> RtdeFace:
    """A face sending outputs only on ``tick`` (started by ``with``)."""
    face = RtdeFace(node, host, model=model, paced=False, clock=clock)
    face.on_cycle(node.cycle(clock()))
    return face


def _slider_recipe(client: RawClient) -> Recipe:
    names = ("input_int_register_23", "speed_slider_mask", "speed_slider_fraction")
    recipe_id, types = rtde.decode_setup_reply(
        client.request(MessageType.CONTROL_PACKAGE_SETUP_INPUTS, rtde.encode_input_setup(names))
    )
    return Recipe(recipe_id, names, types)


@pytest.mark.parametrize(("frequency_hz", "ticks_per_package"), [(500.0, 2), (125.0, 4)])
def test_a_slider_write_is_in_the_first_package_of_the_next_cycle_at_every_frequency(
    node: ControllerNode, ur5: RobotModel, frequency_hz: float, ticks_per_package: int
) -> None:
    """Write (the face has it), then one controller cycle and one package's ticks: that package shows it."""
    clock = FakeClock()
    host = "127.0.41.21" if frequency_hz == 500.0 else "127.0.41.22"
    with _face(node, ur5, host, clock) as face:
        reader, writer = RawClient(host), RawClient(host)
        outputs = reader.handshake(frequency_hz)
        assert rtde.decode_accepted(reader.request(MessageType.CONTROL_PACKAGE_START))
        writer.handshake()
        slider = _slider_recipe(writer)
        for i in range(20):
            fraction = 0.1 + 0.04 * i
            writer.send(MessageType.DATA_PACKAGE, rtde.encode_data(slider, (22, 1, fraction)))
            _wait_for(lambda n=i + 1: face.stats().slider_writes == n, "the slider write")
            face.on_cycle(node.cycle(clock.advance(0.004)))
            face.tick(ticks_per_package)
            values = dict(zip(OUTPUTS, rtde.decode_data(outputs, reader.receive().payload), strict=True))
            assert values["target_speed_fraction"] == fraction
        assert face.stats().slider_writes == 20
        reader.close()
        writer.close()


def test_a_write_is_never_in_the_data_of_a_cycle_before_it(node: ControllerNode, ur5: RobotModel) -> None:
    """The cycle before the write is sent after it: it shows the old slider; the next cycle the new one."""
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.31", clock) as face:
        reader, writer = RawClient("127.0.41.31"), RawClient("127.0.41.31")
        outputs = reader.handshake(500.0)
        assert rtde.decode_accepted(reader.request(MessageType.CONTROL_PACKAGE_START))
        writer.handshake()
        slider = _slider_recipe(writer)
        face.on_cycle(node.cycle(clock.advance(0.004)))  # taken before the write
        clock.advance(0.001)
        writer.send(MessageType.DATA_PACKAGE, rtde.encode_data(slider, (22, 1, 0.45)))
        _wait_for(lambda: face.stats().slider_writes == 1, "the slider write")
        face.tick(2)
        before = dict(zip(OUTPUTS, rtde.decode_data(outputs, reader.receive().payload), strict=True))
        assert before["target_speed_fraction"] == 0.0
        face.on_cycle(node.cycle(clock.advance(0.003)))
        face.tick(2)
        after = dict(zip(OUTPUTS, rtde.decode_data(outputs, reader.receive().payload), strict=True))
        assert after["target_speed_fraction"] == 0.45
        assert after["timestamp"] - before["timestamp"] == pytest.approx(0.004)
        reader.close()
        writer.close()


def test_output_timestamps_are_the_times_of_the_cycles_they_carry(node: ControllerNode, ur5: RobotModel) -> None:
    """One package per new cycle, stamped with the cycle's time (a late cycle late); a tick without a new cycle
    sends nothing."""
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.23", clock) as face:
        client = RawClient("127.0.41.23")
        outputs = client.handshake(500.0)
        assert rtde.decode_accepted(client.request(MessageType.CONTROL_PACKAGE_START))
        stamps = []
        for step_s in (0.004, 0.004, 0.011, 0.004):  # the third cycle 7 ms late
            face.on_cycle(node.cycle(clock.advance(step_s)))
            face.tick(3)  # three output periods: one package, the cycle's
            stamps.append(rtde.decode_data(outputs, client.receive().payload)[0])
        assert stamps == pytest.approx([0.004, 0.008, 0.019, 0.023])
        face.tick(3)  # no new cycle: nothing; the next package is the next cycle's
        face.on_cycle(node.cycle(clock.advance(0.004)))
        face.tick(1)
        assert rtde.decode_data(outputs, client.receive().payload)[0] == pytest.approx(0.027)
        assert face.stats().packages_sent == 5
        client.close()


def test_watchdog_stop_shows_as_protective_stop_and_zero_scaling(node: ControllerNode, ur5: RobotModel) -> None:
    """Slider writes stop: after watchdog_s the node stops the robot; RTDE shows it (rtde_set_watchdog "pause")."""
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.24", clock) as face:
        client = RawClient("127.0.41.24")
        outputs = client.handshake()
        slider = _slider_recipe(client)
        assert rtde.decode_accepted(client.request(MessageType.CONTROL_PACKAGE_START))
        client.send(MessageType.DATA_PACKAGE, rtde.encode_data(slider, (22, 1, 0.6)))
        _wait_for(lambda: face.stats().slider_writes == 1, "the slider write")
        face.on_cycle(node.cycle(clock.advance(0.004)))
        face.tick()
        running = dict(zip(OUTPUTS, rtde.decode_data(outputs, client.receive().payload), strict=True))
        assert (running["runtime_state"], running["safety_mode"]) == (2, 1)
        # accelerating from standstill: the combined scaling is the applied override, one cycle's ramp of 0.6
        applied = node.stats().delta_applied
        assert 0.0 < applied < 0.6
        assert running["speed_scaling"] * running["target_speed_fraction"] == pytest.approx(applied)
        assert running["target_speed_fraction"] == 0.6
        for _ in range(30):  # 0.12 s without a write
            output = node.cycle(clock.advance(0.004))
            face.on_cycle(output)
        face.tick()
        held = dict(zip(OUTPUTS, rtde.decode_data(outputs, client.receive().payload), strict=True))
        assert held["safety_mode"] == rtde.SAFETY_PROTECTIVE_STOP
        assert held["speed_scaling"] == 0.0
        assert held["runtime_state"] in (rtde.RUNTIME_PAUSING, rtde.RUNTIME_PAUSED)
        assert held["target_speed_fraction"] == 0.6  # the slider stays where it was
        client.close()


def test_output_values_carry_the_applied_override_in_target_qd(node: ControllerNode) -> None:
    clock = FakeClock()
    output = node.cycle(clock())
    values = output_values(output, 0.7, 1.5)
    assert values["target_qd"] == tuple(output.joint_state.qd)
    assert values["target_speed_fraction"] == 0.7
    assert values["timestamp"] == 1.5


def test_the_default_recipe_carries_one_cycle_consistent_with_itself(node: ControllerNode, ur5: RobotModel) -> None:
    """ur-rtde's default recipe, decoded from the bytes: every package one cycle, its pose the DH flange at its
    joints, its qdd the change of qd between packages, the registers a client wrote read back."""
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.32", clock) as face:
        client = RawClient("127.0.41.32")
        outputs = client.handshake(500.0, list(UR_RTDE_DEFAULT_OUTPUTS))
        assert outputs.recipe_id == 1
        assert outputs.types == tuple(rtde.output_type(n) for n in UR_RTDE_DEFAULT_OUTPUTS)
        slider = _slider_recipe(client)  # input_int_register_23, speed_slider_mask, speed_slider_fraction
        recipe_id, _ = rtde.decode_setup_reply(
            client.request(
                MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS,
                rtde.encode_output_setup(500.0, [*UR_RTDE_DEFAULT_OUTPUTS, "input_int_register_23"]),
            )
        )
        assert recipe_id == 1  # set up again (before the start), now with the register read back
        outputs = Recipe(1, (*UR_RTDE_DEFAULT_OUTPUTS, "input_int_register_23"), (*outputs.types, "INT32"))
        assert rtde.decode_accepted(client.request(MessageType.CONTROL_PACKAGE_START))
        packages = []
        for i in range(60):
            client.send(MessageType.DATA_PACKAGE, rtde.encode_data(slider, (22, 1, 0.8)))
            _wait_for(lambda n=i + 1: face.stats().slider_writes == n, "the slider write")
            face.on_cycle(node.cycle(clock.advance(0.004)))
            face.tick(2)
            packages.append(dict(zip(outputs.names, rtde.decode_data(outputs, client.receive().payload), strict=True)))
        before, last = packages[-2], packages[-1]
        assert last["input_int_register_23"] == 22
        assert last["timestamp"] - before["timestamp"] == pytest.approx(0.004)
        qdd = (np.asarray(last["target_qd"]) - np.asarray(before["target_qd"])) / 0.004
        assert last["target_qdd"] == pytest.approx(qdd, abs=1e-9)
        assert any(abs(a) > 1e-3 for p in packages for a in p["target_qdd"])  # it accelerated from rest
        for package in packages:
            flange = ur5_flange_in_base(package["actual_q"])
            assert package["actual_TCP_pose"][:3] == pytest.approx(flange[:3, 3], abs=1e-9)
            assert rotation_of(package["actual_TCP_pose"][3:]) == pytest.approx(flange[:3, :3], abs=1e-9)
            assert package["target_TCP_pose"] == package["actual_TCP_pose"]
        assert last["actual_momentum"] > 0.0
        assert last["joint_mode"] == (253,) * 6
        assert last["actual_TCP_force"] == (0.0,) * 6
        assert face.stats().errors == {}
        client.close()


def test_outputs_a_5_11_controller_lacks_are_not_found(node: ControllerNode, ur5: RobotModel) -> None:
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.33", clock):
        client = RawClient("127.0.41.33")
        client.handshake()
        names = ["actual_q", "actual_current_as_torque", "joint_position_deviation_ratio", "output_bit_register_3"]
        recipe_id, types = rtde.decode_setup_reply(
            client.request(MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS, rtde.encode_output_setup(500.0, names))
        )
        assert (recipe_id, types) == (0, ("VECTOR6D", rtde.NOT_FOUND, rtde.NOT_FOUND, rtde.NOT_FOUND))
        client.close()


def test_second_client_gets_in_use_for_the_slider(node: ControllerNode, ur5: RobotModel) -> None:
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.25", clock) as face:
        owner, intruder = RawClient("127.0.41.25"), RawClient("127.0.41.25")
        owner.handshake()
        intruder.handshake()
        assert _slider_recipe(owner).recipe_id == 1
        recipe_id, types = rtde.decode_setup_reply(
            intruder.request(
                MessageType.CONTROL_PACKAGE_SETUP_INPUTS, rtde.encode_input_setup(["speed_slider_fraction"])
            )
        )
        assert (recipe_id, types) == (0, (rtde.IN_USE,))
        owner.close()
        _wait_for(lambda: face.stats().clients == 1, "the owner's disconnect")
        recipe_id, types = rtde.decode_setup_reply(
            intruder.request(
                MessageType.CONTROL_PACKAGE_SETUP_INPUTS, rtde.encode_input_setup(["speed_slider_fraction"])
            )
        )
        assert (recipe_id, types) == (2, ("DOUBLE",))  # numbered in arrival order, the refused one included
        intruder.close()


def test_unknown_outputs_are_not_found_and_fast_frequencies_refused(node: ControllerNode, ur5: RobotModel) -> None:
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.26", clock) as face:
        client = RawClient("127.0.41.26")
        client.handshake()
        recipe_id, types = rtde.decode_setup_reply(
            client.request(
                MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS, rtde.encode_output_setup(500.0, ["timestamp", "tcp_force"])
            )
        )
        assert (recipe_id, types) == (0, ("DOUBLE", rtde.NOT_FOUND))
        recipe_id, _ = rtde.decode_setup_reply(
            client.request(MessageType.CONTROL_PACKAGE_SETUP_OUTPUTS, rtde.encode_output_setup(501.0, ["timestamp"]))
        )
        assert recipe_id == 0
        assert not rtde.decode_accepted(client.request(MessageType.CONTROL_PACKAGE_START))
        assert face.stats().errors["output_setup_refused"] == 2
        client.close()


def test_slider_values_out_of_range_are_not_applied(node: ControllerNode, ur5: RobotModel) -> None:
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.27", clock) as face:
        client = RawClient("127.0.41.27")
        client.handshake()
        slider = _slider_recipe(client)
        for mask, fraction in [(1, 1.5), (1, -0.1), (1, float("nan")), (2, 0.5)]:
            client.send(MessageType.DATA_PACKAGE, b"\x01" + struct.pack(">iId", 22, mask, fraction))
        client.send(MessageType.DATA_PACKAGE, rtde.encode_data(slider, (22, 0, 0.9)))  # mask 0: no change
        _wait_for(lambda: face.stats().errors.get("slider_value", 0) == 4, "the refusals")
        assert face.stats().slider_writes == 0
        assert node.stats().override_seq == -1
        client.close()


@pytest.mark.parametrize(
    ("raw", "reason"),
    [
        (b"\x00\x01\x00garbage", "garbage"),
        (b"\x20\x00U" + bytes(100), "oversize"),
        (b"\x00\x05Z\x00\x02", "unknown_type"),
        (b"\x00\x03v", "not_negotiated"),
    ],
)
def test_hostile_bytes_disconnect_that_client_only(
    node: ControllerNode, ur5: RobotModel, raw: bytes, reason: str
) -> None:
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.28", clock) as face:
        good = RawClient("127.0.41.28")
        outputs = good.handshake()
        assert rtde.decode_accepted(good.request(MessageType.CONTROL_PACKAGE_START))
        hostile = RawClient("127.0.41.28")
        hostile.sock.sendall(raw)
        text = hostile.receive()
        assert text.type_code == MessageType.TEXT_MESSAGE
        message, _source, level = rtde.decode_text(text.payload)
        assert level == rtde.TextLevel.ERROR
        assert message
        assert hostile.closed()
        assert face.stats().errors[reason] == 1
        face.tick()
        assert rtde.decode_data(outputs, good.receive().payload)[0] == 0.0  # the good client still served: the cycle
        good.close()
        hostile.close()


def test_wrong_version_is_refused_and_the_client_may_retry(node: ControllerNode, ur5: RobotModel) -> None:
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.29", clock) as face:
        client = RawClient("127.0.41.29")
        assert not rtde.decode_accepted(client.request(MessageType.REQUEST_PROTOCOL_VERSION, b"\x00\x01"))
        assert rtde.decode_accepted(client.request(MessageType.REQUEST_PROTOCOL_VERSION, b"\x00\x02"))
        assert rtde.decode_controller_version(client.request(MessageType.GET_URCONTROL_VERSION))[0] == 5
        assert face.stats().errors["bad_version"] == 1
        client.close()


def test_data_for_a_recipe_not_set_up_disconnects(node: ControllerNode, ur5: RobotModel) -> None:
    clock = FakeClock()
    with _face(node, ur5, "127.0.41.30", clock) as face:
        client = RawClient("127.0.41.30")
        client.handshake()
        client.send(MessageType.DATA_PACKAGE, b"\x07" + struct.pack(">Id", 1, 1.0))
        assert client.receive().type_code == MessageType.TEXT_MESSAGE
        assert client.closed()
        assert face.stats().errors["unknown_recipe"] == 1
        assert node.stats().override_seq == -1
