"""FMI cross-check files for CanTracker: ``_in.csv``, ``_ref.csv``, ``_ref.opt``.

Conventions of the FMI cross-check repository: CSV with quoted column names, ``time`` first,
booleans as 0/1; ``_ref.opt`` holds StartTime, StopTime, StepSize and RelTol.  The FMU runs
with its default parameters.

Scenario: the smoke scenario of ``cantrack fmu check`` (conveyor at 300 mm/s along X with
y = 50 mm, angle 10 deg + 20 deg/s; ``engage`` true from 0.1 s to 1.0 s), 1.5 s at 1 ms.
Input row k is the master state at t_k = k*T (an importer sets it at the start of the step
[t_k, t_k+1]); reference row k is the tracker's output at t_k, computed with the core
(``controller.tracking.Tracker``), row 0 being the initial outputs.  Floats are written with
``repr`` (exact round trip), so an importer that applies the input rows at the step starts
reproduces the reference bit for bit; RelTol is for importers that interpolate differently.
"""

from __future__ import annotations

import csv
from pathlib import Path

from .runner import (
    MASTER_INPUTS,
    OUTPUT_INTS,
    OUTPUT_REALS,
    conveyor_scenario,
    core_run,
    master_values,
)

MODEL = "CanTracker"
START_TIME_S = 0.0
STOP_TIME_S = 1.5
STEP_SIZE_S = 0.001
REL_TOL = 1e-6


def _default_params():
    from .engine import VARIABLES, tracker_params

    return tracker_params({row[0]: row[4] for row in VARIABLES if row[2] == "parameter"})


def crosscheck_tables() -> tuple[list[list], list[list]]:
    """(input rows, reference rows), each row starting with the time [s]."""
    params = _default_params()
    T = STEP_SIZE_S
    n = round((STOP_TIME_S - START_TIME_S) / T)
    scenario = conveyor_scenario(T)
    inputs = []
    for k in range(n + 1):
        m, engage = scenario(k)
        inputs.append([k * T, *master_values(m), int(engage)])
    run = core_run(params, scenario, n)
    refs = [[0.0] + [0.0] * len(OUTPUT_REALS) + [0] * len(OUTPUT_INTS)]
    for k in range(n):
        refs.append([(k + 1) * T, *run.reals[k], *run.ints[k]])
    return inputs, refs


def _fmt(value) -> str:
    return repr(float(value)) if isinstance(value, float) else str(value)


def _write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as f:
        f.write(",".join(f'"{h}"' for h in header) + "\n")
        for row in rows:
            f.write(",".join(_fmt(v) for v in row) + "\n")


def write_crosscheck(dest_dir: str | Path) -> list[Path]:
    """Write the three files into ``dest_dir``; returns [in.csv, ref.csv, ref.opt]."""
    dest = Path(dest_dir)
    dest.mkdir(parents=True, exist_ok=True)
    inputs, refs = crosscheck_tables()
    p_in, p_ref, p_opt = (dest / f"{MODEL}_in.csv", dest / f"{MODEL}_ref.csv",
                          dest / f"{MODEL}_ref.opt")
    _write_csv(p_in, ["time", *MASTER_INPUTS, "engage"], inputs)
    _write_csv(p_ref, ["time", *OUTPUT_REALS, *OUTPUT_INTS], refs)
    p_opt.write_text(f"StartTime, {START_TIME_S!r}\nStopTime, {STOP_TIME_S!r}\n"
                     f"StepSize, {STEP_SIZE_S!r}\nRelTol, {REL_TOL!r}\n", encoding="utf-8")
    return [p_in, p_ref, p_opt]


def read_csv(path: str | Path) -> tuple[list[str], list[list[float]]]:
    """(header, rows as floats) of a cross-check CSV."""
    with open(path, newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        header = next(reader)
        return header, [[float(v) for v in row] for row in reader]


def read_opt(path: str | Path) -> dict[str, float]:
    opts = {}
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        if line.strip():
            key, value = line.split(",", 1)
            opts[key.strip()] = float(value)
    return opts


def compare_fmu(fmu_path: str | Path, folder: str | Path, exact: bool = True) -> list[str]:
    """Simulate ``fmu_path`` in fmpy with ``folder``'s ``_in.csv`` / ``_ref.opt`` and compare
    with ``_ref.csv``: bit-identical (``exact``) or within RelTol; returns the problems."""
    import numpy as np
    from fmpy import simulate_fmu
    from fmpy.util import read_csv as fmpy_read_csv

    folder = Path(folder)
    opts = read_opt(folder / f"{MODEL}_ref.opt")
    signals = fmpy_read_csv(str(folder / f"{MODEL}_in.csv"))
    header, ref = read_csv(folder / f"{MODEL}_ref.csv")
    result = simulate_fmu(str(fmu_path), start_time=opts["StartTime"],
                          stop_time=opts["StopTime"], output_interval=opts["StepSize"],
                          input=signals, output=header[1:])
    problems = []
    if len(result) != len(ref):
        return [f"{len(result)} result rows, {len(ref)} reference rows"]
    tol = opts.get("RelTol", 0.0)
    for j, name in enumerate(header):
        got = np.asarray(result[name], dtype=float)
        want = np.asarray([row[j] for row in ref])
        if exact:
            bad = np.nonzero(got != want)[0]
        else:
            scale = np.maximum(np.abs(want), 1.0)
            bad = np.nonzero(np.abs(got - want) > tol * scale)[0]
        if len(bad):
            k = int(bad[0])
            problems.append(f"{name}: {len(bad)} rows differ, first at t={ref[k][0]!r}: "
                            f"{got[k]!r} != {want[k]!r}")
    return problems
