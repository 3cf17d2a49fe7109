"""benchmarks/norm_bound.py: the lower bound on a norm-keeping plan's time to sync is a bound
(never above what the norm-keeping ``optimal`` planner achieves) and tight along one axis."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import norm_bound as nb  # noqa: E402
from benchmarks import tracking as bt  # noqa: E402
from benchmarks.reference import plan_duration_s  # noqa: E402


def _case(pos, vel=(0.0, 0.0, 0.0), mv=(300.0, 0.0, 0.0), limits="A", dim=3):
    z = (0.0, 0.0, 0.0)
    return bt.Case("t", "random", dim, 0.001, limits, mv, z, pos, vel)


def test_one_axis_bound_is_the_one_axis_optimum():
    c = _case((-100.0, 0.0, 0.0))
    lim = bt.LIMIT_SETS["A"]
    ref = plan_duration_s(lim, c.robot_pos, c.robot_vel, (0.0,) * 3, c.master_vel,
                          c.master_acc)
    b = nb.projected_duration(c, np.array([1.0, 0.0, 0.0]), 5.0)
    assert math.isclose(b, ref, rel_tol=1e-6)
    assert math.isclose(nb.lower_bound_s(c, 5.0), b, rel_tol=1e-9)


def test_diagonal_bound_exceeds_the_per_axis_reference_and_not_the_optimal_planner():
    """A diagonal offset: the per-axis reference moves every axis at the whole limits, a
    norm-keeping plan cannot; the bound lies between the two."""
    c = _case((-200.0, 200.0, 200.0), mv=(0.0, 0.0, 0.0), limits="B")
    lim = bt.LIMIT_SETS["B"]
    ref = plan_duration_s(lim, c.robot_pos, c.robot_vel, (0.0,) * 3, c.master_vel,
                          c.master_acc)
    bt.register_reference()
    opt = bt.run_case(c, "optimal", bt.master_states(c))
    assert opt["success"]
    lb = nb.lower_bound_s(c, opt["time_to_sync_s"])
    assert lb > 1.15 * ref
    assert lb <= opt["time_to_sync_s"] + 1e-9
