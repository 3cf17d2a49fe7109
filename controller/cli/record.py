"""``cantrack record -o FILE``: record a bus session in one of python-can's log formats.

The format follows the extension (``can.Logger``): candump ``.log``, Vector ``.asc``,
``.blf``, ``.csv``, ``.trc``, ...  Records until ``--duration``, Ctrl-C or SIGTERM (then the
file is closed properly and the exit code is 0).  ``--ready-file PATH`` is written once
the bus is open, for scripts that start sending after it.  Bus flags as ``cantrack run``
(-i/-c/-b, --can-config, CAN_* environment variables); a bus.yml may be given for its bitrate.
"""

from __future__ import annotations

import argparse
import sys
import time

import can

from ..canopen.apps.record import LOG_FORMATS
from ..canopen.config import load_bus_config
from ..canopen.io import canbus
from ..errors import CanError
from .common import add_bus_arguments


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("config", nargs="?", help="bus.yml (only for its bitrate)")
    add_bus_arguments(p)
    p.add_argument("-o", "--output", required=True,
                   help="log file: .log (candump), .asc, .blf, .csv, .trc, ...")
    p.add_argument("--duration", type=float, help="stop after this many seconds")
    p.add_argument("--ready-file", metavar="PATH",
                   help="write this file (JSON: pid, output) once the bus is open and "
                        "recording")
    p.add_argument("-q", "--quiet", action="store_true")
    return p


def main(argv: list[str] | None = None, prog: str = "cantrack record") -> int:
    args = build_parser(prog).parse_args(argv)
    bitrate = load_bus_config(args.config).bitrate if args.config else 500_000
    bus = canbus.open_bus(args, bitrate)
    stop = [False]

    def on_term(signum, frame) -> None:
        stop[0] = True

    old = canbus.set_sigterm(on_term)
    try:
        logger = can.Logger(args.output)
    except ValueError as exc:  # unknown extension
        bus.shutdown()
        canbus.set_sigterm(old)
        raise CanError(f"{args.output}: {exc}; formats: {LOG_FORMATS}") from None
    if args.ready_file:
        canbus.write_ready_file(args.ready_file, {"output": str(args.output)})
    count = 0
    t_end = None if args.duration is None else time.monotonic() + args.duration
    try:
        try:
            while not stop[0] and (t_end is None or time.monotonic() < t_end):
                msg = bus.recv(0.1)
                if msg is not None:
                    logger.on_message_received(msg)
                    count += 1
        except KeyboardInterrupt:
            pass
        # what the bus has already received is part of the session (a SIGTERM sent right
        # after another process's last frame must not lose it): drain it, without waiting
        for _ in range(100_000):
            msg = bus.recv(0.0)
            if msg is None:
                break
            logger.on_message_received(msg)
            count += 1
    finally:
        logger.stop()
        bus.shutdown()
        canbus.set_sigterm(old)
    if not args.quiet:
        print(f"{count} frames -> {args.output}", file=sys.stderr)
    return 0
