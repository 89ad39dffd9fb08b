"""bench.open_lp runs, times the stages (the compiled decision beside its numpy reference) and reports its target
(tiny run; the figures are not asserted)."""

from __future__ import annotations

import json
from pathlib import Path

from bench import open_lp


def test_the_open_lp_benchmark_runs_and_reports(tmp_path: Path) -> None:
    out = tmp_path / "open_lp.json"
    assert open_lp.main(["--samples", "20", "--repeat", "2", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert set(doc["results"]["time_us"]) == {
        "lp9 numpy",
        "lp9+lp13",
        "lp9+lp13 numpy",
        "command",
        "lp9+lp13 least of 2",
        "lp9+lp13 numpy least of 2",
    }
    assert doc["results"]["time_us"]["lp9+lp13"]["n"] == 20
    assert doc["results"]["same_answers"] == "20 of 20"
    assert doc["results"]["rows_of_all_pairs"] == 7 * 30 * 4  # 7 links × 2 people × 15 capsules × 4 corners
    assert {t["verdict"] for t in doc["targets"]} <= {"PASS", "MISS"}
