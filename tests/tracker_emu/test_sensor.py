"""The sensor model: noise statistics, drop rate, truth without noise, the covered volume, missed people, id swaps,
occlusion, and the wire message it becomes."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from hrc_contract.config import Box, TrackerConfig, TrackingConfig
from hrc_contract.messages import Humans, parse_message, to_payload
from tracker_emu.body import BodyPose, body_capsules
from tracker_emu.occlusion import Blockers
from tracker_emu.scenario import TrackedHuman
from tracker_emu.sensor import centre_m, covered_volume, humans_message, measure, rename, swap_ids

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


# -- the covered volume, missed people, id swaps --------------------------------------------------------------------

COVERAGE = Box(min_m=(-5.5, -5.5, -0.2), max_m=(5.5, 5.5, 2.6))
EXACT = TrackerConfig(noise_std_m=0.0, drop_probability=0.0)


def person_at(human_id: str, x_m: float, y_m: float = 0.0) -> TrackedHuman:
    return TrackedHuman(human_id, body_capsules(BodyPose(x_m, y_m, np.pi)))


def test_people_outside_the_covered_volume_are_not_reported() -> None:
    inside_one = person_at("in", 5.4)
    outside_x = person_at("out_x", 5.7)
    outside_y = person_at("out_y", 1.0, -5.6)
    measured = measure([outside_x, inside_one, outside_y], np.random.default_rng(0), EXACT, coverage=COVERAGE)
    assert [h.id for h in measured or []] == ["in"]
    # What decides is the centre (the mean of the capsule end points), not a hand or a foot across the boundary.
    assert centre_m(inside_one)[0] == pytest.approx(5.4, abs=0.05)
    everywhere = measure([outside_x, inside_one, outside_y], np.random.default_rng(0), EXACT)
    assert [h.id for h in everywhere or []] == ["out_x", "in", "out_y"]


def test_covered_volume_is_the_cells_tracking_section() -> None:
    box = covered_volume(TrackingConfig(coverage_min_m=(-1.0, -2.0, 0.0), coverage_max_m=(1.0, 2.0, 2.0)))
    assert (box.min_m, box.max_m) == ((-1.0, -2.0, 0.0), (1.0, 2.0, 2.0))


def test_each_person_is_missed_with_the_configured_probability() -> None:
    tracker = TrackerConfig(noise_std_m=0.0, drop_probability=0.0, miss_probability=0.2)
    rng = np.random.default_rng(3)
    frames = [measure(TRUTH, rng, tracker) or [] for _ in range(4000)]
    for human_id in ("h1", "h2"):
        seen = sum(any(h.id == human_id for h in frame) for frame in frames)
        assert 1.0 - seen / len(frames) == pytest.approx(0.2, abs=0.02)
    # Misses are per person: both missed in the same frame about 0.2² of the time.
    assert sum(frame == [] for frame in frames) / len(frames) == pytest.approx(0.04, abs=0.01)
    # A missed person is missing from a frame that is published (not a dropped frame).
    assert all(frame is not None for frame in frames)


def test_misses_are_the_same_for_the_same_seed() -> None:
    tracker = TrackerConfig(noise_std_m=0.01, miss_probability=0.3)

    def run(seed: int) -> list[list[str]]:
        rng = np.random.default_rng(seed)
        return [[h.id for h in measure(TRUTH, rng, tracker) or []] for _ in range(60)]

    assert run(9) == run(9)
    assert run(9) != run(10)


def test_zero_probabilities_draw_what_the_sensor_drew_before_them() -> None:
    """Misses, coverage and id swaps off: the random stream (drop, noise) is the one of the plain sensor model."""
    tracker = TrackerConfig(noise_std_m=0.02, drop_probability=0.1)
    rng_a, rng_b = np.random.default_rng(5), np.random.default_rng(5)
    for _ in range(20):
        plain = measure(TRUTH, rng_a, tracker)
        full = measure(TRUTH, rng_b, tracker, coverage=COVERAGE)
        names = swap_ids(full or [], {}, rng_b, tracker.id_swap_probability)
        assert names == {}
        assert (plain is None and full is None) or np.array_equal(end_points(plain or []), end_points(full or []))
    assert rng_a.random() == rng_b.random()


def test_id_swaps_happen_at_the_configured_rate_and_persist() -> None:
    rng = np.random.default_rng(2)
    names: dict[str, str] = {}
    swaps = 0
    for _ in range(2000):
        new = swap_ids(TRUTH, names, rng, 0.05)
        swaps += new != names
        names = new
        reported = rename(TRUTH, names)
        assert sorted(h.id for h in reported) == ["h1", "h2"]  # a permutation: ids stay unique
    assert swaps / 2000 == pytest.approx(0.05, abs=0.015)
    # With two people every swap exchanges the two: the ids are swapped after an odd number of them.
    assert [h.id for h in rename(TRUTH, names)] == (["h2", "h1"] if swaps % 2 else ["h1", "h2"])


def test_an_id_swap_needs_two_people_and_is_deterministic() -> None:
    alone = [TRUTH[0]]
    assert swap_ids(alone, {}, np.random.default_rng(0), 0.99) == {}
    three = [*TRUTH, person_at("h3", 2.0, 2.0)]

    def run(seed: int) -> list[dict[str, str]]:
        rng = np.random.default_rng(seed)
        names: dict[str, str] = {}
        out = []
        for _ in range(40):
            names = swap_ids(three, names, rng, 0.3)
            out.append(names)
        return out

    assert run(4) == run(4)
    assert run(4) != run(5)
    for names in run(4):
        assert sorted(names.get(i, i) for i in ("h1", "h2", "h3")) == ["h1", "h2", "h3"]


def test_occlusion_needs_the_sensors_position() -> None:
    with pytest.raises(ValidationError, match="occlusion = true needs the sensor's position_m"):
        TrackerConfig(occlusion=True)
    assert TrackerConfig(occlusion=True, position_m=(3.5, 0.0, 2.2)).position_m == (3.5, 0.0, 2.2)
    with pytest.raises(ValidationError, match="miss_probability"):
        TrackerConfig(miss_probability=1.0)
    with pytest.raises(ValidationError, match="id_swap_probability"):
        TrackerConfig(id_swap_probability=-0.1)


def test_with_occlusion_the_sensor_reports_what_it_sees() -> None:
    tracker = TrackerConfig(noise_std_m=0.0, occlusion=True, position_m=(3.5, 0.0, 2.2))
    cabinet = Blockers(np.array([[2.0, 0.0, 0.0]]), np.array([[2.0, 0.0, 2.4]]), np.array([0.4]))
    behind = person_at("hidden", 0.5)
    beside = person_at("seen", 1.0, 2.5)
    measured = measure([behind, beside], np.random.default_rng(0), tracker, blockers=cabinet)
    assert [h.id for h in measured or []] == ["seen"]
    # Without occlusion the same sensor sees through the cabinet.
    plain = measure([behind, beside], np.random.default_rng(0), EXACT, blockers=cabinet)
    assert [h.id for h in plain or []] == ["hidden", "seen"]
