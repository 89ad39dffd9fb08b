"""Helpers of the security tests: a listening check, a joint-state watch, and an intruder (the programs are
started by ``hrc_tools.cell.procs``).

The intruder is also a program, run in another network namespace by ``test_security_netns.py``::

    python tests/securecell.py --connect tls/10.0.0.1:7447 --ca ca.crt [--cert C --key K] --out report.json

It connects as a client (so that a peer that routes would pass its puts on), reads the gateway status (proof
that it is on the bus), then puts ``δ = 1`` overrides with fresh stamps on the robot's override key. The report
says whether it connected, how many status documents it read and how many overrides it put.
"""

from __future__ import annotations

import argparse
import json
import socket
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from hrc_contract import keys
from hrc_contract.messages import JointState, Override, parse_message, to_payload

FORGED_SEQ_START = 10**9
"""Far above any seq the gateway reaches in a test, so that a controller checking seq would take it."""


# -- listeners --------------------------------------------------------------------------------------


def listening(endpoint: str) -> bool:
    """Whether something accepts TCP connections at the loopback endpoint (``tls/127.0.0.1:PORT``)."""
    port = int(endpoint.rsplit(":", 1)[1])
    with socket.socket() as s:
        return s.connect_ex(("127.0.0.1", port)) == 0


# -- what the controller does -----------------------------------------------------------------------


@dataclass(frozen=True)
class StateSample:
    """One joint state as received: when [monotonic s], applied override δ, mode."""

    received_s: float
    override: float
    mode: str


class StateWatch:
    """Every joint state of a robot received by a session, as :class:`StateSample`."""

    def __init__(self, session: zenoh.Session, cell: str, robot: str) -> None:
        self._lock = threading.Lock()
        self._samples: list[StateSample] = []
        self._subscriber = session.declare_subscriber(keys.robot_state(cell, robot), self._on_sample)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        state = parse_message(sample.payload.to_bytes(), JointState)
        with self._lock:
            self._samples.append(StateSample(time.monotonic(), state.override, state.mode))

    def since(self, start_s: float) -> list[StateSample]:
        with self._lock:
            return [s for s in self._samples if s.received_s >= start_s]

    def latest(self) -> StateSample | None:
        with self._lock:
            return self._samples[-1] if self._samples else None


# -- the intruder -----------------------------------------------------------------------------------


def intruder_config(
    connect: list[str], ca_certificate: Path | None, certificate: Path | None = None, private_key: Path | None = None
) -> zenoh.Config:
    """A client configuration: TLS trusting ``ca_certificate`` (None: plain TCP), presenting a certificate if given.

    No access control: an intruder runs what it likes. Trusting the cell CA (whose certificate is public)
    lets it check the server; only a certificate signed by the cell CA gets it past mutual TLS.
    """
    conf: dict[str, Any] = {
        "mode": "client",
        "connect": {"endpoints": connect},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
    }
    if ca_certificate is not None:
        tls: dict[str, Any] = {"root_ca_certificate": str(ca_certificate), "enable_mtls": certificate is not None}
        if certificate is not None and private_key is not None:
            tls.update(connect_certificate=str(certificate), connect_private_key=str(private_key))
        conf["transport"] = {"link": {"tls": tls}}
    return zenoh.Config.from_json5(json.dumps(conf))


def forge_overrides(
    session: zenoh.Session, cell: str, robot: str, duration_s: float, rate_hz: float = 250.0
) -> tuple[int, int]:
    """Put ``δ = 1`` overrides for ``duration_s`` at ``rate_hz`` while reading the gateway status.

    Returns:
        Overrides put, status documents read meanwhile.
    """
    statuses = 0
    lock = threading.Lock()

    def on_status(_sample: zenoh.Sample) -> None:
        nonlocal statuses
        with lock:
            statuses += 1

    subscriber = session.declare_subscriber(keys.gateway_status(cell), on_status)
    publisher = session.declare_publisher(keys.robot_override(cell, robot), express=True)
    puts = 0
    end_s = time.monotonic() + duration_s
    while time.monotonic() < end_s:
        message = Override(robot=robot, seq=FORGED_SEQ_START + puts, stamp_ns=time.time_ns(), delta=1.0)
        publisher.put(to_payload(message))
        puts += 1
        time.sleep(1.0 / rate_hz)  # pacing the forger, not synchronisation
    subscriber.undeclare()  # type: ignore[no-untyped-call]  # zenoh stub
    with lock:
        return puts, statuses


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description="intruder: tries to command a robot (see module docstring)")
    parser.add_argument("--connect", action="append", required=True)
    parser.add_argument("--ca", type=Path, default=None, help="CA to trust (none: plain TCP)")
    parser.add_argument("--cert", type=Path, default=None)
    parser.add_argument("--key", type=Path, default=None)
    parser.add_argument("--cell", default="demo")
    parser.add_argument("--robot", default="ur5")
    parser.add_argument("--duration-s", type=float, default=2.0)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    report: dict[str, Any] = {"connected": False, "puts": 0, "statuses": 0, "error": None}
    try:
        session = zenoh.open(intruder_config(args.connect, args.ca, args.cert, args.key))
    except zenoh.ZError as exc:
        report["error"] = str(exc).split(" at /", 1)[0]
    else:
        with session:
            report["connected"] = True
            report["puts"], report["statuses"] = forge_overrides(session, args.cell, args.robot, args.duration_s)
    args.out.write_text(json.dumps(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
