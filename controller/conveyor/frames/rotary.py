"""Type 1 (rotary) and type 2 (rotary decoupled) moving frames: an arc through three points.

Spec: docs/spec/conveyor.md#3.4 (softMC's rotary moving frame).  NOF = 1: the single DOF is the
running arc angle x [deg].  The user gives UpStream[1] (a location, with master value
UpMaster[1]), ArcPoint (a position) and DownStream[1] (a position, master value
DownMaster[1]).  The three positions define:

- ``center`` - the circle's center; ``radius`` R - its radius;
- ``start`` - unit vector from the center to UpStream[1];
- ``normal`` - unit vector in the arc's plane, normal to ``start``, pointing the way the arc
  runs (from UpStream[1] through ArcPoint to DownStream[1]);
- ``alpha`` - the arc angle [deg] from UpStream[1] to DownStream[1] (0 < alpha < 360);
- ``axis`` v - the unit rotation axis of the arc (right-hand rule in the running direction).

**softMC's description contradicts itself** (docs/spec/conveyor.md#3.4.2).  It writes
``MF(t).pos = (R+dR)*(start*sin(x) + normal*cos(x)) + center`` and, in the same place,
``UpStream[1].pos = center + R*start`` and ``DownStream[1].pos = center +
R*(start*sin(alpha) + normal*cos(alpha))``: with the first formula x = 0 is at
``center + R*normal``, not at UpStream[1].  softMC's tracking algorithm (its stopping state)
writes the arc as ``start*cos(alpha) + normal*sin(alpha) + center``.  **Our reading** keeps
the stated identity (UpStream[1] is the arc's start, x = 0) and the algorithm's form::

    MF(x).pos = center + (R + dR) * (start*cos(x) + normal*sin(x))      x in [0, alpha]
    UpStream[1].pos   = center + R*start                                (x = 0)
    DownStream[1].pos = center + R*(start*cos(alpha) + normal*sin(alpha))

This is the published trajectory formula with the names ``start`` and ``normal`` exchanged, so
its axis ``v = normal x start`` (in its names) is ``v = start x normal`` in ours: the axis
about which the position turns with increasing x.  The orientation turns with the position
(a rigid rotary table; docs/spec/conveyor.md#3.4.3)::

    MF(x).ori = Q(x, v) * UpStream[1].ori  (type 1)          = Q(x + Delta, v)  when
    UpStream[1].ori = Q(Delta, v), softMC's equation for Delta
    MF(x).ori = UpStream[1].ori             (type 2, decoupled: does not turn with x)

softMC defines Delta by ``UpStream[1].ori = Q(Delta, v)``, which has a solution only if
UpStream[1].ori is a rotation about v.  ``Q(x, v)*UpStream[1].ori`` equals ``Q(x + Delta, v)``
then and stays defined otherwise (the item keeps its tilt); :attr:`RotaryGeometry.delta_deg`
is the twist angle of UpStream[1].ori about v (the exact Delta when it exists) and
:attr:`RotaryGeometry.ori_about_axis` says whether it does.

Only the orientation of UpStream[1] matters; the orientations of ArcPoint and DownStream[1]
are ignored (they are positions here).  ``dR`` [mm] is the radius offset of the item's
trigger.

**The running angle** (docs/spec/conveyor.md#3.4.4; softMC's formula for it is missing
from its description).  Our reading: the master source value m runs linearly with the angle, so that
UpMaster[1] and DownMaster[1] are the values at the two ends::

    x(t) = alpha * (m(t) - trig) / (DownMaster[1] - UpMaster[1])        [deg]

with ``trig`` the item's trigger value ("the offset values of the conveyor angle will be
defined by the trigger value of the master source"): an item is at UpStream[1] (x = 0) when
triggered.  The scale may be given directly instead (``deg_per_unit``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from ...errors import ParameterError
from ...tracking.values import python_class
from ..errors import ArcGeometryError
from ..location import (Location, Quat, Vec3, vec3, q_axis_angle, q_conj, q_mul, q_rotate,
                        q_twist_angle, q_angle_between, v_add, v_cross, v_dot, v_norm, v_scale,
                        v_sub)
from .base import FramePoint

#: three points whose triangle is thinner than this (|a x b| / (|a| |b|)) count as collinear
COLLINEAR_TOLERANCE = 1e-9


@python_class
@dataclass(frozen=True, slots=True)
class ArcGeometry:
    """The circle pre-calculation of a rotary frame (all vectors in world coordinates).

    ``center`` [mm], ``start``/``normal``/``axis`` unit vectors, ``radius`` [mm], ``alpha_deg``.
    """

    center: Vec3
    start: Vec3
    normal: Vec3
    axis: Vec3
    radius: float
    alpha_deg: float

    def position(self, x_deg: float, dr_mm: float = 0.0) -> Vec3:
        """``center + (R + dR)*(start*cos(x) + normal*sin(x))``."""
        xr = math.radians(x_deg)
        r = self.radius + dr_mm
        c, s = math.cos(xr), math.sin(xr)
        return vec3(o + r * (a * c + b * s) for o, a, b in zip(self.center, self.start,
                                                              self.normal))


def arc_from_points(up: Sequence[float], arc_point: Sequence[float],
                    down: Sequence[float]) -> ArcGeometry:
    """The arc from UpStream[1] through ArcPoint to DownStream[1] (positions in mm).

    Raises :class:`ArcGeometryError` if the points are collinear or two of them coincide.
    """
    p1, p2, p3 = (tuple(float(x) for x in p) for p in (up, arc_point, down))
    a = v_sub(p1, p3)
    b = v_sub(p2, p3)
    axb = v_cross(a, b)
    na, nb, nab = v_norm(a), v_norm(b), v_norm(axb)
    d12 = v_norm(v_sub(p1, p2))
    if na == 0.0 or nb == 0.0 or d12 == 0.0 or nab <= COLLINEAR_TOLERANCE * na * nb:
        raise ArcGeometryError(
            f"the rotary moving frame's points UpStream[1] = {p1}, ArcPoint = {p2} and "
            f"DownStream[1] = {p3} are collinear (or coincide): they do not define an arc")
    # circumcenter: p3 + ((|a|^2 b - |b|^2 a) x (a x b)) / (2 |a x b|^2)
    u = v_sub(v_scale(b, na * na), v_scale(a, nb * nb))
    center = v_add(p3, v_scale(v_cross(u, axb), 1.0 / (2.0 * nab * nab)))
    r1 = v_sub(p1, center)
    radius = v_norm(r1)
    start = v_scale(r1, 1.0 / radius)
    # running direction: P1 -> P2 -> P3 turns about (P2 - P1) x (P3 - P2)
    w = v_cross(v_sub(p2, p1), v_sub(p3, p2))
    axis = v_scale(w, 1.0 / v_norm(w))
    normal = v_cross(axis, start)
    normal = v_scale(normal, 1.0 / v_norm(normal))
    r3 = v_sub(p3, center)
    alpha = math.degrees(math.atan2(v_dot(r3, normal), v_dot(r3, start)))
    if alpha <= 0.0:
        alpha += 360.0
    return ArcGeometry(center, start, normal, axis, radius, alpha)


@python_class
@dataclass(frozen=True, slots=True)
class RotaryGeometry:
    """A rotary frame for one arc.  ``upstream``: UpStream[1] (its orientation is the frame's
    orientation at x = 0); ``deg_per_unit``: running-angle scale [deg per source unit];
    ``decoupled``: type 2 (the orientation does not follow x)."""

    arc: ArcGeometry
    upstream: Location
    deg_per_unit: float
    decoupled: bool = False

    def __post_init__(self) -> None:
        if not (math.isfinite(self.deg_per_unit) and self.deg_per_unit != 0.0):
            raise ParameterError(f"deg_per_unit (={self.deg_per_unit!r}) must be a finite "
                                 "non-zero number [deg per source unit]")

    @classmethod
    def from_points(cls, upstream: Location, arc_point: Sequence[float],
                    downstream: Sequence[float], *, up_master: float = 0.0,
                    down_master: float | None = None, deg_per_unit: float | None = None,
                    decoupled: bool = False) -> "RotaryGeometry":
        """Build from softMC's three points and UpMaster[1]/DownMaster[1] (or a scale)."""
        arc = arc_from_points(upstream.pos, arc_point, downstream)
        if deg_per_unit is None:
            if down_master is None or down_master == up_master:
                raise ParameterError(
                    f"DownMaster[1] (={down_master!r}) must differ from UpMaster[1] "
                    f"(={up_master!r}), or give deg_per_unit")
            deg_per_unit = arc.alpha_deg / (down_master - up_master)
        return cls(arc, upstream, float(deg_per_unit), decoupled)

    # (properties, not class attributes: compiled, a dataclass's class attributes would be
    # fields, docs/architecture.md "Compiled core")
    @property
    def nof(self) -> int:
        return 1

    @property
    def units(self) -> str:
        return "deg"

    @property
    def center(self) -> Vec3:
        return self.arc.center

    @property
    def start(self) -> Vec3:
        return self.arc.start

    @property
    def normal(self) -> Vec3:
        return self.arc.normal

    @property
    def radius(self) -> float:
        return self.arc.radius

    @property
    def alpha_deg(self) -> float:
        return self.arc.alpha_deg

    @property
    def axis(self) -> Vec3:
        return self.arc.axis

    @property
    def rotates(self) -> bool:
        return not self.decoupled

    @property
    def delta_deg(self) -> float:
        """softMC's Delta: UpStream[1].ori = Q(Delta, v) (twist about v if not exact;
        docs/spec/conveyor.md#3.4.3)."""
        return q_twist_angle(self.upstream.ori, self.arc.axis)

    @property
    def ori_about_axis(self) -> bool:
        """True when UpStream[1].ori is a rotation about v (Delta exists)."""
        return q_angle_between(self.upstream.ori,
                               q_axis_angle(self.arc.axis, self.delta_deg)) < 1e-6

    @property
    def local_axis(self) -> Vec3:
        """The rotation axis of ``MF(0) ⊖ MF(t)`` orientations: UpStream[1].ori⁻¹ · v."""
        return q_rotate(q_conj(self.upstream.ori), self.arc.axis)

    def coords(self, values: Sequence[float], trigger: Sequence[float]) -> tuple[float, ...]:
        """The running angle x [deg] of an item triggered at ``trigger[0]``."""
        return (self.deg_per_unit * (values[0] - trigger[0]),)

    def rates(self, rates: Sequence[float]) -> tuple[float, ...]:
        return (self.deg_per_unit * rates[0],)

    def orientation(self, x_deg: float) -> Quat:
        if self.decoupled:
            return self.upstream.ori
        return q_mul(q_axis_angle(self.arc.axis, x_deg), self.upstream.ori)

    def zero(self, dr_mm: float = 0.0, item: object = None) -> Location:
        """MF.zero for an item with radius offset ``dr_mm``: x = 0."""
        return Location(self.arc.position(0.0, dr_mm), self.upstream.ori)

    def point(self, c: Sequence[float], cd: Sequence[float], cdd: Sequence[float],
              dr_mm: float = 0.0, item: object = None) -> FramePoint:
        arc = self.arc
        x, xd, xdd = c[0], cd[0], cdd[0]
        xr, wd, wdd = math.radians(x), math.radians(xd), math.radians(xdd)
        r = arc.radius + dr_mm
        cs, sn = math.cos(xr), math.sin(xr)
        radial = tuple(a * cs + b * sn for a, b in zip(arc.start, arc.normal))
        tangent = tuple(-a * sn + b * cs for a, b in zip(arc.start, arc.normal))
        pos = vec3(o + r * u for o, u in zip(arc.center, radial))
        vel = vec3(r * wd * t for t in tangent)
        acc = vec3(r * (wdd * t - wd * wd * u) for t, u in zip(tangent, radial))
        here = Location(pos, self.orientation(x))
        if self.decoupled:
            return FramePoint(here, vel, acc)
        return FramePoint(here, vel, acc, x, xd, xdd)
