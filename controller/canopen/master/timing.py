"""Cycle timing in bounded memory: log-bucketed histograms and rings of the last values.

A real-time run of weeks must not keep one number per cycle.  :class:`Histogram` counts
values [ns] in buckets 1 % wide (from 100 ns up to 100 s: 2,084 buckets, 17 kB), with the
exact count, sum, min and max; a percentile is the geometric middle of its bucket, i.e.
within 0.5 % of the exact order statistic.  :class:`Ring` keeps the last ``n`` values (the
status line's p99 over the last second).  Adding a value is O(1) and allocates nothing.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Iterator

#: smallest bucketed value [ns]; everything at or below it counts in bucket 0
LOW_NS = 100.0
#: relative bucket width
STEP = 0.01
_LOG_STEP = math.log1p(STEP)
#: buckets up to 100 s
BUCKETS = int(math.log(1e11 / LOW_NS) / _LOG_STEP) + 2


class Histogram:
    """Counts of values [ns] in 1 %-wide buckets (see the module docstring)."""

    __slots__ = ("counts", "max", "min", "n", "total")

    def __init__(self) -> None:
        self.counts = array("q", bytes(8 * BUCKETS))
        self.n = 0
        self.total = 0
        #: exact extremes (0 while empty: see ``n``)
        self.min = 0
        self.max = 0

    def add(self, value_ns: int) -> None:
        if value_ns <= LOW_NS:
            i = 0
        else:
            i = int(math.log(value_ns / LOW_NS) / _LOG_STEP) + 1
            if i >= BUCKETS:
                i = BUCKETS - 1
        self.counts[i] += 1
        self.n += 1
        self.total += value_ns
        if self.n == 1 or value_ns > self.max:
            self.max = value_ns
        if self.n == 1 or value_ns < self.min:
            self.min = value_ns

    # (``append`` so that code written for the per-cycle arrays keeps working)
    append = add

    def __len__(self) -> int:
        return self.n

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile [ns] (NaN when empty); exact at the max, 0.5 % elsewhere."""
        if not self.n:
            return math.nan
        rank = q / 100.0 * (self.n - 1)
        if rank >= self.n - 1:
            return float(self.max)
        seen = 0
        for i, c in enumerate(self.counts):
            seen += c
            if seen > rank:
                if i == 0:
                    return float(min(self.min, LOW_NS))
                lo = LOW_NS * math.exp((i - 1) * _LOG_STEP)
                v = lo * math.sqrt(1.0 + STEP)
                return float(min(max(v, self.min), self.max))
        return float(self.max)  # pragma: no cover - counts and n disagree

    def summary_us(self) -> dict[str, float]:
        """p50/p99/max [us] and n (the run report's form)."""
        if not self.n:
            return {"p50": math.nan, "p99": math.nan, "max": math.nan, "n": 0}
        return {"p50": self.percentile(50) / 1e3, "p99": self.percentile(99) / 1e3,
                "max": self.max / 1e3, "n": self.n}

    @property
    def mean(self) -> float:
        return self.total / self.n if self.n else math.nan


class Ring:
    """The last ``size`` values (ints), oldest first when iterated."""

    __slots__ = ("data", "n", "size")

    def __init__(self, size: int) -> None:
        self.data = array("q", bytes(8 * size))
        self.size = size
        self.n = 0

    def add(self, value: int) -> None:
        self.data[self.n % self.size] = value
        self.n += 1

    append = add

    def __len__(self) -> int:
        return min(self.n, self.size)

    def __iter__(self) -> Iterator[int]:
        if self.n <= self.size:
            return iter(self.data[:self.n])
        i = self.n % self.size
        return iter(self.data[i:] + self.data[:i])

    def values(self) -> list[int]:
        return list(self)


class Run:
    """Consecutive events (missed deadlines in a row): the current and the longest run."""

    __slots__ = ("current", "longest", "runs")

    def __init__(self) -> None:
        self.current = 0
        self.longest = 0
        self.runs = 0

    def hit(self) -> int:
        self.current += 1
        if self.current == 1:
            self.runs += 1
        self.longest = max(self.longest, self.current)
        return self.current

    def miss(self) -> None:
        self.current = 0
