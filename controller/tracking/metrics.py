"""Quality figures of a tracking run, computed from the setpoint stream as a drive sees it.

Used by ``cantrack simulate`` (summary) and ``benchmarks/tracking.py`` (suite tables).

Everything is derived by finite differences of the sampled positions (period T):
v_k = (p_k - p_{k-1})/T, a_k = (v_k - v_{k-1})/T, j_k = (a_k - a_{k-1})/T, vector norms for
the 3-D translation.  The master's velocity is differenced the same way.

- time to sync: the first sample time after which |p - m| <= ``pos_tol_mm`` (0.05 mm) and
  |v - v_m| <= ``vel_tol`` (2 mm/s) hold for good (until the end of the trace or the start of
  the de-sync).
- phases: ``approach`` (state SYNCING), ``switch`` (the finite-difference stencils that touch
  the sample where SYNCED begins: 3 samples either side), ``after`` (SYNCED, outside the
  switch), ``desync`` (DESYNCING).
- violations: samples whose norm exceeds the limit by more than a relative tolerance
  (1e-6 and 1 %), counted per phase and per quantity.
- oscillation: sign flips of the velocity error (dot product of consecutive errors) while
  |dv| > ``vel_tol`` during the approach; a run with more than ``max_flips`` is oscillating.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..limits import Limits
from .types import TrackState
from .values import mypyc_attr

PHASES = ("approach", "switch", "after", "desync")
QUANTITIES = ("vel", "acc", "jerk")
POS_TOL_MM = 0.05
VEL_TOL = 2.0


@dataclass
@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class TraceMetrics:
    """Figures of one run.  Norms in mm/s, mm/s^2, mm/s^3; times in s."""

    time_to_sync_s: float | None
    synced: bool
    #: peak[phase][quantity] = largest finite-difference norm in that phase (0 if empty)
    peak: dict[str, dict[str, float]] = field(default_factory=dict)
    #: ratio[phase][quantity] = peak / limit
    ratio: dict[str, dict[str, float]] = field(default_factory=dict)
    #: violations[tol][phase] = number of samples over limit*(1+tol) (any quantity)
    violations: dict[float, dict[str, int]] = field(default_factory=dict)
    #: largest |setpoint - master| [mm] in the ``after`` phase (None if never synced)
    error_after_sync_mm: float | None = None
    oscillation_flips: int = 0
    oscillating: bool = False


def _fd(x: np.ndarray, T: float) -> np.ndarray:
    """Backward difference along axis 0 divided by T; first row repeats (no information)."""
    d = np.empty_like(x)
    d[1:] = (x[1:] - x[:-1]) / T
    d[0] = d[1] if len(x) > 1 else 0.0
    return d


def analyze(setpoint_mm: np.ndarray, master_mm: np.ndarray, states: np.ndarray,
            sample_time_s: float, limits: Limits, *, pos_tol_mm: float = POS_TOL_MM,
            vel_tol: float = VEL_TOL, tolerances: tuple[float, ...] = (1e-6, 0.01),
            max_flips: int = 2, t0_s: float = 0.0) -> TraceMetrics:
    """Figures of one run.

    ``setpoint_mm`` and ``master_mm``: (N, D) positions per sample (D = 1 or 3);
    ``states``: (N,) :class:`TrackState` values per sample.  Row 0 is the last sample before
    the engage (time ``t0_s``); row i is at t0_s + i*T.  Time to sync is an absolute time on
    that axis (subtract t0_s for a duration).
    """
    T = float(sample_time_s)
    sp = np.asarray(setpoint_mm, dtype=float)
    ms = np.asarray(master_mm, dtype=float)
    if sp.ndim == 1:
        sp = sp[:, None]
        ms = ms[:, None]
    st = np.asarray(states, dtype=int)
    n = len(sp)
    v = _fd(sp, T)
    a = _fd(v, T)
    j = _fd(a, T)
    vm = _fd(ms, T)
    # the first 1/2/3 rows of v/a/j carry no information (they need earlier samples)
    norms = {"vel": np.linalg.norm(v, axis=1), "acc": np.linalg.norm(a, axis=1),
             "jerk": np.linalg.norm(j, axis=1)}
    for q, skip in (("vel", 1), ("acc", 2), ("jerk", 3)):
        norms[q][:min(skip, n)] = 0.0
    lim = {"vel": limits.vel, "acc": limits.acc, "jerk": limits.jerk}

    phase = np.full(n, "", dtype=object)
    phase[st == TrackState.SYNCING] = "approach"
    phase[st == TrackState.SYNCED] = "after"
    phase[st == TrackState.DESYNCING] = "desync"
    switch_idx = np.nonzero((st[1:] == TrackState.SYNCED) & (st[:-1] != TrackState.SYNCED))[0] + 1
    for s in switch_idx:
        phase[max(0, s - 3):min(n, s + 4)] = "switch"

    peak: dict[str, dict[str, float]] = {}
    ratio: dict[str, dict[str, float]] = {}
    violations: dict[float, dict[str, int]] = {tol: {} for tol in tolerances}
    for ph in PHASES:
        mask = phase == ph
        peak[ph] = {}
        ratio[ph] = {}
        over = {tol: np.zeros(n, dtype=bool) for tol in tolerances}
        for q in QUANTITIES:
            vals = norms[q][mask]
            pk = float(vals.max()) if vals.size else 0.0
            peak[ph][q] = pk
            ratio[ph][q] = pk / lim[q]
            for tol in tolerances:
                over[tol] |= mask & (norms[q] > lim[q] * (1.0 + tol))
        for tol in tolerances:
            violations[tol][ph] = int(over[tol].sum())

    # time to sync: first index after which the errors stay within tolerance, for good
    ep = np.linalg.norm(sp - ms, axis=1)
    ev = np.linalg.norm(v - vm, axis=1)
    ok = (ep <= pos_tol_mm) & (ev <= vel_tol)
    ok[0] = ok[0] and n == 1
    end = n
    desync_idx = np.nonzero(st == TrackState.DESYNCING)[0]
    if desync_idx.size:
        end = int(desync_idx[0])
    tts = None
    synced = False
    if end > 0 and ok[end - 1]:
        bad = np.nonzero(~ok[:end])[0]
        first = int(bad[-1]) + 1 if bad.size else 0
        tts = t0_s + first * T
        synced = True

    after = phase == "after"
    err_after = float(ep[after].max()) if after.any() else None

    # oscillation: sign flips of the velocity error during the approach
    appr = np.nonzero(st == TrackState.SYNCING)[0]
    flips = 0
    if appr.size > 2:
        dv = (v - vm)[appr]
        big = np.linalg.norm(dv, axis=1) > vel_tol
        dots = np.einsum("ij,ij->i", dv[1:], dv[:-1])
        flips = int(np.count_nonzero((dots < 0) & big[1:] & big[:-1]))
    return TraceMetrics(tts, synced, peak, ratio, violations, err_after, flips, flips > max_flips)
