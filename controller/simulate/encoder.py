"""A simulated conveyor and its encoder: the true belt, and the samples a controller gets.

:class:`Belt` is the belt coordinate s(t) [mm] as constant-jerk pieces (S-curve speed
changes from :func:`controller.simulate.master.speed_change_phases`), evaluated in closed
form.  :class:`EncoderSim` turns it into what the controller's master input receives per
cycle k (docs/spec/master-conditioning.md#1):

- the position at the sampling instant t_k = (k - latency)*T + delta_k, delta_k uniform in
  [-jitter, +jitter]*T (the instant is known to the controller: ``time_offset_s``),
- quantised to whole counts of ``resolution_mm`` (round half up, as a counter reads),
- missing with probability ``missing_rate`` (NaN),
- a glitch with probability ``glitch_rate``: the sample off by a size uniform in
  ``glitch_mm`` with a random sign (one sample; the next is right again).

Deterministic: everything random comes from ``seed``.  Used by the benchmark, the property
tests and the simulator's ``encoder:`` section.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

import numpy as np

from .master import speed_change_phases


class Belt:
    """s(t) [mm] of a belt starting at ``s0`` with speed ``v0`` [mm/s] and no acceleration,
    then the given speed changes ``(t_start [s], v1 [mm/s], acc [mm/s^2], jerk [mm/s^3])``
    (S-curves, each starting after the previous one ended)."""

    def __init__(self, v0: float, changes: tuple[tuple[float, float, float, float], ...] = (),
                 s0: float = 0.0) -> None:
        # pieces (t0, p0, v0, a0, j)
        pieces = [(-math.inf, s0, v0, 0.0, 0.0)]
        t, p, v = 0.0, s0, v0
        for t_start, v1, acc, jerk in changes:
            if t_start < t:
                raise ValueError(f"speed change at {t_start} s starts before the previous ended")
            p += v * (t_start - t)
            t = t_start
            a = 0.0
            for dur, j in speed_change_phases(v, v1, acc, jerk):
                pieces.append((t, p, v, a, j))
                p, v, a = (p + v * dur + a * dur * dur / 2 + j * dur ** 3 / 6,
                           v + a * dur + j * dur * dur / 2, a + j * dur)
                t += dur
            v = v1
            pieces.append((t, p, v, 0.0, 0.0))
        self.pieces = pieces
        self._t0 = [pc[0] for pc in pieces]
        self.v0 = v0
        self.changes = tuple(changes)

    def state(self, t: float) -> tuple[float, float, float, float]:
        """(s, v, a, j) at time t [s]."""
        t0, p, v, a, j = self.pieces[bisect_right(self._t0, t) - 1]
        if t0 == -math.inf:
            return p + v * t, v, 0.0, 0.0
        tau = t - t0
        return (p + v * tau + a * tau * tau / 2 + j * tau ** 3 / 6, v + a * tau + j * tau * tau / 2,
                a + j * tau, j)

    def positions(self, t: np.ndarray) -> np.ndarray:
        return np.array([self.state(float(x))[0] for x in t])

    def states(self, t: np.ndarray) -> np.ndarray:
        """(len(t), 4) array of (s, v, a, j)."""
        return np.array([self.state(float(x)) for x in t])

    def in_change(self, t: np.ndarray, settle_s: float = 0.0) -> np.ndarray:
        """True where a speed change is under way (acceleration or jerk not zero), or ended
        less than ``settle_s`` ago."""
        t = np.asarray(t, dtype=float)
        st = self.states(t)
        out = (st[:, 2] != 0.0) | (st[:, 3] != 0.0)
        if settle_s > 0.0:
            for t0, v1, acc, jerk in self.changes:
                dur = sum(d for d, _ in speed_change_phases(self.state(t0)[1], v1, acc, jerk))
                out |= (t >= t0) & (t < t0 + dur + settle_s)
        return out


@dataclass(frozen=True)
class EncoderSim:
    """The encoder model: count size [mm], latency [cycles], jitter [share of T], glitches."""

    resolution_mm: float = 0.01
    latency_samples: int = 1
    jitter: float = 0.1
    glitch_rate: float = 0.0
    glitch_mm: tuple[float, float] = (1.0, 5.0)
    missing_rate: float = 0.0
    seed: int = 0

    def quantise(self, x: np.ndarray) -> np.ndarray:
        q = self.resolution_mm
        return np.floor(x / q + 0.5) * q if q > 0.0 else np.asarray(x, dtype=float)

    def samples(self, belt: Belt, T: float, n: int) -> EncoderStream:
        """What cycles 0..n-1 receive."""
        rng = np.random.default_rng(self.seed)
        k = np.arange(n)
        delta = rng.uniform(-self.jitter, self.jitter, n) * T if self.jitter else np.zeros(n)
        ts = (k - self.latency_samples) * T + delta
        pos = self.quantise(belt.positions(ts))
        glitch = np.zeros(n)
        if self.glitch_rate:
            hit = rng.random(n) < self.glitch_rate
            size = rng.uniform(*self.glitch_mm, n) * rng.choice((-1.0, 1.0), n)
            glitch[hit] = size[hit]
            pos = pos + glitch
        if self.missing_rate:
            miss = rng.random(n) < self.missing_rate
            miss &= glitch == 0.0  # a missing glitch would not count as one
            pos[miss] = np.nan
        return EncoderStream(pos, delta, glitch)


@dataclass(frozen=True)
class EncoderStream:
    """Per cycle: the received position [mm] (NaN: missing), the sampling instant's offset
    from nominal [s] and the injected glitch [mm] (0: none)."""

    position_mm: np.ndarray
    time_offset_s: np.ndarray
    glitch_mm: np.ndarray

    def sample(self, k: int) -> tuple[float | None, float]:
        x = float(self.position_mm[k])
        return (None if math.isnan(x) else x), float(self.time_offset_s[k])
