"""Locations (position + unit quaternion) and softMC's operators ⊕, ⊖ and ':'.

Spec: docs/spec/conveyor.md#2 (locations #2.1, operators #2.2, algebra #2.3) and #6.3 (the
proof with base and tool).  Units: positions in mm, angles in deg.

Quaternions are Hamilton quaternions written as tuples ``(w, x, y, z)``; a unit quaternion q
rotates a vector v as q·v·q⁻¹.  ``q_axis_angle(axis, angle_deg)`` is softMC's Q(angle, axis)
("the quaternion defined by the rotation vector and rotation angle about it").

softMC's operators, implemented exactly::

    C = A ⊕ B:   C.pos = A.pos + B.pos      C.ori = A.ori * B.ori
    C = A ⊖ B:   C.pos = A.pos - B.pos      C.ori = B.ori⁻¹ * A.ori

and the compound ':' of two frames (rigid transforms, "base:Robot:tool")::

    C = A : B:   C.pos = A.pos + A.ori·B.pos·A.ori⁻¹      C.ori = A.ori * B.ori

Algebra (used by the tracking scheme and tested): ⊕ is associative with the identity
location I = (0, 1) as neutral element; ``A ⊕ (B ⊖ A) = B`` for every A, B (the step of
softMC's Q.E.D. ``MF(0) ⊕ [MF(t) ⊖ MF(0)] = MF(t)``); ``A ⊖ B = B⁻ ⊕ A`` with the ⊕-inverse
``B⁻ = (-B.pos, B.ori⁻¹)``.  Note that ``(A ⊕ B) ⊖ B`` is *not* A in general (its orientation
is B.ori⁻¹·A.ori·B.ori): ⊕ multiplies on the right, ⊖ divides on the left, as softMC writes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterable, Sequence

from ..errors import ParameterError
from ..tracking.values import python_class

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]

Q_IDENTITY: Quat = (1.0, 0.0, 0.0, 0.0)
ZERO3: Vec3 = (0.0, 0.0, 0.0)

#: a quaternion whose norm differs from 1 by more than this is rejected as "not a rotation"
UNIT_TOLERANCE = 1e-6


# -- 3-vectors ----------------------------------------------------------------------------
def vec3(a: Iterable[float]) -> Vec3:
    """``a`` (three components, e.g. a per-axis generator) as a 3-tuple; a ValueError
    otherwise (for internal results whose length is 3 by construction)."""
    x, y, z = a
    return (x, y, z)


def pos3(pos: Iterable[float]) -> Vec3:
    """A location's position given by a caller: a ParameterError unless 3 components."""
    t = tuple(pos)
    if len(t) != 3:
        raise ParameterError(f"location pos (={t!r}) must be 3 finite numbers [mm]")
    return t


def v_add(a: Sequence[float], b: Sequence[float]) -> Vec3:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def v_sub(a: Sequence[float], b: Sequence[float]) -> Vec3:
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def v_scale(a: Sequence[float], s: float) -> Vec3:
    return (a[0] * s, a[1] * s, a[2] * s)


def v_dot(a: Sequence[float], b: Sequence[float]) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def v_cross(a: Sequence[float], b: Sequence[float]) -> Vec3:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def v_norm(a: Sequence[float]) -> float:
    return math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])


def v_unit(a: Sequence[float], what: str = "vector") -> Vec3:
    """``a / |a|``; a zero (or non-finite) vector is a ParameterError naming ``what``."""
    n = v_norm(a)
    if not (n > 0.0 and math.isfinite(n)):
        raise ParameterError(f"{what} (={tuple(a)!r}) must be a non-zero finite vector")
    return (a[0] / n, a[1] / n, a[2] / n)


# -- quaternions --------------------------------------------------------------------------
def q_mul(a: Sequence[float], b: Sequence[float]) -> Quat:
    """Hamilton product a·b."""
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def q_conj(q: Sequence[float]) -> Quat:
    return (q[0], -q[1], -q[2], -q[3])


def q_norm(q: Sequence[float]) -> float:
    return math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])


def q_inv(q: Sequence[float]) -> Quat:
    """The quaternion inverse q⁻¹ = conj(q)/|q|² (= conj(q) for a unit quaternion)."""
    n2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
    if n2 == 0.0:
        raise ParameterError("the zero quaternion has no inverse")
    return (q[0] / n2, -q[1] / n2, -q[2] / n2, -q[3] / n2)


def q_normalize(q: Sequence[float]) -> Quat:
    n = q_norm(q)
    if not (n > 0.0 and math.isfinite(n)):
        raise ParameterError(f"quaternion (={tuple(q)!r}) must be non-zero and finite")
    return (q[0] / n, q[1] / n, q[2] / n, q[3] / n)


def q_rotate(q: Sequence[float], v: Sequence[float]) -> Vec3:
    """The vector v rotated by the unit quaternion q (q·v·q⁻¹)."""
    w, x, y, z = q
    # t = 2 * (q_vec x v); v' = v + w*t + q_vec x t
    tx = 2.0 * (y * v[2] - z * v[1])
    ty = 2.0 * (z * v[0] - x * v[2])
    tz = 2.0 * (x * v[1] - y * v[0])
    return (v[0] + w * tx + (y * tz - z * ty),
            v[1] + w * ty + (z * tx - x * tz),
            v[2] + w * tz + (x * ty - y * tx))


def q_axis_angle(axis: Sequence[float], angle_deg: float) -> Quat:
    """softMC's Q(angle, axis): rotation by ``angle_deg`` [deg] about the unit ``axis``."""
    h = math.radians(angle_deg) * 0.5
    s = math.sin(h)
    return (math.cos(h), axis[0] * s, axis[1] * s, axis[2] * s)


def q_to_axis_angle(q: Sequence[float]) -> tuple[Vec3, float]:
    """(unit axis, angle [deg] in [0, 180]) of a unit quaternion; axis (0, 0, 1) for angle 0."""
    w, x, y, z = q if q[0] >= 0.0 else (-q[0], -q[1], -q[2], -q[3])
    s = math.sqrt(x * x + y * y + z * z)
    if s < 1e-15:
        return (0.0, 0.0, 1.0), 0.0
    return (x / s, y / s, z / s), math.degrees(2.0 * math.atan2(s, w))


def q_twist_angle(q: Sequence[float], axis: Sequence[float]) -> float:
    """Angle [deg, (-180, 180]] of the twist of q about the unit ``axis`` (swing-twist split).

    If q is a rotation about ``axis`` this is exactly its angle; otherwise it is the angle of
    the rotation about ``axis`` closest to q.
    """
    p = q[1] * axis[0] + q[2] * axis[1] + q[3] * axis[2]
    ang = math.degrees(2.0 * math.atan2(p, q[0]))
    if ang > 180.0:
        ang -= 360.0
    elif ang <= -180.0:
        ang += 360.0
    return ang


def q_angle_between(a: Sequence[float], b: Sequence[float]) -> float:
    """Rotation angle [deg] between two unit quaternions (0 when they are the same rotation)."""
    r = q_mul(q_conj(a), b)  # well conditioned near 0, unlike acos(|a.b|)
    return math.degrees(2.0 * math.atan2(math.sqrt(r[1] * r[1] + r[2] * r[2] + r[3] * r[3]),
                                         abs(r[0])))


def q_slerp(a: Sequence[float], b: Sequence[float], s: float) -> Quat:
    """Spherical interpolation from a (s = 0) to b (s = 1), the short way."""
    d = a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3]
    if d < 0.0:
        b = (-b[0], -b[1], -b[2], -b[3])
        d = -d
    if d > 0.9999995:
        return q_normalize(tuple(x + s * (y - x) for x, y in zip(a, b)))
    th = math.acos(d)
    sa = math.sin((1.0 - s) * th) / math.sin(th)
    sb = math.sin(s * th) / math.sin(th)
    return (sa * a[0] + sb * b[0], sa * a[1] + sb * b[1], sa * a[2] + sb * b[2],
            sa * a[3] + sb * b[3])


def q_power(q: Sequence[float], s: float) -> Quat:
    """q^s for a unit quaternion (the rotation scaled to s times its angle, same axis)."""
    return q_slerp(Q_IDENTITY, q, s)


# -- locations ----------------------------------------------------------------------------
@python_class
@dataclass(frozen=True, slots=True)
class Location:
    """A softMC location: ``pos`` [mm] and ``ori``, a unit quaternion (w, x, y, z).

    ``ori`` must have norm 1 within :data:`UNIT_TOLERANCE` and is stored normalised.
    """

    pos: Vec3 = ZERO3
    ori: Quat = Q_IDENTITY

    def __post_init__(self) -> None:
        if len(self.pos) != 3 or not all(math.isfinite(float(x)) for x in self.pos):
            raise ParameterError(f"location pos (={self.pos!r}) must be 3 finite numbers [mm]")
        if len(self.ori) != 4 or not all(math.isfinite(float(x)) for x in self.ori):
            raise ParameterError(f"location ori (={self.ori!r}) must be 4 finite numbers "
                                 "(w, x, y, z)")
        n = q_norm(self.ori)
        if abs(n - 1.0) > UNIT_TOLERANCE:
            raise ParameterError(f"location ori (={self.ori!r}) must be a unit quaternion "
                                 f"(norm {n!r}, allowed 1 +- {UNIT_TOLERANCE:g})")
        object.__setattr__(self, "pos", tuple(float(x) for x in self.pos))
        object.__setattr__(self, "ori", tuple(float(x) / n for x in self.ori))

    # -- constructors
    @staticmethod
    def trusted(pos: Vec3, ori: Quat) -> "Location":
        """A Location from values known to be valid (3 floats [mm], a unit quaternion to
        rounding): ``ori`` normalised as the constructor does, without its checks (the
        per-sample paths, about 4x cheaper)."""
        return _loc(pos, ori)

    @classmethod
    def identity(cls) -> "Location":
        return cls()

    @classmethod
    def at(cls, x: float = 0.0, y: float = 0.0, z: float = 0.0) -> "Location":
        return cls((x, y, z), Q_IDENTITY)

    @classmethod
    def from_axis_angle(cls, pos: Sequence[float], axis: Sequence[float],
                        angle_deg: float) -> "Location":
        """Position [mm] and the rotation Q(angle_deg, axis) (axis normalised here)."""
        return cls(pos3(pos), q_axis_angle(v_unit(axis, "rotation axis"), angle_deg))

    # -- softMC's operators (docs/spec/conveyor.md#2.2)
    def oplus(self, other: "Location") -> "Location":
        """``self ⊕ other``: pos added, ori = self.ori·other.ori."""
        return _loc(v_add(self.pos, other.pos), q_mul(self.ori, other.ori))

    def ominus(self, other: "Location") -> "Location":
        """``self ⊖ other``: pos subtracted, ori = other.ori⁻¹·self.ori."""
        return _loc(v_sub(self.pos, other.pos), q_mul(q_conj(other.ori), self.ori))

    def compound(self, other: "Location") -> "Location":
        """``self : other`` (frame composition): pos + ori(other.pos), ori·other.ori."""
        return _loc(v_add(self.pos, q_rotate(self.ori, other.pos)), q_mul(self.ori, other.ori))

    def inverse(self) -> "Location":
        """The compound inverse self⁻¹ (``self : self⁻¹ = I``)."""
        qi = q_conj(self.ori)
        p = q_rotate(qi, self.pos)
        return _loc((-p[0], -p[1], -p[2]), qi)

    def oplus_inverse(self) -> "Location":
        """The ⊕-inverse (-pos, ori⁻¹): ``A ⊕ A.oplus_inverse() = I``."""
        return _loc((-self.pos[0], -self.pos[1], -self.pos[2]), q_conj(self.ori))

    # -- comparisons
    def distance_to(self, other: "Location") -> float:
        """Position distance [mm]."""
        return v_norm(v_sub(self.pos, other.pos))

    def angle_to(self, other: "Location") -> float:
        """Orientation difference [deg]."""
        return q_angle_between(self.ori, other.ori)

    def isclose(self, other: "Location", pos_tol_mm: float = 1e-9,
                ang_tol_deg: float = 1e-7) -> bool:
        return self.distance_to(other) <= pos_tol_mm and self.angle_to(other) <= ang_tol_deg


#: the slots of Location, set directly (a frozen dataclass refuses setattr)
_set_pos = vars(Location)["pos"].__set__
_set_ori = vars(Location)["ori"].__set__
_new = object.__new__


def _loc(pos: Vec3, ori: Quat) -> Location:
    """A Location from values known to be valid (normalises ori without the checks' cost)."""
    loc = _new(Location)
    w, x, y, z = ori
    n = math.sqrt(w * w + x * x + y * y + z * z)  # (q_norm written out)
    _set_pos(loc, pos)
    _set_ori(loc, ori if n == 1.0 else (w / n, x / n, y / n, z / n))
    return loc


def oplus(*locations: Location) -> Location:
    """``A ⊕ B ⊕ ...`` left to right (⊕ is associative)."""
    it = iter(locations)
    acc = next(it)
    for loc in it:
        acc = acc.oplus(loc)
    return acc


def ominus(a: Location, b: Location) -> Location:
    """``a ⊖ b``."""
    return a.ominus(b)


def compound(*locations: Location) -> Location:
    """``A : B : ...`` left to right."""
    it = iter(locations)
    acc = next(it)
    for loc in it:
        acc = acc.compound(loc)
    return acc


def as_location(value: Location | Iterable[float]) -> Location:
    """A Location from a Location or a position (x, y, z) [mm] with identity orientation."""
    if isinstance(value, Location):
        return value
    return Location(pos3(value))
