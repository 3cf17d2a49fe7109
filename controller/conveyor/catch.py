""""Can it catch this item?" - predict the rendezvous before committing (not
part of the softMC model, docs/spec/conveyor.md#1).

:func:`predict_catch` answers from the current state, the limits and the window:

1. Early "no" (no simulation), each with its reason:
   - the item already left the window downstream, or does not move towards the window;
   - the frame moves faster than the robot's sync velocity (translation or rotation), or
     faster than the frame's own VelocityMaxTrans/Rot (the tracker would stop on an error);
   - a lower bound of the approach time does not fit before the item leaves the window.
     The bound: the tracker must cancel the position error e and the velocity error
     de/dt along e's direction with |acceleration| <= the sync acceleration A (the master's
     acceleration taken as 0).  Projected on one axis this is the minimum-time double
     integrator, ``T = s*v0/A + 2*sqrt(v0^2/(2A^2) + s*x0/A)`` with
     ``s = sign(x0 + v0|v0|/(2A))`` - a true lower bound for the vector problem, since a
     vector acceleration of norm <= A has a projection of magnitude <= A.  The same for the
     rotation channel with the rotation limits.
2. Otherwise the exact answer under the assumption that the conveyor keeps its current speed:
   a copy of the robot's tracker (or a fresh one from the current contribution, engaged when
   the item enters the window) is run against the extrapolated frame - the very algorithm,
   with the same steps in the same order as the robot's frame link - until it synchronises,
   the item leaves the window (no), an error occurs (no) or ``horizon_s`` passes (no).  The
   virtual robot's started and queued motions are run along (motions the program has not
   entered yet are not known).

The question asked is "if the robot goes on with this item now": for the item the robot's
link tracks, the run continues as it is; for another item of the frame it is what NEXTITEM to
it would do (a new approach from the current state if the item is inside the window, else a
de-sync now and an approach at the entry).  The lower bound uses the frame contribution's
current state; while a de-sync is pending it ignores the stop (a heuristic then, not a bound:
only the simulation's answer counts).

The result gives the time (from now and absolute, robot samples * T), the item's location at
the rendezvous (``<MF>.here`` then) and the robot's TCP there (V ⊕ the frame's contribution;
equal to the item when V is at ``<MF>.zero``).  Pure: the robot and frames are not changed.
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass
from typing import TypedDict

from ..tracking import Mode, MotionState, TrackState
from ..tracking.values import python_class
from .frame import MovingFrame
from .frames import RotaryGeometry
from .location import Location, q_axis_angle, q_conj, q_mul, q_to_axis_angle, q_twist_angle
from .sources import SourceState
from .tracker import ConveyorTracker
from .triggers import TriggerEntry
from .window import WindowPosition


class _Timing(TypedDict, total=False):
    """The window times a prediction reports besides its verdict [s]."""

    enter_in_s: float
    leave_in_s: float
    lower_bound_s: float


@python_class
@dataclass(frozen=True, slots=True)
class CatchPrediction:
    """Times in s; ``in_s`` from now, ``time_s`` absolute (robot samples * T)."""

    can_catch: bool
    reason: str
    frame: str
    item: int | None
    early: bool = False  #: decided without simulating
    in_s: float | None = None
    time_s: float | None = None
    item_location: Location | None = None  #: <MF>.here at the rendezvous
    robot_location: Location | None = None  #: the TCP (setpoint) at the rendezvous
    enter_in_s: float | None = None
    leave_in_s: float | None = None
    lower_bound_s: float | None = None


def min_time_double_integrator(x0: float, v0: float, acc: float) -> float:
    """Minimum time to bring (x, x') from (x0, v0) to (0, 0) with |x''| <= acc."""
    if x0 == 0.0 and v0 == 0.0:
        return 0.0
    # error dynamics: e'' = -u; drive x -> 0 (x0 = error, v0 = its rate)
    s = x0 + v0 * abs(v0) / (2.0 * acc)
    sig = 1.0 if s > 0 else -1.0 if s < 0 else (1.0 if v0 > 0 else -1.0)
    return sig * v0 / acc + 2.0 * math.sqrt(max(0.0, v0 * v0 / (2.0 * acc * acc)
                                                + sig * x0 / acc))


def _lower_bound(target: MotionState, state: MotionState, acc_t: float, acc_r: float) -> float:
    e = [a - b for a, b in zip(target.pos, state.pos)]
    de = [a - b for a, b in zip(target.vel, state.vel)]
    n = math.sqrt(sum(x * x for x in e))
    if n > 0.0:
        u = [x / n for x in e]
        v0 = sum(a * b for a, b in zip(de, u))
        bt = min_time_double_integrator(n, v0, acc_t)
    else:
        dn = math.sqrt(sum(x * x for x in de))
        bt = dn / acc_t
    br = min_time_double_integrator(target.ang - state.ang, target.ang_vel - state.ang_vel,
                                    acc_r)
    return max(bt, br)


def predict_catch(robot, frame: MovingFrame | None = None, item: TriggerEntry | None = None,
                  horizon_s: float = 10.0) -> CatchPrediction:
    """Predict the rendezvous of ``robot`` with ``item`` of ``frame`` (see module docstring)."""
    fr = robot._resolve(frame, "CANCATCH") if frame is None else frame
    link = robot.link_for(fr)
    if item is None:
        item = link.item if link is not None and link.item is not None else \
            robot.current_item(fr)
    if item is None:
        return CatchPrediction(False, f"no item of frame {fr.name!r} in the buffer", fr.name,
                               None, True)
    T = robot.T
    geo = link.geo if link is not None else fr.geometry()
    master = fr.master
    c, cd, _ = fr.coords(item, master)
    assert master is not None  # coords() raised a StateError before the first update
    win = fr.window
    name, iid = fr.name, item.id
    if win.classify(c, item.inverse) == WindowPosition.AFTER:
        return CatchPrediction(False, "the item has already left the window", name, iid, True,
                               leave_in_s=0.0)
    t_enter = win.time_to_enter(c, cd, item.inverse)
    t_leave = win.time_to_leave(c, cd, item.inverse)
    if math.isinf(t_enter):
        return CatchPrediction(False, "the item does not move towards the window", name, iid,
                               True, enter_in_s=t_enter, leave_in_s=t_leave)
    params = link.params if link is not None else robot.tracker_params.with_(
        mode=Mode.ABSOLUTE, master_max_trans=fr.limits.trans, master_max_rot=fr.limits.rot)
    eff = params.effective()
    pt = geo.point(c, cd, (0.0,) * geo.nof, item.dr_mm, item)
    speed = math.sqrt(sum(x * x for x in pt.vel))
    common: _Timing = {"enter_in_s": t_enter, "leave_in_s": t_leave}
    if speed > fr.limits.trans.vel or abs(pt.ang_vel) > fr.limits.rot.vel:
        return CatchPrediction(False, f"the frame moves faster ({speed:.6g} mm/s, "
                                      f"{abs(pt.ang_vel):.6g} deg/s) than its VelocityMax",
                               name, iid, True, **common)
    if speed > eff.sync_trans.vel or abs(pt.ang_vel) > eff.sync_rot.vel:
        return CatchPrediction(False, f"the frame moves faster ({speed:.6g} mm/s, "
                                      f"{abs(pt.ang_vel):.6g} deg/s) than the sync velocity "
                                      f"({eff.sync_trans.vel:g} mm/s, {eff.sync_rot.vel:g} "
                                      "deg/s)", name, iid, True, **common)

    # the state to start from: the robot going on with this item now (as after NEXTITEM)
    if link is not None:
        tracker = link.tracker.snapshot()
        off_p, off_a = link.offset_pos, link.offset_ang
        axis = link.axis
        same_item = link.item is item
        ref = link.ref if same_item else None
        mode = link.mode
    else:
        tracker = ConveyorTracker(params, MotionState())
        off_p, off_a = (0.0, 0.0, 0.0), 0.0
        axis = geo.local_axis
        ref, same_item, mode = None, False, robot.default_mode
    if ref is None:
        ref = geo.zero(item.dr_mm, item) if mode == Mode.RELATIVE else robot.virtual.location
    twist = 0.0
    if mode == Mode.ABSOLUTE:
        # slave = 3 brings the orientation on too: the angle channel's part of the offset
        # (the swing channel, if any, is not simulated: the answer is then optimistic)
        if same_item and link is not None:
            twist = link.twist_deg
        else:
            e = q_mul(q_conj(ref.ori), geo.zero(item.dr_mm, item).ori)
            if not (isinstance(geo, RotaryGeometry) and geo.rotates) and \
                    tracker.setpoint.ang == 0.0 and off_a == 0.0:
                axis, ang = q_to_axis_angle(e)
                axis = axis if ang > 1e-12 else geo.local_axis
            twist = q_twist_angle(e, axis)
    active = tracker.state in (TrackState.SYNCING, TrackState.SYNCED)
    running = same_item and active
    if running and tracker.state == TrackState.SYNCED:
        return CatchPrediction(True, "already synchronised", name, iid, True, 0.0,
                               robot.k * T, fr.point(item, master).here, robot.setpoint,
                               enter_in_s=t_enter, leave_in_s=t_leave, lower_bound_s=0.0)
    inside_now = win.classify(c, item.inverse) == WindowPosition.INSIDE
    if active and not same_item:
        if inside_now:   # a new approach from the current state
            tracker = ConveyorTracker(params, tracker.setpoint)
            tracker.engage()
            running = True
        else:            # the current contribution stops; the approach starts at the entry
            tracker.disengage()
    virtual = copy.deepcopy(robot.virtual)
    seen = tracker.desync_count

    def frame_point(t: float):
        m = tuple(SourceState(s.pos + s.vel * t, s.vel, 0.0) for s in master)
        cc, ccd, _ = fr.coords(item, m)
        return cc, geo.point(cc, ccd, (0.0,) * geo.nof, item.dr_mm, item)

    def target_of(p, op, oa) -> MotionState:
        pos = tuple(h - r + o for h, r, o in zip(p.here.pos, ref.pos, op))
        return MotionState(pos, p.vel, p.acc, p.ang + twist + oa, p.ang_vel, p.ang_acc)

    # lower bound: the contribution C (setpoint minus offset) must catch the item's motion D
    t0 = 0.0 if running else max(t_enter, 0.0)
    _, p0 = frame_point(t0)
    sp0 = tracker.setpoint
    contrib = MotionState(tuple(a - b for a, b in zip(sp0.pos, off_p)), sp0.vel, sp0.acc,
                          sp0.ang - off_a, sp0.ang_vel, sp0.ang_acc)
    lb = _lower_bound(target_of(p0, (0.0, 0.0, 0.0), 0.0), contrib, eff.sync_trans.acc,
                      eff.sync_rot.acc)
    common["lower_bound_s"] = t0 + lb
    if t0 + lb > t_leave:
        return CatchPrediction(False, f"cannot synchronise before the item leaves the window "
                                      f"(in {t_leave:.3f} s): the approach needs at least "
                                      f"{lb:.3f} s from {t0:.3f} s", name, iid, True,
                               **common)

    n = int(math.ceil(min(horizon_s, t_leave + T if math.isfinite(t_leave) else horizon_s)
                      / T))
    engaged = running
    # the same steps, in the same order, as FrameLink.step and RobotGroup.update
    for j in range(1, n + 1):
        t = j * T
        cc, p = frame_point(t)
        wp = win.classify(cc, item.inverse)
        if wp == WindowPosition.AFTER:
            return CatchPrediction(False, f"not synchronised before the item leaves the "
                                          f"window (in {t_leave:.3f} s)", name, iid, False,
                                   **common)
        if not engaged and wp == WindowPosition.INSIDE:
            tracker.engage()
            engaged = True
        due = virtual.due()
        if isinstance(geo, RotaryGeometry):
            arc = geo.arc
            tracker.set_arc(tuple(a - r + o for a, r, o in zip(arc.center, ref.pos, off_p)),
                            arc.axis, geo.rotates)
        out = tracker.update(target_of(p, off_p, off_a))
        if tracker.desync_count != seen:     # a de-sync started: its end moves into V
            seen = tracker.desync_count
            # (not ``e``, the quaternion above: compiled, a name keeps its first type)
            end = tracker.desync_end
            assert end is not None  # (set when the de-sync started)
            virtual.shift(Location(tuple(a - b for a, b in zip(end.pos, off_p)),
                                   q_axis_angle(axis, end.ang - off_a)))
            off_p, off_a = end.pos, end.ang
        if out.error:
            return CatchPrediction(False, f"the tracker would stop with {out.error.name}",
                                   name, iid, False, **common)
        sp = out.setpoint
        c_loc = Location(tuple(a - b for a, b in zip(sp.pos, off_p)),
                         q_axis_angle(axis, sp.ang - off_a))
        if tracker.state == TrackState.OFF and tracker.desync_end is not None:
            tracker.set_robot_state(MotionState())
            tracker.desync_end = None
            off_p, off_a = (0.0, 0.0, 0.0), 0.0
        for m in due:
            virtual.start(m)
        virtual.step()
        if out.synchronized_now:
            return CatchPrediction(True, "synchronises in time", name, iid, False, t,
                                   (robot.k + j) * T, p.here,
                                   virtual.location.oplus(c_loc), **common)
    return CatchPrediction(False, f"not synchronised within {horizon_s:g} s", name, iid, False,
                           **common)
