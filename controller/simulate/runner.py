"""Run a scenario through the tracking core: a thin shell around :class:`Tracker`.

The loop is exactly what a controller does, without the clock: for each sample k = 1..N,
give the commands due at sample k - 1 (``engage()`` / ``disengage()``), then
``update(master_k)``.  Nothing is added to or taken from the core's setpoints, so calling the
core directly with the same inputs gives bit-identical results (tested).

Metrics (:func:`controller.tracking.metrics.analyze`) are computed per engage cycle on rows
k_e .. k_next (k_e the engage sample, the last one before the engage; k_next the next engage
sample or N), against the *true* master (not the estimator's output), shifted by the offset of
the relative mode (mode 5: robot(k_e) - master(k_e + 1) extrapolated back one sample, as the
core computes it).  Translation phases approach/switch/after are compared with the effective
sync limits and the desync phase with the effective de-sync limits (two ``analyze`` calls,
the desync figures taken from the second); the rotation channel likewise with its limits.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..limits import Limits
from ..tracking import Mode, MotionState, Tracker, TrackError, TrackerParams, TrackState
from ..tracking.metrics import TraceMetrics, analyze
from ..tracking.types import EffectiveLimits
from .master import master_states
from .scenario import Scenario, load_scenario

__all__ = ["CycleResult", "SimulationResult", "run_scenario", "simulate"]


@dataclass
class CycleResult:
    """One engage cycle.  Times in s; ``trans`` in mm, ``rot`` in deg."""

    index: int
    engage_s: float
    disengage_s: float | None
    #: rows [first_row, last_row] of the trace analysed (first_row = engage sample)
    first_row: int
    last_row: int
    mode: Mode
    trans: TraceMetrics
    rot: TraceMetrics
    #: relative-mode offset robot - master at engage [mm] / [deg] (0 in absolute mode)
    offset_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    offset_ang: float = 0.0
    #: the tracker's own switch into SYNCED, seconds after the engage (None: never)
    synced_after_s: float | None = None
    #: errors reported in this cycle: (time [s], error) at the first sample of each
    errors: list[tuple[float, TrackError]] = field(default_factory=list)

    @property
    def time_to_sync_s(self) -> float | None:
        """analyze()'s time to sync of both channels, relative to the engage (None: never)."""
        if not (self.trans.synced and self.rot.synced):
            return None
        return max(self.trans.time_to_sync_s, self.rot.time_to_sync_s) - self.engage_s


@dataclass
class SimulationResult:
    """Arrays of a run (N + 1 rows; row 0 = the state before the first update) and metrics.

    Units: mm, mm/s, mm/s^2 (``*_pos``, ``*_vel``, ``*_acc``: shape (N+1, 3)); deg, deg/s,
    deg/s^2 (``*_ang``, ``*_ang_vel``, ``*_ang_acc``: shape (N+1,)); s.
    ``master_*`` is the true master, ``input_*`` what the tracker was given (the same unless
    the scenario has an ``estimator``), ``reference_*`` the master plus the relative-mode
    offset of the current cycle (what the setpoint should follow).
    """

    scenario: Scenario
    params: TrackerParams
    limits: EffectiveLimits
    time_s: np.ndarray
    master_pos: np.ndarray
    master_vel: np.ndarray
    master_acc: np.ndarray
    master_ang: np.ndarray
    master_ang_vel: np.ndarray
    master_ang_acc: np.ndarray
    input_pos: np.ndarray
    input_vel: np.ndarray
    input_ang: np.ndarray
    input_ang_vel: np.ndarray
    reference_pos: np.ndarray
    reference_ang: np.ndarray
    setpoint_pos: np.ndarray
    setpoint_vel: np.ndarray
    setpoint_acc: np.ndarray
    setpoint_ang: np.ndarray
    setpoint_ang_vel: np.ndarray
    setpoint_ang_acc: np.ndarray
    state: np.ndarray
    imfs: np.ndarray
    error: np.ndarray
    cycles: list[CycleResult]
    #: the exact MotionState objects passed to ``Tracker.update`` (index k-1 for sample k)
    master_inputs: list[MotionState] = field(repr=False, default_factory=list)

    @property
    def sample_time_s(self) -> float:
        return self.params.sample_time_s

    @property
    def has_estimator(self) -> bool:
        return self.scenario.estimator is not None or self.scenario.conditioning is not None

    @property
    def final_state(self) -> TrackState:
        return TrackState(int(self.state[-1]))

    @property
    def final_error(self) -> TrackError:
        return TrackError(int(self.error[-1]))

    @property
    def metrics(self) -> TraceMetrics:
        """Translation metrics of the first cycle (convenience)."""
        return self.cycles[0].trans


def _arrays(states: list[MotionState]) -> dict[str, np.ndarray]:
    return {"pos": np.array([s.pos for s in states], dtype=float).reshape(-1, 3),
            "vel": np.array([s.vel for s in states], dtype=float).reshape(-1, 3),
            "acc": np.array([s.acc for s in states], dtype=float).reshape(-1, 3),
            "ang": np.array([s.ang for s in states], dtype=float),
            "ang_vel": np.array([s.ang_vel for s in states], dtype=float),
            "ang_acc": np.array([s.ang_acc for s in states], dtype=float)}


def _analyze(sp: np.ndarray, ref: np.ndarray, st: np.ndarray, T: float, sync: Limits,
             desync: Limits, t0: float) -> TraceMetrics:
    """analyze() against the sync limits, with the desync phase against the de-sync limits."""
    m = analyze(sp, ref, st, T, sync, t0_s=t0)
    if desync != sync:
        d = analyze(sp, ref, st, T, desync, t0_s=t0)
        m.ratio["desync"] = d.ratio["desync"]
        for tol in m.violations:
            m.violations[tol]["desync"] = d.violations[tol]["desync"]
    return m


def simulate(scenario: Scenario) -> SimulationResult:
    """Run a validated scenario."""
    params = scenario.params
    T = params.sample_time_s
    n = scenario.n_samples
    true, fed = master_states(scenario)
    tracker = Tracker(params, scenario.robot)
    engage = set(scenario.engage_samples)
    disengage = set(scenario.disengage_samples)

    setpoints = [tracker.setpoint]
    states = [int(tracker.state)]
    imfs = [int(tracker.imfs)]
    errors = [int(tracker.error)]
    synced_at: list[int] = []
    inputs = fed[1:]
    for k in range(1, n + 1):
        if k - 1 in engage:
            tracker.engage()
        elif k - 1 in disengage:
            tracker.disengage()
        out = tracker.update(inputs[k - 1])
        setpoints.append(out.setpoint)
        states.append(int(out.state))
        imfs.append(int(out.imfs))
        errors.append(int(out.error))
        if out.synchronized_now:
            synced_at.append(k)

    m = _arrays(true)
    f = _arrays(fed) if fed is not true else m
    s = _arrays(setpoints)
    state = np.array(states, dtype=int)
    error = np.array(errors, dtype=int)
    ref_pos = m["pos"].copy()
    ref_ang = m["ang"].copy()
    limits = params.effective()

    cycles: list[CycleResult] = []
    starts = list(scenario.engage_samples)
    for i, ke in enumerate(starts):
        last = starts[i + 1] if i + 1 < len(starts) else n
        mode = params.mode
        off_p, off_a = (0.0, 0.0, 0.0), 0.0
        if mode == Mode.RELATIVE:
            back = fed[ke + 1].extrapolated(-T)
            sp = setpoints[ke]
            off_p = tuple(a - b for a, b in zip(sp.pos, back.pos))
            off_a = sp.ang - back.ang
            ref_pos[ke + 1:last + 1] += np.array(off_p)
            ref_ang[ke + 1:last + 1] += off_a
        rows = slice(ke, last + 1)
        t0 = ke * T
        # row 0 of the analysis is the sample before the engage: compare it with the
        # reference the approach starts from
        sp_rows = s["pos"][rows]
        ref_rows = ref_pos[rows].copy()
        ref_rows[0] = m["pos"][ke] + np.array(off_p)
        ang_ref_rows = ref_ang[rows].copy()
        ang_ref_rows[0] = m["ang"][ke] + off_a
        trans = _analyze(sp_rows, ref_rows, state[rows], T, limits.sync_trans,
                         limits.desync_trans, t0)
        rot = _analyze(s["ang"][rows], ang_ref_rows, state[rows], T, limits.sync_rot,
                       limits.desync_rot, t0)
        sync_k = next((k for k in synced_at if ke < k <= last), None)
        errs = []
        seg = error[ke + 1:last + 1]
        prev = TrackError.NONE
        for j, e in enumerate(seg):
            if e != prev and e != TrackError.NONE:
                errs.append(((ke + 1 + j) * T, TrackError(int(e))))
            prev = e
        dis = [t for t, kd in zip(scenario.disengage, scenario.disengage_samples)
               if ke < kd <= last]
        cycles.append(CycleResult(
            i, t0, dis[0] if dis else None, ke, last, mode, trans, rot, off_p, off_a,
            (sync_k - ke) * T if sync_k is not None else None, errs))

    return SimulationResult(
        scenario=scenario, params=params, limits=limits,
        time_s=np.arange(n + 1) * T,
        master_pos=m["pos"], master_vel=m["vel"], master_acc=m["acc"], master_ang=m["ang"],
        master_ang_vel=m["ang_vel"], master_ang_acc=m["ang_acc"],
        input_pos=f["pos"], input_vel=f["vel"], input_ang=f["ang"],
        input_ang_vel=f["ang_vel"],
        reference_pos=ref_pos, reference_ang=ref_ang,
        setpoint_pos=s["pos"], setpoint_vel=s["vel"], setpoint_acc=s["acc"],
        setpoint_ang=s["ang"], setpoint_ang_vel=s["ang_vel"], setpoint_ang_acc=s["ang_acc"],
        state=state, imfs=np.array(imfs, dtype=int), error=error, cycles=cycles,
        master_inputs=inputs)


def run_scenario(source, *, base_dir: str | Path | None = None):
    """Load (a path to a YAML file, or a mapping with the same keys) and run a scenario.

    Returns a :class:`SimulationResult`, or for a conveyor scenario (top-level ``conveyor``
    key) a :class:`controller.simulate.conveyor.ConveyorResult`, for a cell scenario (``cell``)
    a :class:`controller.simulate.cell.CellResult`.
    Raises :class:`controller.errors.ConfigError` for an invalid scenario.
    """
    from .cell import CellScenario, run_cell
    from .conveyor import ConveyorScenario, run_conveyor

    if isinstance(source, (Scenario, ConveyorScenario, CellScenario)):
        scenario = source
    else:
        scenario = load_scenario(source, base_dir=base_dir)
    if isinstance(scenario, ConveyorScenario):
        return run_conveyor(scenario)
    if isinstance(scenario, CellScenario):
        return run_cell(scenario)
    return simulate(scenario)
