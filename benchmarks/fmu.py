"""FMU benchmark: steps per second of CanTracker.fmu in fmpy and libcosimpy next to the core.

Run from the repository root::

    python benchmarks/fmu.py                    # 60 s at 1 ms (60,000 steps) per variant
    python benchmarks/fmu.py --duration 10      # shorter
    python benchmarks/fmu.py --planner 0        # softmc instead of the default (1, optimal)

Scenario (every variant): a conveyor at 300 mm/s along X (y = 50 mm, 20 deg/s), engaged
from 0.1 s to 1.5 s of every 2 s cycle (30 approach/follow/de-sync cycles in 60 s).  The FMU
variants build the FMUs into a temporary folder first.  Variants:

- core: ``Tracker.update`` with the master extrapolated by T, as the FMU does inside;
- fmpy FMU2Slave: a Python loop of setReal(12) + setBoolean + doStep + getReal(12) +
  getInteger(3) per step (what a Python co-simulation master does), and the same loop with a
  do-nothing pythonfmu FMU of the same interface: the floor set by fmpy and pythonfmu;
- fmpy simulate_fmu (input table): ``simulate_fmu(input=..., output_interval=T)``;
- fmpy simulate_fmu (constant inputs): the FMU with fmpy's recorder only (engaged, master
  at rest), the floor of fmpy's own cost with this FMU;
- fmpy FMU3Slave: the FMI 3.0 FMU in the same loop (if pythonfmu3 is installed);
- libcosimpy: CanConveyor.fmu -> CanTracker.fmu (two FMUs, 10 connections) with a
  last-value observer (if libcosimpy is installed).

Figures are wall-clock and vary with the machine and its load; the target for fmpy is
>= 50,000 steps/s.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:  # run as a script from a checkout, installed or not
    sys.path.insert(0, str(ROOT))

from controller.fmu import build_conveyor_fmu, build_tracker_fmu
from controller.fmu.engine import VARIABLES, tracker_params
from controller.fmu.runner import (MASTER_INPUTS, OUTPUT_INTS, OUTPUT_REALS, FmuTracker,
                                   master_values)
from controller.tracking import MotionState, Tracker

T = 0.001
TARGET_FMPY = 50_000


def scenario(k: int) -> tuple[MotionState, bool]:
    t = k * T
    m = MotionState((100.0 + 300.0 * t, 50.0, 0.0), (300.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                    10.0 + 20.0 * t, 20.0, 0.0)
    return m, 0.1 <= math.fmod(t, 2.0) < 1.5


_NULL_SLAVE = '''
from pythonfmu import Boolean, Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real


class NullTracker(Fmi2Slave):
    """CanTracker's interface (12 real + 1 boolean inputs, 12 real + 3 integer outputs) and
    a do_step that does nothing: the cost of fmpy + pythonfmu alone."""

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        c = Fmi2Causality
        for i in range(12):
            setattr(self, f"u{i}", 0.0)
            self.register_variable(Real(f"u{i}", causality=c.input,
                                        variability=Fmi2Variability.continuous))
        self.engage = False
        self.register_variable(Boolean("engage", causality=c.input,
                                       variability=Fmi2Variability.discrete))
        for i in range(12):
            setattr(self, f"y{i}", 0.0)
            self.register_variable(Real(f"y{i}", causality=c.output,
                                        variability=Fmi2Variability.continuous))
        for i in range(3):
            setattr(self, f"k{i}", 0)
            self.register_variable(Integer(f"k{i}", causality=c.output,
                                           variability=Fmi2Variability.discrete))

    def do_step(self, current_time, step_size):
        return True
'''


def build_null_fmu(folder: Path) -> Path:
    """NullTracker.fmu: CanTracker's interface, a do_step that does nothing (pythonfmu)."""
    from pythonfmu import FmuBuilder

    script = folder / "cantrack_bench_null.py"
    script.write_text(_NULL_SLAVE)
    return Path(FmuBuilder.build_FMU(script, dest=folder / "NullTracker.fmu"))


def bench_null_fmu(fmu: Path, n: int) -> float:
    """The same FMU2Slave loop with a do-nothing FMU of the same interface."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    s = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)),
                  modelIdentifier="NullTracker", instanceName="null")
    s.instantiate()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()
    ivr, ovr = [vr[f"u{i}"] for i in range(12)], [vr[f"y{i}"] for i in range(12)]
    kvr, evr = [vr[f"k{i}"] for i in range(3)], [vr["engage"]]
    rate = _time_steps(n, s.setReal, s.setBoolean, s.doStep, s.getReal, s.getInteger,
                       ivr, evr, ovr, kvr)
    s.terminate()
    s.freeInstance()
    return rate


def _time_steps(n: int, set_reals, set_bools, do_step, get_reals, get_ints,
                in_vrs, engage_vrs, out_vrs, int_vrs) -> float:
    """Steps per second of an importer's loop (fmpy's FMU2Slave/FMU3Slave methods): set the
    12 master inputs and engage, step, read the outputs, as a co-simulation master does."""
    inputs = [(master_values(m), e) for m, e in (scenario(k) for k in range(n))]
    t0 = time.perf_counter()
    for k, (vals, e) in enumerate(inputs):
        set_reals(in_vrs, vals)
        set_bools(engage_vrs, [e])
        do_step(currentCommunicationPoint=k * T, communicationStepSize=T)
        get_reals(out_vrs)
        get_ints(int_vrs)
    return n / (time.perf_counter() - t0)


def bench_core(n: int, planner: int) -> float:
    params = tracker_params({**{r[0]: r[4] for r in VARIABLES if r[2] == "parameter"},
                             "planner": planner})
    masters = [scenario(k) for k in range(n)]
    tracker = Tracker(params, MotionState.at())
    engaged = False
    t0 = time.perf_counter()
    for master, engage in masters:
        if engage != engaged:
            tracker.engage() if engage else tracker.disengage()
            engaged = engage
        tracker.update(master.extrapolated(T))
    return n / (time.perf_counter() - t0)


def bench_fmpy_loop(fmu: Path, n: int, planner: int) -> float:
    """The set/step/get loop of an importer on ``CanTracker.fmu`` (FMU2Slave) or
    ``CanTracker3.fmu`` (FMU3Slave): FmuTracker picks the slave by the FMU's version."""
    with FmuTracker(fmu, "bench", start_values={"planner": planner}, logging_on=False) as f:
        s = f.slave
        return _time_steps(n, f._set_real, s.setBoolean, s.doStep, f._get_real, f._get_int,
                           f._in_vrs, f._engage_vr, f._out_vrs, f._int_vrs)


def bench_simulate_fmu(fmu: Path, n: int, planner: int, table: bool) -> float:
    from fmpy import simulate_fmu

    kwargs = {}
    start = {"planner": planner}
    if table:
        rows = []
        for k in range(n + 1):
            m, e = scenario(k)
            rows.append((k * T, *master_values(m), e))
        kwargs["input"] = np.array(rows, dtype=[("time", float)] + [(c, float) for c in
                                                                    MASTER_INPUTS]
                                   + [("engage", bool)])
    else:
        start.update(engage=True, master_x=100.0)
    t0 = time.perf_counter()
    result = simulate_fmu(str(fmu), start_values=start, stop_time=n * T, output_interval=T,
                          output=OUTPUT_REALS + OUTPUT_INTS, **kwargs)
    elapsed = time.perf_counter() - t0
    assert len(result) == n + 1, len(result)
    return n / elapsed


def bench_libcosim(folder: Path, n: int, planner: int) -> float:
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    from controller.fmu.osp import write_system_structure

    conveyor = {"speed": 300.0, "acc": 1e6, "t_start": 0.0, "t_stop": 1e6,
                "t_engage": 0.1, "t_release": n * T}
    path = write_system_structure(folder, conveyor=conveyor, tracker={"planner": planner})
    log_output_level(CosimLogLevel.WARNING)
    execution = CosimExecution.from_osp_config_file(str(path))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    execution.step()  # initialisation outside the timing
    t0 = time.perf_counter()
    execution.step(n - 1)
    return (n - 1) / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--duration", type=float, default=60.0, help="simulated seconds (60)")
    ap.add_argument("--planner", type=int, choices=(0, 1), default=1)
    ap.add_argument("--rounds", type=int, default=3,
                    help="interleaved rounds of the FMU2Slave loop and the do-nothing FMU's "
                         "for their ratio (3)")
    args = ap.parse_args(argv)
    n = round(args.duration / T)
    rows: list[tuple[str, float | None, str]] = []

    def run(name, fn, *a):
        try:
            rows.append((name, fn(*a), ""))
        except ImportError as exc:
            rows.append((name, None, f"skipped: {exc}"))
        print(f"  {name}: done", file=sys.stderr)

    with tempfile.TemporaryDirectory(prefix="cantrack_bench_") as tmp:
        tmp = Path(tmp)
        fmu = build_tracker_fmu(tmp)
        build_conveyor_fmu(tmp)
        run("core (Tracker.update, extrapolated master)", bench_core, n, args.planner)
        run("fmpy FMU2Slave loop (set/step/get)", bench_fmpy_loop, fmu, n, args.planner)
        null = build_null_fmu(tmp)
        run("  same loop, do-nothing FMU (fmpy+pythonfmu floor)", bench_null_fmu, null, n)
        # the machine is shared: the ratio from rounds that alternate the two loops
        pairs = [(bench_fmpy_loop(fmu, n, args.planner), bench_null_fmu(null, n))
                 for _ in range(args.rounds)]
        print("  interleaved rounds: done", file=sys.stderr)
        run("fmpy simulate_fmu, input table", bench_simulate_fmu, fmu, n, args.planner, True)
        run("fmpy simulate_fmu, constant inputs", bench_simulate_fmu, fmu, n, args.planner,
            False)
        try:
            from controller.fmu import build_tracker_fmu3
            fmu3 = build_tracker_fmu3(tmp)
            run("fmpy FMU3Slave loop (FMI 3.0)", bench_fmpy_loop, fmu3, n, args.planner)
        except Exception as exc:  # noqa: BLE001 - pythonfmu3 missing
            rows.append(("fmpy FMU3Slave loop (FMI 3.0)", None, f"skipped: {exc}"))
        run("libcosimpy conveyor -> tracker (2 FMUs)", bench_libcosim, tmp, n, args.planner)

    print(f"\nCanTracker.fmu, {args.duration:g} s at {T * 1e3:g} ms ({n} steps), planner "
          f"{args.planner}")
    width = max(len(r[0]) for r in rows)
    core = rows[0][1]
    for name, rate, note in rows:
        if rate is None:
            print(f"  {name:<{width}}  {note}")
            continue
        rel = f"  {rate / core * 100:5.1f} % of the core" if core and rate != core else ""
        real_time = rate * T
        print(f"  {name:<{width}}  {rate:>10,.0f} steps/s  ({real_time:6.1f} x real time){rel}")
    ratios = sorted(a / b for a, b in pairs)
    print(f"\nFMU2Slave loop / do-nothing FMU loop, {args.rounds} interleaved rounds: median "
          f"{ratios[len(ratios) // 2]:.3f} (" + ", ".join(
              f"{a:,.0f}/{b:,.0f}" for a, b in pairs) + " steps/s); target >= 0.95")
    fmpy_loop = rows[1][1]
    if fmpy_loop is not None:
        print(f"\ntarget >= {TARGET_FMPY:,} steps/s in fmpy: FMU2Slave loop "
              f"{'meets' if fmpy_loop >= TARGET_FMPY else 'misses'} it ({fmpy_loop:,.0f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
