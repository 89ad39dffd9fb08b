"""The systemd units work from a ``pip install``, not only from a checkout (issue 18).

No systemd runs here (no PID 1 of it in a container), so the test does what the units say, literally: the project
is ``pip install``-ed (no checkout on the path: ``--target`` a folder, the console scripts in its ``bin/``), the
configuration is a copy of ``configs/`` in a folder standing for ``/etc/hrc-gateway``, and each unit's
``Environment=``, ``ExecStartPre=`` and ``ExecStart=`` lines run with systemd's specifiers (``%E``, ``%S``, ``%C``,
``%i``) replaced, from an empty working folder, in a network namespace of their own (the units' fixed ports
cannot collide with anything else running). Done when the gateway's ``/readyz`` answers 200 with the controller
and the tracker started by their units, and every program exits 0 on SIGTERM (systemd's stop); once for the default
cell, once for a UR behind ``hrc-controller-bridge@.service`` (the emulator serving RTDE through a drop-in's
``HRC_CONTROLLER_ARGS``).

Needs root and ``ip`` (iproute2): skipped with the reason otherwise.
"""

from __future__ import annotations

import os
import shlex
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Iterator
from contextlib import suppress
from pathlib import Path

import pytest
from support.paths import REPO_ROOT

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.skipif(os.geteuid() != 0, reason="network namespaces need root"),
    pytest.mark.skipif(shutil.which("ip") is None, reason="ip (iproute2) is not installed"),
]

UNITS_DIR = REPO_ROOT / "deploy" / "systemd"
INSTALLED_BIN = "/opt/hrc-gateway/.venv/bin/"
PACKAGES = tuple(
    pattern.rstrip("*")
    for pattern in tomllib.loads((REPO_ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]["find"][
        "include"
    ]
)
"""The project's import names, as the wheel is told to find them: every one must come from the install."""
READY_TIMEOUT_S = 150.0  # the first start compiles the kernels (numba) into the unit's cache folder
STOP_TIMEOUT_S = 20.0


def _service_lines(unit: str, key: str) -> list[str]:
    """Every value of ``key`` in the unit's [Service] section."""
    values: list[str] = []
    section = ""
    for raw in (UNITS_DIR / unit).read_text().splitlines():
        line = raw.strip()
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1]
        elif section == "Service" and line.startswith(f"{key}="):
            values.append(line.partition("=")[2])
    return values


def _specifiers(text: str, root: Path, bin_dir: Path, instance: str) -> str:
    """systemd's specifiers of a system unit, with ``root`` standing for ``/``."""
    return (
        text.replace(INSTALLED_BIN, f"{bin_dir}/")
        .replace("%E", str(root / "etc"))
        .replace("%S", str(root / "var/lib"))
        .replace("%C", str(root / "var/cache"))
        .replace("%i", instance)
    )


def _unit_env(unit: str, root: Path, bin_dir: Path, site: Path, instance: str) -> dict[str, str]:
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "PYTHONPATH": str(site), "LANG": "C.UTF-8"}
    for assignment in _service_lines(unit, "Environment"):
        name, _, value = _specifiers(assignment, root, bin_dir, instance).partition("=")
        env[name] = value.strip('"')
    return env


def _unit_command(unit: str, key: str, root: Path, bin_dir: Path, instance: str, env: dict[str, str]) -> list[str]:
    (line,) = _service_lines(unit, key)
    words = shlex.split(_specifiers(line, root, bin_dir, instance))
    # systemd expands $NAME to the variable's words (an empty one to none)
    return [w for word in words for w in (env.get(word[1:], "").split() if word.startswith("$") else [word])]


@pytest.fixture(scope="module")
def pip_installed(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The project as ``pip install`` puts it: built from a copy of the sources, into a folder of its own."""
    src = tmp_path_factory.mktemp("src")
    shutil.copy(REPO_ROOT / "pyproject.toml", src)
    for package in PACKAGES:
        shutil.copytree(REPO_ROOT / package, src / package, ignore=shutil.ignore_patterns("__pycache__"))
    site = tmp_path_factory.mktemp("site")
    done = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", "--target", site, src],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return site


@pytest.fixture
def netns() -> Iterator[str]:
    name = f"hrcunits{os.getpid()}"
    subprocess.run(["ip", "netns", "add", name], check=True, timeout=10)
    try:
        subprocess.run(["ip", "netns", "exec", name, "ip", "link", "set", "lo", "up"], check=True, timeout=10)
        yield name
    finally:
        for pid in subprocess.run(["ip", "netns", "pids", name], capture_output=True, text=True).stdout.split():
            with suppress(ProcessLookupError, ValueError):
                os.kill(int(pid), signal.SIGKILL)
        subprocess.run(["ip", "netns", "del", name], timeout=10)


def _http_status(netns: str, env: dict[str, str], url: str) -> int:
    probe = (
        "import sys, urllib.request, urllib.error\n"
        "try:\n"
        f"    print(urllib.request.urlopen({url!r}, timeout=2).status)\n"
        "except urllib.error.HTTPError as e:\n"
        "    print(e.code)\n"
        "except OSError:\n"
        "    print(0)\n"
    )
    done = subprocess.run(
        ["ip", "netns", "exec", netns, sys.executable, "-c", probe], capture_output=True, text=True, env=env, timeout=20
    )
    return int(done.stdout.strip() or 0)


def _tails(logs: list[Path]) -> str:
    return "\n".join(f"--- {p.name}\n{p.read_text(errors='replace')[-2500:]}" for p in logs if p.exists())


DEFAULT_UNITS = (
    ("hrc-gateway.service", "", {}),
    ("hrc-controller-emu@.service", "ur5", {}),
    ("hrc-tracker-emu.service", "", {}),
)
# the UR behind a bridge: the emulator serves RTDE (a drop-in's HRC_CONTROLLER_ARGS), the bridge unit drives it
BRIDGED_UNITS = (
    ("hrc-gateway.service", "", {}),
    ("hrc-controller-emu@.service", "ur5", {"HRC_CONTROLLER_ARGS": "--rtde 127.0.0.2"}),
    ("hrc-controller-bridge@.service", "ur5", {}),
    ("hrc-tracker-emu.service", "", {}),
)


@pytest.mark.parametrize(
    ("cell_file", "units"),
    [("cell.toml", DEFAULT_UNITS), ("cell_ur_rtde.toml", BRIDGED_UNITS)],
    ids=["zenoh", "ur_rtde"],
)
def test_the_units_run_the_cell_from_a_pip_install(
    pip_installed: Path,
    netns: str,
    tmp_path: Path,
    cell_file: str,
    units: tuple[tuple[str, str, dict[str, str]], ...],
) -> None:
    root = tmp_path / "root"
    shutil.copytree(REPO_ROOT / "configs", root / "etc" / "hrc-gateway")  # the operations guide's `cp -r configs/.`
    shutil.copy(REPO_ROOT / "configs" / cell_file, root / "etc" / "hrc-gateway" / "cell.toml")
    for folder in ("var/lib/hrc-gateway", "var/cache/hrc-gateway"):
        (root / folder).mkdir(parents=True)
    workdir = tmp_path / "empty"
    workdir.mkdir()
    bin_dir = pip_installed / "bin"

    env = _unit_env("hrc-gateway.service", root, bin_dir, pip_installed, "")
    where = subprocess.run(
        [sys.executable, "-c", f"import {', '.join(PACKAGES)}\nfor m in ({', '.join(PACKAGES)}): print(m.__file__)"],
        capture_output=True,
        text=True,
        env=env,
        cwd=workdir,
        timeout=60,
    )
    assert len(where.stdout.split()) == len(PACKAGES), where.stdout + where.stderr
    assert all(Path(p).is_relative_to(pip_installed) for p in where.stdout.split()), where.stdout + where.stderr

    pre = _unit_command("hrc-gateway.service", "ExecStartPre", root, bin_dir, "", env)
    done = subprocess.run(pre, capture_output=True, text=True, env=env, cwd=workdir, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr

    procs: list[subprocess.Popen[bytes]] = []
    logs: list[Path] = []
    try:
        for unit, instance, drop_in in units:
            unit_env = _unit_env(unit, root, bin_dir, pip_installed, instance) | drop_in
            command = _unit_command(unit, "ExecStart", root, bin_dir, instance, unit_env)
            logs.append(tmp_path / f"{unit.replace('@', '_')}.log")
            with logs[-1].open("wb") as log:
                procs.append(
                    subprocess.Popen(
                        ["ip", "netns", "exec", netns, *command],
                        stdout=log,
                        stderr=subprocess.STDOUT,
                        env=unit_env,
                        cwd=workdir,
                    )
                )
        deadline = time.monotonic() + READY_TIMEOUT_S
        status = 0
        while time.monotonic() < deadline and status != 200:
            assert all(p.poll() is None for p in procs), "a program exited:\n" + _tails(logs)
            status = _http_status(netns, env, "http://127.0.0.1:8080/readyz")
            time.sleep(0.5)
        assert status == 200, f"/readyz answered {status}:\n" + _tails(logs)
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)  # systemd's stop (KillMode=mixed: the main process)
        codes = []
        for p in procs:
            try:
                codes.append(p.wait(timeout=STOP_TIMEOUT_S))
            except subprocess.TimeoutExpired:
                p.kill()
                codes.append(None)
    assert codes == [0] * len(units), f"exit codes {codes}:\n" + _tails(logs)
