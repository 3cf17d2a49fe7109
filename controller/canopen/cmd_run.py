"""``cantrack run CONFIG``: the controller on a real CAN bus (wall-clock time).

Boots the bus (NMT reset, identity, SDO configuration, NMT start), enables the drives in
CSP and runs the cycle until ``--duration`` or Ctrl-C; the application follows a point of
the belt (``--engage-at``/``--disengage-at``, absolute or relative).  Bus flags as in
python-can's tools (-i/-c/-b, --can-config, CAN_* environment variables).
"""

from __future__ import annotations

import argparse
import sys
import time

from ..tracking import Mode
from . import canbus
from .app import ConveyorFollow
from .config import load_bus_config
from .cycle import Controller
from .report import status_line, summary_table, timing_summary, write_telemetry
from .transport import RealtimeTransport


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("config", help="bus.yml with a .tracking section")
    canbus.add_arguments(p)
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--engage-at", type=float, help="engage this many s after tracking starts")
    p.add_argument("--disengage-at", type=float, help="disengage this many s after the start")
    p.add_argument("--offset", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("X", "Y", "Z"), help="the belt point to follow [mm]")
    p.add_argument("--mode", choices=("absolute", "relative"), default="relative")
    p.add_argument("--telemetry", metavar="FILE", help="write JSON-lines telemetry")
    p.add_argument("-q", "--quiet", action="store_true", help="no live status line")
    return p


def main(argv: list[str] | None = None, prog: str = "cantrack run") -> int:
    args = build_parser(prog).parse_args(argv)
    cfg = load_bus_config(args.config)
    period = cfg.period_s
    cyc = (lambda s: None if s is None else round(s / period))
    app = ConveyorFollow(cyc(args.engage_at), cyc(args.disengage_at), args.offset,
                         Mode.ABSOLUTE if args.mode == "absolute" else Mode.RELATIVE,
                         end_cycle=cyc(args.duration))
    bus = canbus.open_bus(args, cfg.bitrate)
    last = [-1.0]

    def on_cycle(ctl: Controller, rec) -> None:
        if not args.quiet and rec.t_s - last[0] >= 0.2:
            last[0] = rec.t_s
            print("\r" + status_line(ctl, rec), end="", file=sys.stderr, flush=True)

    transport = RealtimeTransport(bus)
    wall0 = time.perf_counter()
    ctl = Controller(cfg, transport, app, on_cycle=on_cycle, keep_trace=args.telemetry is not None)
    try:
        ctl.boot()
        try:
            ctl.run()
        except KeyboardInterrupt:
            ctl.disable()
    finally:
        transport.close()
        if not args.quiet:
            print(file=sys.stderr)
    if args.telemetry:
        write_telemetry(args.telemetry, ctl)
    print(summary_table(ctl, [], time.perf_counter() - wall0))
    t = timing_summary(ctl)
    print(f"compute p99 {t['compute_us']['p99']:.0f} us, cpu/cycle p50 "
          f"{t['cpu_cycle_us']['p50']:.0f} us")
    for e in ctl.events:
        if e.reaction:
            print(f"event: {e}")
    return 0
