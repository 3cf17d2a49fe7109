"""Small Cartesian motions of the virtual robot (``MOVES`` / pick motions) for the conveyor
model, its tests and scenarios.  Deliberately small: straight lines with a jerk-limited
rest-to-rest profile, orientation by slerp on the same profile.  (The project's axis-motion
package ``controller.motion`` is separate.)

The virtual robot (docs/spec/conveyor.md#6.1; softMC: "the position of the
robot before the tracking started plus all additional robot movements entered afterwards".
:class:`VirtualRobot` is that location, in world TCP coordinates (``base:Robot_virtual:tool``):

    V(t) = B ⊕ F_1(t) ⊕ F_2(t) ⊕ ...

with B a base location and factors F_i: a motion's displacement scaled by its profile
(``Δ.pos*s(t)``, ``Δ.ori^s(t)``, s from 0 to 1) or a constant (a shift, see :meth:`shift`).
Motions are **superposed**: a motion adds its displacement on top of whatever else runs
(docs/spec/conveyor.md#8.1, "Blending/Superposition of motions will be not affected by
syncing or de-syncing").
A motion starts ("is initiated") when the previous one has ended (queued, the default) or at
once (``superpose=True``).  At its start its displacement is fixed:

- absolute target P: Δ = P ⊖ E with E the planned end of everything already started, so the
  virtual robot ends on P (E ⊕ (P ⊖ E) = P);
- relative: Δ is the given displacement (superposed on the current motion).

The conveyor model shifts V when a de-sync starts (:meth:`shift`: ``V ⊕ c``); a shift moves the
current location and the ends of the running motions alike (docs/spec/conveyor.md#8.1, see
``controller.conveyor.robot``).

Units: mm, mm/s, mm/s^2, mm/s^3; deg, deg/s, deg/s^2, deg/s^3; s.  Time is counted in samples
of the robot's sample time T: a motion started at sample k0 has t = (k - k0)*T.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from ..errors import ParameterError
from ..limits import CartesianLimits, Limits
from ..tracking.values import mypyc_attr, python_class
from .location import (Location, Q_IDENTITY, Vec3, pos3, q_mul, q_power, q_to_axis_angle,
                       v_norm, vec3)

#: marker: a motion that does not change the robot's MasterFrame
KEEP: Any = object()


#: the virtual robot's default motion limits: 500 mm/s, 5000 mm/s^2, 100000 mm/s^3;
#: 180 deg/s, 1800 deg/s^2, 36000 deg/s^3
MOTION_LIMITS = CartesianLimits(Limits(500.0, 5000.0, 100000.0), Limits(180.0, 1800.0, 36000.0))


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: predict_catch deep-copies it)
class SCurve:
    """Rest-to-rest jerk-limited profile over ``distance`` >= 0 with limits V, A, J.

    Seven phases of constant jerk (+J, 0, -J, 0, -J, 0, +J), reduced when V or A is not
    reached (Biagiotti & Melchiorri, "Trajectory Planning for Automatic Machines", 3.4 with
    v0 = v1 = 0).  ``at(t)`` gives (s, s', s'') exactly (piecewise cubic).
    """

    def __init__(self, distance: float, vel: float, acc: float, jerk: float) -> None:
        L = float(distance)
        if L < 0 or not math.isfinite(L):
            raise ParameterError(f"distance (={distance!r}) must be finite and >= 0")
        self.distance = L
        if L == 0.0:
            self.phases: list[tuple[float, float, float, float, float, float]] = []
            self.duration = 0.0
            return
        V, A, J = float(vel), float(acc), float(jerk)
        if V * J >= A * A:
            tj, ta = A / J, A / J + V / A
        else:
            tj = math.sqrt(V / J)
            ta = 2.0 * tj
        tv = L / V - ta
        if tv < 0.0:
            tv = 0.0
            if L >= 2.0 * A ** 3 / (J * J):
                tj = A / J
                ta = 0.5 * tj + math.sqrt(0.25 * tj * tj + L / A)
            else:
                tj = (L / (2.0 * J)) ** (1.0 / 3.0)
                ta = 2.0 * tj
        tc = max(0.0, ta - 2.0 * tj)
        plan = [(tj, J), (tc, 0.0), (tj, -J), (tv, 0.0), (tj, -J), (tc, 0.0), (tj, J)]
        self.phases = []
        t = s = v = a = 0.0
        for dur, j in plan:
            if dur <= 0.0:
                continue
            self.phases.append((t, dur, s, v, a, j))
            s += v * dur + 0.5 * a * dur * dur + j * dur ** 3 / 6.0
            v += a * dur + 0.5 * j * dur * dur
            a += j * dur
            t += dur
        self.duration = t
        self._end = s  # equals L up to rounding; at() returns exactly L at the end

    def at(self, t: float) -> tuple[float, float, float]:
        if t <= 0.0 or not self.phases:
            return 0.0, 0.0, 0.0
        if t >= self.duration:
            return self.distance, 0.0, 0.0
        for t0, dur, s, v, a, j in self.phases:
            if t < t0 + dur:
                tau = t - t0
                scale = self.distance / self._end
                return ((s + v * tau + 0.5 * a * tau * tau + j * tau ** 3 / 6.0) * scale,
                        (v + a * tau + 0.5 * j * tau * tau) * scale, (a + j * tau) * scale)
        return self.distance, 0.0, 0.0  # pragma: no cover


@python_class
@dataclass
class Motion:
    """A motion of the virtual robot.  ``target``: absolute (world TCP) or, with
    ``relative``, the displacement (pos added, ori multiplied on the right).
    ``master_frame``: nodal MasterFrame (docs/spec/conveyor.md#9.6), :data:`KEEP` for none."""

    target: Location
    relative: bool = False
    limits: CartesianLimits | None = None
    superpose: bool = False
    master_frame: Any = KEEP
    name: str = ""
    #: running number per virtual robot (set by :meth:`VirtualRobot.enter`)
    id: int = 0
    #: set at the start: displacement, profile, start sample
    delta: Location | None = None
    profile: SCurve | None = None
    k0: int | None = None
    done: bool = False

    @property
    def started(self) -> bool:
        return self.k0 is not None


@python_class
@dataclass
class _Factor:
    motion: Motion | None  # None: a constant (shift)
    const: Location | None = None

    @property
    def delta(self) -> Location:
        """The displacement at the end: the constant, or the started motion's delta."""
        d = self.const if self.motion is None else self.motion.delta
        assert d is not None  # a factor is a constant or a started motion
        return d


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: predict_catch deep-copies it)
class VirtualRobot:
    """The virtual robot of one robot group (world TCP).  See the module docstring."""

    def __init__(self, start: Location, sample_time_s: float,
                 limits: CartesianLimits = MOTION_LIMITS) -> None:
        self.T = float(sample_time_s)
        self.limits = limits
        self.base = start
        self.factors: list[_Factor] = []
        self.queue: list[Motion] = []
        self.k = 0
        self._loc = start
        self._vel: Vec3 = (0.0, 0.0, 0.0)
        self._acc: Vec3 = (0.0, 0.0, 0.0)
        self._count = 0

    # -- state ------------------------------------------------------------------------------
    @property
    def location(self) -> Location:
        return self._loc

    @property
    def velocity(self) -> Vec3:
        """Translation velocity [mm/s] at the current sample."""
        return self._vel

    @property
    def acceleration(self) -> Vec3:
        return self._acc

    @property
    def busy(self) -> bool:
        """True while a motion runs or waits."""
        return bool(self.queue) or any(f.motion is not None and not f.motion.done
                                       for f in self.factors)

    def running(self) -> list[Motion]:
        return [f.motion for f in self.factors if f.motion is not None and not f.motion.done]

    def planned_end(self) -> Location:
        """Where the started motions end (B ⊕ every factor at its end)."""
        loc = self.base
        for f in self.factors:
            loc = loc.oplus(f.delta)
        return loc

    # -- commands ---------------------------------------------------------------------------
    def enter(self, motion: Motion) -> Motion:
        """Queue a motion (it starts in :meth:`step` when due)."""
        self._count += 1
        motion.id = self._count
        self.queue.append(motion)
        return motion

    def due(self) -> list[Motion]:
        """Motions that start at the next step: superposed ones, and the head of the queue
        when nothing runs."""
        if not self.queue:
            return []  # (nothing waits: the usual sample)
        out = []
        idle = not self.running()
        for m in self.queue:
            if m.superpose:
                out.append(m)
            elif idle:
                out.append(m)
                idle = False
            else:
                break
        return out

    def start(self, motion: Motion) -> None:
        """Fix the displacement of a due motion and start it at the next sample."""
        self.queue.remove(motion)
        end = self.planned_end()
        if motion.relative:
            delta = motion.target
        else:
            delta = motion.target.ominus(end)
        lim = motion.limits or self.limits
        dist = v_norm(delta.pos)
        _, ang = q_to_axis_angle(delta.ori)
        ct = SCurve(dist, lim.trans.vel, lim.trans.acc, lim.trans.jerk)
        cr = SCurve(ang, lim.rot.vel, lim.rot.acc, lim.rot.jerk)
        if cr.duration > ct.duration:
            # the rotation dominates: run it and scale the translation with the same s
            profile, length = cr, ang
        else:
            profile, length = ct, dist
        motion.delta = delta
        motion.profile = profile
        motion._length = length  # type: ignore[attr-defined]
        motion.k0 = self.k
        self.factors.append(_Factor(motion))

    def shift(self, c: Location) -> None:
        """V ← V ⊕ c: the current location and the ends of running motions move by c."""
        if c.pos == (0.0, 0.0, 0.0) and c.ori == Q_IDENTITY:
            return
        self.factors.append(_Factor(None, c))
        self._fold()
        self._evaluate()

    # -- cyclic -----------------------------------------------------------------------------
    def step(self) -> None:
        """Advance one sample (motions started before this call move from this sample on)."""
        self.k += 1
        self._evaluate()
        self._fold()

    def _s(self, m: Motion) -> tuple[float, float, float]:
        length = m._length  # type: ignore[attr-defined]
        if length == 0.0:
            return 1.0, 0.0, 0.0
        assert m.profile is not None and m.k0 is not None  # set when it started
        s, sd, sdd = m.profile.at((self.k - m.k0) * self.T)
        return s / length, sd / length, sdd / length

    def _evaluate(self) -> None:
        if not self.factors:  # at rest on the base: the loop below without a factor
            base = self.base
            self._loc = Location.trusted(base.pos, base.ori)
            self._vel = self._acc = (0.0, 0.0, 0.0)
            return
        pos = list(self.base.pos)
        ori = self.base.ori
        vel = [0.0, 0.0, 0.0]
        acc = [0.0, 0.0, 0.0]
        for f in self.factors:
            d = f.delta
            if f.motion is None:
                pos = [p + c for p, c in zip(pos, d.pos)]
                ori = q_mul(ori, d.ori)
                continue
            m = f.motion
            s, sd, sdd = self._s(m)
            assert m.profile is not None and m.k0 is not None  # set when it started
            if (self.k - m.k0) * self.T >= m.profile.duration:
                m.done = True
                s, sd, sdd = 1.0, 0.0, 0.0
            for j in range(3):
                pos[j] += d.pos[j] * s
                vel[j] += d.pos[j] * sd
                acc[j] += d.pos[j] * sdd
            ori = q_mul(ori, d.ori if s == 1.0 else q_power(d.ori, s))
        self._loc = Location.trusted(vec3(pos), ori)
        self._vel = vec3(vel)
        self._acc = vec3(acc)

    def _fold(self) -> None:
        """Fold leading constants and finished motions into the base (order kept)."""
        while self.factors:
            f = self.factors[0]
            if f.motion is None or f.motion.done:
                self.base = self.base.oplus(f.delta)
            else:
                break
            self.factors.pop(0)


def displacement(pos: Vec3 = (0.0, 0.0, 0.0), ori=Q_IDENTITY) -> Location:
    """A relative motion's displacement (pos [mm] added, ori multiplied on the right)."""
    return Location(pos3(pos), ori)


__all__ = ["KEEP", "MOTION_LIMITS", "Motion", "SCurve", "VirtualRobot", "displacement"]
