"""End to end through the ROS 2 adapter: the tracker emulator speaks ZED (zed_msgs/ObjectsStamped, BODY_34) over
rmw_zenoh, the gateway turns the skeletons into capsules (gateway/ros2_trackers.py): the default scenario's zone
sequence, no fault, and a delay budget that counts from the capture (the header stamp) through the conversion."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

import pytest
from support.cell_files import zed_cell
from support.paths import REPO_ROOT

from hrc_tools.cell.procs import collapse, free_endpoint, is_subsequence, record, running_cell

pytestmark = pytest.mark.e2e

SCENARIO_S = 31.0  # walk_in_reach_leave: nobody, walk in, reach in, leave, nobody
ZONE_SEQUENCE = ["autonomous", "guarded_distance", "safety_exception", "autonomous"]
"""The default scenario's zones through the adapter. The capsule cell also passes reduced_speed on the way in; here the
person's legs, hidden behind the table from the front sensor, are reach spheres around the pelvis (a hidden foot can
be anywhere a leg reaches: hrc_runtime/skeletons.py), which come within the protective distance of the pedestal while
the hand is still far from the moving links: the robot stops from guarded distance, never faster than allowed."""
CONFIGS = REPO_ROOT / "configs"


def test_the_cell_runs_end_to_end_with_the_trackers_speaking_zed(tmp_path: Path) -> None:
    config = zed_cell(tmp_path, free_endpoint())
    with running_cell(tmp_path, config=config, trackers=[["--publish", "zed"]]) as cell:
        cell.wait_until(lambda s: s["zone"] == "autonomous" and not s["faults"], 30.0, "a fault-free autonomous cell")
        trace: list[dict[str, Any]] = record(cell, SCENARIO_S + 4.0)
        status = cell.get("/api/v1/status").json()
        for name, proc in (("gateway", cell.gateway), ("controller", cell.controller), ("tracker", cell.tracker)):
            assert proc.poll() is None, f"{name} died during the run\n{cell.tail()}"
    zones = collapse([s["zone"] for s in trace])
    assert is_subsequence(ZONE_SEQUENCE, zones), zones
    tracker_faults = [f for s in trace for f in s["faults"] if f["code"].startswith("tracker_")]
    assert not tracker_faults, tracker_faults[:3]
    assert all(s["delta"] <= s["delta_bound"] + 1e-9 for s in trace)
    inputs = status["inputs"]
    assert inputs["received"]["tracker/front"] > 100
    assert inputs["received"]["tracker/side"] > 100
    assert not {t: r for t, r in inputs["rejected"].items() if t.startswith("tracker/")}
    # The frames are stamped at capture (header.stamp): their age includes the sensor's latency (0.03-0.04 s in
    # the cell file) and the conversion, never only the hop from the adapter to the loop.
    present = [s for s in trace if s["min_distance_m"] is not None]
    assert present
    assert statistics.median(s["delay_budget_s"]["human_age_s"] for s in present) >= 0.03
    closest = min(present, key=lambda s: s["min_distance_m"])
    assert closest["zone"] == "safety_exception"
    assert closest["delta"] == 0.0
