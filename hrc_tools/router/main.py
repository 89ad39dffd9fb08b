"""``hrc-router``: a Zenoh router for a cell spread over several hosts, with the cell's TLS and access control.

Programs on other hosts run in client mode (``--zenoh-mode client --zenoh-connect tls/<router>:7447``) and
meet through this router. It authenticates every link with mutual TLS (certificate CN ``router``, from the
cell CA; issued on first start when the CA key is in the PKI folder, naming the hosts it listens on), and
enforces the cell's access control on everything it receives, so that a client can only put what its own
certificate allows; what the router forwards is then accepted by the programs from the ``router`` CN.

    hrc-router --listen tls/10.0.0.1:7447 [--listen tls/127.0.0.1:7447] [--config PATH] [--pki-dir DIR]

Exits 0 on SIGINT or SIGTERM, 2 with a one-line reason on an invalid configuration.
"""

from __future__ import annotations

import argparse
import logging
import threading

import zenoh

from hrc_contract.config import ConfigError
from hrc_runtime.access_control import CellPolicy
from hrc_runtime.cli import add_config_argument, add_security_arguments, run_program
from hrc_runtime.config import load_cell_config
from hrc_runtime.signals import StopEvent
from hrc_runtime.zenoh_session import DEFAULT_ENDPOINT, SessionOptions, options_from_args, session_config

PROG = "hrc-router"
COMMON_NAME = "router"

log = logging.getLogger(PROG)


def run_router(listen: list[str], connect: list[str], options: SessionOptions, stop: threading.Event) -> None:
    """Route until ``stop`` is set.

    Raises:
        ConfigError: the session cannot be opened (e.g. the port is in use, an endpoint is malformed).
    """
    try:
        session = zenoh.open(session_config(listen, connect, options))
    except zenoh.ZError as exc:
        reason = str(exc).split(" at /", 1)[0]
        raise ConfigError(f"cannot open the router (listen {listen}, connect {connect}): {reason}") from None
    with session:
        log.info(
            "routing on %s (%s)",
            ", ".join(listen) or "-",
            "INSECURE plain TCP"
            if options.tls is None
            else f"mutual TLS as {options.tls.identity.common_name!r}, access control of cell "
            f"{options.tls.policy.cell if isinstance(options.tls.policy, CellPolicy) else '-'}",
        )
        stop.wait()
    log.info("stopped")


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog=PROG, description="Zenoh router of a cell across hosts (mutual TLS + ACL)")
    add_config_argument(parser)
    parser.add_argument(
        "--listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help=f"endpoint to listen on, e.g. tls/10.0.0.1:7447 (repeatable; default {DEFAULT_ENDPOINT})",
    )
    parser.add_argument(
        "--connect", action="append", default=[], metavar="ENDPOINT", help="another router to connect to"
    )
    add_security_arguments(parser)
    parser.set_defaults(zenoh_mode="router")
    args = parser.parse_args(argv)
    listen = args.listen or ([] if args.connect else [DEFAULT_ENDPOINT])

    def body(stop: StopEvent) -> int:
        config = load_cell_config(args.config)
        options = options_from_args(args, COMMON_NAME, config, [*listen, *args.connect], listen)
        run_router(listen, args.connect, options, stop)
        return 0

    run_program(PROG, args.log_level, body, log=log)


if __name__ == "__main__":
    cli()
