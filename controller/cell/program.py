"""The pick program of a robot in a cell or a conveyor scenario (deterministic,
sample-stepped): one item at a time on one frame, the steps of :class:`PickState`.  Pure; the
offline simulator (``cantrack simulate``) and the bus controller's cell source run it alike.
Units: mm, s.
"""

from __future__ import annotations

from enum import StrEnum

from ..conveyor import (CatchPrediction, Event, EventKind, Location, MovingFrame, RobotGroup,
                        TriggerEntry)
from ..conveyor.location import vec3
from ..tracking import Imfs
from .elements import ProgramSpec

__all__ = ["PickProgram", "PickState"]


class PickState(StrEnum):
    """The step of :class:`PickProgram` (a ``str``: the summary shows the value)."""

    IDLE = "idle"            #: waiting for the next item of the frame
    ENGAGE = "engage"        #: slave = 3: waiting for the link to engage the item
    APPROACH = "approach"    #: moving over the item, until synchronised
    DESCEND = "descend"      #: going down onto the item
    GRIP = "grip"            #: dwelling synchronised (the pick)
    LIFT = "lift"            #: going up with the item
    RECOVER = "recover"      #: the item was lost during the pick: motions finish as they are
    PLACE = "place"          #: moving to the place position


class PickProgram:
    """A small robot program, one item at a time (deterministic, sample-stepped).

    idle: the oldest item of the frame in the buffer; with ``predict`` ask
    :meth:`RobotGroup.can_catch` and skip the item (NEXTITEM) when the answer is no; else
    ``MasterFrame = frame`` and

    - ``slave = 5`` (relative): ``MOVES <MF>.zero`` raised by ``approach_mm`` (the item's
      orientation): the tracking adds ``MF(t) ⊖ MF(0)``, so the TCP ends above ``<MF>.here``;
    - ``slave = 3`` (absolute): no MOVES to ``<MF>.zero`` - the tracker itself brings the
      TCP onto ``<MF>.here`` (plus the virtual robot's motion since the engage, the
      reference); once the link has engaged the item (engage), a relative move up by
      ``approach_mm``, so the robot hovers above the item as with 5;

    -> approach: once synchronised and the move is done, go down
    ``approach_mm`` (relative) -> grip: wait ``dwell_s`` synchronised (the pick) -> lift:
    up again, then ``NEXTITEM`` and ``MasterFrame = none`` and ``MOVES place`` -> place ->
    idle.  "Item missed" (30238) or the item leaving the window during the pick: the motions
    go on as they are (docs/spec/conveyor.md#7), then ``MOVES place`` once they are done;
    the reason is kept in :attr:`unpicked` (so every caught item is either picked or has a
    reason).
    """

    def __init__(self, robot: RobotGroup, frame: MovingFrame, spec: ProgramSpec,
                 slave: int) -> None:
        self.robot = robot
        self.frame = frame
        self.spec = spec
        self.slave = slave
        self.place = spec.place if spec.place is not None else robot.setpoint
        self.state: PickState = PickState.IDLE
        self.item: TriggerEntry | None = None
        self.until = 0
        self.picks: dict[int, float] = {}
        self.predictions: dict[int, CatchPrediction] = {}
        self.skipped: dict[int, str] = {}
        #: items the program went for but did not pick, with the reason
        self.unpicked: dict[int, str] = {}
        self.log: list[tuple[int, str, int | None]] = []

    def _id(self) -> int:
        """The id of the item the program works on (set in every state but idle)."""
        assert self.item is not None  # (the states after idle have one)
        return self.item.id

    def _say(self, what: str) -> None:
        self.log.append((self.robot.k, what, self.item.id if self.item is not None else None))

    def tick(self, events: tuple[Event, ...]) -> None:
        r, f, sp = self.robot, self.frame, self.spec
        v = r.virtual
        for e in events:
            if self.item is not None and e.item == self.item.id and \
                    e.kind in (EventKind.ITEM_MISSED, EventKind.ITEM_LEFT,
                               EventKind.TRACKER_ERROR) and \
                    self.state in (PickState.ENGAGE, PickState.APPROACH, PickState.DESCEND,
                                   PickState.GRIP):
                self._say(f"{e.kind.value}: finishing the motions as they are")
                if self.item.id not in self.picks:
                    self.unpicked[self.item.id] = \
                        f"{e.kind.value.replace('_', ' ')} during the {self.state.value} at " \
                        f"{self.robot.k * self.robot.T:.3f} s" + \
                        (f": {e.message}" if e.message else "")
                self.state = PickState.RECOVER
        if self.state == PickState.IDLE:
            item = r.current_item(f)
            if item is None:
                return
            self.item = item
            if sp.predict:
                p = r.can_catch(f, item)
                self.predictions[item.id] = p
                if not p.can_catch:
                    self.skipped[item.id] = p.reason
                    self._say(f"skip: {p.reason}")
                    r.nextitem(f)
                    self.item = None
                    return
            if r.master_frame is not f:
                r.set_master_frame(f, self.slave)
            if self.slave == 3:
                # absolute: the tracker brings the TCP onto <MF>.here itself (the virtual
                # robot at the engage is the reference); no MOVES to <MF>.zero - only the
                # hover offset, relative, once the link has engaged this item
                self._say("engage")
                self.state = PickState.ENGAGE
                return
            zero = f.zero(item)
            hover = Location(vec3(a + b for a, b in zip(zero.pos, (0.0, 0.0, sp.approach_mm))),
                             zero.ori)
            r.moves(hover, name=f"approach item {item.id}")
            self._say("approach")
            self.state = PickState.APPROACH
        elif self.state == PickState.ENGAGE:
            link = r.link_for(f)
            if link is not None and link.item is self.item and link.ref is not None:
                r.moves_rel((0.0, 0.0, sp.approach_mm), name=f"hover over item {self._id()}")
                self._say("approach")
                self.state = PickState.APPROACH
        elif self.state == PickState.APPROACH:
            if r.imfs == Imfs.SYNCHRONIZED and not v.busy:
                r.moves_rel((0.0, 0.0, -sp.approach_mm), name=f"down to item {self._id()}")
                self.state = PickState.DESCEND
        elif self.state == PickState.DESCEND:
            if not v.busy and r.imfs == Imfs.SYNCHRONIZED:
                self.until = r.k + round(sp.dwell_s / r.T)
                self.state = PickState.GRIP
        elif self.state == PickState.GRIP:
            if r.k >= self.until:
                self.picks[self._id()] = r.k * r.T
                self._say("picked")
                r.moves_rel((0.0, 0.0, sp.approach_mm), name=f"lift item {self._id()}")
                self.state = PickState.LIFT
        elif self.state == PickState.LIFT:
            if not v.busy:
                if r.current_item(f) is self.item:
                    r.nextitem(f)
                r.master_frame = None
                r.moves(self.place, name="place")
                self.state = PickState.PLACE
        elif self.state == PickState.RECOVER:
            if not v.busy:
                if r.master_frame is not None:
                    r.master_frame = None
                r.moves(self.place, name="place")
                self.state = PickState.PLACE
        elif self.state == PickState.PLACE:
            if not v.busy and r.slave == 0:
                self.item = None
                self.state = PickState.IDLE
