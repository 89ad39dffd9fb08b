"""Session options: endpoints allowed per security, options from the command line, real in-process sessions.

The real programs over mutual TLS are in ``test_security_cell.py`` (one host) and ``test_security_netns.py``
(several network namespaces through a router).
"""

from __future__ import annotations

import argparse
import json
import logging
import threading
from pathlib import Path

import pytest
import zenoh
from support.securecell import intruder_config

from hrc_contract.config import CellConfig
from hrc_runtime.access_control import CellPolicy
from hrc_runtime.cli import add_zenoh_arguments
from hrc_runtime.pki import CellPki
from hrc_runtime.zenoh_session import (
    PLAIN_TCP_ENV_VAR,
    PLAIN_TCP_LOOPBACK,
    SecurityError,
    SessionOptions,
    check_endpoints,
    endpoint_host,
    mutual_tls,
    options_from_args,
    session_config,
)
from hrc_tools.cell.launcher import program_commands
from hrc_tools.cell.procs import free_port, wait_or_fail
from hrc_tools.cert.main import cli as cert_cli

pytestmark = pytest.mark.serial  # real processes, sockets or Zenoh sessions, judged in real time (tests/conftest.py)

POLICY = CellPolicy("demo", ("ur5",), ("front", "side"))
OVERRIDE = "hrc/demo/robot/ur5/override"


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_zenoh_arguments(parser)
    return parser.parse_args(list(argv))


@pytest.fixture(autouse=True)
def _no_plain_tcp_from_the_environment(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(PLAIN_TCP_ENV_VAR, raising=False)


# -- endpoints --------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("endpoint", "host"),
    [("tcp/127.0.0.1:7447", "127.0.0.1"), ("tls/[::1]:7447", "::1"), ("tls/gw.local:7447#iface=eth0", "gw.local")],
)
def test_endpoint_host(endpoint: str, host: str) -> None:
    assert endpoint_host(endpoint) == host


@pytest.mark.parametrize("endpoint", ["tcp/127.0.0.1:7447", "tcp/127.3.4.5:1", "tcp/[::1]:7447", "tcp/localhost:7447"])
def test_plain_tcp_on_loopback_is_allowed(endpoint: str) -> None:
    check_endpoints([endpoint], PLAIN_TCP_LOOPBACK)


@pytest.mark.parametrize(
    "endpoint", ["tcp/10.0.0.1:7447", "tcp/0.0.0.0:7447", "tcp/gw.local:7447", "udp/127.0.0.1:7447", "tls/127.0.0.1:1"]
)
def test_plain_session_refuses_anything_else(endpoint: str) -> None:
    with pytest.raises(SecurityError, match="only on loopback"):
        session_config([endpoint])


def test_tls_session_refuses_plain_endpoints(tmp_path: Path) -> None:
    options = SessionOptions("peer", mutual_tls(tmp_path / "pki", "gateway", POLICY))
    with pytest.raises(SecurityError, match="not TLS"):
        check_endpoints(["tcp/127.0.0.1:7447"], options)


# -- options from the command line ----------------------------------------------------------------


def test_default_is_mutual_tls_with_access_control(tmp_path: Path, cell_config: CellConfig) -> None:
    options = options_from_args(_args("--pki-dir", str(tmp_path)), "gateway", cell_config)
    assert options.tls is not None
    assert options.tls.identity.common_name == "gateway"
    assert options.tls.policy == CellPolicy.from_config(cell_config)
    conf = session_config(["tls/127.0.0.1:7447"], [], options)
    assert json.loads(conf.get_json("transport/link/tls/enable_mtls")) is True
    assert json.loads(conf.get_json("transport/link/protocols")) == ["tls"]
    assert json.loads(conf.get_json("access_control/default_permission")) == "deny"


def test_identity_and_mode_from_the_command_line(tmp_path: Path, cell_config: CellConfig) -> None:
    args = _args("--pki-dir", str(tmp_path), "--tls-identity", "observer-alice", "--zenoh-mode", "client")
    options = options_from_args(args, "gateway", cell_config)
    assert options.mode == "client"
    assert options.tls is not None
    assert options.tls.identity.common_name == "observer-alice"


def test_listen_hosts_are_named_in_a_new_certificate(tmp_path: Path, cell_config: CellConfig) -> None:
    args = _args("--pki-dir", str(tmp_path), "--zenoh-listen", "tls/192.0.2.7:7447")
    options = options_from_args(args, "gateway", cell_config)
    assert options.tls is not None
    assert "192.0.2.7" in CellPki(tmp_path).check(options.tls.identity).hosts


def test_plain_tcp_needs_the_flag(cell_config: CellConfig) -> None:
    with pytest.raises(SecurityError, match="--insecure-plain-tcp"):
        options_from_args(_args("--zenoh-listen", "tcp/127.0.0.1:7447"), "gateway", cell_config)


def test_plain_tcp_with_the_flag_warns(cell_config: CellConfig, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING):
        options = options_from_args(
            _args("--insecure-plain-tcp", "--zenoh-listen", "tcp/127.0.0.1:7447"), "gateway", cell_config
        )
    assert options.tls is None
    assert any("INSECURE" in r.getMessage() and r.levelno == logging.WARNING for r in caplog.records)


def test_plain_tcp_flag_from_the_environment(cell_config: CellConfig, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(PLAIN_TCP_ENV_VAR, "1")
    options = options_from_args(_args("--zenoh-connect", "tcp/127.0.0.1:7447"), "tracker-emu", cell_config)
    assert options.tls is None


@pytest.mark.parametrize("endpoint", ["tcp/192.0.2.1:7447", "tcp/0.0.0.0:7447"])
def test_plain_tcp_off_loopback_is_refused_even_with_the_flag(cell_config: CellConfig, endpoint: str) -> None:
    with pytest.raises(SecurityError, match="only on loopback"):
        options_from_args(_args("--insecure-plain-tcp", "--zenoh-listen", endpoint), "gateway", cell_config)


def test_mixed_protocols_are_refused(tmp_path: Path, cell_config: CellConfig) -> None:
    args = _args("--insecure-plain-tcp", "--zenoh-listen", "tls/127.0.0.1:1", "--zenoh-connect", "tcp/127.0.0.1:2")
    with pytest.raises(SecurityError, match="mixed"):
        options_from_args(args, "gateway", cell_config)


# -- real sessions in this process ----------------------------------------------------------------


def test_mutual_tls_delivers_and_access_control_filters(tmp_path: Path) -> None:
    """A gateway's override reaches a controller; a tracker's (valid certificate, client routed by the gateway)
    never does, and neither does a put straight to the controller."""
    pki_dir = tmp_path / "pki"
    gw_ep, ctrl_ep = f"tls/127.0.0.1:{free_port()}", f"tls/127.0.0.1:{free_port()}"
    gateway = SessionOptions("peer", mutual_tls(pki_dir, "gateway", POLICY))
    controller = SessionOptions("peer", mutual_tls(pki_dir, "controller-ur5", POLICY))
    tracker_client = SessionOptions("client", mutual_tls(pki_dir, "tracker-front", None))
    tracker_peer = SessionOptions("peer", mutual_tls(pki_dir, "tracker-front", None))
    received: list[bytes] = []
    lock = threading.Lock()

    def on_override(sample: zenoh.Sample) -> None:
        with lock:
            received.append(sample.payload.to_bytes())

    with (
        zenoh.open(session_config([gw_ep], [], gateway)) as gw,
        zenoh.open(session_config([ctrl_ep], [gw_ep], controller)) as ctrl,
    ):
        ctrl.declare_subscriber(OVERRIDE, on_override)
        publisher = gw.declare_publisher(OVERRIDE)
        wait_or_fail(lambda: bool(publisher.matching_status.matching), 5.0, "the controller subscribed")
        with (
            zenoh.open(session_config([], [gw_ep], tracker_client)) as via_gateway,
            zenoh.open(session_config([], [ctrl_ep], tracker_peer)) as direct,
        ):
            statuses: list[bytes] = []
            via_gateway.declare_subscriber("hrc/demo/gateway/status", lambda s: statuses.append(b""))

            def forge_until_connected() -> bool:
                via_gateway.put(OVERRIDE, b"forged-routed")
                direct.put(OVERRIDE, b"forged-direct")
                gw.put("hrc/demo/gateway/status", b"{}")
                return bool(statuses)

            # The tracker is on the bus (it reads the gateway's status) while it forges.
            wait_or_fail(forge_until_connected, 5.0, "the tracker reading the gateway status")
            for _ in range(20):
                forge_until_connected()
            publisher.put(b"genuine")
            wait_or_fail(lambda: b"genuine" in received, 5.0, "the genuine override")
    assert set(received) == {b"genuine"}


@pytest.mark.parametrize("who", ["no certificate", "another CA's gateway certificate"])
def test_intruder_without_a_cell_certificate_cannot_connect(tmp_path: Path, who: str) -> None:
    pki_dir = tmp_path / "pki"
    gw_ep = f"tls/127.0.0.1:{free_port()}"
    gateway = SessionOptions("peer", mutual_tls(pki_dir, "gateway", POLICY))
    ca = CellPki(pki_dir).ca_certificate  # public: the intruder can check the gateway with it
    if who == "no certificate":
        conf = intruder_config([gw_ep], ca)
    else:
        forged = CellPki(tmp_path / "other-ca").issue("gateway")
        conf = intruder_config([gw_ep], ca, forged.certificate, forged.private_key)
    with zenoh.open(session_config([gw_ep], [], gateway)), pytest.raises(zenoh.ZError, match="Unable to connect"):
        zenoh.open(conf)


def test_program_commands_run_tls_by_default(cell_config: CellConfig, tmp_path: Path) -> None:
    secure = program_commands(cell_config, None, None, 8080, "tls/127.0.0.1:7447", ["--pki-dir", str(tmp_path)])
    assert set(secure) == {"gateway", "controller-ur5", "tracker"}
    for command in secure.values():
        assert "tls/127.0.0.1:7447" in command
        assert command[command.index("--pki-dir") + 1] == str(tmp_path)
        assert "--insecure-plain-tcp" not in command


def test_hrc_cert_init_issue_list(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pki_dir = str(tmp_path / "pki")
    with pytest.raises(SystemExit) as done:
        cert_cli(["--pki-dir", pki_dir, "init"])
    assert done.value.code == 0
    assert "issued: gateway, controller-ur5, tracker-emu, observer-audit" in capsys.readouterr().out
    with pytest.raises(SystemExit) as done:
        cert_cli(["--pki-dir", pki_dir, "issue", "--role", "tracker", "--name", "lidar2", "--host", "10.1.2.3"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert "tracker-lidar2: certificate" in out
    assert "10.1.2.3" in out
    assert "not among the trackers" in out  # the shipped cell has front and side
    with pytest.raises(SystemExit) as done:
        cert_cli(["--pki-dir", pki_dir, "issue", "--role", "tracker"])
    assert done.value.code == 2
    assert "needs --name" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cert_cli(["--pki-dir", pki_dir, "list"])
    listed = capsys.readouterr().out.split()
    assert {"gateway", "controller-ur5", "tracker-emu", "observer-audit", "tracker-lidar2"} <= set(listed)
