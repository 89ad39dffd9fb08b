"""The cell through each controller bridge, end to end: gateway → bridge → vendor face (RTDE, RWS) → controller
emulator → bridge → gateway, all real processes (``hrc_tools.cell.procs.running_cell``, as ``hrc-cell`` runs them).

For each interface: the default scenario's zone sequence; a silent controller (the emulator frozen) and a slow one
(its vendor link delayed by a TCP relay) stop the robot with a reason in the status; a constant delay on the vendor
link with a steady δ (1, nobody near) shows in the override path the gateway measures (every write is provable:
``controller_bridge/bridge.py``); a dead bridge leaves the controller without speed writes, and the emulator's own
watchdog (URScript ``rtde_set_watchdog`` on a real UR, a RAPID heartbeat task on an ABB) stops the robot, while the
gateway shows the joint state stale.
"""

from __future__ import annotations

import random
import shutil
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh
from support.paths import REPO_ROOT
from support.tcp_delay import TcpDelay

from hrc_contract import keys
from hrc_contract.config import AbbRwsInterfaceConfig, CellConfig, UrRtdeInterfaceConfig
from hrc_contract.messages import JointState, parse_message
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.launcher import vendor_face_args
from hrc_tools.cell.procs import (
    Cell,
    collapse,
    free_port,
    is_subsequence,
    late_data_only,
    record,
    recovered,
    running_cell,
    scenario_window_s,
    write_cell_config,
)

pytestmark = pytest.mark.e2e

KINDS = ("abb_rws", "ur_rtde")
READY_S = 30.0
DETECT_S = 3.0
RECOVER_S = 15.0
SCENARIO_S = 31.0
ZONE_SEQUENCE = ["autonomous", "guarded_distance", "reduced_speed", "safety_exception", "autonomous"]
SLOW_LINK_S = 0.3
"""One-way delay of the slow vendor link [s]: above safety.max_data_age_s (0.2 s) for the override's round trip."""
STOPS = {"joint_state_stale", "override_path_stale"}
CONSTANT_LINK_S = {"ur_rtde": 0.3, "abb_rws": 0.03}
"""One-way delay of a constant slow vendor link [s]. RWS reads need three round trips (6 × 0.03 s per reading) and
its reads and writes share one connection: at 0.05 s the override path already nears the 1 s guard time."""
TOLERANT_S = 1.0
FAR_AWAY = "far_away"
WATCH_S = 4.0
STEADY_S = 1.2
"""δ = 1 without a fault for this long: the gateway's override path window (1 s) holds only its echoes [s]."""


def _loopback() -> str:
    """A loopback address of its own (RTDE's port 30004 is fixed: one address per emulated robot)."""
    return f"127.{random.randint(1, 254)}.{random.randint(0, 255)}.{random.randint(2, 254)}"


def _bridged_cell(
    kind: str, tmp_path: Path, via_relay: tuple[str, int] | None = None, tolerant: bool = False
) -> tuple[Path, list[str]]:
    """A copy of ``configs/cell_<kind>.toml`` on addresses of its own, and the emulator's face options.

    ``via_relay``: the bridge talks to this address (a relay in front of the face) instead of the face's.
    ``tolerant``: every guard time at its limit (1 s: the gateway's data age, the controller's watchdog, the
    bridge's read timeout), so that a slow link is measured and shown rather than stopped at once.
    """
    base = load_cell_config(REPO_ROOT / "configs" / f"cell_{kind}.toml")
    if tolerant:
        base = _tolerant(base, tmp_path)
    robot = base.robots["ur5"]
    interface = robot.interface
    if isinstance(interface, AbbRwsInterfaceConfig):
        face_at = ("127.0.0.1", free_port())
        bridge_at = via_relay or face_at
        update = {"url": f"http://{bridge_at[0]}:{bridge_at[1]}"}
    else:
        assert isinstance(interface, UrRtdeInterfaceConfig)
        face_at = (_loopback(), 30004)
        update = {"host": (via_relay or face_at)[0]}
    if tolerant:
        update["read_timeout_s"] = TOLERANT_S  # type: ignore[assignment]
    config = _with_interface(base, interface.model_copy(update=update))
    face_config = _with_interface(base, interface.model_copy(update=_face_update(interface, face_at)))
    return write_cell_config(config, tmp_path / "cell.toml"), vendor_face_args(face_config.robots["ur5"])


def _tolerant(config: CellConfig, tmp_path: Path) -> CellConfig:
    """``config`` with guard times of :data:`TOLERANT_S` and a scenario ``far_away`` (δ stays 1)."""
    scenarios = tmp_path / "scenarios"
    shutil.copytree(config.scenarios_dir, scenarios)
    (scenarios / f"{FAR_AWAY}.toml").write_text(
        'description = "one person standing still far from the robot"\nduration_s = 30.0\nloop = true\n\n'
        '[[humans]]\nid = "h1"\n\n'
        "[[humans.keyframes]]\nt_s = 0.0\nxy_m = [6.0, 0.0]\nheading_rad = 0.0\n\n"
        "[[humans.keyframes]]\nt_s = 30.0\nxy_m = [6.0, 0.0]\nheading_rad = 0.0\n"
    )
    robot = config.robots["ur5"]
    controller = robot.controller.model_copy(update={"watchdog_s": TOLERANT_S})
    safety = config.safety.model_copy(update={"max_data_age_s": TOLERANT_S})
    robots = {"ur5": robot.model_copy(update={"controller": controller})}
    return config.model_copy(update={"robots": robots, "safety": safety, "scenarios_dir": str(scenarios)})


def _face_update(interface: Any, face_at: tuple[str, int]) -> dict[str, str]:
    if isinstance(interface, AbbRwsInterfaceConfig):
        return {"url": f"http://{face_at[0]}:{face_at[1]}"}
    return {"host": face_at[0]}


def _with_interface(config: CellConfig, interface: Any) -> CellConfig:
    robot = config.robots["ur5"].model_copy(update={"interface": interface})
    return config.model_copy(update={"robots": {"ur5": robot}})


def _codes(status: dict[str, Any]) -> set[str]:
    return {f["code"] for f in status["faults"]}


def _healthy(status: dict[str, Any]) -> bool:
    return not status["faults"] and status["delta"] > 0.0 and status["controller_mode"] == "running"


def _stopped_by(codes: set[str]) -> Any:
    return lambda s: bool(_codes(s) & codes) and s["delta"] == 0.0 and s["zone"] == "safety_exception"


def _assert_alive(cell: Cell) -> None:
    for name, proc in cell.procs.items():
        assert proc.poll() is None, f"{name} died\n{cell.tail()}"


@pytest.fixture(params=KINDS)
def kind(request: pytest.FixtureRequest) -> str:
    return str(request.param)


@pytest.fixture
def cell(kind: str, tmp_path: Path) -> Iterator[Cell]:
    config, face = _bridged_cell(kind, tmp_path)
    with running_cell(tmp_path, config=config, scenario="standing_inside", face=face) as cell:
        yield cell


def test_the_default_scenario_through_the_bridge(kind: str, tmp_path: Path) -> None:
    config, face = _bridged_cell(kind, tmp_path)
    with running_cell(tmp_path, config=config, face=face) as cell:
        cell.wait_until(
            lambda s: s["zone"] == "autonomous" and not s["faults"], READY_S, "a fault-free autonomous cell"
        )
        trace = record(
            cell,
            scenario_window_s(SCENARIO_S),
            until=lambda t: is_subsequence(ZONE_SEQUENCE, collapse([s["zone"] for s in t])),
        )
        _assert_alive(cell)
    zones = collapse([s["zone"] for s in trace])
    assert is_subsequence(ZONE_SEQUENCE, zones), zones
    # late data on a busy machine fails closed and is tolerated; any other fault is not
    assert late_data_only(trace) == [], "faults on the way"
    bridge = trace[-1]["bridge"]
    assert bridge is not None
    assert bridge["interface"] == kind, bridge
    assert bridge["readback"] is not None, bridge
    assert bridge["readings_per_s"] > 0.0, bridge
    # The override path the gateway measured is the bridge's: echoes come only from the controller's read-back.
    assert all(s["delay_budget_s"]["override_path_s"] > 0.0 for s in trace)


def test_a_silent_controller_stops_the_robot(cell: Cell) -> None:
    cell.wait_until(_healthy, READY_S, "a moving robot")
    cell.controller.send_signal(signal.SIGSTOP)
    try:
        status = cell.wait_until(_stopped_by({"joint_state_stale"}), DETECT_S, "joint_state_stale with δ = 0")
        assert any(f["reason"].startswith("joint state is ") and "(limit " in f["reason"] for f in status["faults"])
    finally:
        cell.controller.send_signal(signal.SIGCONT)
    cell.wait_until(recovered, RECOVER_S, "recovery after the controller answered again")
    _assert_alive(cell)


def test_a_slow_controller_stops_the_robot(kind: str, tmp_path: Path) -> None:
    relay_host = "127.0.0.1" if kind == "abb_rws" else _loopback()
    relay_port = free_port() if kind == "abb_rws" else 30004
    config, face = _bridged_cell(kind, tmp_path, via_relay=(relay_host, relay_port))
    face_at = face[1].rsplit(":", 1) if kind == "abb_rws" else [face[1], "30004"]
    with (
        TcpDelay((relay_host, relay_port), (face_at[0], int(face_at[1]))) as relay,
        running_cell(tmp_path, config=config, scenario="standing_inside", face=face) as cell,
    ):
        cell.wait_until(_healthy, READY_S, "a moving robot")
        relay.delay_s = SLOW_LINK_S
        status = cell.wait_until(_stopped_by(STOPS), DETECT_S + 2 * SLOW_LINK_S, f"one of {sorted(STOPS)} with δ = 0")
        assert any(f["code"] in STOPS and "(limit " in f["reason"] for f in status["faults"]), status["faults"]
        relay.delay_s = 0.0
        cell.wait_until(recovered, RECOVER_S, "recovery after the link is fast again")
        _assert_alive(cell)


def test_a_constant_slow_link_with_a_steady_delta_shows_in_the_override_path(kind: str, tmp_path: Path) -> None:
    """δ is 1 (nobody near) and the vendor link is slow from the start: the echo of every override now comes from a
    read-back of a value written after it (the dither), so the override path the gateway measures (and its status
    shows) carries the link both ways, and the gateway's δ accounts for it (on RWS the path outgrows the 1 s limit:
    ``override_path_stale`` stops the robot at times). Before, a steady δ was confirmed by the next reading and the
    path looked a few milliseconds long."""
    link_s = CONSTANT_LINK_S[kind]
    relay_host = "127.0.0.1" if kind == "abb_rws" else _loopback()
    relay_port = free_port() if kind == "abb_rws" else 30004
    config, face = _bridged_cell(kind, tmp_path, via_relay=(relay_host, relay_port), tolerant=True)
    face_at = face[1].rsplit(":", 1) if kind == "abb_rws" else [face[1], "30004"]
    with TcpDelay((relay_host, relay_port), (face_at[0], int(face_at[1]))) as relay:
        relay.delay_s = link_s
        with running_cell(tmp_path, config=config, scenario=FAR_AWAY, face=face) as cell:
            cell.wait_until(lambda s: s["delta"] == 1.0 and not s["faults"], 2 * READY_S, "δ = 1 without a fault")
            trace = record(cell, WATCH_S)
            _assert_alive(cell)
    paths = [s["delay_budget_s"]["override_path_s"] for s in trace]
    assert sorted(paths)[len(paths) // 2] >= 2 * link_s, f"override path over a link of {link_s} s each way: {paths}"
    steady = _steady(trace, STEADY_S)
    for status in steady:  # δ = 1 without a fault for the gateway's whole window: every echo in it crossed the link
        path = status["delay_budget_s"]["override_path_s"]
        assert path >= 2 * link_s, f"at t = {status['t_s']:.2f} s after {STEADY_S} s of δ = 1: {path} s"
    bridge = trace[-1]["bridge"]
    assert bridge is not None
    assert bridge["readback_latency_max_s"] is None or bridge["readback_latency_max_s"] >= 2 * link_s, bridge


def _steady(trace: list[dict[str, Any]], steady_s: float) -> list[dict[str, Any]]:
    """The statuses preceded by ``steady_s`` of statuses with δ = 1 and no fault (a stop at δ = 0 is confirmed by
    the value in force, which proves nothing of the link, and stays in the gateway's 1 s window that long)."""
    out, since = [], None
    for status in trace:
        if status["delta"] != 1.0 or status["faults"]:
            since = None
            continue
        since = status["t_s"] if since is None else since
        if status["t_s"] - since >= steady_s:
            out.append(status)
    return out


class _Truth:
    """The emulator's true joint states (its ground-truth key), read from it directly."""

    def __init__(self) -> None:
        self.states: list[JointState] = []
        self._lock = threading.Lock()

    def on_sample(self, sample: zenoh.Sample) -> None:
        state = parse_message(sample.payload.to_bytes(), JointState)
        with self._lock:
            self.states.append(state)

    def since(self, stamp_ns: int) -> list[JointState]:
        with self._lock:
            return [s for s in self.states if s.stamp_ns > stamp_ns]


def test_a_dead_bridge_leaves_the_robot_to_the_controllers_watchdog(cell: Cell) -> None:
    truth = _Truth()
    cell.wait_until(_healthy, READY_S, "a moving robot")
    with zenoh.open(session_config(connect=[cell.controller_endpoint])) as session:
        session.declare_subscriber(keys.truth_robot_state("demo", "ur5"), truth.on_sample)
        time.sleep(0.5)
        killed_ns = time.time_ns()
        cell.bridge.kill()
        cell.bridge.wait()
        status = cell.wait_until(_stopped_by({"joint_state_stale"}), DETECT_S, "joint_state_stale with δ = 0")
        assert "joint_state_stale" in _codes(status)
        time.sleep(0.5)
        after = truth.since(killed_ns)
    assert after, "no ground truth from the emulator"
    stopped = [s for s in after if s.mode == "protective_stop"]
    assert stopped, f"the emulator never stopped on its own: modes {sorted({s.mode for s in after})}"
    # Within its watchdog (0.1 s) after the last write, plus the braking ramp, the robot stands.
    assert (stopped[0].stamp_ns - killed_ns) / 1e9 < 0.5
    assert after[-1].override == 0.0
    assert all(v == 0.0 for v in after[-1].qd)
    cell.start("bridge")
    cell.wait_until(recovered, RECOVER_S, "recovery with a new bridge")
    _assert_alive(cell)
