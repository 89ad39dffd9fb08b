"""bench.door runs, times the parsers on every frame and admission on the crowd, and reports its targets (tiny run;
no figure asserted)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from bench import door
from hrc_contract.humans import humans_from_payload


def test_the_door_benchmark_runs_and_reports(tmp_path: Path) -> None:
    out = tmp_path / "door.json"
    assert door.main(["--repeats", "10", "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert set(doc["results"]) == {*door.SIZES, door.CROWD, door.TRACKS}
    assert {"door + plausible", "packed + plausible"} <= set(doc["results"][door.CROWD])
    assert doc["results"].pop(door.TRACKS)["n"] == 10
    for figures in doc["results"].values():
        assert {"json.loads", "reference", "door", "packed"} <= set(figures)
        assert figures["packed_bytes"] < figures["bytes"]
        assert figures["door"]["n"] == 10
    assert {t["verdict"] for t in doc["targets"]} <= {"PASS", "MISS"}


def test_the_benchmarks_frames_are_valid_and_as_large_as_it_says() -> None:
    header, capsules = humans_from_payload(door.frame_payload(np.random.default_rng(0), 2, 1000))
    assert header.human_count == 2
    assert capsules.n_capsules == 2000
    assert door.admitted(door.crowd_payload()).n_capsules == door.CROWD_CAPSULES  # and plausible: else it raises
