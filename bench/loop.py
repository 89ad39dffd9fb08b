"""Sustained loop: the real gateway at 500 Hz and 250 Hz, with and without HTTP load on its REST API.

Each run starts a whole cell on loopback (gateway with ``gateway.rate_hz`` changed in a temporary copy
of the cell, one controller emulator per robot, tracker emulator playing a looping scenario) and, for ``duration``
seconds, records:

- the period of the fixed-rate ticks: differences of the ``stamp_ns`` of consecutive ticks' overrides
  (the gateway takes it at the start of every cycle, and sends one override per robot per cycle),
  p50/p99/max. The gateway also decides when a tracker frame arrives (event cycles, between ticks);
  the status documents list their override seqs (``loop.event_seqs``), which tells ticks from event
  cycles. Pairs that cannot be told (a status lost) are left out and counted;
- the interval between consecutive decisions, ticks and event cycles alike (consecutive seqs; pairs
  with a seq this subscriber did not get are left out and counted);
- missed cycles: the growth of ``loop.missed_cycles`` in the gateway's status over the window, plus the
  tick periods longer than 1.5 nominal periods seen here; event cycles: the growth of
  ``loop.event_cycles``;
- ``loop.last_lateness_s`` and ``loop.compute_max_s`` from every status document.

With load, a generator in this process sends ``--http-rate`` requests/s (status, one robot, readyz,
config) to the gateway's REST API on 127.0.0.1, at most rate × duration requests, each with a 1 s timeout.

With ``--sse-clients N``, every (rate, HTTP rate) is run twice, without and with N clients of the status
stream (``GET /api/v1/stream``, server-sent events, served by the gateway's HTTP child) connected during the
whole window, each counting the documents it receives; the report compares the period with and without them.

    python -m bench.loop [--duration 60] [--rates 500,250] [--http-rates 0,200] [--sse-clients 10]
                         [--fixed-rate] [--json out/bench/loop.json]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import os
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

import httpx
import numpy as np
import zenoh

from bench._progress import Progress
from bench._report import Report, Target, default_json_path, print_header, summary, table, targets_table
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import session_config
from hrc_tools.cell.procs import (
    BenchError,
    Program,
    StartupError,
    exited_programs,
    free_port,
    log_tail,
    programs,
    wait_for,
    with_gateway_rate,
    with_retries,
    write_cell_config,
)

NAME = "loop"
TARGET_P99_PERIODS = 1.1
LATE_PERIODS = 1.5
HTTP_PATHS = ["/api/v1/status"] * 10 + ["/api/v1/robots/{robot}"] * 5 + ["/readyz"] * 3 + ["/api/v1/config"] * 2
"""The request mix of the load: half status, a quarter one robot, the rest readyz and config."""
STREAM_PATH = "/api/v1/stream"
TARGET_SSE_DOCS_PER_S = 20.0
"""Issue 11: the stream delivers at least this many documents/s to each of 10 clients ..."""
TARGET_SSE_P99_RATIO = 1.05
"""Issue 11: ... without raising the loop's period p99 by more than 5 %."""
SSE_READ_TIMEOUT_S = 5.0
"""An SSE client gives up when no byte arrives for this long (the gateway publishes at the status rate)."""


class Stamp(NamedTuple):
    seq: int
    stamp_ns: int


class LoopStatus(NamedTuple):
    received_s: float
    cycles: int | None
    missed_cycles: int | None
    last_lateness_s: float | None
    compute_max_s: float | None
    override_seq: int | None = None
    tick_cycles: int | None = None
    event_cycles: int | None = None
    event_seqs: tuple[int, ...] = ()


@dataclass
class Recorder:
    """Zenoh callbacks of one robot's overrides and of the status; appends only while ``on`` is set."""

    robot: str = ""
    on: threading.Event = field(default_factory=threading.Event)
    overrides: list[Stamp] = field(default_factory=list)
    statuses: list[LoopStatus] = field(default_factory=list)
    any_status: threading.Event = field(default_factory=threading.Event)

    def on_override(self, sample: zenoh.Sample) -> None:
        if self.on.is_set():
            msg = json.loads(sample.payload.to_bytes())
            self.overrides.append(Stamp(int(msg["seq"]), int(msg["stamp_ns"])))

    def on_status(self, sample: zenoh.Sample) -> None:
        self.any_status.set()
        if self.on.is_set():
            doc = json.loads(sample.payload.to_bytes())
            loop = doc.get("loop", {})
            self.statuses.append(
                LoopStatus(
                    time.monotonic(),
                    loop.get("cycles"),
                    loop.get("missed_cycles"),
                    loop.get("last_lateness_s"),
                    loop.get("compute_max_s"),
                    doc.get("robots", {}).get(self.robot, {}).get("override_seq"),
                    loop.get("tick_cycles"),
                    loop.get("event_cycles"),
                    tuple(int(seq) for seq in loop.get("event_seqs", ())),
                )
            )


# -- HTTP load ---------------------------------------------------------------------------------------


class HttpLoad:
    """``rate`` GET requests/s spread over ``workers`` threads, each with its own keep-alive connection.

    Each worker keeps its own schedule; a worker that falls behind does not burst to catch up. At most
    ``rate × duration_s`` requests are sent, none after ``duration_s``. Each worker thread lowers its own CPU
    priority by ``nice`` (Linux: the niceness of a thread id), so the load generator, which in a cell runs on
    other machines, does not take the CPU from the programs under test on this one.
    """

    def __init__(
        self, base_url: str, robot: str, rate: float, duration_s: float, workers: int = 4, nice: int = 0
    ) -> None:
        self.base_url = base_url
        self.nice = nice
        self.paths = [p.format(robot=robot) for p in HTTP_PATHS]
        self.rate = rate
        self.duration_s = duration_s
        self.workers = workers
        self.latency_ns: list[int] = []
        self.codes: Counter[str] = Counter()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._started_s = 0.0
        self._ended_s = 0.0

    def start(self) -> None:
        self._started_s = time.monotonic()
        budget = int(self.rate * self.duration_s)
        for w in range(self.workers):
            count = budget // self.workers + (1 if w < budget % self.workers else 0)
            thread = threading.Thread(target=self._work, args=(w, count), name=f"http-load-{w}", daemon=True)
            thread.start()
            self._threads.append(thread)

    def _work(self, worker: int, count: int) -> None:
        if self.nice:
            tid = threading.get_native_id()
            os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + self.nice)
        interval_s = self.workers / self.rate
        next_s = self._started_s + worker * interval_s / self.workers
        deadline = self._started_s + self.duration_s
        paths = itertools.cycle(self.paths[worker:] + self.paths[:worker])
        with httpx.Client(base_url=self.base_url, timeout=1.0) as client:
            for _ in range(count):
                now = time.monotonic()
                next_s = max(next_s, now)
                if next_s >= deadline or self._stop.wait(next_s - now):
                    break
                started = time.perf_counter_ns()
                try:
                    code = str(client.get(next(paths)).status_code)
                except httpx.HTTPError as exc:
                    code = type(exc).__name__
                elapsed = time.perf_counter_ns() - started
                with self._lock:
                    self.codes[code] += 1
                    self.latency_ns.append(elapsed)
                next_s += interval_s

    def stop(self) -> dict[str, Any]:
        self._stop.set()
        for thread in self._threads:
            thread.join(5.0)
        self._ended_s = time.monotonic()
        sent = sum(self.codes.values())
        elapsed_s = max(1e-9, min(self._ended_s - self._started_s, self.duration_s))
        return {
            "target_rate_per_s": self.rate,
            "requests": sent,
            "achieved_rate_per_s": round(sent / elapsed_s, 1),
            "responses": dict(self.codes),
            "latency_ms": summary(self.latency_ns, 1e-6, 2),
        }


# -- SSE clients ------------------------------------------------------------------------------------


def stream_rate(received_s: Sequence[float], start_s: float, end_s: float) -> dict[str, Any]:
    """One client's documents in the window ``[start_s, end_s)`` [monotonic s]: how many, per second, and the
    fewest in any whole second of it (a stall shows there even when the mean looks fine)."""
    times = np.asarray(received_s, dtype=float)
    inside = times[(times >= start_s) & (times < end_s)]
    span_s = end_s - start_s
    whole_s = int(span_s)
    bins: list[int] = (
        np.histogram(inside, bins=whole_s, range=(start_s, start_s + whole_s))[0].tolist() if whole_s >= 1 else []
    )
    return {
        "documents": int(inside.size),
        "docs_per_s": round(inside.size / span_s, 2) if span_s > 0 else 0.0,
        "fewest_in_a_second": min(bins) if bins else None,
    }


def versions_skipped(ids: Sequence[int]) -> int:
    """Status versions a client never got between the first and last it got (the stream sends only the newest:
    a client that reads too slowly skips some)."""
    ordered = sorted(set(ids))
    return sum(b - a - 1 for a, b in itertools.pairwise(ordered))


class SseClients:
    """``count`` clients of the status stream, each in its own thread with its own connection, each recording
    when every ``status`` event arrived [monotonic s] and its id (the board's version).

    A context manager: the clients connect on entry and disconnect on exit. Like :class:`HttpLoad`, the
    threads lower their CPU priority by ``nice``: in a cell the clients are browsers on other machines.
    """

    def __init__(self, base_url: str, count: int, nice: int = 0) -> None:
        self.url = base_url + STREAM_PATH
        self.count = count
        self.nice = nice
        self.received_s: list[list[float]] = [[] for _ in range(count)]
        self.ids: list[list[int]] = [[] for _ in range(count)]
        self.errors: list[str | None] = [None] * count
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []

    def __enter__(self) -> SseClients:
        for k in range(self.count):
            thread = threading.Thread(target=self._read, args=(k,), name=f"sse-client-{k}", daemon=True)
            thread.start()
            self._threads.append(thread)
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._stop.set()
        for thread in self._threads:
            thread.join(SSE_READ_TIMEOUT_S + 1.0)

    def all_receiving(self) -> bool:
        """Every client has received a document."""
        return all(self.received_s)

    def _read(self, k: int) -> None:
        if self.nice:
            tid = threading.get_native_id()
            os.setpriority(os.PRIO_PROCESS, tid, os.getpriority(os.PRIO_PROCESS, tid) + self.nice)
        try:
            with httpx.Client(timeout=SSE_READ_TIMEOUT_S) as client, client.stream("GET", self.url) as response:
                response.raise_for_status()
                event, event_id, has_data = "", -1, False
                for line in response.iter_lines():
                    if self._stop.is_set():
                        return
                    if not line:  # the end of an event
                        if event == "status" and has_data:
                            self.received_s[k].append(time.monotonic())
                            self.ids[k].append(event_id)
                        event, event_id, has_data = "", -1, False
                    elif line.startswith("event:"):
                        event = line[6:].strip()
                    elif line.startswith("id:"):
                        event_id = int(line[3:].strip() or -1)
                    elif line.startswith("data:"):
                        has_data = True
            if not self._stop.is_set():
                self.errors[k] = "the stream ended"
        except (httpx.HTTPError, ValueError) as exc:
            if not self._stop.is_set():
                self.errors[k] = f"{type(exc).__name__}: {exc}"

    def results(self, start_s: float, end_s: float) -> dict[str, Any]:
        """Documents/s of each client over the window, the slowest client's, and what went wrong."""
        clients = []
        for received_s, ids, error in zip(self.received_s, self.ids, self.errors, strict=True):
            in_window = [i for t, i in zip(received_s, ids, strict=True) if start_s <= t < end_s]
            clients.append({**stream_rate(received_s, start_s, end_s), "versions_skipped": versions_skipped(in_window)})
            if error is not None:
                clients[-1]["error"] = error
        rates = [c["docs_per_s"] for c in clients]
        return {
            "clients": self.count,
            "min_docs_per_s": min(rates) if rates else None,
            "docs_per_s": summary(rates, 1.0, 2),
            "fewest_in_a_second": min(
                (c["fewest_in_a_second"] for c in clients if c["fewest_in_a_second"] is not None), default=None
            ),
            "versions_skipped": sum(c["versions_skipped"] for c in clients),
            "errors": [c["error"] for c in clients if "error" in c],
            "per_client": clients,
        }


# -- one run ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunSettings:
    rate_hz: float
    http_rate: float
    duration_s: float
    warmup_s: float
    scenario: str
    seed: int
    event_driven: bool = True
    load_nice: int = 0
    controllers_per_process: int = 1
    sse_clients: int = 0

    @property
    def label(self) -> str:
        """E.g. ``250 Hz, 200 req/s, 10 SSE clients`` (the SSE part only with clients)."""
        sse = f", {self.sse_clients} SSE clients" if self.sse_clients else ""
        return f"{self.rate_hz:g} Hz, {self.http_rate:g} req/s{sse}"


def periods(stamps: list[Stamp]) -> tuple[np.ndarray, int]:
    """Periods between consecutive overrides [ns] and the number of pairs skipped for a missing seq."""
    ordered = sorted(set(stamps))
    seq = np.array([s.seq for s in ordered], dtype=np.int64)
    stamp = np.array([s.stamp_ns for s in ordered], dtype=np.int64)
    if len(seq) < 2:
        return np.zeros(0, dtype=np.int64), 0
    consecutive = np.diff(seq) == 1
    return np.diff(stamp)[consecutive], int((~consecutive).sum())


def tick_periods(stamps: list[Stamp], statuses: list[LoopStatus]) -> tuple[np.ndarray, int]:
    """Periods between consecutive ticks [ns], and the number of tick pairs left out.

    A pair of received overrides ``(t1, t2)`` is a pair of consecutive ticks when both are known ticks and
    every seq between them is a known event cycle. Known: inside a window between two statuses whose
    ``event_seqs`` is complete (as long as the growth of ``event_cycles``; a status lost on the way makes
    the next one's list shorter, unless that window had no event cycle).
    """
    ordered = [s for s in statuses if s.override_seq is not None and s.event_cycles is not None]
    events: set[int] = set()
    windows: list[tuple[int, int]] = []
    for before, after in itertools.pairwise(ordered):
        events.update(after.event_seqs)
        grown = (after.event_cycles or 0) - (before.event_cycles or 0)
        if grown == len(after.event_seqs) and (after.override_seq or 0) > (before.override_seq or 0):
            windows.append((before.override_seq or 0, after.override_seq or 0))
    known_set = {seq for first, last in windows for seq in range(first + 1, last + 1)}
    stamp_of = {s.seq: s.stamp_ns for s in stamps}
    ticks = sorted(seq for seq in stamp_of if seq in known_set and seq not in events)
    out: list[int] = []
    skipped = 0
    for t1, t2 in itertools.pairwise(ticks):
        between = range(t1 + 1, t2)
        if all(seq in events and seq in known_set for seq in between):
            out.append(stamp_of[t2] - stamp_of[t1])
        else:
            skipped += 1
    return np.array(out, dtype=np.int64), skipped


def _controller_spec(robots: list[str], args: list[str], log: Path) -> tuple[str, list[str], Path]:
    """One controller emulator process for one robot, or a ``bench.controller_host`` for several."""
    if len(robots) == 1:
        return "controller_emu", [*args, "--robot", robots[0]], log
    return "bench.controller_host", [*args, "--robots", ",".join(robots)], log


def run_once(
    base: CellConfig, settings: RunSettings, work_dir: Path, on_progress: Callable[[float], None] | None = None
) -> dict[str, Any]:
    """Start the cell, measure ``settings.duration_s`` (``on_progress(seconds measured)`` every 0.1 s), analyse."""
    robots = list(base.robots)
    robot = robots[0]  # the robot whose overrides are recorded (the gateway sends one per robot per cycle)
    gw_port, http_port = free_port(), free_port()
    gw_ep = f"tcp/127.0.0.1:{gw_port}"
    tag = f"{settings.rate_hz:g}hz-{settings.http_rate:g}rps-{settings.sse_clients}sse"
    config = with_gateway_rate(base, settings.rate_hz, http_port, settings.event_driven)
    config_path = write_cell_config(config, work_dir / f"cell-{tag}.toml")
    n = settings.controllers_per_process
    groups = [robots[k : k + n] for k in range(0, len(robots), n)]
    controllers = {f"controller-{'-'.join(group)}": group for group in groups}
    logs = {name: work_dir / "logs" / f"{NAME}-{tag}-{name}.log" for name in ("gateway", *controllers, "tracker")}
    cfg = ["--config", str(config_path)]
    specs = [
        ("gateway", [*cfg, "--zenoh-listen", gw_ep], logs["gateway"]),
        *(_controller_spec(group, [*cfg, "--zenoh-connect", gw_ep], logs[name]) for name, group in controllers.items()),
        (
            "tracker_emu",
            [*cfg, "--scenario", settings.scenario, "--seed", str(settings.seed), "--zenoh-connect", gw_ep],
            logs["tracker"],
        ),
    ]
    recorder = Recorder(robot)
    base_url = f"http://127.0.0.1:{http_port}"
    spec_logs = [log for _, _, log in specs]
    http_result: dict[str, Any] | None = None
    sse_result: dict[str, Any] | None = None
    with programs(specs) as procs, zenoh.open(session_config(connect=[gw_ep])) as session:
        subscribers = [
            session.declare_subscriber(keys.robot_override(base.cell, robot), recorder.on_override),
            session.declare_subscriber(keys.gateway_status(base.cell), recorder.on_status),
        ]
        try:
            wait_for(recorder.any_status.is_set, 30.0, "the gateway's first status", procs)
            wait_for(lambda: _http_up(base_url), 30.0, "the gateway's REST API", procs)
        except StartupError as exc:
            raise StartupError(f"{exc}\n{exited_programs(procs, spec_logs) or log_tail(logs['gateway'])}") from None
        time.sleep(settings.warmup_s)
        with SseClients(base_url, settings.sse_clients, settings.load_nice) as sse:
            wait_for(sse.all_receiving, 10.0, "a first document on every SSE stream", procs)
            load = (
                HttpLoad(base_url, robot, settings.http_rate, settings.duration_s, nice=settings.load_nice)
                if settings.http_rate > 0
                else None
            )
            recorder.on.set()
            started_s = time.monotonic()
            if load is not None:
                load.start()
            try:
                _watch(settings.duration_s, started_s, procs, spec_logs, on_progress)
            finally:
                recorder.on.clear()
                ended_s = time.monotonic()
                if load is not None:
                    http_result = load.stop()
            if settings.sse_clients:
                sse_result = sse.results(started_s, ended_s)
        del subscribers
    return {**analyse(settings, recorder, http_result), "sse_clients": settings.sse_clients, "sse": sse_result}


def _watch(
    duration_s: float,
    started_s: float,
    procs: list[Program],
    logs: list[Path],
    on_progress: Callable[[float], None] | None,
) -> None:
    """Wait out the measured window, checking every 0.1 s that every program still runs.

    Raises:
        BenchError: a program exited during the window.
    """
    while (elapsed_s := time.monotonic() - started_s) < duration_s:
        if on_progress is not None:
            on_progress(elapsed_s)
        time.sleep(0.1)
        exited = exited_programs(procs, logs)
        if exited is not None:
            raise BenchError(f"a program exited during the run: {exited}")


def _http_up(base_url: str) -> bool:
    try:
        return httpx.get(base_url + "/healthz", timeout=0.5).status_code == 200
    except httpx.HTTPError:
        return False


def _growth(values: list[int | None]) -> int | None:
    known = [v for v in values if v is not None]
    return known[-1] - known[0] if len(known) >= 2 else None


def analyse(settings: RunSettings, recorder: Recorder, http: dict[str, Any] | None) -> dict[str, Any]:
    statuses = recorder.statuses
    period_ns, ticks_skipped = tick_periods(recorder.overrides, statuses)
    interval_ns, skipped = periods(recorder.overrides)
    nominal_ms = 1e3 / settings.rate_hz
    period = summary(period_ns, 1e-6, 3)
    return {
        "rate_hz": settings.rate_hz,
        "nominal_period_ms": nominal_ms,
        "http_rate_per_s": settings.http_rate,
        "duration_s": settings.duration_s,
        "period_ms": period,
        "p99_over_nominal": round(period["p99"] / nominal_ms, 3) if period_ns.size else None,
        "periods_over_1_5_nominal": int((period_ns > LATE_PERIODS * nominal_ms * 1e6).sum()),
        "tick_pairs_skipped_unknown": ticks_skipped,
        "decision_interval_ms": summary(interval_ns, 1e-6, 3),
        "pairs_skipped_missing_seq": skipped,
        "status_per_s": round(len(statuses) / settings.duration_s, 2),
        "cycles_in_window": _growth([s.cycles for s in statuses]),
        "tick_cycles_in_window": _growth([s.tick_cycles for s in statuses]),
        "event_cycles_in_window": _growth([s.event_cycles for s in statuses]),
        "missed_cycles_in_window": _growth([s.missed_cycles for s in statuses]),
        "lateness_ms": summary([s.last_lateness_s for s in statuses if s.last_lateness_s is not None], 1e3, 3),
        "compute_max_per_status_ms": summary(
            [s.compute_max_s for s in statuses if s.compute_max_s is not None], 1e3, 3
        ),
        "http": http,
    }


# -- the benchmark ----------------------------------------------------------------------------------


def matrix(
    rates: Sequence[float], http_rates: Sequence[float], sse_clients: int, common: RunSettings
) -> list[RunSettings]:
    """The runs: every rate × HTTP rate, and with ``sse_clients`` > 0 each of them without and with the clients
    (next to each other, so the pair sees the same machine as far as possible)."""
    sse_counts = [0, sse_clients] if sse_clients > 0 else [0]
    return [
        dataclasses.replace(common, rate_hz=rate, http_rate=http_rate, sse_clients=sse)
        for rate in rates
        for http_rate in http_rates
        for sse in sse_counts
    ]


def run_matrix(base: CellConfig, runs: list[RunSettings], work_dir: Path) -> list[dict[str, Any]]:
    """Each run in order (start-up retried), with a progress line over the measured seconds of all of them."""
    results = []
    total_s = sum(r.duration_s for r in runs)
    with Progress(NAME, total_s, "s measured") as progress:
        for k, settings in enumerate(runs):
            progress.message(f"... {settings.label}, {settings.duration_s:g} s")
            done_s = sum(r.duration_s for r in runs[:k])
            note = f"run {k + 1}/{len(runs)}: {settings.label}"
            progress.update(done_s, note)

            def measured(elapsed_s: float, done_s: float = done_s, note: str = note) -> None:
                progress.update(done_s + elapsed_s, note)

            results.append(with_retries(partial(run_once, base, settings, work_dir, measured), settings.label))
            progress.update(done_s + settings.duration_s)
    return results


def _same_point(a: dict[str, Any], b: dict[str, Any]) -> bool:
    return bool(a["rate_hz"] == b["rate_hz"] and a["http_rate_per_s"] == b["http_rate_per_s"])


def sse_targets(runs: list[dict[str, Any]]) -> list[Target]:
    """Issue 11's targets for each run with SSE clients: the slowest client's documents/s, and the period p99
    with the clients over the p99 of the run without them at the same rate and HTTP rate."""
    targets = []
    for with_sse in runs:
        sse = with_sse.get("sse")
        if not sse:
            continue
        point = f"{with_sse['rate_hz']:g} Hz, {with_sse['http_rate_per_s']:g} req/s"
        targets.append(
            Target(
                f"SSE documents/s to each of {sse['clients']} clients (slowest) at {point}",
                sse["min_docs_per_s"],
                TARGET_SSE_DOCS_PER_S,
                "docs/s",
                at_least=True,
            )
        )
        without = [r for r in runs if _same_point(r, with_sse) and not r.get("sse_clients")]
        if without and without[0]["period_ms"].get("n") and with_sse["period_ms"].get("n"):
            ratio = with_sse["period_ms"]["p99"] / without[0]["period_ms"]["p99"]
            targets.append(
                Target(
                    f"period p99 with {sse['clients']} SSE clients / without at {point}",
                    round(ratio, 3),
                    TARGET_SSE_P99_RATIO,
                    "×",
                )
            )
    return targets


def run(
    rates: list[float],
    http_rates: list[float],
    duration_s: float,
    warmup_s: float,
    scenario: str,
    seed: int,
    config_path: Path | None,
    work_dir: Path,
    event_driven: bool = True,
    load_nice: int = 0,
    controllers_per_process: int = 1,
    sse_clients: int = 0,
) -> Report:
    base = load_cell_config(config_path)
    report = Report(
        NAME,
        {
            "rates_hz": rates,
            "event_driven": event_driven,
            "http_rates_per_s": http_rates,
            "sse_clients": sse_clients,
            "status_rate_hz": base.gateway.status_rate_hz,
            "load_nice": load_nice,
            "controllers_per_process": controllers_per_process,
            "duration_s": duration_s,
            "warmup_s": warmup_s,
            "scenario": scenario,
            "seed": seed,
            "http_paths": sorted(set(HTTP_PATHS)),
            "config": str(config_path) if config_path else "configs/cell.toml",
        },
    )
    common = RunSettings(
        0.0, 0.0, duration_s, warmup_s, scenario, seed, event_driven, load_nice, controllers_per_process
    )
    runs = run_matrix(base, matrix(rates, http_rates, sse_clients, common), work_dir)
    report.results["runs"] = runs
    loaded = max(http_rates)
    for r in runs:
        if r["http_rate_per_s"] == loaded and r["period_ms"].get("n"):
            with_sse = f" and {r['sse_clients']} SSE clients" if r["sse_clients"] else ""
            report.targets.append(
                Target(
                    f"period p99 at {r['rate_hz']:g} Hz with {loaded:g} req/s{with_sse}",
                    r["period_ms"]["p99"],
                    round(TARGET_P99_PERIODS * r["nominal_period_ms"], 3),
                    "ms",
                )
            )
    report.targets += sse_targets(runs)
    report.notes = [
        "period = difference of the override stamp_ns of consecutive ticks, i.e. of the gateway's tick "
        "starts (time.time_ns in the gateway; the loop itself sleeps on the monotonic clock); event cycles "
        "(a decision when a tracker frame arrives) are told apart by the seqs the status lists "
        "(loop.event_seqs). decision_interval = the same over all decisions, ticks and event cycles.",
        "missed_cycles_in_window is the gateway's own count (RateLoop: boundaries skipped after an overrun; "
        "event cycles are never missed or late ticks); event_cycles_in_window counts the event cycles.",
        "The HTTP server is a child process of the gateway at niceness +10 (gateway.http.server); the load "
        "generator runs in this process, its threads at niceness +load_nice (in a cell the HTTP clients are "
        "other machines); all share the same 2 cores with the controller and tracker emulators.",
        "SSE clients (sse_clients > 0): each a thread of this process (niceness +load_nice, like the load) with "
        "its own connection to GET /api/v1/stream, connected and receiving before the window opens; docs_per_s = "
        "status events received in the window / window length; the stream sends the newest document at the "
        "status rate (status_rate_hz), so docs_per_s is at most that. fewest_in_a_second: the fewest in any "
        "whole second of the window; versions_skipped: status versions a client never got (it read too slowly).",
        "Figures on a shared 2-core machine are indicative: see load_average.",
    ]
    return report


def print_report(doc: dict[str, Any]) -> None:
    rows = []
    for r in doc["results"]["runs"]:
        p = r["period_ms"]
        http = r["http"] or {}
        sse = r.get("sse") or {}
        rows.append(
            [
                f"{r['rate_hz']:g} Hz",
                f"{r['http_rate_per_s']:g}",
                http.get("achieved_rate_per_s", "-"),
                r.get("sse_clients", 0),
                sse.get("min_docs_per_s", "-"),
                p.get("n"),
                p.get("p50"),
                p.get("p99"),
                p.get("max"),
                r["p99_over_nominal"],
                r["missed_cycles_in_window"],
                r["periods_over_1_5_nominal"],
                r["event_cycles_in_window"],
                r["decision_interval_ms"].get("p50"),
                r["compute_max_per_status_ms"].get("max"),
            ]
        )
    print(
        "\n"
        + table(
            [
                "gateway",
                "req/s",
                "achieved",
                "SSE",
                "docs/s min",
                "periods",
                "p50 [ms]",
                "p99 [ms]",
                "max [ms]",
                "p99/T",
                "missed",
                ">1.5T",
                "events",
                "decision p50 [ms]",
                "compute max [ms]",
            ],
            rows,
        )
    )
    for r in doc["results"]["runs"]:
        if r["http"]:
            h = r["http"]
            print(
                f"{r['rate_hz']:g} Hz with load: {h['requests']} requests, responses {h['responses']}, "
                f"latency p50 {h['latency_ms'].get('p50')} ms p99 {h['latency_ms'].get('p99')} ms"
            )
    for line in sse_lines(doc["results"]["runs"]):
        print(line)
    print("\n" + targets_table([Target.from_dict(t) for t in doc["targets"]]))
    load = doc["load_average"]
    print(f"\nload average start {load['start']} end {load['end']}")


def sse_lines(runs: list[dict[str, Any]]) -> list[str]:
    """For each run with SSE clients: what the clients got, and the period beside the run without them."""
    lines = []
    for r in runs:
        sse = r.get("sse")
        if not sse:
            continue
        point = f"{r['rate_hz']:g} Hz, {r['http_rate_per_s']:g} req/s"
        rates = sse["docs_per_s"]
        lines.append(
            f"{point} with {sse['clients']} SSE clients (status documents received over Zenoh: "
            f"{r.get('status_per_s')}/s): docs/s per client min {rates.get('min')} "
            f"mean {rates.get('mean')} max {rates.get('max')}; fewest in a second {sse['fewest_in_a_second']}; "
            f"versions skipped {sse['versions_skipped']}; errors {sse['errors'] or 'none'}"
        )
        without = [o for o in runs if _same_point(o, r) and not o.get("sse_clients")]
        if without:
            a, b = without[0]["period_ms"], r["period_ms"]
            lines.append(
                f"{point} period without → with SSE clients: p50 {a.get('p50')} → {b.get('p50')} ms, "
                f"p99 {a.get('p99')} → {b.get('p99')} ms"
            )
    return lines


class MatrixArguments(NamedTuple):
    """The run matrix and its common settings, from the command line (:func:`add_matrix_arguments`)."""

    rates_hz: list[float]
    http_rates: list[float]
    sse_clients: int
    duration_s: float
    warmup_s: float
    load_nice: int


def add_matrix_arguments(parser: argparse.ArgumentParser, rates: str = "500,250", warmup_s: float = 2.0) -> None:
    """The options of the run matrix, shared with ``bench.many_robots`` (read back by :func:`matrix_arguments`)."""
    parser.add_argument("--duration", type=float, default=60.0, help="measured seconds per run")
    parser.add_argument("--warmup", type=float, default=warmup_s, help="seconds after start-up before measuring")
    parser.add_argument("--rates", default=rates, help="gateway rates, comma-separated [Hz]")
    parser.add_argument("--http-rates", default="0,200", help="HTTP request rates, comma-separated [1/s]")
    parser.add_argument(
        "--sse-clients",
        type=int,
        default=0,
        help=f"clients of the status stream ({STREAM_PATH}); > 0: every run without and with them (default 0)",
    )
    parser.add_argument(
        "--load-nice",
        type=int,
        default=10,
        help="the HTTP load generator's and SSE clients' threads lower their CPU priority by this much "
        "(default 10; 0 = not)",
    )


def matrix_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> MatrixArguments:
    """The options of :func:`add_matrix_arguments`, checked (``parser.error`` on a bad value)."""
    try:
        rates = [float(x) for x in args.rates.split(",") if x.strip()]
        http_rates = [float(x) for x in args.http_rates.split(",") if x.strip()]
    except ValueError as exc:
        parser.error(f"--rates and --http-rates are comma-separated numbers: {exc}")
    if not rates or any(r <= 0 for r in rates):
        parser.error("--rates must list rates > 0")
    if not http_rates or any(r < 0 for r in http_rates):
        parser.error("--http-rates must list rates >= 0")
    if args.load_nice < 0:
        parser.error("--load-nice must be >= 0")
    if args.sse_clients < 0:
        parser.error("--sse-clients must be >= 0")
    if args.duration <= 0 or args.warmup < 0:
        parser.error("--duration must be > 0 and --warmup >= 0")
    return MatrixArguments(rates, http_rates, args.sse_clients, args.duration, args.warmup, args.load_nice)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.loop", description=__doc__.split("\n\n")[0])
    add_matrix_arguments(parser)
    parser.add_argument("--scenario", default="two_people", help="tracker scenario (looping)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--fixed-rate", action="store_true", help="gateway.event_driven = false: decide at the ticks only"
    )
    parser.add_argument("--config", type=Path, default=None, help="cell configuration (default configs/cell.toml)")
    parser.add_argument("--json", type=Path, default=default_json_path(NAME), help="where to write the results")
    args = parser.parse_args(argv)
    m = matrix_arguments(parser, args)
    print_header("sustained loop: period and missed cycles of the real gateway, with and without HTTP load")
    report = run(
        m.rates_hz,
        m.http_rates,
        m.duration_s,
        m.warmup_s,
        args.scenario,
        args.seed,
        args.config,
        args.json.parent,
        event_driven=not args.fixed_rate,
        load_nice=m.load_nice,
        sse_clients=m.sse_clients,
    )
    doc = report.finish(args.json)
    print_report(doc)
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
