"""The real gateway and controller emulator over mutual TLS with access control, attacked on one host.

A module-wide cell: the gateway (listening) and the controller emulator (listening too, and connected to
the gateway), each with its own certificate from a fresh CA. No tracker program: the test plays the tracker
emulator (its certificate), or plays nobody so that the gateway commands δ = 0 (missing tracker data).

Teeth: ``HRC_SECURITY_TEETH=plain`` runs the same tests against the cell with ``--insecure-plain-tcp`` and
plain intruders; then the intruder and observer tests fail (the robot is moved by the forged overrides).
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest
import zenoh
from support.securecell import StateWatch, forge_overrides, intruder_config, listening

from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.messages import Humans, to_payload
from hrc_runtime.access_control import CellPolicy
from hrc_runtime.config import load_cell_config
from hrc_runtime.locate import STATE_DIR_ENV_VAR
from hrc_runtime.pki import CellPki
from hrc_runtime.zenoh_session import SessionOptions, mutual_tls, session_config
from hrc_tools.cell.procs import Program, free_port, program_env, start_program, stop_all, stop_program, wait_or_fail
from hrc_tools.cert.main import provision_cell

pytestmark = pytest.mark.e2e

ROBOT = "ur5"
PLAIN = os.environ.get("HRC_SECURITY_TEETH") == "plain"
START_TIMEOUT_S = 60.0
FORGE_S = 2.0


@dataclass
class SecureCell:
    """The running cell and how to join it."""

    config: CellConfig
    pki: CellPki
    gateway_endpoint: str
    controller_endpoint: str
    logs: list[Path]
    procs: dict[str, Program] = field(default_factory=dict)

    @property
    def cell(self) -> str:
        return self.config.cell

    def options(self, common_name: str, mode: str = "client", *, enforce: bool = False) -> SessionOptions:
        """A legitimate member's session options (plain in the teeth run); ``enforce``: the cell's access control."""
        if PLAIN:
            return SessionOptions("client" if mode == "client" else "peer")
        tls = mutual_tls(self.pki.root, common_name, CellPolicy.from_config(self.config) if enforce else None)
        return SessionOptions("client" if mode == "client" else "peer", tls)

    def intruder(self, common_name: str | None, endpoint: str) -> zenoh.Config:
        """A client presenting the cell certificate ``common_name`` (None: no certificate); plain in the teeth run."""
        if PLAIN:
            return intruder_config([endpoint], None)
        if common_name is None:
            return intruder_config([endpoint], self.pki.ca_certificate)
        identity, _ = self.pki.identity(common_name)
        return intruder_config([endpoint], self.pki.ca_certificate, identity.certificate, identity.private_key)


@pytest.fixture(scope="module")
def secure_cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SecureCell]:
    work = tmp_path_factory.mktemp("secure-cell")
    config = load_cell_config(None)
    pki = CellPki(work / "pki")
    provision_cell(pki, CellPolicy.from_config(config))
    protocol = "tcp" if PLAIN else "tls"
    gw_ep, ctrl_ep = f"{protocol}/127.0.0.1:{free_port()}", f"{protocol}/127.0.0.1:{free_port()}"
    security = ["--insecure-plain-tcp"] if PLAIN else ["--pki-dir", str(pki.root)]
    commands = {
        "gateway": ("gateway", ["--zenoh-listen", gw_ep, "--http-port", str(free_port()), *security]),
        "controller": ("controller_emu", ["--zenoh-listen", ctrl_ep, "--zenoh-connect", gw_ep, *security]),
    }
    cell = SecureCell(config, pki, gw_ep, ctrl_ep, [work / f"{name}.log" for name in commands])
    try:
        for (name, (module, args)), log in zip(commands.items(), cell.logs, strict=True):
            cell.procs[name] = start_program(module, args, log, program_env(plain_tcp=False))
        wait_or_fail(lambda: listening(gw_ep) and listening(ctrl_ep), START_TIMEOUT_S, "the listeners", cell.logs)
        with zenoh.open(session_config([], [gw_ep], cell.options("observer-fixture"))) as session:
            watch = StateWatch(session, cell.cell, ROBOT)
            statuses: list[bytes] = []
            session.declare_subscriber(keys.gateway_status(cell.cell), lambda s: statuses.append(b""))
            wait_or_fail(lambda: bool(statuses) and watch.latest() is not None, START_TIMEOUT_S, "the cell", cell.logs)
        yield cell
    finally:
        stop_all(cell.procs.values())


def _publish_nobody(session: zenoh.Session, cell: str, trackers: list[str], halt: threading.Event) -> None:
    """Every tracker sees nobody, at 30 Hz, until ``halt``."""
    publishers = {t: session.declare_publisher(keys.tracker_humans(cell, t)) for t in trackers}
    seq = 0
    while not halt.wait(1.0 / 30.0):
        seq += 1
        for name, publisher in publishers.items():
            publisher.put(to_payload(Humans(tracker=name, seq=seq, stamp_ns=time.time_ns(), humans=[])))


def _wait_robot_stopped(cell: SecureCell, watch: StateWatch) -> None:
    """The gateway, without tracker data, commands δ = 0: wait until the controller has applied it."""

    def stopped() -> bool:
        latest = watch.latest()
        return latest is not None and latest.override == 0.0 and latest.mode != "running"

    wait_or_fail(stopped, 10.0, "the controller applying δ = 0", cell.logs)


def test_override_reaches_the_controller_over_mutual_tls(secure_cell: SecureCell) -> None:
    """Tracker frames (the tracker emulator's certificate) → gateway → δ = 1 → controller, all over mutual TLS."""
    cell = secure_cell
    with (
        zenoh.open(session_config([], [cell.gateway_endpoint], cell.options("tracker-emu", "peer"))) as tracker,
        zenoh.open(session_config([], [cell.gateway_endpoint], cell.options("observer-alice"))) as observer,
    ):
        watch = StateWatch(observer, cell.cell, ROBOT)
        halt = threading.Event()
        publisher = threading.Thread(
            target=_publish_nobody, args=(tracker, cell.cell, list(cell.config.trackers), halt)
        )
        publisher.start()
        try:
            wait_or_fail(
                lambda: (s := watch.latest()) is not None and s.override >= 0.9, 15.0, "δ = 1 applied", cell.logs
            )
        finally:
            halt.set()
            publisher.join()
        _wait_robot_stopped(cell, watch)  # and back to δ = 0 once the tracker data stops
    if not PLAIN:
        assert not any("INSECURE" in log.read_text() for log in cell.logs)


def test_tracker_certificate_cannot_move_the_robot(secure_cell: SecureCell) -> None:
    """A valid tracker certificate puts δ = 1 on the override key, through the gateway and straight to the
    controller, while the gateway commands 0: the controller never applies anything but 0."""
    cell = secure_cell
    with zenoh.open(session_config([], [cell.gateway_endpoint], cell.options("observer-fixture"))) as observer:
        watch = StateWatch(observer, cell.cell, ROBOT)
        _wait_robot_stopped(cell, watch)
        with (
            zenoh.open(cell.intruder("tracker-front", cell.gateway_endpoint)) as routed,
            zenoh.open(cell.intruder("tracker-front", cell.controller_endpoint)) as direct,
        ):
            started_s = time.monotonic()
            results: dict[str, tuple[int, int]] = {}
            other = threading.Thread(
                target=lambda: results.update(direct=forge_overrides(direct, cell.cell, ROBOT, FORGE_S))
            )
            other.start()
            results["routed"] = forge_overrides(routed, cell.cell, ROBOT, FORGE_S)
            other.join()
        window = watch.since(started_s)
    puts, statuses = results["routed"]
    assert puts > 100
    assert results["direct"][0] > 100
    assert statuses > 0, "the intruder was on the bus (it read the gateway status)"
    assert len(window) > 100, "the controller kept publishing its state"
    assert max(s.override for s in window) == 0.0, "a forged override moved the robot"


def test_observer_reads_status_but_its_puts_are_denied(secure_cell: SecureCell) -> None:
    """An observer certificate reads the gateway status; its forged status and overrides reach nobody."""
    cell = secure_cell
    with (
        zenoh.open(session_config([], [cell.gateway_endpoint], cell.options("observer-alice"))) as alice,
        zenoh.open(session_config([], [cell.gateway_endpoint], cell.options("observer-bob"))) as bob,
    ):
        watch = StateWatch(bob, cell.cell, ROBOT)
        _wait_robot_stopped(cell, watch)
        seen_by_bob: list[bytes] = []
        lock = threading.Lock()

        def on_status(sample: zenoh.Sample) -> None:
            with lock:
                seen_by_bob.append(sample.payload.to_bytes())

        bob.declare_subscriber(keys.gateway_status(cell.cell), on_status)
        started_s = time.monotonic()
        forged_status = json.dumps({"forged": True}).encode()
        status_key = keys.gateway_status(cell.cell)
        alice.put(status_key, forged_status)
        puts, statuses = forge_overrides(alice, cell.cell, ROBOT, 1.0)
        alice.put(status_key, forged_status)
        wait_or_fail(lambda: len(watch.since(started_s)) > 100, 5.0, "joint states", cell.logs)
        with lock:
            seen = list(seen_by_bob)
    assert statuses > 0, "the observer reads the gateway status"
    assert puts > 50
    assert seen, "bob reads the gateway status too"
    assert forged_status not in seen, "the observer's forged status reached another reader"
    assert max(s.override for s in watch.since(started_s)) == 0.0


def test_auditor_reads_the_controller_through_the_gateway(secure_cell: SecureCell) -> None:
    """The auditor's identity with the cell's access control, a Zenoh client of the gateway: the controller's
    ground truth reaches it, routed by the gateway (which forwards what its own access control let in)."""
    cell = secure_cell
    received: list[bytes] = []
    options = cell.options("observer-audit", enforce=True)
    with zenoh.open(session_config([], [cell.gateway_endpoint], options)) as auditor:
        auditor.declare_subscriber(keys.truth_robot_state(cell.cell, ROBOT), lambda s: received.append(b""))
        wait_or_fail(lambda: len(received) > 10, 10.0, "the controller's truth through the gateway", cell.logs)


@pytest.mark.parametrize("who", ["no certificate", "certificate of another CA", "plain TCP"])
@pytest.mark.parametrize("target", ["gateway", "controller"])
def test_no_cell_certificate_no_connection(secure_cell: SecureCell, tmp_path: Path, who: str, target: str) -> None:
    cell = secure_cell
    endpoint = cell.gateway_endpoint if target == "gateway" else cell.controller_endpoint
    if who == "no certificate":
        conf = cell.intruder(None, endpoint)
    elif who == "certificate of another CA":
        forged = CellPki(tmp_path / "other-ca").issue("gateway")  # the right CN, the wrong CA
        conf = intruder_config(
            [endpoint], None if PLAIN else cell.pki.ca_certificate, forged.certificate, forged.private_key
        )
    else:
        conf = intruder_config(["tcp/" + endpoint.split("/", 1)[1]], None)
    with pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(conf).close()


def _run_secure(module: str, *args: str) -> subprocess.CompletedProcess[str]:
    """``python -m module args`` to its end, without the test harness's permission for plain TCP."""
    command = [sys.executable, "-m", module, *args]
    return subprocess.run(
        command, capture_output=True, text=True, timeout=60, env=program_env(plain_tcp=False), check=False
    )


@pytest.mark.parametrize(
    ("args", "says"),
    [
        (["--zenoh-connect", "tcp/127.0.0.1:1"], "--insecure-plain-tcp"),
        (["--insecure-plain-tcp", "--zenoh-connect", "tcp/192.0.2.1:7447"], "only on loopback"),
    ],
)
def test_controller_refuses_plain_tcp(tmp_path: Path, args: list[str], says: str) -> None:
    result = _run_secure("controller_emu", "--pki-dir", str(tmp_path), *args)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1
    assert says in lines[0]


def test_router_refuses_plain_tcp_off_loopback(tmp_path: Path) -> None:
    result = _run_secure("hrc_tools.router", "--insecure-plain-tcp", "--listen", "tcp/0.0.0.0:7447")
    assert result.returncode == 2
    assert "only on loopback" in result.stderr


def test_hrc_cell_creates_the_pki_and_runs_over_mutual_tls(tmp_path: Path) -> None:
    """``./run-cell.sh`` on a fresh clone: ``hrc-cell`` creates the CA and certificates in the state folder without
    a question and runs the cell over TLS; ``/readyz`` turns 200 once overrides flow to the controller and back."""
    state = tmp_path / "state"
    http_port, zenoh_port = free_port(), free_port()
    log = tmp_path / "hrc-cell.log"
    args = ["--http-port", str(http_port), "--zenoh-port", str(zenoh_port)]
    proc = start_program("hrc_tools.cell", args, log, program_env(plain_tcp=False) | {STATE_DIR_ENV_VAR: str(state)})

    def ready() -> bool:
        try:
            return httpx.get(f"http://127.0.0.1:{http_port}/readyz", timeout=2.0).status_code == 200
        except (httpx.HTTPError, OSError):
            return False

    try:
        wait_or_fail(ready, START_TIMEOUT_S, "/readyz 200 (inputs fresh, overrides flowing)", [log])
    finally:
        code = stop_program(proc)
    assert code == 0
    text = log.read_text()
    assert f"on tls/127.0.0.1:{zenoh_port}" in text
    assert "created the cell CA" in text
    assert "INSECURE" not in text
    pki = state / "pki"
    for key in ("ca.key", "gateway.key", "controller-ur5.key", "tracker-emu.key"):
        assert stat.S_IMODE((pki / key).stat().st_mode) == 0o600
