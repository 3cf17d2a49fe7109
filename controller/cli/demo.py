"""``cantrack demo``: the whole controller on an embedded python-can virtual bus.

A simulated conveyor encoder, four drives (x, y, z, c) and a photo-eye; the controller boots
the bus (NMT, identity, SDO configuration, 402 enable), catches the items in the window,
follows each for the pick, de-syncs and places it: a robot group on the conveyor model
(:mod:`controller.canopen.apps.demo`, :mod:`controller.conveyor`).  Stepped time by default (finishes in
seconds), ``--realtime`` for wall-clock time.  Writes to ``-o DIR`` (default
./cantrack-demo/): ``bus.log`` (candump format, python-can's CanutilsLogWriter),
``telemetry.jsonl``, ``demo.png``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace
from pathlib import Path

from ..canopen.apps.demo import PhotoEye, PickPlace
from ..canopen.apps.report import plot_run, status_line, summary_table, write_telemetry
from ..canopen.config import load_bus_config
from ..canopen.master.cycle import Controller
from ..canopen.master.plc_node import attach_plc_node
from ..canopen.slave.world import SimWorld
from ..errors import ConfigError
from ..resources import data_path
from .common import StatusLine

DEFAULT_CONFIG = data_path("examples", "bus", "demo.yml")


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("config", nargs="?", default=str(DEFAULT_CONFIG),
                   help="bus.yml with .tracking, .simulation and .demo sections "
                        f"(default: {DEFAULT_CONFIG})")
    p.add_argument("-o", "--output", default="cantrack-demo",
                   help="output directory (default: ./cantrack-demo)")
    p.add_argument("--realtime", action="store_true",
                   help="run in wall-clock time (default: stepped, as fast as possible)")
    p.add_argument("--items", type=int, help="number of items (default: from .demo)")
    p.add_argument("--duration", type=float, help="stop after this many seconds of tracking")
    p.add_argument("--no-plot", action="store_true", help="do not write demo.png")
    p.add_argument("-q", "--quiet", action="store_true", help="no live status line")
    p.add_argument("--plc-node", action="store_true",
                   help="the controller is also a CANopen node for a PLC "
                        "(eds/cantrack-controller.eds: SDO server, TPDO1-3, RPDO1)")
    return p


def main(argv: list[str] | None = None, prog: str = "cantrack demo") -> int:
    args = build_parser(prog).parse_args(argv)
    cfg = load_bus_config(args.config)
    if cfg.demo is None or cfg.tracking is None:
        raise ConfigError("the demo needs .tracking and .demo sections", file=cfg.file)
    demo = cfg.demo
    if args.items is not None:
        if args.items < 1:
            raise ConfigError(f"--items (={args.items}) must be >= 1")
        demo = replace(demo, items=args.items)
    if args.duration is not None:
        demo = replace(demo, duration_s=args.duration)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    enc_name = cfg.tracking.conveyor.node
    app = PickPlace(demo)
    status = StatusLine(args.quiet)

    def on_cycle(ctl: Controller, rec) -> None:
        if status.due(rec.t_s):
            status.show(rec.t_s, status_line(ctl, rec, f"items {len(app.done_items)}/"
                                                       f"{demo.items}  "))

    wall0 = time.perf_counter()
    with SimWorld(cfg, realtime=args.realtime, bus_log=out / "bus.log") as world:
        ctl = Controller(cfg, world.transport, app, on_cycle=on_cycle)
        plc = attach_plc_node(ctl, app, cfg.plc) if args.plc_node else None
        if plc is not None:
            app.trigger_overflow = plc.config.trigger_overflow
        ctl.boot()
        ctl.start()
        encoder = world.device(enc_name)
        app.eye = PhotoEye(encoder.profile, demo, world.clock.now_ns() * 1e-9)
        ctl.run()
    wall = time.perf_counter() - wall0
    status.close()
    items = app.items()
    write_telemetry(out / "telemetry.jsonl", ctl, items)
    if not args.no_plot:
        plot_run(out / "demo.png", ctl, items)
    print(summary_table(ctl, items, wall))
    reactions = [e for e in ctl.events if e.reaction]
    for e in reactions:
        print(f"event: {e}")
    if plc is not None:
        print(f"plc node: id {plc.node_id}, SDO server 0x{0x600 + plc.node_id:03X}/"
              f"0x{0x580 + plc.node_id:03X}, TPDOs sent "
              + ", ".join(f"0x{p.cob_id:03X} x{p.sent}" for p in plc.tpdos))
    print(f"files: {out / 'bus.log'}, {out / 'telemetry.jsonl'}"
          + ("" if args.no_plot else f", {out / 'demo.png'}"))
    return 0
