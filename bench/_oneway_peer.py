"""A Zenoh peer in its own process that records the one-way latency of stamped pings (the floor of bench.reaction).

Each ping is ``{"seq": k, "stamp_ns": t}`` with ``t`` from ``time.time_ns()`` just before ``put``; the
latency is the receive time minus ``t`` (same machine, same clock). On SIGINT or SIGTERM it writes
``{"seq": [...], "latency_ns": [...]}`` to ``--out`` and exits 0.

    python -m bench._oneway_peer --connect tcp/127.0.0.1:PORT --key bench/oneway/ping --out PATH
"""

from __future__ import annotations

import argparse
import json
import threading
import time
from pathlib import Path

import zenoh

from hrc_runtime.signals import stop_on_signals
from hrc_runtime.zenoh_session import session_config


def record(connect: list[str], key: str, stop: threading.Event) -> tuple[list[int], list[int]]:
    """Receive pings until ``stop`` is set; returns their seq and one-way latency [ns]."""
    seqs: list[int] = []
    latencies: list[int] = []

    def on_sample(sample: zenoh.Sample) -> None:
        received_ns = time.time_ns()
        ping = json.loads(sample.payload.to_bytes())
        seqs.append(int(ping["seq"]))
        latencies.append(received_ns - int(ping["stamp_ns"]))

    with zenoh.open(session_config(connect=connect)) as session:
        subscriber = session.declare_subscriber(key, on_sample)
        stop.wait()
        del subscriber
    return seqs, latencies


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench._oneway_peer", description=__doc__.split("\n\n")[0])
    parser.add_argument("--connect", action="append", required=True, metavar="ENDPOINT")
    parser.add_argument("--key", required=True)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    with stop_on_signals() as stop:
        seqs, latencies = record(args.connect, args.key, stop)
    args.out.write_text(json.dumps({"seq": seqs, "latency_ns": latencies}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
