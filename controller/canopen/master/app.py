"""What the controller tracks: the application interface and the plain conveyor follower.

The cycle asks its application, once per cycle while RUNNING and before
``Tracker.update``, for the master state of the next SYNC; the application may call
``ctl.tracker.engage()`` / ``disengage()`` then (they act in the same update).  The demo's
pick-and-place sequence (:mod:`controller.canopen.apps.demo`) is one application;
:class:`ConveyorFollow` (follow a point of the belt, engage/disengage at given times) is
the one ``cantrack run`` and the tests use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Protocol

from ...tracking import MasterEstimate, Mode, MotionState

if TYPE_CHECKING:
    from ..config.tracking import ConveyorConfig
    from .cycle import Controller


def belt_frame(conv: ConveyorConfig, est: MasterEstimate,
               offset: Sequence[float] = (0.0, 0.0, 0.0), angle: float = 0.0) -> MotionState:
    """The state of the belt point at travel ``est.pos`` [mm] from the conveyor's origin:
    origin + direction * s + offset [mm], velocity direction * v, acceleration direction * a."""
    d, o = conv.direction, conv.origin
    s, v, a = est.pos, est.vel, est.acc
    return MotionState((o[0] + d[0] * s + offset[0], o[1] + d[1] * s + offset[1],
                        o[2] + d[2] * s + offset[2]),
                       (d[0] * v, d[1] * v, d[2] * v), (d[0] * a, d[1] * a, d[2] * a),
                       angle, 0.0, 0.0)


class Application(Protocol):
    def start(self, ctl: Controller, cycle: int) -> None:
        """Tracking begins (all drives enabled, master ready)."""

    def update(self, ctl: Controller, cycle: int, belt: MasterEstimate) -> MotionState:
        """The master state [mm, deg] at the next SYNC; may engage/disengage the tracker."""

    def master_lost(self, ctl: Controller, cycle: int) -> None:
        """The encoder went silent; the controller has started the de-sync."""

    def done(self, ctl: Controller, cycle: int) -> bool:
        """True when the run is over."""


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
