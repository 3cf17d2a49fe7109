"""Set-membership study: every count a hard interval, the frame's JerkMax a hard constraint.

docs/spec/master-conditioning.md#5.4.  Per cycle k, the belts consistent with the last
``window`` accepted samples are a polytope (the belt's position, speed and acceleration at
the window's first sample and its jerk per sample interval, |j| <= JerkMax; each sample
t_i inside its count interval [c_i - q/2, c_i + q/2] widened by ``EPS_MM``); two linear
programs (scipy's HiGHS, a prototype: a benchmark-only dependency) give the range
[p_lo, p_hi] of the belt's position at the setpoint time t_sp = (k + 1) T.  The true belt
is in the set (up to ``EPS_MM``), so ANY point of the range is within its width of the
truth, the midpoint within half of it.

Run from the repository root::

    python benchmarks/setmember.py --seeds 1-6 --cells 50um:2ms    # the offline study
    python benchmarks/setmember.py --seeds 1-6 --harness           # through the tracker

Offline (per cell, the benchmark's belt at JerkMax, ``benchmarks/encoder.py``'s belts,
encoder and glitches; outliers are the kept conditioner's, a sample that empties the set
is one too), following error to the true belt at t_sp, p99 over the S-curve samples (the
setpoint within a speed change or 0.25 s after it, from the engage + 50 ms on) and the
constant-speed ones, of:

- ``kept``: the kept conditioner's output (docs/spec/master-conditioning.md#4);
- ``kalman``: its estimate predicted to t_sp (no output stage);
- ``mid``: the set's midpoint (p_lo + p_hi) / 2 -- the set-membership estimate;
- ``kept->set``: the kept output clipped into [p_lo - m, p_hi + m] (a jump handed on, as
  the kept design's revisions, eq. 4.5), m = ``--margin`` [mm];
- ``width/2``: half the set's width (the mid's worst case at that sample).

``--harness`` runs the encoder benchmark's ``run_belt`` (the tracker, its sync limits, the
after-sync norms) with the ``kept->set`` conditioner as the master input and prints the
per-seed S-curve-at-JerkMax and constant-speed p99 beside the kept design's.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np
from scipy.optimize import linprog

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from benchmarks import encoder as eb  # noqa: E402
from benchmarks.encoder_seeds import _cells, _seeds  # noqa: E402
from controller.tracking.conditioning import (  # noqa: E402
    ConditioningParams,
    EncoderModel,
    EventKind,
    MasterConditioner,
    _low_gain,
)

#: the count interval widened by this [mm]: the LP's jerk is constant per sample interval,
#: the belt's steps inside one (J h^3 / 6 < 1e-4 mm for h <= 4 ms at 5000 mm/s^3)
EPS_MM = 1e-4
#: the LP's time unit [s] (scaling: positions mm, times in units of 10 ms)
_U = 0.01
#: the triples of the last samples tried
TRI_MAX = 20000


class SetMember:
    """The belts within JerkMax consistent with the last samples: the range of the
    position at a given instant, by two LPs."""

    def __init__(self, q_mm: float, jerk: float, window_s: float, T: float) -> None:
        self.q = q_mm
        self.J = jerk * _U ** 3  # mm / u^3
        self.n = max(6, math.ceil(window_s / T))
        self.t: list[float] = []
        self.z: list[float] = []
        self.n_lp = 0
        self.lp_s = 0.0

    def add(self, t_s: float, z_mm: float) -> None:
        self.t.append(t_s)
        self.z.append(z_mm)
        if len(self.t) > self.n:
            del self.t[0], self.z[0]

    def drop_last(self) -> None:
        self.t.pop()
        self.z.pop()

    def range_at(self, t_s: float) -> tuple[float, float, np.ndarray, np.ndarray] | None:
        """(p_lo, p_hi, state_lo, state_hi) at ``t_s`` [mm]; the states (p, v, a, j) of the
        two extreme belts there [mm, mm/s, ...]; None: the set is empty (or too few
        samples)."""
        N = len(self.t)
        if N < 4:
            return None
        t0 = self.t[0]
        tau = (np.asarray(self.t) - t0) / _U
        ts = (t_s - t0) / _U
        z0 = self.z[0]
        zs = np.asarray(self.z) - z0
        s = np.append(tau, ts)  # knots: the jerk is constant between them
        J = self.J

        def rows(x: np.ndarray, order: int) -> np.ndarray:
            D = np.clip(x[:, None] - s[None, :], 0.0, None)
            f = math.factorial(3 - order)
            C = (D[:, :-1] ** (3 - order) - D[:, 1:] ** (3 - order)) / f
            if order == 0:
                base = np.stack([np.ones_like(x), x, x * x / 2], 1)
            elif order == 1:
                base = np.stack([np.zeros_like(x), np.ones_like(x), x], 1)
            else:
                base = np.stack([np.zeros_like(x), np.zeros_like(x), np.ones_like(x)], 1)
            return np.hstack([base, J * C])

        Ap = rows(tau, 0)
        half = self.q / 2.0 + EPS_MM
        A_ub = np.vstack([Ap, -Ap])
        b_ub = np.concatenate([zs + half, -(zs - half)])
        c = rows(np.array([ts]), 0)[0]
        bounds = [(None, None)] * 3 + [(-1.0, 1.0)] * N
        out = []
        t_clock = time.perf_counter()
        for sign in (1.0, -1.0):
            r = linprog(sign * c, A_ub=A_ub, b_ub=b_ub, bounds=bounds, method="highs")
            self.n_lp += 1
            if r.status != 0:
                self.lp_s += time.perf_counter() - t_clock
                return None
            out.append(r.x)
        self.lp_s += time.perf_counter() - t_clock
        at = np.array([ts])
        st = []
        for x in out:
            p = float(rows(at, 0)[0] @ x) + z0
            v = float(rows(at, 1)[0] @ x) / _U
            a = float(rows(at, 2)[0] @ x) / _U ** 2
            j = float(x[-1]) * J / _U ** 3
            st.append(np.array([p, v, a, j]))
        return st[0][0], st[1][0], st[0], st[1]


KEYS = ("kept", "kalman", "mid", "clip", "half", "kal_clip", "clip_s", "tri_half", "tri_mid",
        "tri_clip_s")


def triple_edges(t: np.ndarray, z: np.ndarray, tri: np.ndarray, ts: np.ndarray, q_mm: float,
                 jerk: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) [mm]: the range of the position at each instant of ``ts`` [s] that every belt
    within ``jerk`` [mm/s^3] through the counts (instants ``t`` [s], positions ``z`` [mm],
    count ``q_mm``) must be in, by quadratic interpolation through each of the index triples
    ``tri`` into t, z and the Peano bound of its remainder (eq. 5.3 for one belt:
    |p - P2| <= J/6 prod |t_s - t_j|): the intersection of the triples' intervals (an outer
    bound of the LP's range)."""
    tt = t[tri]  # (m, 3)
    zz = z[tri]
    d = ts[None, :, None] - tt[:, None, :]  # (m, h, 3)
    t0, t1, t2 = tt[:, 0, None], tt[:, 1, None], tt[:, 2, None]
    l0 = d[:, :, 1] * d[:, :, 2] / ((t0 - t1) * (t0 - t2))
    l1 = d[:, :, 0] * d[:, :, 2] / ((t1 - t0) * (t1 - t2))
    l2 = d[:, :, 0] * d[:, :, 1] / ((t2 - t0) * (t2 - t1))
    c = l0 * zz[:, 0, None] + l1 * zz[:, 1, None] + l2 * zz[:, 2, None]
    r = ((q_mm / 2 + EPS_MM) * (np.abs(l0) + np.abs(l1) + np.abs(l2))
         + jerk / 6 * np.abs(d[:, :, 0] * d[:, :, 1] * d[:, :, 2]))
    return np.max(c - r, axis=0), np.min(c + r, axis=0)


def triple_range(t: list[float], z: list[float], t_s: float, q_mm: float, jerk: float,
                 triples: np.ndarray) -> tuple[float, float]:
    """:func:`triple_edges` at the one instant ``t_s`` [s]."""
    lo, hi = triple_edges(np.asarray(t), np.asarray(z), triples, np.array([t_s]), q_mm, jerk)
    return float(lo[0]), float(hi[0])


def _all_triples(m: int, newest: int | None = None) -> np.ndarray:
    """The index triples of ``m`` samples (those whose newest index is among the newest
    ``newest``, or all)."""
    import itertools
    first = 0 if newest is None else m - newest
    return np.array([t for t in itertools.combinations(range(m), 3) if t[2] >= first])


def _estimate_age_s(c: MasterConditioner, t_s: float, T: float) -> float:
    """``t_s`` minus the instant of the conditioner's estimate [s] (its time stamp: a
    cycle index and an offset)."""
    return t_s - (c._tx[0] * T + c._tx[1])


def study_belt(case: eb.BeltCase, window_s: float, margin: float, shrink: float) -> dict:
    """Offline figures of one belt (see the module's docstring)."""
    T = case.T
    n = round(eb.RUN_S / T)
    stream = eb._encoder(case).samples(case.belt, T, n)
    cond = MasterConditioner(ConditioningParams(T, EncoderModel(case.count_mm, eb.LATENCY),
                                                eb.FRAME))
    sm = SetMember(case.count_mm, eb.FRAME.jerk, window_s, T)
    t_sp = (np.arange(n) + 1) * T
    truth = case.belt.states(t_sp)[:, 0]
    k_from = round(case.engage_s / T) + round(eb.SETTLE_S / T)
    res = {key: np.full(n, np.nan) for key in KEYS}
    n_empty = 0
    tri_cache: dict = {}
    for k in range(n):
        x, off = stream.sample(k)
        n_out = cond.n_outliers
        o = cond.update(x, off)
        if x is not None and cond.n_outliers == n_out:
            sm.add((k - eb.LATENCY) * T + off, x)
        if k < k_from or not o.valid:
            continue
        r = sm.range_at(t_sp[k])
        if r is None and x is not None and cond.n_outliers == n_out:
            sm.drop_last()  # the newest sample emptied the set: an outlier
            n_empty += 1
            r = sm.range_at(t_sp[k])
        if r is None:
            continue
        lo, hi = r[0], r[1]
        xs = cond._x
        dt = _estimate_age_s(cond, t_sp[k], T)
        pk = cond._predict(xs, dt)[0]
        res["kept"][k] = o.pos - truth[k]
        res["kalman"][k] = pk - truth[k]
        res["mid"][k] = (lo + hi) / 2 - truth[k]
        res["clip"][k] = min(max(o.pos, lo - margin), hi + margin) - truth[k]
        res["half"][k] = (hi - lo) / 2
        w = (hi - lo) * shrink
        res["kal_clip"][k] = min(max(pk, lo + w), hi - w) - truth[k]
        res["clip_s"][k] = min(max(o.pos, lo + w), hi - w) - truth[k]
        m = len(sm.t)
        if m >= 3:
            if m not in tri_cache:
                tri_cache[m] = _all_triples(m)[-TRI_MAX:]
            tlo, thi = triple_range(sm.t, sm.z, t_sp[k], case.count_mm, eb.FRAME.jerk,
                                    tri_cache[m])
            res["tri_half"][k] = (thi - tlo) / 2
            res["tri_mid"][k] = (thi + tlo) / 2 - truth[k]
            w = (thi - tlo) * shrink
            res["tri_clip_s"][k] = min(max(o.pos, tlo + w), thi - w) - truth[k]
    change = case.belt.in_change(t_sp, eb.SETTLE_CHANGE_S)
    out = {"n_empty": n_empty, "lp_us": 1e6 * sm.lp_s / max(sm.n_lp, 1)}
    for key, e in res.items():
        e = np.abs(e)
        for name, m in (("change", change), ("const", ~change)):
            v = e[m & np.isfinite(e)]
            out[f"{key}_{name}"] = float(np.percentile(v, 99)) if v.size else math.nan
    return out


class SetClipInput:
    """The kept conditioner, its output's position clipped each cycle into the set's
    range at the setpoint time shrunk by ``shrink`` of its width per side (the clip
    handed on as a revision, eq. 4.5: the output continues from the clipped state)."""

    def __init__(self, case: eb.BeltCase, window_s: float, shrink: float, newest: int,
                 mode: str, pole_mult: float = 2.0) -> None:
        self.pole_mult = pole_mult
        T = case.T
        self.T = T
        self.c = MasterConditioner(ConditioningParams(T, EncoderModel(case.count_mm,
                                                                      eb.LATENCY), eb.FRAME))
        self.q = case.count_mm
        self.n = max(6, math.ceil(window_s / T))
        self.t: list[float] = []
        self.z: list[float] = []
        self.shrink = shrink
        self.newest = newest
        self.mode = mode
        self.cache: dict = {}
        self.n_clip = 0

    @property
    def n_outliers(self) -> int:
        return self.c.n_outliers

    def triples(self, m: int) -> np.ndarray:
        if m not in self.cache:
            self.cache[m] = _all_triples(m, self.newest)
        return self.cache[m]

    def update(self, x: float | None, off: float):
        c = self.c
        k = c.k
        no = c.n_outliers
        y_prev = c._y
        o = c.update(x, off)
        if x is not None and c.n_outliers == no:
            self.t.append((k - eb.LATENCY) * self.T + off)
            self.z.append(x)
            if len(self.t) > self.n:
                del self.t[0], self.z[0]
        if not o.valid or c._y is None or len(self.t) < 6:
            return o.pos, o.vel, o.acc, o.jerk, o.valid
        lo, hi = triple_range(self.t, self.z, (k + 1) * self.T, self.q, eb.FRAME.jerk,
                              self.triples(len(self.t)))
        w = (hi - lo) * self.shrink
        if self.mode == "est":
            # the estimate's position at t_sp projected into the shrunk set (its state
            # shifted at its own instant), the output clipped into the whole set
            dt = _estimate_age_s(c, (k + 1) * self.T, self.T)
            pe = c._predict(c._x, dt)[0]
            d = min(max(pe, lo + w), hi - w) - pe
            if d:
                x0, x1, x2, x3 = c._x
                c._x = (x0 + d, x1, x2, x3)
            w = 0.0
        lo, hi = lo + w, hi - w
        p, v, a = c._y
        if self.mode == "law":
            # smooth: where the kept output ends outside the shrunk set, this step is made
            # again by the law with its pole x pole_mult and the position error taken to
            # the set's nearest point (the estimate's v, a, j fed as before)
            if (p < lo or p > hi) and y_prev is not None and (
                    o.event is None or o.event.kind != EventKind.JERK_STEP):
                self.n_clip += 1
                d = (lo if p < lo else hi) - p
                T = self.T
                dt = _estimate_age_s(c, (k + 1) * T, T) - T
                pe, ve, ae, je = c._predict(c._x, dt)
                yp, yv, ya = y_prev
                w = c._gains[0] / 3.0 * self.pole_mult
                J, A = c._Jout, c._A
                ulo = max(-J, (-A - ya) / T)
                uhi = min(J, (A - ya) / T)
                u = _low_gain(je, ae - ya, ve - yv, pe - yp + d, w, ulo, uhi)
                h = T * T
                c._y = (yp + yv * T + ya * h / 2 + u * h * T / 6, yv + ya * T + u * h / 2,
                        ya + u * T)
                c._yj = u
                p, v, a = c._y
            return p, v, a, c._yj, True
        if p < lo or p > hi:
            pc = lo if p < lo else hi
            self.n_clip += 1
            if self.mode in ("kalman", "est", "kalmanj"):  # the estimate's v, a at t_sp
                dt = _estimate_age_s(c, (k + 1) * self.T, self.T)
                _, v, a, je = c._predict(c._x, dt)
                if self.mode == "kalmanj":  # and its jerk
                    c._yj = je
            c._y = (pc, v, a)
            p = pc
        return p, v, a, c._yj, True


def harness(seeds: list[int], cells: list, window_s: float, shrink: float, newest: int,
            mode: str, pole_mult: float = 2.0) -> None:
    """The encoder benchmark's run_belt with SetClipInput ("setclip") beside the kept
    design, per seed and cell: S-curve-at-JerkMax p99, constant-speed p99, worst after-sync
    norm ratio, outliers / glitches, clips per 1000 cycles."""
    made: list = []

    def make(name: str, case: eb.BeltCase):
        if name == "setclip":
            made.append(SetClipInput(case, window_s, shrink, newest, mode, pole_mult))
            return made[-1]
        return orig(name, case)

    orig, orig_inputs = eb.make_input, eb.INPUTS
    eb.make_input = make
    eb.INPUTS = orig_inputs + ("setclip",)
    try:
        print("| seed | cell | kept: S-curve p99 / const p99 / after max | setclip: S-curve p99 "
              "/ const p99 / after max | outliers / glitches | clips per 1000 |")
        for seed in seeds:
            cases = [c for c in eb.belt_cases(seed, 4) if (c.count_mm, c.T) in cells]
            for cell in cells:
                row = []
                for name in (eb.KEPT, "setclip"):
                    made.clear()
                    runs = [eb.run_belt(c, name) for c in cases if (c.count_mm, c.T) == cell]
                    f = eb.summarize(runs)[(cell[0], cell[1], name)]
                    after = max(f["after_vel"], f["after_acc"], f["after_jerk"])
                    ej = f["err_change_jmax_p99"]
                    ec = f["err_const"][1] if f["err_const"] else math.nan
                    row.append(f"{ej if ej is not None else math.nan:.3f} / {ec:.3f} / "
                               f"{after:.3f}" + ("" if after <= 1.01 else
                                                 f" (v {f['after_vel']:.3f} a "
                                                 f"{f['after_acc']:.3f} j {f['after_jerk']:.3f})")
                               + (f" [{f['synced']}/{f['runs']} synced; "
                                  f"{','.join(f['errors'])}]" if f["errors"]
                                  or f["synced"] < f["runs"] else ""))
                    if name == "setclip":
                        clips = 1000 * sum(m.n_clip for m in made) / sum(
                            round(eb.RUN_S / m.T) for m in made)
                        row.append(f"{f['outliers']} / {f['glitches']}")
                        row.append(f"{clips:.1f}")
                print(f"| {seed} | {cell[0] * 1e3:g}um {cell[1] * 1e3:g}ms | "
                      + " | ".join(row) + " |", flush=True)
    finally:
        eb.make_input, eb.INPUTS = orig, orig_inputs


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1")
    ap.add_argument("--cells", default="50um:1ms,50um:2ms,50um:4ms")
    ap.add_argument("--window", type=float, default=0.08, help="the LP's window [s]")
    ap.add_argument("--margin", type=float, default=0.0, help="kept->set margin [mm]")
    ap.add_argument("--shrink", type=float, default=0.25,
                    help="kal_clip / clip_s: the set shrunk by this share of its width per side")
    ap.add_argument("--belts", default="0", help="belts of each cell (0: the one at JerkMax)")
    ap.add_argument("--harness", action="store_true")
    ap.add_argument("--newest", type=int, default=4,
                    help="setclip: triples with their newest sample among the newest N")
    ap.add_argument("--mode", default="pos", choices=("pos", "kalman", "est", "kalmanj", "law"),
                    help="setclip: at a clip keep the output's v, a (pos) or take the "
                         "estimate's (kalman)")
    ap.add_argument("--pole", type=float, default=2.0, help="law mode: pole multiplier")
    args = ap.parse_args(argv)
    cells = _cells(args.cells)
    if args.harness:
        harness(_seeds(args.seeds), cells, args.window, args.shrink, args.newest, args.mode,
                args.pole)
        return
    belts = [int(b) for b in args.belts.split(",")]
    keys = KEYS
    print(f"window {args.window * 1e3:g} ms, margin {args.margin:g} mm; p99 [mm] "
          f"S-curve | constant speed")
    print("| cell | seed | belt | " + " | ".join(keys) + " | const: " + " | ".join(keys)
          + " | empty | LP us |")
    for seed in _seeds(args.seeds):
        cases = eb.belt_cases(seed, 4)
        for count, T in cells:
            cc = [c for c in cases if c.count_mm == count and c.T == T]
            for b in belts:
                f = study_belt(cc[b], args.window, args.margin, args.shrink)
                print(f"| {count * 1e3:g}um {T * 1e3:g}ms | {seed} | {b} | "
                      + " | ".join(f"{f[k + '_change']:.3f}" for k in keys) + " | "
                      + " | ".join(f"{f[k + '_const']:.3f}" for k in keys)
                      + f" | {f['n_empty']} | {f['lp_us']:.0f} |", flush=True)


if __name__ == "__main__":
    main()
