"""The real programs as subprocesses on loopback, and temporary cell configurations for them."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Any, TypeVar

from hrc_common.config import REPO_ROOT, CellConfig, ConfigError, load_cell_config
from hrc_common.errors import HrcError

T = TypeVar("T")


class BenchError(HrcError, RuntimeError):
    """A benchmark could not run (a program did not start, a configuration did not round-trip)."""


class StartupError(BenchError):
    """The programs of a run did not come up (e.g. a free port was taken meanwhile): worth one more try."""


START_ATTEMPTS = 3


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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


# -- configuration ------------------------------------------------------------------------------

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
    lines: list[str] = ["# Written by bench/: a temporary copy of a cell configuration."]
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


# -- programs -----------------------------------------------------------------------------------


def start_program(module: str, args: list[str], log_path: Path) -> subprocess.Popen[bytes]:
    """Start ``python -m module args`` from the repository root, output to ``log_path``."""
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with log_path.open("wb") as log:
        return subprocess.Popen(
            [sys.executable, "-m", module, *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            cwd=REPO_ROOT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )


def stop_program(proc: subprocess.Popen[bytes], timeout_s: float = 10.0) -> int:
    """SIGINT, then wait; killed (this process only) if it does not end in time."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
    try:
        return proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


@contextmanager
def programs(specs: list[tuple[str, list[str], Path]]) -> Iterator[list[subprocess.Popen[bytes]]]:
    """Start each ``(module, args, log)`` in order; stop them in reverse order afterwards."""
    with ExitStack() as stack:
        procs = []
        for module, args, log in specs:
            proc = start_program(module, args, log)
            stack.callback(stop_program, proc)
            procs.append(proc)
        yield procs


def wait_for(predicate: Callable[[], bool], timeout_s: float, what: str, procs: list[subprocess.Popen[bytes]]) -> None:
    """Poll ``predicate`` every 50 ms.

    Raises:
        StartupError: ``timeout_s`` passed, or one of ``procs`` exited meanwhile.
    """
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return
        for proc in procs:
            if proc.poll() is not None:
                raise StartupError(f"{describe(proc)} exited with code {proc.returncode} ({what})")
        time.sleep(0.05)
    raise StartupError(f"timed out after {timeout_s} s waiting for {what}")


def describe(proc: subprocess.Popen[bytes]) -> str:
    """``python -m <module>`` of a program started by :func:`start_program`."""
    args = [str(a) for a in proc.args] if isinstance(proc.args, list | tuple) else [str(proc.args)]
    return " ".join(args[1:3]) if len(args) >= 3 else " ".join(args)


def exited_programs(procs: list[subprocess.Popen[bytes]], logs: list[Path]) -> str | None:
    """A description (with the end of its log) of the first program that has exited, None if all run."""
    for proc, log in zip(procs, logs, strict=True):
        if proc.poll() is not None:
            return f"{describe(proc)} exited with code {proc.returncode}:\n{log_tail(log)}"
    return None


def log_tail(path: Path, lines: int = 10) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return ""
