"""Axis jobs on the CANopen controller: homing, point-to-point moves and jog (issue 7).

The same cycle as tracking (:class:`~controller.canopen.master.cycle.Controller`: boot, SYNC, 402
enable in CSP, supervision), but while RUNNING the setpoint of one axis comes from a pure
:mod:`controller.motion` object instead of the tracker; the other axes hold where they
were enabled.  Units: mm (deg for c), s; counts only at the drive boundary
(:class:`~controller.kinematics.AxisScale`, machine coordinates).

The jobs are pure: they see their drive through its :class:`AxisSlot` (filled from the
cycle's :class:`~controller.canopen.master.source.CycleContext`: statusword, 6064h, 60FDh,
touch probe 1), return a :class:`~controller.canopen.master.source.DriveCommand` and a
target each cycle, ask for the quick stop as a value (:meth:`Job.fail`), and do their SDO
transfers as a program (:meth:`Job.between`: a generator of
:class:`~controller.canopen.master.source.SdoDownload` /
:class:`~controller.canopen.master.source.SdoUpload` that the cycle runs before the next
SYNC; a 6060h write tells the cycle the drive's mode: in homing mode statusword bit 13 is
"homing error", not a following error).

Jobs (one axis each; :class:`~controller.canopen.apps.axis_controller.JobSequence`, the
setpoint source of :class:`~controller.canopen.apps.axis_controller.MotionController`, runs
a list of them one after the other in one session -- one boot, one enable -- and
:func:`home` homes several axes that way):

* :class:`MoveJob` -- :class:`~controller.motion.PointToPoint` (Sled_Y) to a target in
  machine coordinates; the target must lie within the axis' min/max; it can be re-targeted
  while moving (:meth:`MoveJob.set_target`, e.g. from ``on_cycle``).
* :class:`JogJob` -- :class:`~controller.motion.Jog` at a speed for a time; stops
  (jerk-limited) early so that it never passes the axis' min/max.
* :class:`GotoYJob` -- :class:`~controller.motion.GotoY`: the slow-down sensor (60FDh bit
  16), the home switch (bit 2) and the limit switches (bits 0/1) come from a drive TPDO
  that maps 60FDh (transmission 1); a limit switch aborts with a clear error.  At the end
  the drive's position is set so that the latched home reads ``homing.home_offset`` (the
  homed coordinate, kept by the drive for later commands): once the drive stands on the
  last setpoint, 6098h = 37 ("current position as home"), 6060h = 6, 6064h read, 607Ch =
  home offset + (6064h - latched home), controlword bit 4 until "homing attained", then
  607Ah = 6064h and 6060h = 8 again (SDO between two cycles, as for the drive's homing);
  the report has the latched position and 6064h before/after the set.
  With ``homing.touch_probe: true`` (the home switch is also wired to the drive's
  touch-probe-1 input) the latch is the drive's instead of the setpoint of the sample in
  which the switch was read (one sample or more late at the creep speed): before the search
  (one cycle holding, state ARM_PROBE) 60B8h = 0 then 0011h (probe 1 enabled, first event,
  positive edge, source = the probe input) by SDO, checked by 60B9h (bit 0 set, bit 1
  clear); once GotoY has seen the home sensor (DOGE), 60B9h and 60BAh are taken from their
  TPDO when the drive maps both in one (event-driven: it is sent at the edge; waited for up
  to ``PROBE_PDO_WAIT_CYCLES``), else read by SDO (between two cycles, while the push-in
  runs: two round trips that must fit between SYNCs on a real bus), and 60BAh (6064h
  latched at the edge, counts)
  replaces the latch (:meth:`GotoY.refine_latch <controller.motion.GotoY.refine_latch>`).
  No positive edge stored (60B9h bit 1 clear) -- the switch is not wired to the probe
  input, or the probe is broken -- fails the homing (``ERROR_SENSOR``, the message names
  60B9h; GotoY stops jerk-limited): no silent fall-back to the less precise latch.  An axis
  that starts on the home switch backs off it and re-approaches (GotoY: BACK, SMALL_V), so
  the probe armed on the active input sees the re-approach's positive edge like any other.  The report has which latch was used (``latch_source``),
  both latches and their difference.
* :class:`DriveHomingJob` -- the drive's own homing mode: 6098h/6099h/609Ah/607Ch by SDO,
  6060h = 6, controlword bit 4 (after one cycle with it low), then statusword bit 12 (homing
  attained, with bit 10) or bit 13 (homing error) within the configured time-out; then
  607Ah = 6064h and 6060h = 8 (CSP) again, all SDO writes between two cycles.
* :class:`NoHomingJob` -- absolute encoders: the configured offset, no motion.

Every job ends in a :class:`MotionReport` (ok, result code, message, the states passed,
end position in mm and counts, time).

Ending early:

* The time limit (``max_time_s``, ``--max-time``; from the start of the session, enable
  included) is a controlled stop, not a quick stop: the running job stops jerk-limited from
  its present (p, v, a) (:meth:`PointToPoint.stop <controller.motion.PointToPoint.stop>`,
  :meth:`Jog.stop <controller.motion.Jog.stop>`, :meth:`GotoY.stop
  <controller.motion.GotoY.stop>`; the drive's homing is interrupted by controlword bit 4
  low), the brake engages, then the drives are disabled; the report has
  ``ERROR_TIMEOUT`` and where the axis stopped; a job after it does not start (its report
  says "not started").  The wait for the stop is bounded (2 (V/A + A/J) plus the brake
  and stop times).  It must be a finite number of seconds > 0.
* A limit switch (60FDh bit 0/1, when mapped) while moving into it: the drive has stopped
  itself at the switch, so the setpoint (607Ah) stops where the drive stands (6064h), not
  where the profile would have gone; then the quick stop of all drives.  GotoY stops
  jerk-limited on a limit switch (its own ``ERROR_LIMIT_SWITCH``) and then holds where the
  drive stands.  Either way the last setpoint equals the actual position: no jump when the
  drive is enabled again.
* Homing needs a ``homing:`` section: a named axis without one is an error; homing all
  axes skips (and reports as ``SKIPPED``) the axes without one.

:class:`~controller.canopen.apps.axis_controller.MotionController` runs them in the cycle;
:func:`controller.canopen.apps.axis_motion.home`, ``move``, ``jog`` are the Python API.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Any

from ...errors import CanError
from ...kinematics import AxisScale
from ...kinematics.counts import axis_unit
from ...motion import AxisConfig as MotionAxisConfig
from ...motion import (
    GotoY,
    HomingConfig,
    HomingTimeouts,
    Jog,
    MotionResult,
    PointToPoint,
)
from ...motion.profile import stopping_distance_mm
from ..config.tracking import AxisConfig, AxisHomingConfig
from ..master.events import EventKind
from ..master.source import DriveCommand, DriveView, QuickStop, SdoDownload, SdoUpload, Transfers
from ..protocol import cia402

#: 60FDh digital input bits (CiA 402-2; bit 16 is the manufacturer-specific slow-down input)
DI_NEG_LIMIT = 1 << 0
DI_POS_LIMIT = 1 << 1
DI_HOME = 1 << 2
DI_SLOW_DOWN = 1 << 16

CW_HOMING_START = 1 << 4  #: controlword bit 4 in homing mode
SW_HOMING_ATTAINED = 1 << 12  #: statusword bit 12 in homing mode
SW_HOMING_ERROR = 1 << 13  #: statusword bit 13 in homing mode


class MotionError(CanError):
    """A motion job could not be started (bad target, missing 60FDh mapping, ...)."""


class JobResult(StrEnum):
    """How a job ended (a ``str``: reports show the value).  The :class:`~controller.motion.
    MotionResult` names of the pure motion objects, and what only the CANopen job knows."""

    IDLE = "IDLE"                              #: not started (yet)
    WORKING = "WORKING"
    FINISHED = "FINISHED"                      #: done
    SKIPPED = "SKIPPED"                        #: homing all axes: this one has no homing:
    ERROR = "ERROR"
    ERROR_LIMIT_SWITCH = "ERROR_LIMIT_SWITCH"  #: a limit switch (60FDh bit 0/1)
    ERROR_TIMEOUT = "ERROR_TIMEOUT"            #: max_time_s, or a homing time-out
    ERROR_SENSOR = "ERROR_SENSOR"              #: sensors or touch probe contradict the sequence
    ERROR_ABORTED = "ERROR_ABORTED"
    ERROR_LIMIT = "ERROR_LIMIT"                #: a setpoint outside the axis' min/max
    ERROR_HOMING = "ERROR_HOMING"              #: the drive's homing mode reported an error
    ERROR_SET_POSITION = "ERROR_SET_POSITION"  #: setting the homed position (method 37) failed


@dataclass
class MotionReport:
    """The result of one job on one axis (mm/deg, counts, s)."""

    kind: str  #: "home" | "move" | "jog"
    axis: str
    ok: bool = False
    result: JobResult = JobResult.IDLE  #: (a :class:`JobResult` value is accepted too)
    message: str = ""
    states: list[str] = field(default_factory=list)  #: states passed, in order
    start_mm: float = math.nan
    end_mm: float = math.nan  #: actual position at the end (machine coordinate)
    end_counts: int = 0  #: 6064h at the end
    setpoint_mm: float = math.nan  #: the last setpoint (exact end position of the profile)
    home_offset_mm: float | None = None  #: homing: the raw position of the axis' 0
    #: GotoY: where home was latched, in the coordinate before the position was set [mm]
    latched_mm: float | None = None
    #: GotoY: the drive's position (6064h) set at the end (method 37, 607Ch): before and
    #: after [counts] / [mm]; None if it was not set
    set_before_counts: int | None = None
    set_after_counts: int | None = None
    set_before_mm: float | None = None
    set_after_mm: float | None = None
    #: GotoY: which latch is home: "sensor" (setpoint of the sample DNP was read) or
    #: "touch probe" (the drive's 60BAh); None if homing did not latch
    latch_source: str | None = None
    #: GotoY: the sensor latch [mm] (also when the touch probe's replaced it)
    sensor_latched_mm: float | None = None
    #: GotoY with touch_probe: 60BAh [counts] and in mm; None if not read / not stored
    probe_latched_counts: int | None = None
    probe_latched_mm: float | None = None
    #: how 60B9h/60BAh were read: "TPDO" (mapped, event-driven) or "SDO"; None if not read
    probe_source: str | None = None
    #: GotoY with touch_probe: 60BAh - the sensor latch in counts (None unless both)
    latch_difference_counts: int | None = None
    #: GotoY with touch_probe: why the sensor latch was kept (e.g. started on the switch)
    latch_note: str = ""
    time_s: float = 0.0  #: from the job's start to its end
    cycles: int = 0
    targets: list[int] = field(default_factory=list)  #: 607Ah sent each cycle [counts]
    actuals: list[int] = field(default_factory=list)  #: 6064h received each cycle [counts]
    inputs: list[int] = field(default_factory=list)  #: 60FDh each cycle (homing)

    def __post_init__(self) -> None:
        self.result = JobResult(self.result)

    @property
    def latch_difference_mm(self) -> float | None:
        """Touch-probe latch - sensor latch [mm] (None unless both exist)."""
        if self.probe_latched_mm is None or self.sensor_latched_mm is None:
            return None
        return self.probe_latched_mm - self.sensor_latched_mm

    @property
    def homed_end_mm(self) -> float | None:
        """The end position in the homed coordinate (raw - home offset)."""
        return None if self.home_offset_mm is None else self.end_mm - self.home_offset_mm

    def summary(self) -> str:
        unit = axis_unit(self.axis)
        if self.result is JobResult.SKIPPED:
            return f"{self.kind} {self.axis}: SKIPPED: {self.message}"
        lines = [f"{self.kind} {self.axis}: {'OK' if self.ok else 'FAILED'} ({self.result})"
                 + (f": {self.message}" if self.message else ""),
                 f"  states:   {' -> '.join(self.states) if self.states else '-'}",
                 f"  start:    {self.start_mm:.4f} {unit}",
                 (f"  end:      {self.end_mm:.4f} {unit} ({self.end_counts} counts), "
                  f"setpoint {self.setpoint_mm:.4f} {unit}"),
                 f"  time:     {self.time_s:.3f} s ({self.cycles} cycles)"]
        if self.set_after_counts is not None:
            lines.append(f"  position set: {self.set_before_mm:.4f} -> {self.set_after_mm:.4f} "
                         f"{unit} ({self.set_before_counts} -> {self.set_after_counts} counts; "
                         f"home latched at {self.latched_mm:.4f} {unit})")
        if self.latch_source is not None:
            line = f"  latch:    {self.latch_source}"
            if self.latch_difference_mm is not None:
                diff = self.latch_difference_mm
                line += (f" {self.probe_latched_mm:.4f} {unit} (60BAh "
                         f"{self.probe_latched_counts} counts); sensor "
                         f"{self.sensor_latched_mm:.4f} {unit}; difference {diff:+.4f} {unit}"
                         f" ({self.latch_difference_counts:+d} counts)")
            elif self.sensor_latched_mm is not None:
                line += f" {self.sensor_latched_mm:.4f} {unit}"
            if self.latch_note:
                line += f" ({self.latch_note})"
            lines.append(line)
        if self.home_offset_mm is not None:
            lines.append(f"  home offset: {self.home_offset_mm:.4f} {unit} (end at "
                         f"{self.homed_end_mm:.4f} {unit} in homed coordinates)")
        return "\n".join(lines)


def _motion_axis_config(ax: AxisConfig, period_s: float) -> MotionAxisConfig:
    m = ax.motion
    return MotionAxisConfig(m.limits, period_s, m.brake_release_s,
                            m.brake_engage_s, m.stop_time_s)


@dataclass(frozen=True, slots=True)
class Reading:
    """The drive's last TPDO: 6041h statusword and 6064h position actual [counts]."""

    statusword: int
    actual: int


@dataclass
class AxisSlot:
    """One axis as the job sequence keeps it: where it holds and the last target sent
    [counts], what its drive's TPDOs said this cycle (``reading``: None before the first;
    ``di`` 60FDh, 0 when not mapped; ``probe`` (60B9h, 60BAh)), and what the drive maps
    (60FDh in a TPDO of transmission 1; 60B9h and 60BAh in one TPDO)."""

    index: int  #: in ``.tracking.axes``
    label: str  #: the drive's, for events
    scale: AxisScale
    inputs_mapped: bool = False
    probe_mapped: bool = False
    hold: int = 0
    target: int = 0
    reading: Reading | None = None
    di: int = 0
    probe: tuple[int, int] | None = None

    def see(self, d: DriveView) -> None:
        """This cycle's view of the drive (positions back to counts: exact, they came from
        counts)."""
        if d.actual is not None:
            self.reading = Reading(d.statusword, self.scale.to_counts(d.actual))
        self.di = d.inputs if d.inputs is not None else 0
        self.probe = d.probe


def _value(v: int | None) -> int:
    """The value an :class:`SdoUpload` brought back (the cycle always sends one)."""
    if v is None:
        raise MotionError("an SDO upload without a value")
    return v


def _no_transfers() -> Transfers:
    return
    yield  # (a generator without transfers)


class Job:
    """One axis' motion, a pure part of the job sequence's setpoint source
    (:class:`~controller.canopen.apps.axis_controller.JobSequence`): ``cycle()`` is called
    once per RUNNING cycle and returns (:class:`DriveCommand`, target counts) for the axis'
    RPDO; ``between()`` is the SDO program to run before the next cycle (it yields
    :class:`SdoDownload`/:class:`SdoUpload` values, the cycle does the transfers)."""

    kind = "?"

    def __init__(self, ax: AxisConfig, period_s: float) -> None:
        self.ax = ax
        self.period_s = period_s
        self.report = MotionReport(self.kind, ax.name)
        self.done = False
        self.slot: AxisSlot | None = None
        self.started = False
        self._k0 = 0
        self._stop: QuickStop | None = None

    #: GotoY needs 60FDh; moves and jogs use it (limit switches) when it is mapped
    needs_inputs = False

    def bind(self, slot: AxisSlot) -> None:
        """The axis the job moves (the sequence's slot of it)."""
        self.slot = slot

    @property
    def di(self) -> int:
        """60FDh of this cycle (0 when not mapped)."""
        return self.slot.di if self.slot is not None else 0

    def _slot(self) -> AxisSlot:
        if self.slot is None:
            raise MotionError(f"axis {self.ax.name}: the {self.kind} job is not bound to an "
                              "axis (JobSequence binds it)")
        return self.slot

    def _input(self) -> Reading | None:
        """The drive's last TPDO (None before the first)."""
        return self._slot().reading

    def start(self, k: int, actual_mm: float) -> None:
        self.started = True
        self._k0 = k
        self.report.start_mm = actual_mm

    def not_started(self, k: int, start_mm: float, result: str, message: str) -> None:
        """The session is stopping before the job could start (cycle ``k``): it ends without
        running."""
        self._k0 = k
        self.report.start_mm = start_mm
        self.finish(k, False, result, f"{message}: not started")

    def between(self, k: int) -> Transfers:
        """The SDO transfers before cycle ``k`` (a generator, run lazily by the cycle; none
        here)."""
        return _no_transfers()

    def cycle(self, k: int) -> tuple[DriveCommand, int]:
        raise NotImplementedError

    def request_stop(self, k: int, result: str, message: str) -> float:
        """Stop the running job in a controlled way (e.g. ``--max-time`` is up): the job
        then ends by itself with ``result``/``message`` once the axis is at rest.  Returns
        an upper bound [s] of the time that takes (0: the job has been finished here)."""
        self.finish(k, False, result, message)
        return 0.0

    def progress(self) -> str:
        """Extra text for the progress line (the final target, the jog speed ...)."""
        return ""

    def take_stop(self) -> QuickStop | None:
        """The quick stop of all drives this cycle's :meth:`cycle` asked for (once)."""
        stop, self._stop = self._stop, None
        return stop

    # -- helpers ----------------------------------------------------------------------------
    def state(self, name: str) -> None:
        if not self.report.states or self.report.states[-1] != name:
            self.report.states.append(name)

    def fail(self, k: int, message: str, result: str = "ERROR_LIMIT") -> None:
        """A limit: the quick stop of all drives (asked of the cycle), the job fails."""
        label = self.slot.label if self.slot is not None else self.ax.name
        self._stop = QuickStop(label, EventKind.LIMIT, message)
        self.finish(k, False, result, message)

    def finish(self, k: int, ok: bool, result: str, message: str = "") -> None:
        if self.done:
            return
        self.done = True
        r = self.report
        r.ok, r.result, r.message = ok, JobResult(result), message
        r.cycles = k - self._k0 + 1
        r.time_s = r.cycles * self.period_s


class _SetpointJob(Job):
    """Jobs whose setpoint [mm] comes from a motion object each cycle."""

    def __init__(self, ax: AxisConfig, period_s: float) -> None:
        super().__init__(ax, period_s)
        self.obj: Any = None
        self.setpoint_mm = 0.0
        self._error: Any = None
        #: (result, message) of a stop requested from outside (:meth:`request_stop`)
        self._abort: tuple[str, str] | None = None

    def output(self, k: int):
        raise NotImplementedError

    def cycle(self, k: int) -> tuple[DriveCommand, int]:
        out = self.output(k)
        self.state(out.state.name)
        self.setpoint_mm = out.position_mm
        self.report.setpoint_mm = out.position_mm
        sc = self.ax.scale
        inp = self._input()
        if self.checks_limits and self.di & (DI_NEG_LIMIT | DI_POS_LIMIT):
            # moving into an active limit switch (60FDh bit 0 / 1): abort.  The drive has
            # stopped itself at the switch (it refuses to move into it): the setpoint stream
            # stops where the drive stands, not where the profile would have been
            v = out.velocity_mm_s * sc.sign
            which = ("negative", 0) if self.di & DI_NEG_LIMIT and v < 0 else \
                ("positive", 1) if self.di & DI_POS_LIMIT and v > 0 else None
            if which is not None:
                self.report.inputs.append(self.di)
                actual = inp.actual if inp is not None else self._slot().target
                self.report.setpoint_mm = sc.from_counts(actual)
                self.fail(k, f"{which[0]} limit switch (60FDh bit {which[1]}) active at "
                                f"{sc.from_counts(actual):.4f} while moving",
                             result="ERROR_LIMIT_SWITCH")
                return DriveCommand.QUICK_STOP, actual
        if self.checks_limits and not sc.min <= out.position_mm <= sc.max:
            self.report.setpoint_mm = sc.from_counts(self._slot().target)  # the last one sent
            self.fail(k, f"setpoint {out.position_mm:.4f} outside [{sc.min:g}, {sc.max:g}]")
            return DriveCommand.QUICK_STOP, self._slot().target
        if out.result < 0 and self._error is None:
            self._error = out  # the motion object stops (ABORT, brake): follow it to rest
        target = sc.to_counts(out.position_mm)
        if out.result is not MotionResult.WORKING and out.state.name in ("STOP", "READY"):
            first = self._error or out
            if self._abort is not None:
                unit = self.ax.scale.unit
                result, message = self._abort
                self.finish(k, False, result,
                            f"{message}: stopped (jerk-limited) at {out.position_mm:.4f} {unit}")
            else:
                if first.result is MotionResult.ERROR_LIMIT_SWITCH and inp is not None:
                    # the drive stopped itself at the switch while the stop profile went
                    # on: hold where the drive stands (no jump on the next enable)
                    target = inp.actual
                    self.report.setpoint_mm = sc.from_counts(target)
                self.finish(k, first.result is MotionResult.FINISHED,
                            first.result.name, first.message)
            self.ended(out)
        return DriveCommand.ENABLE, target

    def request_stop(self, k: int, result: str, message: str) -> float:
        if self.obj is None:
            return super().request_stop(k, result, message)
        if self._abort is None and self._error is None:
            self._abort = (result, message)
            self.obj.stop()  # jerk-limited stop from the present (p, v, a), then the brake
        m = self.ax.motion
        # an upper bound: the longest stop (from full speed and full acceleration), the
        # brake and the stop time, and some cycles of margin
        stop_s = 2.0 * (m.limits.vel / m.limits.acc + m.limits.acc / m.limits.jerk)
        return stop_s + m.brake_engage_s + m.stop_time_s + 20 * self.period_s

    checks_limits = True

    def ended(self, out) -> None:
        pass


class MoveJob(_SetpointJob):
    """Point-to-point move (Sled_Y) to ``target_mm`` (machine coordinate)."""

    kind = "move"

    def __init__(self, ax: AxisConfig, period_s: float, target_mm: float) -> None:
        super().__init__(ax, period_s)
        self._check(target_mm)
        self.target_mm = float(target_mm)
        self.obj: PointToPoint | None = None

    def _check(self, target_mm: float) -> None:
        sc = self.ax.scale
        if not (math.isfinite(target_mm) and sc.min <= target_mm <= sc.max):
            raise MotionError(f"axis {self.ax.name}: target {target_mm} outside the axis "
                              f"limits [{sc.min:g}, {sc.max:g}]")

    def start(self, k: int, actual_mm: float) -> None:
        super().start(k, actual_mm)
        self.obj = PointToPoint(_motion_axis_config(self.ax, self.period_s), actual_mm)
        self.obj.set_target(self.target_mm)

    def set_target(self, target_mm: float) -> None:
        """Re-target (also while moving: re-planned from the present p, v, a)."""
        self._check(target_mm)
        if self._abort is not None or self.done:
            return  # stopping (time is up) or done: no new target
        self.target_mm = float(target_mm)
        if self.obj is not None:
            self.obj.set_target(self.target_mm)

    def output(self, k: int):
        return self.obj.update()

    def progress(self) -> str:
        return f"target {self.target_mm:10.4f}"


class JogJob(_SetpointJob):
    """Jog at ``speed`` [mm/s] for ``time_s``, then stop; never past min/max."""

    kind = "jog"

    def __init__(self, ax: AxisConfig, period_s: float, speed: float, time_s: float) -> None:
        super().__init__(ax, period_s)
        if not math.isfinite(speed) or abs(speed) > ax.motion.limits.vel or speed == 0:
            raise MotionError(f"axis {ax.name}: jog speed {speed} must be non-zero and "
                              f"within +-{ax.motion.limits.vel:g} (motion.vel)")
        if not (math.isfinite(time_s) and time_s > 0):
            raise MotionError(f"jog time {time_s} must be a finite number of seconds > 0")
        self.speed = float(speed)
        self.n_run = max(1, round(time_s / period_s))
        self.obj: Jog | None = None
        self.soft_limit = False

    def start(self, k: int, actual_mm: float) -> None:
        super().start(k, actual_mm)
        self.obj = Jog(_motion_axis_config(self.ax, self.period_s), actual_mm)
        self.obj.set_velocity(self.speed)

    def output(self, k: int):
        jog = self.obj
        if k - self._k0 == self.n_run and jog.velocity_command_mm_s != 0.0:
            jog.stop()
        kin = jog.kinematic_state
        if jog.velocity_command_mm_s != 0.0 and kin.velocity_mm_s != 0.0:
            # stop early enough: where would a stop that starts after the next sample end?
            v = kin.velocity_mm_s
            ahead = kin.position_mm + 2.0 * abs(v) * self.period_s * math.copysign(1.0, v)
            reach = stopping_distance_mm(kin, jog.config.limits)
            end = ahead + reach if v > 0 else ahead - abs(reach)
            sc = self.ax.scale
            if not sc.min <= end <= sc.max:
                jog.stop()
                self.soft_limit = True
        return jog.update()

    def ended(self, out) -> None:
        if self.soft_limit and self.report.ok:
            self.report.message = "stopped early at the axis limit"

    def progress(self) -> str:
        return f"speed {self.speed:+g}"


class GotoYJob(_SetpointJob):
    """Sensor homing (GotoY) with the drive's 60FDh inputs."""

    kind = "home"
    checks_limits = False  # the position is not known before homing

    def __init__(self, ax: AxisConfig, period_s: float) -> None:
        super().__init__(ax, period_s)
        h = ax.homing or AxisHomingConfig()
        m = ax.motion
        self.config = HomingConfig(
            m.limits, period_s, h.search_vel, h.creep_vel,
            h.push_in_counts, ax.scale.counts_per_unit, h.back_off, h.direction,
            m.brake_release_s, m.brake_engage_s,
            HomingTimeouts(total_s=h.timeout_s, **dict(h.state_timeouts)))
        self.obj: GotoY | None = None
        self.touch_probe = h.touch_probe
        #: arm (touch probe, holding) | gotoy | settle | setup | low | run | back | csp
        self.phase = "arm" if self.touch_probe else "gotoy"
        self._probe_read = False
        self._probe_waits = 0

    needs_inputs = True

    #: cycles to wait for the probe's event TPDO after the home sensor was seen, before the
    #: SDO read (the TPDO is sent at the edge, before the SYNC TPDO with 60FDh bit 2)
    PROBE_PDO_WAIT_CYCLES = 5

    #: 60B8h: probe 1 enabled (bit 0), first event (bit 1 = 0), trigger = the probe-1
    #: input (bits 2-3 = 00), latch on the positive edge (bit 4)
    PROBE_FUNCTION = 0x0011
    PROBE_ENABLED = 0x0001  #: 60B9h bit 0: probe 1 enabled
    PROBE_STORED = 0x0002  #: 60B9h bit 1: positive-edge value stored in 60BAh

    def start(self, k: int, actual_mm: float) -> None:
        super().start(k, actual_mm)
        self.obj = GotoY(self.config, actual_mm)
        self.obj.start()

    def output(self, k: int):
        di = self.di
        self.report.inputs.append(di)
        return self.obj.update(bool(di & DI_SLOW_DOWN), bool(di & DI_HOME),
                               limit_neg=bool(di & DI_NEG_LIMIT),
                               limit_pos=bool(di & DI_POS_LIMIT))

    def ended(self, out) -> None:
        r = self.report
        r.home_offset_mm = out.home_offset_mm
        r.latched_mm = out.home_offset_mm
        r.sensor_latched_mm = self.obj.sensor_latched_mm if self.obj is not None else None
        if out.home_offset_mm is not None:
            r.latch_source = "touch probe" if r.probe_latched_mm is not None else "sensor"

    # -- touch probe 1 (homing.touch_probe) ---------------------------------------------------
    def _arm_probe(self) -> Transfers:
        """60B8h = 0 (disarm, clears 60B9h), then the function: a fresh single shot (the
        cycle then forgets what the probe's TPDO said before this arming)."""
        i = self._slot().index
        yield SdoDownload(i, 0x60B8, 0, (0).to_bytes(2, "little"))
        yield SdoDownload(i, 0x60B8, 0, self.PROBE_FUNCTION.to_bytes(2, "little"))
        status = _value((yield SdoUpload(i, 0x60B9, 0)))
        if not status & self.PROBE_ENABLED or status & self.PROBE_STORED:
            raise MotionError(
                f"axis {self.ax.name}: touch probe 1 not armed: 60B9h = {status:04X}h after "
                f"60B8h = {self.PROBE_FUNCTION:04X}h (bit 0 'enabled' expected, bit 1 "
                f"'stored' clear)")

    def _read_probe(self) -> Transfers:
        """Home has been seen (DOGE): the drive's latch replaces the sensor's."""
        self._probe_read = True
        obj, r, sc = self.obj, self.report, self.ax.scale
        assert obj is not None and obj.sensor_latched_mm is not None  # (GotoY has latched)
        sensor_mm = obj.sensor_latched_mm
        unit = self.ax.scale.unit
        slot = self._slot()
        pdo = slot.probe
        counts: int | None
        if pdo is not None and pdo[0] & self.PROBE_STORED:
            # the probe's TPDO (60B9h, 60BAh) came with the edge: no SDO during the motion
            status, counts = pdo
            r.probe_source = "TPDO"
        elif slot.probe_mapped and self._probe_waits < self.PROBE_PDO_WAIT_CYCLES:
            self._probe_waits += 1
            self._probe_read = False  # again after the next cycle
            return
        else:
            try:
                status = _value((yield SdoUpload(slot.index, 0x60B9, 0)))
                counts = _value((yield SdoUpload(slot.index, 0x60BA, 0, signed=True))) \
                    if status & self.PROBE_STORED else None
            except CanError as exc:
                self._probe_failed(f"touch probe 1 could not be read: {exc}")
                return
            r.probe_source = "SDO"
        if counts is None:
            self._probe_failed(
                f"touch probe 1 stored no positive edge (60B9h = {status:04X}h, bit 1 clear) "
                f"although the home sensor (60FDh bit 2) was seen at "
                f"{sensor_mm:.4f} {unit}: is the home switch wired to the "
                f"drive's touch-probe-1 input (homing.touch_probe)?")
            return
        r.probe_latched_counts = counts
        r.probe_latched_mm = sc.from_counts(counts)
        r.latch_difference_counts = counts - sc.to_counts(sensor_mm)
        obj.refine_latch(r.probe_latched_mm)

    def _probe_failed(self, message: str) -> None:
        if self._abort is None and self._error is None:
            self._abort = ("ERROR_SENSOR", message)
            self.obj.stop()  # jerk-limited from the push-in, then the brake

    # -- the end: set the drive's position (homing mode, method 37) ---------------------------
    #: 6098h method "current position as home" (37; 35 is its older number, same meaning)
    SET_METHOD = 37
    #: cycles to wait for the drive to stand on the last setpoint before the set
    SETTLE_CYCLES_MAX = 50
    #: time-out for "homing attained" of method 37 [s]
    SET_TIMEOUT_S = 1.0

    phase = "gotoy"  #: gotoy | settle | setup | low | run | back | csp
    _pending: tuple[str, str] = ("", "")
    _expected = 0
    _hold = 0
    _stable = 0
    _k_set = 0
    #: why setting the drive's position failed (None: it did not)
    _set_error: str | None = None

    def finish(self, k: int, ok: bool, result: str, message: str = "") -> None:
        if ok and self.phase == "gotoy":
            # GotoY finished: the job ends after the drive's position has been set
            self.phase = "settle"
            self._pending = (result, message)
            self._k_set = k
            return
        super().finish(k, ok, result, message)

    def request_stop(self, k: int, result: str, message: str) -> float:
        if self.phase == "arm":  # not moved yet
            self.phase = "gotoy"
            self.report.setpoint_mm = self.report.start_mm
            self.finish(k, False, result, f"{message}: not started")
            return 0.0
        if self.phase == "gotoy":
            return super().request_stop(k, result, message)
        # GotoY is done and the axis at rest: the drive's position is being set (no
        # motion); let that end (bounded by its own time-outs)
        return (self.SETTLE_CYCLES_MAX + 20) * self.period_s + self.SET_TIMEOUT_S

    def _fail_set(self, k: int, message: str) -> None:
        self.phase = "csp"
        super().finish(k, False, "ERROR_SET_POSITION", message)

    def between(self, k: int) -> Transfers:
        if self.done:
            return
        if self.phase == "arm":
            self.phase = "gotoy"
            try:
                yield from self._arm_probe()
            except CanError as exc:  # at rest, nothing moved: the job ends here
                self.finish(k, False, "ERROR_SENSOR", str(exc))
            return
        if self.phase == "gotoy":
            obj = self.obj
            if (self.touch_probe and not self._probe_read and obj is not None
                    and obj.state in GotoY.REFINE_STATES and obj.latched_mm is not None
                    and self._abort is None and self._error is None):
                yield from self._read_probe()
            return
        if self.phase not in ("setup", "back"):
            return
        i, sc, r = self._slot().index, self.ax.scale, self.report
        if self.phase == "setup":
            h = self.ax.homing or AxisHomingConfig()
            yield SdoDownload(i, 0x6098, 0, self.SET_METHOD.to_bytes(1, "little", signed=True))
            yield SdoDownload(i, 0x6060, 0, bytes([cia402.MODE_HM]))
            # in homing mode (not started) the drive holds: read where it stands now
            before = _value((yield SdoUpload(i, 0x6064, 0, signed=True)))
            before_mm = sc.from_counts(before)
            after_mm = h.home_offset + (before_mm - r.latched_mm)
            self._expected = sc.to_counts(after_mm)
            yield SdoDownload(i, 0x607C, 0, self._expected.to_bytes(4, "little", signed=True))
            r.set_before_counts, r.set_before_mm = before, before_mm
            self.phase = "low"
        else:  # back
            actual = _value((yield SdoUpload(i, 0x6064, 0, signed=True)))
            yield SdoDownload(i, 0x607A, 0, actual.to_bytes(4, "little", signed=True))
            yield SdoDownload(i, 0x6060, 0, bytes([cia402.MODE_CSP]))
            self._slot().hold = actual
            r.set_after_counts, r.set_after_mm = actual, sc.from_counts(actual)
            self.phase = "csp"
            self.state("CSP")

    def cycle(self, k: int) -> tuple[DriveCommand, int]:
        if self.phase == "arm":  # hold while touch probe 1 is armed (SDO, after this cycle)
            self.state("ARM_PROBE")
            self._hold = self._slot().hold
            self.report.setpoint_mm = self.ax.scale.from_counts(self._hold)
            return DriveCommand.ENABLE, self._hold
        if self.phase == "gotoy":
            out = super().cycle(k)
            self._hold = out[1]
            return out
        io = self._slot()
        inp = self._input()
        actual = inp.actual if inp is not None else self._hold
        if self.phase == "settle":
            self.state("SET_POSITION")
            self._stable = self._stable + 1 if actual == self._hold else 0
            if self._stable >= 2 or k - self._k_set >= self.SETTLE_CYCLES_MAX:
                self.phase = "setup"  # the SDO transfers follow before the next cycle
            return DriveCommand.ENABLE, self._hold
        if self.phase == "setup":
            return DriveCommand.ENABLE, self._hold
        if self.phase == "low":  # one cycle with bit 4 low, then the rising edge
            self.phase = "run"
            self._k_start = k
            return DriveCommand.ENABLE, actual
        if self.phase == "run":
            sw = inp.statusword if inp is not None else 0
            if sw & SW_HOMING_ERROR:
                self._set_error = (f"the drive reports a homing error (statusword {sw:04X}h "
                                   f"bit 13) with method {self.SET_METHOD}")
            elif sw & SW_HOMING_ATTAINED and sw & cia402.SW_TARGET_REACHED:
                self._set_error = None
            elif (k - self._k_start) * self.period_s > self.SET_TIMEOUT_S:
                self._set_error = (f"method {self.SET_METHOD} not attained within "
                                   f"{self.SET_TIMEOUT_S:g} s (statusword {sw:04X}h)")
            else:
                return DriveCommand.HOMING_START, actual
            self.phase = "back"
            return DriveCommand.ENABLE, actual
        if self.phase == "back":
            return DriveCommand.ENABLE, actual
        # csp: back in CSP, holding where the drive stands (the new coordinate)
        r = self.report
        r.setpoint_mm = self.ax.scale.from_counts(io.hold)
        err = self._set_error
        tol = max(2, round(0.01 * self.ax.scale.counts_per_unit))
        if err is None and abs(r.set_after_counts - self._expected) > tol:
            err = (f"6064h reads {r.set_after_counts} counts after the set, "
                   f"{self._expected} expected (607Ch)")
        if err is not None:
            self._fail_set(k, err)
        else:
            r.home_offset_mm = 0.0  # the drive's position is now the homed coordinate
            super().finish(k, True, *self._pending)
        return DriveCommand.ENABLE, io.hold


class NoHomingJob(Job):
    kind = "home"

    def cycle(self, k: int) -> tuple[DriveCommand, int]:
        self.state("NONE")
        h = self.ax.homing or AxisHomingConfig(method="none")
        self.report.home_offset_mm = h.home_offset
        self.report.setpoint_mm = self.report.start_mm
        self.finish(k, True, MotionResult.FINISHED.name, "absolute encoder: no homing")
        return DriveCommand.ENABLE, self._slot().hold


class DriveHomingJob(Job):
    """The drive's own homing mode (6060h = 6)."""

    kind = "home"

    def __init__(self, ax: AxisConfig, period_s: float) -> None:
        super().__init__(ax, period_s)
        self.h = ax.homing or AxisHomingConfig(method="drive")
        self.phase = "setup"
        self._k_start = 0
        self._error: tuple[str, str] | None = None
        self._stop_req: tuple[str, str] | None = None


    def _u32(self, mm: float) -> bytes:
        return max(1, round(mm * self.ax.scale.counts_per_unit)).to_bytes(4, "little")

    def request_stop(self, k: int, result: str, message: str) -> float:
        # the drive runs the homing: controlword bit 4 low interrupts it (the drive stops
        # with its own ramp), then back to CSP on the position it stands
        if self._stop_req is None:
            self._stop_req = (result, message)
        return 1.0 + 20 * self.period_s

    def between(self, k: int) -> Transfers:
        if not self.started or (self._stop_req is not None and self.phase == "setup"):
            return
        i = self._slot().index
        if self.phase == "setup":
            h = self.h
            yield SdoDownload(i, 0x6098, 0, h.drive_method.to_bytes(1, "little", signed=True))
            if h.switch_vel is not None:
                yield SdoDownload(i, 0x6099, 1, self._u32(h.switch_vel))
            if h.zero_vel is not None:
                yield SdoDownload(i, 0x6099, 2, self._u32(h.zero_vel))
            if h.drive_acc is not None:
                yield SdoDownload(i, 0x609A, 0, self._u32(h.drive_acc))
            offset = round(h.home_offset * self.ax.scale.counts_per_unit)
            yield SdoDownload(i, 0x607C, 0, offset.to_bytes(4, "little", signed=True))
            yield SdoDownload(i, 0x6060, 0, bytes([cia402.MODE_HM]))
            self.phase = "low"
            self.state("SETUP")
        elif self.phase == "back":
            actual = _value((yield SdoUpload(i, 0x6064, 0, signed=True)))
            yield SdoDownload(i, 0x607A, 0, actual.to_bytes(4, "little", signed=True))
            yield SdoDownload(i, 0x6060, 0, bytes([cia402.MODE_CSP]))
            self._slot().hold = actual
            self.phase = "csp"
            self.state("CSP")

    def cycle(self, k: int) -> tuple[DriveCommand, int]:
        io = self._slot()
        inp = self._input()
        actual = inp.actual if inp is not None else io.target
        if self.phase == "setup":
            if self._stop_req is not None:  # not in homing mode yet: nothing to undo
                self.report.setpoint_mm = self.ax.scale.from_counts(actual)
                self.finish(k, False, *self._stop_req)
            return DriveCommand.ENABLE, actual
        if self._stop_req is not None and self.phase in ("low", "run"):
            self._error = self._stop_req
            self.phase = "back"
            return DriveCommand.ENABLE, actual  # bit 4 low: interrupts the homing
        if self.phase == "low":
            self.phase = "run"
            self._k_start = k
            return DriveCommand.ENABLE, actual
        if self.phase == "run":
            self.state("HOMING")
            sw = inp.statusword if inp is not None else 0
            if sw & SW_HOMING_ERROR:
                self._error = ("ERROR_HOMING",
                               (f"the drive reports a homing error (statusword {sw:04X}h "
                                f"bit 13), method {self.h.drive_method}"))
            elif sw & SW_HOMING_ATTAINED and sw & cia402.SW_TARGET_REACHED:
                self.state("ATTAINED")
            elif (k - self._k_start) * self.period_s > self.h.timeout_s:
                self._error = ("ERROR_TIMEOUT",
                               (f"homing not attained within {self.h.timeout_s:g} s (method "
                                f"{self.h.drive_method}, statusword {sw:04X}h)"))
            else:
                return DriveCommand.HOMING_START, actual
            self.phase = "back"
            return DriveCommand.ENABLE, actual  # bit 4 low: ends (or interrupts) the homing
        if self.phase == "back":
            return DriveCommand.ENABLE, actual
        # phase csp: back in CSP, holding
        self.report.setpoint_mm = self.ax.scale.from_counts(io.hold)
        if self._error is None:
            self.report.home_offset_mm = 0.0  # the drive's position is now homed
            self.finish(k, True, MotionResult.FINISHED.name,
                        f"drive homing method {self.h.drive_method} attained")
        elif self._error is self._stop_req:
            unit = self.ax.scale.unit
            result, message = self._error
            self.finish(k, False, result,
                        f"{message}: the drive's homing interrupted (controlword bit 4 low), "
                        f"stopped at {self.report.setpoint_mm:.4f} {unit}")
        else:
            self.finish(k, False, *self._error)
        return DriveCommand.ENABLE, io.hold


def make_home_job(ax: AxisConfig, period_s: float) -> Job:
    """The job for the axis' configured homing method; an axis without a ``homing:``
    section is an error (no default method: homing moves the axis)."""
    if ax.homing is None:
        raise MotionError(f"axis {ax.name} (node {ax.node!r}) has no homing: section")
    method = ax.homing.method
    if method == "none":
        return NoHomingJob(ax, period_s)
    if method == "drive":
        return DriveHomingJob(ax, period_s)
    return GotoYJob(ax, period_s)
