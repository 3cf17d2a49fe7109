"""Following a master in SYNCED within the vector-norm sync limits (and closing the last gap).

The published algorithm's "Full Synchronization" copies the master, all derivatives
(docs/spec/tracking.md#2.1).  That
is exact for an ideal master but copies whatever the master does to the drives: a quantised
or glitching master, or the jump left when an approach ends a little off a master with a
jerk.  :class:`SyncFollower` (``SyncFollow.LIMITED``, the default of the ``optimal``
planner) copies the master only when that step is itself within the limits, else it
closes the gap within them (docs/spec/master-conditioning.md#6):

- copy test (eq. 6.1): from the last setpoint (p, v, a) the constant jerks that land on the
  master's acceleration, velocity and position, (a_m - a)/T, 2(v_m - v - aT)/T^2 and
  6(p_m - p - vT - aT^2/2)/T^3, must each be within J, and |a_m| <= A, |v_m| <= V (vector
  norms).  A conditioned master (:mod:`.conditioning`) moves with a constant jerk per sample
  (all three equal), so in steady state the follower copies it exactly, at the cost of a few
  multiply-adds; an ideal master is copied exactly as before.
- otherwise (eq. 6.2): in the master's frame, with the master taken back one sample with
  its own jerk j_m, e0 = setpoint - master(k-1); a Ruckig plan brings e to 0 in minimum
  time with the per-axis bounds (L - |x_m|) / sqrt(n) for L = V, A, J and x_m the master's
  velocity, acceleration and jerk norms, so that the robot's v = v_m + e', a = a_m + e'',
  j = j_m + e''' stay within the norms; the setpoint is master(k) + e(T).  Made again every
  sample (the master may move anyhow); it ends in the copy once the gap is closed.

Pure and deterministic; Ruckig objects are rebuilt on restore (not picklable).
"""

from __future__ import annotations

import math
from typing import Any

from ..limits import Limits
from .values import attributes, mypyc_attr, restore
from .vec import Vec

_ZERO3 = (0.0, 0.0, 0.0)

#: lengths (mm or deg) -> Ruckig units (m or kdeg), as in optimal.py
_S = 1e-3
#: share of a limit kept when the master itself uses all of it (no bound of zero width)
_MIN_SHARE = 0.05
#: share of J kept in closing a gap to a master with a jerk, for its change between samples
_JERK_CHANGE_SHARE = 0.03


def _norm(x: Vec) -> float:
    s = 0.0
    for c in x:
        s += c * c
    return math.sqrt(s)


def rest_target_solver(n: int) -> tuple[Any, Any, Any]:
    """A Ruckig solver, its input and its trajectory for ``n`` DOFs, synchronised in time
    where necessary, with the target at rest at 0 (the planners work in the gap to the
    master). ruckig is imported here, on first use: the softMC planner runs without it."""
    from ruckig import InputParameter, Ruckig, Synchronization, Trajectory
    inp = InputParameter(n)
    inp.synchronization = Synchronization.TimeIfNecessary
    zero = [0.0] * n
    inp.target_position = zero
    inp.target_velocity = zero
    inp.target_acceleration = zero
    return Ruckig(n), inp, Trajectory(n)

@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class SyncFollower:
    """Follow one channel's master within its sync ``limits`` (see the module docstring)."""

    def __init__(self, limits: Limits, sample_time_s: float) -> None:
        self.limits = limits
        self.T = float(sample_time_s)
        k = 1.0 - 1e-9
        self._V, self._A, self._J = limits.vel * k, limits.acc * k, limits.jerk * k
        self._constants()
        self.n = 0
        self._rk: Any = None
        self._inp: Any = None
        self._traj: Any = None
        #: statistics: samples copied, samples closing a gap
        self.n_copied = 0
        self.n_closing = 0

    def __getstate__(self):
        d = attributes(self)
        d["_rk"] = d["_inp"] = d["_traj"] = None
        d["n"] = 0
        return d

    def __setstate__(self, d) -> None:
        restore(self, d)
        if "_c" not in d:  # a state saved before the constants were cached
            self._constants()

    def _constants(self) -> None:
        """The copy test's constants of T and the limits, computed once with the
        expressions the test used per call (the same values, bit for bit)."""
        T = self.T
        T2 = T * T
        J2 = self._J * self._J
        #: 1/T, 2/T^2, 6/T^3, T^2/2, T^3/6, J^2, V^2 T^2, A^2 T^4, J^2 T^6
        self._c = (1.0 / T, 2.0 / (T * T), 6.0 / (T * T * T), 0.5 * T * T, T * T * T / 6.0,
                   J2, self._V * self._V * T2, self._A * self._A * T2 * T2,
                   J2 * T2 * T2 * T2)

    def _solver(self, n: int) -> None:
        self.n = n
        self._rk, self._inp, self._traj = rest_target_solver(n)

    def copyable(self, p: Vec, v: Vec, a: Vec, mp: Vec, mv: Vec, ma: Vec,
                 p2: Vec | None = None, p3: Vec | None = None,
                 mj: Vec | None = None) -> bool:
        """Eq. 6.1: is the step from (p, v, a) onto the master within the limits?  The
        constant jerk that lands on the master's acceleration, on its velocity and on its
        position (three values, equal for a master that moves with a constant jerk over the
        sample) must each be within J, and the master within V and A (vector norms).  With
        the two setpoint positions before p (``p2``, ``p3``), the finite differences that
        the step makes, (m - p)/T, (m - 2p + p2)/T^2, (m - 3p + 3p2 - p3)/T^3 (what the
        drive sees), and those of the next two samples with the master going on at its
        jerk ``mj``, must also be within V, A and J.

        The 3-D and 1-D channels run written-out forms of the same operations in the same
        order (:meth:`_copyable3`, :meth:`copyable1`: bit-identical sums, a few
        microseconds less per sample); other lengths the loop (:meth:`_copyable_n`)."""
        n = len(p)
        if n == 3:
            return self._copyable3(p, v, a, mp, mv, ma, p2, p3, mj)
        if n == 1:
            return self.copyable1(p[0], v[0], a[0], mp[0], mv[0], ma[0],
                                  None if p2 is None else p2[0],
                                  None if p3 is None else p3[0],
                                  0.0 if mj is None else mj[0])
        return self._copyable_n(p, v, a, mp, mv, ma, p2, p3, mj)

    def _copyable3(self, p: Vec, v: Vec, a: Vec, mp: Vec, mv: Vec, ma: Vec,
                   p2: Vec | None, p3: Vec | None, mj: Vec | None) -> bool:
        """:meth:`copyable` for 3 components, written out (the loop's operations in its
        order; a sum that starts at 0.0 adds its first square exactly)."""
        ia, iv, ip, h, h3, J2, lv, la, lj = self._c
        T = self.T
        p0, p1, p2_ = p
        v0, v1, v2 = v
        a0, a1, a2 = a
        m0, m1, m2 = mp
        n0, n1, n2 = mv
        b0, b1, b2 = ma
        x = (b0 - a0) * ia
        y = (b1 - a1) * ia
        z = (b2 - a2) * ia
        if not x * x + y * y + z * z <= J2:
            return False
        x = (n0 - v0 - a0 * T) * iv
        y = (n1 - v1 - a1 * T) * iv
        z = (n2 - v2 - a2 * T) * iv
        if not x * x + y * y + z * z <= J2:
            return False
        x = (m0 - p0 - v0 * T - a0 * h) * ip
        y = (m1 - p1 - v1 * T - a1 * h) * ip
        z = (m2 - p2_ - v2 * T - a2 * h) * ip
        if not (x * x + y * y + z * z <= J2
                and math.sqrt(b0 * b0 + b1 * b1 + b2 * b2) <= self._A
                and math.sqrt(n0 * n0 + n1 * n1 + n2 * n2) <= self._V):
            return False
        if p2 is None or p3 is None:
            return True
        # per component: the differences e of the positions p3, p2, p, m, m(+1), m(+2)
        # (m(+1), m(+2): the master going on with its jerk) and their differences c; the
        # sums over the components of the three steps' first, second and third differences
        # (the loop's d1, x, y), written out component by component.  The master's next
        # positions drop the jerk terms when its jerk is zero: they add an exact zero, which
        # can only change the sign of a zero, and every value compared is a sum of squares.
        vt0, vt1, vt2 = n0 * T, n1 * T, n2 * T
        if mj is None or mj == _ZERO3:
            s40 = m0 + vt0 + b0 * h
            s41 = m1 + vt1 + b1 * h
            s42 = m2 + vt2 + b2 * h
            s50 = m0 + 2.0 * (vt0 + b0 * 2.0 * h)
            s51 = m1 + 2.0 * (vt1 + b1 * 2.0 * h)
            s52 = m2 + 2.0 * (vt2 + b2 * 2.0 * h)
        else:
            j0, j1, j2 = mj
            s40 = m0 + vt0 + b0 * h + j0 * h3
            s41 = m1 + vt1 + b1 * h + j1 * h3
            s42 = m2 + vt2 + b2 * h + j2 * h3
            s50 = m0 + 2.0 * (vt0 + b0 * 2.0 * h) + 8.0 * j0 * h3
            s51 = m1 + 2.0 * (vt1 + b1 * 2.0 * h) + 8.0 * j1 * h3
            s52 = m2 + 2.0 * (vt2 + b2 * 2.0 * h) + 8.0 * j2 * h3
        q0, q1, q2 = p2
        r0, r1, r2 = p3
        # x
        e1 = p0 - q0
        e2 = m0 - p0
        e3 = s40 - m0
        e4 = s50 - s40
        c1 = e1 - (q0 - r0)
        c2 = e2 - e1
        c3 = e3 - e2
        c4 = e4 - e3
        fv3, fa3, fv4, fa4, fv5, fa5 = e2 * e2, c2 * c2, e3 * e3, c3 * c3, e4 * e4, c4 * c4
        x = c2 - c1
        fj3 = x * x
        x = c3 - c2
        fj4 = x * x
        x = c4 - c3
        fj5 = x * x
        # y
        e1 = p1 - q1
        e2 = m1 - p1
        e3 = s41 - m1
        e4 = s51 - s41
        c1 = e1 - (q1 - r1)
        c2 = e2 - e1
        c3 = e3 - e2
        c4 = e4 - e3
        fv3 += e2 * e2
        fa3 += c2 * c2
        fv4 += e3 * e3
        fa4 += c3 * c3
        fv5 += e4 * e4
        fa5 += c4 * c4
        x = c2 - c1
        fj3 += x * x
        x = c3 - c2
        fj4 += x * x
        x = c4 - c3
        fj5 += x * x
        # z
        e1 = p2_ - q2
        e2 = m2 - p2_
        e3 = s42 - m2
        e4 = s52 - s42
        c1 = e1 - (q2 - r2)
        c2 = e2 - e1
        c3 = e3 - e2
        c4 = e4 - e3
        fv3 += e2 * e2
        fa3 += c2 * c2
        fv4 += e3 * e3
        fa4 += c3 * c3
        fv5 += e4 * e4
        fa5 += c4 * c4
        x = c2 - c1
        fj3 += x * x
        x = c3 - c2
        fj4 += x * x
        x = c4 - c3
        fj5 += x * x
        return not (fv3 > lv or fa3 > la or fj3 > lj or fv4 > lv or fa4 > la or fj4 > lj
                    or fv5 > lv or fa5 > la or fj5 > lj)

    def copyable1(self, p: float, v: float, a: float, mp: float, mv: float, ma: float,
                  p2: float | None = None, p3: float | None = None,
                  mj: float = 0.0) -> bool:
        """:meth:`copyable` of a 1-D channel on floats (the rotation angle), written out."""
        ia, iv, ip, h, h3, J2, lv, la, lj = self._c
        T = self.T
        x = (ma - a) * ia
        if not x * x <= J2:
            return False
        x = (mv - v - a * T) * iv
        if not x * x <= J2:
            return False
        x = (mp - p - v * T - a * h) * ip
        if not (x * x <= J2 and math.sqrt(ma * ma) <= self._A
                and math.sqrt(mv * mv) <= self._V):
            return False
        if p2 is None or p3 is None:
            return True
        vt = mv * T
        if mj == 0.0:  # the jerk terms add an exact zero (see _copyable3)
            s4 = mp + vt + ma * h
            s5 = mp + 2.0 * (vt + ma * 2.0 * h)
        else:
            s4 = mp + vt + ma * h + mj * h3
            s5 = mp + 2.0 * (vt + ma * 2.0 * h) + 8.0 * mj * h3
        e0 = p2 - p3
        e1 = p - p2
        e2 = mp - p
        e3 = s4 - mp
        e4 = s5 - s4
        c1 = e1 - e0
        c2 = e2 - e1
        c3 = e3 - e2
        c4 = e4 - e3
        y3 = c2 - c1
        y4 = c3 - c2
        y5 = c4 - c3
        return not (e2 * e2 > lv or c2 * c2 > la or y3 * y3 > lj or e3 * e3 > lv
                    or c3 * c3 > la or y4 * y4 > lj or e4 * e4 > lv or c4 * c4 > la
                    or y5 * y5 > lj)

    def _copyable_n(self, p: Vec, v: Vec, a: Vec, mp: Vec, mv: Vec, ma: Vec,
                    p2: Vec | None = None, p3: Vec | None = None,
                    mj: Vec | None = None) -> bool:
        """:meth:`copyable` for any number of components (the reference form)."""
        T = self.T
        ia = 1.0 / T
        iv = 2.0 / (T * T)
        ip = 6.0 / (T * T * T)
        h = 0.5 * T * T
        ja = jv = jp = 0.0
        for i in range(len(p)):
            x = (ma[i] - a[i]) * ia
            ja += x * x
            x = (mv[i] - v[i] - a[i] * T) * iv
            jv += x * x
            x = (mp[i] - p[i] - v[i] * T - a[i] * h) * ip
            jp += x * x
        J2 = self._J * self._J
        if not (ja <= J2 and jv <= J2 and jp <= J2 and _norm(ma) <= self._A
                and _norm(mv) <= self._V):
            return False
        if p2 is None or p3 is None:
            return True
        # the finite differences of this step and of the next two, the master going on
        # with its jerk: a step that is not one constant jerk shows in the next ones
        n = len(p)
        h3 = T * T * T / 6.0
        mj = (0.0,) * n if mj is None else mj
        seq = [p3, p2, p, mp,
               [mp[i] + mv[i] * T + ma[i] * h + mj[i] * h3 for i in range(n)],
               [mp[i] + 2.0 * (mv[i] * T + ma[i] * 2.0 * h) + 8.0 * mj[i] * h3
                for i in range(n)]]
        T2 = T * T
        lv, la, lj = self._V * self._V * T2, self._A * self._A * T2 * T2, J2 * T2 * T2 * T2
        for k in (3, 4, 5):
            fv = fa = fj = 0.0
            q0, q1, q2, q3 = seq[k], seq[k - 1], seq[k - 2], seq[k - 3]
            for i in range(n):
                d1 = q0[i] - q1[i]
                d2 = q1[i] - q2[i]
                x = d1 - d2
                y = x - (d2 - (q2[i] - q3[i]))
                fv += d1 * d1
                fa += x * x
                fj += y * y
            if fv > lv or fa > la or fj > lj:
                return False
        return True

    def step(self, p: Vec, v: Vec, a: Vec, mp: Vec, mv: Vec, ma: Vec,
             mj: Vec, p2: Vec | None = None, p3: Vec | None = None) -> tuple[Vec, Vec, Vec]:
        """The setpoint of this sample from the last one (p, v, a), the positions of the two
        before it (``p2``, ``p3``; None: not known) and the master of this sample
        (mp, mv, ma, mj)."""
        if (self._copyable3(p, v, a, mp, mv, ma, p2, p3, mj) if len(p) == 3
                else self.copyable(p, v, a, mp, mv, ma, p2, p3, mj)):
            self.n_copied += 1
            return tuple(mp), tuple(mv), tuple(ma)
        return self._close(p, v, a, mp, mv, ma, mj)

    def step1(self, p: float, v: float, a: float, mp: float, mv: float, ma: float,
              mj: float, p2: float | None = None,
              p3: float | None = None) -> tuple[float, float, float]:
        """:meth:`step` of a 1-D channel on floats (the same result)."""
        if self.copyable1(p, v, a, mp, mv, ma, p2, p3, mj):
            self.n_copied += 1
            return mp, mv, ma
        (x,), (xv,), (xa,) = self._close((p,), (v,), (a,), (mp,), (mv,), (ma,), (mj,))
        return x, xv, xa

    def _close(self, p: Vec, v: Vec, a: Vec, mp: Vec, mv: Vec, ma: Vec,
               mj: Vec) -> tuple[Vec, Vec, Vec]:
        """Eq. 6.2: close the gap to the master within the limits (see the module
        docstring)."""
        self.n_closing += 1
        n = len(p)
        if n != self.n or self._rk is None:
            self._solver(n)
        T = self.T
        rng = range(n)
        h = 0.5 * T * T
        h3 = T * T * T / 6.0
        # the master one sample back, with its own jerk
        mbp = [mp[i] - mv[i] * T + ma[i] * h - mj[i] * h3 for i in rng]
        mbv = [mv[i] - ma[i] * T + mj[i] * h for i in rng]
        mba = [ma[i] - mj[i] * T for i in rng]
        r = 1.0 / math.sqrt(n)
        s = _S
        V, A, J = self._V, self._A, self._J
        bv = max(V - _norm(mv), _MIN_SHARE * V) * r * s
        ba = max(A - _norm(ma), _MIN_SHARE * A) * r * s
        nj = _norm(mj)
        if nj > 0.0:
            # a master with a jerk (a conditioned one) changes it from sample to sample;
            # the positions before this step were made with the last one, so a share of J
            # is kept for that change (eq. 6.2; an ideal master, jerk 0, plans as before)
            nj += _JERK_CHANGE_SHARE * J
        bj = max(J - nj, _MIN_SHARE * J) * r * s
        inp = self._inp
        inp.current_position = [(p[i] - mbp[i]) * s for i in rng]
        inp.current_velocity = [(v[i] - mbv[i]) * s for i in rng]
        inp.current_acceleration = [(a[i] - mba[i]) * s for i in rng]
        inp.min_velocity = [-bv] * n
        inp.max_velocity = [bv] * n
        inp.min_acceleration = [-ba] * n
        inp.max_acceleration = [ba] * n
        inp.max_jerk = [bj] * n
        try:
            ok = int(self._rk.calculate(inp, self._traj)) >= 0
        except Exception:  # noqa: BLE001 - the binding raises on unknown result codes
            ok = False
        if not ok:  # not seen: copy (the published reading)
            return tuple(mp), tuple(mv), tuple(ma)
        ep, ev, ea = self._traj.at_time(T)
        si = 1.0 / s
        return (tuple([mp[i] + ep[i] * si for i in rng]), tuple([mv[i] + ev[i] * si for i in rng]),
                tuple([ma[i] + ea[i] * si for i in rng]))
