"""What the ``cantrack`` commands share: the bus flags and the status line.

- :func:`add_bus_arguments` — python-can's own ``-i/-c/-b/--fd/--data-bitrate/--timing/
  --bus-kwargs`` (``can.cli.add_bus_arguments``, as in ``python -m can.logger``) plus
  ``--can-config`` (a python-can configuration file); every command that opens a bus uses it,
  :func:`controller.canopen.io.canbus.bus_config` turns the flags into a bus.
- :func:`real_bus_requested` — whether the flags ask for a real bus (else the simulated one).
- :class:`StatusLine` — the one-line progress display on stderr: redrawn in place (``\\r``)
  on a terminal at most every ``every_tty_s``, one line per ``every_s`` otherwise (a log
  file gets lines, not carriage returns); nothing with ``quiet``.
"""

from __future__ import annotations

import argparse
import sys
from typing import TextIO

import can.cli


def add_bus_arguments(parser: argparse.ArgumentParser) -> None:
    """The bus flags (python-can's, plus ``--can-config FILE``)."""
    can.cli.add_bus_arguments(parser)
    parser.add_argument("--can-config", metavar="FILE",
                        help="python-can configuration file (default: ~/.canrc etc.)")


def real_bus_requested(args: argparse.Namespace) -> bool:
    """True when ``-i``, ``-c`` or ``--can-config`` was given."""
    return bool(getattr(args, "interface", None) or getattr(args, "channel", None)
                or getattr(args, "can_config", None))


class StatusLine:
    """Progress on ``stream`` (default stderr); :meth:`show` with the time [s] of the line,
    :meth:`close` at the end (ends a line drawn in place)."""

    def __init__(self, quiet: bool = False, *, every_s: float = 1.0, every_tty_s: float = 0.1,
                 stream: TextIO | None = None, tty: bool | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        self.quiet = quiet
        self.tty = self.stream.isatty() if tty is None else tty
        self.every_s = every_tty_s if self.tty else every_s
        self._last_s: float | None = None
        self._drawn = False

    def due(self, t_s: float) -> bool:
        """Whether a line for time ``t_s`` [s] would be shown (to skip building it)."""
        return not self.quiet and (self._last_s is None or t_s - self._last_s >= self.every_s)

    def show(self, t_s: float, line: str) -> None:
        """Show ``line`` if one is due at ``t_s`` [s]."""
        if not self.due(t_s):
            return
        self._last_s = t_s
        if self.tty:
            print("\r" + line, end="", file=self.stream, flush=True)
            self._drawn = True
        else:
            print(line, file=self.stream, flush=True)

    def close(self) -> None:
        if self._drawn:
            print(file=self.stream)
            self._drawn = False
