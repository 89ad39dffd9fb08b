"""Command-line arguments every program shares: Zenoh endpoints, security (PKI, plain TCP), the cell file."""

from __future__ import annotations

import argparse


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
