"""Across hosts: tracker, gateway and controller in separate network namespaces, joined by ``hrc-router``.

Each program runs in its own Linux network namespace (a "host") with a veth link to the root namespace, where
the router listens on one address per link; programs are Zenoh clients of the router. Everything is mutual
TLS with the cell's certificates and access control. The cell works (δ = 1 reaches the controller from the
tracker's frames); then, with the tracker stopped (the gateway commands δ = 0), an intruder namespace tries
with no certificate (refused at connect) and with a valid tracker certificate (connected, its δ = 1 overrides
never reach the controller).

Needs root and ``ip`` (iproute2): skipped with the reason otherwise. The namespaces and links are removed
even when a test fails.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import ExitStack, suppress
from dataclasses import dataclass
from pathlib import Path

import pytest
import zenoh
from support.paths import REPO_ROOT
from support.securecell import StateWatch, listening

from hrc_runtime.access_control import CellPolicy
from hrc_runtime.config import load_cell_config
from hrc_runtime.pki import CellPki
from hrc_runtime.zenoh_session import SessionOptions, mutual_tls, session_config
from hrc_tools.cell.procs import Program, free_port, program_env, start_program, stop_program, wait_or_fail
from hrc_tools.cert.main import provision_cell

pytestmark = pytest.mark.e2e

HOSTS = ("gw", "ctl", "trk", "int")
ROBOT = "ur5"


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check, timeout=10)


def _free_second_octet() -> int:
    """A 10.X.0.0/16 that no address or route of this machine uses."""
    used = _ip("-4", "addr").stdout + _ip("-4", "route").stdout
    for octet in range(213, 250):
        if f"10.{octet}." not in used:
            return octet
    pytest.skip("no free 10.X.0.0/16 for the test links")


@dataclass(frozen=True)
class Lan:
    """The namespaces: ``netns[host]`` reaches the router at ``router_ip[host]``."""

    netns: dict[str, str]
    router_ip: dict[str, str]

    def command(self, host: str, argv: Sequence[str] = ()) -> list[str]:
        """``argv`` run in ``host``'s namespace."""
        return ["ip", "netns", "exec", self.netns[host], *argv]


def _remove(tag: str) -> None:
    for i, host in enumerate(HOSTS, start=1):
        netns = f"hrc{tag}-{host}"
        pids = _ip("netns", "pids", netns, check=False).stdout.split()
        for pid in pids:
            with suppress(ProcessLookupError, ValueError):
                os.kill(int(pid), 9)
        _ip("netns", "del", netns, check=False)
        _ip("link", "del", f"hr{tag}{i}", check=False)


@pytest.fixture(scope="module")
def lan() -> Iterator[Lan]:
    if shutil.which("ip") is None:
        pytest.skip("no `ip` command (iproute2): cannot create network namespaces")
    if os.geteuid() != 0:
        pytest.skip("network namespaces need root (ip netns add); run the tests as root")
    tag = f"{os.getpid() % 100000:05d}"
    probe = _ip("netns", "add", f"hrc{tag}-probe", check=False)
    if probe.returncode != 0:
        pytest.skip(f"cannot create a network namespace: {probe.stderr.strip()}")
    _ip("netns", "del", f"hrc{tag}-probe", check=False)
    octet = _free_second_octet()
    try:
        netns, router_ip = {}, {}
        for i, host in enumerate(HOSTS, start=1):
            ns, outside, inside = f"hrc{tag}-{host}", f"hr{tag}{i}", f"hn{tag}{i}"
            _ip("netns", "add", ns)
            _ip("link", "add", outside, "type", "veth", "peer", "name", inside)
            _ip("link", "set", inside, "netns", ns)
            _ip("addr", "add", f"10.{octet}.{i}.1/30", "dev", outside)
            _ip("link", "set", outside, "up")
            _ip("-n", ns, "addr", "add", f"10.{octet}.{i}.2/30", "dev", inside)
            _ip("-n", ns, "link", "set", inside, "up")
            _ip("-n", ns, "link", "set", "lo", "up")
            netns[host], router_ip[host] = ns, f"10.{octet}.{i}.1"
        yield Lan(netns, router_ip)
    finally:
        _remove(tag)


def test_cell_across_namespaces_through_a_router(lan: Lan, tmp_path: Path) -> None:
    config = load_cell_config(None)
    pki = CellPki(tmp_path / "pki")
    provision_cell(pki, CellPolicy.from_config(config))  # the router's certificate it issues itself, naming its IPs
    tracker = pki.issue("tracker-front")
    port, local_port = free_port(), free_port()
    pki_args = ["--pki-dir", str(pki.root)]
    router_eps = {host: f"tls/{ip}:{port}" for host, ip in lan.router_ip.items()}
    logs: list[Path] = []

    def launch(name: str, module: str, args: list[str], host: str | None = None) -> Program:
        logs.append(tmp_path / f"{name}.log")
        wrapper = lan.command(host) if host else []
        return start_program(module, args, logs[-1], program_env(plain_tcp=False), wrapper)

    def client(host: str) -> list[str]:
        return ["--zenoh-mode", "client", "--zenoh-connect", router_eps[host], *pki_args]

    with ExitStack() as stack:
        listen = [a for ep in (*router_eps.values(), f"tls/127.0.0.1:{local_port}") for a in ("--listen", ep)]
        router = launch("router", "hrc_tools.router", [*listen, *pki_args])
        stack.callback(stop_program, router)
        wait_or_fail(
            lambda: listening(f"tls/127.0.0.1:{local_port}") or router.poll() is not None, 20.0, "the router", logs
        )
        assert router.poll() is None, (tmp_path / "router.log").read_text()
        procs = {
            "gateway": launch("gateway", "gateway", [*client("gw"), "--http-port", str(free_port())], "gw"),
            "controller": launch("controller", "controller_emu", client("ctl"), "ctl"),
            "tracker": launch("tracker", "tracker_emu", client("trk"), "trk"),
        }
        for proc in procs.values():
            stack.callback(stop_program, proc)
        observer = SessionOptions("client", mutual_tls(pki.root, "observer-test", None))
        session = stack.enter_context(zenoh.open(session_config([], [f"tls/127.0.0.1:{local_port}"], observer)))
        watch = StateWatch(session, config.cell, ROBOT)

        # The cell works across hosts: tracker → router → gateway → router → controller.
        wait_or_fail(lambda: any(s.override >= 0.5 for s in watch.since(0.0)), 60.0, "δ > 0.5 applied", logs)

        stop_program(procs["tracker"])  # no tracker data: the gateway commands δ = 0
        wait_or_fail(
            lambda: (s := watch.latest()) is not None and s.override == 0.0 and s.mode != "running",
            10.0,
            "δ = 0 applied",
            logs,
        )
        started_s = time.monotonic()
        ca = str(pki.ca_certificate)
        intruders = {
            "no-cert": ["--ca", ca],
            "tracker-cert": ["--ca", ca, "--cert", str(tracker.certificate), "--key", str(tracker.private_key)],
        }
        runs = {
            name: subprocess.run(
                lan.command(
                    "int",
                    [
                        sys.executable,
                        str(REPO_ROOT / "tests" / "support" / "securecell.py"),
                        "--connect",
                        router_eps["int"],
                        *args,
                        "--out",
                        str(tmp_path / f"{name}.json"),
                    ],
                ),
                capture_output=True,
                text=True,
                timeout=60,
                env=program_env(plain_tcp=False),
                check=False,
            )
            for name, args in intruders.items()
        }
        window = watch.since(started_s)
        assert all(p.poll() is None for p in procs.values() if p is not procs["tracker"]), "a program died"

    for name, run in runs.items():
        assert run.returncode == 0, f"{name}: {run.stderr}"
    no_cert = json.loads((tmp_path / "no-cert.json").read_text())
    with_cert = json.loads((tmp_path / "tracker-cert.json").read_text())
    assert not no_cert["connected"], no_cert
    assert "Unable to connect" in no_cert["error"]
    assert with_cert["connected"], with_cert
    assert with_cert["statuses"] > 0, "the tracker-certificate intruder was on the bus (it read the status)"
    assert with_cert["puts"] > 100
    assert len(window) > 100, "the controller kept publishing through the router"
    assert max(s.override for s in window) == 0.0, "a forged override moved the robot"
