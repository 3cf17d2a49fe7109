"""A work cell (``.tracking.cell``) under ``cantrack demo``: the cell's encoders and every
robot's drives simulated on the embedded virtual bus, the cell run by its setpoint source
(:class:`controller.canopen.apps.cell.CellSource`).

Stepped time by default, ``--realtime`` on the wall clock; ``--duration`` [s of tracking]
(default: until nothing is scheduled any more and every robot stands).  Writes to ``-o DIR``:
``bus.log`` (candump), ``telemetry.jsonl`` (``run``, ``cycle``, ``event``, one ``item`` per
robot's item with its frame and outcome, ``end`` with every robot's and frame's counts) and
``demo.png`` (the simulator's cell plot: every frame's window, every robot's TCP path, per
robot x, y, z [mm] and IMFS over time [s] with its MasterFrame).  The summary: per robot
(items, caught, picked, missed, ignored, hand-offs, tracking error), per frame, per item.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from ..canopen.apps.cell import CellSource, finish_telemetry, format_cell_table
from ..canopen.apps.report import Telemetry, status_line, summary_table
from ..canopen.config import ControllerConfig
from ..canopen.io.canbus import StopSignals
from ..canopen.io.rotating import BusLog
from ..canopen.master.cycle import Controller
from ..canopen.master.plc_node import attach_plc_node
from ..canopen.slave.world import SimWorld
from ..cell.scenario import CellScenario
from ..errors import ConfigError
from ..simulate.cell import CellResult, RobotTrace, plot_cell_result
from .common import StatusLine

#: samples of every robot recorded for the plot (a longer run plots its beginning)
PLOT_SAMPLES = 200_000


def cell_result(cfg: ControllerConfig, src: CellSource) -> CellResult:
    """The recorded part of a bus run of a cell as the simulator's result (its plot)."""
    cell = cfg.tracking.cell if cfg.tracking is not None else None
    assert cell is not None and src.run is not None
    tc = cfg.tracking
    assert tc is not None
    n = src.recorded
    sc = CellScenario(tc.tracker, max(1, n - 1) * src.T, {}, cell.frames,
                      tuple(r.spec for r in cell.robots), cell.sensors,
                      f"{Path(cfg.file).name} on the bus", Path(cfg.file))
    robots = {}
    for rc in cell.robots:
        tr = src.traces[rc.name]
        rg = src.run.robots[rc.name]
        prog = src.run.programs.get(rc.name)
        robots[rc.name] = RobotTrace(rc.name, np.array(tr.pos), np.array(tr.ori),
                                     np.array(tr.imfs), np.array(tr.slave), tr.mf, tr.events,
                                     src.records(rc.name),
                                     dict(prog.picks) if prog is not None else {}, rg)
    return CellResult(sc, np.arange(n) * src.T,
                      {k: np.array(v) for k, v in src.master_values.items()}, robots,
                      src.run.frames, list(src.run.triggers))


def run_cell_demo(args: argparse.Namespace, cfg: ControllerConfig) -> int:
    """``cantrack demo CELL.yml`` (see the module docstring)."""
    if args.items is not None:
        raise ConfigError("--items is for the demo's photo-eye; a cell's items come from its "
                          "sensors (.tracking.cell.sensors)", file=cfg.file)
    if args.telemetry_every < 1:
        raise ConfigError(f"--telemetry-every (={args.telemetry_every}) must be >= 1")
    tc = cfg.tracking
    assert tc is not None and tc.cell is not None
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    telemetry: list[Telemetry] = []

    def on_item(robot: str, rec) -> None:
        if telemetry:
            telemetry[0].cell_item(robot, rec)

    app = CellSource(tc.cell, duration_s=args.duration,
                     record=0 if args.no_plot else PLOT_SAMPLES, on_item=on_item)
    status = StatusLine(args.quiet)

    def on_cycle(ctl: Controller, rec) -> None:
        if telemetry:
            telemetry[0].cycle(rec)
        if status.due(rec.t_s):
            items = sum(s.triggered for s in app.summaries.values())
            status.show(rec.t_s, status_line(ctl, rec, f"items {items}  "))

    rotation = dict(max_age_s=args.file_time, keep=args.keep)
    bus_log = BusLog(out / "bus.log", args.file_size, **rotation)
    wall0 = time.perf_counter()
    end, error = "end", None
    with StopSignals() as stop, SimWorld(cfg, realtime=args.realtime, bus_log=bus_log) as world:
        ctl = Controller(cfg, world.transport, app, on_cycle=on_cycle, keep_trace=False)
        tel = Telemetry(out / "telemetry.jsonl", ctl, max_bytes=args.file_size,
                        every=args.telemetry_every, extra={
                            "cell": {"encoders": list(tc.cell.encoders),
                                     "frames": [f.name for f in tc.cell.frames],
                                     "robots": {r.name: [a.name for a in r.axes]
                                                for r in tc.cell.robots}}}, **rotation)
        telemetry.append(tel)
        try:
            if args.plc_node:
                attach_plc_node(ctl, cfg.plc)
            ctl.boot()
            ctl.start()
            ctl.run(stop=stop)
            if stop.requested:
                end = stop.requested
        except BaseException as exc:  # every exit keeps the data: the files are completed
            end, error = "error", f"{type(exc).__name__}: {exc}"
            raise
        finally:
            tel.close(end, error, extra={   # (as the demo: the items still pending first)
                **finish_telemetry(tel, app), "wall_s": time.perf_counter() - wall0})
    wall = time.perf_counter() - wall0
    status.close()
    if not args.no_plot and app.recorded:
        plot_cell_result(cell_result(cfg, app), out / "demo.png")
    sim_s = ctl.k * cfg.period_s
    print(format_cell_table(app))
    print()
    print(f"{len(tc.cell.robots)} robots, {len(tc.cell.frames)} frames, "
          f"{len(tc.cell.encoders)} encoders; "
          + summary_table(ctl, [], wall, item_rows=False))
    for e in ctl.events:
        if e.reaction:
            print(f"event: {e}")
    print(f"files: {out / 'bus.log'}, {out / 'telemetry.jsonl'}"
          + ("" if args.no_plot else f", {out / 'demo.png'}"))
    if end in ("sigterm", "sigint"):
        print(f"stopped by {end.upper()} after {sim_s:.2f} s", file=sys.stderr)
    return ctl.exit_code()
