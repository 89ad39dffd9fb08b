"""Event cycles of the real gateway: a tracker frame is decided on when it arrives, not at the next tick.

The gateway runs at 20 Hz (a tick every 50 ms) while this process, as the tracker, sends a sample every
~15 ms alternating a person far away (δ = 1) and a person enclosing the robot (δ = 0) (``bench.reaction``
does the sending and the matching). The status documents list the override seqs of the event cycles,
so the test asserts *which* cycle reflected each sample, not how fast: no timing threshold.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import pytest

from bench.reaction import SEQ_GAP, RunSettings, run_once
from gateway.status import loop_status
from hrc_runtime.config import load_cell_config
from hrc_runtime.rate_loop import RateLoop
from hrc_tools.cell.procs import load_scale, with_retries

RATE_HZ = 20.0
SAMPLES = 60
MATCHED_SHARE = 0.5
"""Samples reflected in time: at least this share with event cycles, fewer with the ticks only."""


@pytest.mark.e2e
@pytest.mark.parametrize("event_driven", [True, False])
def test_tracker_samples_are_decided_by_event_cycles(tmp_path: Path, event_driven: bool) -> None:
    settings = RunSettings(
        rate_hz=RATE_HZ,
        samples=SAMPLES,
        interval_s=0.015,
        jitter=0.2,
        warmup_timeout_s=30.0,
        settle_s=0.3,
        seed=3,
        event_driven=event_driven,
    )
    run = with_retries(partial(run_once, load_cell_config(None), settings, tmp_path), f"{RATE_HZ:g} Hz")
    assert run["faults_in_status"] == {}
    assert run["status_cross_check"]["disagree"] == 0
    by = run["reflected_by"]
    matched = run["samples_matched"]
    detail = f"matched {matched}/{SAMPLES}, reflected by {by}, excluded {run['excluded']}"
    if event_driven:
        # Three samples per tick period: only a decision per sample reflects each of them. A sample whose override
        # this process lost on its way (its own receiving, on a loaded host) says nothing of the gateway.
        judged = SAMPLES - run["excluded"].get(SEQ_GAP, 0)
        assert judged >= SAMPLES // 2, f"this process lost too many overrides to judge: {detail}"
        # Ticks alone reflect at most one sample per tick: 60 samples ~15 ms apart span ~18 ticks of 50 ms, so more
        # than half the samples matched is beyond any run at the ticks only (the teeth below, measured 7-11 of 60 on
        # the slower AMD machine, idle). Event cycles matched 46-48 there: a cycle held past the next-but-one sample
        # (every ~10th on that machine, more on a loaded host) is excluded as late, and its successor as ambiguous,
        # so a share as high as 0.8 failed CI twice on 2026-12-07, the parent commit's code 2 runs of 4 alone. What
        # only event cycles do (the teeth below: 0) holds at any load.
        assert matched >= MATCHED_SHARE / load_scale() * judged, detail
        assert by["event_cycle"] >= 0.8 * matched, detail
        assert run["gateway_event_cycles_during_run"] > 0
    else:
        # The teeth: at the ticks only, nothing is an event cycle, and many samples are never reflected
        # before the next-but-one was sent (excluded by the matching).
        assert by["event_cycle"] == 0, detail
        assert run["gateway_event_cycles_during_run"] == 0
        assert matched < MATCHED_SHARE * SAMPLES, detail


def test_loop_block_counts_ticks_and_event_cycles_apart() -> None:
    rate = RateLoop(0.004)
    rate.tick_cycles, rate.event_cycles, rate.missed_cycles = 10, 3, 1
    block = loop_status(rate, 0.0005, True, [4, 7, 9])
    assert block.rate_hz == 250.0
    assert (block.cycles, block.tick_cycles, block.event_cycles, block.missed_cycles) == (13, 10, 3, 1)
    assert block.event_seqs == [4, 7, 9]
    assert block.event_driven is True
