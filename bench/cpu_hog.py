"""Bursty CPU load beside a test or a benchmark: N processes, each busy for a random 5–60 ms, then asleep 0–60 ms.

    .venv/bin/python -m bench.cpu_hog --processes 3 --seconds 300 &
    .venv/bin/python -m pytest "tests/e2e/test_bridges.py::test_the_default_scenario_through_the_bridge[ur_rtde]"

What a shared 2-core machine does to the cell at its worst: threads descheduled for tens of milliseconds at random.
The bursts are seeded per process (``--seed``), the figures of a run beside it are not (the scheduler decides).
Stops after ``--seconds``, or on Ctrl-C / SIGTERM (its processes with it).
"""

from __future__ import annotations

import argparse
import multiprocessing
import random
import signal
import sys
import time

BUSY_S = (0.005, 0.060)
"""Each burst of work lasts a uniform random time in this range [s]."""

IDLE_S = (0.0, 0.060)
"""Each pause between bursts lasts a uniform random time in this range [s]."""


def burn(seconds: float, seed: int) -> None:
    """Alternate busy bursts and pauses for ``seconds``."""
    rng = random.Random(seed)
    end_s = time.monotonic() + seconds
    while time.monotonic() < end_s:
        busy_until_s = time.monotonic() + rng.uniform(*BUSY_S)
        while time.monotonic() < busy_until_s:
            pass
        time.sleep(rng.uniform(*IDLE_S))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.cpu_hog", description=__doc__.split("\n\n")[0])
    parser.add_argument("--processes", type=int, default=3, help="busy processes (default 3)")
    parser.add_argument("--seconds", type=float, default=300.0, help="how long (default 300 s)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the first process's bursts (default 0)")
    args = parser.parse_args(argv)
    if not 1 <= args.processes <= 64 or not 0.0 < args.seconds <= 86_400.0:
        parser.error(f"--processes {args.processes} (1..64), --seconds {args.seconds} (0..86400]")
    workers = [
        multiprocessing.Process(target=burn, args=(args.seconds, args.seed + i), daemon=True)
        for i in range(args.processes)
    ]
    for worker in workers:
        worker.start()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    print(f"cpu_hog: {args.processes} processes for {args.seconds:g} s", file=sys.stderr, flush=True)
    try:
        for worker in workers:
            worker.join()
    except KeyboardInterrupt:
        pass
    finally:
        for worker in workers:
            worker.terminate()
    return 0


if __name__ == "__main__":
    sys.exit(main())
