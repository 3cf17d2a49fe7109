"""Master-axis estimator: sampled positions in, position/velocity/acceleration out.

The conveyor encoder arrives as quantised positions (counts already scaled to mm by the
caller), one sample per cycle, typically one cycle late.  The estimator fits a quadratic
p(t) = c0 + c1*t + c2*t^2 by least squares to the last ``window`` samples and evaluates it
``lead_samples`` sample periods after the newest sample (the time the setpoint is for).

A quadratic fit is exact for a constant-acceleration master, so the tracker's error after
synchronisation stays at rounding level for such a master; on quantised data the window
averages the quantisation noise (velocity noise ~ q/(T*window^1.5)).  With fewer samples
than the window the fit uses what it has (1 sample: constant; fewer than half a window:
linear — a quadratic through a few quantised samples has a huge acceleration error).

The weights are fixed per (window, lead), precomputed once: an estimate costs 3*window
multiply-adds.  Pure: samples in, estimate out; no clock.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .values import fast_init, mypyc_attr


@fast_init
@dataclass(frozen=True, slots=True)
class MasterEstimate:
    """Estimated master state [mm, mm/s, mm/s^2, mm/s^3] (or deg...) at the evaluation time.

    ``jerk``: known only from a conditioned master (:mod:`.conditioning`); 0 from the fit."""

    pos: float
    vel: float
    acc: float
    jerk: float = 0.0


def _weights(n: int, lead: float, sample_time_s: float, degree: int) -> tuple[tuple[float, ...], ...]:
    """Rows of weights w_p, w_v, w_a with estimate = sum(w[i]*x[i]) over oldest..newest."""
    T = sample_time_s
    # sample times relative to the evaluation time (newest sample at -lead*T)
    t = (np.arange(n, dtype=float) - (n - 1) - lead) * T
    deg = min(degree, n - 1)
    V = np.vander(t, deg + 1, increasing=True)  # columns 1, t, t^2
    pinv = np.linalg.pinv(V)  # (deg+1, n): coefficients = pinv @ x
    wp = pinv[0]
    wv = pinv[1] if deg >= 1 else np.zeros(n)
    wa = 2.0 * pinv[2] if deg >= 2 else np.zeros(n)
    return tuple(float(x) for x in wp), tuple(float(x) for x in wv), tuple(float(x) for x in wa)


#: window lengths up to this get their sums written out (_fit_sums); longer ones (rare: the
#: code grows with the square of the window) the loop (_fit_loop), with the same results
FIT_WRITTEN_OUT = 64


def _fit_loop(wp: tuple[float, ...], wv: tuple[float, ...], wa: tuple[float, ...]
              ) -> Callable[..., tuple[float, float, float]]:
    """``f(x_0, ..., x_n-1) -> (p, v, a)``: the weighted sums as a loop."""
    def fit(*xs: float) -> tuple[float, float, float]:
        p = v = a = 0.0
        for x, kp, kv, ka in zip(xs, wp, wv, wa):
            p += kp * x
            v += kv * x
            a += ka * x
        return p, v, a
    return fit


def _fit_sums(wp: tuple[float, ...], wv: tuple[float, ...], wa: tuple[float, ...]
              ) -> Callable[..., tuple[float, float, float]]:
    """``f(x_0, ..., x_n-1) -> (p, v, a)``, the weighted sums of one window length written
    out: ``p = 0.0 + wp[0]*x_0 + wp[1]*x_1 + ...`` evaluated left to right, the operations
    and their order of ``p = 0.0; for i: p += wp[i] * x_i`` (bit-identical), without the
    loop's per-sample work (a third of the cost).  Generated once per window length from
    the weights' exact reprs, as ``dataclasses`` generates ``__init__``."""
    n = len(wp)
    xs = [f"x{i}" for i in range(n)]

    def total(w: tuple[float, ...]) -> str:
        return "0.0" + "".join(f" + ({w[i]!r}) * {x}" for i, x in enumerate(xs))

    src = (f"def fit({', '.join(xs)}):\n"
           f"    return ({total(wp)},\n            {total(wv)},\n            {total(wa)})\n")
    ns: dict[str, object] = {}
    exec(src, ns)  # noqa: S102 -- generated from float reprs only
    fit = ns["fit"]
    assert callable(fit)
    return fit


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class MasterEstimator:
    """Least-squares quadratic fit over a sliding window, predicted ``lead_samples`` ahead.

    ``sample_time_s`` [s]: the sample period.  ``window``: samples in the fit (>= 3).
    ``lead_samples``: how far past the newest sample to predict (1 = the sample arrives one
    cycle late and the setpoint is for the next one).  ``degree``: 2 (quadratic, default) or 1.
    """

    def __init__(self, sample_time_s: float, window: int = 16, lead_samples: float = 1.0,
                 degree: int = 2) -> None:
        if window < 3:
            raise ValueError(f"window (={window}) must be >= 3")
        if degree not in (1, 2):
            raise ValueError(f"degree (={degree}) must be 1 or 2")
        self.sample_time_s = float(sample_time_s)
        self.window = int(window)
        self.lead = float(lead_samples)
        self.degree = degree
        self._x: deque[float] = deque(maxlen=self.window)
        full = max(3, self.window // 2)
        self._w = {n: _weights(n, self.lead, self.sample_time_s, degree if n >= full else 1)
                   for n in range(1, self.window + 1)}
        self._fit = {n: _fit_sums(*w) if n <= FIT_WRITTEN_OUT else _fit_loop(*w)
                     for n, w in self._w.items()}
        self._missed = 0

    def reset(self) -> None:
        self._x.clear()
        self._missed = 0

    @property
    def samples(self) -> int:
        return len(self._x)

    def push(self, position: float) -> None:
        """Add the newest position sample (one per sample period, oldest first)."""
        self._x.append(float(position))
        self._missed = 0

    def estimate(self, extra_samples: float = 0.0) -> MasterEstimate:
        """The master state ``lead + extra_samples`` periods after the newest sample.

        ``extra_samples`` extrapolates further with the fitted acceleration (used when
        samples are missing: the caller passes how many periods the newest one is stale).
        """
        n = len(self._x)
        if n == 0:
            raise ValueError("no master samples yet")
        p, v, a = self._fit[n](*self._x)
        if extra_samples:
            dt = extra_samples * self.sample_time_s
            p += v * dt + 0.5 * a * dt * dt
            v += a * dt
        return MasterEstimate(p, v, a)


def unwrap_counts(previous: int, raw: int, modulus: int) -> int:
    """Unwrap an encoder count that wraps at ``modulus`` (CiA 406 6002 total measuring range).

    Returns the continuous count nearest to ``previous`` that is congruent to ``raw``.
    """
    if modulus <= 0:
        return raw
    delta = (raw - previous) % modulus
    if delta > modulus // 2:
        delta -= modulus
    return previous + delta
