"""Small-vector arithmetic on tuples of floats (1-D rotation or 3-D translation channels).

Plain tuples beat numpy for 1-3 components by an order of magnitude, which is what keeps a
scalar tracker step in the microseconds.  The batch path (``batch.py``) performs the same
operations in the same order on numpy arrays, so both give bit-identical results.
"""

from __future__ import annotations

import math

Vec = tuple[float, ...]


def vec3(a: Vec) -> tuple[float, float, float]:
    """``a`` as a 3-D translation (the fixed-length channel of a ``MotionState``); a
    ValueError unless it has 3 components."""
    x, y, z = a
    return (x, y, z)


def add(a: Vec, b: Vec) -> Vec:
    return tuple([x + y for x, y in zip(a, b)])


def sub(a: Vec, b: Vec) -> Vec:
    return tuple([x - y for x, y in zip(a, b)])


def scale(a: Vec, s: float) -> Vec:
    return tuple([x * s for x in a])


def norm(a: Vec) -> float:
    """Euclidean norm, summed left to right (the batch path uses the same order)."""
    s = 0.0
    for x in a:
        s += x * x
    return math.sqrt(s)


def dot(a: Vec, b: Vec) -> float:
    s = 0.0
    for x, y in zip(a, b):
        s += x * y
    return s


def clamp_norm(a: Vec, limit: float) -> tuple[Vec, bool]:
    """``a`` scaled down to norm ``limit`` if longer: ``limit * a/|a|`` (``a*``: the unit
    vector of docs/spec/tracking.md#1.1)."""
    n = norm(a)
    if n > limit:
        k = limit / n
        return tuple([x * k for x in a]), True
    return a, False
