"""``hrc-replay``: a gateway recording fed through a new gateway node on the recorded clocks.

    hrc-replay RECORDING [--set section.key=value ...] [--tolerance 1e-9]

Builds a :class:`~gateway.node.GatewayNode` from the recorded configuration (with ``--set`` changes), gives it
every recorded input and cycle in the order the recording gives (the order the gateway saw them in), at the
recorded arrival and decision times, and compares each cycle's δ with the recorded one. Unchanged, a complete
recording reproduces every δ (the node is deterministic: no clock and no randomness inside); with a changed
parameter the report says, per robot, how many cycles differ, the first one and the largest |Δδ|. A recorded
incident thus becomes a regression test of a change.

Exit code: 0 identical within the tolerance, 1 different, 2 the recording or a ``--set`` cannot be used.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from pydantic import ValidationError

from gateway.main import build_node
from gateway.recording import GatewayRecording, InputRecord, InternalErrorRecord, read_gateway_recording
from hrc_contract.config import CellConfig, ConfigError
from hrc_runtime.config import one_line
from hrc_runtime.mcap_sink import RecordingError

PROG = "hrc-replay"
DEFAULT_TOLERANCE = 1e-9
NS_PER_S = 1_000_000_000


class RobotDifference(NamedTuple):
    """How one robot's replayed δ compares with the recorded one.

    Attributes:
        cycles: cycles compared.
        differing: cycles whose |Δδ| exceeds the tolerance.
        first_seq: override seq of the first differing cycle (None if none).
        first_t_s: its time since the first recorded cycle [s] (None if none).
        max_abs_delta: the largest |Δδ| over all cycles.
    """

    cycles: int
    differing: int
    first_seq: int | None
    first_t_s: float | None
    max_abs_delta: float


class ReplayReport(NamedTuple):
    robots: dict[str, RobotDifference]
    cycles: int
    inputs: int
    tolerance: float

    @property
    def identical(self) -> bool:
        return all(r.differing == 0 for r in self.robots.values())


def parse_setting(setting: str) -> tuple[list[str], Any]:
    """``section.key=value`` → (path, value); the value is JSON if it parses (numbers, true, lists), else text.

    Raises:
        ConfigError: not of the form ``section.key=value``.
    """
    path, sep, text = setting.partition("=")
    if not sep or not path or any(not part for part in path.split(".")):
        raise ConfigError(f"--set {setting!r}: expected section.key=value, e.g. safety.human_speed_mps=2.0")
    try:
        value = json.loads(text)
    except json.JSONDecodeError:
        value = text
    return path.split("."), value


def apply_settings(config: CellConfig, settings: Sequence[str]) -> CellConfig:
    """``config`` with each ``section.key=value`` changed, validated as a loaded file would be.

    Raises:
        ConfigError: an unknown key, or a value the configuration refuses (the message says what is allowed).
    """
    raw = config.model_dump(mode="json")
    for setting in settings:
        path, value = parse_setting(setting)
        table: Any = raw
        for part in path[:-1]:
            table = table.get(part) if isinstance(table, dict) else None
            if not isinstance(table, dict):
                raise ConfigError(f"--set {setting!r}: no section {'.'.join(path[:-1])!r} in the configuration")
        if path[-1] not in table:
            known = ", ".join(sorted(table))
            raise ConfigError(f"--set {setting!r}: no key {path[-1]!r} there; known: {known}")
        table[path[-1]] = value
    try:
        return CellConfig.model_validate(raw)
    except ValidationError as exc:
        raise ConfigError(one_line(exc, "--set")) from None


@dataclass
class _Tally:
    """One robot's comparison so far (see :class:`RobotDifference`)."""

    cycles: int = 0
    differing: int = 0
    first_seq: int | None = None
    first_t_s: float | None = None
    max_abs_delta: float = 0.0

    def add(self, seq: int, t_s: float, recorded: float | None, replayed: float | None, tolerance: float) -> None:
        diff = 1.0 if recorded is None or replayed is None else abs(replayed - recorded)
        self.cycles += 1
        self.max_abs_delta = max(self.max_abs_delta, diff)
        if diff > tolerance:
            self.differing += 1
            if self.first_seq is None:
                self.first_seq, self.first_t_s = seq, t_s

    def result(self) -> RobotDifference:
        return RobotDifference(self.cycles, self.differing, self.first_seq, self.first_t_s, self.max_abs_delta)


def replay(recording: GatewayRecording, config: CellConfig, tolerance: float = DEFAULT_TOLERANCE) -> ReplayReport:
    """Feed the recording through a node built from ``config``; compare its δ with the recorded δ.

    Raises:
        ConfigError: the robot models of ``config`` cannot be loaded.
    """
    node = build_node(config, None)
    tallies = {name: _Tally() for name in config.robots}
    cycles = inputs = 0
    first_ns: int | None = None
    for step in recording.steps:
        if isinstance(step, InputRecord):
            inputs += 1
            # as in the gateway's callback; the recording holds the internal error that followed
            with contextlib.suppress(Exception):
                node.on_message(step.key, step.payload, step.received)
        elif isinstance(step, InternalErrorRecord):
            node.on_internal_error(step.key, step.received)
        else:
            cycles += 1
            first_ns = step.now_mono_ns if first_ns is None else first_ns
            overrides = node.cycle(step.now, step.period_s).overrides
            t_s = (step.now_mono_ns - first_ns) / NS_PER_S
            for name, tally in tallies.items():
                replayed = overrides[name].delta if name in overrides else None
                tally.add(step.seq, t_s, step.deltas.get(name), replayed, tolerance)
    return ReplayReport({name: t.result() for name, t in tallies.items()}, cycles, inputs, tolerance)


def format_replay_report(path: Path, recording: GatewayRecording, settings: Sequence[str], report: ReplayReport) -> str:
    """The report for people: what was replayed, per robot whether and where δ differs, the verdict."""
    lines = [
        f"recording {path}: cell {recording.config.cell!r}, {report.cycles} cycles, {report.inputs} inputs"
        + ("" if recording.complete else " (INCOMPLETE)")
    ]
    if recording.truncated is not None:
        lines.append(
            f"  warning: the file ends before its footer ({recording.truncated}): the gateway did not close it; "
            "what was written before is replayed"
        )
    if recording.dropped or recording.missing_after:
        lines.append(
            f"  warning: {recording.dropped} message(s) were dropped while recording (first gap after message "
            f"{recording.missing_after[0] if recording.missing_after else '?'}): the replay is exact only up to there"
        )
    for setting in settings:
        lines.append(f"  changed: {setting}")
    for name, r in report.robots.items():
        if r.differing == 0:
            lines.append(f"  robot {name}: {r.cycles} cycles, δ identical (max |Δδ| = {r.max_abs_delta:.3g})")
        else:
            lines.append(
                f"  robot {name}: {r.differing} of {r.cycles} cycles differ; first at cycle seq {r.first_seq} "
                f"(t = {r.first_t_s:.3f} s), max |Δδ| = {r.max_abs_delta:.6f}"
            )
    verdict = "IDENTICAL" if report.identical else "DIFFERENT"
    lines.append(f"result: {verdict} (tolerance |Δδ| ≤ {report.tolerance:g})")
    return "\n".join(lines)


def main(recording_path: Path, settings: Sequence[str], tolerance: float) -> int:
    """Replay and print the report. Returns the exit code.

    Raises:
        RecordingError, ConfigError: the recording or a setting cannot be used.
    """
    recording = read_gateway_recording(recording_path)
    config = apply_settings(recording.config, settings)
    report = replay(recording, config, tolerance)
    print(format_replay_report(recording_path, recording, settings, report))
    return 0 if report.identical else 1


def cli(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(
        prog=PROG, description="Replay a gateway recording (hrc-gateway --record) and report where δ differs"
    )
    parser.add_argument("recording", type=Path, help="MCAP file written by hrc-gateway --record")
    parser.add_argument(
        "--set",
        dest="settings",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="change the recorded configuration, e.g. safety.human_speed_mps=2.0 (repeatable)",
    )
    parser.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE, help="largest |Δδ| counted as equal")
    args = parser.parse_args(argv)
    try:
        code = main(args.recording, args.settings, args.tolerance)
    except (RecordingError, ConfigError) as exc:
        print(f"{PROG}: {exc}", file=sys.stderr)
        sys.exit(2)
    sys.exit(code)


if __name__ == "__main__":
    cli()
