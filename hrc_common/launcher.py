"""``hrc-cell``: run a whole cell (gateway, one controller emulator per robot, tracker emulator) on this machine.

Each program is its own process, as in production; they meet over Zenoh on loopback. Ctrl-C (or
SIGTERM) stops all of them cleanly; if one of them exits on its own, the others are stopped too.
"""

from __future__ import annotations

import argparse
import signal
import subprocess
import sys
import time

from hrc_common.config import ConfigError, load_cell_config
from hrc_common.service import stop_on_signals


def _module_command(module: str, *args: str) -> list[str]:
    return [sys.executable, "-m", module, *args]


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="hrc-cell", description="Run gateway + controller and tracker emulators")
    parser.add_argument("--config", default=None, metavar="PATH", help="cell configuration (default configs/cell.toml)")
    parser.add_argument("--scenario", default=None, help="tracker scenario (default: the cell's default_scenario)")
    parser.add_argument("--http-port", type=int, default=None, help="REST port (default: gateway.http_port)")
    parser.add_argument("--zenoh-port", type=int, default=7447, help="loopback port of the gateway's Zenoh listener")
    args = parser.parse_args(argv)
    try:
        config = load_cell_config(args.config)
    except ConfigError as exc:
        print(f"hrc-cell: invalid configuration: {exc}", file=sys.stderr)
        sys.exit(2)
    endpoint = f"tcp/127.0.0.1:{args.zenoh_port}"
    common = ["--config", args.config] if args.config else []
    http_port = args.http_port if args.http_port is not None else config.gateway.http_port
    commands = {
        "gateway": _module_command("gateway.main", *common, "--zenoh-listen", endpoint, "--http-port", str(http_port)),
        **{
            f"controller-{robot}": _module_command(
                "controller_emu.main", *common, "--robot", robot, "--zenoh-connect", endpoint
            )
            for robot in config.robots
        },
        "tracker": _module_command(
            "tracker_emu.main",
            *common,
            *(["--scenario", args.scenario] if args.scenario else []),
            "--zenoh-connect",
            endpoint,
        ),
    }
    with stop_on_signals() as stop:
        procs = {name: subprocess.Popen(cmd, start_new_session=True) for name, cmd in commands.items()}
        url = f"http://{config.gateway.http_host}:{http_port}/api/v1/status"
        print(f"hrc-cell: cell {config.cell!r} running ({', '.join(procs)}); status: {url}", flush=True)
        print("hrc-cell: Ctrl-C stops everything", flush=True)
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
