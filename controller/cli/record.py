"""``cantrack record -o FILE``: record a bus session in one of python-can's log formats.

The format follows the extension (``can.Logger``): candump ``.log``, Vector ``.asc``,
``.blf``, ``.csv``, ``.trc``, ...  Records until ``--duration``, Ctrl-C or SIGTERM (then the
file is closed properly and the exit code is 0).  The line-based formats (.log, .asc, .csv)
are flushed every second: after a SIGKILL (or a power cut) they hold everything up to the last
second, at most their last line cut (an .asc then lacks its closing line, which python-can's
reader does not need); a .blf is written in compressed containers with a header completed at
the end and does not survive a SIGKILL.  ``--file-size``/``--file-time``/``--keep`` rotate the
log as ``can.logger``'s ``--file_size`` does (python-can's names), keeping at most N rotated
files.  ``--ready-file PATH`` is written once
the bus is open, for scripts that start sending after it.  Bus flags as ``cantrack run``
(-i/-c/-b, --can-config, CAN_* environment variables); a bus.yml may be given for its bitrate.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import can

from ..canopen.apps.record import LOG_FORMATS
from ..canopen.config import load_config
from ..canopen.io import canbus
from ..canopen.io.rotating import BusLog
from ..canopen.io.rotating import add_arguments as add_rotation_arguments
from ..errors import CanError
from .common import add_bus_arguments


def build_parser(prog: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    p.add_argument("config", nargs="?", help="bus.yml (only for its bitrate)")
    add_bus_arguments(p)
    p.add_argument("-o", "--output", required=True,
                   help="log file: .log (candump), .asc, .blf, .csv, .trc, ...")
    p.add_argument("--duration", type=canbus.seconds, help="stop after this many seconds")
    p.add_argument("--ready-file", metavar="PATH",
                   help="write this file (JSON: pid, output) once the bus is open and "
                        "recording")
    p.add_argument("-q", "--quiet", action="store_true")
    add_rotation_arguments(p, "the log")
    return p


def open_log(path: str, max_bytes: int = 0, max_age_s: float = 0.0,
             keep: int | None = None) -> can.Listener:
    """The log writer: a rotating, flushing :class:`~.io.rotating.BusLog` for the formats
    python-can rotates (.log, .asc, .csv, .blf, .txt), else ``can.Logger`` (no rotation)."""
    suffix = Path(path).suffix.lower()
    if suffix in BusLog._supported_formats:
        return BusLog(path, max_bytes, max_age_s=max_age_s, keep=keep)
    if max_bytes or max_age_s:
        raise CanError(f"{path}: python-can does not rotate {suffix} files; rotation works "
                       f"for {', '.join(sorted(BusLog._supported_formats))}")
    return can.Logger(path)


def main(argv: list[str] | None = None, prog: str = "cantrack record") -> int:
    args = build_parser(prog).parse_args(argv)
    bitrate = load_config(args.config).bitrate if args.config else 500_000
    bus = canbus.open_bus(args, bitrate)
    try:
        logger = open_log(args.output, args.file_size, args.file_time, args.keep)
    except ValueError as exc:  # unknown extension
        bus.shutdown()
        raise CanError(f"{args.output}: {exc}; formats: {LOG_FORMATS}") from None
    stop = canbus.StopSignals().__enter__()  # SIGTERM/SIGINT: close the file properly, exit 0
    count = 0
    t_end = None if args.duration is None else time.monotonic() + args.duration
    try:
        if args.ready_file:
            canbus.write_ready_file(args.ready_file, {"output": str(args.output)})
        try:
            while not stop() and (t_end is None or time.monotonic() < t_end):
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
        try:
            logger.stop()
        finally:
            bus.shutdown()
            stop.__exit__()
            canbus.remove_ready_file(args.ready_file)
    if not args.quiet:
        print(f"{count} frames -> {args.output}", file=sys.stderr)
    return 0
