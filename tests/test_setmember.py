"""benchmarks/setmember.py: the set of belts within JerkMax consistent with the counts
(docs/spec/master-conditioning.md#5.4) -- the true belt is in it, the triples' intersection
is an outer bound of the LP's range and, over all triples, equal to it."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("scipy")

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import setmember as sm  # noqa: E402
from controller.simulate.encoder import Belt, EncoderSim  # noqa: E402

J = 5000.0


@pytest.mark.parametrize("q, T, seed", [(0.05, 0.004, 1), (0.05, 0.002, 2), (0.01, 0.004, 3)])
def test_true_belt_in_both_ranges_and_triples_outer_bound(q, T, seed):
    """At the setpoint time 2 cycles after the newest sample (latency 1, lead 1), during an
    S-curve at JerkMax: the true position is within the LP's range and the triples' range;
    every triple's interval contains the LP's range; over all triples of the window the two
    agree to 5 um (an outer bound, not always exact)."""
    belt = Belt(300.0, ((0.1, 650.0, 700.0, J),))
    n = 140
    stream = EncoderSim(q, 1, 0.1, seed=seed).samples(belt, T, n)
    window = 20
    s = sm.SetMember(q, J, window * T, T)
    tri = sm._all_triples(window)
    checked = 0
    for k in range(n):
        x, off = stream.sample(k)
        s.add((k - 1) * T + off, x)
        if k < 40 or k % 7:
            continue
        t_sp = (k + 1) * T
        truth = belt.state(t_sp)[0]
        r = s.range_at(t_sp)
        assert r is not None
        lo, hi = r[0], r[1]
        assert lo - 1e-6 <= truth <= hi + 1e-6
        tlo, thi = sm.triple_range(s.t, s.z, t_sp, q, J, tri)
        assert tlo - 1e-6 <= truth <= thi + 1e-6
        assert tlo <= lo + 1e-6 and thi >= hi - 1e-6
        assert abs(tlo - lo) < 5e-3 and abs(thi - hi) < 5e-3
        checked += 1
    assert checked >= 10


def test_range_grows_with_the_count():
    """Coarser counts, wider set (same belt and instants)."""
    T = 0.002
    belt = Belt(400.0, ((0.05, 200.0, 500.0, J),))
    widths = []
    for q in (0.001, 0.01, 0.05):
        stream = EncoderSim(q, 1, 0.0).samples(belt, T, 80)
        s = sm.SetMember(q, J, 0.06, T)
        for k in range(80):
            x, off = stream.sample(k)
            s.add((k - 1) * T + off, x)
        r = s.range_at(81 * T)
        assert r is not None
        widths.append(r[1] - r[0])
    assert widths[0] < widths[1] < widths[2]
