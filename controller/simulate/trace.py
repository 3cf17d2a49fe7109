"""The CSV trace of a simulation: one row per sample, row 0 = the state before the first update.

Columns (units in the names)::

    time_s
    master_x_mm, master_y_mm, master_z_mm, master_c_deg           the true master
    master_vx_mm_s, master_vy_mm_s, master_vz_mm_s, master_vc_deg_s
    setpoint_x_mm, setpoint_y_mm, setpoint_z_mm, setpoint_c_deg    the tracker's output
    setpoint_vx_mm_s, setpoint_vy_mm_s, setpoint_vz_mm_s, setpoint_vc_deg_s
    setpoint_ax_mm_s2, setpoint_ay_mm_s2, setpoint_az_mm_s2, setpoint_ac_deg_s2
    state                    TrackState name (OFF, SYNCING, SYNCED, DESYNCING)
    imfs                     IsMovingFrameSynchronized value (0, 1, -1)
    error                    TrackError name (NONE, MASTER_VELOCITY, ...)

With an ``estimator`` section, what the tracker was given follows:
``input_x_mm, input_y_mm, input_z_mm, input_c_deg, input_vx_mm_s, input_vy_mm_s,
input_vz_mm_s, input_vc_deg_s``.

Floats are written with ``repr`` (shortest round-trip form): reading the file back gives the
exact values.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ..tracking import TrackError, TrackState
from .runner import SimulationResult

__all__ = ["TRACE_COLUMNS", "INPUT_COLUMNS", "write_trace"]

TRACE_COLUMNS = (
    "time_s",
    "master_x_mm", "master_y_mm", "master_z_mm", "master_c_deg",
    "master_vx_mm_s", "master_vy_mm_s", "master_vz_mm_s", "master_vc_deg_s",
    "setpoint_x_mm", "setpoint_y_mm", "setpoint_z_mm", "setpoint_c_deg",
    "setpoint_vx_mm_s", "setpoint_vy_mm_s", "setpoint_vz_mm_s", "setpoint_vc_deg_s",
    "setpoint_ax_mm_s2", "setpoint_ay_mm_s2", "setpoint_az_mm_s2", "setpoint_ac_deg_s2",
    "state", "imfs", "error",
)
INPUT_COLUMNS = (
    "input_x_mm", "input_y_mm", "input_z_mm", "input_c_deg",
    "input_vx_mm_s", "input_vy_mm_s", "input_vz_mm_s", "input_vc_deg_s",
)


def write_trace(result: SimulationResult, path: str | Path) -> Path:
    """Write the trace CSV to ``path`` (directories must exist); returns the path.

    A conveyor result gets its own columns
    (:func:`controller.simulate.conveyor.write_conveyor_trace`).
    """
    from .conveyor import ConveyorResult, write_conveyor_trace

    if isinstance(result, ConveyorResult):
        return write_conveyor_trace(result, path)
    from .cell import CellResult, write_cell_trace

    if isinstance(result, CellResult):
        return write_cell_trace(result, path)
    path = Path(path)
    r = result
    state_names = {int(s): s.name for s in TrackState}
    error_names = {int(e): e.name for e in TrackError}
    T = r.sample_time_s
    columns = TRACE_COLUMNS + (INPUT_COLUMNS if r.has_estimator else ())
    blocks = [r.master_pos, r.master_ang[:, None], r.master_vel, r.master_ang_vel[:, None],
              r.setpoint_pos, r.setpoint_ang[:, None], r.setpoint_vel,
              r.setpoint_ang_vel[:, None], r.setpoint_acc, r.setpoint_ang_acc[:, None]]
    inputs = [r.input_pos, r.input_ang[:, None], r.input_vel, r.input_ang_vel[:, None]]
    values = np.hstack(blocks).tolist()
    extra = np.hstack(inputs).tolist() if r.has_estimator else None
    states = r.state.tolist()
    imfs = r.imfs.tolist()
    errors = r.error.tolist()
    with path.open("w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(columns)
        for k, row in enumerate(values):
            out = [repr(round(k * T, 12))] + [repr(x) for x in row]
            out += [state_names[states[k]], imfs[k], error_names[errors[k]]]
            if extra is not None:
                out += [repr(x) for x in extra[k]]
            w.writerow(out)
    return path
