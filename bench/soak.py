"""The soak: the real cell under a seeded chaos schedule for M minutes, audited on truth the whole time.

    tracker ──relay-tracker──┐                       ┌── hrc-audit (truth, status: straight from the programs)
                             ├── gateway (mutual TLS) ┤
    controller ──relay-ctrl──┘   └─ HTTP child ◀──── this process: status, events, stream clients, faults

Every program runs as in the default cell (mutual TLS and the cell's access control, certificates from a fresh CA);
the tracker and controller emulators reach the gateway only through ``hrc-fault-relay`` (one per link), the
auditor reaches every program directly. This process supervises them as systemd would (a program that dies is
started again after :data:`RESTART_AFTER_S`; ``hrc-cell`` itself stops the cell instead) and injects, in a seeded
order, one fault at a time: kill each program, freeze (SIGSTOP) the tracker and the controller, delay, loss and
partitions on each link, a flood of valid frames from an authenticated tracker, stream clients coming and going,
a gateway restart while a person is near, a wall-clock step on the tracker's and on the controller's host (each
emulator runs under libfaketime, its wall clock offset by a file of this folder: :class:`HostClock`). After each
fault it waits until the gateway shows no fault again (the recovery time) and keeps what the status showed
meanwhile (the reason).

The report (printed and ``DIR/soak.json``): violations within K (the auditor), missed ticks by cause (the
``loop_stall`` events, every gateway run), budget overruns, memory, descriptors and threads per program at start
and end (and at the end once more after each program handed its free heap back to the kernel, ``SIGUSR1``:
what grew is then what the programs hold, not what malloc keeps for reuse), events lost (each gateway run's seqs
contiguous in the JSON Lines file, and the file agreeing with
``GET /api/v1/events``), the gateway recordings after a SIGKILL (readable, how many messages), every fault with
its reason and recovery. A fault that cannot be injected is listed as such. Ctrl-C ends it with the report of
what ran.

    .venv/bin/python -m bench.soak --minutes 5 --seed 1 [--out DIR]
"""

from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import random
import re
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import httpx
import zenoh

from bench._report import machine_info
from hrc_contract import keys
from hrc_contract.config import CellConfig
from hrc_contract.messages import Humans, JointState, MessageError, parse_message
from hrc_runtime.access_control import AUDITOR, CellPolicy, control_key
from hrc_runtime.config import load_cell_config
from hrc_runtime.pki import CellPki
from hrc_runtime.signals import stop_on_signals
from hrc_runtime.zenoh_session import SessionOptions, mutual_tls, session_config
from hrc_tools.cell.procs import (
    Program,
    free_port,
    http_get,
    program_env,
    start_program,
    stop_program,
    with_gateway_rate,
    write_cell_config,
)
from hrc_tools.cert.main import provision_cell

RESTART_AFTER_S = 1.0
"""A program that died is started again this long after (systemd's ``RestartSec``) [s]."""
RECOVERY_TIMEOUT_S = 60.0
"""A fault not recovered from within this long after it ended is reported as not recovered [s]."""
SETTLE_S = 2.0
"""Quiet time between the recovery from one fault and the next fault [s]."""
WARMUP_S = 20.0
"""The cell runs this long before the first fault; resources are sampled at its end ("start") [s]."""
POLL_S = 0.1
"""The status is polled this often [s]."""
SAMPLE_EVERY_S = 5.0
"""After the warm-up, every program's memory, descriptors and threads are sampled this often [s]."""
HEAP_REPORT_SETTLE_S = 2.0
"""After asking every program for its heap report (``SIGUSR1``) at the end, the resources are sampled again this
much later [s]."""
PROCESS_WARMUP_S = 15.0
"""A process's RSS counts from when it is this old (a restarted one's start-up is no growth) [s]."""
FLOOD_RATE_HZ = 2000.0
"""Frames per second of the flooding tracker."""
PROGRAMS = ("gateway", "relay-controller", "relay-tracker", "controller", "tracker", "audit", "zenoh-bystander")
"""What the soak runs, in the order it starts them (it stops them in the reverse order)."""
FAULT_KINDS = (
    "kill:gateway",
    "kill:controller",
    "kill:tracker",
    "kill:relay-controller",
    "kill:relay-tracker",
    "freeze:tracker",
    "freeze:controller",
    "delay:controller",
    "delay:tracker",
    "loss:controller",
    "loss:tracker",
    "partition:controller",
    "partition:tracker",
    "flood:tracker",
    "streams",
    "restart-near:gateway",
    "clock-step:tracker",
    "clock-step:controller",
)
"""Every fault of the schedule; each round plays them all, in a seeded order."""
_MISSED = re.compile(r"\((\d+) missed\)")
CLOCK_STEP_S = (1.0, 5.0)
"""Size of a wall-clock step, drawn uniformly in this range; the direction alternates from a seeded first [s]."""
STEP_SEEN_FRACTION = 0.5
"""A clock step counts as injected when the program's stamps were seen off by at least this part of it."""
FAKETIME_CACHE_S = 1
"""libfaketime reads the offset file at most this often (``FAKETIME_CACHE_DURATION``, whole seconds): a step takes
effect within this long. Re-reading it at every clock call (``FAKETIME_NO_CACHE``) costs a file read per call of
a 250 Hz program [s]."""
FAKETIME_LIBRARIES = (
    "/usr/lib/x86_64-linux-gnu/faketime/libfaketimeMT.so.1",
    "/usr/lib/aarch64-linux-gnu/faketime/libfaketimeMT.so.1",
    "/usr/lib/faketime/libfaketimeMT.so.1",
    "/usr/local/lib/faketime/libfaketimeMT.so.1",
)
"""Where Debian's ``libfaketime`` (and ``make install``) put the preload library. The MT variant serialises its
clock calls: the emulators read the clock from several threads (Python's and Zenoh's)."""
NO_FAKETIME = (
    "libfaketime is not installed (Debian's package libfaketime: scripts/bootstrap.sh installs it as root with "
    "apt): the emulators run on this host's clock, and this benchmark does not change the machine's clock"
)


@dataclass
class FaultResult:
    """One injected fault: when, what the status showed, how long the recovery took."""

    kind: str
    t_s: float
    injected: bool
    note: str = ""
    held_s: float = 0.0
    reasons: list[str] = field(default_factory=list)
    recovered: bool | None = None
    recovery_s: float | None = None


class NotInjectedError(Exception):
    """A fault that cannot be injected here; the message says why."""


def find_libfaketime() -> Path | None:
    """libfaketime's preload library (:data:`FAKETIME_LIBRARIES`), None if it is not installed."""
    return next((Path(p) for p in FAKETIME_LIBRARIES if Path(p).is_file()), None)


@dataclass(frozen=True)
class HostClock:
    """A program's wall clock: this host's, offset by what ``offset_file`` says (libfaketime, no test hook).

    The program runs with the library preloaded (:meth:`environment`); it reads the offset (``+0``, ``+2.5``,
    ``-3``: seconds) at most every :data:`FAKETIME_CACHE_S`, so :meth:`step` moves its ``CLOCK_REALTIME``
    (Python's ``time.time_ns``, Rust's ``SystemTime`` in Zenoh) within that long, as a step of its host's clock by
    NTP or a person would. ``CLOCK_MONOTONIC`` is left alone (``FAKETIME_DONT_FAKE_MONOTONIC``), as a real step
    leaves it, and so are the program's timers and waits (``Event.wait``, ``select``, Zenoh's).

    Caveat of libfaketime 0.9.10 (Debian 12): with ``FAKETIME_DONT_FAKE_MONOTONIC`` it still converts the absolute
    ``CLOCK_MONOTONIC`` deadline of ``clock_nanosleep`` as if it were faked, so Python's ``time.sleep`` fails with
    ``EINVAL``. The emulators wait on events, never with ``time.sleep``.

    Attributes:
        library: libfaketime's preload library (:func:`find_libfaketime`).
        offset_file: the program's offset, one line (libfaketime's ``FAKETIME_TIMESTAMP_FILE``).
    """

    library: Path
    offset_file: Path

    def environment(self, env: Mapping[str, str]) -> dict[str, str]:
        """``env`` with libfaketime preloaded and reading :attr:`offset_file`."""
        preload = " ".join(filter(None, (str(self.library), env.get("LD_PRELOAD", ""))))
        return {k: v for k, v in env.items() if k != "FAKETIME"} | {  # FAKETIME would override the file
            "LD_PRELOAD": preload,
            "FAKETIME_TIMESTAMP_FILE": str(self.offset_file),
            "FAKETIME_CACHE_DURATION": str(FAKETIME_CACHE_S),
            "FAKETIME_DONT_FAKE_MONOTONIC": "1",
            "FAKETIME_DISABLE_SHM": "1",  # ≥ 0.9.11: no /dev/shm files (0.9.10 ignores it: remove_dead_faketime_files)
        }

    def step(self, offset_s: float) -> None:
        """Set the program's wall clock ``offset_s`` [s] off this host's (0: set right), replacing the file whole
        so that the program never reads half of it."""
        partial = self.offset_file.with_name(self.offset_file.name + ".new")
        partial.write_text(f"{offset_s:+.3f}\n")
        partial.replace(self.offset_file)


def remove_dead_faketime_files(shm_dir: Path = Path("/dev/shm")) -> int:
    """Remove the files libfaketime 0.9.10 leaves in ``shm_dir`` for each process it ran in (``faketime_shm_<pid>``,
    ``sem.faketime_sem_<pid>``; never removed, even at a clean exit) whose process has ended; how many."""
    removed = 0
    for path in shm_dir.glob("*faketime_s*_*"):
        prefix, _, pid = path.name.rpartition("_")
        if prefix in ("faketime_shm", "sem.faketime_sem") and pid.isdigit() and not Path(f"/proc/{pid}").exists():
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
                removed += 1
    return removed


def clock_step_s(rng: random.Random, index: int, first_sign: int) -> float:
    """The ``index``-th clock step of a run [s]: a size drawn in :data:`CLOCK_STEP_S`, the direction alternating
    from ``first_sign`` (+1 or -1) so that a run of two steps or more plays both."""
    sign = first_sign if index % 2 == 0 else -first_sign
    return round(sign * rng.uniform(*CLOCK_STEP_S), 1)


def fault_schedule(seed: int, rounds: int) -> list[str]:
    """``rounds`` rounds of :data:`FAULT_KINDS`, each shuffled by a generator seeded with ``seed``."""
    rng = random.Random(seed)
    schedule: list[str] = []
    for _ in range(rounds):
        kinds = list(FAULT_KINDS)
        rng.shuffle(kinds)
        schedule += kinds
    return schedule


def split_runs(events: list[dict[str, Any]]) -> list[list[dict[str, Any]]]:
    """The events of the JSON Lines file split into gateway runs (each begins with its seq 1)."""
    runs: list[list[dict[str, Any]]] = []
    for event in events:
        if event["seq"] == 1 or not runs:
            runs.append([])
        runs[-1].append(event)
    return runs


def seq_gaps(run: list[dict[str, Any]]) -> list[int]:
    """Seqs missing in one gateway run's events (they should be 1, 2, 3, ...)."""
    seqs = [e["seq"] for e in run]
    missing = sorted(set(range(1, max(seqs, default=0) + 1)) - set(seqs))
    return missing


def stalls_by_cause(events: list[dict[str, Any]]) -> tuple[dict[str, int], dict[str, int]]:
    """``(stalls, missed ticks)`` by cause, from the ``loop_stall`` events."""
    stalls: dict[str, int] = {}
    missed: dict[str, int] = {}
    for event in events:
        if event["kind"] != "loop_stall":
            continue
        cause = event.get("cause") or "unknown"
        stalls[cause] = stalls.get(cause, 0) + 1
        match = _MISSED.search(event["message"])
        missed[cause] = missed.get(cause, 0) + (int(match.group(1)) if match else 0)
    return stalls, missed


def resources(pid: int) -> dict[str, int] | None:
    """RSS [kB], open descriptors, threads and age [s] of a process (None if it is gone, or exited and not yet
    reaped)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
        started_ticks = int(Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[19])
        uptime_s = float(Path("/proc/uptime").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    if not {"VmRSS", "RssAnon", "RssFile", "Threads"} <= fields.keys():
        return None  # a zombie (exited, not yet reaped: a fault just killed it) has no memory: gone
    age_s = int(uptime_s - started_ticks / os.sysconf("SC_CLK_TCK"))
    return {
        "rss_kb": int(fields["VmRSS"].split()[0]),
        "rss_anon_kb": int(fields["RssAnon"].split()[0]),  # the heaps and stacks (what a leak grows)
        "rss_file_kb": int(fields["RssFile"].split()[0]),  # mapped files: code of the libraries paged in as it runs
        "fds": fds,
        "threads": int(fields["Threads"]),
        "age_s": age_s,
    }


@dataclass(frozen=True)
class Lifetime:
    """One process of a program between its first and its last resource sample (after the warm-up)."""

    pid: int
    first: dict[str, int]
    last: dict[str, int]
    samples: int

    @property
    def rss_growth_percent(self) -> float:
        """RSS growth from the first sample to the last [%]."""
        return 100.0 * (self.last["rss_kb"] / self.first["rss_kb"] - 1.0)

    def growth_percent(self, field: str) -> float | None:
        """Growth of ``field`` (a sample's figure, e.g. ``rss_anon_kb``) from the first sample to the last [%]; None
        if a sample lacks it."""
        first, last = self.first.get(field), self.last.get(field)
        if not first or last is None:
            return None
        return 100.0 * (last / first - 1.0)


def lifetimes(samples: list[dict[str, Any]], warmup_s: float = PROCESS_WARMUP_S) -> dict[str, list[Lifetime]]:
    """Resource samples (``sample_resources``' dictionaries, oldest first) as each program's process lifetimes.

    A program restarted meanwhile has several: comparing a sample of one process with a sample of the next
    compares two start-ups, not a growth. Samples of a process younger than ``warmup_s`` (its own start-up:
    loading, compiling, connecting) [s] and samples without an RSS (the process was gone) are left out.
    """
    spans: dict[tuple[str, int], Lifetime] = {}
    for sample in samples:
        for name, res in sample.items():
            if not res.get("rss_kb") or res.get("age_s", warmup_s) < warmup_s:
                continue
            key = (name, res["pid"])
            seen = spans.get(key)
            spans[key] = Lifetime(res["pid"], seen.first if seen else res, res, (seen.samples if seen else 0) + 1)
    out: dict[str, list[Lifetime]] = {}
    for (name, _pid), span in spans.items():
        out.setdefault(name, []).append(span)
    return out


def rss_growth_percent(
    samples: list[dict[str, Any]], warmup_s: float = PROCESS_WARMUP_S, field: str = "rss_kb"
) -> dict[str, float]:
    """Per program, the largest growth of ``field`` (default the RSS) of any one of its processes over its own
    lifetime [%].

    Only processes sampled at least twice after their warm-up (``warmup_s`` [s], see :func:`lifetimes`) count:
    a growth needs two samples of the same process.
    """
    growth: dict[str, float] = {}
    for name, spans in lifetimes(samples, warmup_s).items():
        measured = [g for span in spans if span.samples >= 2 and (g := span.growth_percent(field)) is not None]
        if measured:
            growth[name] = round(max(measured), 2)
    return growth


FLOOR_WINDOW_SAMPLES = 12
"""Samples (one minute) whose smallest RSS is a process's floor at the start and at the end of its life."""


def rss_floor_growth_percent(
    samples: list[dict[str, Any]], warmup_s: float = PROCESS_WARMUP_S, window: int = FLOOR_WINDOW_SAMPLES
) -> dict[str, float]:
    """Per program, the largest growth of one process's RSS *floor*: the smallest RSS of its last ``window``
    samples against the smallest of its first ``window`` (after its warm-up) [%].

    Under faults a program's RSS swings by megabytes (a queue while a link is cut, freed after): the last sample
    against the first (:func:`rss_growth_percent`) counts a swing caught in the last sample as growth; the floor
    counts what stayed.
    """
    series: dict[tuple[str, int], list[int]] = {}
    for sample in samples:
        for name, res in sample.items():
            if res.get("rss_kb") and res.get("age_s", warmup_s) >= warmup_s:
                series.setdefault((name, res["pid"]), []).append(res["rss_kb"])
    growth: dict[str, float] = {}
    for (name, _pid), rss in series.items():
        if len(rss) >= 2:
            floor_growth = 100.0 * (min(rss[-window:]) / min(rss[:window]) - 1.0)
            growth[name] = max(growth.get(name, -math.inf), round(floor_growth, 2))
    return growth


def rss_after_trim_growth_percent(
    samples: list[dict[str, Any]], trimmed: dict[str, Any], warmup_s: float = PROCESS_WARMUP_S
) -> dict[str, float]:
    """Per program alive at the end, the growth of its RSS after ``malloc_trim`` at the end (``trimmed``: a
    :meth:`Soak.sample_resources` taken after :meth:`Soak.release_free_heaps`) against the same process's first
    sample after its warm-up [%]: the growth without the freed memory malloc held. The first sample is not
    trimmed, so this can only understate a growth by the free heap at the start (small: a start-up frees little).
    """
    growth: dict[str, float] = {}
    for name, spans in lifetimes(samples, warmup_s).items():
        after = trimmed.get(name, {})
        for span in spans:
            if span.pid == after.get("pid") and after.get("rss_kb") and span.samples >= 2:
                growth[name] = round(100.0 * (after["rss_kb"] / span.first["rss_kb"] - 1.0), 2)
    return growth


def _children(pid: int) -> list[int]:
    try:
        return [int(c) for c in Path(f"/proc/{pid}/task/{pid}/children").read_text().split()]
    except OSError:
        return []


class Soak:
    """The cell, its supervision, the status watch and the faults."""

    def __init__(self, work: Path, seed: int, stop: threading.Event) -> None:
        self.work = work
        self.stop = stop
        self.rng = random.Random(seed)
        self.start_s = time.monotonic()
        base = load_cell_config(None)
        self.http_port = free_port()
        self.config: CellConfig = with_gateway_rate(base, base.gateway.rate_hz, self.http_port)
        self.config_path = write_cell_config(self.config, work / "cell.toml")
        self.pki_dir = work / "pki"
        pki = CellPki(self.pki_dir)
        pki.ensure_ca()
        self.policy = CellPolicy.from_config(self.config)
        provision_cell(pki, self.policy)
        self.ports = {name: free_port() for name in ("gateway", "controller", "tracker", "rc", "rt")}
        self.procs: dict[str, Program] = {}
        self.paused: set[str] = set()  # not restarted meanwhile (a fault is being played)
        self.gateway_runs = 0
        self.recordings: list[dict[str, Any]] = []
        self.latest: dict[str, Any] | None = None
        self.latest_s = 0.0
        self.status_lock = threading.Lock()
        self.relay_rules: dict[str, list[str]] = {"relay-controller": [], "relay-tracker": []}
        self.events_checks: list[dict[str, Any]] = []
        self.incarnation_loops: list[dict[str, Any]] = []
        self.resource_samples: list[dict[str, Any]] = []  # every SAMPLE_EVERY_S once sampling is on
        self.sampling = False
        self.next_sample_s = 0.0
        library = find_libfaketime()
        self.clocks: dict[str, HostClock] = {}  # the emulators' hosts' wall clocks (none without libfaketime)
        if library is not None:
            self.clocks = {n: HostClock(library, work / f"clock-{n}.offset") for n in ("tracker", "controller")}
            for clock in self.clocks.values():
                clock.step(0.0)
        self.clock_steps = 0
        self.first_step_sign = self.rng.choice((1, -1))

    # -- programs -------------------------------------------------------------------------------

    def ep(self, name: str) -> str:
        return f"tls/127.0.0.1:{self.ports[name]}"

    def _command(self, name: str) -> tuple[str, list[str]]:
        common = ["--config", str(self.config_path), "--pki-dir", str(self.pki_dir)]
        if name == "gateway":
            self.gateway_runs += 1
            record = self.work / f"gateway-{self.gateway_runs}.mcap"
            self.recordings.append({"path": str(record), "killed": False})
            return "gateway", [
                *common,
                *("--zenoh-listen", self.ep("gateway"), "--http-port", str(self.http_port)),
                *("--events-log", str(self.work / "events.jsonl"), "--record", str(record)),
            ]
        if name == "controller":
            links = ["--zenoh-listen", self.ep("controller"), "--zenoh-connect", self.ep("rc")]
            return "controller_emu", [*common, *links]
        if name == "tracker":
            return "tracker_emu", [*common, "--zenoh-listen", self.ep("tracker"), "--zenoh-connect", self.ep("rt")]
        if name in ("relay-controller", "relay-tracker"):
            side_a = self.ep("rc" if name == "relay-controller" else "rt")
            rules = [arg for rule in self.relay_rules[name] for arg in ("--rule", rule)]
            return "hrc_tools.faultinject", [
                *common,
                *("--a-listen", side_a, "--b-connect", self.ep("gateway"), "--seed", str(self.rng.randrange(1 << 30))),
                *rules,
            ]
        if name == "audit":
            connect = [arg for n in ("gateway", "controller", "tracker") for arg in ("--zenoh-connect", self.ep(n))]
            return "hrc_tools.audit", [*common, *connect, "--json", str(self.work / "audit.json")]
        if name == "zenoh-bystander":  # joins like the auditor, does nothing: Zenoh's own growth under the churn
            connect = [arg for n in ("gateway", "controller", "tracker") for arg in ("--zenoh-connect", self.ep(n))]
            return "bench.zenoh_bystander", [*common, *connect]
        raise KeyError(name)

    def start(self, name: str) -> None:
        module, args = self._command(name)
        env = program_env(plain_tcp=False)
        if name in self.clocks:
            env = self.clocks[name].environment(env)
            remove_dead_faketime_files()  # the previous run's, if this is a restart
        self.procs[name] = start_program(module, args, self.work / f"{name}.log", env=env)

    def supervise(self) -> None:
        """Start again, after :data:`RESTART_AFTER_S`, every program that exited (not one a fault holds)."""
        for name, proc in list(self.procs.items()):
            if name not in self.paused and proc.poll() is not None:
                self.sleep(RESTART_AFTER_S)
                self.start(name)

    def sleep(self, duration_s: float) -> None:
        """Wait ``duration_s``, polling the status meanwhile (returns early on Ctrl-C)."""
        end_s = time.monotonic() + duration_s
        while not self.stop.is_set() and time.monotonic() < end_s:
            self.poll_status()
            self.sample_now()
            self.stop.wait(min(POLL_S, max(0.0, end_s - time.monotonic())))

    def sample_now(self, force: bool = False) -> dict[str, Any] | None:
        """Sample every program's resources if sampling is on and it is time (or ``force``); the sample."""
        if not self.sampling or (not force and time.monotonic() < self.next_sample_s):
            return None
        self.next_sample_s = time.monotonic() + SAMPLE_EVERY_S
        sample = self.sample_resources()
        self.resource_samples.append(sample)
        with (self.work / "resources.jsonl").open("a") as f:  # the curves behind the growth figures
            f.write(json.dumps({"wall_s": round(time.time(), 3), **sample}) + "\n")
        return sample

    # -- the status -----------------------------------------------------------------------------

    def poll_status(self) -> dict[str, Any] | None:
        try:
            reply = http_get(f"http://127.0.0.1:{self.http_port}/api/v1/status", timeout_s=2.0)
        except OSError:
            return None
        if reply.status_code != 200:
            return None
        doc: dict[str, Any] = reply.json()
        with self.status_lock:
            self.latest, self.latest_s = doc, time.monotonic()
        return doc

    def reasons(self, doc: dict[str, Any] | None) -> dict[str, str]:
        """The active faults' codes, each with its reason (the first robot's); a missing status is one too."""
        if doc is None:
            return {"no_status": "the gateway does not answer"}
        return {f["code"]: f["reason"] for r in doc["robots"].values() for f in r["faults"]}

    def healthy(self) -> bool:
        """Every program runs, and a fresh status shows no fault on any robot."""
        if any(p.poll() is not None for p in self.procs.values()):
            return False
        doc = self.poll_status()
        return doc is not None and not self.reasons(doc)

    def someone_near(self) -> bool:
        doc = self.poll_status()
        return doc is not None and any(r["zone"] != "autonomous" for r in doc["robots"].values())

    # -- faults ---------------------------------------------------------------------------------

    def play(self, kind: str) -> FaultResult:
        """Inject one fault, end it, wait for the recovery; what the status showed meanwhile."""
        result = FaultResult(kind, round(time.monotonic() - self.start_s, 1), injected=True)
        seen: dict[str, str] = {}
        began_s = time.monotonic()

        def watch(duration_s: float) -> None:
            end_s = time.monotonic() + duration_s
            while not self.stop.is_set() and time.monotonic() < end_s:
                seen.update({k: v for k, v in self.reasons(self.poll_status()).items() if k not in seen})
                self.sample_now()
                self.stop.wait(POLL_S)

        try:
            result.note = self._inject(kind, self.rng.uniform(2.0, 6.0), watch)
        except NotInjectedError as exc:
            result.injected, result.note = False, str(exc)
            return result
        except (OSError, zenoh.ZError, httpx.HTTPError) as exc:
            result.injected, result.note = False, f"could not inject: {exc}"
        result.held_s = round(time.monotonic() - began_s, 2)
        result.recovered, result.recovery_s = self._recover(seen)
        result.reasons = [f"{code}: {reason}" for code, reason in sorted(seen.items())]
        return result

    def _inject(self, kind: str, hold_s: float, watch: Callable[[float], None]) -> str:
        """Play fault ``kind`` for about ``hold_s`` [s] and end it; a note on what was done.

        Raises:
            NotInjectedError: this fault cannot be injected here (the message says why).
        """
        action, _, target = kind.partition(":")
        if action in ("kill", "restart-near"):
            if action == "restart-near" and not self._wait_near(30.0):
                raise NotInjectedError("nobody came near the robot within 30 s")
            self._restart(target, signal.SIGKILL if action == "kill" else signal.SIGINT, watch)
        elif action == "freeze":
            proc = self.procs[target]
            self.paused.add(target)
            proc.send_signal(signal.SIGSTOP)
            try:
                watch(hold_s)
            finally:
                proc.send_signal(signal.SIGCONT)
                self.paused.discard(target)
        elif action in ("delay", "loss"):
            relay = f"relay-{target}"
            self.relay_rules[relay] = ["hrc/**:delay=0.08,jitter=0.03" if action == "delay" else "hrc/**:loss=0.3"]
            try:
                self._restart(relay, signal.SIGINT, watch)
                watch(hold_s)
            finally:
                self.relay_rules[relay] = []
                self._restart(relay, signal.SIGINT, watch)
            return f"relay restarted with {action} for {hold_s:.1f} s, then restarted without"
        elif action == "partition":
            self._partition(f"relay-{target}", hold_s)
            watch(hold_s + 0.5)
        elif action == "flood":
            return self._flood(hold_s, watch)
        elif action == "streams":
            return self._streams(hold_s)
        elif action == "clock-step":
            return self._clock_step(target, hold_s, watch)
        return ""

    def _recover(self, seen: dict[str, str]) -> tuple[bool | None, float | None]:
        """Wait until every program runs and the gateway shows no fault: ``(recovered, after how long [s])``."""
        ended_s = time.monotonic()
        while not self.stop.is_set() and time.monotonic() - ended_s < RECOVERY_TIMEOUT_S:
            self.supervise()
            if self.healthy():
                return True, round(time.monotonic() - ended_s, 2)
            seen.update({k: v for k, v in self.reasons(self.latest).items() if k not in seen})
            self.sample_now()
            self.stop.wait(POLL_S)
        return (None if self.stop.is_set() else False), None

    def _wait_near(self, timeout_s: float) -> bool:
        end_s = time.monotonic() + timeout_s
        while not self.stop.is_set() and time.monotonic() < end_s:
            if self.someone_near():
                return True
            self.stop.wait(POLL_S)
        return False

    def _restart(self, name: str, sig: int, watch: Callable[[float], None]) -> None:
        """Stop ``name`` with ``sig`` and start it again after :data:`RESTART_AFTER_S` (watching meanwhile)."""
        self.paused.add(name)
        try:
            if name == "gateway":
                self._before_gateway_stop()
                if sig == signal.SIGKILL:
                    self.recordings[-1]["killed"] = True
                    self.recordings[-1]["killed_ns"] = time.time_ns()
            proc = self.procs[name]
            if sig == signal.SIGKILL:
                proc.kill()
                proc.wait()
            else:
                with contextlib.suppress(Exception):
                    stop_program(proc, sig)
            watch(RESTART_AFTER_S)
            self.start(name)
        finally:
            self.paused.discard(name)

    def _before_gateway_stop(self) -> None:
        """This gateway run's last status (loop counts) and its events as the API has them."""
        doc = self.poll_status()
        if doc is not None:
            self.incarnation_loops.append(doc["loop"])
        self.events_checks.append(self.check_events_api())

    def _session(self, common_name: str, connect: list[str]) -> zenoh.Session:
        tls = mutual_tls(self.pki_dir, common_name, self.policy, create=False)
        return zenoh.open(session_config(connect=connect, options=SessionOptions("client", tls)))

    def _partition(self, relay: str, duration_s: float) -> None:
        side_a = self.ep("rc" if relay == "relay-controller" else "rt")
        with self._session("relay", [side_a]) as session:
            time.sleep(0.5)  # the route to the relay's control subscriber
            session.put(control_key(self.config.cell), json.dumps({"partition_for_s": duration_s}))
            time.sleep(0.2)

    def _flood(self, duration_s: float, watch: Callable[[float], None]) -> str:
        """The tracker emulator's identity puts copies of its newest real frames at :data:`FLOOD_RATE_HZ`."""
        newest: dict[str, bytes] = {}
        lock = threading.Lock()

        def on_frame(sample: zenoh.Sample) -> None:
            payload = sample.payload.to_bytes()
            parse_message(payload, Humans)  # raises on an invalid frame: only valid frames are copied
            with lock:
                newest[str(sample.key_expr)] = payload

        puts = 0
        with self._session("tracker-emu", [self.ep("gateway")]) as session:
            session.declare_subscriber(f"hrc/{self.config.cell}/tracker/*/humans", on_frame)
            end_s = time.monotonic() + duration_s
            publishers: dict[str, Any] = {}
            while not self.stop.is_set() and time.monotonic() < end_s:
                with lock:
                    frames = dict(newest)
                for key, payload in frames.items():
                    if key not in publishers:
                        publishers[key] = session.declare_publisher(key, express=True)
                    publishers[key].put(payload)
                    puts += 1
                time.sleep(1.0 / FLOOD_RATE_HZ)  # pacing the flood, not synchronisation
        if puts == 0:
            raise OSError("no tracker frame to copy arrived")
        watch(0.5)
        return f"{puts} copies of real frames put in {duration_s:.1f} s"

    def _clock_step(self, target: str, hold_s: float, watch: Callable[[float], None]) -> str:
        """Step ``target``'s wall clock (seeded, ±1–5 s), hold it ``hold_s`` [s], set it right again (as NTP or PTP
        would); check on the wire that its stamps moved.

        Raises:
            NotInjectedError: no libfaketime, or the program's stamps did not move.
        """
        clock = self.clocks.get(target)
        if clock is None:
            raise NotInjectedError(NO_FAKETIME)
        step_s = clock_step_s(self.rng, self.clock_steps, self.first_step_sign)
        self.clock_steps += 1
        offsets_s: list[float] = []
        with self._stamp_watch(target, offsets_s):
            clock.step(step_s)
            try:
                watch(hold_s)
            finally:
                clock.step(0.0)
        seen_s = max(offsets_s, key=abs, default=0.0)
        if abs(seen_s) < STEP_SEEN_FRACTION * abs(step_s):
            raise NotInjectedError(
                f"the {target}'s clock was stepped by {step_s:+.1f} s (libfaketime), but its stamps did not move: "
                f"{len(offsets_s)} messages, at most {seen_s:+.3f} s off this host's clock"
            )
        return (
            f"the {target}'s wall clock stepped by {step_s:+.1f} s for {hold_s:.1f} s (libfaketime), then set right; "
            f"its stamps seen up to {seen_s:+.3f} s off this host's clock"
        )

    @contextlib.contextmanager
    def _stamp_watch(self, target: str, offsets_s: list[float]) -> Iterator[None]:
        """Within the block, append to ``offsets_s`` each of ``target``'s messages' stamp − this host's clock at
        arrival [s] (read as an observer through the gateway, which routes them)."""
        cell = self.config.cell
        key = keys.tracker_humans(cell, "*") if target == "tracker" else keys.robot_state(cell, "*")
        model: type[Humans] | type[JointState] = Humans if target == "tracker" else JointState
        lock = threading.Lock()

        def on_message(sample: zenoh.Sample) -> None:
            arrived_ns = time.time_ns()
            try:
                stamp_ns = parse_message(sample.payload.to_bytes(), model).stamp_ns
            except MessageError:
                return
            with lock:
                offsets_s.append((stamp_ns - arrived_ns) / 1e9)

        with self._session(AUDITOR, [self.ep("gateway")]) as session:
            session.declare_subscriber(key, on_message)
            yield

    def _streams(self, duration_s: float) -> str:
        """Stream clients (``/api/v1/stream``) come and go: each reads a random while, then drops the connection."""
        url = f"http://127.0.0.1:{self.http_port}/api/v1/stream"
        opened = lines = 0
        end_s = time.monotonic() + duration_s
        while not self.stop.is_set() and time.monotonic() < end_s:
            stay_s = self.rng.uniform(0.1, 1.5)
            with httpx.stream("GET", url, timeout=5.0) as response:
                opened += 1
                until_s = time.monotonic() + stay_s
                for _ in response.iter_lines():
                    lines += 1
                    if time.monotonic() > until_s:
                        break
        return f"{opened} stream clients, {lines} lines read"

    # -- checks ---------------------------------------------------------------------------------

    def read_events_file(self) -> list[dict[str, Any]]:
        path = self.work / "events.jsonl"
        rotated = sorted(self.work.glob("events.jsonl.*"), key=lambda p: -int(p.suffix[1:]))
        events = []
        for p in [*rotated, path]:
            if p.exists():
                events += [json.loads(line) for line in p.read_text().splitlines() if line.strip()]
        return events

    def check_events_api(self) -> dict[str, Any]:
        """The current gateway run's events: the API's (the newest 1000) against the file's, seq by seq."""
        try:
            api = http_get(f"http://127.0.0.1:{self.http_port}/api/v1/events?since=0", timeout_s=5.0).json()["events"]
        except (OSError, ValueError, KeyError):
            return {"checked": False}
        runs = split_runs(self.read_events_file())
        current = {e["seq"]: e for e in runs[-1]} if runs else {}
        differing = [e["seq"] for e in api if current.get(e["seq"]) != {k: v for k, v in e.items() if v is not None}]
        return {"checked": True, "api_events": len(api), "file_events": len(current), "differing_seqs": differing}

    def release_free_heaps(self, settle_s: float = HEAP_REPORT_SETTLE_S) -> dict[str, Any]:
        """Ask every program for its heap report (``SIGUSR1``: the free heap handed back to the kernel,
        ``hrc_runtime/memory.py``), then sample the resources again: what the resident set is without the freed
        memory malloc held."""
        for res in self.sample_resources().values():
            with contextlib.suppress(OSError):
                os.kill(res["pid"], signal.SIGUSR1)
        self.sleep(settle_s)
        return self.sample_resources()

    def sample_resources(self) -> dict[str, Any]:
        out = {}
        for name, proc in self.procs.items():
            out[name] = {"pid": proc.pid, **(resources(proc.pid) or {})}
            if name == "gateway":
                for child in _children(proc.pid):
                    out["gateway-http"] = {"pid": child, **(resources(child) or {})}
        return out


def check_recording(path: Path) -> dict[str, Any]:
    """A gateway recording read after a SIGKILL: messages readable, the sequence numbers gapless per channel."""
    from mcap.records import Message
    from mcap.stream_reader import StreamReader  # record by record: a killed writer left no summary

    read = 0
    last_ns = 0
    error = None
    sequences: list[int] = []  # one counter over every channel (hrc_runtime.mcap_sink)
    try:
        with path.open("rb") as f:
            for record in StreamReader(f).records:
                if isinstance(record, Message):
                    read += 1
                    last_ns = max(last_ns, record.log_time)
                    sequences.append(record.sequence)
    except Exception as exc:  # a truncated tail ends the reading: how far it got is the result
        error = f"{type(exc).__name__}: {str(exc)[:120]}"
    gaps = sum(1 for a, b in itertools.pairwise(sorted(sequences)) if b != a + 1)
    return {"path": str(path), "messages_read": read, "last_log_ns": last_ns, "sequence_gaps": gaps, "tail": error}


def run_soak(minutes: float, seed: int, work: Path, stop: threading.Event) -> dict[str, Any]:
    soak = Soak(work, seed, stop)
    faults: list[FaultResult] = []
    started: dict[str, Any] = {}
    ended: dict[str, Any] = {}
    trimmed: dict[str, Any] = {}
    end_s = soak.start_s + minutes * 60.0
    try:
        for name in PROGRAMS:
            soak.start(name)
        print(f"soak: cell up in {work} (mutual TLS); warming up {WARMUP_S:.0f} s", flush=True)
        soak.sleep(min(WARMUP_S, minutes * 60.0 / 4))
        soak.supervise()
        soak.sampling = True
        started = soak.sample_now(force=True) or {}
        for kind in fault_schedule(seed, rounds=1000):
            if stop.is_set() or time.monotonic() > end_s - 10.0:
                break
            result = soak.play(kind)
            faults.append(result)
            state = f"recovered in {result.recovery_s} s" if result.recovered else f"recovered={result.recovered}"
            print(f"soak: t={result.t_s:7.1f} s {kind:24s} {state}; {'; '.join(result.reasons)[:160]}", flush=True)
            soak.sleep(SETTLE_S)
        soak.sleep(max(0.0, min(5.0, end_s - time.monotonic())))
        ended = soak.sample_now(force=True) or {}
        trimmed = soak.release_free_heaps()
        soak._before_gateway_stop()
    finally:
        for name in reversed(PROGRAMS):
            if name in soak.procs:
                with contextlib.suppress(Exception):
                    stop_program(soak.procs[name])
        remove_dead_faketime_files()
    if not started:
        started = {}
        ended = {}
        trimmed = {}
    return build_report(soak, faults, started, ended, minutes, seed, trimmed)


def build_report(
    soak: Soak,
    faults: list[FaultResult],
    started: dict[str, Any],
    ended: dict[str, Any],
    minutes: float,
    seed: int,
    trimmed: dict[str, Any] | None = None,
) -> dict[str, Any]:
    trimmed = trimmed or {}
    try:
        audit = json.loads((soak.work / "audit.json").read_text())
    except (OSError, ValueError):
        audit = {"violations": None, "verdict": "no audit report (the auditor did not finish)"}
    events = soak.read_events_file()
    runs = split_runs(events)
    stalls, missed = stalls_by_cause(events)
    loops = soak.incarnation_loops
    recordings = []
    for r in soak.recordings:
        if r["killed"] and Path(r["path"]).exists():
            rec = check_recording(Path(r["path"]))
            rec["lost_tail_s"] = round((r["killed_ns"] - rec["last_log_ns"]) / 1e9, 3) if rec["last_log_ns"] else None
            recordings.append(rec)
    growth = rss_growth_percent(soak.resource_samples)
    spans = lifetimes(soak.resource_samples)
    return {
        "schema": "hrc.bench.soak/1",
        "machine": machine_info(),
        "minutes": minutes,
        "seed": seed,
        "wall_s": round(time.monotonic() - soak.start_s, 1),
        "work_dir": str(soak.work),
        "audit": {
            k: audit.get(k) for k in ("violations", "verdict", "cycles_audited", "human_speed_mps", "wall_duration_s")
        },
        "audit_unaudited_cycles": {n: r.get("unaudited_cycles") for n, r in audit.get("robots", {}).items()},
        "audit_truth_gap_cycles": {n: r.get("truth_gap_cycles") for n, r in audit.get("robots", {}).items()},
        "audit_longest_truth_gap_s": {n: r.get("longest_truth_gap_s") for n, r in audit.get("robots", {}).items()},
        "gateway_runs": len(runs),
        "missed_ticks": sum(loop.get("missed_cycles", 0) for loop in loops),
        "stalls_by_cause": stalls,
        "missed_ticks_by_cause": missed,
        "budget_overruns": sum(loop.get("budget_overruns", 0) for loop in loops),
        "worst_last_lateness_s": max((loop.get("last_lateness_s", 0.0) for loop in loops), default=None),
        "events": {
            "in_file": len(events),
            "runs": len(runs),
            "seq_gaps": {i + 1: gaps for i, run in enumerate(runs) if (gaps := seq_gaps(run))},
            "api_vs_file": soak.events_checks,
        },
        "resources_start": started,
        "resources_end": ended,
        "rss_growth_percent": growth,
        "rss_floor_growth_percent": rss_floor_growth_percent(soak.resource_samples),
        "rss_anon_growth_percent": rss_growth_percent(soak.resource_samples, field="rss_anon_kb"),
        "rss_file_growth_percent": rss_growth_percent(soak.resource_samples, field="rss_file_kb"),
        "resources_after_trim": trimmed,
        "rss_after_trim_growth_percent": rss_after_trim_growth_percent(soak.resource_samples, trimmed),
        "rss_growth_note": "per program, the largest growth of one process between its first sample after its "
        f"warm-up ({PROCESS_WARMUP_S:g} s old) and its last (sampled every {SAMPLE_EVERY_S:g} s); zenoh-bystander: "
        "a Zenoh session joined like the auditor that does nothing (Zenoh's own growth while the peers restart)",
        "processes_sampled": {name: len(s) for name, s in spans.items()},
        "recordings_after_sigkill": recordings,
        "faults": [asdict(f) for f in faults],
        "faults_not_injected": [f.kind for f in faults if not f.injected],
        "faults_not_recovered": [f.kind for f in faults if f.recovered is False],
    }


def format_report(report: dict[str, Any]) -> str:
    lines = [
        f"soak: {report['wall_s']:.0f} s, seed {report['seed']}, {len(report['faults'])} faults, "
        f"{report['gateway_runs']} gateway runs",
        f"  violations within K: {report['audit']['violations']} ({report['audit']['verdict']}, "
        f"{report['audit']['cycles_audited']} cycles audited; of them across a gap in the human truth "
        f"{report['audit_truth_gap_cycles']}, the longest gap {report['audit_longest_truth_gap_s']} s; "
        f"not audited {report['audit_unaudited_cycles']})",
        f"  missed ticks: {report['missed_ticks']} (status, summed over gateway runs); by cause (events): "
        f"{report['missed_ticks_by_cause']}; stalls {report['stalls_by_cause']}",
        f"  budget overruns: {report['budget_overruns']}; worst last lateness {report['worst_last_lateness_s']}",
        f"  events: {report['events']['in_file']} in the file, seq gaps {report['events']['seq_gaps'] or 'none'}, "
        f"API vs file: {[c.get('differing_seqs') for c in report['events']['api_vs_file']]}",
        f"  RSS growth [%], the largest of one process over its lifetime: {report['rss_growth_percent']}",
        f"    its floor (the smallest of the first and of the last minute): {report['rss_floor_growth_percent']}",
        f"    of it anonymous (heaps, stacks): {report['rss_anon_growth_percent']}; mapped files (library code paged "
        f"in): {report['rss_file_growth_percent']}",
        f"    after each program handed its free heap back (malloc_trim on SIGUSR1, at the end): "
        f"{report.get('rss_after_trim_growth_percent', {})}",
    ]
    for name, start in report["resources_start"].items():
        end = report["resources_end"].get(name, {})
        restarted = "" if start.get("pid") == end.get("pid") else " (restarted meanwhile)"
        lines.append(
            f"    {name:18s} rss {start.get('rss_kb')}→{end.get('rss_kb')} kB, fds {start.get('fds')}→"
            f"{end.get('fds')}, threads {start.get('threads')}→{end.get('threads')}{restarted}"
        )
    for rec in report["recordings_after_sigkill"]:
        lines.append(
            f"  recording after SIGKILL {Path(rec['path']).name}: {rec['messages_read']} messages readable, "
            f"{rec['sequence_gaps']} sequence gaps, the last {rec['lost_tail_s']} s before the kill not on disk, "
            f"tail: {rec['tail'] or 'clean'}"
        )
    lines.append("  faults:")
    for f in report["faults"]:
        if not f["injected"]:
            lines.append(f"    t={f['t_s']:7.1f} {f['kind']:24s} NOT INJECTED: {f['note']}")
            continue
        rec = f"recovered in {f['recovery_s']} s" if f["recovered"] else f"recovered={f['recovered']}"
        note = f" [{f['note']}]" if f["note"] else ""
        reasons = "; ".join(f["reasons"])
        lines.append(f"    t={f['t_s']:7.1f} {f['kind']:24s} held {f['held_s']} s, {rec}; {reasons}{note}")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.soak", description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, required=True, help="how long the cell runs under faults")
    parser.add_argument("--seed", type=int, default=0, help="seed of the chaos schedule (default 0)")
    parser.add_argument("--out", type=Path, default=None, help="folder of the logs and soak.json (default: a new one)")
    args = parser.parse_args(argv)
    if not 0.0 < args.minutes < 1e5:
        parser.error(f"--minutes {args.minutes}; allowed: > 0")
    work = args.out or Path(tempfile.mkdtemp(prefix="hrc-soak-"))
    work.mkdir(parents=True, exist_ok=True)
    with stop_on_signals() as stop:
        report = run_soak(args.minutes, args.seed, work, stop)
    (work / "soak.json").write_text(json.dumps(report, indent=2, default=str) + "\n")
    sys.stdout.write(format_report(report))
    print(f"soak: report {work / 'soak.json'}")
    ok = report["audit"]["violations"] == 0 and not report["events"]["seq_gaps"]
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
