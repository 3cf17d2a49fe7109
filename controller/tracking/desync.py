"""De-synchronisation "on the path": a sine-acceleration stop along a path.

Spec: docs/spec/tracking.md#5.  softMC replaces the real master at disengagement by a
virtual one with the same initial velocity, reduced to zero along the direction of the
moving frame with a sine-acceleration profile; its algorithm drives a path parameter alpha
(alpha, alpha', alpha'' from a profiler; p = start*cos(alpha) + normal*sin(alpha) + center
for an arc, p = direction*l(t) + pos for a line; #5.1).

The stop profile is not written out by softMC (docs/spec/tracking.md#5.2).  Ours: the path speed
s' is brought from v0 to 0 with the acceleration changing along half-cosine ("sine") ramps,
a(t) = a_s + (a_e - a_s)*(1 - cos(pi*t/tau))/2, whose peak jerk is pi*|a_e - a_s|/(2*tau) = J;
ramps a0 -> a_p, an optional plateau at a_p = -A, and a_p -> 0.  Velocity, acceleration and
jerk are continuous; |a| <= max(A, |a0|), |jerk| <= J.

Which initial acceleration: softMC's algorithm starts from the current acceleration, its
conveyor overview from zero (docs/spec/tracking.md#5.3).  Starting from zero makes an
acceleration step (an unbounded jerk) when the master was accelerating, so the tracker
uses the current one by default (``TrackerParams.desync_from_current_acceleration``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from .values import mypyc_attr, python_class
from .vec import Vec


@python_class
@dataclass(frozen=True, slots=True)
class _Segment:
    """One piece of the stop profile, starting at time t0 with path state (s0, v0)."""

    t0: float
    duration: float
    s0: float
    v0: float
    a_start: float
    a_end: float  # equal to a_start for a constant-acceleration plateau

    def at(self, t: float) -> tuple[float, float, float]:
        """(s, s', s'') at ``t`` seconds into this segment."""
        a_s, da = self.a_start, self.a_end - self.a_start
        if da == 0.0 or self.duration == 0.0:
            return (self.s0 + self.v0 * t + 0.5 * a_s * t * t, self.v0 + a_s * t, a_s)
        w = math.pi / self.duration
        c = math.cos(w * t)
        acc = a_s + 0.5 * da * (1.0 - c)
        vel = self.v0 + a_s * t + 0.5 * da * (t - math.sin(w * t) / w)
        pos = self.s0 + self.v0 * t + 0.5 * a_s * t * t + 0.5 * da * (0.5 * t * t - (1.0 - c) / (w * w))
        return pos, vel, acc


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class SineStop:
    """A 1-D stop: path coordinate s from (0, v0, a0) to rest, sine-acceleration ramps.

    ``acc_max`` [unit/s^2] and ``jerk_max`` [unit/s^3] are the de-sync limits.
    """

    def __init__(self, v0: float, a0: float, acc_max: float, jerk_max: float) -> None:
        if not (acc_max > 0 and jerk_max > 0):
            raise ValueError("acc_max and jerk_max must be > 0")
        self.acc_max = float(acc_max)
        self.jerk_max = float(jerk_max)
        self.segments: list[_Segment] = []
        self._plan(0.0, 0.0, float(v0), float(a0), depth=0)
        last = self.segments[-1] if self.segments else None
        self.duration = last.t0 + last.duration if last else 0.0
        if last:
            self.end_position = last.at(last.duration)[0]
        else:
            self.end_position = 0.0

    # -- planning -------------------------------------------------------------------
    def _ramp_time(self, a_s: float, a_e: float) -> float:
        return math.pi * abs(a_e - a_s) / (2.0 * self.jerk_max)

    def _append(self, t: float, s: float, v: float, a_s: float, a_e: float,
                duration: float) -> tuple[float, float, float]:
        if duration <= 0.0:
            return t, s, v
        seg = _Segment(t, duration, s, v, a_s, a_e)
        self.segments.append(seg)
        s1, v1, _ = seg.at(duration)
        return t + duration, s1, v1

    def _plan(self, t: float, s: float, v0: float, a0: float, depth: int) -> None:
        if v0 < 0.0 or (v0 == 0.0 and a0 < 0.0):
            # mirror: plan the stop of (-v0, -a0) and flip the signs of every new segment
            first = len(self.segments)
            self._plan(t, -s, -v0, -a0, depth)
            self.segments[first:] = [
                _Segment(g.t0, g.duration, -g.s0, -g.v0, -g.a_start, -g.a_end)
                for g in self.segments[first:]
            ]
            return
        A, J = self.acc_max, self.jerk_max
        if v0 == 0.0 and a0 == 0.0:
            return
        # speed reached by ramping the acceleration straight to zero
        v_direct = v0 + math.pi * a0 * abs(a0) / (4.0 * J)
        if v_direct <= 0.0 or depth > 0 and v_direct <= 1e-12 * max(1.0, v0):
            t, s, v = self._append(t, s, v0, a0, 0.0, self._ramp_time(a0, 0.0))
            if v_direct < 0.0 and depth < 2:
                self._plan(t, s, v, 0.0, depth + 1)
            return
        # plateau-free solution: v0 + pi*(a0^2 - 2*ap^2)/(4J) = 0 with ap <= min(a0, 0)
        ap = -math.sqrt((4.0 * J * v0 / math.pi + a0 * a0) / 2.0)
        if ap >= -A:
            t, s, v = self._append(t, s, v0, a0, ap, self._ramp_time(a0, ap))
            self._append(t, s, v, ap, 0.0, self._ramp_time(ap, 0.0))
            return
        ap = -A
        t1 = self._ramp_time(a0, ap)
        t3 = self._ramp_time(ap, 0.0)
        dv_ramps = 0.5 * (a0 + ap) * t1 + 0.5 * ap * t3
        tc = max(0.0, (v0 + dv_ramps) / A)
        t, s, v = self._append(t, s, v0, a0, ap, t1)
        t, s, v = self._append(t, s, v, ap, ap, tc)
        self._append(t, s, v, ap, 0.0, t3)

    # -- evaluation -----------------------------------------------------------------
    def at(self, t: float) -> tuple[float, float, float]:
        """(s, s', s'') at time ``t`` [s] after the start; at rest after the end."""
        if not self.segments:
            return 0.0, 0.0, 0.0
        if t >= self.duration:
            return self.end_position, 0.0, 0.0
        for seg in self.segments:
            if t < seg.t0 + seg.duration:
                return seg.at(max(0.0, t - seg.t0))
        return self.end_position, 0.0, 0.0  # pragma: no cover - guarded above

    def finished(self, t: float) -> bool:
        return t >= self.duration


class DesyncPath(Protocol):
    """A path for the de-sync: maps the path coordinate s and its derivatives to a state.

    The linear conveyor supplies :class:`LinearPath`; a rotary conveyor supplies an arc
    (p = start*cos(alpha) + normal*sin(alpha) + center, docs/spec/conveyor.md#8.2).
    """

    def evaluate(self, s: float, sd: float, sdd: float) -> tuple[Vec, Vec, Vec]:
        """Position, velocity and acceleration on the path for (s, s', s'')."""
        ...


@python_class
@dataclass(frozen=True, slots=True)
class LinearPath:
    """p = origin + direction*s (docs/spec/tracking.md#5.1)."""

    origin: Vec
    direction: Vec  # unit vector

    def evaluate(self, s: float, sd: float, sdd: float) -> tuple[Vec, Vec, Vec]:
        u = self.direction
        return (tuple([o + s * x for o, x in zip(self.origin, u)]),
                tuple([sd * x for x in u]), tuple([sdd * x for x in u]))


@dataclass
@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class Desync:
    """A stop on a path, evaluated per sample: ``state(t)`` for t seconds since disengage."""

    path: DesyncPath
    stop: SineStop

    @classmethod
    def linear(cls, p: Vec, v: Vec, a: Vec, acc_max: float, jerk_max: float,
               from_current_acceleration: bool = True) -> "Desync":
        """Stop a channel moving with (p, v, a) along its velocity direction.

        The virtual master keeps the velocity's direction; its path acceleration starts at
        the component of ``a`` along that direction (or 0).  At rest with a non-zero
        acceleration, the acceleration's direction is used.
        """
        vn = math.sqrt(sum(x * x for x in v))
        an = math.sqrt(sum(x * x for x in a))
        if vn > 0.0:
            u = tuple([x / vn for x in v])
            a0 = sum(x * y for x, y in zip(a, u)) if from_current_acceleration else 0.0
            v0 = vn
        elif an > 0.0 and from_current_acceleration:
            u = tuple([x / an for x in a])
            v0, a0 = 0.0, an
        else:
            u = tuple([1.0] + [0.0] * (len(p) - 1))
            v0, a0 = 0.0, 0.0
        return cls(LinearPath(tuple(p), u), SineStop(v0, a0, acc_max, jerk_max))

    def state(self, t: float) -> tuple[Vec, Vec, Vec]:
        return self.path.evaluate(*self.stop.at(t))

    def finished(self, t: float) -> bool:
        return self.stop.finished(t)
