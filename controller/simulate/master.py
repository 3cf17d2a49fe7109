"""The master (moving frame) of a scenario, sampled at the tracker's sample times.

Two sources (see :mod:`controller.simulate.scenario` for the keys):

- segments: the path coordinate s(t) along a unit direction d is a chain of constant-jerk
  pieces, evaluated in closed form on each sample time (no integration, so no drift):
  s = v0*tau + a0*tau^2/2 + j*tau^3/6, v = v0 + a0*tau + j*tau^2/2, a = a0 + j*tau, with tau
  the time since the piece began; position = p0 + d*s.  A speed change is the exact S-curve
  (:func:`speed_change_phases`); the rotation channel c moves at a constant rate per segment.
- CSV: positions linearly interpolated at the sample times; velocities/accelerations from
  the file's columns or estimated with :class:`controller.tracking.MasterEstimator`
  (quadratic least-squares fit, lead 0: the estimate at the newest sample).

The optional encoder path (``estimator:``) turns the true master into what the controller
would see: positions quantised to a step, ``delay_samples`` late, then a MasterEstimator
predicting ``lead_samples`` ahead.  Its history before t = 0 comes from the master's own
pre-history (it moves at its initial speed / a CSV master holds its first row), so the
estimator starts full.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..tracking import MasterEstimator, MotionState

if TYPE_CHECKING:
    from ..cell.reading import CsvMaster, SegmentMaster
    from .scenario import Scenario

__all__ = ["SegmentError", "SegmentProfile", "build_profile", "speed_change_phases",
           "master_states"]


class SegmentError(Exception):
    """A segment that cannot be built (located by the scenario loader)."""

    def __init__(self, index: int, key: str, message: str) -> None:
        super().__init__(message)
        self.index = index
        self.key = key
        self.message = message


def speed_change_phases(v0: float, v1: float, acc: float, jerk: float
                        ) -> list[tuple[float, float]]:
    """The jerk-limited speed change v0 -> v1 [mm/s] as (duration [s], jerk [mm/s^3]) phases.

    Starts and ends at acceleration 0.  With dv = |v1 - v0|: if dv >= acc^2/jerk the profile
    is jerk up for acc/jerk, constant acceleration for dv/acc - acc/jerk, jerk down for
    acc/jerk; otherwise the peak acceleration sqrt(dv*jerk) is reached in sqrt(dv/jerk) and
    the middle phase vanishes.  Total time dv/acc + acc/jerk (resp. 2*sqrt(dv/jerk)).
    """
    dv = abs(v1 - v0)
    if dv == 0.0:
        return []
    sign = 1.0 if v1 > v0 else -1.0
    tj = acc / jerk
    if dv >= acc * tj:
        return [(tj, sign * jerk), (dv / acc - tj, 0.0), (tj, -sign * jerk)]
    tj = math.sqrt(dv / jerk)
    return [(tj, sign * jerk), (tj, -sign * jerk)]


@dataclass(frozen=True, slots=True)
class _Piece:
    """Constant jerk along a direction from time t0 [s] for ``duration`` [s]."""

    t0: float
    duration: float
    p0: tuple[float, float, float]
    d: tuple[float, float, float]
    v0: float
    a0: float
    j: float
    c0: float
    c_rate: float

    def state(self, t: float) -> MotionState:
        tau = t - self.t0
        s = self.v0 * tau + 0.5 * self.a0 * tau * tau + self.j * tau * tau * tau / 6.0
        v = self.v0 + self.a0 * tau + 0.5 * self.j * tau * tau
        a = self.a0 + self.j * tau
        p0, d = self.p0, self.d
        return MotionState((p0[0] + d[0] * s, p0[1] + d[1] * s, p0[2] + d[2] * s),
                           (d[0] * v, d[1] * v, d[2] * v), (d[0] * a, d[1] * a, d[2] * a),
                           self.c0 + self.c_rate * tau, self.c_rate, 0.0)

    def end(self) -> tuple[tuple[float, float, float], float, float, float]:
        """Position, speed, acceleration and angle at the end of the piece."""
        st = self.state(self.t0 + self.duration)
        tau = self.duration
        v = self.v0 + self.a0 * tau + 0.5 * self.j * tau * tau
        a = self.a0 + self.j * tau
        return st.pos, v, a, st.ang


class SegmentProfile:
    """The master of a segment list as constant-jerk pieces; ``state(t)`` for any t [s]."""

    def __init__(self, pieces: list[_Piece], end_s: float, start: _Piece) -> None:
        self.pieces = pieces
        self.end_s = end_s  #: end of the last segment [s]
        self._starts = [p.t0 for p in pieces]
        self._before = start  #: t < 0: the initial speed, no acceleration

    def state(self, t: float) -> MotionState:
        if t < 0.0:
            return self._before.state(t)
        return self.pieces[bisect_right(self._starts, t) - 1].state(t)


def build_profile(master: "SegmentMaster") -> SegmentProfile:
    """The pieces of a segment master.  Raises :class:`SegmentError` for a speed change
    that does not fit in its segment's duration."""
    t = 0.0
    p = master.position
    speed = master.initial_speed
    c = master.c
    c_rate = master.c_rate
    pieces: list[_Piece] = []
    start = _Piece(0.0, math.inf, p, master.initial_direction, speed, 0.0, 0.0, c, c_rate)
    for i, seg in enumerate(master.segments):
        d = seg.direction
        if seg.c_rate is not None:
            c_rate = seg.c_rate
        if seg.kind == "speed_change":
            phases = speed_change_phases(speed, seg.to, seg.acc, seg.jerk)
            need = sum(dur for dur, _ in phases)
            total = need if seg.duration_s is None else seg.duration_s
            if total < need * (1.0 - 1e-12):
                raise SegmentError(
                    i, "duration_s",
                    f"value {total!r} s is too short for the speed change from {speed:g} to "
                    f"{seg.to:g} mm/s (acc {seg.acc:g}, jerk {seg.jerk:g}): it needs "
                    f"{need:.6g} s; omit duration_s or make it >= {need:.6g}")
            plan = [(dur, speed if k == 0 else None, 0.0 if k == 0 else None, jerk)
                    for k, (dur, jerk) in enumerate(phases)]
            plan.append((total - need, seg.to, 0.0, 0.0))
        elif seg.kind == "velocity":
            plan = [(seg.duration_s, seg.value, 0.0, 0.0)]
        elif seg.kind == "acceleration":
            plan = [(seg.duration_s, speed, seg.value, 0.0)]
        else:  # hold
            plan = [(seg.duration_s, speed, 0.0, 0.0)]
        acc = 0.0
        for dur, v0, a0, jerk in plan:
            v0 = speed if v0 is None else v0
            a0 = acc if a0 is None else a0
            if dur <= 0.0:
                speed, acc = v0, a0
                continue
            piece = _Piece(t, dur, p, d, v0, a0, jerk, c, c_rate)
            pieces.append(piece)
            p, speed, acc, c = piece.end()
            t += dur
        if seg.kind == "speed_change":
            speed = seg.to  # exact, not the sum of rounded phases
    d_last = master.segments[-1].direction
    pieces.append(_Piece(t, math.inf, p, d_last, speed, 0.0, 0.0, c, c_rate))
    return SegmentProfile(pieces, t, start)


# -- CSV master ----------------------------------------------------------------------------
def _csv_states(master: "CsvMaster", T: float, kmin: int, n: int) -> list[MotionState]:
    """States at samples kmin..n: positions (and given velocity/acceleration columns)
    linearly interpolated, the rest estimated; before the file's first row its first values
    are held."""
    times = np.asarray(master.time_s)
    ts = np.arange(kmin, n + 1) * T

    def interp(rows, rows_c) -> np.ndarray | None:
        if rows is None:
            return None
        a = np.column_stack([np.asarray(rows), np.asarray(rows_c)])
        return np.column_stack([np.interp(ts, times, a[:, i]) for i in range(4)])

    p = interp(master.pos, master.ang)
    v = interp(master.vel, master.ang_vel)
    a = interp(master.acc, master.ang_acc)
    if v is None or a is None:
        est = [MasterEstimator(T, master.window, lead_samples=0.0) for _ in range(4)]
        ev = np.empty_like(p)
        ea = np.empty_like(p)
        for k in range(len(ts)):
            for i, e in enumerate(est):
                e.push(p[k, i])
                r = e.estimate()
                ev[k, i] = r.vel
                ea[k, i] = r.acc
        v = ev if v is None else v
        a = ea if a is None else a
    p, v, a = p.tolist(), v.tolist(), a.tolist()
    return [MotionState(tuple(p[k][:3]), tuple(v[k][:3]), tuple(a[k][:3]), p[k][3], v[k][3],
                        a[k][3]) for k in range(len(ts))]


# -- the master the tracker sees ------------------------------------------------------------
def _conditioned_states(scenario: "Scenario") -> tuple[list[MotionState], list[MotionState]]:
    """(true, fed) with a ``conditioning`` section: per axis (x, y, z with the frame's
    translation limits, c with its rotation limits) the encoder's quantised, late, jittered
    samples through a :class:`MasterConditioner`, warmed up on the master's pre-history so
    that it is valid at t = 0."""
    from ..tracking.conditioning import ConditioningParams, EncoderModel, MasterConditioner
    from ..cell.reading import CsvMaster

    spec = scenario.conditioning
    assert spec is not None
    params = scenario.params
    T = params.sample_time_s
    n = scenario.n_samples

    def cparams(res: float, frame) -> ConditioningParams:
        return ConditioningParams(T, EncoderModel(res, spec.latency_samples), frame,
                                  lead_samples=0.0, design=spec.design,
                                  jerk_reserve=spec.jerk_reserve, outlier_mm=spec.outlier_mm,
                                  max_outliers=spec.max_outliers)

    ps = [cparams(spec.resolution_mm, params.master_max_trans)] * 3 + [
        cparams(spec.resolution_deg, params.master_max_rot)]
    warm = max(p.warmup for p in ps) + spec.latency_samples + 2
    conds = [MasterConditioner(p) for p in ps]
    L = spec.latency_samples
    rng = np.random.default_rng(spec.seed)
    delta = rng.uniform(-spec.jitter, spec.jitter, n + 1 + warm) * T
    if isinstance(scenario.master, CsvMaster):
        allst = _csv_states(scenario.master, T, -warm - L, n)
        at = [(s.pos[0], s.pos[1], s.pos[2], s.ang) for s in allst]

        def sample(i: int) -> tuple[float, ...]:
            return at[i]  # cycle i - warm samples at (i - warm - L) T
        true = allst[warm + L:]
    else:
        profile = build_profile(scenario.master)

        def sample(i: int) -> tuple[float, ...]:
            s = profile.state((i - warm - L) * T + delta[i])
            return s.pos[0], s.pos[1], s.pos[2], s.ang
        true = [profile.state(k * T) for k in range(n + 1)]
    qs = [p.encoder.resolution_mm for p in ps]
    fed = []
    for i in range(warm + n + 1):
        x = sample(i)
        outs = [c.update(_quantise(v, q), float(delta[i]) if not isinstance(
            scenario.master, CsvMaster) else 0.0) for c, v, q in zip(conds, x, qs)]
        if i >= warm:
            ox, oy, oz, oc = outs
            fed.append(MotionState((ox.pos, oy.pos, oz.pos), (ox.vel, oy.vel, oz.vel),
                                   (ox.acc, oy.acc, oz.acc), oc.pos, oc.vel, oc.acc,
                                   (ox.jerk, oy.jerk, oz.jerk), oc.jerk))
    return true, fed


def _quantise(x: float, step: float) -> float:
    return math.floor(x / step + 0.5) * step if step > 0.0 else x


def master_states(scenario: "Scenario") -> tuple[list[MotionState], list[MotionState]]:
    """(true, fed): the master at samples k = 0..N, and what the tracker is given.

    Without an ``estimator`` section both lists are the same objects.
    """
    from ..cell.reading import CsvMaster

    T = scenario.params.sample_time_s
    n = scenario.n_samples
    if scenario.conditioning is not None:
        return _conditioned_states(scenario)
    enc = scenario.estimator
    kmin = -(enc.delay_samples + enc.window) if enc is not None else 0
    if isinstance(scenario.master, CsvMaster):
        allst = _csv_states(scenario.master, T, kmin, n)
    else:
        profile = build_profile(scenario.master)
        allst = [profile.state(k * T) for k in range(kmin, n + 1)]
    true = allst[-kmin:]
    if enc is None:
        return true, true

    ests = [MasterEstimator(T, enc.window, lead_samples=enc.lead_samples, degree=enc.degree)
            for _ in range(4)]
    qs = (enc.quantisation_mm,) * 3 + (enc.quantisation_deg,)

    def push(k: int) -> None:  # the encoder sample of time k*T
        m = allst[k - kmin]
        for e, x, q in zip(ests, (m.pos[0], m.pos[1], m.pos[2], m.ang), qs):
            e.push(_quantise(x, q))

    for j in range(kmin, -enc.delay_samples):
        push(j)
    fed = []
    for k in range(0, n + 1):
        push(k - enc.delay_samples)
        ex, ey, ez, ec = (e.estimate() for e in ests)
        fed.append(MotionState((ex.pos, ey.pos, ez.pos), (ex.vel, ey.vel, ez.vel),
                               (ex.acc, ey.acc, ez.acc), ec.pos, ec.vel, ec.acc))
    return true, fed
