"""Command-line arguments every program shares (Zenoh endpoints, security (PKI, plain TCP), the cell file) and the
one body of the long-running programs' command lines (:func:`run_program`)."""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Callable
from typing import NoReturn

from hrc_contract.config import ConfigError
from hrc_runtime.logs import configure_logging
from hrc_runtime.memory import configure_heap
from hrc_runtime.signals import StopEvent, stop_on_signals


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """``--zenoh-listen``, ``--zenoh-connect``, ``--zenoh-mode``, and :func:`add_security_arguments`."""
    parser.add_argument(
        "--zenoh-listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tls/127.0.0.1:7447 (repeatable)",
    )
    parser.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to connect to (repeatable)",
    )
    parser.add_argument(
        "--zenoh-mode",
        choices=["peer", "client"],
        default="peer",
        help="peer (default: programs meet directly) or client (through an hrc-router, e.g. across hosts)",
    )
    add_security_arguments(parser)


def add_security_arguments(parser: argparse.ArgumentParser) -> None:
    """``--pki-dir``, ``--tls-identity`` and ``--insecure-plain-tcp`` (read by ``zenoh_session.options_from_args``)."""
    parser.add_argument(
        "--pki-dir",
        default=None,
        metavar="DIR",
        help="the cell's CA and certificates (default $HRC_STATE_DIR/pki, else .state/pki of this project)",
    )
    parser.add_argument(
        "--tls-identity",
        default=None,
        metavar="CN",
        help="certificate to use, by common name (default: the program's own, e.g. gateway, controller-<robot>)",
    )
    parser.add_argument(
        "--insecure-plain-tcp",
        action="store_true",
        help="DEVELOPMENT ONLY (also HRC_INSECURE_PLAIN_TCP=1): allow tcp/ endpoints on loopback, without "
        "authentication, encryption or access control (anyone on this machine can command the robot); refused on "
        "any other address",
    )


def add_config_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config",
        default=None,
        metavar="PATH",
        help="cell configuration (TOML); default: configs/cell.toml of this project",
    )
    parser.add_argument("--log-level", default="INFO", choices=["DEBUG", "INFO", "WARNING", "ERROR"])


def run_program(prog: str, log_level: str, body: Callable[[StopEvent], int], *, log: logging.Logger) -> NoReturn:
    """The body every long-running program's command line shares: logging at ``log_level``, the C heap's arenas and
    report (:func:`hrc_runtime.memory.configure_heap`, before the program's threads), SIGINT/SIGTERM to a stop
    event, then ``body(stop)``; its return value is the exit code. An invalid configuration (:class:`ConfigError`
    from the body, before or while it runs) is one line ``PROG: invalid configuration: reason`` and exit code 2."""
    configure_logging(log_level)
    configure_heap(log)
    with stop_on_signals() as stop:
        try:
            code = body(stop)
        except ConfigError as exc:
            sys.stderr.write(f"{prog}: invalid configuration: {' '.join(str(exc).split())}\n")
            code = 2
    sys.exit(code)
