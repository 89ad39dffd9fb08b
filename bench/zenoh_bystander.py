"""A Zenoh bystander: a session that joins the cell like the auditor and does nothing else (no subscriber, no
publisher), so that the soak can tell what a program's memory grows by from what Zenoh's session itself grows by
while the peers around it restart (bench/soak.py samples it as ``zenoh-bystander``).

    python -m bench.zenoh_bystander --config CELL.toml --pki-dir PKI --zenoh-connect tls/127.0.0.1:PORT ...

Runs until SIGINT or SIGTERM; exit 2 on an invalid configuration.
"""

from __future__ import annotations

import argparse
import logging
import sys

import zenoh

from hrc_contract.config import ConfigError
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments
from hrc_runtime.config import load_cell_config
from hrc_runtime.logs import configure_logging
from hrc_runtime.memory import configure_heap
from hrc_runtime.signals import stop_on_signals
from hrc_runtime.zenoh_session import DEFAULT_ENDPOINT, options_from_args, session_config

PROG = "python -m bench.zenoh_bystander"
COMMON_NAME = "observer-audit"
"""The certificate it joins with: the auditor's (it reads nothing, so the read-only role is more than it needs)."""

log = logging.getLogger("zenoh-bystander")


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.split("\n\n")[0])
    add_config_argument(parser)
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    configure_heap(log)  # as every program of the cell does (hrc_runtime/memory.py)
    connect = args.zenoh_connect or ([] if args.zenoh_listen else [DEFAULT_ENDPOINT])
    with stop_on_signals() as stop:
        try:
            config = load_cell_config(args.config)
            options = options_from_args(args, COMMON_NAME, config)
        except ConfigError as exc:
            sys.stderr.write(f"{PROG}: invalid configuration: {' '.join(str(exc).split())}\n")
            sys.exit(2)
        with zenoh.open(session_config(args.zenoh_listen, connect, options)):
            log.info("joined cell %r (connect %s); idle until stopped", config.cell, ", ".join(connect))
            stop.wait()
    log.info("stopped")


if __name__ == "__main__":
    cli()
