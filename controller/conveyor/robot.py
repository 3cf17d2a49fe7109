"""The robot group on moving frames: MasterFrame, slave, IMFS, triggers, hand-off, virtual robot.

Spec: docs/spec/conveyor.md#6 (the tracking formula) to #11; item numbers below are the
sections of conveyor.md (hand-off 9.1-9.6 as softMC numbers them).

**The tracking formula.**  In world TCP coordinates (``base:Robot:tool``)::

    setpoint = V ⊕ C_1 ⊕ C_2          Robot_real = base⁻¹ : setpoint : tool⁻¹

V is the virtual robot (:class:`controller.conveyor.motion.VirtualRobot`: the robot before the
tracking plus every motion entered afterwards; ``Robot_virtual = base⁻¹:V:tool⁻¹``), C_i the
contribution of the i-th moving frame the robot follows (at most two: #9.3).  Each
contribution is produced by a core tracker (:class:`controller.conveyor.tracker.ConveyorTracker`,
always in the core's absolute mode) whose master is the frame's motion since the item's zero::

    D(t) = [MF(t) ⊖ MF(0)]        (slave = 5, softMC's formula; MF(0) = <MF>.zero)

so that, synchronised and with V standing still, ``setpoint = V ⊕ [MF(t) ⊖ MF(0)]`` exactly as
softMC writes, and ``MOVES <robot> <MF>.zero`` ends on ``<MF>.here`` (the Q.E.D. of #6.3, tested).
The tracker smooths the frame's contribution: it approaches D from where the contribution is
(at rest, zero, when the robot is engaged) with the sync limits, follows it exactly when
synchronised, and stops it on the path (line, or arc for rotary frames) when de-syncing.
The translation of D goes through the tracker's 3-D channel; its orientation
``MF(0).ori⁻¹·MF(t).ori`` is a rotation about a fixed (local) axis for all our frame types
(``Q(x, UpStream[1].ori⁻¹·v)`` for type 1; identity for types 0 and 2), so its angle goes
through the tracker's 1-D rotation channel.

``slave = 3`` (absolute; the old algorithm, softMC 4.2.8 keeps only 5 for the new one;
#6.4): the TCP goes onto ``<MF>.here`` in position *and* orientation ("once synchronization is
achieved, both positions are equal"; "both robot's position and orientation coordinates are
taken into account").  The master is ``MF(t).pos - V(engage).pos`` for the position; the
orientation offset ``E = V(engage).ori⁻¹·MF(0).ori`` is split into a twist about the angle
channel's axis (added to that channel's target) and a constant swing approached by a second
one-angle tracker with the same sync rotation limits (:meth:`FrameLink._orientation_offset`;
docs/spec/conveyor-extensions.md#1).  slave = 5 is unchanged: the robot turns
with the frame, keeping its own orientation offset.

**Virtual stopping position (#8.1).**  When a contribution starts to de-sync, the core's
stop is deterministic and its end E (the frame's "virtual stopping position") is known at
that moment.  We move E into the virtual robot at once (V ← V ⊕ E, a constant: V's location
and the ends of its running motions shift by E) and count the contribution from E from then
on, C = D̃ ⊖ E, which runs to zero as the stop ends.  The setpoint is unchanged by this
bookkeeping, and:

- no motion is stopped or cancelled by a de-sync;
- a motion started while de-syncing ends where it would on a free robot (its
  absolute target is computed after the shift, and C goes to zero);
- an absolute target of a motion started while synchronised ends at
  ``target ⊕ E``: the combination of the frame's virtual stopping position and the target;
- superposition of motions is not touched by sync or de-sync.

The robot's location after a de-sync is the new "robot before tracking" of the next engage.

**Hand-off (#9).**  A different MasterFrame makes the current frame's contribution
de-sync (on its path) and a new contribution sync to the new frame, both active at once:
``setpoint = V ⊕ C_old(de-syncing) ⊕ C_new(syncing)``, superposed relative motions (old
first; positions add, orientations multiply in that order).  The old frame is marked
de-syncing (``<MF>.desyncing_by``) until its stop ends: no robot can engage it before (9.4).
A third frame is rejected (9.3), the same frame again is ignored (9.4).  ``STOP``,
``slave = 0`` and ``MasterFrame = none`` are the same command here (9.5): every attached frame
de-syncs and ``slave`` becomes 0 when the last stop has ended (9.1).  Only ``slave = 0``
clears the trigger buffer: softMC states it for that command alone ("As before, slave=0 will
delete all items"), and a program that leaves a frame with ``MasterFrame = none`` (or hands
off) keeps its queue of items.  MasterFrame given with a motion (nodal,
:meth:`RobotGroup.moves` ``master_frame=``) acts when that motion starts (9.6).

Order within one ``update``: nodal MasterFrame of the motions due now, then the frame links
(window, tracker, a de-sync's stopping position moved into V), then the due motions start
(their absolute targets fixed after that shift), then V and the setpoint.

**Items and the window (#7).**  A frame link tracks the oldest trigger entry of its frame.  The
tracker engages when the item is inside the window (before that the robot waits, IMFS 0) and:

- the item leaves downstream while SYNCED: it is done (removed from the buffer); the link
  goes on with the next item of that frame: a new approach from the current state if that one
  is inside the window, else a de-sync and a wait ("Then, the robot starts tracking the next
  item on the frame");
- the item leaves downstream before it was caught: error 30238 "Item missed": the
  frame de-syncs and detaches (like ``MasterFrame = none`` for that frame), the item is
  removed, motions go on as they are;
- ``NEXTITEM``: the same as "done" for the current item, at once.

**IMFS** (#10): 0 not synchronised (not engaged, waiting for an item, or
approaching); 1 synchronised; -1 de-syncing (the only frame, or the engaged frame waiting for
its next item after a de-sync); -2 de-syncing from one frame while engaged to (catching or
following) another.

Everything is sample-stepped (``update()`` once per sample, after the frames' ``update``);
commands act at the next ``update``; no clock, no randomness.  Commands raise
``CantrackError`` subclasses; ``update()`` never raises and reports events and error codes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum, StrEnum
from typing import Any, Iterable, Mapping, Sequence, overload

from ..tracking.values import fast_init, mypyc_attr
from ..errors import CantrackError, ParameterError, StateError
from ..limits import CartesianLimits, Limits
from ..tracking import Imfs, Mode, MotionState, TrackError, TrackerParams, TrackState
from .errors import (ITEM_MISSED_CODE, FrameBusyError, NoFrameError, TooManyFramesError)
from .frame import MovingFrame
from .kinematics import Kinematics, check_compatible
from .frames import FramePoint, GroupGeometry, RotaryGeometry
from .location import (Q_IDENTITY, Location, Quat, Vec3, as_location, q_axis_angle, q_conj,
                       q_mul, q_to_axis_angle, q_twist_angle, vec3)
from .motion import KEEP, MOTION_LIMITS, Motion, VirtualRobot
from .telemetry import ItemRecord, ItemStatus
from .tracker import ConveyorTracker
from .triggers import TriggerBuffer, TriggerEntry
from .window import WindowPosition


class LinkState(IntEnum):
    """State of one robot-frame link."""

    WAITING = 0  #: engaged, no item inside the window (tracker off)
    SYNCING = 1
    SYNCED = 2
    DESYNCING = 3
    DONE = 4  #: detached


#: a link's state from its tracker's (OFF: waiting for an item)
_LINK_STATE = {TrackState.OFF: LinkState.WAITING, TrackState.SYNCING: LinkState.SYNCING,
               TrackState.SYNCED: LinkState.SYNCED, TrackState.DESYNCING: LinkState.DESYNCING}


class EventKind(StrEnum):
    """What an :class:`Event` is about (a ``str``: traces and summaries show the value)."""

    ITEM_ENTERED = "item_entered"      #: the tracked item entered the window
    ENGAGED = "engaged"                #: a link engaged an item (its reference taken)
    SYNCHRONIZED = "synchronized"      #: the link is synchronised with the item
    ITEM_LEFT = "item_left"            #: the tracked item left the window
    ITEM_MISSED = "item_missed"        #: softMC error 30238 (``code``)
    ITEM_IGNORED = "item_ignored"      #: an item of a type the robot does not track
    NEXTITEM = "nextitem"              #: NEXTITEM: the buffer's next item
    LEAVE = "leave"                    #: a frame starts to be left (hand-off, none, STOP,
    #:                                    slave = 0, error)
    DESYNC_STARTED = "desync_started"  #: the de-sync started (``message``: line / arc)
    DETACHED = "detached"              #: the link is done
    HANDOFF = "handoff"                #: following goes over to another frame
    TRACKER_ERROR = "tracker_error"    #: a tracker error (``message`` names it)
    MOTION_STARTED = "motion_started"  #: a motion of the virtual robot started
    COMMAND_ERROR = "command_error"    #: a command that failed (e.g. a nodal MasterFrame)
    TRIGGER_REJECTED = "trigger_rejected"  #: a trigger the buffer refused (the simulator)


@fast_init
@dataclass(frozen=True, slots=True)
class Event:
    """Something that happened at ``sample`` (``kind``: :class:`EventKind`).  ``code``: 30238
    for item_missed.  Commands given between two updates report their events with the sample
    of the last update."""

    sample: int
    kind: EventKind
    frame: str = ""
    item: int | None = None
    code: int = 0
    message: str = ""


@fast_init
@dataclass(frozen=True, slots=True)
class RobotOutput:
    """One sample of a robot group.  ``setpoint``: world TCP (``base:Robot_real:tool``);
    ``velocity`` [mm/s] of its position; ``virtual``: V (world TCP)."""

    sample: int
    setpoint: Location
    velocity: Vec3
    virtual: Location
    imfs: Imfs
    slave: int
    master_frame: str | None
    links: tuple[tuple[str, LinkState], ...]
    events: tuple[Event, ...]
    error: TrackError = TrackError.NONE


_ZERO3 = (0.0, 0.0, 0.0)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class FrameLink:
    """One robot following one moving frame (internal to :class:`RobotGroup`)."""

    def __init__(self, robot: "RobotGroup", frame: MovingFrame, mode: Mode) -> None:
        self.robot = robot
        self.frame = frame
        self.mode = Mode(mode)
        # "These values are taken during moving frame assignment" (Tracking Process)
        self.params = robot.tracker_params.with_(
            mode=Mode.ABSOLUTE, master_max_trans=frame.limits.trans,
            master_max_rot=frame.limits.rot)
        self.geo = frame.geometry()
        #: the rotation axis of the tracker's angle channel (local): the frame's own for a
        #: rotary type 1; for frames whose orientation does not turn, chosen at the first
        #: slave = 3 engage as the axis of the orientation offset (else z, unused)
        self.axis: Vec3 = self.geo.local_axis
        self._axis_free = not ((isinstance(self.geo, RotaryGeometry) and self.geo.rotates)
                               or isinstance(self.geo, GroupGeometry))
        self._rotary = isinstance(self.geo, RotaryGeometry)
        self.tracker = ConveyorTracker(self.params, MotionState())
        self.offset_pos: Vec3 = _ZERO3
        self.offset_ang = 0.0
        #: slave = 3: the orientation offset's part about ``axis`` [deg] (added to the angle
        #: channel's target) and the rest, a swing about ``swing_axis`` approached by a second
        #: one-angle tracker (None while the offset is a rotation about ``axis``)
        self.twist_deg = 0.0
        self.swing_axis: Vec3 | None = None
        self.swing_deg = 0.0
        self.swing: ConveyorTracker | None = None
        self.offset_swing = 0.0
        self.item: TriggerEntry | None = None
        self.record: ItemRecord | None = None
        self.ref: Location | None = None
        self.leaving = False
        self.done = False
        self.error = TrackError.NONE
        self.point: FramePoint | None = None
        self.window_position: WindowPosition | None = None
        self.target = MotionState()
        self._seen_desync = 0
        self._reapproach = False

    # -- state ------------------------------------------------------------------------------
    @property
    def state(self) -> LinkState:
        if self.done:
            return LinkState.DONE
        return _LINK_STATE[self.track_state]

    @property
    def track_state(self) -> TrackState:
        """The tracker's state, SYNCED only when the swing channel (slave = 3) is synced too."""
        st = self.tracker.state
        if self.swing is not None and st == TrackState.SYNCED and \
                self.swing.state == TrackState.SYNCING:
            return TrackState.SYNCING
        return st

    def _raw_ori(self, ang: float, swing: float) -> Quat:
        q = q_axis_angle(self.axis, ang) if ang else Q_IDENTITY
        if swing and self.swing_axis is not None:
            q = q_mul(q_axis_angle(self.swing_axis, swing), q)
        return q

    def contribution(self) -> Location:
        """C = D̃ ⊖ O: the trackers' output minus the offset O (the output where the last
        stop ended; positions subtract, ``O.ori⁻¹·D̃.ori``)."""
        sp = self.tracker.setpoint
        pos = (sp.pos[0] - self.offset_pos[0], sp.pos[1] - self.offset_pos[1],
               sp.pos[2] - self.offset_pos[2])
        sw = self.swing.setpoint.ang if self.swing is not None else 0.0
        if self.swing is None or (sw == self.offset_swing):
            ang = sp.ang - self.offset_ang
            return Location.trusted(pos, q_axis_angle(self.axis, ang) if ang else Q_IDENTITY)
        raw = self._raw_ori(sp.ang, sw)
        off = self._raw_ori(self.offset_ang, self.offset_swing)
        return Location(pos, q_mul(q_conj(off), raw))

    def contribution_velocity(self) -> Vec3:
        return self.tracker.setpoint.vel

    # -- items ------------------------------------------------------------------------------
    def _take(self, entry: TriggerEntry, k: int, ev: list[Event]) -> None:
        self.item = entry
        rec = self.record = self.robot._record(entry)
        if rec.left_sample is not None:
            # taken again (e.g. MasterFrame = none closed it as SKIPPED while it was the
            # link's next item, and the program engages it later): it has not left yet
            rec.left_sample = None
            if rec.status == ItemStatus.SKIPPED:
                rec.status = ItemStatus.CAUGHT if rec.caught else ItemStatus.PENDING
        if isinstance(self.geo, GroupGeometry) and self.tracker.state == TrackState.OFF and \
                self.offset_ang == 0.0 and self.tracker.setpoint.ang == 0.0:
            # the item's own rotation axis (its orientation at the trigger); kept while the
            # angle channel is in use
            self.axis = self.geo.local_axis_for(entry)
        if self.mode == Mode.RELATIVE:
            self.ref = self.geo.zero(entry.dr_mm, entry)
        else:
            self.ref = None  # set at the engage (the virtual robot then)
        self._evaluate()

    def _evaluate(self) -> None:
        """Item coordinates, window position and tracker target from the frame's master."""
        item = self.item
        assert item is not None  # called with an assigned item
        c, cd, cdd = self.frame.coords(item)
        self.point = self.geo.point(c, cd, cdd, item.dr_mm, item)
        self.window_position = self.frame.window.classify(c, item.inverse)

    def _make_target(self) -> MotionState:
        p, ref, o = self.point, self.ref, self.offset_pos
        assert p is not None and ref is not None  # the caller checked both
        h0, h1, h2 = p.here.pos
        r0, r1, r2 = ref.pos
        q0, q1, q2 = o
        pos = (h0 - r0 + q0, h1 - r1 + q1, h2 - r2 + q2)
        return MotionState(pos, p.vel, p.acc, p.ang + self.twist_deg + self.offset_ang,
                           p.ang_vel, p.ang_acc)

    def _swing_target(self) -> float:
        """The swing channel's target [deg] in the trackers' (raw) coordinates: the swing S
        behind the offset O, ``Q(ψ*, s) = Q(ψ_O, s)·Q(θ_O, a)·S·Q(θ_O, a)⁻¹`` (exact when
        θ_O = 0; else its part about s)."""
        if not self.offset_ang:
            return self.offset_swing + self.swing_deg
        s = self.swing_axis
        assert s is not None  # a swing channel exists
        qa = q_axis_angle(self.axis, self.offset_ang)
        q = q_mul(q_mul(q_axis_angle(s, self.offset_swing), qa),
                  q_mul(q_axis_angle(s, self.swing_deg), q_conj(qa)))
        return q_twist_angle(q, s)

    def _orientation_offset(self) -> None:
        """slave = 3 (absolute): the setpoint must reach ``<MF>.here`` in orientation too.

        The contribution's orientation must end at ``E·Q(x, a)`` with the constant
        ``E = V(engage).ori⁻¹·MF(0).ori`` (V ⊕ C = MF.here, MF.here.ori = MF(0).ori·Q(x, a)).
        E is split into a twist about the angle channel's axis a (added to that channel's
        target) and a swing S about an axis perpendicular to a: ``E = S·Q(τ, a)``, so that
        ``C.ori = S·Q(τ + x, a)``.  The swing is a constant rotation, approached by a second
        one-angle tracker with the same sync limits; the link is synchronised when both are.
        On a frame whose orientation does not turn (linear, rotary decoupled) a is chosen as
        E's own axis at the first engage, so there is no swing.
        """
        assert self.ref is not None and self.item is not None  # at the engage of an item
        e = q_mul(q_conj(self.ref.ori), self.geo.zero(self.item.dr_mm, self.item).ori)
        if self._axis_free and self.tracker.state == TrackState.OFF and \
                self.offset_ang == 0.0 and self.tracker.setpoint.ang == 0.0:
            axis, ang = q_to_axis_angle(e)
            if ang > 1e-12:
                self.axis = axis
        self.twist_deg = q_twist_angle(e, self.axis)
        swing = q_mul(e, q_axis_angle(self.axis, -self.twist_deg))
        s_axis, s_ang = q_to_axis_angle(swing)
        if s_ang <= 1e-9 and self.swing is None:
            self.swing_deg = 0.0
            return
        if self.swing_axis is None:
            self.swing_axis = s_axis
        self.swing_deg = q_twist_angle(swing, self.swing_axis)
        if self.swing is None:
            self.swing = ConveyorTracker(self.params, MotionState())

    def _engage(self, k: int, ev: list[Event]) -> None:
        if self.ref is None:
            self.ref = self.robot.virtual.location
            if self.mode == Mode.ABSOLUTE:
                self._orientation_offset()
        if self.swing is not None:
            if self.swing.state in (TrackState.SYNCING, TrackState.SYNCED):
                self.swing = ConveyorTracker(self.params, self.swing.setpoint)
            self.swing.engage()
        tr = self.tracker
        if tr.state in (TrackState.SYNCING, TrackState.SYNCED):
            # a new approach from the current state (next item while tracking): the core
            # cannot re-engage from SYNCING/SYNCED, so the next update starts a new tracker
            # from the current setpoint (a leave() before that cancels it)
            self._reapproach = True
        else:
            tr.engage()
        assert self.record is not None and self.item is not None  # engaging an item
        self.record.engaged_sample = k
        self.record.status = ItemStatus.TRACKING
        ev.append(Event(k, EventKind.ENGAGED, self.frame.name, self.item.id))

    def _close_item(self, k: int, ev: list[Event], status: ItemStatus | None) -> None:
        """The current item is finished for this link (left, NEXTITEM, missed, skipped)."""
        if self.item is not None:
            self.robot._drop_untracked(self.item, k, ev)
        rec = self.record
        if rec is not None:
            if status is not None and not (status == ItemStatus.SKIPPED and rec.caught):
                rec.status = status
            elif rec.caught:
                rec.status = ItemStatus.CAUGHT
            if rec.left_sample is None:
                rec.left_sample = k
        self.item = None
        self.record = None
        self.point = None
        self.window_position = None

    def advance(self, k: int, ev: list[Event], status: ItemStatus | None) -> None:
        """Finish the current item and go on with the next item of this frame."""
        caught_before = self.record is not None and self.record.caught
        self._close_item(k, ev, status if not caught_before else None)
        nxt = self.robot._current(self.frame.name)
        tr = self.tracker
        active = tr.state in (TrackState.SYNCING, TrackState.SYNCED)
        if nxt is not None:
            self._take(nxt, k, ev)
            if self.window_position == WindowPosition.INSIDE and not self.leaving:
                if active:
                    self._engage(k, ev)
                return
        if active:
            tr.disengage()

    def leave(self, k: int, ev: list[Event], reason: str) -> None:
        """De-sync from this frame and detach when the stop has ended."""
        if self.leaving:
            return
        self.leaving = True
        self._reapproach = False
        fr = self.frame
        ev.append(Event(k, EventKind.LEAVE, fr.name, message=reason))
        if fr.engaged_by == self.robot.name:
            fr.engaged_by = None
        fr.desyncing_by.add(self.robot.name)
        if self.item is not None:
            self._close_item(k, ev, ItemStatus.SKIPPED)
        tr = self.tracker
        if tr.state in (TrackState.SYNCING, TrackState.SYNCED):
            tr.disengage()
        elif tr.state == TrackState.OFF:
            self._finish(k, ev)

    def _finish(self, k: int, ev: list[Event]) -> None:
        self.done = True
        fr = self.frame
        fr.desyncing_by.discard(self.robot.name)
        fr._unlink_if_free()
        ev.append(Event(k, EventKind.DETACHED, fr.name))

    # -- cyclic -----------------------------------------------------------------------------
    def step(self, k: int, ev: list[Event]) -> TrackError:
        """One sample: window logic, tracker update, de-sync bookkeeping, telemetry."""
        err = TrackError.NONE
        if self.item is None and not self.leaving:
            nxt = self.robot._current(self.frame.name)
            if nxt is not None:
                self._take(nxt, k, ev)
        elif self.item is not None:
            self._evaluate()
        if self.item is not None and not self.leaving:
            rec = self.record
            assert rec is not None  # kept with the item
            wp = self.window_position
            if wp == WindowPosition.INSIDE and rec.entered_sample is None:
                rec.entered_sample = k
                ev.append(Event(k, EventKind.ITEM_ENTERED, self.frame.name, self.item.id))
            st = self.track_state
            if wp == WindowPosition.AFTER:
                if st == TrackState.SYNCED:
                    item = self.item
                    self.robot.buffer.remove(item)
                    ev.append(Event(k, EventKind.ITEM_LEFT, self.frame.name, item.id))
                    self.advance(k, ev, ItemStatus.CAUGHT)
                else:
                    err = self._missed(k, ev)
            elif wp == WindowPosition.INSIDE and st in (TrackState.OFF, TrackState.DESYNCING):
                self._engage(k, ev)
        if self._reapproach:
            self._reapproach = False
            self.tracker = ConveyorTracker(self.params, self.tracker.setpoint)
            self._seen_desync = 0
            self.tracker.engage()
        tr = self.tracker
        if self.item is not None and self.point is not None and self.ref is not None:
            self.target = self._make_target()
            if self._rotary:
                geo = self.geo
                assert isinstance(geo, RotaryGeometry)  # (what _rotary says)
                arc = geo.arc
                center = vec3(c - r + o for c, r, o in zip(arc.center, self.ref.pos,
                                                          self.offset_pos))
                tr.set_arc(center, arc.axis, couple_angle=geo.rotates)
        was_synced = self.track_state == TrackState.SYNCED
        out = tr.update(self.target)
        sw = self.swing
        if sw is not None:
            if tr.desync_count != self._seen_desync and \
                    sw.state in (TrackState.SYNCING, TrackState.SYNCED):
                sw.disengage()
            sw.update(MotionState(ang=self._swing_target()) if self.item is not None and
                      self.ref is not None else MotionState(ang=sw.setpoint.ang))
        synced_now = self.track_state == TrackState.SYNCED and not was_synced
        if tr.desync_count != self._seen_desync:
            self._seen_desync = tr.desync_count
            self._absorb_stop(k, ev)
        rec = self.record
        if rec is not None and tr.state in (TrackState.SYNCING, TrackState.SYNCED) and \
                not self.leaving:
            sp, tg = out.setpoint, self.target
            (t0, t1, t2), (s0, s1, s2) = tg.pos, sp.pos
            (u0, u1, u2), (w0, w1, w2) = tg.vel, sp.vel
            rec.observe(self.track_state == TrackState.SYNCED and not synced_now,
                        (t0 - s0, t1 - s1, t2 - s2), tg.ang - sp.ang,
                        (u0 - w0, u1 - w1, u2 - w2))
        if synced_now and rec is not None:
            rec.synced_sample = k
            rec.status = ItemStatus.CAUGHT
            ev.append(Event(k, EventKind.SYNCHRONIZED, self.frame.name, rec.item_id))
        if out.error and self.error == TrackError.NONE:
            self.error = out.error
            err = out.error
            ev.append(Event(k, EventKind.TRACKER_ERROR, self.frame.name,
                            self.item.id if self.item else None, message=out.error.name))
            if self.record is not None and not self.record.caught:
                self.record.error = out.error.name
                self._close_item(k, ev, ItemStatus.LOST)
            self.leave(k, ev, f"tracker error {out.error.name}")
        if tr.state == TrackState.OFF and tr.desync_end is not None and \
                (sw is None or sw.state == TrackState.OFF):
            # the stop has ended: the contribution is exactly zero; reset the bookkeeping
            tr.set_robot_state(MotionState())
            tr.desync_end = None
            self.offset_pos, self.offset_ang = _ZERO3, 0.0
            if sw is not None:
                sw.set_robot_state(MotionState())
                sw.desync_end = None
                self.offset_swing = 0.0
            if self.leaving and not self.done:
                self._finish(k, ev)
        return err

    def _missed(self, k: int, ev: list[Event]) -> TrackError:
        item = self.item
        rec = self.record
        assert item is not None and rec is not None  # a missed item is the current one
        rec.missed_sample = k
        rec.error = f"Item missed ({ITEM_MISSED_CODE})"
        self.robot.buffer.remove(item)
        ev.append(Event(k, EventKind.ITEM_MISSED, self.frame.name, item.id, ITEM_MISSED_CODE,
                        f"Item missed: item {item.id} of frame {self.frame.name!r} left the "
                        "window before the robot was synchronised"))
        self._close_item(k, ev, ItemStatus.MISSED)
        self.error = TrackError.ITEM_MISSED
        self.leave(k, ev, "item missed (30238)")
        return TrackError.ITEM_MISSED

    def _absorb_stop(self, k: int, ev: list[Event]) -> None:
        """A de-sync started: move its end E into the virtual robot, C = D̃ ⊖ E from now on."""
        e = self.tracker.desync_end
        assert e is not None  # set when the de-sync started
        dpos = vec3(a - b for a, b in zip(e.pos, self.offset_pos))
        sw = self.swing
        if sw is None:
            dang = e.ang - self.offset_ang
            self.robot.virtual.shift(Location(dpos, q_axis_angle(self.axis, dang)))
        else:
            # the swing's stop ends where its de-sync (started in this sample) comes to rest
            s_end = sw.desync_end.ang if sw.state == TrackState.DESYNCING and \
                sw.desync_end is not None else sw.setpoint.ang
            off = self._raw_ori(self.offset_ang, self.offset_swing)
            end = self._raw_ori(e.ang, s_end)
            self.robot.virtual.shift(Location(dpos, q_mul(q_conj(off), end)))
            self.offset_swing = s_end
        self.offset_pos, self.offset_ang = e.pos, e.ang
        ev.append(Event(k, EventKind.DESYNC_STARTED, self.frame.name,
                        message=f"along the {self.tracker.desync_path}"))


#: item types are 0...255 (one UNSIGNED8 in a CANopen object)
ITEM_TYPE_MAX = 255


def _check_item_type(value: Any, what: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or \
            not 0 <= value <= ITEM_TYPE_MAX:
        raise ParameterError(f"{what} (={value!r}) must be an integer in [0...{ITEM_TYPE_MAX}]")


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class RobotGroup:
    """A robot group that tracks moving frames (see the module docstring).

    ``tracker``: sync/de-sync limits, rates, planner and sample time
    (:class:`controller.tracking.TrackerParams`; its ``mode`` is ignored, each link uses the
    core's absolute mode; ``master_max_*`` come from the frame).  ``start``: the TCP location
    in world coordinates at sample 0; ``base``/``tool``: the robot's base and tool frames.
    ``default_mode``: the slave value a MasterFrame assignment starts with (5).
    ``kinematics``: the robot type and its world frame's dimension; a MasterFrame of another
    kinematics system is rejected (:class:`controller.conveyor.kinematics.KinematicsError`).
    """

    def __init__(self, name: str, tracker: TrackerParams | None = None, *,
                 start: Location | Sequence[float] = Location(),
                 base: Location = Location(), tool: Location = Location(),
                 motion_limits: CartesianLimits = MOTION_LIMITS, buffer_capacity: int = 32,
                 default_mode: Mode | int = Mode.RELATIVE,
                 kinematics: Kinematics = Kinematics()) -> None:
        self.name = str(name)
        if not isinstance(kinematics, Kinematics):
            raise ParameterError(f"robot {name!r}: kinematics (={kinematics!r}) must be a "
                                 "Kinematics")
        #: robot type and world-frame dimension, checked against each MasterFrame
        self.kinematics = kinematics
        self.tracker_params = tracker if tracker is not None else TrackerParams(
            sample_time_s=0.002, planner="softmc")
        self.T = self.tracker_params.sample_time_s
        self.base = base
        self.tool = tool
        start = as_location(start)
        self.virtual = VirtualRobot(start, self.T, motion_limits)
        self.buffer = TriggerBuffer(buffer_capacity, self.name)
        self.links: list[FrameLink] = []
        self.default_mode = Mode(default_mode)
        if self.default_mode == Mode.OFF:
            raise ParameterError("default_mode (=0) must be 3 or 5")
        self.k = 0
        self._slave = 0
        self._last_frame: MovingFrame | None = None
        self._pending: list[Event] = []
        self._ids = 0
        #: tracked item types per frame name (absent: every type)
        self._types: dict[str, frozenset[int]] = {}
        #: telemetry per trigger entry id
        self.records: dict[int, ItemRecord] = {}
        self.setpoint = start
        self.velocity: Vec3 = _ZERO3
        self.last_output: RobotOutput | None = None

    # -- properties -------------------------------------------------------------------------
    def _active(self) -> FrameLink | None:
        for link in self.links:
            if not link.leaving:
                return link
        return None

    def link_for(self, frame: MovingFrame | str) -> FrameLink | None:
        name = frame if isinstance(frame, str) else frame.name
        for link in self.links:
            if link.frame.name == name:
                return link
        return None

    @property
    def slave(self) -> int:
        """``<robot>.slave``: 0, 3 or 5 (stays 3/5 during a de-sync, 0 when it has ended)."""
        return self._slave

    @slave.setter
    def slave(self, value: int) -> None:
        self.set_slave(value)

    @property
    def master_frame(self) -> MovingFrame | None:
        """``<robot>.MasterFrame``: the frame being caught or followed (None: none)."""
        a = self._active()
        return a.frame if a is not None else None

    @master_frame.setter
    def master_frame(self, frame: MovingFrame | None) -> None:
        self.set_master_frame(frame)

    @property
    def imfs(self) -> Imfs:
        """``<robot>.IsMovingFrameSynchronized`` (Functionality Changes)."""
        leaving = False
        active = None  # (any() and _active() in one pass over the links)
        for lk in self.links:
            if lk.leaving:
                leaving = True
            elif active is None:
                active = lk
        if leaving and active is not None:
            return Imfs.HANDOFF
        if leaving:
            return Imfs.DESYNCING
        if active is not None:
            st = active.track_state
            if st == TrackState.SYNCED:
                return Imfs.SYNCHRONIZED
            if st == TrackState.DESYNCING:
                return Imfs.DESYNCING
        return Imfs.NOT_SYNCHRONIZED

    @property
    def real(self) -> Location:
        """Robot_real = base⁻¹ : setpoint : tool⁻¹ (the robot's own coordinates)."""
        return self.base.inverse().compound(self.setpoint).compound(self.tool.inverse())

    @property
    def robot_virtual(self) -> Location:
        """Robot_virtual = base⁻¹ : V : tool⁻¹."""
        return self.base.inverse().compound(self.virtual.location).compound(self.tool.inverse())

    def to_world(self, robot_location: Location) -> Location:
        """base : robot_location : tool."""
        return self.base.compound(robot_location).compound(self.tool)

    # -- MasterFrame / slave / STOP ---------------------------------------------------------
    def set_master_frame(self, frame: MovingFrame | None, mode: Mode | int | None = None
                         ) -> None:
        """``<robot>.MasterFrame = frame`` (modal).  None: de-sync every frame (9.1, 9.5)."""
        self._set_master_frame(frame, mode, self._pending, self.k)

    def _set_master_frame(self, frame: MovingFrame | None, mode: Mode | int | None,
                          ev: list[Event], k: int) -> None:
        if frame is None:
            self._desync_all(ev, k, "MasterFrame = none")
            return
        active = self._active()
        if active is not None and active.frame is frame:
            return  # 9.4: already engaged with it - ignored
        if frame.desyncing_by:
            raise FrameBusyError(
                f"robot {self.name!r}: moving frame {frame.name!r} cannot be engaged while "
                f"robot(s) {', '.join(sorted(frame.desyncing_by))} de-sync from it (item 9.4)")
        if frame.engaged_by is not None and frame.engaged_by != self.name:
            raise FrameBusyError(
                f"robot {self.name!r}: moving frame {frame.name!r} is engaged by robot "
                f"{frame.engaged_by!r}; several robots on one region need one moving frame "
                "each")
        if len(self.links) >= 2:
            names = ", ".join(repr(lk.frame.name) for lk in self.links)
            raise TooManyFramesError(
                f"robot {self.name!r} follows two moving frames ({names}); a third one "
                f"({frame.name!r}) is rejected (item 9.3)")
        if mode is None:
            mode = self._slave if self._slave in (3, 5) else self.default_mode
        mode = Mode(mode)
        if mode == Mode.OFF:
            raise ParameterError("mode (=0) must be 3 or 5")
        check_compatible(self.name, self.kinematics, frame)  # KinematicsError
        frame._link()  # circle pre-calculation: ArcGeometryError for collinear points
        if active is not None:
            active.leave(k, ev, f"hand-off to {frame.name!r}")
            ev.append(Event(k, EventKind.HANDOFF, frame.name,
                            message=f"from {active.frame.name!r}"))
        link = FrameLink(self, frame, mode)
        frame.engaged_by = self.name
        self.links.append(link)
        self._slave = int(mode)
        self._last_frame = frame

    def set_slave(self, value: int, frame: MovingFrame | None = None) -> None:
        """``<robot>.slave = value``: 0 de-syncs everything (9.5); 3/5 engage ``frame`` or
        the last MasterFrame."""
        if value == 0:
            self._desync_all(self._pending, self.k, "slave = 0", clear=True)
            return
        if value not in (3, 5):
            raise ParameterError(f"<{self.name}>.slave (={value!r}) must be 0, 3 or 5")
        active = self._active()
        if active is not None:
            if active.mode != value:
                raise StateError(f"<{self.name}>.slave cannot change from {int(active.mode)} to "
                                 f"{value} while engaged; set slave = 0 first")
            if frame is None or frame is active.frame:
                return
        target = frame or self._last_frame
        if target is None:
            raise NoFrameError(f"<{self.name}>.slave = {value}: no MasterFrame given")
        self._set_master_frame(target, value, self._pending, self.k)

    def stop(self) -> None:
        """``STOP <robot>``: equivalent to ``slave = 0`` and ``MasterFrame = none`` (9.5)."""
        self._desync_all(self._pending, self.k, "STOP")

    def _desync_all(self, ev: list[Event], k: int, reason: str, clear: bool = False) -> None:
        for link in list(self.links):
            link.leave(k, ev, reason)
        if clear:
            for e in self.buffer:
                rec = self.records.get(e.id)
                if rec is not None and rec.status in (ItemStatus.PENDING, ItemStatus.TRACKING):
                    rec.status = ItemStatus.SKIPPED
            self.buffer.clear()
        self._drop_done()

    def _drop_done(self) -> None:
        for lk in self.links:
            if lk.done:
                self.links = [lk for lk in self.links if not lk.done]
                break
        if not self.links:
            self._slave = 0

    # -- item types -------------------------------------------------------------------------
    def track_types(self, frame: MovingFrame | str, types: Iterable[int] | None) -> None:
        """Track only items of ``types`` on ``frame`` (None: every type, the default).

        The link takes the oldest item of a tracked type; NEXTITEM skips the others; they
        never enter the window logic (no engage, no 30238) and are dropped (IGNORED) once an
        item triggered after them has been finished.  Acts from the next update.
        """
        name = frame if isinstance(frame, str) else frame.name
        if types is None:
            self._types.pop(name, None)
            return
        ts = frozenset(types)
        for t in ts:
            _check_item_type(t, f"{self.name}.track_types({name!r})")
        if not ts:
            raise ParameterError(f"{self.name}.track_types({name!r}): give at least one item "
                                 "type (None tracks every type)")
        self._types[name] = ts

    def tracked_types(self, frame: MovingFrame | str) -> frozenset[int] | None:
        """The item types tracked on ``frame`` (None: every type)."""
        return self._types.get(frame if isinstance(frame, str) else frame.name)

    def _current(self, frame: str) -> TriggerEntry | None:
        return self.buffer.current(frame, self._types.get(frame))

    def _drop_untracked(self, entry: TriggerEntry, k: int, ev: list[Event]) -> None:
        types = self._types.get(entry.frame)
        if types is None:
            return
        for e in self.buffer.drop_untracked_before(entry, types):
            rec = self.records.get(e.id)
            if rec is not None and rec.status == ItemStatus.PENDING:
                rec.status = ItemStatus.IGNORED
            ev.append(Event(k, EventKind.ITEM_IGNORED, e.frame, e.id,
                            message=f"type {e.item_type} is not tracked"))

    # -- triggers ---------------------------------------------------------------------------
    @overload
    def _resolve(self, frame: MovingFrame | None, command: str) -> MovingFrame: ...
    @overload
    def _resolve(self, frame: MovingFrame | str | None, command: str) -> MovingFrame | str: ...

    def _resolve(self, frame: MovingFrame | str | None, command: str) -> MovingFrame | str:
        if frame is not None:
            return frame
        frames = [lk.frame for lk in self.links]
        if len(frames) == 1:
            return frames[0]
        if not frames:
            raise NoFrameError(f"{command} {self.name}: no MasterFrame named and the robot is "
                               "not engaged to any moving frame")
        raise NoFrameError(f"{command} {self.name}: the robot is engaged to several moving "
                           f"frames ({', '.join(repr(f.name) for f in frames)}); name one "
                           "with MasterFrame = ...")

    def trigger(self, frame: MovingFrame | str | None = None, *, ndof: int | None = None,
                value: float | None = None, values: Sequence[float] | None = None,
                dr_mm: float = 0.0, inverse: bool = False,
                age_s: float | None = None, item_type: int | float = 0,
                attributes: Mapping[str, float | str] | None = None,
                offset: Location | None = None,
                location: Location | None = None) -> TriggerEntry:
        """``TRIGGER <robot> {NDOF = ndof Value = value} {MasterFrame = frame}
        {Type = item_type}``.

        The entry's master values are the frame's source values latched now, corrected for
        the delay from the sensor edge (``age_s`` [s], default the frame's
        ``trigger_delay_s``: taken back along the sources' motion), or ``values`` (all DOFs,
        as given), with DOF ``ndof`` (1-based) set to ``value`` if given.
        ``dr_mm``: radius offset (rotary frames); ``inverse``: the window direction flag;
        ``item_type``: the item's class (0...255; see :meth:`track_types`), ``attributes``:
        what else the sensor says about it (name -> number or text), kept in the entry.
        Group frames (type 3): the item's full location at the trigger is taken now, the
        master TCP's (at the edge) composed with ``offset`` (the item relative to the TCP,
        default identity), or ``location`` (world) as given.
        Raises :class:`TriggerBufferFull` when the buffer is full.
        """
        fr = self._resolve(frame, "TRIGGER")
        link = self.link_for(fr) if isinstance(fr, str) else None
        if link is not None:
            fr = link.frame
        name = fr if isinstance(fr, str) else fr.name
        if values is not None:
            vals = [float(v) for v in values]
        elif isinstance(fr, MovingFrame):
            age = fr.trigger_delay_s if age_s is None else age_s
            if not (isinstance(age, (int, float)) and math.isfinite(age) and age >= 0.0):
                raise ParameterError(f"TRIGGER {self.name}: the edge's age (={age!r}) must "
                                     "be >= 0 s")
            vals = list(fr.source_values(age))
        else:
            raise NoFrameError(f"TRIGGER {self.name}: frame {name!r} given by name only: give "
                               "the values or the MovingFrame object")
        if ndof is not None or value is not None:
            if ndof is None or value is None:
                raise ParameterError("TRIGGER: give both NDOF and Value")
            if not 1 <= ndof <= len(vals):
                raise ParameterError(f"TRIGGER {self.name}: NDOF (={ndof!r}) must be in "
                                     f"[1...{len(vals)}]")
            vals[ndof - 1] = float(value)
        if not (isinstance(dr_mm, (int, float)) and math.isfinite(dr_mm)):
            raise ParameterError(f"TRIGGER: radius offset (={dr_mm!r}) must be finite [mm]")
        _check_item_type(item_type, f"TRIGGER {self.name}: Type")
        attrs: tuple[tuple[str, float | str], ...] = ()
        if attributes:
            for key, v in attributes.items():
                if not isinstance(key, str) or not key or isinstance(v, bool) or not (
                        isinstance(v, str) or (isinstance(v, (int, float))
                                               and math.isfinite(v))):
                    raise ParameterError(f"TRIGGER {self.name}: attribute {key!r} (={v!r}) "
                                         "must be a name with a finite number or a text")
            attrs = tuple((k, v if isinstance(v, str) else float(v))
                          for k, v in attributes.items())
        zero = None
        if isinstance(fr, MovingFrame) and fr.group_source is not None:
            zero = self._group_zero(fr, vals, offset, location)
        elif offset is not None or location is not None:
            raise ParameterError(f"TRIGGER {self.name}: offset/location are for group frames "
                                 f"(type 3), not for frame {name!r}")
        self._ids += 1
        linked = self.link_for(name) is not None
        entry = TriggerEntry(self._ids, name, tuple(vals), float(dr_mm), bool(inverse), self.k,
                             linked, int(item_type), attrs, zero)
        self.buffer.add(entry)  # raises TriggerBufferFull (the id is not reused: fine)
        self.records[entry.id] = ItemRecord(entry.id, name, self.name, self.T, self.k,
                                            item_type=int(item_type))
        return entry

    @staticmethod
    def _group_zero(fr: MovingFrame, vals: Sequence[float], offset: Location | None,
                    location: Location | None) -> Location:
        """W0, the item's location at the trigger on a group frame: the master TCP at the
        latched values (the position; the orientation turned back about the frame axis by the
        angle the TCP turned since) composed with ``offset``, or ``location``."""
        if location is not None:
            if offset is not None:
                raise ParameterError("TRIGGER: give offset or location, not both")
            return as_location(location)
        src = fr.group_source
        if src is None:
            raise ParameterError(f"TRIGGER: frame {fr.name!r} is not a group frame (type 3)")
        now = src.location()
        cur = fr.source_values()
        back = q_axis_angle(fr.group_axis, vals[3] - cur[3])
        l0 = Location(vec3(vals[:3]), q_mul(back, now.ori))
        return l0.compound(offset) if offset is not None else l0

    def _record(self, entry: TriggerEntry) -> ItemRecord:
        rec = self.records.get(entry.id)
        if rec is None:
            rec = self.records[entry.id] = ItemRecord(entry.id, entry.frame, self.name, self.T,
                                                      entry.sample)
        return rec

    def nextitem(self, frame: MovingFrame | str | None = None) -> TriggerEntry | None:
        """``NEXTITEM <robot> {MasterFrame = frame}``: drop the frame's current item (other
        frames' items are skipped); a link tracking it goes on with the next one."""
        fr = self._resolve(frame, "NEXTITEM")
        name = fr if isinstance(fr, str) else fr.name
        link = self.link_for(name)
        entry = self.buffer.nextitem(name, self._types.get(name))
        if entry is None:
            return None
        ev = self._pending
        ev.append(Event(self.k, EventKind.NEXTITEM, name, entry.id))
        if link is not None and link.item is entry:
            link.advance(self.k, ev, ItemStatus.SKIPPED)
        else:
            rec = self.records.get(entry.id)
            if rec is not None and rec.status == ItemStatus.PENDING:
                rec.status = ItemStatus.SKIPPED
        return entry

    def current_item(self, frame: MovingFrame | str | None = None) -> TriggerEntry | None:
        fr = self._resolve(frame, "ITEM")
        name = fr if isinstance(fr, str) else fr.name
        link = self.link_for(name)
        if link is not None and link.item is not None:
            return link.item
        return self._current(name)

    def zero(self, frame: MovingFrame | None = None) -> Location:
        """``<MF>.zero`` of the frame's current item (the trigger point without an item)."""
        fr = self._resolve(frame, "ZERO")
        item = self.current_item(fr)
        return fr.zero(item)

    # -- motions ----------------------------------------------------------------------------
    def moves(self, target: Location | Sequence[float], *, limits: CartesianLimits | None = None,
              superpose: bool = False, master_frame: Any = KEEP, name: str = "") -> Motion:
        """``MOVES <robot> target`` (world TCP, absolute).  ``master_frame``: nodal
        MasterFrame (a frame or None), acting when the motion starts (9.6)."""
        return self.virtual.enter(Motion(as_location(target), False, limits, superpose,
                                         master_frame, name))

    def moves_rel(self, delta: Location | Sequence[float], *, limits: CartesianLimits | None = None,
                  superpose: bool = False, master_frame: Any = KEEP, name: str = "") -> Motion:
        """A relative ``MOVES``: the displacement is superposed on the robot's motion."""
        return self.virtual.enter(Motion(as_location(delta), True, limits, superpose,
                                         master_frame, name))

    # -- prediction -------------------------------------------------------------------------
    def can_catch(self, frame: MovingFrame | None = None, item: TriggerEntry | None = None,
                  horizon_s: float = 10.0):
        """Predict whether (when, where) the robot synchronises with an item
        (:func:`controller.conveyor.catch.predict_catch`)."""
        from .catch import predict_catch

        return predict_catch(self, frame, item, horizon_s)

    def _limit_superimposed(self, m: Motion) -> None:
        """PHASE2 (docs/spec/conveyor.md#11): a motion that starts while frames
        move the robot (links syncing, synced or de-syncing) gets the robot's maxima minus
        those frames' ``{Velocity|Acceleration|Jerk}Max{Trans|Rot}``, so that "increasing
        these values will effectively decrease the velocity of the superimposed robot
        motion" and the combined motion stays within the robot's limits.  Only with the
        robot's maxima given (``TrackerParams.robot_max_trans/_rot``); the motion's own
        limits still apply when lower.  Raises ParameterError when nothing is left."""
        rt, rr = self.tracker_params.robot_max_trans, self.tracker_params.robot_max_rot
        moving = [link.frame.limits for link in self.links
                  if link.state in (LinkState.SYNCING, LinkState.SYNCED, LinkState.DESYNCING)]
        if not moving or (rt is None and rr is None):
            return
        lim = m.limits or self.virtual.limits
        capped = []
        for channel, robot, own, suffix in (("trans", rt, lim.trans, "Trans"),
                                            ("rot", rr, lim.rot, "Rot")):
            if robot is None:
                capped.append(own)
                continue
            bounds = []
            for bound, softmc in (("vel", "VelocityMax"), ("acc", "AccelerationMax"),
                                  ("jerk", "JerkMax")):
                used = sum(getattr(getattr(f, channel), bound) for f in moving)
                left = getattr(robot, bound) - used
                if left <= 0.0:
                    raise ParameterError(
                        f"{self.name}: motion {m.name or m.id} cannot start: the moving "
                        f"frames' {softmc}{suffix} ({used:g}) leaves nothing of the robot's "
                        f"maximum ({getattr(robot, bound):g}) for a superimposed motion")
                bounds.append(min(getattr(own, bound), left))
            capped.append(Limits(*bounds))
        m.limits = CartesianLimits(*capped)

    # -- cyclic -----------------------------------------------------------------------------
    def update(self) -> RobotOutput:
        """Compute the next sample (call after the frames' ``update`` of that sample)."""
        self.k += 1
        k = self.k
        ev, self._pending = self._pending, []
        error = TrackError.NONE
        v = self.virtual
        due = v.due()
        for m in due:   # nodal MasterFrame: acts at the motion's start (9.6)
            if m.master_frame is not KEEP:
                try:
                    self._set_master_frame(m.master_frame, None, ev, k)
                except CantrackError as exc:
                    ev.append(Event(k, EventKind.COMMAND_ERROR,
                                    getattr(m.master_frame, "name", "") or "", message=str(exc)))
        for link in list(self.links) if self.links else ():
            e = link.step(k, ev)
            if e and not error:
                error = e
        # motions start after the links: a de-sync that starts in this sample has moved its
        # stopping position into V already, so a motion started now ends on its target (7)
        for m in due:
            try:
                self._limit_superimposed(m)
            except ParameterError as exc:
                v.queue.remove(m)
                ev.append(Event(k, EventKind.COMMAND_ERROR, message=str(exc)))
                continue
            v.start(m)
            ev.append(Event(k, EventKind.MOTION_STARTED, message=m.name or f"motion {m.id}"))
        v.step()
        loc = v.location
        v0, v1, v2 = v.velocity
        for link in self.links:
            if link.done:
                continue
            loc = loc.oplus(link.contribution())
            c0, c1, c2 = link.contribution_velocity()
            v0, v1, v2 = v0 + c0, v1 + c1, v2 + c2
        self._drop_done()
        self.setpoint = loc
        self.velocity = (v0, v1, v2)
        links = self.links
        a = self._active() if links else None
        out = RobotOutput(k, loc, self.velocity, v.location, self.imfs, self._slave,
                          a.frame.name if a is not None else None,
                          tuple([(lk.frame.name, lk.state) for lk in links]) if links else (),
                          tuple(ev), error)
        self.last_output = out
        return out
