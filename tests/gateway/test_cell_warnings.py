"""Start-up warnings of a valid cell file that works against the cell (gateway/cell_warnings.py)."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from support.paths import DEFAULT_CELL_PATH

from gateway.cell_warnings import (
    cell_warnings,
    exit_zones_nobody_leaves_by,
    noise_beyond_clearance,
    stale_between_frames,
)
from gateway.main import build_node
from hrc_contract.config import Box, CellConfig
from hrc_runtime.config import load_cell_config


def _with_side(config: CellConfig, **side: float) -> CellConfig:
    tracker = config.trackers["side"].model_copy(update=side)
    return config.model_copy(update={"trackers": {**config.trackers, "side": tracker}})


@pytest.mark.parametrize("path", sorted(DEFAULT_CELL_PATH.parent.glob("cell*.toml")), ids=lambda p: p.name)
def test_the_shipped_cells_warn_of_nothing(path: Path) -> None:
    assert cell_warnings(load_cell_config(path)) == []


def test_a_tracker_noisier_than_the_clearance_is_named(cell_config: CellConfig) -> None:
    """c covers the sensors' error (eq. (11)): the shipped trackers' 3σ (0.03, 0.045 m) are within c = 0.05 m."""
    noisy = _with_side(cell_config, noise_std_m=0.02)
    (line,) = noise_beyond_clearance(noisy)
    assert "tracker 'side'" in line
    assert "3 × noise_std_m = 0.060 m, exceeds safety.clearance_static_m = 0.05 m" in line
    wider = noisy.model_copy(update={"safety": noisy.safety.model_copy(update={"clearance_static_m": 0.06})})
    assert noise_beyond_clearance(wider) == []


@pytest.mark.parametrize(
    ("rate_hz", "latency_s", "warned"),
    [(30.0, 0.04, False), (5.0, 0.0, False), (5.0, 0.01, True), (4.0, 0.0, True), (60.0, 0.19, True)],
)
def test_a_tracker_whose_data_goes_stale_between_frames_is_named(
    cell_config: CellConfig, rate_hz: float, latency_s: float, warned: bool
) -> None:
    """Period + latency against max_data_age_s (0.2 s): 5 Hz alone is exactly at the limit (not stale)."""
    lines = stale_between_frames(_with_side(cell_config, rate_hz=rate_hz, latency_s=latency_s))
    assert len(lines) == warned
    if warned:
        assert "tracker 'side'" in lines[0]
        assert f"more than safety.max_data_age_s = {cell_config.safety.max_data_age_s} s" in lines[0]


def test_the_gateway_logs_each_warning_once_at_start_up(
    cell_config: CellConfig, caplog: pytest.LogCaptureFixture
) -> None:
    troubled = _with_side(cell_config, noise_std_m=0.02, rate_hz=4.0)
    expected = cell_warnings(troubled)
    assert len(expected) == 2
    with caplog.at_level(logging.WARNING, logger="hrc-gateway"):
        build_node(troubled, None)
    assert [r.getMessage() for r in caplog.records if r.getMessage() in expected] == expected


@pytest.mark.parametrize(
    ("min_m", "max_m", "warned"),
    [
        ((-6.0, -1.0, -0.2), (-5.0, 1.0, 2.6), False),  # a door on the -x face
        ((-5.2, -1.0, 0.0), (-4.0, 1.0, 2.0), False),  # inside, but reaching into the -x band (-5.5 + 0.4)
        ((-1.0, 5.2, 0.0), (1.0, 7.0, 2.0), False),  # the +y face
        ((-1.0, -1.0, 0.0), (1.0, 1.0, 2.0), True),  # in the middle of the cell
        ((-6.0, 6.0, 0.0), (-5.0, 7.0, 2.0), False),  # beyond the +y face, where the cell spans its x
        ((-7.0, 6.0, 0.0), (-6.0, 7.0, 2.0), True),  # beyond a corner: the covered volume spans neither axis
        ((-6.0, -1.0, 3.0), (-5.0, 1.0, 4.0), True),  # above the covered volume
    ],
)
def test_an_exit_zone_nobody_can_leave_by_is_named(
    cell_config: CellConfig, min_m: tuple[float, float, float], max_m: tuple[float, float, float], warned: bool
) -> None:
    tracking = cell_config.tracking.model_copy(update={"exit_zones": [Box(min_m=min_m, max_m=max_m)]})
    lines = exit_zones_nobody_leaves_by(cell_config.model_copy(update={"tracking": tracking}))
    assert len(lines) == warned
    if warned:
        assert lines[0].startswith("tracking.exit_zones[0]")
