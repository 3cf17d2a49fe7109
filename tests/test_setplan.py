"""benchmarks/setplan.py: the output planned inside the set's future range
(docs/spec/master-conditioning.md#5.4.1) -- the range ahead contains the true belt, the
per-step jerk range is what it claims and leaves a u within the envelope, and where the
kept output is well inside the set the plan leaves it alone."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import setplan as sp  # noqa: E402
from controller.simulate.encoder import Belt, EncoderSim  # noqa: E402
from controller.tracking.conditioning import (  # noqa: E402
    ConditioningParams,
    EncoderModel,
    MasterConditioner,
)

J = 5000.0


@pytest.mark.parametrize("q, T, seed", [(0.05, 0.004, 1), (0.05, 0.001, 2), (0.01, 0.002, 3)])
def test_range_ahead_contains_the_true_belt(q, T, seed):
    """During an S-curve at JerkMax, at every horizon instant (up to 60 ms ahead of the
    setpoint time) the true position is inside the triples' range (unshrunk), and the range
    widens with the distance ahead."""
    belt = Belt(300.0, ((0.1, 650.0, 700.0, J),))
    n = round(0.6 / T)
    stream = EncoderSim(q, 1, 0.1, seed=seed).samples(belt, T, n)
    p = sp.SetPlanInput(T, q, horizon_s=0.06, shrink=0.0)
    checked = 0
    for k in range(n):
        x, off = stream.sample(k)
        p.t.append((k - 1) * T + off)
        p.z.append(x)
        if len(p.t) > p.n:
            del p.t[0], p.z[0]
        if len(p.t) < sp.MIN_SAMPLES or k % 5:
            continue
        t_sp = (k + 1) * T
        lo, hi = p.range_ahead(t_sp)
        truth = belt.positions(t_sp + p.hs)
        assert np.all(lo - 1e-9 <= truth) and np.all(truth <= hi + 1e-9)
        assert hi[-1] - lo[-1] > hi[0] - lo[0]
        checked += 1
    assert checked >= 20


def test_jerk_range_keeps_the_path_inside_and_a_u_in_the_envelope():
    """Random output states and edges: without a conflict the jerk range meets the
    envelope (eq. 4.3); at its ends the braking path is on or inside the edges at every
    instant that some u of the envelope can meet."""
    rng = np.random.default_rng(7)
    T, Jout, A, V = 0.002, 4 * J, 1000.0, 1000.0
    Jb = 0.25 * Jout
    hs = np.arange(0, 31, 3) * T
    n_ok = n_conflict = 0
    for _ in range(2000):
        y = (0.0, rng.uniform(-5, 5), rng.uniform(-300, 300))
        free = sp.path_after(y, 0.0, hs, T, 0.0)
        c = free + rng.normal(0, 0.05, hs.size)
        w = rng.uniform(0.01, 0.3) * (1 + 10 * hs)
        lo, hi = c - w, c + w
        env = sp.envelope(y, T, Jout, A, V)
        assert env[0] <= env[1]
        u_lo, u_hi = sp.jerk_range(y, hs, lo, hi, T, env, Jb)
        assert u_hi >= env[0] and u_lo <= env[1]
        meet_hi = sp.path_after(y, env[0], hs, T, -Jb) <= hi + 1e-12
        meet_lo = sp.path_after(y, env[1], hs, T, Jb) >= lo - 1e-12
        if meet_hi.any():
            ph = sp.path_after(y, u_hi, hs, T, -Jb)
            assert np.all(ph[meet_hi] <= hi[meet_hi] + 1e-9)
        if meet_lo.any():
            pl = sp.path_after(y, u_lo, hs, T, Jb)
            assert np.all(pl[meet_lo] >= lo[meet_lo] - 1e-9)
        if u_lo <= u_hi:
            n_ok += 1
            assert max(u_lo, env[0]) <= min(u_hi, env[1])
        else:
            n_conflict += 1
    assert n_ok > 500 and n_conflict > 10


@pytest.mark.parametrize("q, T", [(0.001, 0.001), (0.01, 0.002)])
def test_clean_constant_speed_belt_leaves_the_kept_output_alone(q, T):
    """A clean encoder (no glitches) on a belt at constant speed, the set unshrunk: the kept
    output's braking paths stay inside the set's range, the plan never changes its jerk, and
    the planned output is the kept conditioner's, bit for bit.  (The middle half, the
    study's --shrink 0.25, is left by the kept output now and then even there.)"""
    n = round(1.2 / T)
    stream = EncoderSim(q, 1, 0.1, seed=4).samples(Belt(400.0), T, n)
    p = sp.SetPlanInput(T, q, horizon_s=0.06, shrink=0.0)
    kept = MasterConditioner(ConditioningParams(T, EncoderModel(q, 1), sp.eb.FRAME))
    for k in range(n):
        x, off = stream.sample(k)
        a = p.update(x, off)
        b = kept.update(x, off)
        assert a == (b.pos, b.vel, b.acc, b.jerk, b.valid)
    assert p.n_cycles > n // 2 and p.n_bind == 0
