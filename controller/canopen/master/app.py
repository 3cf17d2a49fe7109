"""What the controller tracks: the application interface and the plain conveyor follower.

The cycle asks its application, once per cycle while RUNNING and before
``Tracker.update``, for the master state of the next SYNC; the application may call
``ctl.tracker.engage()`` / ``disengage()`` then (they act in the same update).  The demo's
pick-and-place sequence (:mod:`controller.canopen.apps.demo`) is one application;
:class:`ConveyorFollow` (follow a point of the belt, engage/disengage at given times) is
the one ``cantrack run`` and the tests use.

Everything the cycle and the controller's own node (:mod:`.plc_node`) read of an application
is declared here: :meth:`Application.status` returns a typed :class:`AppStatus` after each
cycle, and a PLC's engage command and item trigger go to :meth:`Application.engage` and
:meth:`Application.trigger` (no attribute lookups on the application).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol

from ...tracking import Imfs, MasterEstimate, Mode, MotionState, TrackState

if TYPE_CHECKING:
    from ..config.tracking import ConveyorConfig
    from .cycle import Controller


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


@dataclass(frozen=True, slots=True)
class AppStatus:
    """What an application reports after a cycle (read by the cycle record and the PLC node).

    ``track_state``/``imfs``: the application's own belt tracking (the demo's robot group);
    None: the controller's tracker is the one (its state is reported).  ``items_detected``:
    items seen by the application's item sensor so far (None: it has none; the PLC node then
    counts its own triggers); ``items_missed``: items missed so far; ``triggers_dropped``:
    item triggers dropped by a full trigger buffer (``.plc.trigger_overflow``);
    ``items_ignored``: items of a type that is not tracked."""

    track_state: TrackState | None = None
    imfs: Imfs | None = None
    items_detected: int | None = None
    items_missed: int = 0
    triggers_dropped: int = 0
    #: items of a type the application does not track (2016h)
    items_ignored: int = 0


#: the status of an application without tracking of its own and without items
NO_STATUS = AppStatus()


class Application(Protocol):
    def start(self, ctl: Controller, cycle: int) -> None:
        """Tracking begins (all drives enabled, master ready)."""

    def update(self, ctl: Controller, cycle: int, belt: MasterEstimate) -> MotionState:
        """The master state [mm, deg] at the next SYNC; may engage/disengage the tracker."""

    def master_lost(self, ctl: Controller, cycle: int) -> None:
        """The encoder went silent; the controller has started the de-sync."""

    def done(self, ctl: Controller, cycle: int) -> bool:
        """True when the run is over."""

    def status(self) -> AppStatus:
        """The application's status after the last cycle."""

    def engage(self, ctl: Controller, mode: Mode) -> bool:
        """A PLC's engage command (2005h): True if the application took it, False to let the
        controller's tracker engage (``mode`` 3/5) or disengage (0)."""

    def trigger(self, t_ns: int, item_type: int = 0) -> bool:
        """A PLC's item trigger at ``t_ns`` [ns, controller clock] for an item of
        ``item_type`` (2014h): True if the application took it as an item edge, False if it
        has no item sensor."""

    def track_types(self, types: frozenset[int] | None) -> bool:
        """A PLC's tracked item types (2015h; None: every type): True if the application
        tracks only those from now on, False if it has no items to classify."""


class ConveyorFollow:
    """Follow the belt point that is at ``offset`` from the origin when the belt is at 0.

    ``engage_cycle``/``disengage_cycle`` count from the start of tracking; ``mode`` 3
    (absolute: go onto the point) or 5 (relative: keep the offset at engage).
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

    def start(self, ctl: Controller, cycle: int) -> None:
        self.start_cycle = cycle

    def update(self, ctl: Controller, cycle: int, belt: MasterEstimate) -> MotionState:
        n = cycle - self.start_cycle
        if self.engage_cycle is not None and n == self.engage_cycle:
            ctl.tracker.engage(self.mode)
        if self.disengage_cycle is not None and n == self.disengage_cycle:
            ctl.tracker.disengage()
        return belt_frame(ctl.cfg.tracking.conveyor, belt, self.offset)

    def master_lost(self, ctl: Controller, cycle: int) -> None:
        pass

    def done(self, ctl: Controller, cycle: int) -> bool:
        return self.end_cycle is not None and cycle - self.start_cycle >= self.end_cycle

    def status(self) -> AppStatus:
        return NO_STATUS

    def engage(self, ctl: Controller, mode: Mode) -> bool:
        return False

    def trigger(self, t_ns: int, item_type: int = 0) -> bool:
        return False

    def track_types(self, types: frozenset[int] | None) -> bool:
        return False
