"""The master estimator: least-squares quadratic over a window, predicted ahead."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, strategies as st

from controller.tracking import MasterEstimator, unwrap_counts


@given(p0=st.floats(-1e4, 1e4), v=st.floats(-1000, 1000), a=st.floats(-2000, 2000),
       window=st.integers(3, 32), lead=st.sampled_from([0.0, 1.0, 2.0]))
def test_exact_for_a_constant_acceleration_master(p0, v, a, window, lead):
    T = 0.002
    est = MasterEstimator(T, window=window, lead_samples=lead)
    n = window + 5
    for k in range(n):
        t = k * T
        est.push(p0 + v * t + 0.5 * a * t * t)
    t = (n - 1 + lead) * T
    e = est.estimate()
    scale = 1.0 + abs(p0) + abs(v) + abs(a)
    assert e.pos == pytest.approx(p0 + v * t + 0.5 * a * t * t, abs=1e-7 * scale)
    assert e.vel == pytest.approx(v + a * t, abs=1e-5 * scale)
    assert e.acc == pytest.approx(a, abs=1e-2 * scale)


def test_hand_computed_weights_for_three_samples_lead_one():
    # samples at t = -3T, -2T, -T relative to the evaluation time (lead 1): the quadratic
    # through them extrapolated one sample: p = x1 - 3*x2 + 3*x3 (x3 newest),
    # v = (3*x1 - 8*x2 + 5*x3)/(2T), a = (x1 - 2*x2 + x3)/T^2
    T = 0.001
    est = MasterEstimator(T, window=3, lead_samples=1.0)
    x1, x2, x3 = 1.0, 4.0, 10.0
    for x in (x1, x2, x3):
        est.push(x)
    e = est.estimate()
    assert e.pos == pytest.approx(x1 - 3 * x2 + 3 * x3)
    assert e.vel == pytest.approx((3 * x1 - 8 * x2 + 5 * x3) / (2 * T))
    assert e.acc == pytest.approx((x1 - 2 * x2 + x3) / T**2)


def test_few_samples_degrade_gracefully():
    est = MasterEstimator(0.001, window=8, lead_samples=1.0)
    with pytest.raises(ValueError, match="no master samples"):
        est.estimate()
    est.push(5.0)
    assert est.estimate().pos == pytest.approx(5.0) and est.estimate().vel == 0.0
    est.push(5.3)  # linear: 300 mm/s, extrapolated one sample
    e = est.estimate()
    assert e.vel == pytest.approx(300.0) and e.pos == pytest.approx(5.6)
    assert e.acc == 0.0


def test_quantisation_noise_is_averaged():
    # a 300 mm/s conveyor through an encoder of 0.0244 mm per count (4096 counts / 100 mm) at
    # 1 ms: a 2-sample difference is off by up to q/T = 24 mm/s; the 32-sample quadratic fit
    # averages the quantisation (mean error below 15 mm/s, and below the difference's)
    T = 0.001
    q = 100.0 / 4096
    est = MasterEstimator(T, window=32, lead_samples=1.0)
    errs = []
    for k in range(2000):
        t = k * T
        est.push(np.floor(300.0 * t / q) * q)
        if k > 40:
            errs.append(est.estimate().vel - 300.0)
    errs = np.abs(errs)
    assert errs.mean() < 15.0
    # averaging works: a 2-sample difference would be off by up to q/T = 24 mm/s each sample
    est2 = MasterEstimator(T, window=3, degree=1)
    big = []
    for k in range(2000):
        est2.push(np.floor(300.0 * k * T / q) * q)
        if k > 5:
            big.append(abs(est2.estimate().vel - 300.0))
    assert np.mean(big) > errs.mean()


def test_extra_samples_extrapolate_a_stale_master():
    T = 0.001
    est = MasterEstimator(T, window=8)
    for k in range(10):
        est.push(200.0 * k * T)
    assert est.estimate(extra_samples=3).pos == pytest.approx(200.0 * (9 + 1 + 3) * T)


@pytest.mark.parametrize("prev,raw,mod,expected", [
    (100, 105, 4096, 105),
    (4090, 5, 4096, 4101),        # forward across the wrap
    (4101, 4095, 4096, 4095),     # backward across it
    (-3, 4094, 4096, -2),
    (10, 20, 0, 20),              # no modulus: raw
])
def test_unwrap_counts(prev, raw, mod, expected):
    assert unwrap_counts(prev, raw, mod) == expected


@pytest.mark.parametrize("window,lead,degree", [(16, 2.0, 2), (5, 1.0, 1), (3, 0.0, 2),
                                                 (40, 1.5, 2), (70, 1.0, 2)])
def test_fit_is_the_weighted_sums_bit_for_bit(window, lead, degree):
    """The generated per-length sums give exactly what the plain loop over the weights gives
    (same operations, same order; also the sign of a zero), for every fill of the window."""
    import math
    import random

    est = MasterEstimator(0.002, window, lead_samples=lead, degree=degree)
    rng = random.Random(window)
    x = 0.0
    for k in range(3 * window + 50):
        x += rng.uniform(-1.0, 1.0) * 10.0 ** rng.randint(-3, 3)
        est.push(x if k % 7 else -0.0)
        wp, wv, wa = est._w[est.samples]
        p = v = a = 0.0
        for xi, kp, kv, ka in zip(est._x, wp, wv, wa):
            p += kp * xi
            v += kv * xi
            a += ka * xi
        got = est.estimate()
        for g, r in zip((got.pos, got.vel, got.acc), (p, v, a)):
            assert g == r and math.copysign(1.0, g) == math.copysign(1.0, r), k
