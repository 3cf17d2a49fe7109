"""``cantrack demo``: the whole controller on an embedded python-can virtual bus.

A simulated conveyor encoder, four drives (x, y, z, c) and a photo-eye; the controller boots
the bus (NMT, identity, SDO configuration, 402 enable), catches the items in the window,
follows each for the pick, de-syncs and places it: a robot group on the conveyor model
(:mod:`controller.canopen.apps.demo`, :mod:`controller.conveyor`).  Stepped time by default (finishes in
seconds), ``--realtime`` for wall-clock time.  Writes to ``-o DIR`` (default
./cantrack-demo/): ``bus.log`` (candump format, python-can's CanutilsLogWriter),
``telemetry.jsonl`` (written as it happens), ``demo.png``.

Long runs: memory stays bounded (the last 1000 items and events, a decimated plot trace);
``--file-size``/``--file-time``/``--keep`` rotate bus.log and telemetry.jsonl (python-can's
``can.logger`` naming).  SIGTERM and Ctrl-C end the demo like its duration: the drives stop,
every file is complete, exit 0 (3 if a supervision reaction stopped the drives).

A bus.yml with a ``.tracking.cell`` runs that cell instead (:mod:`controller.cli.cell`): every
encoder and every robot's drives simulated, the cell's sensors and MasterFrame changes as its
program; the summary per robot, frame and item, ``telemetry.jsonl`` with each robot's items,
``demo.png`` with every frame and robot.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

from ..canopen.apps.demo import PhotoEye, PickPlace
from ..canopen.apps.report import PlotTrace, Telemetry, plot_run, status_line, summary_table
from ..canopen.config import load_config
from ..canopen.io.canbus import StopSignals, seconds
from ..canopen.io.rotating import BusLog
from ..canopen.io.rotating import add_arguments as add_rotation_arguments
from ..canopen.master.cycle import Controller
from ..canopen.master.plc_node import attach_plc_node
from ..canopen.slave.world import SimWorld
from ..errors import ConfigError
from ..resources import data_path
from .common import StatusLine

DEFAULT_CONFIG = data_path("examples", "bus", "demo.yml")


def _count(text: str) -> int:
    """A number of items: an integer, also written as 1e30 (then it is that integer)."""
    try:
        v = int(text)
    except ValueError:
        try:
            f = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number of items") from None
        if not math.isfinite(f) or f != int(f):
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number of items") \
                from None
        v = int(f)
    if v < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: must be >= 1")
    return v


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", nargs="?", default=str(DEFAULT_CONFIG),
                   help="bus.yml with .tracking, .simulation and .demo sections, or with a "
                        ".tracking.cell (several encoders, frames, robots: its sensors and "
                        f"MasterFrame changes are the program) (default: {DEFAULT_CONFIG})")
    p.add_argument("-o", "--output", default="cantrack-demo",
                   help="output directory (default: ./cantrack-demo)")
    p.add_argument("--realtime", action="store_true",
                   help="run in wall-clock time (default: stepped, as fast as possible)")
    p.add_argument("--items", type=_count,
                   help="number of items (default: from .demo; made one at a time)")
    p.add_argument("--duration", type=seconds,
                   help="stop after this many seconds of tracking")
    p.add_argument("--no-plot", action="store_true", help="do not write demo.png")
    p.add_argument("-q", "--quiet", action="store_true", help="no live status line")
    p.add_argument("--plc-node", action="store_true",
                   help="the controller is also a CANopen node for a PLC "
                        "(eds/cantrack-controller.eds: SDO server, TPDO1-3, RPDO1)")
    p.add_argument("--telemetry-every", type=int, default=1, metavar="N",
                   help="a cycle line in telemetry.jsonl every N cycles (default 1)")
    add_rotation_arguments(p)
    return p


#: cycle records kept for the plot (decimated beyond that)
PLOT_POINTS = 20_000


def main(argv: list[str] | None = None, prog: str = "cantrack demo") -> int:
    args = build_parser(prog).parse_args(argv)
    cfg = load_config(args.config)
    if cfg.tracking is not None and cfg.tracking.cell is not None:
        from .cell import run_cell_demo
        return run_cell_demo(args, cfg)
    if cfg.demo is None or cfg.tracking is None:
        raise ConfigError("the demo needs .tracking and .demo sections", file=cfg.file)
    demo = cfg.demo
    if args.items is not None:
        demo = replace(demo, items=args.items)
    if args.duration is not None:
        demo = replace(demo, duration_s=args.duration)
    if args.telemetry_every < 1:
        raise ConfigError(f"--telemetry-every (={args.telemetry_every}) must be >= 1")
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    enc_name = cfg.tracking.conveyor.node
    app = PickPlace(demo)
    status = StatusLine(args.quiet)
    plot = PlotTrace(PLOT_POINTS) if not args.no_plot else None
    telemetry: list[Telemetry] = []

    def on_cycle(ctl: Controller, rec) -> None:
        if telemetry:
            telemetry[0].cycle(rec)
        if plot is not None:
            plot.add(rec)
        if status.due(rec.t_s):
            status.show(rec.t_s, status_line(ctl, rec, f"items {app.finished}/"
                                                       f"{demo.items}  "))

    rotation = dict(max_age_s=args.file_time, keep=args.keep)
    bus_log = BusLog(out / "bus.log", args.file_size, **rotation)
    wall0 = time.perf_counter()
    end, error = "end", None
    plc = None
    with StopSignals() as stop, SimWorld(cfg, realtime=args.realtime, bus_log=bus_log) as world:
        ctl = Controller(cfg, world.transport, app, on_cycle=on_cycle, keep_trace=False)
        tel = Telemetry(out / "telemetry.jsonl", ctl, max_bytes=args.file_size,
                        every=args.telemetry_every, **rotation)
        telemetry.append(tel)
        app.on_item = tel.item
        try:
            plc = attach_plc_node(ctl, cfg.plc) if args.plc_node else None
            if plc is not None:
                app.trigger_overflow = plc.config.trigger_overflow
            ctl.boot()
            ctl.start()
            encoder = world.device(enc_name)
            app.eye = PhotoEye(encoder.profile, demo, world.clock.now_ns() * 1e-9)
            ctl.run(stop=stop)
            if stop.requested:
                end = stop.requested
        except BaseException as exc:  # every exit keeps the data: the files are completed
            end, error = "error", f"{type(exc).__name__}: {exc}"
            raise
        finally:
            tel.close(end, error, app.items(), extra={
                "items_placed": app.placed, "items_missed": app.missed,
                "items_ignored": app.ignored,
                "wall_s": time.perf_counter() - wall0})
    wall = time.perf_counter() - wall0
    status.close()
    items = app.items()
    if plot is not None:
        plot_run(out / "demo.png", ctl, items, trace=plot)
    print(summary_table(ctl, items, wall, counts=(app.placed, app.missed,
                                                  app.eye.detected if app.eye else 0),
                        ignored_count=app.ignored))
    for e in ctl.events:
        if e.reaction:
            print(f"event: {e}")
    if plc is not None:
        print(f"plc node: id {plc.node_id}, SDO server 0x{0x600 + plc.node_id:03X}/"
              f"0x{0x580 + plc.node_id:03X}, TPDOs sent "
              + ", ".join(f"0x{p.cob_id:03X} x{p.sent}" for p in plc.tpdos))
    print(f"files: {out / 'bus.log'}, {out / 'telemetry.jsonl'}"
          + ("" if args.no_plot else f", {out / 'demo.png'}"))
    if end in ("sigterm", "sigint"):
        print(f"stopped by {end.upper()} after {ctl.k * cfg.period_s:.2f} s", file=sys.stderr)
    return ctl.exit_code()
