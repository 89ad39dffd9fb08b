"""A tracker frame at the door: the pydantic reference against the msgspec fast path, per frame size.

    .venv/bin/python -m bench.door [--repeats 200] [--json out/bench/door.json]

Frames of 1 person × 15 capsules and 2 × 1000 capsules (the contract's largest frame: 2000 capsules, ~380 KB of
JSON at full float precision). Timed, on the same payloads in one run: ``reference``
(:func:`hrc_contract.messages.parse_message_reference` then :func:`hrc_contract.humans.capsules_from_message`,
what the door did before) and ``door``
(:func:`hrc_contract.humans.humans_from_payload`), and ``json.loads`` alone as the floor of any JSON door.
Then the same frame packed (``hrc.humans_packed/1``: a MessagePack map, each person's capsules one binary array)
through the same door: ``packed``. Those random frames are not people (each "person" spans metres), so admission,
the door's whole work, is timed on a third frame: the crowd of ``bench.crowded`` (2000 capsules, ~130 people),
decoded and judged plausible (:func:`hrc_contract.humans.implausible_detail` with the compiled
:func:`gateway.kernels.frame_numbers`, as ``gateway.inputs`` admits a frame):
``door + plausible`` and ``packed + plausible``. The target of issue 36 is admission p99 ≤ 0.5 ms for 2000 capsules.

What the loop does next with an admitted frame, the tracks' update (:meth:`gateway.tracks.TrackSet.update`: the
frame's people continued, their boxes, the persons regrouped), is timed on the same crowd seen by the default cell's
two trackers, their frames taken alternately 16.5 ms apart (people standing still, 2 × 134 tracks): ``tracks``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from bench._report import Report, Target, default_json_path, print_header, summary, table, targets_table
from bench.crowded import crowd
from gateway.kernels import frame_numbers
from gateway.tracks import TrackSet
from hrc_contract.config import PlausibilityConfig
from hrc_contract.humans import capsules_from_message, humans_from_payload, implausible_detail, packed_payload
from hrc_contract.messages import Humans, parse_message, parse_message_reference
from hrc_runtime.config import load_cell_config

NAME = "door"
TARGET_P99_MS = 0.5
STAMP_NS = 1_790_000_000_000_000_000
SIZES = {"1 × 15": (1, 15), "2 × 1000": (2, 1000)}
CROWD = "crowd of 2000"
CROWD_CAPSULES = 2000
TRACKS = "tracks"
TRACKERS = ("front", "side")
"""The default cell's trackers (``configs/cell.toml``), each seeing the whole crowd."""
TRACKS_WARMUP_FRAMES = 20
FRAME_GAP_NS = 16_500_000
"""Between one tracker's frame and the other's [ns]: two trackers at 30 Hz, out of step."""


def random_frame(rng: np.random.Generator, people: int, parts: int, seq: int = 1) -> dict[str, Any]:
    """A valid ``hrc.humans/1`` frame of tracker ``front``: ``people`` × ``parts`` random capsules within 3 m."""
    humans = []
    for k in range(people):
        capsules = []
        for j in range(parts):
            a = rng.uniform(-3.0, 3.0, 3)
            b = a + rng.uniform(-0.2, 0.2, 3)
            radius = float(rng.uniform(0, 0.2))
            capsules.append({"name": f"part{j}", "a": a.tolist(), "b": b.tolist(), "radius": radius})
        humans.append({"id": f"p{k}", "capsules": capsules})
    return {"schema": "hrc.humans/1", "tracker": "front", "seq": seq, "stamp_ns": STAMP_NS, "humans": humans}


def frame_payload(rng: np.random.Generator, people: int, parts: int) -> bytes:
    return json.dumps(random_frame(rng, people, parts)).encode()


def _reference(payload: bytes) -> object:
    message = parse_message_reference(payload, Humans)
    return capsules_from_message(message.tracker, message)


def _time_ms(parse: Callable[[bytes], object], payload: bytes, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        parse(payload)
        times.append((time.perf_counter_ns() - t0) / 1e6)
    return times


def crowd_payload(tracker: str = "front") -> bytes:
    """The crowd of ``bench.crowded`` as one valid, plausible frame of ``tracker`` (:data:`CROWD_CAPSULES`)."""
    humans = crowd((0.0, 0.0), 1.2, CROWD_CAPSULES)
    frame = {"schema": "hrc.humans/1", "tracker": tracker, "seq": 1, "stamp_ns": STAMP_NS, "humans": humans}
    return json.dumps(frame).encode()


def admitted(payload: bytes, plausibility: PlausibilityConfig = PlausibilityConfig()) -> object:  # noqa: B008
    """What the gateway does to admit a frame (``gateway.inputs``): decode, then judge it plausible with the compiled
    numbers and the decoder's person starts (it must be)."""
    header, capsules = humans_from_payload(payload)
    problem = implausible_detail(capsules, plausibility, frame_numbers, header.human_starts)
    if problem is not None:
        raise AssertionError(f"the benchmark's frame is not plausible: {problem}")
    return capsules


def tracks_update_ms(frames: int) -> list[float]:
    """Per frame [ms]: :meth:`TrackSet.update` of the default cell taking the crowd's frame of one tracker, then the
    other's, after :data:`TRACKS_WARMUP_FRAMES` frames (the tracks set up, the kernels compiled)."""
    track_set = TrackSet(load_cell_config(None))
    decoded = {}
    for tracker in TRACKERS:
        header, capsules = humans_from_payload(crowd_payload(tracker))
        decoded[tracker] = (capsules, header.human_starts)
    times = []
    stamp_ns = STAMP_NS
    for k in range(TRACKS_WARMUP_FRAMES + frames):
        stamp_ns += FRAME_GAP_NS
        tracker = TRACKERS[k % len(TRACKERS)]
        capsules, starts = decoded[tracker]
        t0 = time.perf_counter_ns()
        track_set.update({tracker: (object(), capsules, stamp_ns, starts)}, stamp_ns)
        if k >= TRACKS_WARMUP_FRAMES:
            times.append((time.perf_counter_ns() - t0) / 1e6)
    if len(track_set.live) != len(TRACKERS) * len(crowd((0.0, 0.0), 1.2, CROWD_CAPSULES)):
        raise AssertionError(f"the crowd made {len(track_set.live)} tracks: not every person of both trackers")
    return times


def run(repeats: int, seed: int) -> dict[str, object]:
    rng = np.random.default_rng(seed)
    results: dict[str, object] = {}
    payloads = {label: frame_payload(rng, people, parts) for label, (people, parts) in SIZES.items()}
    for label, payload in {**payloads, CROWD: crowd_payload()}.items():
        packed = packed_payload(parse_message(payload, Humans))
        parsers: dict[str, tuple[Callable[[bytes], object], bytes]] = {
            "json.loads": (json.loads, payload),
            "reference": (_reference, payload),
            "door": (humans_from_payload, payload),
            "packed": (humans_from_payload, packed),
        }
        if label == CROWD:
            parsers |= {"door + plausible": (admitted, payload), "packed + plausible": (admitted, packed)}
        times: dict[str, list[float]] = {name: [] for name in parsers}
        for _ in range(repeats // 10):  # interleaved rounds, so that a busy moment hurts all alike
            for name, (parse, data) in parsers.items():
                times[name] += _time_ms(parse, data, 10)
        figures = {k: summary(v, 1.0, 3) for k, v in times.items()}
        results[label] = {"bytes": len(payload), "packed_bytes": len(packed), **figures}
    results[TRACKS] = summary(tracks_update_ms(repeats), 1.0, 3)
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.door", description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=200)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--json", type=Path, default=default_json_path(NAME))
    args = parser.parse_args(argv)
    print_header("a tracker frame at the door: pydantic reference against the msgspec door")
    report = Report(NAME, {"repeats": args.repeats, "seed": args.seed})
    results = run(max(10, args.repeats), args.seed)
    report.results = results
    rows = []
    for label, figures in results.items():
        assert isinstance(figures, dict)
        if label == TRACKS:
            continue
        for name, f in figures.items():
            if not isinstance(f, dict):
                continue
            size = figures["packed_bytes" if name.startswith("packed") else "bytes"]
            rows.append([label, size, name, f["p50"], f["p99"], f["max"]])
        for slow, fast in (("reference", "door"), ("door", "packed")):
            ratio = figures[slow]["p50"] / max(figures[fast]["p50"], 1e-9)
            rows.append([label, "", f"{slow} / {fast} (p50)", round(ratio, 2), "", ""])
    print(table(["frame", "bytes", "parsed by", "p50 [ms]", "p99", "max"], rows))
    tracks = results[TRACKS]
    assert isinstance(tracks, dict)
    print(
        f"\nthe tracks' update per frame, the crowd seen by {len(TRACKERS)} trackers: p50 {tracks['p50']} ms, "
        f"p99 {tracks['p99']}, max {tracks['max']} ({tracks['n']} frames)"
    )
    largest = results[CROWD]
    assert isinstance(largest, dict)
    report.targets = [
        Target("2000-capsule JSON frame admitted, p99", largest["door + plausible"]["p99"], TARGET_P99_MS, "ms"),
        Target("2000-capsule packed frame admitted, p99", largest["packed + plausible"]["p99"], TARGET_P99_MS, "ms"),
    ]
    print("\n" + targets_table(report.targets))
    report.finish(args.json)
    print(f"\nwrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
