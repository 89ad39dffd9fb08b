"""``hrc-cell``: run a whole cell (gateway, one controller emulator per robot, tracker emulator) on this machine.

A robot whose ``interface`` is ``ur_rtde`` or ``abb_rws`` (a closed controller) or ``abb_egm`` (an open one) is
reached as a real one would be: its emulator serves the vendor's face (``--rtde HOST``, ``--rws HOST:PORT``, ``--egm
HOST:PORT``) and ``hrc-controller-bridge --robot R`` (program ``bridge-<robot>``) runs beside it, with the same
certificate (``controller-<robot>``), between that face and the cell's Zenoh contract (docs/controllers.md).

Each program is its own process, as in production; they meet over Zenoh on loopback, with mutual TLS and the
cell's access control: on first start the cell CA and the programs' certificates are created in the state
folder (``$HRC_STATE_DIR/pki``, else ``.state/pki``; see docs/security.md). ``--insecure-plain-tcp`` runs them
over plain TCP instead (development only, loudly). Ctrl-C (or SIGTERM) stops all of them cleanly; if one of
them exits on its own, the others are stopped too.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from hrc_contract.config import CellConfig, ConfigError, RobotConfig
from hrc_devices.controllers.registry import OPEN_VENDORS, VENDORS
from hrc_runtime.access_control import CellPolicy
from hrc_runtime.config import load_cell_config
from hrc_runtime.pki import CellPki, default_pki_dir
from hrc_runtime.signals import stop_on_signals
from hrc_tools.cert.main import provision_cell


def _module_command(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", module, *args]


def vendor_face_args(robot: RobotConfig) -> list[str]:
    """The emulator's options that serve the robot's vendor interface (none for ``zenoh``).

    Raises:
        ConfigError: the emulator cannot serve the interface as configured (an ``abb_rws`` URL that is not
            ``http://HOST:PORT``: the emulator serves RWS 1.0 only).
    """
    kind = robot.interface.kind
    vendor = VENDORS.get(kind) or OPEN_VENDORS.get(kind)
    return [] if vendor is None else vendor.emulator_args(robot.interface)


def bridged_robots(config: CellConfig) -> list[str]:
    """The robots reached through a controller bridge (an interface kind of either registry: a closed controller's
    speed input or an open controller's joint references), sorted."""
    kinds = {*VENDORS, *OPEN_VENDORS}
    return sorted(name for name, robot in config.robots.items() if robot.interface.kind in kinds)


def bridge_environment(config: CellConfig, environ: dict[str, str] | None = None) -> dict[str, str]:
    """The bridges' environment: what each bridged robot's vendor needs where unset (an ``abb_rws`` robot's RWS
    password variable, set to the emulator's password; the cell's controllers are emulators; a value already set is
    kept)."""
    env = dict(os.environ if environ is None else environ)
    for robot in config.robots.values():
        vendor = VENDORS.get(robot.interface.kind)
        if vendor is not None:
            vendor.environment(robot.interface, env)
    return env


def program_commands(
    config: CellConfig,
    config_path: str | None,
    scenario: str | None,
    http_port: int,
    endpoint: str,
    security_args: list[str],
    record_dir: Path | None = None,
) -> dict[str, list[str]]:
    """The command line of each program of the cell, by name (gateway, controller-<robot>, bridge-<robot> for a
    robot behind a bridge, tracker[, recorder]).

    Args:
        config: the cell.
        config_path: its file, passed on (None: the programs' default).
        scenario: the tracker's scenario (None: the cell's default).
        http_port: the gateway's REST port.
        endpoint: the gateway's Zenoh endpoint; the emulators connect to it.
        security_args: given to every program (``--pki-dir DIR`` or ``--insecure-plain-tcp``).
        record_dir: if given, the gateway records itself to ``gateway.mcap`` there and ``hrc-record`` records
            every topic of the cell to ``cell.mcap`` (docs/operations.md, "Recording and replay").
    """
    common = [*(["--config", config_path] if config_path else []), *security_args]
    gateway_record = ["--record", str(record_dir / "gateway.mcap")] if record_dir else []
    recorder = {}
    if record_dir is not None:
        events_url = f"http://{config.gateway.http_host}:{http_port}"
        output = str(record_dir / "cell.mcap")
        recorder["recorder"] = _module_command(
            "hrc_tools.record", *common, "--output", output, "--zenoh-connect", endpoint, "--events-url", events_url
        )
    return {
        "gateway": _module_command(
            "gateway", *common, "--zenoh-listen", endpoint, "--http-port", str(http_port), *gateway_record
        ),
        **{
            f"controller-{robot}": _module_command(
                "controller_emu", *common, "--robot", robot, "--zenoh-connect", endpoint, *vendor_face_args(r)
            )
            for robot, r in config.robots.items()
        },
        **{
            f"bridge-{robot}": _module_command(
                "controller_bridge", *common, "--robot", robot, "--zenoh-connect", endpoint
            )
            for robot in bridged_robots(config)
        },
        "tracker": _module_command(
            "tracker_emu", *common, *(["--scenario", scenario] if scenario else []), "--zenoh-connect", endpoint
        ),
        **recorder,
    }


def _security(config: CellConfig, pki_dir: Path, zenoh_port: int, insecure: bool) -> tuple[str, list[str]]:
    """The gateway's endpoint and the programs' security options; sets up the PKI on first start.

    Raises:
        ConfigError: (PkiError) the PKI folder cannot provide the programs' identities.
    """
    if insecure:
        print(
            "hrc-cell: WARNING: --insecure-plain-tcp: plain TCP on loopback, no authentication, no encryption, no "
            "access control: any process on this machine can command the robot. Development only.",
            file=sys.stderr,
            flush=True,
        )
        return f"tcp/127.0.0.1:{zenoh_port}", ["--insecure-plain-tcp"]
    pki = CellPki(pki_dir)
    created = pki.ensure_ca()
    issued = provision_cell(pki, CellPolicy.from_config(config))
    if created or issued:
        print(
            f"hrc-cell: {'created the cell CA and ' if created else ''}issued certificates for {', '.join(issued)} in "
            f"{pki_dir} (see docs/security.md)",
            flush=True,
        )
    return f"tls/127.0.0.1:{zenoh_port}", ["--pki-dir", str(pki_dir)]


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="hrc-cell", description="Run gateway + controller and tracker emulators")
    parser.add_argument("--config", default=None, metavar="PATH", help="cell configuration (default configs/cell.toml)")
    parser.add_argument("--scenario", default=None, help="tracker scenario (default: the cell's default_scenario)")
    parser.add_argument("--http-port", type=int, default=None, help="REST port (default: gateway.http_port)")
    parser.add_argument("--zenoh-port", type=int, default=7447, help="loopback port of the gateway's Zenoh listener")
    parser.add_argument(
        "--pki-dir", default=None, metavar="DIR", help="the cell's CA and certificates (default $HRC_STATE_DIR/pki)"
    )
    parser.add_argument(
        "--insecure-plain-tcp",
        action="store_true",
        help="DEVELOPMENT ONLY: plain TCP on loopback, without authentication, encryption or access control",
    )
    parser.add_argument(
        "--record",
        type=Path,
        default=None,
        metavar="DIR",
        help="record the run: DIR/gateway.mcap (the gateway's inputs and decisions, for hrc-replay) and "
        "DIR/cell.mcap (every topic, with 3D capsules for Foxglove)",
    )
    args = parser.parse_args(argv)
    if args.record is not None:
        args.record.mkdir(parents=True, exist_ok=True)
    try:
        config = load_cell_config(args.config)
        pki_dir = Path(args.pki_dir) if args.pki_dir else default_pki_dir()
        endpoint, security_args = _security(config, pki_dir, args.zenoh_port, args.insecure_plain_tcp)
    except ConfigError as exc:
        print(f"hrc-cell: invalid configuration: {' '.join(str(exc).split())}", file=sys.stderr)
        sys.exit(2)
    http_port = args.http_port if args.http_port is not None else config.gateway.http_port
    try:
        commands = program_commands(config, args.config, args.scenario, http_port, endpoint, security_args, args.record)
    except ConfigError as exc:
        print(f"hrc-cell: invalid configuration: {' '.join(str(exc).split())}", file=sys.stderr)
        sys.exit(2)
    with stop_on_signals() as stop:
        bridge_env = bridge_environment(config)
        procs = {
            name: subprocess.Popen(cmd, start_new_session=True, env=bridge_env if name.startswith("bridge-") else None)
            for name, cmd in commands.items()
        }
        url = f"http://{config.gateway.http_host}:{http_port}/api/v1/status"
        print(f"hrc-cell: cell {config.cell!r} running ({', '.join(procs)}) on {endpoint}; status: {url}", flush=True)
        page = f"http://{config.gateway.http_host}:{http_port}/"
        print(f"hrc-cell: operator page: {page}; Ctrl-C stops everything", flush=True)
        failed = None
        while not stop.wait(0.2):
            failed = next((name for name, p in procs.items() if p.poll() is not None), None)
            if failed:
                print(f"hrc-cell: {failed} exited with code {procs[failed].returncode}; stopping", file=sys.stderr)
                break
        for proc in procs.values():
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 10.0
        for name, proc in procs.items():
            try:
                proc.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                print(f"hrc-cell: {name} did not stop in time; killing it", file=sys.stderr)
                proc.kill()
                proc.wait()
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    cli()
