"""End to end through the ROS 2 adapter: the tracker emulator speaks ZED (zed_msgs/ObjectsStamped) over rmw_zenoh,
the gateway turns the skeletons into capsules (gateway/ros2_trackers.py): the default scenario's zone sequence with
the cameras' body fitting on and off (docs/ros2.md, "ZED body fitting"), no fault, and a delay budget that counts from
the capture (the header stamp) through the conversion."""

from __future__ import annotations

import statistics
from pathlib import Path
from typing import Any

import pytest
from support.cell_files import zed_cell

from hrc_tools.cell.procs import (
    collapse,
    free_endpoint,
    is_subsequence,
    record,
    refused_tracker_frames,
    running_cell,
    scenario_window_s,
)

pytestmark = pytest.mark.e2e

SCENARIO_S = 31.0  # walk_in_reach_leave: nobody, walk in, reach in, leave, nobody
ZONES = ["autonomous", "guarded_distance", "safety_exception", "autonomous"]
"""The default scenario's zones, the reduced-speed step on the way in left out (see the test). Without body fitting
(the ZED wrapper's default) the person's legs, hidden behind the table from the front sensor, are NaN, so reach
spheres around the pelvis stand for them (a hidden foot can be anywhere a leg reaches:
hrc_devices/trackers/skeletons.py); the step was measured at 0.05 s at 3d80349 and 0.20-0.28 s at 2c4fa55, after
the radii check."""


@pytest.mark.parametrize("body_fitting", ["on", "off"])
def test_the_cell_runs_end_to_end_with_the_trackers_speaking_zed(tmp_path: Path, body_fitting: str) -> None:
    config = zed_cell(tmp_path, free_endpoint())
    trackers = [["--publish", "zed", "--zed-body-fitting", body_fitting]]
    with running_cell(tmp_path, config=config, trackers=trackers) as cell:
        # Generous: three programs and a ROS 2 session start on a loaded 2-core machine.
        cell.wait_until(lambda s: s["zone"] == "autonomous" and not s["faults"], 120.0, "a fault-free autonomous cell")
        trace: list[dict[str, Any]] = record(
            cell,
            scenario_window_s(SCENARIO_S),
            until=lambda t: is_subsequence(ZONES, collapse([s["zone"] for s in t])),
        )
        status = cell.get("/api/v1/status").json()
        for name, proc in (("gateway", cell.gateway), ("controller", cell.controller), ("tracker", cell.tracker)):
            assert proc.poll() is None, f"{name} died during the run\n{cell.tail()}"
    zones = collapse([s["zone"] for s in trace])
    assert is_subsequence(ZONES, zones), collapse([_zone_and_faults(s) for s in trace])
    # The reduced-speed step on the way in is not asserted with either setting: it lasts 0.28-0.36 s with both here
    # (two runs of each, idle, b2a3c54), yet a CI run on a loaded machine saw guarded distance go straight to the safety
    # exception with fitting on, no fault and no gap in the samples. Whether δ falls below the reduced-speed level
    # before the person reaches the protective distance depends on how fast the program moves the links toward them
    # in those 0.3 s and on the measured delay; stopping without the step is the earlier, safer side.
    # Stale frames (tracker_stale: older than max_data_age_s) are a loaded machine's, failing closed; any other
    # tracker fault, or a frame the adapter refused, is the adapter's.
    tracker_faults = [f for s in trace for f in s["faults"] if f["code"].startswith("tracker_")]
    assert not [f for f in tracker_faults if f["code"] != "tracker_stale"], tracker_faults[:3]
    assert all(s["delta"] <= s["delta_bound"] + 1e-9 for s in trace)
    inputs = status["inputs"]
    assert inputs["received"]["tracker/front"] > 100
    assert inputs["received"]["tracker/side"] > 100
    # No frame the adapter refused (a loaded run dropped 4-6 of a held-up burst as rate_exceeded: not a refusal)
    assert not refused_tracker_frames(inputs), inputs["rejected"]
    # The frames are stamped at capture (header.stamp): their age includes the sensor's latency (0.03-0.04 s in
    # the cell file) and the conversion, never only the hop from the adapter to the loop.
    present = [s for s in trace if s["min_distance_m"] is not None]
    assert present
    assert statistics.median(s["delay_budget_s"]["human_age_s"] for s in present) >= 0.03
    closest = min(present, key=lambda s: s["min_distance_m"])
    assert closest["zone"] == "safety_exception"
    assert closest["delta"] == 0.0


def _zone_and_faults(status: dict[str, Any]) -> str:
    """A status sample as its zone and fault codes (for the failure messages)."""
    codes = sorted({f["code"] for f in status["faults"]})
    return status["zone"] + (f" {codes}" if codes else "")
