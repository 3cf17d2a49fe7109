"""``cantrack replay CONFIG LOG``: replay a recorded encoder stream into the controller.

Reads the session (any python-can log: candump ``.log``, ``.asc``, ``.blf``, ...), takes the
conveyor encoder's sample after each SYNC and runs the controller cycle in stepped time on a
simulated bus whose encoder sends exactly those samples (drives: the configuration's simulated
ones); the application is ``cantrack run``'s belt follower (``--engage-at``,
``--disengage-at``, ``--duration``, ``--offset``, ``--mode`` as given to the recorded run) or,
with ``--demo``, the demo's pick and place (``--items``, ``--duration`` as given to
``cantrack demo``).  Then every RPDO (6040h, 607Ah) of the replay is
compared with the recorded one.  Exit code 0 when all are bit-identical, 1 otherwise
(:mod:`controller.canopen.apps.record`).
"""

from __future__ import annotations

import argparse

from ..canopen.apps.record import compare, drive_setpoints, encoder_stream, read_frames, replay
from ..canopen.apps.report import write_telemetry
from ..canopen.config import load_config
from ..canopen.apps.follow import ConveyorFollow
from ..errors import ConfigError
from ..tracking import Mode


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("config", help="the bus.yml of the recorded session")
    p.add_argument("log", help="the recorded session (.log, .asc, .blf, ...)")
    p.add_argument("--demo", action="store_true", help="the demo's pick and place application")
    p.add_argument("--items", type=int, help="--demo: number of items (as given to the demo)")
    p.add_argument("--duration", type=float)
    p.add_argument("--engage-at", type=float)
    p.add_argument("--disengage-at", type=float)
    p.add_argument("--offset", type=float, nargs=3, default=(0.0, 0.0, 0.0),
                   metavar=("X", "Y", "Z"))
    p.add_argument("--mode", choices=("absolute", "relative"), default="relative")
    p.add_argument("--telemetry", metavar="FILE", help="write the replay's telemetry")
    return p


def main(argv: list[str] | None = None, prog: str = "cantrack replay") -> int:
    args = build_parser(prog).parse_args(argv)
    cfg = load_config(args.config)
    if cfg.tracking is None:
        raise ConfigError("replay needs a .tracking section", file=cfg.file)
    frames = read_frames(args.log)
    stream = encoder_stream(cfg, frames)
    if not stream:
        raise ConfigError(f"{args.log}: no SYNC frames: nothing to replay")
    setup = None
    if args.demo:
        from ..canopen.apps.demo import PhotoEye, PickPlace
        if cfg.demo is None:
            raise ConfigError("--demo needs a .demo section", file=cfg.file)
        from dataclasses import replace as dc_replace
        demo = cfg.demo
        if args.items is not None:
            demo = dc_replace(demo, items=args.items)
        if args.duration is not None:
            demo = dc_replace(demo, duration_s=args.duration)
        app = PickPlace(demo)

        def setup(ctl, world) -> None:
            enc = world.device(cfg.tracking.conveyor.node)
            app.eye = PhotoEye(enc.profile, demo, world.clock.now_ns() * 1e-9)
    else:
        def cyc(s: float | None) -> int | None:
            return None if s is None else round(s / cfg.period_s)
        app = ConveyorFollow(cyc(args.engage_at), cyc(args.disengage_at), args.offset,
                             Mode.ABSOLUTE if args.mode == "absolute" else Mode.RELATIVE,
                             end_cycle=cyc(args.duration))
    ctl, replayed = replay(cfg, stream, app, setup)
    if args.telemetry:
        write_telemetry(args.telemetry, ctl)
    missing = sum(1 for v in stream if v is None)
    print(f"{args.log}: {len(frames)} frames, {len(stream)} SYNC, {len(stream) - missing} "
          f"encoder samples ({missing} SYNC without one)")
    result = compare(drive_setpoints(cfg, frames), drive_setpoints(cfg, replayed))
    print(result.format())
    return 0 if result.exact else 1
