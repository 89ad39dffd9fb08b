"""The productivity benchmark still runs (tiny counts, in process) and reports every variant.

Not timed assertions: only the shape of the results and the identities between variants are checked.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bench import productivity


def test_productivity_benchmark_runs(tmp_path: Path) -> None:
    out = tmp_path / "productivity.json"
    argv = ["--scenarios", "1", "--seed", "3", "--workers", "1", "--duration-s", "1.5", "--quiet"]
    assert productivity.main([*argv, "--json", str(out)]) == 0
    doc: dict[str, Any] = json.loads(out.read_text())
    assert doc["benchmark"] == "productivity"
    assert doc["machine"]["nproc"] >= 1
    assert len(doc["load_average"]["start"]) == 3
    figures = doc["results"]["all_cases"]
    assert list(figures) == list(productivity.VARIANTS)
    for f in figures.values():
        assert f["runs"] == 1
        assert f["simulated_s"] == 1.5
        assert f["counts"] == (f["violations"] == 0)
    assert [t["name"] for t in doc["targets"]] == [
        f"cycles/h {m} / {b}" for m in productivity.RATIO_METHODS for b in ("three_zones", "stop_only", "no_human")
    ]
    for target in doc["targets"]:
        assert target["verdict"] in ("PASS", "MISS")
        assert target["comparison"] == ">="
    runs = doc["results"]["runs"]
    assert [r["variant"] for r in runs] == list(productivity.VARIANTS)
    # The same case (and seed) for every variant.
    assert len({(r["index"], r["seed"]) for r in runs}) == 1


def test_ratio_target_counts_only_without_violations() -> None:
    ok = productivity.AtLeast("r", 2.5, 2.0, "x", counts=True)
    assert ok.verdict == "PASS"
    assert productivity.AtLeast("r", 1.5, 2.0, "x", counts=True).verdict == "MISS"
    assert productivity.AtLeast("r", 2.5, 2.0, "x", counts=False).verdict == "MISS"
    figures = {
        "zanchettin2016": {"cycles_per_hour": 300.0, "counts": True},
        "three_zones": {"cycles_per_hour": 200.0, "counts": True},
        "stop_only": {"cycles_per_hour": 100.0, "counts": False},
    }
    three, stop = productivity.ratios(figures)
    assert (three.measured, three.verdict) == (1.5, "PASS")
    assert (stop.measured, stop.counts, stop.verdict) == (3.0, False, "MISS")


def test_case_kind_takes_the_first_kind_present() -> None:
    kind = productivity.case_kind
    assert kind([{"kind": "cross"}, {"kind": "standing"}, {"kind": "approach"}]) == "standing"
    assert kind([{"kind": "cross"}, {"kind": "approach"}]) == "approach"
    assert kind([{"kind": "cross"}]) == "cross"
    assert kind([]) == "nobody"
