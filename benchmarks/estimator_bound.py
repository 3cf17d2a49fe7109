"""A lower bound on the S-curve following error of ANY causal estimator, by indistinguishability.

Run from the repository root::

    python benchmarks/estimator_bound.py             # the encoder benchmark's 9 cells
    python benchmarks/estimator_bound.py --quick     # its --quick belts (1 per cell)

docs/spec/master-conditioning.md#5.3.  Per cell (count size q x cycle T) the encoder
benchmark's belt at JerkMax (``benchmarks/encoder.py``, the same seed, the same encoder
stream: sampling instants, glitches, missing samples) is belt A.  For each jerk step of A
(at theta_e) an alternative belt B_e = A + d is built by a linear program over d's jerk,
piecewise constant on a grid of step h (2 ms, or T/2 if longer):

- B_e is physically possible: its jerk within +-JerkMax, its acceleration within
  +-AccelerationMax (its speed is checked within VelocityMax), it equals A before
  t_a = theta_e - ``back_s`` and again after t_b (d's position, speed and acceleration 0);
- B_e gives exactly A's received data up to cycle k*: at every sample instant t_i,
  i <= k*, not missing, B_e(t_i) lies in A's count interval [(c_i - 1/2) q, (c_i + 1/2) q)
  (round half up, ``EncoderSim.quantise``; with a margin ``eps_mm`` inside), so the counts,
  and the received values with A's glitches added, are the same;
- objective: the smallest gap |d(t_sp(k))| over a block of m consecutive cycles
  k* - m + 1 .. k*, t_sp(k) = (k + lead) T the setpoint time, maximised (sign fixed).

Every LP solution is re-checked outside the LP (the counts recomputed with
``EncoderSim.quantise``, the jerk, acceleration and speed limits): a belt that fails is
dropped, so each figure rests on an explicit pair of belts.

Any causal estimator gives the same estimate on A and B_e at every cycle k <= k*, so there
err_A(k) + err_B(k) >= g_k = |d(t_sp(k))|.  Over the S-curve samples S (N cycles; the
benchmark's "S-curve" set: setpoint time within a speed change or 0.25 s after it, from the
engage + 50 ms on), with r = ceil(N/100) + 1: if blocks of m_e cycles (disjoint, between
consecutive steps) with gaps >= 2X are found for E' steps and sum m_e >= (E' + 1)(r - 1) + 1,
then A and the B_e cannot all have fewer than r samples of S with an error >= X (every
block cycle is bad for A or for its B_e; A has at most r - 1 of them).  Hence, proved:

    for any causal estimator, on at least one of the belts A, B_1 .. B_E' (all physically
    possible, each with the benchmark's data model), at least r of the N S-curve samples
    (more than 1 %) have a following error >= X  -- its p99 (numpy, linear) is >= X.

X is the largest such value found.  Also printed: the single-sample bound max_k g_k / 2
(for one cycle: max(err_A, err_B) >= g/2 there), and the ceiling of every such argument,
``spread_bound`` (eq. 5.3): how far apart ANY two belts within JerkMax with the same counts
can be at the setpoint time, halved -- what a set-membership estimate achieves.  Pure arithmetic plus scipy's HiGHS LP
(a benchmark-only dependency).
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from controller.simulate.encoder import Belt, EncoderSim  # noqa: E402


@dataclass(frozen=True)
class Frame:
    """The moving frame's limits [mm/s, mm/s^2, mm/s^3]."""

    vel: float = 1000.0
    acc: float = 1000.0
    jerk: float = 5000.0


@dataclass(frozen=True)
class Data:
    """What the controller received: per cycle i the sampling instant t_i [s] and the count
    interval [lo_i, hi_i) [mm] the belt was in (NaN: missing sample, no constraint)."""

    t_s: np.ndarray
    lo_mm: np.ndarray
    hi_mm: np.ndarray


def received(belt: Belt, t_s: np.ndarray, q_mm: float,
             missing: np.ndarray | None = None) -> Data:
    """The count intervals of ``belt`` at the instants ``t_s`` (round half up; q = 0: the
    position itself, an unquantised encoder)."""
    x = belt.positions(np.asarray(t_s, dtype=float))
    if q_mm > 0.0:
        c = np.floor(x / q_mm + 0.5)
        lo, hi = (c - 0.5) * q_mm, (c + 0.5) * q_mm
    else:
        lo, hi = x.copy(), x.copy()
    if missing is not None:
        lo = np.where(missing, np.nan, lo)
        hi = np.where(missing, np.nan, hi)
    return Data(np.asarray(t_s, dtype=float), lo, hi)


def _kernel(t: np.ndarray, s0: np.ndarray, h: float, order: int) -> np.ndarray:
    """The contribution to d's position (order 0), speed (1), acceleration (2) at the times
    ``t`` of a unit jerk [mm/s^3] on each piece [s0_p, s0_p + h)."""
    a = np.clip(t[:, None] - s0[None, :], 0.0, None)
    b = np.clip(a - h, 0.0, None)
    p = 3 - order
    return (a ** p - b ** p) / math.factorial(p)


@dataclass
class Pair:
    """An alternative belt B = A + d: d's jerk [mm/s^3] on pieces from ``t_a`` [s] of ``h``;
    indistinguishable up to cycle ``k_last``; gaps ``gap_mm`` at the setpoints of ``ks``."""

    t_a: float
    h: float
    jerk: np.ndarray
    k_last: int
    ks: np.ndarray
    gap_mm: np.ndarray

    def d(self, t: np.ndarray, order: int = 0) -> np.ndarray:
        s0 = self.t_a + self.h * np.arange(len(self.jerk))
        return _kernel(np.asarray(t, dtype=float), s0, self.h, order) @ self.jerk


def _jerk_bounds(belt: Belt, s0: np.ndarray, h: float, frame: Frame):
    """d's jerk on each piece so that A + d keeps |jerk| <= JerkMax whatever A does there."""
    lo = np.full(len(s0), -np.inf)
    hi = np.full(len(s0), np.inf)
    starts = np.array([pc[0] for pc in belt.pieces])
    for p, s in enumerate(s0):
        inside = [s] + [x for x in starts if s < x < s + h]
        for t in inside:
            j = belt.state(float(t))[3]
            lo[p] = max(lo[p], -frame.jerk - j)
            hi[p] = min(hi[p], frame.jerk - j)
    return lo, hi


class StepLP:
    """The LP's fixed part for one window [t_a, t_b): d's jerk pieces of ``h``, their bounds
    (A + d keeps |jerk| <= JerkMax), the acceleration rows, d back to 0 at t_b, and the
    count rows of every received sample in the window."""

    def __init__(self, belt: Belt, data: Data, t_a: float, t_b: float, h: float,
                 frame: Frame = Frame(), eps_mm: float = 1e-7) -> None:
        self.belt, self.data, self.t_a, self.h, self.frame = belt, data, t_a, h, frame
        n = self.n = int(math.ceil((t_b - t_a) / h - 1e-9))
        s0 = self.s0 = t_a + h * np.arange(n)
        self.t_b = t_b = t_a + n * h
        self.jl, self.jh = _jerk_bounds(belt, s0, h, frame)
        starts = np.array([pc[0] for pc in belt.pieces[1:]])
        tn = np.unique(np.concatenate([s0[1:], [t_b], starts[(starts > t_a) & (starts < t_b)]]))
        aa = belt.states(tn)[:, 2]
        Ka = _kernel(tn, s0, h, 2)
        self.acc_rows = np.vstack([Ka, -Ka])
        self.acc_rhs = np.concatenate([frame.acc - aa, frame.acc + aa])
        self.eq_rows = np.vstack([_kernel(np.array([t_b]), s0, h, o) for o in (0, 1, 2)])
        sel = (data.t_s > t_a) & (data.t_s < t_b) & ~np.isnan(data.lo_mm)
        self.sample_k = np.nonzero(sel)[0]
        ti = data.t_s[sel]
        xa = belt.positions(ti)
        lo, hi = data.lo_mm[sel], data.hi_mm[sel]
        pad = np.where(hi - lo > 0.0, eps_mm, 0.0)
        self.Ki = _kernel(ti, s0, h, 0)
        self.count_hi = hi - pad - xa
        self.count_lo = lo + pad - xa

    def best_block(self, T: float, lead: float, k_last: int, m: int, sign: float) -> Pair | None:
        """max z s.t. sign * d(t_sp(k)) >= z for the m cycles up to ``k_last`` (t_sp(k) =
        (k + lead) T), B = A + d within the limits and in A's counts at every sample instant
        up to ``k_last``.  None if infeasible or not verified."""
        from scipy.optimize import linprog

        n = self.n
        ks = np.arange(k_last - m + 1, k_last + 1)
        K = _kernel((ks + lead) * T, self.s0, self.h, 0)
        use = self.sample_k <= k_last
        Ki = self.Ki[use]
        A_ub = np.vstack([np.hstack([-sign * K, np.ones((m, 1))]),
                          np.hstack([Ki, np.zeros((len(Ki), 1))]),
                          np.hstack([-Ki, np.zeros((len(Ki), 1))]),
                          np.hstack([self.acc_rows, np.zeros((len(self.acc_rows), 1))])])
        b_ub = np.concatenate([np.zeros(m), self.count_hi[use], -self.count_lo[use],
                               self.acc_rhs])
        A_eq = np.hstack([self.eq_rows, np.zeros((3, 1))])
        c = np.zeros(n + 1)
        c[-1] = -1.0
        res = linprog(c, A_ub=A_ub, b_ub=b_ub, A_eq=A_eq, b_eq=np.zeros(3),
                      bounds=list(zip(self.jl, self.jh)) + [(None, None)], method="highs")
        if res.status != 0 or res.x[-1] <= 0.0:
            return None
        pair = Pair(self.t_a, self.h, res.x[:n], k_last, ks, np.abs(K @ res.x[:n]))
        return pair if verify(self.belt, self.data, pair, self.frame) else None


def verify(belt: Belt, data: Data, pair: Pair, frame: Frame = Frame(), q_mm: float | None = None,
           tol: float = 1e-9) -> bool:
    """B = A + d outside the LP: in A's count interval at every received sample up to
    ``k_last`` (half-open, as the counter rounds), its jerk, acceleration and speed within
    the frame's limits (jerk: 1e-9 relative slack for the LP's rounding), d = 0 at the end."""
    idx = np.arange(pair.k_last + 1)
    ok = ~np.isnan(data.lo_mm[idx])
    ti = data.t_s[idx][ok]
    xb = belt.positions(ti) + pair.d(ti)
    lo, hi = data.lo_mm[idx][ok], data.hi_mm[idx][ok]
    point = hi == lo
    inside = np.where(point, np.abs(xb - lo) <= 1e-9, (xb >= lo) & (xb < hi))
    if not inside.all():
        return False
    n = len(pair.jerk)
    s0 = pair.t_a + pair.h * np.arange(n)
    tt = np.linspace(pair.t_a, pair.t_a + n * pair.h, 8 * n + 1)
    st = belt.states(tt)
    if np.max(np.abs(st[:, 2] + pair.d(tt, 2))) > frame.acc * (1 + tol):
        return False
    if np.max(np.abs(st[:, 1] + pair.d(tt, 1))) > frame.vel * (1 + tol):
        return False
    jl, jh = _jerk_bounds(belt, s0, pair.h, frame)
    slack = frame.jerk * 1e-9
    if np.any(pair.jerk < jl - slack) or np.any(pair.jerk > jh + slack):
        return False
    end = np.array([pair.t_a + n * pair.h])
    return all(abs(float(pair.d(end, o)[0])) <= 1e-9 for o in (0, 1, 2))


def jerk_steps(belt: Belt) -> list[float]:
    """The instants [s] where A's jerk changes."""
    out = []
    for (_t0, *_r, j0), (t1, *_s, j1) in zip(belt.pieces, belt.pieces[1:]):
        if j1 != j0:
            out.append(t1)
    return out


def needed_block(n_steps: int, r: int) -> int:
    """Cycles per step so that n_steps blocks cover (n_steps + 1)(r - 1) + 1 samples."""
    return math.ceil(((n_steps + 1) * (r - 1) + 1) / n_steps)


@dataclass
class StepResult:
    """One jerk step: the best single-cycle pair and, per block length m, the best pair."""

    theta_s: float
    single: Pair | None
    blocks: dict[int, Pair]


def step_pairs(belt: Belt, data: Data, T: float, lead: float, theta: float,
               ks_allowed: np.ndarray, block_lengths: list[int], frame: Frame = Frame(),
               back_s: float = 0.08, ahead_s: float = 0.08, recover_s: float = 0.25,
               h: float | None = None) -> StepResult:
    """The jerk step at ``theta``: the single-cycle optimum over the cycles of
    ``ks_allowed`` whose setpoint is within ``ahead_s`` after it, then for each block length
    the best block ending at most a block after that cycle (blocks of consecutive cycles of
    ``ks_allowed``, both signs)."""
    h = h or max(T / 2.0, 0.002)
    lp = StepLP(belt, data, theta - back_s, theta + ahead_s + lead * T + recover_s + T, h, frame)
    allowed = {int(k) for k in ks_allowed}
    best: Pair | None = None
    sign0 = 1.0
    for k in sorted(allowed):
        if (k + lead) * T - theta > ahead_s:
            break
        for sign in (1.0, -1.0):
            p = lp.best_block(T, lead, k, 1, sign)
            if p is not None and (best is None or p.gap_mm[0] > best.gap_mm[0]):
                best, sign0 = p, sign
    res = StepResult(theta, best, {})
    if best is None:
        return res
    k0 = best.k_last
    for m in sorted(set(block_lengths)):
        for k_last in sorted({k0, k0 + m // 4, k0 + m // 2, k0 + (3 * m) // 4, k0 + m - 1}):
            if (k_last + lead) * T - theta > ahead_s or not all(
                    k in allowed for k in range(k_last - m + 1, k_last + 1)):
                continue
            for sign in (sign0, -sign0):
                p = lp.best_block(T, lead, k_last, m, sign)
                if p is not None and (m not in res.blocks
                                      or p.gap_mm.min() > res.blocks[m].gap_mm.min()):
                    res.blocks[m] = p
    return res


def p99_bound(steps: list[StepResult], r: int) -> tuple[float, int, int]:
    """(X [mm], steps used E', cycles per step m) of the module docstring's argument: the
    E'-th largest smallest gap over blocks of m = needed_block(E', r) cycles, halved,
    maximised over E'."""
    best = (0.0, 0, 0)
    for e in range(1, len(steps) + 1):
        m = needed_block(e, r)
        z = sorted((float(s.blocks[m].gap_mm.min()) for s in steps if m in s.blocks),
                   reverse=True)
        if len(z) >= e and z[e - 1] / 2.0 > best[0]:
            best = (z[e - 1] / 2.0, e, m)
    return best


def cell_bound(belt: Belt, enc: EncoderSim, T: float, n_cycles: int, k_from: int, lead: float,
               settle_s: float, frame: Frame = Frame()) -> dict:
    """The bound for one benchmark belt: S, its jerk steps, their pairs, X and the
    single-sample bound."""
    stream = enc.samples(belt, T, n_cycles)
    k = np.arange(n_cycles)
    t_s = (k - enc.latency_samples) * T + stream.time_offset_s
    data = received(belt, t_s, enc.resolution_mm, np.isnan(stream.position_mm))
    t_sp = (k + lead) * T
    in_s = belt.in_change(t_sp, settle_s) & (k >= k_from)
    n_s = int(in_s.sum())
    r = math.ceil(n_s / 100) + 1
    thetas = [th for th in jerk_steps(belt) if in_s[(t_sp >= th)].any()]
    lengths = [needed_block(e, r) for e in range(1, len(thetas) + 1)]
    steps = []
    for e, th in enumerate(thetas):
        nxt = thetas[e + 1] if e + 1 < len(thetas) else math.inf
        ks = k[in_s & (t_sp >= th) & (t_sp < nxt)]
        steps.append(step_pairs(belt, data, T, lead, th, ks, lengths, frame))
    x, used, m = p99_bound(steps, r)
    single = max((float(s.single.gap_mm[0]) / 2.0 for s in steps if s.single is not None),
                 default=0.0)
    # glitched samples identified (the gate, docs/spec/master-conditioning.md#3.1): not nodes
    valid = ~np.isnan(stream.position_mm) & (stream.glitch_mm == 0.0)
    spread = max(spread_bound(t_s, valid, int(kk), float(t_sp[kk]), enc.resolution_mm,
                              frame.jerk) for kk in k[in_s])
    return {"n_samples": n_s, "r": r, "steps": len(thetas), "x_mm": x, "steps_used": used,
            "spread_mm": spread,
            "block": m, "single_mm": single, "results": steps}


def spread_bound(t_s: np.ndarray, valid: np.ndarray, k: int, t_sp: float, q_mm: float,
                 jerk: float, window: int = 48) -> float:
    """An upper bound [mm] on |B(t_sp) - C(t_sp)| for ANY two belts B, C with |jerk| <=
    ``jerk`` that gave the same counts at the valid samples up to cycle k: e = B - C has
    |e| < q at those instants and |e'''| <= 2 jerk, so by quadratic interpolation at three
    of them tau_j (the Peano kernel of the third divided difference is >= 0 with integral
    1/6) |e(t_sp)| <= q sum_j |l_j(t_sp)| + (2 jerk / 6) prod_j |t_sp - tau_j|, minimised
    over the triples of the last ``window`` samples (the newest two as the last node)."""
    idx = np.nonzero(valid[:k + 1])[0][-window:]
    tau = t_s[idx]
    n = len(tau)
    if n < 3:
        return math.inf
    best = math.inf
    i0, i1 = np.triu_indices(n - 1, 1)
    x = t_sp
    for i2 in range(max(2, n - 2), n):
        sel = i1 < i2
        a, b, c = tau[i0[sel]], tau[i1[sel]], tau[i2]
        la = (x - b) * (x - c) / ((a - b) * (a - c))
        lb = (x - a) * (x - c) / ((b - a) * (b - c))
        lc = (x - a) * (x - b) / ((c - a) * (c - b))
        v = q_mm * (np.abs(la) + np.abs(lb) + np.abs(lc)) + jerk / 3.0 * np.abs(
            (x - a) * (x - b) * (x - c))
        best = min(best, float(v.min()))
    return best


def benchmark_cells(seed: int, per_cell: int):
    """The encoder benchmark's JerkMax belt per cell, with its encoder and cycle window."""
    from benchmarks import encoder as be

    for case in be.belt_cases(seed, per_cell):
        if not case.at_jerk_max:
            continue
        T = case.T
        yield case, be._encoder(case), round(be.RUN_S / T), \
            round(case.engage_s / T) + round(be.SETTLE_S / T), be.SETTLE_CHANGE_S


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="the --quick benchmark's belts")
    ap.add_argument("--belts", type=int, default=None, help="belts per cell (default 4)")
    args = ap.parse_args(argv)
    from benchmarks import encoder as be

    per = args.belts or (1 if args.quick else 4)
    frame = Frame(be.FRAME.vel, be.FRAME.acc, be.FRAME.jerk)
    lead = 1.0  # the benchmark's setpoint time (k + 1) T
    print(f"benchmark belts at JerkMax {frame.jerk:g} mm/s^3 (seed {args.seed}, {per} per cell), "
          f"latency {be.LATENCY}, setpoint (k + {lead:g}) T\n")
    print("| count | cycle | S-curve samples N | r (> 1 %) | jerk steps in S | steps used × "
          "cycles each | any estimator: p99 >= X [mm] | one sample: max(err_A, err_B) >= "
          "[mm] | some estimator: error <= at every sample [mm] |")
    print("|---|---|---|---|---|---|---|---|---|")
    rows = []
    for case, enc, n, k_from, settle in benchmark_cells(args.seed, per):
        b = cell_bound(case.belt, enc, case.T, n, k_from, lead, settle, frame)
        b.update(count_mm=case.count_mm, T=case.T)
        rows.append(b)
        used = f"{b['steps_used']} × {b['block']}" if b["steps_used"] else "–"
        print(f"| {case.count_mm * 1e3:g} µm | {case.T * 1e3:g} ms | {b['n_samples']} | "
              f"{b['r']} | {b['steps']} | {used} | {b['x_mm']:.3f} | {b['single_mm']:.3f} | "
              f"{b['spread_mm'] / 2.0:.3f} |",
              flush=True)
    return rows


if __name__ == "__main__":
    main()
