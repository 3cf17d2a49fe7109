"""The demo's pick and place: photo-eye -> item on the belt -> window -> follow -> place.

One application (:class:`PickPlace`, the :class:`~controller.canopen.app.Application`
interface) drives the :class:`~controller.tracking.Tracker` directly, cycle by cycle:

    WAIT      an item is inside the window [start, end) -> engage (absolute) onto the item
    APPROACH  Tracker SYNCING; SYNCED -> FOLLOW
    FOLLOW    follow the item for ``pick_dwell_s`` (the pick) -> disengage (de-sync)
    DESYNC    the tracker stops on the path; OFF -> engage onto the place position
    PLACE     SYNCED at the place -> dwell ``place_dwell_s`` -> disengage -> WAIT
    An item that leaves the window (u >= end) before its pick is *missed*; so is the item
    being approached or followed when the tracker reports an error or the encoder goes
    silent (the controller has started the de-sync then).

Items: the photo-eye at u = ``photo_eye`` (coordinates u [mm] along the conveyor direction
from its origin, like the window) reports the time of each rising edge (a timestamped
input).  The item's belt coordinate is the measured belt travel of that cycle moved back by
the estimated belt velocity x (t_cycle - t_edge); its machine position is then
``origin + direction*(photo_eye + s - s_item) + across*lateral + z*height``, its angle the
item's.  The place move is the same tracker engaged onto a master at rest at the place pose.

To switch to the conveyor model (issue 3) later: :class:`Item`, :class:`Window` and
:meth:`PickPlace._item_state` are the only places that know about items and frames.

The simulated side (:class:`PhotoEye`) knows the true belt travel (the encoder's speed
profile) and the items' belt positions (seeded pitch, lateral offset and angle), and turns
them into edge times.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from enum import Enum
from typing import TYPE_CHECKING

from ..tracking import MasterEstimate, Mode, MotionState, TrackState
from .demo_config import DemoConfig

if TYPE_CHECKING:
    from .cycle import Controller
    from .devices.encoder import SpeedProfile


class Step(Enum):
    WAIT = "wait"
    APPROACH = "approach"
    FOLLOW = "follow"
    DESYNC = "desync"
    PLACE = "place"


@dataclass
class Item:
    """One item: seen by the photo-eye at controller time ``t_edge_ns``."""

    index: int
    t_edge_ns: int
    lateral: float  # mm across the belt
    angle: float  # deg
    s_item: float | None = None  # belt travel when it passed the photo-eye [mm]
    trigger_cycle: int | None = None
    engage_cycle: int | None = None
    synced_cycle: int | None = None
    picked_cycle: int | None = None
    placed_cycle: int | None = None
    outcome: str = "pending"  # pending, placed, missed
    reason: str = ""
    max_error_mm: float = 0.0
    u_pick: float | None = None


@dataclass(frozen=True)
class Window:
    start: float
    end: float

    def contains(self, u: float) -> bool:
        return self.start <= u < self.end


class PhotoEye:
    """Simulated photo-eye: item edges from the true belt travel (the encoder's profile)."""

    def __init__(self, profile: SpeedProfile, demo: DemoConfig, start_s: float) -> None:
        rng = random.Random(demo.seed)
        self.items: list[Item] = []
        b = profile.travel(start_s + demo.first_item_s)
        for i in range(demo.items):
            t = self._time_at(profile, b, start_s)
            self.items.append(Item(i, round(t * 1e9), rng.uniform(*demo.lateral),
                                   rng.uniform(*demo.angle)))
            b += rng.uniform(*demo.pitch_mm)
        self._next = 0

    @staticmethod
    def _time_at(profile: SpeedProfile, travel: float, t_lo: float) -> float:
        lo, hi = t_lo, t_lo + 1.0
        while profile.travel(hi) < travel:
            hi += 2 * (hi - lo)
            if hi > 1e6:
                raise ValueError("the belt never reaches the item (speed profile <= 0?)")
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            if profile.travel(mid) < travel:
                lo = mid
            else:
                hi = mid
        return hi

    @property
    def detected(self) -> int:
        """Items whose edge has been reported so far (PLC triggers included)."""
        return self._next

    def trigger(self, t_edge_ns: int, lateral: float = 0.0, angle: float = 0.0) -> Item:
        """An edge reported from outside (the PLC's trigger input, 2004h of the controller
        node): a new item at the photo-eye at ``t_edge_ns``, on the belt's centre line."""
        item = Item(len(self.items), int(t_edge_ns), lateral, angle)
        i = self._next
        while i < len(self.items) and self.items[i].t_edge_ns <= item.t_edge_ns:
            i += 1
        self.items.insert(i, item)
        return item

    def edges_until(self, t_ns: int) -> list[Item]:
        out = []
        while self._next < len(self.items) and self.items[self._next].t_edge_ns <= t_ns:
            out.append(self.items[self._next])
            self._next += 1
        return out


@dataclass
class PickPlace:
    """The demo sequence (see the module docstring)."""

    demo: DemoConfig
    eye: PhotoEye | None = None
    step: Step = Step.WAIT
    pending: list[Item] = field(default_factory=list)
    done_items: list[Item] = field(default_factory=list)
    current: Item | None = None
    _step_cycle: int = 0
    _start_cycle: int = 0
    _end_cycle: int | None = None

    # -- geometry -------------------------------------------------------------------------
    def _frame(self, ctl: Controller) -> tuple[tuple, tuple, tuple]:
        c = ctl.cfg.tracking.conveyor
        d = c.direction
        across = (-d[1], d[0], 0.0)
        n = math.hypot(across[0], across[1])
        across = (across[0] / n, across[1] / n, 0.0) if n > 1e-9 else (0.0, 1.0, 0.0)
        return c.origin, d, across

    def _u(self, item: Item, belt: MasterEstimate) -> float:
        return self.demo.photo_eye + belt.pos - item.s_item

    def _item_state(self, ctl: Controller, item: Item, belt: MasterEstimate) -> MotionState:
        o, d, n = self._frame(ctl)
        u = self._u(item, belt)
        h = self.demo.pick_height
        pos = tuple(o[i] + d[i] * u + n[i] * item.lateral + (h if i == 2 else 0.0)
                    for i in range(3))
        return MotionState(pos, tuple(x * belt.vel for x in d), tuple(x * belt.acc for x in d),
                           item.angle, 0.0, 0.0)

    def _place_state(self) -> MotionState:
        return MotionState.at(*self.demo.place_position, self.demo.place_angle)

    # -- Application -------------------------------------------------------------------------
    def start(self, ctl: Controller, cycle: int) -> None:
        self._start_cycle = cycle
        self._end_cycle = cycle + int(self.demo.duration_s / ctl.cfg.period_s)
        if self.eye is None:
            raise ValueError("PickPlace needs a photo-eye")

    def _goto(self, step: Step, cycle: int) -> None:
        self.step = step
        self._step_cycle = cycle

    def _finish_item(self, item: Item, outcome: str, reason: str = "") -> None:
        item.outcome = outcome
        item.reason = reason
        self.done_items.append(item)
        if item is self.current:
            self.current = None
        if item in self.pending:
            self.pending.remove(item)

    def update(self, ctl: Controller, cycle: int, belt: MasterEstimate) -> MotionState:
        tr = ctl.tracker
        assert tr is not None
        T = ctl.cfg.period_s
        window = Window(*ctl.cfg.tracking.window)
        t_now = ctl.t0 + cycle * ctl.period_ns  # the SYNC of this cycle (sample time)
        # new items: belt coordinate at the edge, from this cycle's measurement
        for item in self.eye.edges_until(t_now):
            s_meas = ctl.master.belt_mm if ctl.master.belt_mm is not None else belt.pos
            item.s_item = s_meas - belt.vel * (t_now - item.t_edge_ns) * 1e-9
            item.trigger_cycle = cycle
            self.pending.append(item)
        # items that left the window unpicked
        for item in list(self.pending):
            if item is not self.current and self._u(item, belt) >= window.end:
                self._finish_item(item, "missed", "left the window")
                ctl.events.add(cycle, (t_now - ctl.t0) * 1e-9, "demo", "item_missed",
                               f"item {item.index} left the window", level=20)
        step = self.step
        if step is Step.WAIT:
            if ctl.master.ready and tr.state is TrackState.OFF:
                for item in self.pending:
                    if window.contains(self._u(item, belt)):
                        self.current = item
                        item.engage_cycle = cycle
                        tr.engage(Mode.ABSOLUTE)
                        self._goto(Step.APPROACH, cycle)
                        break
        elif step in (Step.APPROACH, Step.FOLLOW):
            item = self.current
            assert item is not None
            u = self._u(item, belt)
            if tr.state not in (TrackState.SYNCING, TrackState.SYNCED):
                self._finish_item(item, "missed", f"tracker error {tr.error.name}")
                self._goto(Step.DESYNC, cycle)
            elif u >= window.end:
                tr.disengage()
                self._finish_item(item, "missed", "left the window during the approach")
                self._goto(Step.DESYNC, cycle)
            elif step is Step.APPROACH and tr.state is TrackState.SYNCED:
                item.synced_cycle = cycle
                self._goto(Step.FOLLOW, cycle)
            elif step is Step.FOLLOW:
                item.max_error_mm = max(item.max_error_mm, ctl.last_tracking_error)
                if (cycle - self._step_cycle) * T >= self.demo.pick_dwell_s:
                    item.picked_cycle = cycle
                    item.u_pick = u
                    tr.disengage()
                    self.pending.remove(item)
                    self._goto(Step.DESYNC, cycle)
        elif step is Step.DESYNC:
            if tr.state is TrackState.OFF:
                if self.current is not None and self.current.picked_cycle is not None:
                    tr.engage(Mode.ABSOLUTE)
                    self._goto(Step.PLACE, cycle)
                else:
                    self.current = None
                    self._goto(Step.WAIT, cycle)
        elif step is Step.PLACE:
            item = self.current
            if tr.state is TrackState.SYNCED:
                if item.placed_cycle is None:
                    item.placed_cycle = cycle  # at the place; dwell, then release
                if (cycle - item.placed_cycle) * T >= self.demo.place_dwell_s:
                    tr.disengage()
                    self._finish_item(item, "placed")
                    self._goto(Step.DESYNC, cycle)
            elif tr.state is TrackState.OFF:
                tr.engage(Mode.ABSOLUTE)  # (an error de-synced the place move: again)
        # the master of the next SYNC
        if self.step is Step.PLACE or (self.step is Step.DESYNC and self.current is not None
                                       and self.current.picked_cycle is not None):
            return self._place_state()
        if self.current is not None:
            return self._item_state(ctl, self.current, belt)
        return self._place_state()

    def master_lost(self, ctl: Controller, cycle: int) -> None:
        if self.current is not None and self.step in (Step.APPROACH, Step.FOLLOW):
            self._finish_item(self.current, "missed", "encoder silent")
            self._goto(Step.DESYNC, cycle)

    def done(self, ctl: Controller, cycle: int) -> bool:
        if self._end_cycle is not None and cycle >= self._end_cycle:
            return True
        all_seen = self.eye is not None and len(self.done_items) == len(self.eye.items)
        return all_seen and self.step is Step.WAIT and ctl.tracker is not None \
            and ctl.tracker.state is TrackState.OFF

    # -- results ----------------------------------------------------------------------------
    def items(self) -> list[Item]:
        seen = {i.index for i in self.done_items}
        rest = [i for i in (self.eye.items if self.eye else []) if i.index not in seen]
        return sorted(self.done_items + rest, key=lambda i: i.index)
