"""Study (not in ``controller/``): the conditioner's output planned to stay inside the set's
predicted range over a horizon.

docs/spec/master-conditioning.md#5.4.1 (issue 13's open S-curve target).  The kept
conditioner (docs/spec/master-conditioning.md#4) runs unchanged; each cycle the jerk u of
its output's next step (the law's, eq. 4.1-4.3) is limited to [u_lo, u_hi] so that the
output's predicted path stays inside the range of the belt's position that the samples
allow, at up to ``HORIZON_POINTS`` instants over ``--horizon`` seconds.

*The set's range* (the cheap outer bound, eq. 5.3 for one belt): per triple of accepted
samples (instants tau_j, positions z_j), the quadratic through them widened by
(q/2 + ``EPS_MM``)·Σ|l_j(t)| + (J_f/6)·Π|t − tau_j| (l_j the Lagrange basis) bounds every
belt within the frame's JerkMax J_f through those counts; the range is the intersection over
a family of triples from the last ``--window`` seconds (the newest sample or the one before,
with two lags from a geometric set: 56-144 triples), shrunk by ``--shrink`` of its width on
each side.

*The plan* (linear in u, no LP): after this step at u the output brakes at the fixed jerk
−Jb towards the upper edge (+Jb towards the lower), Jb = ``--brake`` × (1 + r)·J_f; that
path must be inside the edges at every horizon instant, which bounds u from above (below) at
each instant.  An instant that no u within the envelope (eq. 4.3: |u| ≤ (1 + r)·J_f,
|a + uT| ≤ A_f, the braking distance of the velocity) can meet is left out (the output is
to be inside from the earliest instant it can be).  The bounds conflicting (u_lo > u_hi):
the midpoint (``--conflict mid``) or the law's own u (``keep``).  The change to the law's u
is at most ``--auth`` × J_f; a cycle with a detected jerk step (the revision handed on,
eq. 4.5) is left to the kept design.

Run from the repository root (the two variants of the spec's table, A and B)::

    python benchmarks/setplan.py --seeds 1-6 --horizon 0.06 --brake 0.25 --conflict mid
    python benchmarks/setplan.py --seeds 1-6 --horizon 0.04 --brake 0.5 --auth 3 --conflict keep

Prints one row per seed and cell (``--cells``, default the three 50 um cells and 10 um / 4 ms)
through the encoder benchmark's ``run_belt`` (its belts, encoder, tracker and figures,
``benchmarks/encoder.py``), for the kept design and the planned output: following error to
the true belt in SYNCED [mm], p99 during S-curves at JerkMax and at constant speed; the
after-sync peaks of the velocity, acceleration and jerk vector norms and the switch jerk
÷ the sync limits; tracking errors; outliers found / glitches injected; and, per 1000
cycles, how often the limit changed the law's u and how often its bounds conflicted.
Deterministic for a seed.  Cost: 56-144 triples × up to 13 instants, some 2000 cubic
evaluations per cycle (numpy), far beyond the cost target (§5.2).
"""

from __future__ import annotations

import argparse
import itertools
import math
import sys
from pathlib import Path

import numpy as np

_ROOT = Path(__file__).resolve().parents[1]
if str(_ROOT) not in sys.path:
    sys.path.insert(0, str(_ROOT))

from benchmarks import encoder as eb  # noqa: E402
from benchmarks.encoder_seeds import _cells, _seeds  # noqa: E402
from benchmarks.setmember import triple_edges as edges  # noqa: E402
from controller.tracking.conditioning import (  # noqa: E402
    ConditionedMaster,
    ConditioningParams,
    EncoderModel,
    EventKind,
    MasterConditioner,
)

#: instants of the horizon at most (evenly spaced, whole cycles, the first the setpoint's)
HORIZON_POINTS = 12
#: the geometric set of the family's lags [samples]
_LAGS = sorted({round(1.4 ** i) for i in range(20)})
#: samples in the window before the limit acts
MIN_SAMPLES = 8


def family(m: int) -> np.ndarray:
    """Index triples (i < j < l) into the newest ``m`` samples (index m - 1 the newest): the
    newest or the one before with two lags from ``_LAGS``."""
    lags = [x for x in _LAGS if x < m]
    out = {(n0 - b, n0 - a, n0) for n0 in (m - 1, m - 2)
           for a, b in itertools.combinations(lags, 2) if n0 - b >= 0}
    return np.array(sorted(out))


def envelope(y: tuple[float, float, float], T: float, J: float, A: float,
             V: float) -> tuple[float, float]:
    """The jerks u [mm/s^3] of the next step from the output y = (p, v, a) within eq. 4.3:
    |u| <= J, |a + uT| <= A and the braking distance of the velocity (lo > hi: none)."""
    _, v, a = y
    lo, hi = max(-J, (-A - a) / T), min(J, (A - a) / T)
    vn = v + a * T
    amax = math.sqrt(2.0 * J * (V - vn)) if vn < V else 0.0
    amin = -math.sqrt(2.0 * J * (V + vn)) if vn > -V else 0.0
    return max(lo, (amin - a) / T), min(hi, (amax - a) / T)


def path_after(y: tuple[float, float, float], u: float, hs: np.ndarray, T: float,
               brake: float) -> np.ndarray:
    """The output's position [mm] at ``hs`` [s] after this step's end: the step at jerk u
    from y = (p, v, a), then the jerk ``brake`` [mm/s^3]."""
    p, v, a = y
    h = T * T
    p1, v1, a1 = p + v * T + a * h / 2 + u * h * T / 6, v + a * T + u * h / 2, a + u * T
    return p1 + v1 * hs + a1 * hs * hs / 2 + brake * hs ** 3 / 6


def jerk_range(y: tuple[float, float, float], hs: np.ndarray, lo: np.ndarray,
               hi: np.ndarray, T: float, env: tuple[float, float],
               Jb: float) -> tuple[float, float]:
    """(u_lo, u_hi) [mm/s^3]: the output's path after the step at u, braking at −Jb (+Jb),
    stays below ``hi`` (above ``lo``) at the instants ``hs`` [s] after the step's end that
    some u of ``env`` can meet (the others left out; none: the envelope's other end).
    The path is linear in u: path_after(y, u) = base + u·cu."""
    base = path_after(y, 0.0, hs, T, 0.0)
    cu = T ** 3 / 6 + T * T / 2 * hs + T * hs * hs / 2
    br = Jb * hs ** 3 / 6
    need_hi = (hi - base + br) / cu  # path(u) - Jb hs^3/6 <= hi  <=>  u <= need_hi
    need_lo = (lo - base - br) / cu
    ok_hi = need_hi >= env[0]
    ok_lo = need_lo <= env[1]
    u_hi = float(np.min(need_hi[ok_hi])) if ok_hi.any() else env[0]
    u_lo = float(np.max(need_lo[ok_lo])) if ok_lo.any() else env[1]
    return u_lo, u_hi


class SetPlanInput:
    """The encoder benchmark's master input (``update(x, dt)`` as ``benchmarks/encoder.py``'s
    inputs) for a cycle ``T`` [s] and a count ``count_mm``: the kept conditioner with its
    output's jerk limited to the plan's range (the module's docstring)."""

    def __init__(self, T: float, count_mm: float, window_s: float = 0.08,
                 horizon_s: float = 0.06, shrink: float = 0.25, brake: float = 0.25,
                 auth: float = 100.0, conflict: str = "mid") -> None:
        self.T = T
        self.c = MasterConditioner(ConditioningParams(T, EncoderModel(count_mm, eb.LATENCY),
                                                      eb.FRAME))
        self.q = count_mm
        self.n = max(6, math.ceil(window_s / T))
        n_h = max(1, round(horizon_s / T))
        self.hs = np.unique(np.round(np.linspace(0.0, n_h, min(n_h, HORIZON_POINTS) + 1))) * T
        self.shrink, self.brake, self.auth, self.conflict = shrink, brake, auth, conflict
        self.t: list[float] = []
        self.z: list[float] = []
        self._family: dict[int, np.ndarray] = {}
        #: statistics: cycles planned, cycles whose u the limit changed, conflicts
        self.n_cycles = self.n_bind = self.n_conflict = 0

    @property
    def n_outliers(self) -> int:
        return self.c.n_outliers

    def range_ahead(self, t_sp: float) -> tuple[np.ndarray, np.ndarray]:
        """The set's range (shrunk) at t_sp + ``hs`` [mm]."""
        m = len(self.t)
        if m not in self._family:
            self._family[m] = family(m)
        lo, hi = edges(np.asarray(self.t), np.asarray(self.z), self._family[m],
                       t_sp + self.hs, self.q, eb.FRAME.jerk)
        w = (hi - lo) * self.shrink
        return lo + w, hi - w

    def update(self, x: float | None, off: float):
        c = self.c
        k = c.k
        n_out = c.n_outliers
        y = c._y
        o = c.update(x, off)
        T = self.T
        if x is not None and c.n_outliers == n_out:
            self.t.append((k - eb.LATENCY) * T + off)
            self.z.append(x)
            if len(self.t) > self.n:
                del self.t[0], self.z[0]
        if (not o.valid or y is None or len(self.t) < MIN_SAMPLES
                or (o.event is not None and o.event.kind == EventKind.JERK_STEP)):
            return self._out(o)
        self.n_cycles += 1
        lo, hi = self.range_ahead(k * T + c._lead_s)
        env = envelope(y, T, c._Jout, c._A, c._V)
        if env[0] > env[1]:
            return self._out(o)
        u_lo, u_hi = jerk_range(y, self.hs, lo, hi, T, env, self.brake * c._Jout)
        u = c._yj
        if u_lo > u_hi:
            self.n_conflict += 1
            un = u if self.conflict == "keep" else 0.5 * (u_lo + u_hi)
        else:
            un = min(max(u, u_lo), u_hi)
        Jc = self.auth * c._J
        un = min(max(un, u - Jc), u + Jc)
        un = min(max(un, env[0]), env[1])
        if un == u:
            return self._out(o)
        self.n_bind += 1
        p, v, a = y
        h = T * T
        c._y = (p + v * T + a * h / 2 + un * h * T / 6, v + a * T + un * h / 2, a + un * T)
        c._yj = un
        return c._y[0], c._y[1], c._y[2], un, True

    @staticmethod
    def _out(o: ConditionedMaster):
        return o.pos, o.vel, o.acc, o.jerk, o.valid


def harness(seeds: list[int], cells: list[tuple[float, float]], **kw) -> None:
    made: list[SetPlanInput] = []
    orig, orig_inputs = eb.make_input, eb.INPUTS

    def make(name: str, case: eb.BeltCase):
        if name == "setplan":
            made.append(SetPlanInput(case.T, case.count_mm, **kw))
            return made[-1]
        return orig(name, case)

    eb.make_input = make
    eb.INPUTS = (*orig_inputs, "setplan")
    names = (eb.KEPT, "setplan")
    try:
        print(", ".join(f"{k} {v}" for k, v in kw.items()))
        print("| seed | cell | " + " | ".join(
            f"{n}: S-curve p99 / const p99 [mm], after v a j, switch j" for n in names)
            + " | outliers / glitches | limit changed u, conflicts per 1000 cycles |")
        print("|---|---|---|---|---|---|")
        for seed in seeds:
            cases = [c for c in eb.belt_cases(seed, 4) if (c.count_mm, c.T) in cells]
            for cell in cells:
                row = []
                for name in names:
                    made.clear()
                    runs = [eb.run_belt(c, name) for c in cases if (c.count_mm, c.T) == cell]
                    f = eb.summarize(runs)[(cell[0], cell[1], name)]
                    ej = f["err_change_jmax_p99"]
                    ec = f["err_const"][1] if f["err_const"] else math.nan
                    row.append(f"{math.nan if ej is None else ej:.3f} / {ec:.3f}, "
                               f"{f['after_vel']:.2f} {f['after_acc']:.2f} "
                               f"{f['after_jerk']:.3f}, {f['switch_jerk']:.3f}"
                               + (f" [{f['synced']}/{f['runs']} synced; "
                                  f"{','.join(f['errors'])}]" if f["errors"]
                                  or f["synced"] < f["runs"] else ""))
                    if name == "setplan":
                        cyc = max(1, sum(m.n_cycles for m in made))
                        row.append(f"{f['outliers']} / {f['glitches']}")
                        row.append(f"{1000 * sum(m.n_bind for m in made) / cyc:.0f}, "
                                   f"{1000 * sum(m.n_conflict for m in made) / cyc:.0f}")
                print(f"| {seed} | {cell[0] * 1e3:g} µm {cell[1] * 1e3:g} ms | "
                      + " | ".join(row) + " |", flush=True)
    finally:
        eb.make_input, eb.INPUTS = orig, orig_inputs


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", default="1", help="seeds: 1-6 or 1,2,5 (default 1)")
    ap.add_argument("--cells", default="50um:1ms,50um:2ms,50um:4ms,10um:4ms",
                    help="cells COUNTum:CYCLEms, comma-separated")
    ap.add_argument("--window", type=float, default=0.08, help="samples' window [s]")
    ap.add_argument("--horizon", type=float, default=0.06, help="[s] (default 0.06)")
    ap.add_argument("--shrink", type=float, default=0.25,
                    help="the range shrunk by this share of its width per side")
    ap.add_argument("--brake", type=float, default=0.25,
                    help="braking jerk Jb / the output's jerk limit (1 + r) J_f")
    ap.add_argument("--auth", type=float, default=100.0,
                    help="the change to the law's u at most this x J_f (default: no limit)")
    ap.add_argument("--conflict", choices=("mid", "keep"), default="mid",
                    help="on conflicting bounds: their midpoint or the law's u")
    a = ap.parse_args(argv)
    harness(_seeds(a.seeds), _cells(a.cells), window_s=a.window, horizon_s=a.horizon,
            shrink=a.shrink, brake=a.brake, auth=a.auth, conflict=a.conflict)


if __name__ == "__main__":
    main()
