"""Axis jobs as a setpoint source: :class:`JobSequence` runs
:mod:`~controller.canopen.apps.axis_jobs` one after the other in one session (one boot, one
enable) as a pure :class:`~controller.canopen.master.source.SetpointSource`;
:class:`MotionController` is the cycle with such a sequence, :func:`run_jobs` drives it until
the jobs are done, a job fails or the time is up."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from ...errors import CanError
from ..master.axisio import AxisIO
from ..master.cycle import Controller, CycleRecord, Phase
from ..master.source import (
    NO_STATUS,
    AxisSetpoints,
    CycleContext,
    DriveCommand,
    SourceOutput,
    SourceStart,
    SourceStatus,
    Transfers,
)
from .axis_jobs import AxisSlot, Job, MotionError, MotionReport


class JobSequence:
    """The axis jobs of one session, one after the other; the axes without a running job hold
    where they were enabled (or where their last job ended).  A failed job ends the session.

    Each cycle: this cycle's drive views into the axes' slots; the next job started when the
    last is done (with the axis' hold as its start); the running job's (command, target)
    for its axis, the hold for the others, as :class:`AxisSetpoints` [mm | deg]; the job's
    quick stop (a limit) and its SDO program for before the next cycle as requests."""

    def __init__(self, jobs: Sequence[Job], slots: Sequence[AxisSlot],
                 names: Sequence[str]) -> None:
        """``slots``/``names``: every axis of ``.tracking.axes``, in order."""
        if not jobs:
            raise MotionError("no motion job")
        self.jobs = list(jobs)
        self.slots = list(slots)
        self.index = 0
        #: (result, message) once a controlled stop was requested (:meth:`request_stop`)
        self.stop_reason: tuple[str, str] | None = None
        by_name = dict(zip(names, self.slots))
        #: each job's axis
        self.job_slots: list[AxisSlot] = []
        for job in self.jobs:
            slot = by_name.get(job.ax.name)
            if slot is None:
                raise MotionError(f"no axis {job.ax.name!r}")
            job.bind(slot)
            self.job_slots.append(slot)

    @property
    def job(self) -> Job:
        """The job running (or the last one)."""
        return self.jobs[self.index]

    @property
    def slot(self) -> AxisSlot:
        """The axis of the running job."""
        return self.job_slots[self.index]

    @property
    def all_done(self) -> bool:
        job = self.job
        return job.done and (not job.report.ok or self.index == len(self.jobs) - 1)

    def request_stop(self, k: int, result: str, message: str, period_s: float) -> int:
        """Stop in a controlled way (no quick stop): the running job stops jerk-limited and
        ends with ``result``/``message`` when the axis is at rest; no further job starts.
        Returns the number of cycles after which to give up waiting for that."""
        if self.stop_reason is None:
            self.stop_reason = (result, message)
        job = self.job
        if job.done or not job.started:
            return 2  # the next cycle ends it (see step)
        return math.ceil(job.request_stop(k, result, message) / period_s) + 1

    def hold_last_target(self) -> None:
        """The running job's axis holds the last target sent from now on (time is up)."""
        slot = self.slot
        slot.hold = slot.target

    # -- the source --------------------------------------------------------------------------
    def start(self, start: SourceStart) -> SourceStatus:
        for slot, j, d in zip(self.slots, start.joints, start.drives):
            slot.hold = slot.target = slot.scale.to_counts(j)
            slot.see(d)
        return NO_STATUS

    def step(self, ctx: CycleContext) -> SourceOutput:
        k = ctx.cycle
        for slot, d in zip(self.slots, ctx.drives):
            slot.see(d)
        if self.job.done and not self.all_done:
            self.index += 1
        job, jslot = self.job, self.slot
        if not job.started and self.stop_reason is not None and not job.done:
            # stopped (time is up) before this job could start: it does not run
            job.not_started(k, jslot.scale.from_counts(jslot.hold), *self.stop_reason)
        elif not job.started:
            job.start(k, jslot.scale.from_counts(jslot.hold))
        positions: list[float] = []
        commands: list[DriveCommand] = []
        stop = None
        for slot in self.slots:
            if slot is jslot and not job.done:
                cmd, target = job.cycle(k)
                inp = slot.reading
                job.report.targets.append(target)
                job.report.actuals.append(inp.actual if inp is not None else 0)
                if job.done:
                    slot.hold = target
                stop = job.take_stop()
            else:
                # (the axes after one that asked for the quick stop get it in this cycle
                # already; the cycle sends it to every drive from the next one on)
                cmd = DriveCommand.QUICK_STOP if stop is not None else DriveCommand.ENABLE
                target = slot.hold
            slot.target = target
            positions.append(slot.scale.from_counts(target))
            commands.append(cmd)
        return SourceOutput(AxisSetpoints(tuple(positions), tuple(commands)), NO_STATUS,
                            stop=stop, done=self.all_done, transfers=self._between(k + 1))

    def _between(self, k: int) -> Transfers:
        """The running job's SDO program before cycle ``k`` (decided when it runs)."""
        job = self.job
        if job.started and not job.done:
            yield from job.between(k)


class MotionController(Controller):
    """The cycle with a :class:`JobSequence` of ``jobs`` as its setpoint source (one boot, one
    enable for all of them)."""

    def __init__(self, cfg, transport, jobs: Job | Sequence[Job], **kw: Any) -> None:
        jobs = [jobs] if isinstance(jobs, Job) else list(jobs)
        if not jobs:
            raise MotionError("no motion job")
        tc = cfg.tracking
        slots = [AxisSlot(i, cfg.label(a.node), a.scale) for i, a in enumerate(tc.axes)]
        self.sequence = JobSequence(jobs, slots, [a.name for a in tc.axes])
        super().__init__(cfg, transport, self.sequence, **kw)
        self.ios: list[AxisIO] = []
        for job, slot in zip(jobs, self.sequence.job_slots):
            io = self.axes[slot.index]
            if job.needs_inputs and not io.inputs_mapped:
                raise MotionError(
                    f"axis {job.ax.name}: {job.kind} needs 60FDh (digital inputs) of "
                    f"'{io.node}' mapped in an enabled TPDO with transmission 1")
            self.ios.append(io)
        for slot, io in zip(slots, self.axes):
            slot.inputs_mapped, slot.probe_mapped = io.inputs_mapped, io.probe_mapped

    @property
    def jobs(self) -> list[Job]:
        return self.sequence.jobs

    @property
    def index(self) -> int:
        """The running job's (or the last one's) index in :attr:`jobs`."""
        return self.sequence.index

    @property
    def stop_reason(self) -> tuple[str, str] | None:
        return self.sequence.stop_reason

    @property
    def job(self) -> Job:
        """The job running (or the last one)."""
        return self.sequence.job

    @property
    def io(self) -> AxisIO:
        """The drive I/O of the running job's axis."""
        return self.ios[self.sequence.index]

    @property
    def all_done(self) -> bool:
        return self.sequence.all_done

    def request_stop(self, result: str, message: str) -> int:
        """:meth:`JobSequence.request_stop` now (in cycle ``k``)."""
        return self.sequence.request_stop(self.k, result, message, self.cfg.period_s)


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
                if not ctl.job.done and ctl.job.started:
                    ctl.sequence.hold_last_target()  # not an older setpoint
                ctl.job.finish(ctl.k - 1, False, "ERROR_TIMEOUT",
                               timeout + (" and not at rest after the stop" if stopping
                                          else ""))
                break
            ctl.step()  # (first the SDO transfers the running job asked for)
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
        ctl.job.finish(ctl.k, False, "ERROR", str(exc))
    job = ctl.job
    reasons = "; ".join(f"{e.source}: {e.detail}" for e in ctl.events if e.reaction)
    if ctl.failure is not None and not job.done:
        job.finish(ctl.k, False, "ERROR", str(ctl.failure))
    if not job.done:
        job.finish(ctl.k, False, "ERROR", reasons or "stopped")
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
