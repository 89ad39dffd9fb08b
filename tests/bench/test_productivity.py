"""The productivity benchmark still runs (tiny counts, in process) and reports every variant.

Not timed assertions: only the shape of the results and the identities between variants are checked.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path
from typing import Any

import pytest

from bench import productivity

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_size(path: Path) -> tuple[int, int]:
    """Width and height of a PNG file, read from its IHDR chunk (raises if it is not a PNG)."""
    head = path.read_bytes()[:24]
    if head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        raise ValueError(f"{path} is not a PNG file")
    width, height = struct.unpack(">II", head[16:24])
    return width, height


def test_productivity_benchmark_runs(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="the plot needs matplotlib (dev extra: scripts/bootstrap.sh)")
    out = tmp_path / "productivity.json"
    argv = ["--scenarios", "1", "--seed", "3", "--workers", "1", "--duration-s", "1.5", "--quiet"]
    assert productivity.main([*argv, "--json", str(out)]) == 0
    width, height = png_size(out.with_suffix(".png"))  # the plot, next to the JSON by default
    assert width >= 600
    assert height >= 300
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
        f"cycles/h {m} / {b}"
        for m in productivity.RATIO_METHODS
        if m in productivity.VARIANTS  # the open variant runs on request only
        for b in ("three_zones", "stop_only", "no_human")
    ]
    for target in doc["targets"]:
        assert target["verdict"] in ("PASS", "MISS")
        assert target["comparison"] == ">="
    runs = doc["results"]["runs"]
    assert [r["variant"] for r in runs] == list(productivity.VARIANTS)
    # The same case (and seed) for every variant.
    assert len({(r["index"], r["seed"]) for r in runs}) == 1
    # People within K and faster than K, apart: the one case is on one side for every variant.
    split = doc["results"]["speed_split"]
    assert list(split) == list(productivity.VARIANTS)
    for groups in split.values():
        assert groups["within_k"]["cases"] + groups["beyond_k"]["cases"] == 1
    assert doc["results"]["human_speed_mps"] == 1.6
    assert len({(r["beyond_k"], r["fastest_approach_mps"]) for r in runs}) == 1


def _run(
    index: int, variant: str, violations: int, margin: float | None, approach_mps: float
) -> productivity.VariantRun:
    return productivity.VariantRun(
        index=index,
        seed=index,
        variant=variant,
        beyond_budget=None,
        kind="approach",
        program_cycles=1.0,
        audited_s=10.0,
        time_stopped_s=1.0,
        mean_delta=0.5,
        smallest_margin_moving_m=margin,
        violations=violations,
        duration_s=10.0,
        wall_s=1.0,
        fastest_approach_mps=approach_mps,
        beyond_k=approach_mps > 1.6,
    )


def test_people_faster_than_k_are_a_figure_of_their_own() -> None:
    runs = [
        _run(0, "zanchettin2016", 0, 0.25, 1.2),
        _run(1, "zanchettin2016", 5, -0.03, 1.9),
        _run(2, "zanchettin2016", 0, 0.1, 1.7),
        _run(0, "stop_only", 0, None, 1.2),
    ]
    split = productivity.speed_split(runs)
    eq15 = split["zanchettin2016"]
    assert eq15["within_k"] == {
        "cases": 1,
        "violations": 0,
        "cases_with_violations": 0,
        "smallest_margin_moving_m": 0.25,
        "margin_lost_m": 0.0,
        "fastest_approach_mps": 1.2,
    }
    beyond = eq15["beyond_k"]
    assert (beyond["cases"], beyond["violations"], beyond["cases_with_violations"]) == (2, 5, 1)
    assert beyond["smallest_margin_moving_m"] == -0.03
    assert beyond["margin_lost_m"] == 0.03
    assert beyond["fastest_approach_mps"] == 1.9
    assert split["stop_only"]["within_k"]["smallest_margin_moving_m"] is None  # never moved near anyone
    assert "no_human" not in split  # a variant that did not run (--variants) has no row
    text = productivity.speed_split_table(split)
    assert "faster than K: cases" in text
    assert "5 (1 cases)" in text


def test_progress_lines_on_stderr_and_quiet(capsys: pytest.CaptureFixture[str]) -> None:
    runs = [_run(0, v, 0, 0.2, 1.2) for v in productivity.VARIANTS]
    runs[1] = _run(0, productivity.VARIANTS[1], 3, -0.01, 1.9)
    assert productivity._collect(iter(runs), len(runs), "stress", quiet=False) == runs
    captured = capsys.readouterr()
    assert captured.out == ""  # the report on stdout stays the same with or without progress
    assert "productivity (stress)" in captured.err
    assert f"{len(runs)}/{len(runs)} runs" in captured.err
    assert "VIOLATION: case 0 zanchettin2016_speed_aware (faster than K, 1.90 m/s): 3 cycles" in captured.err
    assert productivity._collect(iter(runs), len(runs), "stress", quiet=True) == runs
    assert capsys.readouterr().err == ""


def _doc(suite: str, kinds: tuple[str, ...]) -> dict[str, Any]:
    figures = {
        v: {"cycles_per_hour": 100.0 + 10 * i, "counts": v != "stop_only"} for i, v in enumerate(productivity.VARIANTS)
    }
    return {
        "parameters": {"suite": suite, "scenarios": 4, "duration_s": 30.0, "seed": 0},
        "results": {
            "within_budget": {"cases": 4, "figures": figures},
            "within_budget_by_kind": {k: {"cases": 2, "figures": figures, "ratios": []} for k in kinds},
        },
    }


def test_plot_of_both_suites_from_earlier_results(tmp_path: Path) -> None:
    pytest.importorskip("matplotlib", reason="the plot needs matplotlib (dev extra: scripts/bootstrap.sh)")
    stress, collaborative = tmp_path / "stress.json", tmp_path / "collaborative.json"
    stress.write_text(json.dumps(_doc("stress", ("standing", "approach"))))
    collaborative.write_text(json.dumps(_doc("collaborative", ("shared_table", "walk_by", "reach_in"))))
    one, two = tmp_path / "one.png", tmp_path / "both.png"
    assert productivity.main(["--plot-from", str(stress), "--plot", str(one)]) == 0
    assert productivity.main(["--plot-from", str(stress), str(collaborative), "--plot", str(two)]) == 0
    (w1, h1), (w2, h2) = png_size(one), png_size(two)
    assert w1 == w2
    assert h2 == 2 * h1  # one panel per suite
    not_results = tmp_path / "other.json"
    not_results.write_text(json.dumps({"results": {}}))
    assert productivity.main(["--plot-from", str(not_results), "--plot", str(tmp_path / "x.png")]) == 2
    assert not (tmp_path / "x.png").exists()


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


def test_the_open_variant_runs_every_robot_open_and_the_others_closed() -> None:
    from hrc_devices.robots.model import load_robot_model
    from hrc_runtime.config import load_cell_config

    config = load_cell_config("configs/cell_open_panda.toml")
    robots = {name: load_robot_model(name, r) for name, r in config.robots.items()}
    runs = {
        v: productivity.run_variant(config, robots, 0, 0, 1.5, v, "collaborative")
        for v in (productivity.OPEN, "zanchettin2016")
    }
    assert {r.variant for r in runs.values()} == {productivity.OPEN, "zanchettin2016"}
    assert productivity.with_control(config, "closed").robots["panda"].controller.control == "closed"
    assert productivity.with_control(config, "open").robots["panda"].controller.control == "open"
    assert all(r.violations == 0 for r in runs.values())
