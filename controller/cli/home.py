"""``cantrack home CONFIG [--axis x]``: home axes with their configured method.

Each axis' ``homing:`` section (.tracking.kinematics.axes) says how: ``gotoy`` (slow-down
and home switch read from 60FDh in a TPDO), ``drive`` (the drive's homing mode 6060h = 6)
or ``none`` (absolute encoder).  There is no default method: ``--axis`` naming an axis
without a ``homing:`` section is an error (exit code 2, nothing moves).  Without ``--axis``
every axis with a ``homing:`` section is homed, in order, and the others are listed as
``SKIPPED`` (not homed; an error if no axis has one).  On the embedded virtual bus with
simulated devices (stepped time) by default; on a real bus with -i/-c/-b.  ``--max-time``
stops the axis jerk-limited (ERROR_TIMEOUT).  Exit code 0 if all succeeded, 1 otherwise.
Python/HIL: :func:`controller.canopen.apps.axis_motion.home`.
"""

from __future__ import annotations

import argparse

from ..canopen.apps import axis_motion as am
from .axis import add_axis_arguments, run_axis_command


def main(argv: list[str] | None = None, prog: str = "cantrack home") -> int:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    add_axis_arguments(p)
    p.add_argument("--axis", action="append",
                   help="axis to home (repeatable; it must have a homing: section).  Default: "
                        "every axis with a homing: section; the others are listed as SKIPPED")
    args = p.parse_args(argv)
    return run_axis_command(args, lambda cfg, **kw: am.home(cfg, args.axis, **kw))
