"""The latency cost of mutual TLS and access control: one put → a subscriber in another process, on loopback.

For each security (plain TCP; mutual TLS; mutual TLS + the cell's access control on both sessions) a
subscriber process listens and records ``receive time − stamp`` of each sample; this process connects as the
gateway and puts stamped samples on a robot's override key at ``--rate-hz`` (declared publisher, express),
discarding the first ``--warmup`` samples. Prints p50, p99 and max per security, and the differences to plain.

    .venv/bin/python -m bench.tls_cost [--samples 3000] [--rate-hz 500] [--rounds 2]
"""

from __future__ import annotations

import argparse
import json
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from bench._progress import Progress
from hrc_runtime.access_control import CellPolicy
from hrc_runtime.pki import CellPki
from hrc_runtime.signals import stop_on_signals
from hrc_runtime.zenoh_session import PLAIN_TCP_LOOPBACK, SessionOptions, mutual_tls, session_config

KEY = "hrc/demo/robot/ur5/override"
POLICY = CellPolicy("demo", ("ur5",), ("front",))
SECURITIES = ("plain", "tls", "tls+acl")


def _options(security: str, pki_dir: Path, cn: str) -> SessionOptions:
    if security == "plain":
        return PLAIN_TCP_LOOPBACK
    return SessionOptions("peer", mutual_tls(pki_dir, cn, POLICY if security == "tls+acl" else None))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def subscriber(endpoint: str, security: str, pki_dir: Path, out: Path) -> None:
    """Record one-way latencies [ns] until the ``done`` sample (or SIGINT); write them to ``out``."""
    latencies: list[int] = []
    with stop_on_signals() as stop:

        def on_sample(sample: zenoh.Sample) -> None:
            received_ns = time.time_ns()
            ping = json.loads(sample.payload.to_bytes())
            if ping.get("done"):
                stop.set()
            else:
                latencies.append(received_ns - int(ping["stamp_ns"]))

        options = _options(security, pki_dir, "controller-ur5")
        with zenoh.open(session_config([endpoint], [], options)) as session:
            session.declare_subscriber(KEY, on_sample)
            stop.wait()
    out.write_text(json.dumps(latencies))


def measure(security: str, pki_dir: Path, work: Path, samples: int, warmup: int, rate_hz: float) -> np.ndarray:
    """One-way latencies [µs] of ``samples`` puts after ``warmup``, with this security."""
    protocol = "tcp" if security == "plain" else "tls"
    endpoint = f"{protocol}/127.0.0.1:{_free_port()}"
    out = work / f"{security}.json"
    command = [sys.executable, "-m", "bench.tls_cost", "--subscriber", endpoint, security, str(pki_dir), str(out)]
    proc = subprocess.Popen(command)
    try:
        options = _options(security, pki_dir, "gateway")
        with zenoh.open(session_config([], [endpoint], options)) as session:
            publisher = session.declare_publisher(KEY, express=True)
            deadline = time.monotonic() + 10.0
            while not publisher.matching_status.matching:  # type: ignore[attr-defined]  # zenoh stub: an object
                if time.monotonic() > deadline:
                    raise RuntimeError(f"{security}: the subscriber process did not appear")
                time.sleep(0.01)
            period_s = 1.0 / rate_hz
            next_s = time.monotonic()
            for seq in range(warmup + samples):
                publisher.put(json.dumps({"seq": seq, "stamp_ns": time.time_ns()}).encode())
                next_s += period_s
                threading.Event().wait(max(0.0, next_s - time.monotonic()))
            publisher.put(json.dumps({"done": True}).encode())  # after every sample: same publisher, in order
            proc.wait(10.0)
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            proc.wait(10.0)
    latencies = json.loads(out.read_text())
    return np.asarray(latencies[warmup:], dtype=float) / 1e3


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.tls_cost", description=__doc__.split("\n\n")[0])
    parser.add_argument("--samples", type=int, default=3000)
    parser.add_argument("--warmup", type=int, default=300)
    parser.add_argument("--rate-hz", type=float, default=500.0)
    parser.add_argument("--rounds", type=int, default=2, help="each security this many times, interleaved")
    parser.add_argument(
        "--subscriber", nargs=4, metavar=("ENDPOINT", "SECURITY", "PKI_DIR", "OUT"), help=argparse.SUPPRESS
    )
    args = parser.parse_args(argv)
    if args.subscriber:
        endpoint, security, pki_dir, out = args.subscriber
        subscriber(endpoint, security, Path(pki_dir), Path(out))
        return 0
    with tempfile.TemporaryDirectory(prefix="hrc-tls-cost-") as tmp:
        work = Path(tmp)
        pki_dir = work / "pki"
        for cn in ("gateway", "controller-ur5"):
            CellPki(pki_dir).identity(cn)
        results: dict[str, list[np.ndarray]] = {s: [] for s in SECURITIES}
        with Progress("tls_cost", args.rounds * len(SECURITIES), "measurements") as progress:
            for k in range(args.rounds):
                for security in SECURITIES:
                    progress.update(progress.done, f"round {k + 1}/{args.rounds}: {security}")
                    results[security].append(measure(security, pki_dir, work, args.samples, args.warmup, args.rate_hz))
                    progress.advance(note=f"round {k + 1}/{args.rounds}: {security} done")
    print(f"one-way put → subscriber, loopback: {args.samples} samples × {args.rounds} rounds at {args.rate_hz:g} Hz")
    p50_plain = p99_plain = 0.0
    for security in SECURITIES:
        lat = np.concatenate(results[security])
        p50, p99, worst = np.percentile(lat, 50), np.percentile(lat, 99), lat.max()
        if security == "plain":
            p50_plain, p99_plain = p50, p99
        print(
            f"  {security:8} n={lat.size:5d}  p50 {p50:7.1f} µs  p99 {p99:7.1f} µs  max {worst:8.1f} µs"
            + (
                ""
                if security == "plain"
                else f"   (p50 {p50 - p50_plain:+.1f} µs, p99 {p99 - p99_plain:+.1f} µs vs plain)"
            )
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
