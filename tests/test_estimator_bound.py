"""benchmarks/estimator_bound.py: the indistinguishability bound on any causal estimator's
following error (docs/spec/master-conditioning.md#5.3) -- zero for an ideal encoder, the
hand value where the count constraints do not bind, growing with the count and the cycle,
and every pair it rests on re-checked."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("scipy")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import estimator_bound as eb  # noqa: E402
from controller.simulate.encoder import Belt  # noqa: E402

J = 5000.0
FRAME = eb.Frame(1000.0, 1000.0, J)


def _data(belt, T, q, n=120, latency=0):
    t = (np.arange(n) - latency) * T
    return eb.received(belt, t, q)


def test_ideal_encoder_bound_is_zero():
    """Unquantised, no latency, setpoint at the sample instant: B must equal A at every
    sample, so no pair has a gap; the spread bound is 0 too."""
    T = 0.002
    belt = Belt(300.0, ((0.1, 500.0, 800.0, J),))
    data = _data(belt, T, 0.0)
    lp = eb.StepLP(belt, data, 0.05, 0.4, 0.002, FRAME)
    for k in (60, 75, 90):
        for sign in (1.0, -1.0):
            assert lp.best_block(T, 0.0, k, 1, sign) is None
    valid = np.ones(len(data.t_s), dtype=bool)
    assert eb.spread_bound(data.t_s, valid, 75, 75 * T, 0.0, J) == pytest.approx(0.0, abs=1e-12)


def test_unbound_counts_give_the_hand_value():
    """12.5 mm/s = one 50 um count per 4 ms cycle: every sample sits at its count's centre,
    q/2 = 0.025 mm from either edge.  B = A + d, d = 0 up to t_a = t_k - 30 ms: any jerk
    <= J gives d(t) <= J (t - t_a)^3 / 6, which stays below 0.0225 mm up to t_k, so the
    counts do not bind and the optimum is J (t_sp - t_a)^3 / 6 at t_sp = t_k + 2 T."""
    T, q, k = 0.004, 0.05, 50
    belt = Belt(12.5)
    data = _data(belt, T, q)
    t_k = k * T
    t_a = t_k - 0.03
    assert J * 0.03 ** 3 / 6 < q / 2
    hand = J * (0.03 + 2 * T) ** 3 / 6  # 0.04573 mm
    lp = eb.StepLP(belt, data, t_a, t_k + 0.3, 0.002, FRAME)
    for sign in (1.0, -1.0):
        p = lp.best_block(T, 2.0, k, 1, sign)
        assert p is not None
        assert p.gap_mm[0] == pytest.approx(hand, rel=1e-6)
        assert math.isclose(hand, 0.045727, rel_tol=1e-4)
    # 50 ms back the counts bind: less than the unconstrained cubic, still a verified pair
    lp = eb.StepLP(belt, data, t_k - 0.05, t_k + 0.3, 0.002, FRAME)
    p = lp.best_block(T, 2.0, k, 1, 1.0)
    assert p is not None and p.gap_mm[0] < J * (0.05 + 2 * T) ** 3 / 6 - 0.01
    assert eb.verify(belt, data, p, FRAME)


def test_a_pair_that_leaves_its_count_is_rejected():
    T, q, k = 0.004, 0.05, 50
    belt = Belt(12.5)
    data = _data(belt, T, q)
    p = eb.StepLP(belt, data, k * T - 0.05, k * T + 0.3, 0.002, FRAME).best_block(
        T, 2.0, k, 1, 1.0)
    assert p is not None and eb.verify(belt, data, p, FRAME)
    p.jerk = p.jerk * 1.5
    assert not eb.verify(belt, data, p, FRAME)


def _single(q, T):
    belt = Belt(300.0, ((0.2, 600.0, 800.0, J),))
    data = _data(belt, T, q, n=round(0.5 / T), latency=1)
    ks = np.arange(round(0.2 / T), round(0.3 / T))
    r = eb.step_pairs(belt, data, T, 1.0, 0.2, ks, [], FRAME, ahead_s=0.045)
    assert r.single is not None
    return float(r.single.gap_mm[0])


def test_bound_grows_with_the_count_and_the_cycle():
    g = {(q, T): _single(q, T) for q in (0.01, 0.05) for T in (0.002, 0.004)}
    assert g[(0.05, 0.002)] > g[(0.01, 0.002)]
    assert g[(0.05, 0.004)] > g[(0.01, 0.004)]
    assert g[(0.01, 0.004)] > g[(0.01, 0.002)]
    assert g[(0.05, 0.004)] > g[(0.05, 0.002)]
    # and never above what the spread bound allows any two consistent belts
    for (q, T), gap in g.items():
        t = (np.arange(round(0.5 / T)) - 1) * T
        valid = np.ones(len(t), dtype=bool)
        worst = max(eb.spread_bound(t, valid, k, (k + 1) * T, q, J)
                    for k in range(round(0.2 / T), round(0.26 / T)))
        assert gap <= worst


def test_p99_argument_counts_blocks():
    """E' steps of m cycles each must cover (E' + 1)(r - 1) + 1 samples."""
    assert eb.needed_block(1, 5) == 9
    assert eb.needed_block(4, 5) == 6
    assert eb.needed_block(7, 4) == 4
