"""What a cell file allows but an integrator would not want: one line each, logged as a WARNING when the gateway starts.

The cell file's validation refuses what would be unsafe or meaningless (``hrc_contract.config``); these are settings
that are valid but work against the cell: a tracker's stated error beyond the static margin that should cover it, or
a tracker whose frames are too far apart to be fresh between them (the robot stops on stale data), an exit zone
where nobody can leave (a lost person is then released only by a detection or a reset). Pure: the
configuration in, the lines out.
"""

from __future__ import annotations

from hrc_contract.config import NOISE_SIGMAS, CellConfig


def cell_warnings(config: CellConfig) -> list[str]:
    """Every warning of the cell file: :func:`noise_beyond_clearance`, :func:`stale_between_frames` (in the trackers'
    order), then :func:`exit_zones_nobody_leaves_by`."""
    return noise_beyond_clearance(config) + stale_between_frames(config) + exit_zones_nobody_leaves_by(config)


def noise_beyond_clearance(config: CellConfig) -> list[str]:
    """One line per tracker whose stated position noise, 3 × ``noise_std_m``, exceeds the static margin
    ``safety.clearance_static_m`` (c: sensor uncertainty and model error, eq. (11)): the separation then does not
    cover that tracker's error. A ROS 2 skeleton tracker is left out (its ``uncertainty_m`` grows every radius)."""
    c_m = config.safety.clearance_static_m
    lines = []
    for name, tracker in config.trackers.items():
        error_m = NOISE_SIGMAS * tracker.noise_std_m
        if tracker.ros2 is None and error_m > c_m:
            lines.append(
                f"tracker {name!r}: its stated noise, 3 × noise_std_m = {error_m:.3f} m, exceeds "
                f"safety.clearance_static_m = {c_m} m: the separation does not cover its position error; raise the "
                "clearance to at least 3 σ of the noisiest tracker"
            )
    return lines


def stale_between_frames(config: CellConfig) -> list[str]:
    """One line per tracker whose frames are older than ``safety.max_data_age_s`` before the next one arrives: its
    period (``1 / rate_hz``) plus its stated capture-to-publish latency (``latency_s``). Its data is stale between
    frames, and the robots stop on it (δ = 0, ``tracker_stale``) for part of every period."""
    max_age_s = config.safety.max_data_age_s
    lines = []
    for name, tracker in config.trackers.items():
        oldest_s = 1.0 / tracker.rate_hz + tracker.latency_s
        if oldest_s > max_age_s:
            lines.append(
                f"tracker {name!r}: a frame every {1.0 / tracker.rate_hz:.3f} s (rate_hz = {tracker.rate_hz}) that is "
                f"{tracker.latency_s} s old when published is {oldest_s:.3f} s old before the next one, more than "
                f"safety.max_data_age_s = {max_age_s} s: the robots stop on its stale data (δ = 0) for part of every "
                "period; raise its rate or the age limit"
            )
    return lines


def exit_zones_nobody_leaves_by(config: CellConfig) -> list[str]:
    """One line per exit zone (``tracking.exit_zones``) that reaches no side face's exit band of the covered volume
    (within ``exit_band_m`` of the face, or beyond it, where the covered volume spans the other axes): nobody can be
    seen leaving through it, so it releases nobody."""
    tracking = config.tracking
    low, high, band_m = tracking.coverage_min_m, tracking.coverage_max_m, tracking.exit_band_m
    lines = []
    for k, zone in enumerate(tracking.exit_zones):
        spans = [zone.min_m[a] <= high[a] and zone.max_m[a] >= low[a] for a in range(3)]
        reaches = any(
            spans[2]
            and spans[1 - axis]
            and (zone.min_m[axis] <= low[axis] + band_m or zone.max_m[axis] >= high[axis] - band_m)
            for axis in (0, 1)
        )
        if not reaches:
            lines.append(
                f"tracking.exit_zones[{k}] ({zone.min_m} to {zone.max_m} m) reaches no side face's exit band of the "
                f"covered volume ({low} to {high} m, exit_band_m = {band_m} m): nobody can be seen leaving through "
                "it, so it releases nobody"
            )
    return lines
