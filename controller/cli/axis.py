"""What ``cantrack home``, ``move`` and ``jog`` share: their arguments and the run of an axis
command (:func:`run_axis_command`): the configuration, the bus (simulated devices unless the
bus flags ask for a real one), the progress line, the reports and the exit code."""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from ..canopen.apps.axis_motion import (
    MotionController,
    MotionReport,
    check_max_time,
    load_axes_config,
)
from ..canopen.apps.axis_jobs import JobResult
from ..canopen.io import canbus
from ..canopen.io.transport import RealtimeTransport
from ..canopen.master.cycle import CycleRecord
from .common import StatusLine, add_bus_arguments, real_bus_requested


def add_axis_arguments(p: argparse.ArgumentParser) -> None:
    """CONFIG, the bus flags, ``--max-time S``, ``-q``."""
    p.add_argument("config", help="bus.yml with a .tracking section (axes, motion, homing)")
    add_bus_arguments(p)
    p.add_argument("--max-time", type=float, default=600.0, metavar="S",
                   help="time limit [s] (default 600): when it is up, the axis stops "
                        "jerk-limited, then the drives are disabled (result ERROR_TIMEOUT)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress display")


def run_axis_command(args: argparse.Namespace,
                     action: Callable[..., list[MotionReport] | MotionReport]) -> int:
    """Run ``action(cfg, transport=..., on_cycle=..., max_time_s=...)``; print the report(s);
    exit code 0 if every job succeeded (a ``SKIPPED`` axis counts as success), 1 otherwise;
    a bad ``--max-time`` (not a finite number > 0) is an error (:class:`MotionError`: exit
    code 2 from ``cantrack``)."""
    # checked before anything else (one line "cantrack: error: ...", exit code 2)
    check_max_time(args.max_time, "--max-time")
    cfg = load_axes_config(args.config)
    status = StatusLine(args.quiet, every_s=0.5)
    signals = canbus.StopSignals()
    stopped = [False]

    def on_cycle(ctl: MotionController, rec: CycleRecord) -> None:
        if signals.requested and not stopped[0]:
            # SIGTERM / Ctrl-C: the controlled stop of --max-time (jerk-limited to rest, then
            # the drives disabled); the report says ERROR_ABORTED, exit code 1
            stopped[0] = True
            ctl.request_stop(JobResult.ERROR_ABORTED, f"stopped by {signals.requested.upper()}")
        if not status.due(rec.t_s):
            return
        job = ctl.job
        io = ctl.io
        state = job.report.states[-1] if job.report.states else ctl.phase.value
        actual = io.scale.from_counts(io.input.actual) if io.input is not None else math.nan
        extra = job.progress()
        status.show(rec.t_s, f"{job.kind} {job.ax.name}: t {rec.t_s:7.3f} s  {state:<14} "
                             f"actual {actual:10.4f}  setpoint "
                             f"{io.scale.from_counts(io.target):10.4f}"
                             + (f"  {extra}" if extra else ""))

    transport = None
    if real_bus_requested(args):
        settings, cfg = canbus.bus_config_for(args, cfg)  # -b wins; load checked at it
        transport = RealtimeTransport(canbus.open_configured(settings))
    try:
        with signals:
            result = action(cfg, transport=transport, on_cycle=on_cycle,
                            max_time_s=args.max_time)
    finally:
        if transport is not None:
            transport.close()
        status.close()
    reports = result if isinstance(result, list) else [result]
    for r in reports:
        print(r.summary())
    return 0 if all(r.ok for r in reports) else 1
