"""The cycle with axis jobs instead of the tracker: :class:`MotionController` runs
:mod:`~controller.canopen.apps.axis_jobs` one after the other in one session (one boot, one
enable); :func:`run_jobs` drives it until they are done, a job fails or the time is up."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from ...errors import CanError
from ...tracking import Mode
from ..master.app import NO_STATUS, AppStatus
from ..master.axisio import AxisIO, DriveInput
from ..master.cycle import Controller, CycleRecord, Phase
from ..protocol import cia402
from .axis_jobs import (
    Job,
    MotionError,
    MotionReport,
)


class _JobApp:
    """The Application the cycle sees: ends the run when the jobs are done."""

    def __init__(self) -> None:
        self.ctl: MotionController | None = None

    def start(self, ctl: Controller, cycle: int) -> None:
        pass

    def update(self, ctl, cycle, belt):  # not called: MotionController._run_step
        raise AssertionError

    def master_lost(self, ctl: Controller, cycle: int) -> None:
        pass

    def done(self, ctl: Controller, cycle: int) -> bool:
        return ctl.all_done

    def status(self) -> AppStatus:
        return NO_STATUS

    def engage(self, ctl: Controller, mode: Mode) -> bool:
        return True  # (the jobs, not the tracker, move the axes: a PLC command is ignored)

    def trigger(self, t_ns: int, item_type: int = 0) -> bool:
        return False

    def track_types(self, types: frozenset[int] | None) -> bool:
        return False


class MotionController(Controller):
    """The cycle with :class:`Job` s instead of the tracker, run one after the other in one
    session (one boot, one enable); the axes without a running job hold.  A failed job
    ends the session."""

    def __init__(self, cfg, transport, jobs: Job | Sequence[Job], **kw: Any) -> None:
        super().__init__(cfg, transport, _JobApp(), **kw)
        self.jobs = [jobs] if isinstance(jobs, Job) else list(jobs)
        if not self.jobs:
            raise MotionError("no motion job")
        self.index = 0
        #: (result, message) once a controlled stop was requested (:meth:`request_stop`)
        self.stop_reason: tuple[str, str] | None = None
        self.ios: list[AxisIO] = []
        for job in self.jobs:
            io = next((a for a in self.axes if a.axis == job.ax.name), None)
            if io is None:
                raise MotionError(f"no axis {job.ax.name!r}")
            self.ios.append(io)
            job.attach(self, io)

    @property
    def job(self) -> Job:
        """The job running (or the last one)."""
        return self.jobs[self.index]

    @property
    def io(self) -> AxisIO:
        return self.ios[self.index]

    @property
    def all_done(self) -> bool:
        job = self.job
        return job.done and (not job.report.ok or self.index == len(self.jobs) - 1)

    def request_stop(self, result: str, message: str) -> int:
        """Stop in a controlled way (no quick stop): the running job stops jerk-limited and
        ends with ``result``/``message`` when the axis is at rest; no further job starts.
        Returns the number of cycles after which to give up waiting for that."""
        if self.stop_reason is None:
            self.stop_reason = (result, message)
        job = self.job
        if job.done or not job.started:
            return 2  # the next cycle ends it (see _run_step)
        return math.ceil(job.request_stop(self, result, message) / self.cfg.period_s) + 1

    def fail_job(self, k: int, message: str, result: str = "ERROR_LIMIT") -> None:
        t_s = (self.clock.now_ns() - self.t0) * 1e-9
        self.quick_stop(k, t_s, self.io.label, "limit", message)
        self.job.finish(self, k, False, result, message)

    def _supervise(self, k: int, t_s: float) -> None:
        io = self.io
        raw = io.input
        masked = self.job.masks_bit13() and raw is not None
        if masked:
            io.input = DriveInput(raw.statusword & ~cia402.SW_FOLLOWING_ERROR, raw.actual,
                                  raw.t_ns, raw.cycle)
        try:
            super()._supervise(k, t_s)
        finally:
            if masked:
                io.input = raw

    def _run_step(self, k: int, t_s: float, est) -> tuple[float, ...]:
        if self.job.done and not self.all_done:
            self.index += 1
        job = self.job
        if not job.started and self.stop_reason is not None and not job.done:
            # stopped (time is up) before this job could start: it does not run
            job._k0 = k
            job.report.start_mm = self.io.scale.from_counts(self.io.hold)
            job.finish(self, k, False, self.stop_reason[0],
                       f"{self.stop_reason[1]}: not started")
        elif not job.started:
            job.start(self, k, self.io.scale.from_counts(self.io.hold))
        out = []
        for a in self.axes:
            if a is self.io and not job.done:
                cw, target = job.cycle(self, k)
                inp = a.input
                job.report.targets.append(target)
                job.report.actuals.append(inp.actual if inp is not None else 0)
                if job.done:
                    a.hold = target
            else:
                cw, target = cia402.CW_ENABLE, a.hold
            if self.phase is Phase.STOPPING:
                cw = cia402.CW_QUICK_STOP_CMD
            a.send(cw, target)
            out.append(a.scale.from_counts(target))
        return tuple(out)


# -- running ---------------------------------------------------------------------------------
ProgressFn = Callable[[MotionController, CycleRecord], None]


def run_jobs(ctl: MotionController, max_time_s: float = 600.0,
             boot: bool = True) -> list[MotionReport]:
    """Boot, enable, run the jobs until they are done (or one fails); returns the reports
    of the jobs that ran (a job after a failure does not run)."""
    check_max_time(max_time_s)
    if boot:
        ctl.boot()
    ctl.start()
    deadline = int(max_time_s / ctl.cfg.period_s) + 1
    timeout = f"not done within {max_time_s:g} s"
    stopping = False
    try:
        while True:
            if ctl.k >= deadline and ctl.phase is Phase.RUNNING and not stopping:
                # time is up: a controlled (jerk-limited) stop of the running job, to rest;
                # not a quick stop, and no following error from a setpoint that jumps
                stopping = True
                deadline = ctl.k + ctl.request_stop("ERROR_TIMEOUT", timeout)
            if ctl.k >= deadline and ctl.phase is not Phase.STOPPING:
                io = ctl.io
                if not ctl.job.done and ctl.job.started:
                    io.hold = io.target  # hold the last setpoint sent, not an older one
                ctl.job.finish(ctl, ctl.k - 1, False, "ERROR_TIMEOUT",
                               timeout + (" and not at rest after the stop" if stopping
                                          else ""))
                break
            if ctl.phase is Phase.RUNNING and ctl.job.started and not ctl.job.done:
                ctl.job.between(ctl)
            ctl.step()
            if ctl.phase is Phase.RUNNING and ctl.all_done:
                break
            if ctl.phase is Phase.STOPPED:  # (a stop ends confirmed or unconfirmed)
                break
        if ctl.phase is Phase.RUNNING:
            # let the drive settle on the last setpoint before reading the end position
            for _ in range(5):
                ctl.step()
            ctl.disable()
        elif ctl.phase is Phase.ENABLING:
            ctl.disable()  # time up while enabling: leave no drive enabled
    except CanError as exc:
        ctl.job.finish(ctl, ctl.k, False, "ERROR", str(exc))
    job = ctl.job
    reasons = "; ".join(f"{e.source}: {e.detail}" for e in ctl.events if e.reaction)
    if ctl.failure is not None and not job.done:
        job.finish(ctl, ctl.k, False, "ERROR", str(ctl.failure))
    if not job.done:
        job.finish(ctl, ctl.k, False, "ERROR", reasons or "stopped")
    elif not job.report.ok and not job.report.message:
        job.report.message = reasons
    reports = []
    for j, io in zip(ctl.jobs[:ctl.index + 1], ctl.ios):
        r = j.report
        if io.input is not None:
            r.end_counts = io.input.actual
            r.end_mm = io.scale.from_counts(io.input.actual)
        reports.append(r)
    return reports


def check_max_time(max_time_s: float, name: str = "max_time_s") -> float:
    """``max_time_s`` if it is a finite number of seconds > 0; else :class:`MotionError`."""
    if not (isinstance(max_time_s, (int, float)) and math.isfinite(max_time_s)
            and max_time_s > 0):
        raise MotionError(f"{name} {max_time_s:g}: must be a finite number of seconds > 0"
                          if isinstance(max_time_s, (int, float)) else
                          f"{name} {max_time_s!r}: must be a finite number of seconds > 0")
    return float(max_time_s)


def run_job(ctl: MotionController, max_time_s: float = 600.0, boot: bool = True) -> MotionReport:
    """:func:`run_jobs` for one job: its report."""
    return run_jobs(ctl, max_time_s, boot)[-1]
