"""Helpers for end-to-end tests: start the real programs as subprocesses on loopback, watch the REST API."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import httpx
import zenoh

from hrc_common import keys
from hrc_common.status_models import GatewayStatus, RobotStatusResponse
from hrc_common.zenoh_session import session_config

REPO_ROOT = Path(__file__).resolve().parents[1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_program(module: str, args: list[str], log_path: Path) -> subprocess.Popen[bytes]:
    log = log_path.open("ab")
    return subprocess.Popen(
        [sys.executable, "-m", module, *args],
        stdout=log,
        stderr=subprocess.STDOUT,
        cwd=REPO_ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )


def stop_program(proc: subprocess.Popen[bytes], sig: int = signal.SIGINT, timeout_s: float = 10.0) -> int:
    if proc.poll() is None:
        proc.send_signal(sig)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        raise


@dataclass
class Cell:
    """A running cell: the programs (by name: gateway, controller, tracker[, tracker-2 ...]) and where to reach them."""

    procs: dict[str, subprocess.Popen[bytes]]
    commands: dict[str, tuple[str, list[str]]]
    http_port: int
    gateway_endpoint: str
    controller_endpoint: str
    logs: dict[str, Path] = field(default_factory=dict)
    name: str = "demo"
    relay_endpoint: str = ""

    @property
    def gateway(self) -> subprocess.Popen[bytes]:
        return self.procs["gateway"]

    @property
    def controller(self) -> subprocess.Popen[bytes]:
        return self.procs["controller"]

    @property
    def tracker(self) -> subprocess.Popen[bytes]:
        return self.procs["tracker"]

    def start(self, name: str) -> subprocess.Popen[bytes]:
        """(Re)start a program with its original command line; its log is appended to."""
        module, args = self.commands[name]
        self.procs[name] = start_program(module, args, self.logs[name])
        return self.procs[name]

    @property
    def base_url(self) -> str:
        return f"http://127.0.0.1:{self.http_port}"

    def get(self, path: str) -> httpx.Response:
        return httpx.get(self.base_url + path, timeout=10.0)

    def robot(self, name: str = "ur5") -> dict[str, Any] | None:
        try:
            response = self.get(f"/api/v1/robots/{name}")
        except httpx.HTTPError:
            return None
        if response.status_code != 200:
            return None
        return RobotStatusResponse.model_validate_json(response.content).model_dump(mode="json")

    def wait_until(self, predicate: Any, timeout_s: float, what: str, robot: str = "ur5") -> dict[str, Any]:
        deadline = time.monotonic() + timeout_s
        last = None
        while time.monotonic() < deadline:
            last = self.robot(robot)
            if last is not None and predicate(last):
                return last
            time.sleep(0.05)
        raise AssertionError(f"timed out after {timeout_s} s waiting for {what}; last status: {last}\n{self.tail()}")

    def tail(self, lines: int = 15) -> str:
        out = []
        for name, path in self.logs.items():
            text = path.read_text(errors="replace").splitlines()[-lines:]
            out.append(f"--- {name} ---\n" + "\n".join(text))
        return "\n".join(out)


@contextmanager
def running_cell(
    tmp_path: Path,
    config: Path | None = None,
    scenario: str | None = None,
    seed: int = 0,
    trackers: list[list[str]] | None = None,
    controller_relay: list[str] | None = None,
) -> Iterator[Cell]:
    """Start gateway, controller emulator and tracker emulator(s); stop them with SIGINT afterwards.

    ``trackers``: extra arguments of each tracker emulator process (default: one process, all trackers).
    ``controller_relay``: if given, the controller reaches the gateway only through ``hrc-fault-relay``
    (these are its extra arguments); the relay's side A listens on ``cell.relay_endpoint``.
    """
    gw_port, ctrl_port, http_port = free_port(), free_port(), free_port()
    gw_ep, ctrl_ep = f"tcp/127.0.0.1:{gw_port}", f"tcp/127.0.0.1:{ctrl_port}"
    cfg = ["--config", str(config)] if config else []
    scenario_args = ["--scenario", scenario] if scenario else []
    relay_ep = f"tcp/127.0.0.1:{free_port()}"
    commands = {"gateway": ("gateway.main", [*cfg, "--zenoh-listen", gw_ep, "--http-port", str(http_port)])}
    if controller_relay is not None:
        commands["relay"] = ("faultinject.relay", ["--a-listen", relay_ep, "--b-connect", gw_ep, *controller_relay])
    upstream = relay_ep if controller_relay is not None else gw_ep
    commands["controller"] = ("controller_emu.main", [*cfg, "--zenoh-listen", ctrl_ep, "--zenoh-connect", upstream])
    for i, extra in enumerate(trackers or [[]]):
        name = "tracker" if i == 0 else f"tracker-{i + 1}"
        args = [*cfg, "--zenoh-connect", gw_ep, "--seed", str(seed + i), *scenario_args, *extra]
        commands[name] = ("tracker_emu.main", args)
    logs = {name: tmp_path / f"{name}.log" for name in commands}
    cell = Cell({}, commands, http_port, gw_ep, ctrl_ep, logs, relay_endpoint=relay_ep)
    for name in commands:
        cell.start(name)
    try:
        yield cell
    finally:
        for proc in reversed(cell.procs.values()):
            with suppress(subprocess.TimeoutExpired, ProcessLookupError):
                if proc.poll() is None:
                    proc.send_signal(signal.SIGCONT)
                stop_program(proc)


def record(
    cell: Cell,
    duration_s: float,
    robot: str = "ur5",
    until: Callable[[list[dict[str, Any]]], bool] | None = None,
) -> list[dict[str, Any]]:
    """Every status document the gateway publishes on Zenoh (25 Hz) for ``duration_s``, or until ``until(trace)``.

    Each entry is the robot's status with ``t_s`` (seconds since the start of the recording).
    """
    trace: list[dict[str, Any]] = []
    lock = threading.Lock()
    start = time.monotonic()

    def on_status(sample: zenoh.Sample) -> None:
        doc = GatewayStatus.model_validate_json(sample.payload.to_bytes())  # raises (drops it) if not the contract
        with lock:
            trace.append({**doc.robots[robot].model_dump(mode="json"), "t_s": time.monotonic() - start})

    with zenoh.open(session_config(connect=[cell.gateway_endpoint])) as session:
        session.declare_subscriber(keys.gateway_status(cell.name), on_status)
        while time.monotonic() - start < duration_s:
            time.sleep(0.1)
            with lock:
                if until is not None and until(trace):
                    break
    with lock:
        return list(trace)


def collapse(values: list[str]) -> list[str]:
    """Consecutive duplicates removed: the sequence of distinct states."""
    out: list[str] = []
    for v in values:
        if not out or out[-1] != v:
            out.append(v)
    return out


def is_subsequence(needle: list[str], haystack: list[str]) -> bool:
    it = iter(haystack)
    return all(any(x == y for y in it) for x in needle)
