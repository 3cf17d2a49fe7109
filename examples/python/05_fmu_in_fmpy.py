"""05 - Build the tracker FMU and run it in fmpy: the same setpoints as the core.

``CanTracker.fmu`` (FMI 2.0 co-simulation, built with pythonfmu) is the tracking core behind
the FMI interface.  This example builds it, simulates it with ``fmpy.simulate_fmu`` on a belt
at 300 mm/s (the master inputs at every step start, ``engage`` true from 0.1 s), and steps the
core ``Tracker`` by hand with the FMU's rules (the master at the step start, moved on to the
sample time; the output is the setpoint at the step's end).  Both give the same numbers, to
the bit.  FMU variables and rules: fmu/README.md; spec: docs/spec/tracking.md#2.2 (time
axis).

Run from the repository root (needs the ``fmu`` extras: pythonfmu, fmpy):

    python examples/python/05_fmu_in_fmpy.py [-o DIR]    # DIR/CanTracker.fmu (default: a temp dir)

Units: mm, mm/s, s.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from controller.fmu.build import build_tracker_fmu
from controller.tracking import MotionState, Tracker, TrackerParams

T_S = 0.002
STOP_S = 1.5
ENGAGE_S = 0.1
BELT_MM_S = 300.0
START = {"sample_time": T_S, "planner": 1, "x0": -250.0, "y0": 150.0}  # planner 1: optimal


def master(t: float) -> MotionState:
    return MotionState((BELT_MM_S * t, 0.0, 0.0), (BELT_MM_S, 0.0, 0.0))


def run_fmu(fmu: Path):
    from fmpy import simulate_fmu

    n = round(STOP_S / T_S)
    inputs = [f"master_{a}" for a in ("x", "y", "z", "c", "vx", "vy", "vz", "vc",
                                      "ax", "ay", "az", "ac")]
    table = np.zeros(n + 1, dtype=[("time", float)] + [(name, float) for name in inputs]
                     + [("engage", bool)])  # every input at every step start (0 if unused)
    table["time"] = np.arange(n + 1) * T_S
    table["master_x"] = [master(t).pos[0] for t in table["time"]]
    table["master_vx"] = BELT_MM_S
    table["engage"] = table["time"] >= ENGAGE_S - 1e-12
    return simulate_fmu(str(fmu), start_time=0.0, stop_time=STOP_S, output_interval=T_S,
                        start_values=START, input=table, output=["x", "y", "vx", "imfs"])


def run_core():
    """The core with the FMU's stepping rules: step [t_k, t_k+1] sees the master at t_k."""
    params = TrackerParams(sample_time_s=T_S, planner="optimal")
    tracker = Tracker(params, MotionState.at(START["x0"], START["y0"]))
    rows = [(0.0, START["x0"], START["y0"], 0.0, 0)]
    engaged = False
    for k in range(round(STOP_S / T_S)):
        t = k * T_S
        if t >= ENGAGE_S - 1e-12 and not engaged:
            tracker.engage()
            engaged = True
        out = tracker.update(master(t).extrapolated(T_S))
        sp = out.setpoint
        rows.append(((k + 1) * T_S, sp.pos[0], sp.pos[1], sp.vel[0], int(out.imfs)))
    return rows


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--out-dir", type=Path, default=None, help="where to build the FMU")
    args = ap.parse_args(argv)
    out_dir = args.out_dir or Path(tempfile.mkdtemp(prefix="cantrack-fmu-"))
    fmu = build_tracker_fmu(out_dir)
    print(f"built {fmu}")
    res = run_fmu(fmu)
    core = run_core()
    n = min(len(res), len(core))
    diff = max(max(abs(res["x"][i] - core[i][1]), abs(res["y"][i] - core[i][2]))
               for i in range(n))
    synced = [res["time"][i] for i in range(len(res)) if res["imfs"][i] == 1]
    t_sync = synced[0] - ENGAGE_S if synced else float("nan")
    last = len(res) - 1
    error = abs(res["x"][last] - master(res["time"][last]).pos[0]) + abs(res["y"][last])
    print(f"fmpy rows: {len(res)}, core rows: {len(core)}")
    print(f"time to sync (IMFS 1): {t_sync:.3f} s after the engage")
    print(f"error at the end: {error:.3g} mm, velocity {res['vx'][last]:.3f} mm/s")
    print(f"max |FMU - core|: {diff:.3g} mm")
    return {"rows": len(res), "core_rows": len(core), "time_to_sync_s": t_sync,
            "final_error_mm": error, "max_diff_mm": diff}


if __name__ == "__main__":
    main()
