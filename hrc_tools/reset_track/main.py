"""``hrc-reset-track``: an operator releases a lost person after checking the area (docs/contract.md "Tracks").

Puts one ``hrc.track_reset/1`` on ``hrc/<cell>/operator/track_reset`` with the ``operator`` certificate (the only
identity that may), waits until the gateway's status shows the track released (or no longer lost), and says so.

    hrc-reset-track --track front/h1 --operator alice --zenoh-connect tls/127.0.0.1:7447
"""

from __future__ import annotations

import argparse
import sys
import threading
import time

import zenoh

from hrc_contract import keys
from hrc_contract.config import ConfigError
from hrc_contract.errors import HrcError
from hrc_contract.messages import TrackReset, to_payload
from hrc_contract.status_models import GatewayStatus
from hrc_runtime.access_control import OPERATOR
from hrc_runtime.cli import add_config_argument, add_zenoh_arguments
from hrc_runtime.config import load_cell_config
from hrc_runtime.logs import configure_logging
from hrc_runtime.zenoh_session import options_from_args, session_config

CONFIRM_TIMEOUT_S = 5.0
"""How long to wait for the gateway's status to show the reset [s]."""


def still_lost(status: GatewayStatus, track: str) -> list[str]:
    """The lost tracks the reset of ``track`` (``*``: all) concerns in a status document."""
    return [t.label for t in status.tracks if t.state == "lost" and track in ("*", t.label)]


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog="hrc-reset-track", description="Release a lost person after checking the area (operator station)."
    )
    add_config_argument(parser)
    parser.add_argument("--track", required=True, help="label of a lost track as the status lists it, or '*' for all")
    parser.add_argument("--operator", required=True, help="who checked the area (logged with the reset)")
    add_zenoh_arguments(parser)
    args = parser.parse_args(argv)
    configure_logging(args.log_level)
    try:
        config = load_cell_config(args.config)
        message = TrackReset(operator=args.operator, seq=0, stamp_ns=time.time_ns(), track=args.track)
        options = options_from_args(args, OPERATOR, config)
    except (ConfigError, HrcError, ValueError) as exc:
        print(f"hrc-reset-track: {exc}", file=sys.stderr)
        sys.exit(2)
    released = threading.Event()

    def on_status(sample: zenoh.Sample) -> None:
        try:
            status = GatewayStatus.model_validate_json(sample.payload.to_bytes())
        except ValueError:
            return
        if not still_lost(status, args.track):
            released.set()

    with zenoh.open(session_config(args.zenoh_listen, args.zenoh_connect, options)) as session:
        subscriber = session.declare_subscriber(keys.gateway_status(config.cell), on_status)
        publisher = session.declare_publisher(keys.operator_track_reset(config.cell))
        deadline = time.monotonic() + CONFIRM_TIMEOUT_S
        while not released.is_set() and time.monotonic() < deadline:
            publisher.put(to_payload(message.model_copy(update={"stamp_ns": time.time_ns()})))
            released.wait(0.5)
        del subscriber
    if released.is_set():
        print(f"hrc-reset-track: {args.track} is no longer lost (reset by {args.operator})")
        sys.exit(0)
    print(f"hrc-reset-track: the gateway's status still lists {args.track} as lost after {CONFIRM_TIMEOUT_S} s")
    sys.exit(1)


if __name__ == "__main__":
    cli()
