"""``cantrack move CONFIG --axis x --to 100``: a jerk-limited point-to-point move.

The axis' ``motion:`` limits and brake times (.tracking.kinematics.axes); the target is a
machine coordinate [mm|deg] within the axis' min/max.  ``--max-time`` (> 0 s) stops the
move jerk-limited where it is (ERROR_TIMEOUT, exit code 1).  Simulated devices by default, a
real bus with -i/-c/-b.  Python/HIL: :func:`controller.canopen.apps.axis_motion.move`.
"""

from __future__ import annotations

import argparse

from ..canopen.apps import axis_motion as am
from .axis import add_axis_arguments, run_axis_command


def main(argv: list[str] | None = None, prog: str = "cantrack move") -> int:
    p = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0])
    add_axis_arguments(p)
    p.add_argument("--axis", required=True, help="the axis to move")
    p.add_argument("--to", type=float, required=True, help="target [mm|deg]")
    args = p.parse_args(argv)
    return run_axis_command(args, lambda cfg, **kw: am.move(cfg, args.axis, args.to, **kw))
