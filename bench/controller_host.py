"""Several emulated controllers in one process, for benchmarks of cells with many robots.

Each robot runs the controller emulator's own loop (:func:`controller_emu.main.main`: its ``ControllerNode``, rate
loop, Zenoh session and keys) in a thread of this process, so that N robots cost one Python process instead of N
on a machine with few cores. A controller that fails stops all of them.

    python -m bench.controller_host --config CELL --robots ur5_1,panda_1 --zenoh-connect tcp/127.0.0.1:7447
"""

from __future__ import annotations

import argparse
import sys
import threading

from controller_emu import main as controller
from hrc_contract.config import CellConfig, ConfigError
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments
from hrc_runtime.config import load_cell_config
from hrc_runtime.logs import configure_logging
from hrc_runtime.signals import stop_on_signals
from hrc_runtime.zenoh_session import options_from_args

PROG = "bench.controller_host"


def _run(config: CellConfig, robot: str, args: argparse.Namespace, stop: threading.Event, failed: list[str]) -> None:
    """One controller until ``stop``; on an error, record it and stop the others."""
    try:
        options = options_from_args(args, f"controller-{robot}", config)
        controller.main(config, robot, args.zenoh_listen, args.zenoh_connect, stop, zenoh_options=options)
    except Exception as exc:  # any failure of one controller ends the host: the gateway sees its robots go stale
        failed.append(f"{robot}: {' '.join(str(exc).split())}")
        stop.set()


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    add_config_argument(parser)
    parser.add_argument("--robots", required=True, metavar="A,B", help="robots of the cell to emulate, comma-separated")
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    try:
        config = load_cell_config(args.config)
    except ConfigError as exc:
        sys.stderr.write(f"{PROG}: invalid configuration: {' '.join(str(exc).split())}\n")
        sys.exit(2)
    robots = [r.strip() for r in args.robots.split(",") if r.strip()]
    unknown = sorted(set(robots) - set(config.robots))
    if not robots or unknown:
        sys.stderr.write(f"{PROG}: unknown robots {unknown}; allowed: {', '.join(config.robots)}\n")
        sys.exit(2)
    failed: list[str] = []
    with stop_on_signals() as stop:
        threads = [
            threading.Thread(target=_run, args=(config, r, args, stop, failed), name=f"controller-{r}") for r in robots
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
    if failed:
        sys.stderr.write(f"{PROG}: {'; '.join(failed)}\n")
        sys.exit(2)
    sys.exit(0)


if __name__ == "__main__":
    cli()
