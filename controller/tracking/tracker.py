"""The tracker: OFF -> SYNCING -> SYNCED -> DESYNCING -> OFF for one robot on one master.

Spec: docs/spec/tracking.md#2 (states #2.1, time axis #2.2, modes #2.3, IMFS #2.4, limits
#2.5, errors #2.6; the de-sync #5).

Time: the tracker counts samples.  ``update(master)`` is called once per sample period T with
the master's state *at the time of the setpoint being computed* (sample k); it returns the
setpoint for sample k.  The shells predict the master to that time (see ``estimator``).

Channels: translation (3-D, vector-norm limits ``sync_trans``) and rotation (one angle about
the tool axis, ``sync_rot``) are approached independently by the same planner; the tracker is
SYNCED when both are.  A synchronised channel follows the master: ``SyncFollow.COPY`` copies
it (all derivatives, as published), ``SyncFollow.LIMITED`` (default with ``optimal``) copies it
while that keeps the sync limits and closes any gap within them (:mod:`.follow`).

Modes (``<robot>.slave``): 3 absolute — the robot goes onto the master; 5 relative — the
robot keeps the offset it had to the master at engage (the master shifted by
robot(k0-1) - master(k0-1), the master extrapolated back one sample to the robot's time).

Errors (each starts the de-sync on the path and is reported until the next engage): a master
over the moving frame's VelocityMax/AccelerationMax (checked in SYNCING and SYNCED),
over-oscillation, approach timeout.

In OFF the setpoint continues the robot state last given (``set_robot_state`` or the initial
state) at constant acceleration: another motion source owns the robot then.
"""

from __future__ import annotations

import copy
import math
from typing import Any, Callable, cast

from .desync import Desync
from .follow import SyncFollower
from .oscillation import OscillationMonitor
from .planner import ChannelPlanner, planner_factory
from .types import (Imfs, Mode, MotionState, SyncFollow, TrackError, TrackerOutput,
                    TrackerParams, TrackState, motion_state)
from .values import attributes, mypyc_attr, restore
from .vec import Vec, vec3

#: Builds the de-sync stops (translation, rotation) for a tracker about to de-sync, or returns
#: None for the default straight-line stops.  The conveyor model supplies arcs this way.
DesyncBuilder = Callable[["Tracker"], "tuple[Desync, Desync] | None"]

_SYNCING, _SYNCED, _DESYNCING = TrackState.SYNCING, TrackState.SYNCED, TrackState.DESYNCING
_RELATIVE = Mode.RELATIVE
_NO_ERROR, _MASTER_VELOCITY, _MASTER_ACCELERATION = (
    TrackError.NONE, TrackError.MASTER_VELOCITY, TrackError.MASTER_ACCELERATION)
#: IMFS per state, indexed by the state's value (an IntEnum indexes a tuple directly; a dict
#: would hash the member with Enum's Python-level __hash__)
_IMFS: tuple[Imfs, ...] = (Imfs.NOT_SYNCHRONIZED, Imfs.NOT_SYNCHRONIZED, Imfs.SYNCHRONIZED,
                           Imfs.DESYNCING)
assert [int(s) for s in TrackState] == [0, 1, 2, 3]



# (subclassed by controller.conveyor.tracker.ConveyorTracker; copied by snapshot())
@mypyc_attr(allow_interpreted_subclasses=True)
class Tracker:
    """One tracker.  ``engage()`` / ``disengage()`` take effect at the next ``update()``."""

    def __init__(self, params: TrackerParams | None = None,
                 initial: MotionState | None = None) -> None:
        self.params = params = params if params is not None else TrackerParams()
        self.limits = params.effective()
        self.T = params.sample_time_s
        factory = planner_factory(params.planner)
        self._planners: tuple[ChannelPlanner, ChannelPlanner] = (
            factory(self.limits.sync_trans, params), factory(self.limits.sync_rot, params))
        #: the approach's setpoints made with ``types.motion_state`` (not converted): the
        #: translation planner's ``step`` returns tuples of Python floats (a planner says so
        #: with ``float_tuples = True``: the optimal one; softmc's carry a numpy scalar of
        #: the parameters into its vectors, which ``MotionState`` converts)
        self._trusted = getattr(self._planners[0], "float_tuples", False) is True
        window = max(1, round(params.max_flops_time_s / self.T))
        self._osc = (
            OscillationMonitor(params.max_flops, window,
                               params.filter_factor * self.limits.sync_trans.acc * self.T),
            OscillationMonitor(params.max_flops, window,
                               params.filter_factor * self.limits.sync_rot.acc * self.T))
        self._timeout_samples = max(1, round(params.approach_timeout_s / self.T))
        #: the moving frame's VelocityMax/AccelerationMax (translation, rotation) the master
        #: is checked against: (vel, rot vel, acc, rot acc) [mm/s, deg/s, mm/s^2, deg/s^2]
        mt, mr = params.master_max_trans, params.master_max_rot
        self._master_max = (mt.vel, mr.vel, mt.acc, mr.acc)
        #: SYNCED followers (translation, rotation); None: copy the master (as published)
        self._follow: tuple[SyncFollower, SyncFollower] | None = (
            (SyncFollower(self.limits.sync_trans, self.T),
             SyncFollower(self.limits.sync_rot, self.T))
            if params.synced_follow == SyncFollow.LIMITED else None)
        self.sample = 0
        self.setpoint = initial if initial is not None else MotionState()
        #: the two setpoints before ``setpoint`` (finite differences of the SYNCED follower)
        self._prev: tuple[MotionState | None, MotionState | None] = (None, None)
        self._hist: tuple[MotionState | None, MotionState | None] = (None, None)
        self.state = TrackState.OFF
        self.error = TrackError.NONE
        self.mode = params.mode
        self._request: str | None = None
        self._request_error = TrackError.NONE
        self._request_mode: Mode | None = None
        self._offset_pos: Vec = (0.0, 0.0, 0.0)
        self._offset_ang = 0.0
        self._synced = [False, False]
        self._approach_start = 0
        self._desync: tuple[Desync, Desync] | None = None
        self._desync_start = 0
        #: sample at which the last approach completed (None while not yet)
        self.synced_at: int | None = None
        #: optional builder of the de-sync stops (e.g. along an arc); None: straight lines
        self.desync_builder: DesyncBuilder | None = None
        #: where the current (or last) de-sync comes to rest (set when it starts)
        self.desync_end: MotionState | None = None
        #: number of de-syncs started so far
        self.desync_count = 0

    # -- commands -------------------------------------------------------------------
    def engage(self, mode: object = None) -> None:
        """Start synchronising at the next update (``mode`` 3 absolute / 5 relative: a
        :class:`Mode` or any integer, e.g. a numpy one; ``None``: the params' mode)."""
        if mode is not None:
            m = Mode(cast(Any, mode))  # (what Mode takes: a Mode, an int, numpy's ints)
            if m == Mode.OFF:
                self.disengage()
                return
            self._request_mode = m
        self._request = "engage"

    def disengage(self, error: object = TrackError.NONE) -> None:
        """Start the de-sync at the next update (``slave = 0``).

        ``error``: the reason when a shell stops the tracking for one (e.g.
        ``TrackError.MASTER_LOST`` when the encoder falls silent, or its int value); reported
        like the core's own.
        """
        self._request = "disengage"
        self._request_error = TrackError(cast(Any, error))

    def set_robot_state(self, state: MotionState) -> None:
        """Set the robot state while OFF (the setpoint another motion source produced)."""
        if self.state != TrackState.OFF:
            raise RuntimeError("set_robot_state is only allowed while OFF")
        self.setpoint = state

    @property
    def imfs(self) -> Imfs:
        return _IMFS[self.state]

    def __getstate__(self) -> dict:
        # (the compiled class's own state omits a Python subclass's attributes)
        return attributes(self)

    def __setstate__(self, state: dict) -> None:
        restore(self, state)
        if "_trusted" not in state:  # a state saved before the approach's trusted setpoints
            self._trusted = False

    def snapshot(self) -> "Tracker":
        """A deep copy of the whole tracker (for FMU state save/restore and what-if runs)."""
        return copy.deepcopy(self)

    def target(self, master: MotionState) -> MotionState:
        """What the tracker follows for ``master`` [mm, deg]: the master itself (absolute) or
        the master shifted by the offset kept at engage (relative); the tracking error is
        measured against it."""
        return self._shifted(master)

    # -- helpers --------------------------------------------------------------------
    def _shifted(self, m: MotionState) -> MotionState:
        if self.mode != Mode.RELATIVE:
            return m
        o = self._offset_pos
        p = m.pos
        return MotionState((p[0] + o[0], p[1] + o[1], p[2] + o[2]), m.vel, m.acc,
                           m.ang + self._offset_ang, m.ang_vel, m.ang_acc, m.jerk, m.ang_jerk)

    def _start_sync(self, master: MotionState) -> None:
        self.mode = self._request_mode or self.params.mode
        sp = self.setpoint
        if self.mode == Mode.RELATIVE:
            back = master.extrapolated(-self.T)
            self._offset_pos = tuple(s - m for s, m in zip(sp.pos, back.pos))
            self._offset_ang = sp.ang - back.ang
        else:
            self._offset_pos = (0.0, 0.0, 0.0)
            self._offset_ang = 0.0
        self._planners[0].reset(sp.pos, sp.vel, sp.acc)
        self._planners[1].reset((sp.ang,), (sp.ang_vel,), (sp.ang_acc,))
        for m in self._osc:
            m.reset()
        self._synced = [False, False]
        self._approach_start = self.sample
        self.synced_at = None
        self.error = TrackError.NONE
        self._desync = None
        self.state = TrackState.SYNCING

    def _start_desync(self, start_sample: int) -> None:
        """Stop on the path from the setpoint of ``start_sample`` (the last one computed)."""
        built = self.desync_builder(self) if self.desync_builder is not None else None
        if built is None:
            sp = self.setpoint
            lim = self.limits
            cur = self.params.desync_from_current_acceleration
            built = (
                Desync.linear(sp.pos, sp.vel, sp.acc, lim.desync_trans.acc,
                              lim.desync_trans.jerk, cur),
                Desync.linear((sp.ang,), (sp.ang_vel,), (sp.ang_acc,), lim.desync_rot.acc,
                              lim.desync_rot.jerk, cur))
        self._desync = built
        self._desync_start = start_sample
        self.state = TrackState.DESYNCING
        tr, rot = built
        p, _, _ = tr.state(tr.stop.duration)
        (a,), _, _ = rot.state(rot.stop.duration)
        self.desync_end = MotionState(vec3(p), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), a, 0.0, 0.0)
        self.desync_count += 1

    def _check_master(self, m: MotionState) -> TrackError:
        vel_max, rot_vel_max, acc_max, rot_acc_max = self._master_max
        x, y, z = m.vel  # (the vector norms written out: sums of squares in x, y, z order)
        if math.sqrt(x * x + y * y + z * z) > vel_max or abs(m.ang_vel) > rot_vel_max:
            return _MASTER_VELOCITY
        x, y, z = m.acc
        if math.sqrt(x * x + y * y + z * z) > acc_max or abs(m.ang_acc) > rot_acc_max:
            return _MASTER_ACCELERATION
        return _NO_ERROR

    # -- the cyclic call ------------------------------------------------------------
    def _hist_t(self) -> tuple:
        """Positions of setpoints k-2, k-3 (None until there are two)."""
        a, b = self._hist
        return (None, None) if a is None or b is None else (a.pos, b.pos)

    def _hist_r(self) -> tuple:
        """Angles of setpoints k-2, k-3 (None until there are two)."""
        a, b = self._hist
        return (None, None) if a is None or b is None else (a.ang, b.ang)

    def update(self, master: MotionState) -> TrackerOutput:
        """Compute the setpoint of the next sample from the master's state at that sample."""
        synced_now = self.advance(master)
        state = self.state
        return TrackerOutput(self.setpoint, state, _IMFS[state], self.error, self.sample,
                             synced_now)

    def advance(self, master: MotionState) -> bool:
        """:meth:`update` without its output record (a shell that reads ``setpoint``,
        ``state``, ``imfs`` and ``error`` itself: the FMU's step); True on the sample where
        the approach ended (``TrackerOutput.synchronized_now``)."""
        prev = self._prev  # setpoints k-2, k-3 (self.setpoint is k-1)
        self._hist = prev
        self._prev = (self.setpoint, prev[0])
        request = self._request
        if request is not None:
            self._request = None
            if request == "engage" and self.state in (TrackState.OFF, TrackState.DESYNCING):
                self._start_sync(master)
            elif request == "disengage" and self.state in (TrackState.SYNCING,
                                                           TrackState.SYNCED):
                if self._request_error:
                    self.error = self._request_error
                self._start_desync(self.sample)
        self.sample += 1
        k = self.sample
        state = self.state
        synced_now = False
        pos: Vec
        vel: Vec
        acc: Vec

        if state is _SYNCED or state is _SYNCING:
            err = self._check_master(master)
            if err:
                self.error = err
                self._start_desync(k - 1)
                state = self.state

        if state is _SYNCING:
            m = self._shifted(master)
            pl_t, pl_r = self._planners
            fo = self._follow
            sp = self.setpoint
            if self._synced[0]:
                pos, vel, acc = (m.pos, m.vel, m.acc) if fo is None else fo[0].step(
                    sp.pos, sp.vel, sp.acc, m.pos, m.vel, m.acc, m.jerk, *self._hist_t())
            else:
                pos, vel, acc, ok = pl_t.step(m.pos, m.vel, m.acc, m.jerk)
                self._synced[0] = ok
                if ok and fo is not None:  # the switch: close what is left within the limits
                    pos, vel, acc = fo[0].step(sp.pos, sp.vel, sp.acc, m.pos, m.vel, m.acc,
                                               m.jerk, *self._hist_t())
                if not ok and self._osc[0].update(
                        k, tuple([a - b for a, b in zip(m.vel, vel)])):
                    self.error = TrackError.OVER_OSCILLATION
            if self._synced[1]:
                if fo is None:
                    ang, ang_vel, ang_acc = m.ang, m.ang_vel, m.ang_acc
                else:
                    ang, ang_vel, ang_acc = fo[1].step1(
                        sp.ang, sp.ang_vel, sp.ang_acc, m.ang, m.ang_vel, m.ang_acc,
                        m.ang_jerk, *self._hist_r())
            else:
                (ang,), (ang_vel,), (ang_acc,), ok = pl_r.step(
                    (m.ang,), (m.ang_vel,), (m.ang_acc,), (m.ang_jerk,))
                self._synced[1] = ok
                if ok and fo is not None:
                    ang, ang_vel, ang_acc = fo[1].step1(
                        sp.ang, sp.ang_vel, sp.ang_acc, m.ang, m.ang_vel, m.ang_acc,
                        m.ang_jerk, *self._hist_r())
                if not ok and self._osc[1].update(k, (m.ang_vel - ang_vel,)):
                    self.error = TrackError.OVER_OSCILLATION
            if self._trusted:
                self.setpoint = motion_state(vec3(pos), vec3(vel), vec3(acc), ang, ang_vel,
                                             ang_acc)
            else:
                self.setpoint = MotionState(vec3(pos), vec3(vel), vec3(acc), ang, ang_vel,
                                            ang_acc)
            if self._synced[0] and self._synced[1]:
                self.state = TrackState.SYNCED
                self.synced_at = k
                synced_now = True
            elif self.error == TrackError.NONE and k - self._approach_start >= self._timeout_samples:
                self.error = TrackError.APPROACH_TIMEOUT
            if self.error and self.state == TrackState.SYNCING:
                self._start_desync(k)
        elif state is _SYNCED:
            m = master if self.mode != _RELATIVE else self._shifted(master)
            fo = self._follow
            if fo is None:
                self.setpoint = m
            else:
                sp = self.setpoint
                h2, h3 = self._hist
                if h2 is None or h3 is None:
                    pos, vel, acc = fo[0].step(sp.pos, sp.vel, sp.acc, m.pos, m.vel, m.acc,
                                               m.jerk)
                    ang, ang_vel, ang_acc = fo[1].step1(sp.ang, sp.ang_vel, sp.ang_acc, m.ang,
                                                        m.ang_vel, m.ang_acc, m.ang_jerk)
                else:
                    pos, vel, acc = fo[0].step(sp.pos, sp.vel, sp.acc, m.pos, m.vel, m.acc,
                                               m.jerk, h2.pos, h3.pos)
                    ang, ang_vel, ang_acc = fo[1].step1(sp.ang, sp.ang_vel, sp.ang_acc, m.ang,
                                                        m.ang_vel, m.ang_acc, m.ang_jerk,
                                                        h2.ang, h3.ang)
                # vec3 written out (three calls less per sample); not converted: the
                # follower returns the master's tuples (a MotionState's: converted when it
                # was made) or Python floats it computed
                x, y, z = pos
                vx, vy, vz = vel
                ax, ay, az = acc
                self.setpoint = motion_state((x, y, z), (vx, vy, vz), (ax, ay, az), ang,
                                             ang_vel, ang_acc)
        elif state is _DESYNCING:
            t = (k - self._desync_start) * self.T
            assert self._desync is not None  # set with the DESYNCING state
            tr, rot = self._desync
            pos, vel, acc = tr.state(t)
            (ang,), (ang_vel,), (ang_acc,) = rot.state(t)
            self.setpoint = MotionState(vec3(pos), vec3(vel), vec3(acc), ang, ang_vel, ang_acc)
            if tr.finished(t) and rot.finished(t):
                self.state = TrackState.OFF
                self._desync = None
        else:  # OFF: the robot continues its own motion
            self.setpoint = self.setpoint.extrapolated(self.T)

        return synced_now

