"""How fast can any planner that keeps the vector-norm limits synchronise?  A lower bound.

Run from the repository root::

    python benchmarks/norm_bound.py              # the 3-D random cases of benchmarks/tracking.py
    python benchmarks/norm_bound.py --cases 60

The per-axis reference (``benchmarks/reference.py``) gives every axis the whole V, A, J; its
robot may move at up to sqrt(3) x the norm limits.  A planner that keeps the norms cannot in
general be as fast.  For every 3-D random case of the planner table this computes a lower
bound on the time any norm-keeping plan needs (docs/spec/master-conditioning.md#7):

projected on a unit direction u, the relative motion s = u.e (e = robot - master) must go
from u.e0 to rest at 0, with |u.v_m(t) + s'| <= ||v|| <= V, |u.a_m + s''| <= A and
|s'''| <= J.  The master's velocity changes linearly over the plan, so over the horizon
[0, H] the velocity bounds are loosened to their widest; with H = the ``optimal`` planner's
own time to sync (at least the optimum, since that planner keeps the norms) the 1-D
time-optimal duration of the projection (Ruckig, exact for one axis) is a lower bound, for
every u; the bound is its maximum over u (a Fibonacci sphere of 600 directions, the axes
and the offset's direction, refined by a local search).  Prints, per case and as median / p90: optimal / reference, bound /
reference, optimal / bound.  Deterministic for a seed.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from ruckig import InputParameter, Ruckig, Trajectory  # noqa: E402

from benchmarks import tracking as bt  # noqa: E402

#: Ruckig works in SI-like magnitudes (optimal.py): lengths in m
_S = 1e-3


def _duration_1d(s0: float, v0: float, a0: float, vlo: float, vhi: float, alo: float,
                 ahi: float, jerk: float) -> float | None:
    """Time-optimal duration [s] from (s0, v0, a0) [mm, mm/s, mm/s^2] to rest at 0 within
    the velocity/acceleration bounds and |jerk| [mm/s^3]; None if Ruckig finds none."""
    rk, inp, traj = Ruckig(1), InputParameter(1), Trajectory(1)
    inp.current_position = [s0 * _S]
    inp.current_velocity = [v0 * _S]
    inp.current_acceleration = [a0 * _S]
    inp.target_position = [0.0]
    inp.target_velocity = [0.0]
    inp.target_acceleration = [0.0]
    inp.min_velocity, inp.max_velocity = [vlo * _S], [vhi * _S]
    inp.min_acceleration, inp.max_acceleration = [alo * _S], [ahi * _S]
    inp.max_jerk = [jerk * _S]
    try:
        ok = int(rk.calculate(inp, traj)) >= 0
    except Exception:  # noqa: BLE001 - the binding raises on unknown result codes
        return None
    return traj.duration if ok else None


def projected_duration(case: bt.Case, u: np.ndarray, horizon_s: float) -> float | None:
    """The 1-D time-optimal duration [s] of the case projected on the unit vector u."""
    lim = bt.LIMIT_SETS[case.limits]
    e0 = np.array(case.robot_pos)
    vm0, am = np.array(case.master_vel), np.array(case.master_acc)
    sv = float(u @ (np.array(case.robot_vel) - vm0))
    m0, m1 = float(u @ vm0), float(u @ (vm0 + am * horizon_s))
    vlo, vhi = -lim.vel - max(m0, m1), lim.vel - min(m0, m1)
    if not vlo < sv < vhi:
        return None
    ua = float(u @ am)
    return _duration_1d(float(u @ e0), sv, -ua, vlo, vhi, -lim.acc - ua, lim.acc - ua,
                        lim.jerk)


def _sphere(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi = np.arccos(1.0 - 2.0 * i / n)
    th = math.pi * (1.0 + 5.0 ** 0.5) * i
    return np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)


def lower_bound_s(case: bt.Case, horizon_s: float, seed: int = 0) -> float:
    """max over u of the projected duration [s], at most ``horizon_s``."""
    rng = np.random.default_rng(seed)
    best, bu = 0.0, np.array([1.0, 0.0, 0.0])
    e0 = np.array(case.robot_pos)
    extra = [np.eye(3)[i] * s for i in range(3) for s in (1.0, -1.0)]
    if np.linalg.norm(e0) > 0.0:
        extra += [e0 / np.linalg.norm(e0), -e0 / np.linalg.norm(e0)]
    for u in list(_sphere(600)) + extra:
        t = projected_duration(case, u, horizon_s)
        if t is not None and t > best:
            best, bu = t, u
    step = 0.1
    for _ in range(60):
        c = bu + rng.normal(size=3) * step
        c /= np.linalg.norm(c)
        t = projected_duration(case, c, horizon_s)
        if t is not None and t > best:
            best, bu = t, c
        else:
            step *= 0.93
    return min(best, horizon_s)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--cases", type=int, default=200, help="random cases (half are 3-D)")
    args = ap.parse_args(argv)
    cases, _ = bt.random_cases(args.seed, args.cases)
    bt.register_reference()
    rows = []
    for c in (c for c in cases if c.dim == 3):
        m = bt.master_states(c)
        ref = bt.run_case(c, "reference", m)["time_to_sync_s"]
        run = bt.run_case(c, bt.DEFAULT_PLANNER, m)
        opt = run["time_to_sync_s"]
        if ref is None or opt is None or not run["success"]:
            print(f"{c.id}: not synchronised (reference {ref}, optimal {opt})")
            continue
        lb = lower_bound_s(c, opt)
        rows.append((opt / ref, lb / ref, opt / lb))
        print(f"{c.id} T={c.T * 1e3:g} ms {c.limits}: reference {ref:.3f} s, optimal "
              f"{opt:.3f} s, bound {lb:.3f} s")
    a = np.array(rows)

    def q(col: int, p: float) -> float:
        return float(np.quantile(a[:, col], p))
    res = {"n": len(rows), "optimal_ref": (q(0, 0.5), q(0, 0.9)),
           "bound_ref": (q(1, 0.5), q(1, 0.9)), "optimal_bound": (q(2, 0.5), q(2, 0.9)),
           "optimal_bound_max": float(a[:, 2].max())}
    print(f"\n{len(rows)} 3-D cases (seed {args.seed}), median / p90:\n"
          f"  optimal / reference      {res['optimal_ref'][0]:.3f} / {res['optimal_ref'][1]:.3f}\n"
          f"  bound / reference        {res['bound_ref'][0]:.3f} / {res['bound_ref'][1]:.3f}"
          "   (no norm-keeping planner can be below this)\n"
          f"  optimal / bound          {res['optimal_bound'][0]:.3f} / "
          f"{res['optimal_bound'][1]:.3f} (max {res['optimal_bound_max']:.3f})")
    return res


if __name__ == "__main__":
    main()
