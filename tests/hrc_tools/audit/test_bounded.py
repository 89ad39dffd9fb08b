"""Bounded summaries: the same figures as keeping every value, in a size that does not grow with the run."""

from __future__ import annotations

import random
import statistics
import tracemalloc

import pytest

from hrc_tools.audit.bounded import DELAY_BUCKET_S, DelayHistogram, LargestN, largest_in_order


def test_one_delay_is_its_own_median_and_maximum() -> None:
    histogram = DelayHistogram()
    histogram.add(0.12)
    assert histogram.count == 1
    assert histogram.median_s() == pytest.approx(0.12)
    assert histogram.max_s == 0.12
    assert DelayHistogram().median_s() is None


def test_the_median_is_the_lists_median_to_a_bucket_and_the_maximum_exact() -> None:
    rng = random.Random(23)
    values = [rng.lognormvariate(-1.3, 0.6) for _ in range(5001)]  # odd count: one middle figure
    histogram = DelayHistogram()
    for v in values:
        histogram.add(v)
    assert histogram.count == len(values)
    assert histogram.max_s == max(values)
    assert histogram.median_s() == pytest.approx(round(statistics.median(values) / DELAY_BUCKET_S) * DELAY_BUCKET_S)


def test_delays_beyond_the_range_share_one_bucket_and_the_median_there_is_the_maximum() -> None:
    histogram = DelayHistogram(range_s=1.0)
    for v in (5.0, 28.0, 3.0, float("inf")):
        histogram.add(v)
    assert histogram.median_s() == float("inf") == histogram.max_s
    assert histogram.count == 4


def test_100k_delays_all_different_allocate_nothing_after_the_histograms_creation() -> None:
    rng = random.Random(5)
    histogram = DelayHistogram(range_s=1.0)
    nbytes = histogram.nbytes
    assert nbytes == 8 * (round(1.0 / DELAY_BUCKET_S) + 1)
    values = [rng.uniform(0.0, 2.0) for _ in range(100_000)]
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for v in values:
            histogram.add(v)
        grown_b = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert histogram.count == 100_000
    assert histogram.nbytes == nbytes
    assert grown_b < 1_000  # a dictionary of the buckets seen grew by ~0.7 MB here
    assert histogram.median_s() == pytest.approx(statistics.median(values), abs=DELAY_BUCKET_S)


def test_largest_n_is_the_list_while_fewer_came_and_the_largest_in_order_after() -> None:
    kept = LargestN(4)
    for v in (3.0, 1.0, 2.0):
        kept.add(v)
    assert kept.values() == (3.0, 1.0, 2.0)
    for v in (5.0, 0.5, 4.0, 0.1, 6.0):
        kept.add(v)
    assert kept.values() == (3.0, 5.0, 4.0, 6.0)
    assert kept.count == 8


def test_100k_figures_keep_at_most_2n() -> None:
    rng = random.Random(9)
    kept = LargestN(100)
    values = [rng.random() for _ in range(100_000)]
    for v in values:
        kept.add(v)
    assert kept.n_stored < 200
    assert sorted(kept.values()) == sorted(values)[-100:]
    assert largest_in_order([1.0, 1.0, 0.0], 1) == [1.0]


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(ValueError, match="allowed"):
        DelayHistogram(bucket_s=0.0)
    with pytest.raises(ValueError, match="allowed"):
        LargestN(0)
