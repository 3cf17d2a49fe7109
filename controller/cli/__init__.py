"""The ``cantrack`` command line: one entry point, sub-commands registered in :data:`COMMANDS`.

Each sub-command lives in its own module and is imported only when it is run (python-can
style): ``COMMANDS`` maps the name to ``"module:function"`` and a one-line help.  The function
is called as ``function(argv, prog=...)`` with the arguments after the sub-command's name and
returns an exit code (``None`` = 0); it builds its own argparse parser.  Adding a sub-command
is one line here.

Global behaviour (options before the sub-command)::

    cantrack [--version] [-v | -vv] [--debug] COMMAND [ARGS...]

- ``-v``: INFO logging, ``-vv``: DEBUG (to stderr).
- Any :class:`controller.errors.CantrackError`, and an ``OSError`` of a file, is printed as
  one line ``cantrack: error: <message>`` with exit code 2 (no traceback unless ``--debug``).
- Ctrl-C: exit code 130, quietly.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Callable, Sequence

from .. import __version__
from ..errors import CantrackError

#: sub-command -> ("module:function", one-line help); function(argv, prog=...) -> int | None
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("controller.simulate.command:main",
                 "run a tracking scenario offline (CSV trace, summary, PNG plot)"),
    "capacity": ("controller.cli.capacity:main",
                 "up to which belt speed and item rate a conveyor cell picks every item"),
    "demo": ("controller.cli.demo:main", "tracking demo on a simulated CANopen bus"),
    "run": ("controller.cli.run:main", "the CANopen tracking controller on a CAN bus"),
    "sim-devices": ("controller.cli.sim_devices:main", "simulated encoder and drives on a CAN bus"),
    "check-bus": ("controller.cli.check_bus:main", "compare a bus with its configuration"),
    "record": ("controller.cli.record:main", "record a CAN bus session to a log file"),
    "replay": ("controller.cli.replay:main", "replay a recorded encoder stream"),
    "home": ("controller.cli.home:main", "home axes (GotoY, drive homing mode, none)"),
    "move": ("controller.cli.move:main", "jerk-limited point-to-point move of an axis"),
    "jog": ("controller.cli.jog:main", "jog an axis at a speed for a time"),
    "fmu": ("controller.fmu.cli:main",
            "build and check the tracker FMU (FMI 2.0 / 3.0 co-simulation)"),
}

EXIT_ERROR = 2
EXIT_INTERRUPTED = 130


def _load(target: str) -> Callable[..., int | None]:
    module_name, attr = target.split(":")
    return getattr(importlib.import_module(module_name), attr)


def build_parser() -> argparse.ArgumentParser:
    width = max(len(n) for n in COMMANDS)
    listing = "\n".join(f"  {name.ljust(width)}  {help_}"
                        for name, (_, help_) in COMMANDS.items())
    parser = argparse.ArgumentParser(
        prog="cantrack",
        description="Conveyor tracking (softMC moving-frame synchronisation) for CANopen "
                    "CiA 402 drives.",
        epilog=f"commands:\n{listing}\n\n'cantrack COMMAND --help' shows a command's options.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"cantrack {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="more logging (-v info, -vv debug)")
    parser.add_argument("--debug", action="store_true",
                        help="show tracebacks instead of one-line errors")
    parser.add_argument("command", metavar="COMMAND", nargs="?", choices=sorted(COMMANDS),
                        help="one of: " + ", ".join(COMMANDS))
    parser.add_argument("args", nargs=argparse.REMAINDER, metavar="ARGS",
                        help="the command's arguments")
    return parser


def _message(exc: BaseException) -> str:
    if isinstance(exc, OSError) and not isinstance(exc, CantrackError):
        if exc.filename is not None and exc.strerror:
            return f"{exc.filename}: {exc.strerror}"
        return exc.strerror or str(exc)
    return str(exc)


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``cantrack``; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:  # bare `cantrack`: what it can do, not an argparse complaint
        parser.print_help(sys.stderr)
        return EXIT_ERROR
    level = logging.WARNING if args.verbose == 0 else logging.INFO if args.verbose == 1 \
        else logging.DEBUG
    logging.basicConfig(level=level, format="cantrack: %(levelname)s: %(name)s: %(message)s")
    try:
        function = _load(COMMANDS[args.command][0])
        code = function(args.args, prog=f"cantrack {args.command}")
        return 0 if code is None else int(code)
    except KeyboardInterrupt:
        if args.debug:
            raise
        return EXIT_INTERRUPTED
    except (CantrackError, OSError) as exc:
        if args.debug:
            raise
        print(f"cantrack: error: {_message(exc)}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":
    sys.exit(main())
