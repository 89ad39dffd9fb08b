"""The sensor model: noise statistics, drop rate, truth without noise, and the wire message it becomes."""

from __future__ import annotations

import numpy as np
import pytest

from hrc_common.config import TrackerConfig
from hrc_common.messages import Humans, parse_message, to_payload
from tracker_emu.body import BodyPose, body_capsules
from tracker_emu.scenario import TrackedHuman
from tracker_emu.sensor import humans_message, measure

TRUTH = [
    TrackedHuman("h1", body_capsules(BodyPose(1.35, 0.0, np.pi, reach=1.0))),
    TrackedHuman("h2", body_capsules(BodyPose(2.7, -1.0, np.pi / 2))),
]


def end_points(humans: list[TrackedHuman]) -> np.ndarray:
    """All end points of all capsules, shape (N, 2, 3) [m]."""
    return np.array([[c.a, c.b] for h in humans for c in h.capsules])


def test_noise_std_is_the_configured_one() -> None:
    tracker = TrackerConfig(noise_std_m=0.02, drop_probability=0.0)
    rng = np.random.default_rng(7)
    truth = end_points(TRUTH)
    errors = np.array([end_points(measure(TRUTH, rng, tracker) or []) - truth for _ in range(400)])
    assert errors.shape == (400, *truth.shape)
    assert np.mean(errors) == pytest.approx(0.0, abs=0.001)
    assert np.std(errors) == pytest.approx(0.02, rel=0.05)
    # Every axis and both ends are noisy alike, and independently of each other.
    per_axis = np.std(errors.reshape(-1, 3), axis=0)
    np.testing.assert_allclose(per_axis, 0.02, rtol=0.05)
    flat = errors.reshape(-1, 2 * truth.shape[0] * 3)
    assert abs(np.corrcoef(flat[:, 0], flat[:, 3])[0, 1]) < 0.2


def test_noise_keeps_names_ids_and_radii() -> None:
    measured = measure(TRUTH, np.random.default_rng(1), TrackerConfig(noise_std_m=0.05))
    assert measured is not None
    assert [h.id for h in measured] == ["h1", "h2"]
    for h_meas, h_true in zip(measured, TRUTH, strict=True):
        assert [c.name for c in h_meas.capsules] == [c.name for c in h_true.capsules]
        assert [c.radius_m for c in h_meas.capsules] == [c.radius_m for c in h_true.capsules]
        assert any(not np.array_equal(m.a, t.a) for m, t in zip(h_meas.capsules, h_true.capsules, strict=True))


def test_drop_rate_is_the_configured_one() -> None:
    tracker = TrackerConfig(noise_std_m=0.01, drop_probability=0.1)
    rng = np.random.default_rng(11)
    frames = [measure(TRUTH, rng, tracker) for _ in range(5000)]
    drop_rate = sum(f is None for f in frames) / len(frames)
    assert drop_rate == pytest.approx(0.1, abs=0.015)


def test_no_drops_when_the_probability_is_zero() -> None:
    rng = np.random.default_rng(0)
    assert all(measure(TRUTH, rng, TrackerConfig(drop_probability=0.0)) is not None for _ in range(1000))


def test_zero_noise_gives_the_truth() -> None:
    measured = measure(TRUTH, np.random.default_rng(0), TrackerConfig(noise_std_m=0.0, drop_probability=0.0))
    assert measured is not None
    np.testing.assert_array_equal(end_points(measured), end_points(TRUTH))


def test_nobody_gives_an_empty_frame_not_a_dropped_one() -> None:
    assert measure([], np.random.default_rng(0), TrackerConfig(drop_probability=0.0)) == []


def test_same_seed_same_frames() -> None:
    tracker = TrackerConfig(noise_std_m=0.01, drop_probability=0.3)

    def run(seed: int) -> list[np.ndarray | None]:
        rng = np.random.default_rng(seed)
        frames = [measure(TRUTH, rng, tracker) for _ in range(50)]
        return [None if f is None else end_points(f) for f in frames]

    for a, b in zip(run(5), run(5), strict=True):
        assert (a is None and b is None) or np.array_equal(a, b)  # type: ignore[arg-type]


def test_the_frame_becomes_a_valid_contract_message() -> None:
    measured = measure(TRUTH, np.random.default_rng(0), TrackerConfig())
    assert measured is not None
    message = humans_message("front", 42, 1_790_000_000_000_000_000, measured)
    parsed = parse_message(to_payload(message), Humans)
    assert parsed.schema_ == "hrc.humans/1"
    assert (parsed.tracker, parsed.seq, parsed.stamp_ns) == ("front", 42, 1_790_000_000_000_000_000)
    assert [h.id for h in parsed.humans] == ["h1", "h2"]
    cap = parsed.humans[0].capsules[0]
    assert cap.name == measured[0].capsules[0].name
    assert cap.a == pytest.approx(tuple(measured[0].capsules[0].a), abs=1e-6)
    assert cap.radius == measured[0].capsules[0].radius_m
    empty = parse_message(to_payload(humans_message("side", 1, 0, [])), Humans)
    assert empty.humans == []
