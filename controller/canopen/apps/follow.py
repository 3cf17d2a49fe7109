"""Conveyor following: the plain setpoint source of ``cantrack run`` and the tests.

:class:`ConveyorFollow` owns a :class:`~controller.tracking.Tracker` (softMC synchronisation,
docs/spec/tracking.md) whose master is a point of the belt (:func:`belt_frame`); it engages and
disengages at given cycles, takes a PLC's engage commands, and de-syncs when the master is
lost.  It is a :class:`~controller.canopen.master.source.SetpointSource`: pure, its setpoint
the tracker's tool location [mm, deg].
"""

from __future__ import annotations

from collections.abc import Sequence

from ...tracking import MasterEstimate, Mode, MotionState, Tracker, TrackError, TrackState
from ..config.tracking import ConveyorConfig
from ..master.source import (
    CycleContext,
    Engage,
    MasterEvent,
    SourceOutput,
    SourceStart,
    SourceStatus,
)


def belt_frame(conv: ConveyorConfig, est: MasterEstimate,
               offset: Sequence[float] = (0.0, 0.0, 0.0), angle: float = 0.0) -> MotionState:
    """The state of the belt point at travel ``est.pos`` [mm] from the conveyor's origin:
    origin + direction * s + offset [mm], velocity direction * v, acceleration direction * a,
    jerk direction * j (the conditioned master's; 0 from the estimator)."""
    d, o = conv.direction, conv.origin
    s, v, a, j = est.pos, est.vel, est.acc, est.jerk
    return MotionState((o[0] + d[0] * s + offset[0], o[1] + d[1] * s + offset[1],
                        o[2] + d[2] * s + offset[2]),
                       (d[0] * v, d[1] * v, d[2] * v), (d[0] * a, d[1] * a, d[2] * a),
                       angle, 0.0, 0.0, (d[0] * j, d[1] * j, d[2] * j))


#: the statuses of a plain tracker by (state, error): made once each, not every cycle
_STATUS: dict[tuple[TrackState, TrackError], SourceStatus] = {}


def tracker_status(tr: Tracker) -> SourceStatus:
    """The status of a source whose tracker is both the one reported and the one whose
    setpoint goes out."""
    key = (tr.state, tr.error)
    st = _STATUS.get(key)
    if st is None:
        st = _STATUS[key] = SourceStatus(tr.state, tr.imfs, tr.state, tr.imfs, tr.error)
    return st


def desync_on_master_loss(tr: Tracker, event: MasterEvent) -> None:
    """The master went silent (de-sync) or was lost (de-sync with MASTER_LOST): on the
    estimator's extrapolated master, if ``tr`` follows it."""
    if event is MasterEvent.SILENT or event is MasterEvent.LOST:
        if tr.state in (TrackState.SYNCING, TrackState.SYNCED):
            tr.disengage(TrackError.MASTER_LOST if event is MasterEvent.LOST
                         else TrackError.NONE)


class ConveyorFollow:
    """Follow the belt point that is at ``offset`` [mm] from the origin when the belt is at 0.

    ``engage_cycle``/``disengage_cycle`` count from the start of tracking; ``mode`` 3
    (absolute: go onto the point) or 5 (relative: keep the offset at engage); ``end_cycle``
    (from the start) ends the run.  A PLC's engage command (:class:`Engage`) engages (3/5) or
    de-syncs (0) the tracker; its item triggers are not taken (no item sensor).
    """

    def __init__(self, engage_cycle: int | None = None, disengage_cycle: int | None = None,
                 offset: Sequence[float] = (0.0, 0.0, 0.0), mode: Mode = Mode.ABSOLUTE,
                 end_cycle: int | None = None) -> None:
        self.engage_cycle = engage_cycle
        self.disengage_cycle = disengage_cycle
        self.offset = tuple(offset)
        self.mode = mode
        self.end_cycle = end_cycle
        self.start_cycle = 0
        self.conveyor: ConveyorConfig | None = None
        #: the tracker (made at the start, from the pose where the drives were enabled)
        self.tracker: Tracker | None = None

    def start(self, start: SourceStart) -> SourceStatus:
        self.start_cycle = start.cycle
        self.conveyor = start.tracking.conveyor
        self.tracker = Tracker(start.tracking.tracker, start.pose)
        return tracker_status(self.tracker)

    def step(self, ctx: CycleContext) -> SourceOutput:
        tr, conv = self.tracker, self.conveyor
        assert tr is not None and conv is not None, "step() before start()"
        for cmd in ctx.commands:
            if isinstance(cmd, Engage):
                if cmd.mode == Mode.OFF:
                    tr.disengage()
                else:
                    tr.engage(cmd.mode)
        desync_on_master_loss(tr, ctx.master.event)
        n = ctx.cycle - self.start_cycle
        if self.engage_cycle is not None and n == self.engage_cycle:
            tr.engage(self.mode)
        if self.disengage_cycle is not None and n == self.disengage_cycle:
            tr.disengage()
        m = belt_frame(conv, ctx.master.estimate, self.offset)
        out = tr.update(m)
        return SourceOutput(out.setpoint, tracker_status(tr), target=tr.target(m),
                            done=self.end_cycle is not None and n >= self.end_cycle)
