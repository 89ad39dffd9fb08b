"""Bounded summaries of a long stream of figures: the auditor runs for weeks and keeps none of them in a list.

- :class:`DelayHistogram`: count, exact maximum and a median to one fixed bucket (0.1 ms, the resolution the
  auditor reports it at) of figures in ``[0, range)``; its memory is allocated once, at creation, however many
  figures are added.
- :class:`LargestN`: the ``n`` largest figures, in the order they came, and how many came in all.

No I/O here.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterable
from itertools import accumulate

DELAY_BUCKET_S = 1e-4
"""Width of a :class:`DelayHistogram` bucket: its median is the figures' median rounded to this [s]."""
DELAY_RANGE_S = 10.0
"""Figures at or above this fall into one overflow bucket [s]."""


class DelayHistogram:
    """Fixed-width histogram of non-negative durations: count, maximum (exact) and median (to a bucket).

    Bucket ``k`` holds the figures nearest to ``k · bucket_s`` (each figure rounded to the bucket width), so
    the median of one figure, or of an odd count, is that figure rounded to ``bucket_s``. The counts are one
    array of ``range_s / bucket_s + 1`` 64-bit integers allocated at creation (800 kB at the defaults): adding
    figures never allocates, however many and however spread (a dictionary of the buckets seen grew with every
    new bucket, by ~5 MB over an hour of the soak's delays).

    Args:
        bucket_s: bucket width [s].
        range_s: upper end of the buckets; larger figures share one overflow bucket [s].
    """

    def __init__(self, bucket_s: float = DELAY_BUCKET_S, range_s: float = DELAY_RANGE_S) -> None:
        if not (bucket_s > 0.0 and range_s > bucket_s):
            raise ValueError(f"bucket_s {bucket_s}, range_s {range_s}; allowed: 0 < bucket_s < range_s")
        self._bucket_s = bucket_s
        self._overflow = math.ceil(range_s / bucket_s)
        self._counts = array("Q", bytes(8 * (self._overflow + 1)))
        self.count = 0
        self.max_s: float | None = None

    @property
    def nbytes(self) -> int:
        """Memory of the counts [bytes]: fixed at creation."""
        return self._counts.itemsize * len(self._counts)

    def add(self, value_s: float) -> None:
        """Count one figure [s] (a non-finite or negative one counts in the first or the overflow bucket)."""
        self.count += 1
        if self.max_s is None or value_s > self.max_s or value_s != value_s:
            self.max_s = value_s
        if not value_s < self._overflow * self._bucket_s:  # nan and +inf overflow too
            index = self._overflow
        else:
            index = max(0, round(value_s / self._bucket_s))
        self._counts[index] += 1

    def median_s(self) -> float | None:
        """The median, as its bucket's value ``k · bucket_s`` [s] (the overflow bucket: the maximum); None if empty.

        With an even count, the mean of the two middle figures' buckets, as :func:`statistics.median` does.
        """
        if self.count == 0:
            return None
        lower, upper = (self.count - 1) // 2, self.count // 2  # ranks of the middle figure(s), from 0
        return (self._at_rank(lower) + self._at_rank(upper)) / 2.0

    def _at_rank(self, rank: int) -> float:
        for index, seen in enumerate(accumulate(self._counts)):
            if seen > rank:
                if index == self._overflow:
                    return self.max_s if self.max_s is not None else math.inf
                return index * self._bucket_s
        raise IndexError(rank)  # never: rank < count


class LargestN:
    """The ``n`` largest figures seen, in the order they came, and the count of all of them.

    Below ``n`` figures it holds them all, so what it returns is what a list would; above, the smallest go
    (the earliest first among equal ones). At most ``2 n`` are held between prunings.

    Args:
        n: how many to keep (> 0).
    """

    def __init__(self, n: int) -> None:
        if n <= 0:
            raise ValueError(f"n {n}; allowed: > 0")
        self._n = n
        self._kept: list[float] = []
        self.count = 0

    @property
    def n_stored(self) -> int:
        """Figures held now (the memory bound: at most ``2 n``)."""
        return len(self._kept)

    def add(self, value: float) -> None:
        """Count one figure."""
        self.count += 1
        self._kept.append(value)
        if len(self._kept) >= 2 * self._n:
            self._kept = largest_in_order(self._kept, self._n)

    def values(self) -> tuple[float, ...]:
        """The ``n`` largest figures (all of them while fewer came), in the order they came."""
        return tuple(largest_in_order(self._kept, self._n))


def largest_in_order(values: Iterable[float], n: int) -> list[float]:
    """The ``n`` largest of ``values`` in their original order (among equal ones, the latest stay)."""
    items = list(values)
    if len(items) <= n:
        return items
    chosen = sorted(range(len(items)), key=lambda k: (items[k], k))[-n:]
    return [items[k] for k in sorted(chosen)]
