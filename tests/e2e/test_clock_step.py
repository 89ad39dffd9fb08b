"""A wall-clock step on the tracker's host, end to end: the tracker emulator runs under libfaketime (no test hook in
any program), its clock offset by a file; a step of ±3 s stops the robot with the tracker's fault shown in
``GET /api/v1/status``, and setting the clock right again (as NTP would) lets it move again.

The faults come only from the gateway judging the tracker's stamps: a frame stamped 3 s ahead of the gateway's clock
is ``stamp_in_future`` (``tracker_out_of_order``); one stamped 3 s behind is ``stamp_backwards`` (before the newest
accepted) or, once the stamps pass it, 3 s old (``tracker_stale``). A gateway that judged frames by their arrival
alone would keep the robot moving, and the waits for δ = 0 with one of those faults would fail.
"""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Any

import pytest

from bench.soak import FAKETIME_CACHE_S, NO_FAKETIME, HostClock, find_libfaketime, remove_dead_faketime_files
from hrc_tools.cell.procs import program_env, recovered, running_cell, stop_program

pytestmark = pytest.mark.e2e

LIBFAKETIME = find_libfaketime()
READY_S = 60.0  # generous: start-up under the load of a shared 2-core machine
STOP_S = 15.0 + FAKETIME_CACHE_S  # the step reaches the tracker within FAKETIME_CACHE_S, then the next frame shows it
RECOVER_S = 30.0
STEP_S = 3.0
STAMP_FAULTS = {"tracker_out_of_order", "tracker_stale"}


def _healthy(status: dict[str, Any]) -> bool:
    return not status["faults"] and status["delta"] > 0.0 and status["controller_mode"] == "running"


def _stopped_by_tracker_stamps(status: dict[str, Any]) -> bool:
    return status["delta"] == 0.0 and bool({f["code"] for f in status["faults"]} & STAMP_FAULTS)


def _stamp_rejections(status: dict[str, Any], reason: str) -> int:
    """How many tracker frames the gateway refused for ``reason`` so far, over every tracker (``/api/v1/status``)."""
    rejected = status["inputs"]["rejected"]
    return sum(counts.get(reason, 0) for topic, counts in rejected.items() if topic.startswith("tracker/"))


@pytest.mark.skipif(LIBFAKETIME is None, reason=NO_FAKETIME)
@pytest.mark.parametrize(("step_s", "reason"), [(STEP_S, "stamp_in_future"), (-STEP_S, "stamp_backwards")])
def test_a_clock_step_on_the_trackers_host_stops_the_robot_until_the_clock_is_set_right(
    tmp_path: Path, step_s: float, reason: str
) -> None:
    assert LIBFAKETIME is not None
    clock = HostClock(LIBFAKETIME, tmp_path / "tracker-clock.offset")
    clock.step(0.0)
    with running_cell(tmp_path, scenario="standing_inside") as cell:
        # Started again under libfaketime, on this host's clock (+0 s). SIGTERM, as systemd stops it: a test run as
        # a background job inherits SIGINT ignored (POSIX shells), and so do the programs it starts.
        stop_program(cell.tracker, signal.SIGTERM, timeout_s=READY_S)
        cell.envs["tracker"] = clock.environment(program_env())
        cell.start("tracker")
        cell.wait_until(_healthy, READY_S, "a moving robot, the tracker under libfaketime at +0 s")
        rejected_before = _stamp_rejections(cell.get("/api/v1/status").json(), reason)

        clock.step(step_s)
        cell.wait_until(_stopped_by_tracker_stamps, STOP_S, f"δ = 0 with a tracker fault, the clock {step_s:+} s off")
        status = cell.get("/api/v1/status").json()  # the step is still on: so are its faults
        shown = {f["code"]: f["reason"] for f in status["robots"]["ur5"]["faults"] if f["code"] in STAMP_FAULTS}
        assert any(r.startswith(reason) or " s old " in r for r in shown.values()), status["robots"]["ur5"]["faults"]
        assert _stamp_rejections(status, reason) > rejected_before, status["inputs"]["rejected"]

        clock.step(0.0)
        cell.wait_until(recovered, RECOVER_S, "a moving robot again, the tracker's clock set right")
        for name in ("gateway", "controller", "tracker"):
            assert cell.procs[name].poll() is None, f"{name} exited\n{cell.tail()}"
    remove_dead_faketime_files()
