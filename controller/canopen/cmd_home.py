"""``cantrack home CONFIG [--axis x]``: home axes with their configured method.

Each axis' ``homing:`` section (.tracking.kinematics.axes) says how: ``gotoy`` (slow-down
and home switch read from 60FDh in a TPDO), ``drive`` (the drive's homing mode 6060h = 6)
or ``none`` (absolute encoder).  Without ``--axis`` every axis with a ``homing:`` section
is homed, in order.  On the embedded virtual bus with simulated devices (stepped time) by
default; on a real bus with -i/-c/-b.  Exit code 0 if all succeeded, 1 otherwise.
Python/HIL: :func:`controller.canopen.axis_motion.home`.
"""

from __future__ import annotations

import argparse

from . import axis_motion as am


def main(argv: list[str] | None = None, prog: str = "cantrack home") -> int:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    am.add_common_arguments(p)
    p.add_argument("--axis", action="append",
                   help="axis to home (repeatable; default: every axis with homing:)")
    args = p.parse_args(argv)
    return am.cli_run(args, lambda cfg, **kw: am.home(cfg, args.axis, **kw))
