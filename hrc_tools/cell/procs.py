"""The real programs as subprocesses on loopback, for the benchmarks and the end-to-end tests.

One function for each step, shared by ``bench/`` and ``tests/`` (which import this module as ``hrc_tools.cell.procs``):

* :func:`free_port` / :func:`free_endpoint`: a free loopback port, a Zenoh endpoint on it;
* :func:`write_cell_config`: a temporary, self-contained cell file (checked to load back to the same
  configuration);
* :func:`start_program`: the **only** place that builds a program's command line and environment (security
  options, e.g. TLS certificates, are added there once for every benchmark and test);
* :func:`stop_program`: SIGINT, then wait; killed if it does not end in time;
* :func:`wait_for`: poll a condition until a deadline (the readiness wait of every start-up);
* :func:`running_cell` / :class:`Cell` / :func:`record`: a whole cell (gateway, controller emulator, tracker
  emulators, and for a robot behind a bridge the controller bridge), watched through its REST API and its status
  on Zenoh.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, TypeVar

import zenoh

from hrc_contract import keys
from hrc_contract.config import UNSAFE_ENV_VAR, CellConfig, ConfigError
from hrc_contract.errors import HrcError
from hrc_contract.status_models import GatewayStatus, RobotStatusResponse
from hrc_runtime.config import load_cell_config
from hrc_runtime.zenoh_session import PLAIN_TCP_ENV_VAR, session_config
from hrc_tools.cell.launcher import bridge_environment, vendor_face_args

T = TypeVar("T")

Program = subprocess.Popen[bytes]
Status = dict[str, Any]

POLL_S = 0.05
"""How often :func:`wait_for` evaluates its condition [s]."""

LATE_DATA_FAULTS = frozenset({"tracker_stale", "joint_state_stale", "override_path_stale"})
"""Faults a busy machine legitimately raises: data older than ``safety.max_data_age_s`` because a program was not
scheduled in time. The gateway fails closed on them (δ = 0); a test of what the cell does on an idle machine may
tolerate them where it checks that every status showing one commanded δ = 0 (:func:`late_data_only`)."""

MAX_LOAD_SCALE = 4.0
"""A wait is stretched by the machine's load per core, up to this factor (:func:`load_scale`)."""

STOP_TIMEOUT_S = 10.0
"""How long :func:`stop_program` waits for a program to exit after the signal [s]."""


class BenchError(HrcError, RuntimeError):
    """A benchmark could not run (a program did not start, a configuration did not round-trip)."""


class StartupError(BenchError):
    """The programs did not come up, or a condition was not reached in time (e.g. a free port was taken
    meanwhile): worth one more try for a benchmark."""


START_ATTEMPTS = 3


class HttpReply(NamedTuple):
    """An HTTP answer: its status code and body."""

    status_code: int
    content: bytes
    headers: dict[str, str] = {}  # noqa: RUF012 (a NamedTuple default, never mutated)
    """Response headers, names in lower case."""

    @property
    def text(self) -> str:
        """The body as UTF-8 text."""
        return self.content.decode("utf-8", errors="replace")

    def json(self) -> Any:
        """The body as JSON (raises ``ValueError`` if it is not)."""
        return json.loads(self.content)


def http_get(url: str, timeout_s: float) -> HttpReply:
    """GET ``url``; an HTTP error status is an answer, a network failure raises :class:`OSError`."""
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:
            headers = {k.lower(): v for k, v in response.headers.items()}
            return HttpReply(response.status, response.read(), headers)
    except urllib.error.HTTPError as exc:
        return HttpReply(exc.code, exc.read(), {k.lower(): v for k, v in exc.headers.items()})


def with_retries(run: Callable[[], T], what: str, attempts: int = START_ATTEMPTS) -> T:
    """``run()``, tried again (with new ports, since ``run`` picks them) when the programs did not start."""
    for attempt in range(1, attempts + 1):
        try:
            return run()
        except StartupError as exc:
            if attempt == attempts:
                raise
            first_line = str(exc).splitlines()[0]
            print(f"    {what}: start-up failed ({first_line}); trying again ({attempt + 1}/{attempts})")
    raise AssertionError("unreachable")


# -- loopback addresses ---------------------------------------------------------------------------


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago (another process may take it before it is used)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def free_udp_port() -> int:
    """A free UDP port on 127.0.0.1 (a vendor face's, e.g. ABB EGM's PC)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def free_endpoint() -> str:
    """A Zenoh endpoint on a free loopback port, e.g. ``tcp/127.0.0.1:40123``."""
    return f"tcp/127.0.0.1:{free_port()}"


# -- temporary configuration ----------------------------------------------------------------------

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a valid TOML basic string
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise BenchError(f"cannot write {type(value).__name__} {value!r} as TOML")


def _toml_key(key: str) -> str:
    return key if _BARE_KEY.fullmatch(key) else json.dumps(key)


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list) and bool(value) and all(isinstance(v, dict) for v in value)


def _toml_table(prefix: str, table: dict[str, Any], out: list[str]) -> None:
    # Keys of a table come before its sub-tables; None means "not set" (the default applies).
    for key, value in table.items():
        if value is not None and not isinstance(value, dict) and not _is_table_array(value):
            out.append(f"{_toml_key(key)} = {_toml_value(value)}")
    for key, value in table.items():
        name = f"{prefix}.{_toml_key(key)}" if prefix else _toml_key(key)
        if isinstance(value, dict):
            out.append(f"\n[{name}]")
            _toml_table(name, value, out)
        elif _is_table_array(value):
            for item in value:
                out.append(f"\n[[{name}]]")
                _toml_table(name, item, out)


def write_cell_config(config: CellConfig, path: Path) -> Path:
    """Write ``config`` as a self-contained cell file (absolute paths, robot models inline) and check it
    loads back to the same configuration.

    Raises:
        BenchError: the written file does not load back to ``config``.
    """
    lines: list[str] = ["# Written by hrc_tools.cell.procs: a temporary copy of a cell configuration."]
    _toml_table("", config.model_dump(mode="json"), lines)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    try:
        loaded = load_cell_config(path)
    except ConfigError as exc:
        raise BenchError(f"the temporary configuration {path} does not load: {exc}") from None
    if loaded != config:
        raise BenchError(f"the temporary configuration {path} does not load back to the same configuration")
    return path


def with_gateway_rate(
    config: CellConfig, rate_hz: float, http_port: int | None = None, event_driven: bool | None = None
) -> CellConfig:
    """``config`` with ``gateway.rate_hz`` (and the HTTP port, and ``gateway.event_driven``) changed, validated."""
    update: dict[str, Any] = {"rate_hz": rate_hz}
    if http_port is not None:
        update["http_port"] = http_port
    if event_driven is not None:
        update["event_driven"] = event_driven
    gateway = config.gateway.model_validate({**config.gateway.model_dump(), **update})
    return config.model_copy(update={"gateway": gateway})


# -- programs -------------------------------------------------------------------------------------


@contextmanager
def unsafe_test_settings(*settings: str) -> Iterator[None]:
    """Within the block, this process and the programs it starts accept the named test-only settings (they are
    refused unless ``HRC_ALLOW_UNSAFE`` names them); the environment is restored after."""
    before = os.environ.get(UNSAFE_ENV_VAR)
    os.environ[UNSAFE_ENV_VAR] = ",".join(filter(None, (before, *settings)))
    try:
        yield
    finally:
        if before is None:
            del os.environ[UNSAFE_ENV_VAR]
        else:
            os.environ[UNSAFE_ENV_VAR] = before


def program_env(plain_tcp: bool = True) -> dict[str, str]:
    """This process's environment for a program, its output unbuffered; ``plain_tcp``: plain TCP on loopback
    allowed (development), else without ``HRC_INSECURE_PLAIN_TCP`` (the program must use TLS)."""
    env = {k: v for k, v in os.environ.items() if k != PLAIN_TCP_ENV_VAR} | {"PYTHONUNBUFFERED": "1"}
    return (env | {PLAIN_TCP_ENV_VAR: "1"}) if plain_tcp else env


def start_program(
    module: str, args: Sequence[str], log_path: Path, env: Mapping[str, str] | None = None, wrapper: Sequence[str] = ()
) -> Program:
    """Start ``python -m module args`` from the repository root, stdout and stderr appended to ``log_path``.

    ``env``: its environment (default: :func:`program_env`); ``wrapper``: the command that runs it (e.g.
    ``ip netns exec NS``). Every program of every benchmark and test is started here: options that all of
    them need (e.g. the certificates of a secured Zenoh link) belong in this function only.
    """
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with log_path.open("ab") as log:  # the child keeps its own copy of the descriptor
        return subprocess.Popen(
            [*wrapper, sys.executable, "-m", module, *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            env=program_env() if env is None else dict(env),
        )


def stop_program(
    proc: Program, sig: int = signal.SIGINT, timeout_s: float = STOP_TIMEOUT_S, abort_s: float = 0.0
) -> int:
    """Send ``sig`` (after SIGCONT, in case the program was frozen) and return its exit code.

    ``abort_s`` > 0: a program still running after ``timeout_s`` gets SIGABRT and that long before it is
    killed (under ``PYTHONFAULTHANDLER=1`` it writes every thread's stack to its log: where it hangs).

    Raises:
        subprocess.TimeoutExpired: it did not exit within ``timeout_s``; it has been killed (this process only).
    """
    if proc.poll() is None:
        proc.send_signal(signal.SIGCONT)
        proc.send_signal(sig)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        if abort_s > 0.0:
            proc.send_signal(signal.SIGABRT)
            with suppress(subprocess.TimeoutExpired):
                proc.wait(abort_s)
        proc.kill()
        proc.wait()
        raise


def stop_all(procs: Iterable[Program]) -> None:
    """Stop each program, last started first; one that hangs is killed and the others are still stopped."""
    for proc in reversed(list(procs)):
        with suppress(subprocess.TimeoutExpired, ProcessLookupError):
            stop_program(proc)


@contextmanager
def programs(specs: Sequence[tuple[str, Sequence[str], Path]]) -> Iterator[list[Program]]:
    """Start each ``(module, args, log)`` in order; stop them in reverse order afterwards."""
    procs: list[Program] = []
    try:
        for module, args, log in specs:
            procs.append(start_program(module, args, log))
        yield procs
    finally:
        stop_all(procs)


def late_data_only(statuses: Sequence[Status]) -> list[str]:
    """The faults in ``statuses`` (robot statuses) that a busy machine does not explain, and any status that showed a
    fault with δ > 0: empty when every fault was late data (:data:`LATE_DATA_FAULTS`) and the gateway failed closed.
    """
    problems = {
        f"{f['code']}: {f['reason']}" for s in statuses for f in s["faults"] if f["code"] not in LATE_DATA_FAULTS
    }
    problems |= {
        f"δ = {s['delta']} with faults {[f['code'] for f in s['faults']]}"
        for s in statuses
        if s["faults"] and s["delta"] > 0.0
    }
    return sorted(problems)


def refused_tracker_frames(inputs: dict[str, Any]) -> dict[str, dict[str, int]]:
    """The tracker frames the gateway refused, per topic and reason, from a status document's ``inputs``: every
    rejection but ``rate_exceeded``, which a busy machine explains (a held-up burst beyond the door's budget,
    ``gateway.inputs.FrameBudget``); a forged or broken frame within the budget is refused with its reason."""
    refused = {
        topic: {reason: n for reason, n in reasons.items() if reason != "rate_exceeded"}
        for topic, reasons in inputs["rejected"].items()
        if topic.startswith("tracker/")
    }
    return {topic: reasons for topic, reasons in refused.items() if reasons}


def recovered(status: Status) -> bool:
    """Whether a robot's status shows operation resumed after a fault: no fault, and the robot moving (δ > 0, the
    controller running), or held by its zone for a reason the status itself shows: a safety exception ends only
    beyond ``thresholds_m.resume_m``, which grows with the measured delay, so on a busy machine (longer delays) a
    person who stands just beyond it when idle keeps the robot stopped, as the safety function demands (the
    controller then holds δ = 0: ``stopped``, or still ramping down; never its own ``protective_stop``).
    """
    if status["faults"]:
        return False
    if status["delta"] > 0.0:
        return bool(status["controller_mode"] == "running")
    distance_m = status["min_distance_m"]
    return (
        status["controller_mode"] in ("running", "stopped")
        and status["zone"] == "safety_exception"
        and distance_m is not None
        and distance_m < status["thresholds_m"]["resume_m"]
    )


def load_scale(load_per_core: float | None = None) -> float:
    """How much longer than on an idle machine a wait may take here: the 1-minute load average per core, between 1
    and :data:`MAX_LOAD_SCALE` (a start-up that takes 10 s idle takes about 40 s at a load of 8 on 2 cores, where the
    programs get a quarter of a core each). ``load_per_core``: the figure to scale by instead of this machine's."""
    if load_per_core is None:
        try:
            load_per_core = os.getloadavg()[0] / max(1, os.cpu_count() or 1)
        except OSError:  # no load average on this platform
            load_per_core = 1.0
    if not math.isfinite(load_per_core):
        return MAX_LOAD_SCALE
    return min(MAX_LOAD_SCALE, max(1.0, load_per_core))


def scenario_window_s(loop_s: float) -> float:
    """How long to record a looping scenario for its whole sequence to show [s]: two loops, stretched by
    :func:`load_scale`. On a loaded machine the cell may be ready only after the person's first approach began, so one
    loop from then can miss the sequence's start; record with an ``until`` that ends as soon as it is seen."""
    return 2.0 * loop_s * load_scale()


def wait_for(predicate: Callable[[], bool], timeout_s: float, what: str, procs: Sequence[Program] = ()) -> float:
    """Evaluate ``predicate`` every :data:`POLL_S` until it holds; return how long that took [s].

    ``timeout_s`` is what the wait may take on an idle machine; it is stretched by :func:`load_scale`, read again at
    every poll (a machine that becomes busy while a program starts extends the deadline, never shortens it).

    Raises:
        StartupError: the stretched timeout passed, or one of ``procs`` exited meanwhile.
    """
    start_s = time.monotonic()
    scale = load_scale()
    while time.monotonic() < start_s + timeout_s * scale:
        if predicate():
            return time.monotonic() - start_s
        for proc in procs:
            if proc.poll() is not None:
                raise StartupError(f"{describe(proc)} exited with code {proc.returncode} ({what})")
        time.sleep(POLL_S)
        scale = max(scale, load_scale())
    waited_s = time.monotonic() - start_s
    raise StartupError(
        f"timed out after {waited_s:.1f} s waiting for {what} ({timeout_s} s on an idle machine, × {scale:.2f} for "
        "the load)"
    )


def wait_or_fail(
    predicate: Callable[[], bool],
    timeout_s: float,
    what: str,
    logs: Iterable[Path] = (),
    procs: Sequence[Program] = (),
) -> float:
    """:func:`wait_for` in a test: waiting in vain fails the test with the end of every log.

    Raises:
        AssertionError: ``timeout_s`` passed, or one of ``procs`` exited meanwhile.
    """
    try:
        return wait_for(predicate, timeout_s, what, procs)
    except StartupError as exc:
        raise AssertionError(f"{exc}\n{logs_tail(logs)}") from None


def describe(proc: Program) -> str:
    """``python -m <module>`` of a program started by :func:`start_program`."""
    args = [str(a) for a in proc.args] if isinstance(proc.args, list | tuple) else [str(proc.args)]
    return " ".join(args[1:3]) if len(args) >= 3 else " ".join(args)


def exited_programs(procs: Sequence[Program], logs: Sequence[Path]) -> str | None:
    """A description (with the end of its log) of the first program that has exited, None if all run."""
    for proc, log in zip(procs, logs, strict=True):
        if proc.poll() is not None:
            return f"{describe(proc)} exited with code {proc.returncode}:\n{log_tail(log)}"
    return None


def log_tail(path: Path, lines: int = 10) -> str:
    """The last ``lines`` lines of a log ('' if it cannot be read)."""
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""


def logs_tail(logs: Iterable[Path], lines: int = 15) -> str:
    """The last ``lines`` lines of each log, headed by its name."""
    return "\n".join(f"--- {path.stem} ---\n{log_tail(path, lines)}" for path in logs)


# -- a whole cell ---------------------------------------------------------------------------------


@dataclass
class Cell:
    """A running cell: the programs (by name: gateway, controller, tracker[, tracker-2 ...][, relay][, bridge]) and
    where to reach them."""

    procs: dict[str, Program]
    commands: dict[str, tuple[str, list[str]]]
    http_port: int
    gateway_endpoint: str
    controller_endpoint: str
    logs: dict[str, Path] = field(default_factory=dict)
    name: str = "demo"
    relay_endpoint: str = ""
    tracker_relay_endpoint: str = ""
    """Where the tracker relay's side A listens (``running_cell(tracker_relay=...)`` only)."""
    bridge_endpoint: str = ""
    """Where the controller bridge listens (a robot behind a bridge only): its joint states come from there."""
    envs: dict[str, dict[str, str]] = field(default_factory=dict)
    """A program's own environment (by name; default :func:`program_env`)."""

    @property
    def gateway(self) -> Program:
        return self.procs["gateway"]

    @property
    def controller(self) -> Program:
        return self.procs["controller"]

    @property
    def tracker(self) -> Program:
        return self.procs["tracker"]

    @property
    def bridge(self) -> Program:
        return self.procs["bridge"]

    def start(self, name: str) -> Program:
        """(Re)start a program with its original command line; its log is appended to."""
        module, args = self.commands[name]
        self.procs[name] = start_program(module, args, self.logs[name], self.envs.get(name))
        return self.procs[name]

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}"

    def get(self, path: str) -> HttpReply:
        return http_get(self.base_url + path, timeout_s=10.0)

    def robot(self, name: str = "ur5") -> Status | None:
        """The robot's status from the REST API, None while the gateway does not answer."""
        try:
            response = self.get(f"/api/v1/robots/{name}")
        except OSError:
            return None
        if response.status_code != 200:
            return None
        status: Status = RobotStatusResponse.model_validate_json(response.content).model_dump(mode="json")
        return status

    def wait(self, condition: Callable[[], bool], timeout_s: float, what: str) -> None:
        """:func:`wait_for` ``condition``; a test that waits in vain fails with the end of every log.

        Raises:
            AssertionError: ``timeout_s`` passed (the test using the cell fails).
        """
        wait_or_fail(condition, timeout_s, what, self.logs.values())

    def wait_until(
        self, predicate: Callable[[Status], bool], timeout_s: float, what: str, robot: str = "ur5"
    ) -> Status:
        """Wait until the robot's status satisfies ``predicate``; return that status.

        Raises:
            AssertionError: ``timeout_s`` passed; the message holds the last status and the end of every log.
        """
        last: Status | None = None
        matched: list[Status] = []

        def holds() -> bool:
            nonlocal last
            last = self.robot(robot)
            if last is not None and predicate(last):
                matched.append(last)
            return bool(matched)

        try:
            wait_for(holds, timeout_s, what)
        except StartupError as exc:
            raise AssertionError(f"{exc}; last status: {last}\n{self.tail()}") from None
        return matched[0]

    def tail(self, lines: int = 15) -> str:
        return logs_tail(self.logs.values(), lines)


@contextmanager
def running_cell(
    tmp_path: Path,
    config: Path | None = None,
    scenario: str | None = None,
    seed: int = 0,
    trackers: list[list[str]] | None = None,
    controller_relay: list[str] | None = None,
    face: list[str] | None = None,
    tracker_relay: list[str] | None = None,
) -> Iterator[Cell]:
    """Start gateway, controller emulator and tracker emulator(s); stop them with SIGINT afterwards.

    ``trackers``: extra arguments of each tracker emulator process (default: one process, all trackers).
    ``controller_relay``: if given, the controller reaches the gateway only through ``hrc-fault-relay``
    (these are its extra arguments); the relay's side A listens on ``cell.relay_endpoint``. ``tracker_relay``: the
    same for the tracker(s) (program ``relay-tracker``, side A on ``cell.tracker_relay_endpoint``).

    A cell whose (only) robot has a bridged ``interface`` (``ur_rtde``, ``abb_rws``) is run as ``hrc-cell`` runs it:
    the emulator serves the vendor's face and program ``bridge`` (``hrc-controller-bridge``, listening on
    ``cell.bridge_endpoint``) joins it to the gateway; the relay, if any, then sits between bridge and gateway, and
    the emulator (its ground truth only) connects to the gateway directly. ``face``: the emulator's vendor face
    options instead of the interface's (a test serves the face elsewhere and relays the bridge's TCP to it).
    """
    gw_ep, ctrl_ep, relay_ep, http_port = free_endpoint(), free_endpoint(), free_endpoint(), free_port()
    cfg = ["--config", str(config)] if config else []
    scenario_args = ["--scenario", scenario] if scenario else []
    commands = {"gateway": ("gateway", [*cfg, "--zenoh-listen", gw_ep, "--http-port", str(http_port)])}
    if controller_relay is not None:
        commands["relay"] = ("hrc_tools.faultinject", ["--a-listen", relay_ep, "--b-connect", gw_ep, *controller_relay])
    upstream = relay_ep if controller_relay is not None else gw_ep
    tracker_relay_ep = free_endpoint() if tracker_relay is not None else ""
    if tracker_relay is not None:
        commands["relay-tracker"] = (
            "hrc_tools.faultinject",
            ["--a-listen", tracker_relay_ep, "--b-connect", gw_ep, *tracker_relay],
        )
    tracker_upstream = tracker_relay_ep or gw_ep
    loaded = load_cell_config(config)
    bridged = [name for name, robot in loaded.robots.items() if robot.interface.kind != "zenoh"]
    envs: dict[str, dict[str, str]] = {}
    bridge_ep = ""
    if bridged:
        if len(loaded.robots) != 1:
            raise BenchError(f"running_cell bridges a cell of one robot only; {config} has {sorted(loaded.robots)}")
        robot = bridged[0]
        bridge_ep = free_endpoint()
        face = vendor_face_args(loaded.robots[robot]) if face is None else face
        commands["controller"] = ("controller_emu", [*cfg, "--zenoh-listen", ctrl_ep, "--zenoh-connect", gw_ep, *face])
        bridge_args = [*cfg, "--robot", robot, "--zenoh-listen", bridge_ep, "--zenoh-connect", upstream]
        commands["bridge"] = ("controller_bridge", bridge_args)
        envs["bridge"] = bridge_environment(loaded, program_env())
    else:
        commands["controller"] = ("controller_emu", [*cfg, "--zenoh-listen", ctrl_ep, "--zenoh-connect", upstream])
    for i, extra in enumerate(trackers or [[]]):
        name = "tracker" if i == 0 else f"tracker-{i + 1}"
        args = [*cfg, "--zenoh-connect", tracker_upstream, "--seed", str(seed + i), *scenario_args, *extra]
        commands[name] = ("tracker_emu", args)
    logs = {name: tmp_path / f"{name}.log" for name in commands}
    cell = Cell(
        {},
        commands,
        http_port,
        gw_ep,
        ctrl_ep,
        logs,
        name=loaded.cell,
        relay_endpoint=relay_ep,
        tracker_relay_endpoint=tracker_relay_ep,
        bridge_endpoint=bridge_ep,
        envs=envs,
    )
    try:
        for name in commands:
            cell.start(name)
        yield cell
    finally:
        stop_all(cell.procs.values())


def record(
    cell: Cell,
    duration_s: float,
    robot: str = "ur5",
    until: Callable[[list[Status]], bool] | None = None,
) -> list[Status]:
    """Every status document the gateway publishes on Zenoh (25 Hz) for ``duration_s``, or until ``until(trace)``.

    Each entry is the robot's status with ``t_s`` (seconds since the start of the recording) and ``document_stamp_ns``
    (the status document's own stamp: a gap between two entries' stamps is time the trace did not see).
    """
    trace: list[Status] = []
    lock = threading.Lock()
    start = time.monotonic()

    def on_status(sample: zenoh.Sample) -> None:
        doc = GatewayStatus.model_validate_json(sample.payload.to_bytes())  # raises (drops it) if not the contract
        with lock:
            entry = {**doc.robots[robot].model_dump(mode="json"), "t_s": time.monotonic() - start}
            trace.append({**entry, "document_stamp_ns": doc.stamp_ns})

    with zenoh.open(session_config(connect=[cell.gateway_endpoint])) as session:
        session.declare_subscriber(keys.gateway_status(cell.name), on_status)
        while time.monotonic() - start < duration_s:
            time.sleep(0.1)
            with lock:
                if until is not None and until(trace):
                    break
    with lock:
        return list(trace)


def collapse(values: Sequence[str]) -> list[str]:
    """Consecutive duplicates removed: the sequence of distinct states."""
    out: list[str] = []
    for v in values:
        if not out or out[-1] != v:
            out.append(v)
    return out


def is_subsequence(needle: Sequence[str], haystack: Sequence[str]) -> bool:
    """True if ``needle`` occurs in ``haystack`` in order, not necessarily contiguously."""
    it = iter(haystack)
    return all(any(x == y for y in it) for x in needle)
