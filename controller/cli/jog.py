"""``cantrack jog CONFIG --axis x --speed 50 --time 2``: jog an axis, then stop.

Jerk-limited with the axis' ``motion:`` limits; stops early before the axis' min/max and
aborts on a limit switch (60FDh, when mapped).  ``--max-time`` (> 0 s) stops the jog
jerk-limited where it is (ERROR_TIMEOUT, exit code 1).  Simulated devices by default, a real
bus with -i/-c/-b.  Python/HIL: :func:`controller.canopen.apps.axis_motion.jog`.
"""

from __future__ import annotations

import argparse

from ..canopen.apps import axis_motion as am
from .axis import add_axis_arguments, run_axis_command


def main(argv: list[str] | None = None, prog: str = "cantrack jog") -> int:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    add_axis_arguments(p)
    p.add_argument("--axis", required=True, help="the axis to jog")
    p.add_argument("--speed", type=float, required=True, help="speed [mm/s|deg/s], signed")
    p.add_argument("--time", type=float, required=True, help="jog time [s] before the stop")
    args = p.parse_args(argv)
    return run_axis_command(args, lambda cfg, **kw: am.jog(cfg, args.axis, args.speed, args.time,
                                                       **kw))
