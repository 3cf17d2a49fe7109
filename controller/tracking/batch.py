"""Batch stepping: N independent softMC trackers stepped at once with numpy (tuning sweeps).

``BatchTracker`` runs N trackers, each with its own :class:`TrackerParams` (limits,
FilterFactor, DampingFactor, mode, softMC options, master maxima, MaxFlops, timeouts, ...),
against N masters (or one master broadcast to all), and gives results **bit-identical** to
N scalar :class:`controller.tracking.Tracker` objects with planner ``"softmc"``.  It is meant
for parameter sweeps: thousands of trackers per numpy call instead of thousands of Python
calls.  Units as everywhere in the tracking core: mm, mm/s, mm/s^2 (translation), deg, deg/s,
deg/s^2 (rotation about the tool axis), s.

Only the ``"softmc"`` planner is supported.  The default planner (``"optimal"``) computes a
Ruckig trajectory per tracker and per sample; it is not vectorised, so a ``TrackerParams``
with ``planner="optimal"`` is rejected with a :class:`ParameterError` naming its index.  All
trackers of a batch share one clock (the same ``sample_time_s``).

Sources: the same as the scalar path -- the state machine of ``tracker.py`` (OFF ->
SYNCING -> SYNCED -> DESYNCING -> OFF; docs/spec/tracking.md#2.1), the softMC channel step
of ``softmc.py`` (docs/spec/tracking.md#3, including the ``SoftMcOptions`` switches such as
``time_to_reach_k`` and ``directional_k``), the over-oscillation monitor of
``oscillation.py`` (docs/spec/tracking.md#4.2: counted flips -- half-swings whose peak |dv|
exceeded 2*g*A*T -- inside a sliding window) and the sine-acceleration stop of ``desync.py``
(docs/spec/tracking.md#5.2).  This module re-implements none of the equations differently:
it performs the same floating-point operations in the same order on float64 arrays, and
tests/test_batch.py checks every output bit against N scalar trackers.  When the scalar
code changes, this module has to follow (the test fails until it does).

How bit-identity is kept (and what is not vectorised):

- Layout: the translation channel (3-D) and the rotation channel (1-D) of tracker i are
  columns i and N+i of (3, 2N) arrays; rows 1 and 2 of a rotation column are kept at zero.
  Zero rows leave every norm, dot product and increment of the 1-D channel unchanged
  (x*x + 0 + 0 == x*x; 0*k == 0), so one numpy softMC step serves both channels.
- Norms and dot products are accumulated left to right as the scalar code does
  (``(x0*x0 + x1*x1) + x2*x2``).  Where the scalar code uses the builtin ``sum()`` (which
  Python >= 3.12 evaluates with Neumaier compensation) the batch path does the same.
- ``int(D/T + 1.0)`` (positive) is ``np.floor``; ``vel_cap / dpn`` is divided first and then
  multiplied, as in the scalar code.
- The sync test of softmc.py squares with ``** 2`` (libm ``pow``, which is not always the
  correctly rounded ``x*x``: about 1 in 1000 random values differ in the last bit).  The
  batch path computes the norm with ``x*x`` and, for the rare columns whose norm lies within
  a relative 1e-12 of a threshold, recomputes it with Python's ``** 2``; elsewhere the two
  cannot disagree on the comparison.
- The de-sync stop profile (``SineStop``/``Desync.linear``) is planned with the scalar code
  when a de-sync starts (a rare event: a short Python loop over the trackers that start one,
  about 20-40 us each) and stored as per-tracker segment tables; the per-sample evaluation is
  vectorised, with ``math.cos``/``math.sin`` applied elementwise (numpy's SIMD sin/cos may
  differ in the last ulp from libm's on some builds; on the reference machine they agree).
- Everything else (OFF extrapolation, relative-mode shift, master limits, oscillation window,
  approach timeout, SYNCED copy) is vectorised with boolean masks.  When at least 40 % of
  the trackers are SYNCING, the softMC step runs on all columns and only the SYNCING ones
  are written back (the others' results are discarded); below that the SYNCING columns are
  gathered and scattered.

Run ``python -m controller.tracking.batch`` for throughput figures (tracker-steps/s).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..errors import ParameterError, StateError
from ..limits import Limits
from .desync import Desync, LinearPath
from .types import Mode, MotionState, TrackerParams, TrackError, TrackState
from .values import python_class

__all__ = ["BatchOutput", "BatchTracker", "benchmark"]

_OFF, _SYNCING, _SYNCED, _DESYNCING = (int(TrackState.OFF), int(TrackState.SYNCING),
                                       int(TrackState.SYNCED), int(TrackState.DESYNCING))
_REQ_NONE, _REQ_ENGAGE, _REQ_DISENGAGE = 0, 1, 2
#: IMFS value per TrackState (tracker._IMFS)
_IMFS_OF_STATE = np.array([0, 0, 1, -1], dtype=np.int8)
#: "never" for sample indices of the oscillation ring (far below any sample - window)
_NEVER = -(1 << 62)
#: relative closeness to a sync threshold below which the ``** 2`` norm is recomputed
_CLOSE_REL = 1e-12
_CLOSE_ABS = 1e-150

#: builtin sum() of floats is Neumaier-compensated from Python 3.12 on
_COMPENSATED_SUM = sum([0.1] * 10) == 1.0


# -- arithmetic helpers (the scalar code's operation order) -------------------------------
def _acc3(x: np.ndarray) -> np.ndarray:
    """``s = 0.0; for c in x: s += c*c`` over the 3 components (axis -2) of ``x``.

    (x0*x0 + x1*x1) + x2*x2: adding the first term to 0.0 changes nothing (squares >= +0).
    """
    sq = x * x
    s = sq[..., 0, :] + sq[..., 1, :]
    s += sq[..., 2, :]
    return s


def _dot3(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``s = 0.0; for a, b in zip(x, y): s += a*b`` (equal up to the sign of a zero result)."""
    pr = x * y
    s = pr[0] + pr[1]
    s += pr[2]
    return s


def _neumaier(terms: Sequence[np.ndarray]) -> np.ndarray:
    """CPython >= 3.12 ``sum()`` of floats (bltinmodule.c): Neumaier-compensated."""
    f = terms[0] + 0.0  # sum() starts from int 0: 0 + x0
    c = np.zeros_like(f)
    for x in terms[1:]:
        t = f + x
        c += np.where(np.abs(f) >= np.abs(x), (f - t) + x, (x - t) + f)
        f = t
    return np.where((c != 0.0) & np.isfinite(c), f + c, f)


def _pysum3(pr: np.ndarray) -> np.ndarray:
    """Builtin ``sum()`` over the 3 components (axis -2) of ``pr`` (per-component terms).

    Python <= 3.11: plain left-to-right addition, ((0 + x0) + x1) + x2; the leading
    ``0 +`` only turns a -0.0 into +0.0, which no caller can observe (squares are >= +0;
    the dot product a.dp is only compared with 0).  Python >= 3.12: Neumaier compensation.
    """
    if _COMPENSATED_SUM:
        return _neumaier([pr[..., 0, :], pr[..., 1, :], pr[..., 2, :]])
    s = pr[..., 0, :] + pr[..., 1, :]
    s += pr[..., 2, :]
    return s


def _pysumsq3(x: np.ndarray) -> np.ndarray:
    """``sum(c * c for c in x)`` over the 3 components (axis -2) of ``x``."""
    return _pysum3(x * x)


# -- output ---------------------------------------------------------------------------------
@python_class
@dataclass(frozen=True, slots=True)
class BatchOutput:
    """One sample of N trackers (arrays are fresh copies, safe to keep).

    ``pos``/``vel``/``acc`` (N, 3) mm, mm/s, mm/s^2; ``ang``/``ang_vel``/``ang_acc`` (N,)
    deg, deg/s, deg/s^2; ``state`` (N,) TrackState values, ``imfs`` (N,) Imfs values,
    ``error`` (N,) TrackError values (int8); ``synced_now`` (N,) bool (the sample where the
    approach ended); ``sample`` the sample index k shared by all trackers.
    """

    pos: np.ndarray
    vel: np.ndarray
    acc: np.ndarray
    ang: np.ndarray
    ang_vel: np.ndarray
    ang_acc: np.ndarray
    state: np.ndarray
    imfs: np.ndarray
    error: np.ndarray
    synced_now: np.ndarray
    sample: int

    def setpoint(self, i: int) -> MotionState:
        """The setpoint of tracker ``i`` as a :class:`MotionState` (Python floats)."""
        return MotionState(tuple(self.pos[i].tolist()), tuple(self.vel[i].tolist()),
                           tuple(self.acc[i].tolist()), float(self.ang[i]),
                           float(self.ang_vel[i]), float(self.ang_acc[i]))


class _Cols:
    """Per-column constants of the softMC step (one column per channel)."""

    __slots__ = ("V", "VT", "AT2", "JT3", "A", "J", "twoJ", "damp", "k_faster", "k_slower",
                 "thr", "thr_lo", "thr_hi", "directional", "pred_acc", "brake", "eos", "mid",
                 "dims", "any_directional", "any_no_pred_acc", "any_brake", "any_eos",
                 "any_lit", "any_mid")

    # per column (float64): V, V*T, A*T^2, J*T^3, A, J, 2J, damping, time-to-reach factors
    V: np.ndarray
    VT: np.ndarray
    AT2: np.ndarray
    JT3: np.ndarray
    A: np.ndarray
    J: np.ndarray
    twoJ: np.ndarray
    damp: np.ndarray
    k_faster: np.ndarray
    k_slower: np.ndarray
    #: sync thresholds (velocity, position) x column, and the exact-recompute band around them
    thr: np.ndarray
    thr_lo: np.ndarray
    thr_hi: np.ndarray
    # per column (bool): the SoftMcOptions switches; dims: the channel's dimension (int64)
    directional: np.ndarray
    pred_acc: np.ndarray
    brake: np.ndarray
    eos: np.ndarray
    mid: np.ndarray
    dims: np.ndarray
    # any column with the switch set (finish())
    any_directional: bool
    any_no_pred_acc: bool
    any_brake: bool
    any_eos: bool
    any_lit: bool
    any_mid: bool

    def take(self, idx: np.ndarray) -> _Cols:
        out = _Cols()
        for name in ("V", "VT", "AT2", "JT3", "A", "J", "twoJ", "damp", "k_faster", "k_slower",
                     "directional", "pred_acc", "brake", "eos", "mid", "dims"):
            setattr(out, name, getattr(self, name)[idx])
        for name in ("thr", "thr_lo", "thr_hi"):
            setattr(out, name, getattr(self, name)[:, idx])
        out.finish()
        return out

    def finish(self) -> None:
        self.any_directional = bool(self.directional.any())
        self.any_no_pred_acc = not bool(self.pred_acc.all())
        self.any_brake = bool(self.brake.any())
        self.any_eos = bool(self.eos.any())
        self.any_lit = not bool(self.eos.all())
        self.any_mid = bool(self.mid.any())


def _masked(mask: np.ndarray):
    """``where=`` argument for a masked in-place ufunc: True (no mask) when every column is
    selected (a plain ufunc call is several times faster than a masked one)."""
    return True if mask.all() else mask


def _softmc_step(T: float, p, v, a, dp0, ddp0, mp, mv, ma, c: _Cols):
    """softmc.SoftMcPlanner.step on (3, n) column arrays; inputs are not modified.

    Returns (new_p, new_v, new_a, dp, ddp, synced) -- dp/ddp are the next dp0/ddp0.
    Operation order mirrors softmc.py line by line (see the module docstring); the comments
    quote the scalar expressions.  Per-column scalars (D, t) are expanded to (3, n) once:
    same-shape ufuncs are faster than broadcasting ones.
    """
    T2 = T * T
    T3 = T2 * T
    T4 = T3 * T
    T5 = T4 * T
    shape = p.shape

    # 1.2.1 differences; 1.2.2 time to reach (softmc.time_to_reach).  The four loop
    # accumulations |mp - p|^2, |mv - v|^2, |mv|^2, |v|^2 are stacked: (4, 3, n)
    sq = np.empty((4,) + shape)
    np.subtract(mp, p, out=sq[0])
    np.subtract(mv, v, out=sq[1])
    if c.any_directional:
        # closing = sum over i of (mp - p)[i] * (mv - v)[i], a loop accumulation from 0.0
        closing = _dot3(sq[0], sq[1])
    np.multiply(sq[:2], sq[:2], out=sq[:2])
    np.multiply(mv, mv, out=sq[2])
    np.multiply(v, v, out=sq[3])
    nrm = sq[:, 0] + sq[:, 1]
    nrm += sq[:, 2]
    np.sqrt(nrm, out=nrm)
    pdn, vdn, mvn, vn = nrm
    # K = k_faster if master_speed > robot_speed else k_slower  (published: 4, 2); option
    # directional_k: "faster" when closing > 0.0 (time_to_reach gets (1, 0) or (0, 1))
    faster = mvn > vn
    if c.any_directional:
        np.copyto(faster, closing > 0.0, where=c.directional)
    K = np.where(faster, c.k_faster, c.k_slower)
    # D = sqrt(K * vel_diff / jerk) + sqrt(4.0 * pos_diff / acc); D *= damping
    K *= vdn
    K /= c.J
    D = np.sqrt(K, out=K)
    pdn *= 4.0
    pdn /= c.A
    D += np.sqrt(pdn, out=pdn)
    D *= c.damp
    # D = T * int(D / T + 1.0)   (positive: int() is floor; int -> float is exact)
    D /= T
    D += 1.0
    np.floor(D, out=D)
    D *= T
    D3 = np.empty(shape)
    D3[...] = D

    # 1.2.3 rendezvous prediction: t = D - T; half_t2 = 0.5*t*t
    t = np.subtract(D3, T)
    h = np.multiply(0.5, t)
    h *= t
    # pred_diff = mp + t*mv + half_t2*ma - p
    pd = t * mv
    pd += mp
    h *= ma
    pd += h
    pd -= p
    # pred_vel = mv + t*ma
    pv = t
    pv *= ma
    pv += mv
    # pred_acc = ma (or 0.0: literal)
    pa = np.where(c.pred_acc, ma, 0.0) if c.any_no_pred_acc else ma

    # quintic coefficients (nested form, #3.4); increment (#3.5).  Scratch: x, y (= h)
    x = np.empty(shape)
    y = h
    # c3 = (0.5*(pa - 3.0*a) + (10.0*pd/D - 6.0*v - 4.0*pv)/D)/D
    np.multiply(10.0, pd, out=x)
    x /= D3
    np.multiply(6.0, v, out=y)
    x -= y
    np.multiply(4.0, pv, out=y)
    x -= y
    x /= D3
    c3 = np.multiply(3.0, a)
    np.subtract(pa, c3, out=c3)
    c3 *= 0.5
    c3 += x
    c3 /= D3
    # c4 = (((5.0*pd/D - (pv + 4.0*v))/D - 1.5*a)/D - 2.0*c3)/D
    c4 = np.multiply(5.0, pd)
    c4 /= D3
    np.multiply(4.0, v, out=y)
    y += pv
    c4 -= y
    c4 /= D3
    np.multiply(1.5, a, out=y)
    c4 -= y
    c4 /= D3
    np.multiply(2.0, c3, out=y)
    c4 -= y
    c4 /= D3
    # c5 = ((((pd/D - v)/D - 0.5*a)/D - c3)/D - c4)/D
    c5 = pd
    c5 /= D3
    c5 -= v
    c5 /= D3
    np.multiply(0.5, a, out=y)
    c5 -= y
    c5 /= D3
    c5 -= c3
    c5 /= D3
    c5 -= c4
    c5 /= D3
    # dp = c5*T5 + c4*T4 + c3*T3 + 0.5*a*T2 + v*T
    dp = np.multiply(c5, T5)
    np.multiply(c4, T4, out=x)
    dp += x
    np.multiply(c3, T3, out=x)
    dp += x
    np.multiply(0.5, a, out=x)
    x *= T2
    dp += x
    np.multiply(v, T, out=x)
    dp += x

    # 1.2.5 velocity, acceleration and jerk filter (vector norms)
    # vel_cap = V*T, or with braking_distance_velocity: a_t = sum(a*dp)/|dp| and, if
    # |dp| > 0 and a_t > 0, vel_cap = max(0.0, V - a_t*a_t/(2.0*J))*T
    dpn = np.sqrt(_pysumsq3(dp))
    vel_cap = c.VT
    if c.any_brake:
        a_t = _pysum3(np.multiply(a, dp, out=x))
        a_t /= dpn
        cond = dpn > 0.0
        cond &= a_t > 0.0
        cond &= c.brake
        if cond.any():
            cap = a_t * a_t
            cap /= c.twoJ
            np.subtract(c.V, cap, out=cap)
            np.maximum(0.0, cap, out=cap)
            cap *= T
            vel_cap = np.where(cond, cap, c.VT)
    # if |dp| > vel_cap: dp = dp * (vel_cap / |dp|)
    sat = dpn > vel_cap
    if sat.any():
        k = np.divide(vel_cap, dpn)
        np.multiply(dp, k, out=dp, where=_masked(sat))
    # ddp = dp - dp0; if |ddp| > A*T2: ddp = ddp * (A*T2/|ddp|); dp = ddp + dp0
    ddp = dp - dp0
    ddpn = np.sqrt(_pysumsq3(ddp))
    sat_a = ddpn > c.AT2
    if sat_a.any():
        k = np.divide(c.AT2, ddpn)
        m = _masked(sat_a)
        np.multiply(ddp, k, out=ddp, where=m)
        np.add(ddp, dp0, out=dp, where=m)
        sat |= sat_a
    # dddp = ddp - ddp0; if |dddp| > J*T3: dddp *= J*T3/|dddp|; ddp = dddp + ddp0;
    # dp = ddp + dp0
    dddp = ddp - ddp0
    dddpn = np.sqrt(_pysumsq3(dddp))
    sat_j = dddpn > c.JT3
    if sat_j.any():
        k = np.divide(c.JT3, dddpn)
        m = _masked(sat_j)
        np.multiply(dddp, k, out=dddp, where=m)
        np.add(dddp, ddp0, out=ddp, where=m)
        np.add(ddp, dp0, out=dp, where=m)
        sat |= sat_j

    # new position; velocity and acceleration
    new_p = p + dp
    all_sat = bool(sat.all())
    if not all_sat:
        # v = 5.0*a5*T4 + 4.0*a4*T3 + 3.0*a3*T2 + a*T + v
        new_v = np.multiply(5.0, c5)
        new_v *= T4
        np.multiply(4.0, c4, out=x)
        x *= T3
        new_v += x
        np.multiply(3.0, c3, out=x)
        x *= T2
        new_v += x
        np.multiply(a, T, out=x)
        new_v += x
        new_v += v
        # acc = 20.0*a5*T3 + 12.0*a4*T2 + 6.0*a3*T + a
        new_a = np.multiply(20.0, c5)
        new_a *= T3
        np.multiply(12.0, c4, out=x)
        x *= T2
        new_a += x
        np.multiply(6.0, c3, out=x)
        x *= T
        new_a += x
        new_a += a
    if sat.any():
        if c.any_eos:
            m = sat & c.eos if c.any_lit or not all_sat else None
            # clamped, end of sample: v = (dp + 0.5*ddp + dddp/3.0)/T; a = (ddp + dddp)/T2
            ve = np.multiply(0.5, ddp)
            ve += dp
            np.divide(dddp, 3.0, out=x)
            ve += x
            ve /= T
            ae = np.add(ddp, dddp)
            ae /= T2
            if m is None:
                new_v, new_a = ve, ae
            else:
                if all_sat:
                    new_v = np.empty(shape)
                    new_a = np.empty(shape)
                np.copyto(new_v, ve, where=m)
                np.copyto(new_a, ae, where=m)
        if c.any_lit:
            # clamped, literal: v = dp/T; a = ddp/T2
            m = sat & ~c.eos
            if all_sat and not c.any_eos:
                new_v = np.divide(dp, T)
                new_a = np.divide(ddp, T2)
            else:
                np.divide(dp, T, out=new_v, where=m)
                np.divide(ddp, T2, out=new_a, where=m)

    # 1.2.5.6 synchronised?  |mv - v| and |mp - p| stacked: (2, 3, n).  softmc squares with
    # ``** 2`` (libm pow): columns within a relative 1e-12 of a threshold are recomputed so
    np.subtract(mv, new_v, out=sq[0])
    np.subtract(mp, new_p, out=sq[1])
    err = np.sqrt(_pysumsq3(sq[:2]))
    close = err >= c.thr_lo
    close &= err <= c.thr_hi
    close = close[0] | close[1]
    if close.any():
        _exact_norms(np.flatnonzero(close), mv, new_v, mp, new_p, c.dims, err)
    ok2 = err <= c.thr
    synced = ok2[0] & ok2[1]
    if c.any_mid:
        # take the middle: p = 0.5*(p + mp); v = 0.5*(v + mv)
        m = synced & c.mid
        if m.any():
            np.add(new_p, mp, out=x)
            x *= 0.5
            np.copyto(new_p, x, where=m)
            np.add(new_v, mv, out=x)
            x *= 0.5
            np.copyto(new_v, x, where=m)
    return new_p, new_v, new_a, dp, ddp, synced


def _exact_norms(cols, mv, new_v, mp, new_p, dims, err) -> None:
    """``math.sqrt(sum((mv[i] - new_v[i]) ** 2 ...))`` and the same for the position error
    (softmc.py 1.2.5.6), recomputed with Python's ``** 2`` for ``cols``; written to ``err``."""
    dv = (mv[:, cols] - new_v[:, cols]).T.tolist()
    ep = (mp[:, cols] - new_p[:, cols]).T.tolist()
    for j, dvc, epc in zip(cols.tolist(), dv, ep):
        n = int(dims[j])
        err[0, j] = math.sqrt(sum(d ** 2 for d in dvc[:n]))
        err[1, j] = math.sqrt(sum(d ** 2 for d in epc[:n]))


def _as_index(mask, n: int, what: str) -> np.ndarray:
    """A mask argument (None: all; bool (n,); or integer indices) as an index array."""
    if mask is None:
        return np.arange(n)
    m = np.asarray(mask)
    if m.dtype == bool:
        if m.shape != (n,):
            raise ParameterError(f"{what}: boolean mask shape {m.shape} must be ({n},)")
        return np.flatnonzero(m)
    if m.ndim == 0:
        m = m.reshape(1)
    if m.ndim != 1 or not np.issubdtype(m.dtype, np.integer):
        raise ParameterError(f"{what}: mask must be None, a bool array of shape ({n},) or "
                             f"integer indices")
    bad = (m < -n) | (m >= n)
    if bad.any():
        raise ParameterError(f"{what}: index {int(m[np.argmax(bad)])} out of range "
                             f"[0...{n - 1}]")
    return np.unique(m % n)


class BatchTracker:
    """N independent softMC trackers stepped together (bit-identical to N ``Tracker``).

    ``params``: N :class:`TrackerParams`, all with ``planner="softmc"`` and the same
    ``sample_time_s``; every other field may differ per tracker.  ``initial``: None (all at
    rest at the origin), one :class:`MotionState` for all, N MotionStates, or a mapping with
    arrays ``pos``/``vel``/``acc`` (N, 3) and ``ang``/``ang_vel``/``ang_acc`` (N,) (missing
    keys are zero).  Invalid entries raise :class:`ParameterError` naming the index.

    ``engage(mask)``/``disengage(mask)`` take effect at the next :meth:`update`, like
    ``Tracker.engage``/``disengage``.  The optimal (Ruckig) planner is not supported: it
    plans per tracker and is not vectorised.
    """

    def __init__(self, params: Sequence[TrackerParams], initial=None) -> None:
        # (objects until checked: a caller may pass anything)
        given: list[object] = list(params) if not isinstance(params, TrackerParams) \
            else [params]
        n = len(given)
        if n == 0:
            raise ParameterError("params: at least one TrackerParams is needed (got 0)")
        checked: list[TrackerParams] = []
        for i, q in enumerate(given):
            if not isinstance(q, TrackerParams):
                raise ParameterError(
                    f"params[{i}] (={type(q).__name__}) must be a TrackerParams")
            checked.append(q)
        params = checked
        for i, p in enumerate(params):
            if p.planner != "softmc":
                raise ParameterError(
                    f"batch stepping supports planner 'softmc' only: params[{i}].planner is "
                    f"{p.planner!r} (the optimal planner runs Ruckig per tracker and is not "
                    f"vectorised; step it with controller.tracking.Tracker)")
        T = params[0].sample_time_s
        for i, p in enumerate(params):
            if p.sample_time_s != T:
                raise ParameterError(
                    f"params[{i}].sample_time_s (={p.sample_time_s!r}) must equal "
                    f"params[0].sample_time_s (={T!r}): a batch runs on one clock")
        self.params: tuple[TrackerParams, ...] = tuple(params)
        self.n = n
        self.T = T
        self.sample = 0
        self._build_constants()
        self._init_state(initial)

    # -- construction ---------------------------------------------------------------------
    def _build_constants(self) -> None:
        T = self.T
        T2 = T * T
        T3 = T2 * T
        cols: dict[str, list] = {k: [] for k in (
            "V", "VT", "AT2", "JT3", "A", "J", "twoJ", "damp", "k_faster", "k_slower", "thr_v",
            "thr_p", "directional", "pred_acc",
            "brake", "eos", "mid", "dims", "init_inc", "osc_thr", "window", "ring")}
        self._limits = []
        mt_v, mt_a, mr_v, mr_a, timeout, mode = [], [], [], [], [], []
        for p in self.params:
            lim = p.effective()
            self._limits.append(lim)
            o = p.softmc
            # K of the time-to-reach estimate (softmc.time_to_reach; published: 4 and 2)
            k_faster, k_slower = getattr(o, "time_to_reach_k", (4.0, 2.0))
            window = max(1, round(p.max_flops_time_s / T))
            max_flops = int(p.max_flops)
            for ch, dims in ((lim.sync_trans, 3), (lim.sync_rot, 1)):
                g = float(p.filter_factor)
                cols["V"].append(float(ch.vel))
                cols["VT"].append(ch.vel * T)
                cols["AT2"].append(ch.acc * T2)
                cols["JT3"].append(ch.jerk * T3)
                cols["A"].append(float(ch.acc))
                cols["J"].append(float(ch.jerk))
                cols["twoJ"].append(2.0 * ch.jerk)
                cols["damp"].append(float(p.damping_factor))
                cols["k_faster"].append(float(k_faster))
                cols["k_slower"].append(float(k_slower))
                cols["directional"].append(bool(getattr(o, "directional_k", False)))
                cols["thr_v"].append(g * ch.acc * T)
                cols["thr_p"].append(g * ch.acc * T * T if o.unit_consistent_thresholds
                                     else 0.5 * ch.acc * T * T)
                cols["pred_acc"].append(bool(o.pred_acc_from_master))
                cols["brake"].append(bool(o.braking_distance_velocity))
                cols["eos"].append(bool(o.end_of_sample_feedback))
                cols["mid"].append(bool(o.take_the_middle))
                cols["dims"].append(dims)
                cols["init_inc"].append(bool(o.init_increments_from_state))
                cols["osc_thr"].append(float(p.filter_factor * ch.acc * T))
                cols["window"].append(window)
                # more than max_flops flips inside `window` samples needs max_flops < window
                cols["ring"].append(min(max_flops, window) + 1)
            mt_v.append(float(p.master_max_trans.vel))
            mt_a.append(float(p.master_max_trans.acc))
            mr_v.append(float(p.master_max_rot.vel))
            mr_a.append(float(p.master_max_rot.acc))
            timeout.append(max(1, round(p.approach_timeout_s / T)))
            mode.append(int(p.mode))

        def order(values):  # per tracker (trans, rot) pairs -> columns [trans..., rot...]
            return values[0::2] + values[1::2]

        c = _Cols()
        for name in ("V", "VT", "AT2", "JT3", "A", "J", "twoJ", "damp", "k_faster", "k_slower"):
            setattr(c, name, np.array(order(cols[name]), dtype=np.float64))
        # sync thresholds (velocity, position) and the band around them in which the
        # ``** 2`` norm of softmc.py is recomputed exactly
        c.thr = np.array([order(cols["thr_v"]), order(cols["thr_p"])], dtype=np.float64)
        tol = _CLOSE_REL * c.thr + _CLOSE_ABS
        c.thr_lo = c.thr - tol
        c.thr_hi = c.thr + tol
        for name in ("directional", "pred_acc", "brake", "eos", "mid"):
            setattr(c, name, np.array(order(cols[name]), dtype=bool))
        c.dims = np.array(order(cols["dims"]), dtype=np.int64)
        c.finish()
        self._cols = c
        self._init_inc = np.array(order(cols["init_inc"]), dtype=bool)
        # OscillationMonitor: a flip counts when the peak |dv| exceeded 2.0 * g*A*T
        self._osc_thr2 = 2.0 * np.array(order(cols["osc_thr"]), dtype=np.float64)
        self._window = np.array(order(cols["window"]), dtype=np.int64)
        ring = np.array(order(cols["ring"]), dtype=np.int64)
        self._ring_len = ring
        self._ring_base = np.concatenate([[0], np.cumsum(ring)[:-1]]).astype(np.int64)
        self._ring = np.full(int(ring.sum()), _NEVER, dtype=np.int64)
        self._master_max_trans = np.array([mt_v, mt_a], dtype=np.float64)
        self._master_max_rot = np.array([mr_v, mr_a], dtype=np.float64)
        self._timeout = np.array(timeout, dtype=np.int64)
        self._param_mode = np.array(mode, dtype=np.int64)

    def _init_state(self, initial) -> None:
        n = self.n
        m2 = 2 * n
        self._p = np.zeros((3, m2))
        self._v = np.zeros((3, m2))
        self._a = np.zeros((3, m2))
        self._set_initial(initial)
        self._dp0 = np.zeros((3, m2))
        self._ddp0 = np.zeros((3, m2))
        self._off = np.zeros((3, m2))
        # the masters of this update: position, velocity, acceleration (3, 3, 2N)
        self._m = np.zeros((3, 3, m2))
        self._mp, self._mv, self._ma = self._m
        self._state = np.zeros(n, dtype=np.int8)
        self._error = np.zeros(n, dtype=np.int8)
        self._request = np.zeros(n, dtype=np.int8)
        self._any_request = False
        self._request_mode = np.zeros(n, dtype=np.int64)  # 0: none given yet
        self._mode = self._param_mode.copy()
        self._rel_cols = np.zeros(m2, dtype=bool)
        self._ch_synced = np.zeros(m2, dtype=bool)
        self._approach_start = np.zeros(n, dtype=np.int64)
        self._desync_start = np.zeros(n, dtype=np.int64)
        self._synced_at = np.full(n, -1, dtype=np.int64)
        # oscillation monitors (one per column)
        self._dv0 = np.zeros((3, m2))
        self._has_dv0 = np.zeros(m2, dtype=bool)
        self._peak = np.zeros(m2)  # largest |dv| since the last flip
        self._ring_ptr = np.zeros(m2, dtype=np.int64)
        self._hot_until = np.full(m2, _NEVER, dtype=np.int64)
        # de-sync segment tables (one stop per column)
        self._nseg_max = 4
        self._seg = np.zeros((6, m2, self._nseg_max))  # t0, dur, s0, v0, a_s, a_e
        self._seg_end = np.full((m2, self._nseg_max), np.inf)
        self._stop_dur = np.zeros(m2)
        self._stop_end = np.zeros(m2)
        self._d_origin = np.zeros((3, m2))
        self._d_dir = np.zeros((3, m2))
        self._all_trackers = np.arange(n)
        #: SYNCING trackers from which the softMC step runs on all columns (dense mode)
        self._dense_min = max(1, int(0.4 * n))

    def _set_initial(self, initial) -> None:
        n = self.n
        if initial is None:
            return
        if isinstance(initial, MotionState):
            initial = [initial] * n
        if isinstance(initial, dict):
            arrays = {}
            for key, shape in (("pos", (n, 3)), ("vel", (n, 3)), ("acc", (n, 3)),
                               ("ang", (n,)), ("ang_vel", (n,)), ("ang_acc", (n,))):
                val = initial.get(key, 0.0)
                try:
                    arrays[key] = np.broadcast_to(np.asarray(val, dtype=np.float64), shape)
                except ValueError:
                    raise ParameterError(
                        f"initial[{key!r}]: shape {np.shape(val)} does not broadcast to "
                        f"{shape}") from None
            unknown = set(initial) - set(arrays)
            if unknown:
                raise ParameterError(f"initial: unknown keys {sorted(unknown)} (allowed: pos, "
                                     f"vel, acc, ang, ang_vel, ang_acc)")
            self._p[:, :n] = arrays["pos"].T
            self._v[:, :n] = arrays["vel"].T
            self._a[:, :n] = arrays["acc"].T
            self._p[0, n:] = arrays["ang"]
            self._v[0, n:] = arrays["ang_vel"]
            self._a[0, n:] = arrays["ang_acc"]
            return
        initial = list(initial)
        if len(initial) != n:
            raise ParameterError(f"initial: {len(initial)} states given, {n} needed "
                                 f"(one per TrackerParams)")
        for i, s in enumerate(initial):
            if not isinstance(s, MotionState):
                raise ParameterError(f"initial[{i}] (={type(s).__name__}) must be a MotionState")
            for name in ("pos", "vel", "acc"):
                if len(getattr(s, name)) != 3:
                    raise ParameterError(f"initial[{i}].{name} must have 3 components")
        self._p[:, :n] = np.array([s.pos for s in initial], dtype=np.float64).T
        self._v[:, :n] = np.array([s.vel for s in initial], dtype=np.float64).T
        self._a[:, :n] = np.array([s.acc for s in initial], dtype=np.float64).T
        self._p[0, n:] = [s.ang for s in initial]
        self._v[0, n:] = [s.ang_vel for s in initial]
        self._a[0, n:] = [s.ang_acc for s in initial]

    # -- commands -----------------------------------------------------------------------------
    def engage(self, mask=None, mode: Mode | int | None = None) -> None:
        """Start synchronising the selected trackers at the next update (``Tracker.engage``).

        ``mask``: None (all), a bool array (N,) or integer indices.  ``mode``: 3 absolute /
        5 relative (kept for later engages, as in ``Tracker``); 0 means disengage.
        """
        idx = _as_index(mask, self.n, "engage")
        if mode is not None:
            try:
                m = Mode(mode)
            except ValueError:
                raise ParameterError(f"engage: mode (={mode!r}) must be 0, 3 or 5") from None
            if m == Mode.OFF:
                self.disengage(idx)
                return
            self._request_mode[idx] = int(m)
        self._request[idx] = _REQ_ENGAGE
        self._any_request = True

    def disengage(self, mask=None) -> None:
        """Start the de-sync of the selected trackers at the next update (``slave = 0``)."""
        idx = _as_index(mask, self.n, "disengage")
        self._request[idx] = _REQ_DISENGAGE
        self._any_request = True

    def set_robot_state(self, i: int, state: MotionState) -> None:
        """Set the robot state of tracker ``i`` while OFF (``Tracker.set_robot_state``)."""
        if self._state[i] != _OFF:
            raise StateError(f"set_robot_state: tracker {i} is not OFF "
                             f"(state {TrackState(int(self._state[i])).name})")
        n = self.n
        self._p[:, i] = state.pos
        self._v[:, i] = state.vel
        self._a[:, i] = state.acc
        self._p[0, n + i] = state.ang
        self._v[0, n + i] = state.ang_vel
        self._a[0, n + i] = state.ang_acc

    # -- read-only views ----------------------------------------------------------------------
    @property
    def state(self) -> np.ndarray:
        """TrackState per tracker (copy)."""
        return self._state.copy()

    @property
    def error(self) -> np.ndarray:
        """TrackError per tracker (copy)."""
        return self._error.copy()

    @property
    def synced_at(self) -> np.ndarray:
        """Sample at which each tracker's last approach completed (-1: not yet)."""
        return self._synced_at.copy()

    def setpoint(self, i: int) -> MotionState:
        """The current setpoint of tracker ``i``."""
        n = self.n
        return MotionState(tuple(self._p[:, i].tolist()), tuple(self._v[:, i].tolist()),
                           tuple(self._a[:, i].tolist()), float(self._p[0, n + i]),
                           float(self._v[0, n + i]), float(self._a[0, n + i]))

    # -- transitions --------------------------------------------------------------------------
    def _start_sync(self, idx: np.ndarray) -> None:
        """Tracker._start_sync for trackers ``idx`` with the master of this update."""
        n, T = self.n, self.T
        rm = self._request_mode[idx]
        mode = np.where(rm != 0, rm, self._param_mode[idx])
        self._mode[idx] = mode
        cols = np.concatenate([idx, idx + n])
        rel = np.concatenate([mode, mode]) == int(Mode.RELATIVE)
        self._rel_cols[cols] = rel
        # relative: offset = setpoint - master.extrapolated(-T)
        dt = -T
        h = 0.5 * dt * dt
        mp, mv, ma = self._mp[:, cols], self._mv[:, cols], self._ma[:, cols]
        back = mp + mv * dt
        back += ma * h
        off = self._p[:, cols] - back
        self._off[:, cols] = np.where(rel, off, 0.0)
        # planner reset (softmc.reset): dp0 = v*T, ddp0 = a*T*T (or 0)
        init = self._init_inc[cols]
        self._dp0[:, cols] = np.where(init, self._v[:, cols] * T, 0.0)
        self._ddp0[:, cols] = np.where(init, self._a[:, cols] * T * T, 0.0)
        # oscillation monitors
        self._has_dv0[cols] = False
        self._peak[cols] = 0.0
        self._ring_ptr[cols] = 0
        self._hot_until[cols] = _NEVER
        lens = self._ring_len[cols]
        ends = np.cumsum(lens)
        slot = np.arange(int(ends[-1])) - np.repeat(ends - lens, lens)
        self._ring[np.repeat(self._ring_base[cols], lens) + slot] = _NEVER
        self._ch_synced[cols] = False
        self._approach_start[idx] = self.sample
        self._synced_at[idx] = -1
        self._error[idx] = int(TrackError.NONE)
        self._state[idx] = _SYNCING

    def _start_desync(self, idx: np.ndarray, start_sample: int) -> None:
        """Tracker._start_desync: plan the stops with the scalar code, store the tables."""
        n = self.n
        cols, rows, dirs, origins = [], [], [], []
        P = self._p
        pos = P[:, idx].T.tolist()
        vel = self._v[:, idx].T.tolist()
        acc = self._a[:, idx].T.tolist()
        ang = P[0, idx + n].tolist()
        angv = self._v[0, idx + n].tolist()
        anga = self._a[0, idx + n].tolist()
        for j, i in enumerate(idx.tolist()):
            lim = self._limits[i]
            cur = self.params[i].desync_from_current_acceleration
            tr = Desync.linear(tuple(pos[j]), tuple(vel[j]), tuple(acc[j]),
                               lim.desync_trans.acc, lim.desync_trans.jerk, cur)
            rot = Desync.linear((ang[j],), (angv[j],), (anga[j],), lim.desync_rot.acc,
                                lim.desync_rot.jerk, cur)
            for c, d in ((i, tr), (n + i, rot)):
                cols.append(c)
                rows.append(d.stop)
                path = d.path
                assert isinstance(path, LinearPath)  # Desync.linear's path
                o = tuple(path.origin) + (0.0,) * (3 - len(path.origin))
                u = tuple(path.direction) + (0.0,) * (3 - len(path.direction))
                origins.append(o)
                dirs.append(u)
        nmax = max(len(s.segments) for s in rows)
        if nmax > self._nseg_max:  # pragma: no cover - SineStop plans at most 4 segments
            grow = nmax - self._nseg_max
            self._seg = np.concatenate([self._seg, np.zeros((6, 2 * n, grow))], axis=2)
            self._seg_end = np.concatenate([self._seg_end, np.full((2 * n, grow), np.inf)],
                                           axis=1)
            self._nseg_max = nmax
        w = self._nseg_max
        seg = np.zeros((6, len(cols), w))
        end = np.full((len(cols), w), np.inf)
        for r, stop in enumerate(rows):
            for s, g in enumerate(stop.segments):
                seg[:, r, s] = (g.t0, g.duration, g.s0, g.v0, g.a_start, g.a_end)
                end[r, s] = g.t0 + g.duration
        ca = np.array(cols, dtype=np.int64)
        self._seg[:, ca, :] = seg
        self._seg_end[ca] = end
        self._stop_dur[ca] = [s.duration for s in rows]
        self._stop_end[ca] = [s.end_position for s in rows]
        self._d_origin[:, ca] = np.array(origins, dtype=np.float64).T
        self._d_dir[:, ca] = np.array(dirs, dtype=np.float64).T
        self._desync_start[idx] = start_sample
        self._state[idx] = _DESYNCING

    # -- the cyclic call ----------------------------------------------------------------------
    def _put_master(self, master_pos, master_vel, master_acc, master_ang, master_ang_vel,
                    master_ang_acc) -> None:
        n = self.n
        for buf, val, name in ((self._mp, master_pos, "master_pos"),
                               (self._mv, master_vel, "master_vel"),
                               (self._ma, master_acc, "master_acc")):
            arr = np.asarray(val, dtype=np.float64)
            if arr.shape == (n, 3):
                buf[:, :n] = arr.T
            elif arr.shape == (3,) or arr.shape == (1, 3):
                buf[:, :n] = arr.reshape(3, 1)
            elif arr.ndim == 0:
                buf[:, :n] = arr
            else:
                raise ParameterError(f"{name}: shape {arr.shape} must be ({n}, 3) or (3,)")
        for buf, val, name in ((self._mp, master_ang, "master_ang"),
                               (self._mv, master_ang_vel, "master_ang_vel"),
                               (self._ma, master_ang_acc, "master_ang_acc")):
            arr = np.asarray(val, dtype=np.float64)
            if arr.shape == (n,) or arr.ndim == 0 or arr.shape == (1,):
                buf[0, n:] = arr
            else:
                raise ParameterError(f"{name}: shape {arr.shape} must be ({n},) or a scalar")

    def update(self, master_pos, master_vel=0.0, master_acc=0.0, master_ang=0.0,
               master_ang_vel=0.0, master_ang_acc=0.0) -> BatchOutput:
        """One sample of all trackers (``Tracker.update``) from the masters at this sample.

        ``master_pos``/``master_vel``/``master_acc``: (N, 3) or (3,) (one master for all)
        mm, mm/s, mm/s^2; ``master_ang``/``master_ang_vel``/``master_ang_acc``: (N,) or scalar
        deg, deg/s, deg/s^2.  ``master_pos`` may also be one :class:`MotionState` (for all).
        """
        if isinstance(master_pos, MotionState):
            m = master_pos
            master_pos, master_vel, master_acc = m.pos, m.vel, m.acc
            master_ang, master_ang_vel, master_ang_acc = m.ang, m.ang_vel, m.ang_acc
        self._put_master(master_pos, master_vel, master_acc, master_ang, master_ang_vel,
                         master_ang_acc)
        with np.errstate(all="ignore"):
            synced_now = self._update()
        n = self.n
        st = self._state.copy()
        return BatchOutput(
            pos=self._p[:, :n].T.copy(), vel=self._v[:, :n].T.copy(),
            acc=self._a[:, :n].T.copy(), ang=self._p[0, n:].copy(),
            ang_vel=self._v[0, n:].copy(), ang_acc=self._a[0, n:].copy(),
            state=st, imfs=_IMFS_OF_STATE[st], error=self._error.copy(),
            synced_now=synced_now, sample=self.sample)

    def _update(self) -> np.ndarray:
        n = self.n
        st = self._state
        if self._any_request:
            req = self._request
            eng = (req == _REQ_ENGAGE) & ((st == _OFF) | (st == _DESYNCING))
            dis = (req == _REQ_DISENGAGE) & ((st == _SYNCING) | (st == _SYNCED))
            self._request = np.zeros(n, dtype=np.int8)
            self._any_request = False
            if eng.any():
                self._start_sync(np.flatnonzero(eng))
            if dis.any():
                self._start_desync(np.flatnonzero(dis), self.sample)
        self.sample += 1
        k = self.sample
        synced_now = np.zeros(n, dtype=bool)

        # master limits (SYNCING and SYNCED; tracker._check_master)
        active = (st == _SYNCING) | (st == _SYNCED)
        if active.any():
            m = self._m[1:]  # velocity, acceleration
            bad = np.sqrt(_acc3(m[:, :, :n])) > self._master_max_trans
            bad |= np.abs(m[:, 0, n:]) > self._master_max_rot
            bad &= active
            bad_v, bad_a = bad
            bad = bad_v | bad_a
            if bad.any():
                self._error[bad] = np.where(bad_v[bad], int(TrackError.MASTER_VELOCITY),
                                            int(TrackError.MASTER_ACCELERATION))
                self._start_desync(np.flatnonzero(bad), k - 1)

        syncing = st == _SYNCING
        synced = st == _SYNCED
        desyncing = st == _DESYNCING
        off = st == _OFF
        if syncing.any():
            self._step_syncing(syncing, k, synced_now)
        if synced.any():
            self._step_synced(synced)
        if desyncing.any():
            self._step_desyncing(desyncing, k)
        if off.any():
            self._step_off(off)
        return synced_now

    def _select(self, mask: np.ndarray):
        """(tracker selector, column selector, count): slices when all trackers match."""
        if mask.all():
            return slice(None), slice(None), self.n
        idx = np.flatnonzero(mask)
        return idx, np.concatenate([idx, idx + self.n]), len(idx)

    def _shifted(self, cols, buf_p):
        """Tracker._shifted on the master position columns ``cols`` (relative mode)."""
        mp = buf_p[:, cols] if isinstance(cols, slice) else np.take(buf_p, cols, axis=1)
        rel = self._rel_cols[cols]
        if rel.any():
            off = self._off[:, cols] if isinstance(cols, slice) else np.take(self._off, cols,
                                                                             axis=1)
            mp = np.where(rel, mp + off, mp)
        return mp

    def _step_syncing(self, mask: np.ndarray, k: int, synced_now: np.ndarray) -> None:
        """The SYNCING branch of Tracker.update for the trackers in ``mask``.

        Dense mode (most trackers SYNCING): the softMC step runs on all columns and only the
        SYNCING ones are written back (masked copies); the other columns' results are
        discarded.  Sparse mode: the SYNCING columns are gathered and scattered back.
        """
        n = self.n
        count = int(np.count_nonzero(mask))
        tsel: slice | np.ndarray
        csel: slice | np.ndarray
        if count == n or count >= self._dense_min:
            tsel = csel = slice(None)
            ns = n
            tmask = None if count == n else mask
            cmask = None if count == n else np.concatenate([mask, mask])
            c = self._cols

            def get(arr):
                return arr
        else:
            sel = np.flatnonzero(mask)
            tsel = sel
            csel = csel_idx = np.concatenate([sel, sel + n])
            ns = count
            tmask = cmask = None
            c = self._cols.take(csel_idx)

            def get(arr):
                return np.take(arr, csel, axis=-1)
        mp = self._shifted(csel, self._mp)
        mv, ma = get(self._mv), get(self._ma)
        p, v, a = get(self._p), get(self._v), get(self._a)
        new_p, new_v, new_a, dp, ddp, ok = _softmc_step(
            self.T, p, v, a, get(self._dp0), get(self._ddp0), mp, mv, ma, c)
        chs = get(self._ch_synced)
        if chs.any():
            # a channel synchronised earlier copies the (shifted) master
            np.copyto(new_p, mp, where=chs)
            np.copyto(new_v, mv, where=chs)
            np.copyto(new_a, ma, where=chs)
            ok |= chs
        nok = ~ok  # stepped without synchronising (as in the scalar code: not ok)
        if cmask is not None:
            nok &= cmask

        # over-oscillation monitors (oscillation.OscillationMonitor.update) on the columns
        # that stepped; a channel that synchronised is not monitored again until the next
        # engage resets its monitor, so updating its monitor here is harmless
        dv = mv - new_v
        dvn = np.sqrt(_acc3(dv))  # vec.norm
        flip = _dot3(get(self._dv0), dv) < 0.0
        flip &= get(self._has_dv0)
        if cmask is not None:
            flip &= cmask
        # a flip counts when the peak |dv| since the previous flip exceeded 2*g*A*T; the
        # peak restarts from |dv| at a flip, else grows: ``elif n > peak: peak = n``
        peak = get(self._peak)
        counted = peak > get(self._osc_thr2)
        counted &= flip
        grow = dvn > peak
        grow |= flip
        if cmask is not None:
            grow &= cmask
        np.copyto(peak, dvn, where=grow)
        if counted.any():
            fc = np.flatnonzero(counted) if isinstance(csel, slice) else csel[counted]
            ptr = self._ring_ptr[fc]
            self._ring[self._ring_base[fc] + ptr] = k
            ptr += 1
            ptr %= self._ring_len[fc]
            self._ring_ptr[fc] = ptr
            # more than max_flops counted flips in (k - window, k] while the oldest of the
            # last max_flops + 1 counted flips is younger than `window` samples
            self._hot_until[fc] = self._ring[self._ring_base[fc] + ptr] + self._window[fc]
        osc = get(self._hot_until) > k
        osc &= nok

        # store the new setpoints, planner increments and monitor states
        if cmask is None and isinstance(csel, slice):
            self._p, self._v, self._a = new_p, new_v, new_a
            self._dp0, self._ddp0, self._dv0 = dp, ddp, dv
            self._ch_synced = ok
            self._peak = peak
            self._has_dv0[:] = True
        elif cmask is not None:
            for dst, src in ((self._p, new_p), (self._v, new_v), (self._a, new_a),
                             (self._dp0, dp), (self._ddp0, ddp), (self._dv0, dv)):
                np.copyto(dst, src, where=cmask)
            np.copyto(self._ch_synced, ok, where=cmask)
            self._has_dv0 |= cmask
            # peak (a view of self._peak) was updated in place on flip-masked columns only
        else:
            for dst, src in ((self._p, new_p), (self._v, new_v), (self._a, new_a),
                             (self._dp0, dp), (self._ddp0, ddp), (self._dv0, dv)):
                dst[:, csel] = src
            self._ch_synced[csel] = ok
            self._peak[csel] = peak
            self._has_dv0[csel] = True

        # SYNCED when both channels are; else over-oscillation or approach timeout
        both = ok[:ns] & ok[ns:]
        if tmask is not None:
            both &= tmask
        osc_t = osc[:ns] | osc[ns:]
        tidx = self._all_trackers[tsel]
        if both.any():
            bi = tidx[both]
            self._state[bi] = _SYNCED
            self._synced_at[bi] = k
            synced_now[bi] = True
        timed_out = (k - self._approach_start[tsel]) >= self._timeout[tsel]
        timed_out &= ~both
        timed_out &= ~osc_t
        if tmask is not None:
            timed_out &= tmask
        failed = osc_t | timed_out
        if failed.any():
            fi = tidx[failed]
            self._error[fi] = np.where(osc_t[failed], int(TrackError.OVER_OSCILLATION),
                                       int(TrackError.APPROACH_TIMEOUT))
            self._start_desync(fi, k)

    def _step_synced(self, mask: np.ndarray) -> None:
        _, csel, _ = self._select(mask)
        mp = self._shifted(csel, self._mp)
        self._p[:, csel] = mp
        self._v[:, csel] = self._mv[:, csel]
        self._a[:, csel] = self._ma[:, csel]

    def _step_desyncing(self, mask: np.ndarray, k: int) -> None:
        n, T = self.n, self.T
        idx = np.flatnonzero(mask)
        cols = np.concatenate([idx, idx + n])
        t = (k - self._desync_start[idx]).astype(np.float64) * T
        t = np.concatenate([t, t])
        fin = t >= self._stop_dur[cols]
        s = self._stop_end[cols].copy()  # finished: (end_position, 0, 0)
        sd = np.zeros(len(cols))
        sdd = np.zeros(len(cols))
        run = np.flatnonzero(~fin)
        if len(run):
            rc = cols[run]
            tr = t[run]
            j = np.argmax(tr[:, None] < self._seg_end[rc], axis=1)
            t0, dur, s0, v0, a_s, a_e = self._seg[:, rc, j]
            tt = np.maximum(0.0, tr - t0)
            da = a_e - a_s
            # constant acceleration: (s0 + v0*t + 0.5*a_s*t*t, v0 + a_s*t, a_s)
            hs = 0.5 * a_s
            hs *= tt
            hs *= tt
            pos = s0 + v0 * tt
            pos += hs
            vel = v0 + a_s * tt
            acc = a_s.copy()
            ramp = np.flatnonzero((da != 0.0) & (dur != 0.0))
            if len(ramp):
                rt = tt[ramp]
                rda = da[ramp]
                w = math.pi / dur[ramp]
                wt = (w * rt).tolist()
                cs = np.fromiter(map(math.cos, wt), np.float64, len(wt))
                sn = np.fromiter(map(math.sin, wt), np.float64, len(wt))
                hda = 0.5 * rda
                one_c = 1.0 - cs
                acc[ramp] = a_s[ramp] + hda * one_c
                vel[ramp] += hda * (rt - sn / w)
                pos[ramp] += hda * ((0.5 * rt) * rt - one_c / (w * w))
            s[run] = pos
            sd[run] = vel
            sdd[run] = acc
        u = self._d_dir[:, cols]
        self._p[:, cols] = self._d_origin[:, cols] + s * u
        self._v[:, cols] = sd * u
        self._a[:, cols] = sdd * u
        done = fin[:len(idx)] & fin[len(idx):]
        if done.any():
            self._state[idx[done]] = _OFF

    def _step_off(self, mask: np.ndarray) -> None:
        """MotionState.extrapolated(T): p + v*T + a*(0.5*T*T), v + a*T."""
        _, csel, _ = self._select(mask)
        T = self.T
        h = 0.5 * T * T
        p, v, a = self._p[:, csel], self._v[:, csel], self._a[:, csel]
        np_ = p + v * T
        np_ += a * h
        self._p[:, csel] = np_
        self._v[:, csel] = v + a * T


# -- benchmark ------------------------------------------------------------------------------
def benchmark(n: int | Sequence[int] = (1, 100, 1000, 10000), steps: int = 2000,
              out=print) -> dict[int, tuple[float, float]]:
    """Print and return tracker-steps/s of ``update`` with all N trackers in SYNCING.

    The trackers (FilterFactor 0.5...2, DampingFactor 0.5...2, different limits) chase a
    master that is 10 m away and moving at 500 mm/s, so they stay in the approach with the
    clamps active; the approach timeout is set beyond the run.  The run is split into 10
    rounds; the figures are the mean over all steps and the best round (less disturbed by
    other processes on the machine).  Returns {N: (mean, best)} in tracker-steps/s, and
    under the key 0 the scalar ``Tracker`` on the same problem (100 trackers) for reference.
    """
    sizes = [n] if isinstance(n, int) else list(n)
    results = {}
    for size in sizes:
        rng = np.random.default_rng(size)
        params = [TrackerParams(
            sample_time_s=0.001, planner="softmc", approach_timeout_s=1e6,
            filter_factor=float(rng.uniform(0.5, 2.0)),
            damping_factor=float(rng.uniform(0.5, 2.0)),
            sync_trans=Limits(float(rng.uniform(1000, 3000)), float(rng.uniform(5e3, 3e4)),
                              float(rng.uniform(1e5, 5e5))))
            for _ in range(size)]
        bt = BatchTracker(params)
        bt.engage()
        T = bt.T
        mv = np.array([500.0, 0.0, 0.0])
        ma = np.zeros(3)
        bt.update(np.array([1e4, 0.0, 0.0]), mv, ma, 0.0, 10.0, 0.0)  # engage
        rounds = 10
        per_round = max(1, steps // rounds)
        times = []
        k = 0
        for _ in range(rounds):
            t0 = time.perf_counter()
            for _ in range(per_round):
                k += 1
                o = bt.update(np.array([1e4 + 500.0 * k * T, 0.0, 0.0]), mv, ma, 0.0, 10.0,
                              0.0)
            times.append(time.perf_counter() - t0)
        mean = size * per_round * rounds / sum(times)
        best = size * per_round / min(times)
        syncing = int(np.count_nonzero(o.state == _SYNCING))
        out(f"N={size:6d}: {mean:12,.0f} tracker-steps/s mean, {best:12,.0f} best round "
            f"({sum(times) / (per_round * rounds) * 1e3:7.3f} / "
            f"{min(times) / per_round * 1e3:7.3f} ms per update; "
            f"{syncing}/{size} SYNCING at the end)")
        results[size] = (mean, best)
    # the scalar path on the same problem, for reference
    from .tracker import Tracker
    size = 100
    trackers = [Tracker(p) for p in params[:size]] if len(params) >= size else [
        Tracker(params[i % len(params)]) for i in range(size)]
    for tr in trackers:
        tr.engage()
    scalar_steps = max(1, min(steps, 200))
    t0 = time.perf_counter()
    for k in range(scalar_steps + 1):
        m = MotionState((1e4 + 500.0 * k * 0.001, 0.0, 0.0), (500.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                        0.0, 10.0, 0.0)
        for tr in trackers:
            tr.update(m)
    rate = size * (scalar_steps + 1) / (time.perf_counter() - t0)
    out(f"scalar Tracker (reference): {rate:12,.0f} tracker-steps/s")
    results[0] = (rate, rate)
    return results


if __name__ == "__main__":  # pragma: no cover
    import argparse

    ap = argparse.ArgumentParser(description="BatchTracker throughput (tracker-steps/s)")
    ap.add_argument("-n", type=int, nargs="*", default=[1, 100, 1000, 10000],
                    help="batch sizes N (default: 1 100 1000 10000)")
    ap.add_argument("--steps", type=int, default=2000, help="updates per size (default 2000)")
    args = ap.parse_args()
    benchmark(args.n, args.steps)
