"""The core tracker with the de-sync "on the path" of a rotary frame: along the arc.

Spec: docs/spec/conveyor.md#8.2 (softMC: "The process will be 'on the path' ... reducing the
initial velocity to zero along the same direction of the Moving Frame"; in its algorithm
the stop runs on the curvature angle: desync.pos/vel/acc = alpha, alpha', alpha'';
p = start*cos(alpha) + normal*sin(alpha) + center).

:class:`ConveyorTracker` is :class:`controller.tracking.Tracker` with one override: when it
starts a de-sync from SYNCED and an arc is set (:meth:`ConveyorTracker.set_arc`), the stop
runs along that arc instead of the core's straight line.  The arc of the stop passes through
the current setpoint: same center line and axis as the frame's circle, radius = the setpoint's
distance from the axis, ``start`` = the unit radial vector at the setpoint, ``normal =
axis x start`` (so alpha grows in the running direction), alpha(0) = 0,
alpha'(0) = v.normal/r, alpha''(0) = a.normal/r (the tangential part; the centripetal part of
the acceleration is the arc's own).  The path parameter is stopped by the core's
:class:`controller.tracking.desync.SineStop` with the de-sync limits mapped to the arc:
acceleration min(A_trans/r, A_rot) and jerk min(J_trans/r, J_rot) [rad/s^2, rad/s^3]
(A_rot/J_rot only when the orientation turns with the arc, type 1).  The angle channel stops
with the same profile (``ang = ang0 + deg(alpha)``, type 1) so the orientation stays the
one of the point on the arc; for type 2 it is the core's 1-D stop (of a zero rate).

A de-sync that starts during the approach (SYNCING: the setpoint is not on the arc yet) uses
the core's straight-line stop along the current velocity: an arc through a point off the path
would make a velocity step.

The arc is supplied through the core's public ``Tracker.desync_builder`` hook; the core
records where the stop ends (``Tracker.desync_end``), which the conveyor model needs the
moment the de-sync starts (the virtual stopping position, docs/spec/conveyor.md#8.1 and #9).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..tracking import MotionState, Tracker, TrackerParams, TrackState
from ..tracking.desync import Desync, SineStop
from ..tracking.vec import Vec
from ..errors import ParameterError
from ..tracking.values import mypyc_attr, python_class
from .location import Vec3, v_cross, v_dot, v_norm, v_scale, v_sub, vec3


@python_class
@dataclass(frozen=True, slots=True)
class ArcPath:
    """p = center + r*(start*cos(s) + normal*sin(s)), s in rad (a ``DesyncPath``)."""

    center: Vec3
    start: Vec3
    normal: Vec3
    radius: float

    def evaluate(self, s: float, sd: float, sdd: float) -> tuple[Vec, Vec, Vec]:
        c, sn = math.cos(s), math.sin(s)
        r = self.radius
        radial = tuple(a * c + b * sn for a, b in zip(self.start, self.normal))
        tangent = tuple(-a * sn + b * c for a, b in zip(self.start, self.normal))
        pos = tuple(o + r * u for o, u in zip(self.center, radial))
        vel = tuple(r * sd * t for t in tangent)
        acc = tuple(r * (sdd * t - sd * sd * u) for t, u in zip(tangent, radial))
        return pos, vel, acc


@python_class
@dataclass(frozen=True, slots=True)
class AnglePath:
    """The angle channel coupled to an arc: ang = ang0 + gain*s (gain = 180/pi deg/rad)."""

    ang0: float
    gain: float

    def evaluate(self, s: float, sd: float, sdd: float) -> tuple[Vec, Vec, Vec]:
        g = self.gain
        return (self.ang0 + g * s,), (g * sd,), (g * sdd,)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class ConveyorTracker(Tracker):
    """A :class:`Tracker` that de-syncs along an arc when one is set.

    ``desync_count`` counts de-sync starts; ``desync_end`` is the state the current (or last)
    stop ends in (position [mm], angle [deg], at rest).
    """

    def __init__(self, params: TrackerParams | None = None,
                 initial: MotionState | None = None) -> None:
        super().__init__(params, initial)
        self._arc: tuple[Vec3, Vec3, bool] | None = None
        #: "arc" or "line": the path of the last de-sync
        self.desync_path = ""
        self.desync_builder = self._build_desync

    def set_arc(self, center: Vec3 | None, axis: Vec3 | None = None,
                couple_angle: bool = True) -> None:
        """The arc (a point on its axis, unit axis) for the next de-sync; None: a line."""
        if center is not None and axis is None:
            raise ParameterError("set_arc: an arc needs its axis with its center")
        self._arc = None if center is None or axis is None else (
            vec3(center), vec3(axis), couple_angle)

    def _build_desync(self, _tracker: Tracker) -> tuple[Desync, Desync] | None:
        """The core's ``desync_builder``: along the arc when one is set and synchronised."""
        built = None
        if self._arc is not None and self.state == TrackState.SYNCED:
            built = self._arc_desync(*self._arc)
        self.desync_path = "arc" if built is not None else "line"
        return built

    def _arc_desync(self, center: Vec3, axis: Vec3,
                    couple: bool) -> tuple[Desync, Desync] | None:
        sp = self.setpoint
        rel = v_sub(sp.pos, center)
        h = v_dot(rel, axis)
        radial = v_sub(rel, v_scale(axis, h))
        r = v_norm(radial)
        if not r > 1e-9:
            return None
        start = v_scale(radial, 1.0 / r)
        normal = v_cross(axis, start)
        c0 = vec3(c + h * a for c, a in zip(center, axis))
        cur = self.params.desync_from_current_acceleration
        sd0 = v_dot(sp.vel, normal) / r
        sdd0 = v_dot(sp.acc, normal) / r if cur else 0.0
        lt, lr = self.limits.desync_trans, self.limits.desync_rot
        acc, jerk = lt.acc / r, lt.jerk / r
        if couple:
            acc = min(acc, math.radians(lr.acc))
            jerk = min(jerk, math.radians(lr.jerk))
        stop = SineStop(sd0, sdd0, acc, jerk)
        trans = Desync(ArcPath(c0, start, normal, r), stop)
        if couple:
            rot = Desync(AnglePath(sp.ang, 180.0 / math.pi), stop)
        else:
            rot = Desync.linear((sp.ang,), (sp.ang_vel,), (sp.ang_acc,), lr.acc, lr.jerk, cur)
        return trans, rot
