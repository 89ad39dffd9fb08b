"""The bridge program: its choice of robot and interface, and the real processes (emulator RTDE face + bridge)."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import zenoh
from support.cell_files import CONFIGS, replace_once, write_cell
from support.paths import REPO_ROOT

from controller_bridge.bridge import Bridge, BridgeSettings
from controller_bridge.main import _Reader, make_interface, select_robot
from hrc_contract import keys
from hrc_contract.config import AbbRwsInterfaceConfig, ConfigError, StreamsConfig
from hrc_contract.messages import JointState, Override, parse_message, to_payload
from hrc_devices.controllers.registry import VENDORS
from hrc_devices.controllers.vendor import VendorError
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import free_endpoint, start_program, stop_all, wait_or_fail

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

CELL, ROBOT = "demo", "ur5"
RTDE_HOST = "127.0.41.19"
ROBOT_TABLE = "[robots.ur5]\n"


def _bridged_cell(tmp_path: Path, interface: str) -> Path:
    for extra in CONFIGS.glob("*.toml"):  # files the cell references beside it (e.g. body_regions.toml)
        if extra.name != "cell.toml":
            shutil.copy(extra, tmp_path / extra.name)
    return write_cell(tmp_path, cell=replace_once(ROBOT_TABLE, f"{ROBOT_TABLE}interface = {interface}\n"))


def test_a_robot_on_the_zenoh_interface_needs_no_bridge() -> None:
    config = load_cell_config()
    with pytest.raises(ConfigError, match="no bridge"):
        select_robot(config, ROBOT)
    with pytest.raises(ConfigError, match="0 robots with a bridged interface"):
        select_robot(config, None)


def test_the_cell_file_chooses_the_interface(tmp_path: Path) -> None:
    config = load_cell_config(_bridged_cell(tmp_path, f'{{ kind = "ur_rtde", host = "{RTDE_HOST}" }}'))
    assert select_robot(config, None) == ROBOT
    interface = config.robots[ROBOT].interface
    assert (interface.kind, getattr(interface, "frequency_hz", None)) == ("ur_rtde", 500)


def test_a_password_in_the_cell_file_is_refused(tmp_path: Path) -> None:
    path = _bridged_cell(
        tmp_path, '{ kind = "abb_rws", url = "http://127.0.0.1:8080", password_env = "RWS_PW", password = "robotics" }'
    )
    with pytest.raises(ConfigError, match="password in the cell file is refused"):
        load_cell_config(path)


def test_the_abb_password_comes_from_the_named_environment_variable() -> None:
    interface = AbbRwsInterfaceConfig(kind="abb_rws", url="http://127.0.0.1:8080", password_env="RWS_PW")
    with pytest.raises(ConfigError, match="RWS_PW"):
        make_interface(interface, 6, environ={})
    assert make_interface(interface, 6, environ={"RWS_PW": "robotics"}).kind == "abb_rws"
    https = AbbRwsInterfaceConfig(kind="abb_rws", url="https://127.0.0.1", password_env="RWS_PW")
    with pytest.raises(ConfigError, match="plain HTTP only"):
        make_interface(https, 6, environ={"RWS_PW": "x"})


def test_a_bridge_watchdog_longer_than_the_controllers_is_refused(tmp_path: Path) -> None:
    path = _bridged_cell(tmp_path, f'{{ kind = "ur_rtde", host = "{RTDE_HOST}", watchdog_s = 0.5 }}')
    with pytest.raises(ConfigError, match=r"interface\.watchdog_s"):
        load_cell_config(path)


def _rtde_pieces_missing() -> str | None:
    if importlib.util.find_spec("hrc_devices.controllers.ur_rtde.client") is None:
        return "hrc_devices/controllers/ur_rtde/client.py is not there yet"
    help_text = subprocess.run(
        [sys.executable, "-m", "controller_emu", "--help"], cwd=REPO_ROOT, capture_output=True, text=True, check=False
    ).stdout
    if "--rtde" not in help_text:
        return "hrc-controller-emu has no --rtde face yet"
    return None


@pytest.mark.e2e
def test_the_bridge_confirms_an_override_only_once_the_rtde_read_back_shows_it(tmp_path: Path) -> None:
    missing = _rtde_pieces_missing()
    if missing is not None:
        pytest.skip(missing)
    cell = _bridged_cell(tmp_path, f'{{ kind = "ur_rtde", host = "{RTDE_HOST}", frequency_hz = 500 }}')
    emu_endpoint, endpoint = free_endpoint(), free_endpoint()  # the emulator's own Zenoh face is not on the test's
    logs = [tmp_path / "emu.log", tmp_path / "bridge.log"]
    emu = start_program(
        "controller_emu", ["--config", str(cell), "--rtde", RTDE_HOST, "--zenoh-listen", emu_endpoint], logs[0]
    )
    bridge = start_program("controller_bridge", ["--config", str(cell), "--zenoh-listen", endpoint], logs[1])
    procs = [emu, bridge]
    states: list[JointState] = []
    lock = threading.Lock()

    def on_state(sample: zenoh.Sample) -> None:
        with lock:
            states.append(parse_message(sample.payload.to_bytes(), JointState))

    try:
        with zenoh.open(session_config(connect=[endpoint])) as session:
            sub = session.declare_subscriber(keys.robot_state(CELL, ROBOT), on_state)
            pub = session.declare_publisher(keys.robot_override(CELL, ROBOT), express=True)
            wait_or_fail(lambda: len(states) >= 10, 20.0, "joint states from the bridge", logs, procs)
            with lock:
                assert all(s.override_seq == -1 for s in states), "no override put yet: nothing confirmed"
            sent: dict[int, int] = {}
            seq, end_s = 0, time.monotonic() + 2.0
            while time.monotonic() < end_s:  # play the gateway at 250 Hz: δ = 0.5, then 0.25
                delta = 0.5 if seq < 250 else 0.25
                sent[seq] = time.time_ns()
                pub.put(to_payload(Override(robot=ROBOT, seq=seq, stamp_ns=sent[seq], delta=delta)))
                seq += 1
                time.sleep(0.004)
            with lock:
                echoed = [s for s in states if s.override_seq >= 0]
            assert echoed, "the read-back confirmed an override"
            for state in echoed:
                assert state.override_seq in sent
                # stamped on the controller's time of the package that showed it: the emulator's package is stamped
                # by its output tick, which may begin just before the write it carries; within the gateway's clock
                # tolerance of the send (streams.max_future_stamp_s), never earlier
                earliest_ns = sent[state.override_seq] - round(StreamsConfig().max_future_stamp_s * 1e9)
                assert state.stamp_ns >= earliest_ns, "confirmed after it was sent, never before"
            assert echoed[-1].override_seq >= 250, "the change to 0.25 was confirmed"
            assert echoed[-1].override <= 0.25 + 1e-6
            del sub
    finally:
        stop_all(procs)
    assert bridge.returncode == 0


class _SlowOnce:
    """A polled interface whose second read is held 35 ms (its thread off the CPU); records when each read starts.
    Every read fails with a reason that does not reconnect, so nothing else happens."""

    kind = "abb_rws"

    def __init__(self, stop: threading.Event, reads: int) -> None:
        self.starts_s: list[float] = []
        self._stop, self._reads = stop, reads

    def connect(self) -> None:
        pass

    def close(self) -> None:
        pass

    def read(self, timeout_s: float) -> object:
        self.starts_s.append(time.monotonic())
        if len(self.starts_s) == 2:
            time.sleep(0.035)
        if len(self.starts_s) >= self._reads:
            self._stop.set()
        raise VendorError("timeout", "scripted")


def test_a_polled_reader_never_reads_sooner_than_its_interval_after_a_late_read() -> None:
    """At 50 Hz, a read held 35 ms must not be followed by a catch-up read a few milliseconds later: q would be
    differenced over less than the controller's cycle plus the request's jitter (qd above the joint's limit)."""
    settings = BridgeSettings(
        robot="ur5",
        speed_input=VENDORS["abb_rws"].speed_input,
        velocity_limit_radps=(3.15,) * 6,
        braking_time_s=0.24,
        watchdog_s=0.1,
        heartbeat_s=0.04,
        max_diff_gap_s=5.0,
    )
    stop = threading.Event()
    interface = _SlowOnce(stop, reads=6)
    reader = _Reader(Bridge(settings), interface, lambda state: None, stop, poll_interval_s=0.02)  # type: ignore[arg-type]
    reader.thread.start()
    reader.thread.join(timeout=10.0)
    assert not reader.thread.is_alive()
    gaps_s = [b - a for a, b in zip(interface.starts_s, interface.starts_s[1:], strict=False)]
    assert len(gaps_s) == 5
    assert gaps_s[1] >= 0.035  # the held read
    assert min(gaps_s) >= 0.0195, gaps_s  # the old schedule read again ~5 ms after the held one
