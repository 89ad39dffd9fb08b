"""What every benchmark reports: machine and load, percentiles, targets with PASS/MISS, a table, a JSON file."""

from __future__ import annotations

import datetime
import importlib.metadata
import json
import os
import platform
import subprocess
import sys
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

# bench/ is never installed: it runs from the checkout, so its own location is the checkout
REPO_ROOT = Path(__file__).resolve().parents[1]
OUT_DIR = REPO_ROOT / "out" / "bench"
"""Default folder of the JSON results (git-ignored)."""

PACKAGES = ("eclipse-zenoh", "pin", "coal", "numpy", "pydantic", "fastapi", "uvicorn", "httpx")


def default_json_path(name: str) -> Path:
    return OUT_DIR / f"{name}.json"


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def _git_commit() -> str | None:
    """The checked-out commit (read only), with ``+dirty`` when the working tree has changes."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=REPO_ROOT, capture_output=True, text=True, timeout=5
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            timeout=5,
        )
    except (OSError, subprocess.SubprocessError):
        return None
    if head.returncode != 0:
        return None
    return head.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")


def machine_info() -> dict[str, Any]:
    """CPU model, core counts, Python and the versions of the packages on the measured path."""
    versions: dict[str, str | None] = {}
    for package in PACKAGES:
        try:
            versions[package] = importlib.metadata.version(package)
        except importlib.metadata.PackageNotFoundError:
            versions[package] = None
    return {
        "cpu_model": _cpu_model(),
        "nproc": len(os.sched_getaffinity(0)),
        "cpu_count": os.cpu_count(),
        "python": sys.version.split()[0],
        "implementation": platform.python_implementation(),
        "platform": platform.platform(),
        "packages": versions,
        "git_commit": _git_commit(),
    }


def load_average() -> list[float]:
    """1, 5 and 15 minute load averages (other work on the machine skews every figure)."""
    return [round(x, 2) for x in os.getloadavg()]


def summary(values: Sequence[float] | np.ndarray, scale: float = 1.0, digits: int = 1) -> dict[str, float | int]:
    """n, mean, p50, p90, p95, p99, min, max of ``values × scale`` (e.g. ns → µs with scale 1e-3)."""
    x = np.asarray(values, dtype=float) * scale
    if x.size == 0:
        return {"n": 0}
    p50, p90, p95, p99 = np.percentile(x, [50, 90, 95, 99])
    return {
        "n": int(x.size),
        "mean": round(float(x.mean()), digits),
        "p50": round(float(p50), digits),
        "p90": round(float(p90), digits),
        "p95": round(float(p95), digits),
        "p99": round(float(p99), digits),
        "min": round(float(x.min()), digits),
        "max": round(float(x.max()), digits),
    }


@dataclass(frozen=True)
class Target:
    """A target and the figure measured against it: smaller is better (a time), unless ``at_least`` (a rate)."""

    name: str
    measured: float
    limit: float
    unit: str
    at_least: bool = False
    """The measured figure must reach ``limit`` (≥), instead of staying under it (≤)."""

    @property
    def verdict(self) -> str:
        ok = self.measured >= self.limit if self.at_least else self.measured <= self.limit
        return "PASS" if ok else "MISS"

    def as_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "measured": self.measured,
            "target": self.limit,
            "unit": self.unit,
            "at_least": self.at_least,
            "verdict": self.verdict,
        }

    @classmethod
    def from_dict(cls, doc: dict[str, Any]) -> Target:
        """The target of :meth:`as_dict` (a report's ``targets``; ``at_least`` false when absent)."""
        return cls(doc["name"], doc["measured"], doc["target"], doc["unit"], bool(doc.get("at_least", False)))


def table(headers: Sequence[str], rows: Iterable[Sequence[object]]) -> str:
    """A plain text table, columns right-aligned except the first."""
    cells = [[str(h) for h in headers]] + [[_cell(v) for v in row] for row in rows]
    widths = [max(len(r[i]) for r in cells) for i in range(len(headers))]
    lines = []
    for k, row in enumerate(cells):
        parts = [row[0].ljust(widths[0])] + [c.rjust(w) for c, w in zip(row[1:], widths[1:], strict=True)]
        lines.append("  ".join(parts).rstrip())
        if k == 0:
            lines.append("  ".join("-" * w for w in widths))
    return "\n".join(lines)


def _cell(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.1f}" if abs(value) >= 10 or value == 0 else f"{value:.2f}"
    return "-" if value is None else str(value)


def targets_table(targets: Sequence[Target]) -> str:
    """The targets with their verdicts; a limit the figure must reach (``at_least``) is shown as ``≥ limit``."""
    return table(
        ["target", "measured", "limit", "unit", "verdict"],
        [(t.name, t.measured, f"≥ {_cell(t.limit)}" if t.at_least else t.limit, t.unit, t.verdict) for t in targets],
    )


@dataclass
class Report:
    """The JSON document of one benchmark run; ``finish`` adds the end load and writes it."""

    benchmark: str
    parameters: dict[str, Any]
    started_utc: str = field(default_factory=lambda: datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"))
    load_start: list[float] = field(default_factory=load_average)
    results: dict[str, Any] = field(default_factory=dict)
    targets: list[Target] = field(default_factory=list)
    references: list[dict[str, Any]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def document(self) -> dict[str, Any]:
        return {
            "benchmark": self.benchmark,
            "command": " ".join([Path(sys.executable).name, "-m", f"bench.{self.benchmark}", *sys.argv[1:]]),
            "started_utc": self.started_utc,
            "machine": machine_info(),
            "load_average": {"start": self.load_start, "end": load_average(), "columns": ["1m", "5m", "15m"]},
            "parameters": self.parameters,
            "results": self.results,
            "targets": [t.as_dict() for t in self.targets],
            "references": self.references,
            "notes": self.notes,
        }

    def finish(self, path: Path) -> dict[str, Any]:
        """Write the document to ``path`` (folders created) and return it."""
        doc = self.document()
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(doc, indent=2) + "\n")
        return doc


def print_header(title: str) -> None:
    info = machine_info()
    print(f"== {title}")
    print(
        f"machine: {info['cpu_model']}, {info['nproc']} cores, Python {info['python']}, "
        f"load average {' '.join(str(x) for x in load_average())} (1/5/15 min)"
    )
