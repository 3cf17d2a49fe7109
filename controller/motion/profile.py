"""Jerk-limited axis profiles made of triangular acceleration pulses (thesis task Sled_Y).

Units: mm, mm/s, mm/s^2, mm/s^3, s.  Pure and deterministic: no clocks, the sampled
profile is stepped by an integer sample counter (time = i * T).

Spec: docs/spec/axis.md#2, the thesis' task Sled_Y, states ACCEL_SY / CONST_SY / DECCEL.
The thesis accelerates and brakes with *triangular acceleration pulses* of constant jerk k:

    DECCEL:  a = -k*t            for t <= T2
             a =  k*t - Tr*k     for t >  T2        (Tr = 2*T2, the whole braking time)
             v = v0 + (a + a0)/2 * (t - t0)          (trapezoidal rule)
             y = y0 + (v0 + a*(t - t0)/2) * (t - t0)             <- as printed (wrong)

ACCEL mirrors it and CONST holds the velocity.  A rest-to-rest move is therefore

    ACCEL (+k for T2a, -k for T2a) -> CONST (Tc >= 0) -> DECEL (-k for T2d, +k for T2d)

**Fix of the thesis (docs/spec/axis.md#2.2).**  The printed position
update uses the *new* acceleration ``a`` over the whole step, which does not match its own
velocity rule (that one averages a0 and a).  For an acceleration that changes linearly over
the step, the consistent (and exact) update is

    y = y0 + v0*dt + (2*a0 + a)*dt^2/6

(:func:`integrate_step`).  Read iteratively (t0 = previous sample) the printed form is off by
(a - a_entry)*T^2/3, which vanishes only where the pulse returns to its entry acceleration;
read with t0 = state entry it is off by k*t^3/3 and the move ends beside its target
(:func:`integrate_step_thesis_literal` keeps the printed form for the tests that show this).

**Limits** (docs/spec/axis.md#2.3).  The thesis names only Vm and k.  Given an
:class:`Limits` (V, A, J) a pulse that changes the velocity by dv takes
``T2 = max(sqrt(dv/J), dv/A)`` and ``k = dv/T2^2``:
at full jerk while the peak ``k*T2`` stays below A, otherwise with the peak at A and a lower
jerk, so the pulse stays triangular (thesis shape) instead of growing a plateau.

**Re-planning** from an arbitrary state (p, v, a) (a target changed mid-move; not in the
thesis; docs/spec/axis.md#2.4) uses the same pulses; see :func:`plan_position`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum

from ..errors import ParameterError
from ..limits import Limits
from .checks import require_finite, require_positive

#: Time tolerance [s]: a profile whose remaining duration is below this at a sample counts as
#: finished at that sample (float rounding of i*T against the planned durations).
TIME_EPS_S = 1e-9

#: Bisection steps for the re-plan's peak velocity (it stops earlier when the interval is
#: exhausted at double precision; near 0 mm/s it may need this many).
_BISECTION_STEPS = 200


class Phase(IntEnum):
    """Motion phase of a profile segment (thesis states ACCEL_SY, CONST_SY, DEACCEL_SY)."""

    ACCEL = 1  #: |velocity| grows (thesis ACCEL_SY)
    CONST = 2  #: constant velocity, zero acceleration (thesis CONST_SY; may last 0 s)
    DECEL = 3  #: |velocity| shrinks (thesis DEACCEL_SY / DECCEL)


@dataclass(frozen=True, slots=True)
class KinematicState:
    """Position [mm], velocity [mm/s] and acceleration [mm/s^2] of an axis at one instant."""

    position_mm: float
    velocity_mm_s: float = 0.0
    acceleration_mm_s2: float = 0.0

    @property
    def at_rest(self) -> bool:
        """True when velocity and acceleration are both exactly zero."""
        return self.velocity_mm_s == 0.0 and self.acceleration_mm_s2 == 0.0


@dataclass(frozen=True, slots=True)
class Segment:
    """A piece of constant jerk [mm/s^3] lasting ``duration_s`` [s] (``math.inf`` allowed for
    the final CONST of a velocity profile)."""

    phase: Phase
    duration_s: float
    jerk_mm_s3: float


# --------------------------------------------------------------------------------------------
# The thesis' integration formulas
# --------------------------------------------------------------------------------------------

def integrate_step(y0_mm: float, v0_mm_s: float, a0_mm_s2: float, jerk_mm_s3: float,
                   dt_s: float) -> tuple[float, float, float]:
    """Advance (y, v, a) by ``dt_s`` under constant jerk: the thesis' DECCEL update, fixed.

    Thesis (Sled_Y, DECCEL), with ``a`` the acceleration at the end of the step:
    ``v = v0 + (a + a0)/2*dt`` (kept) and ``y = y0 + v0*dt + (2*a0 + a)*dt^2/6`` (our fix of
    the printed ``y = y0 + (v0 + a*dt/2)*dt``; see the module doc).  Both are exact for a
    linearly changing acceleration, so the step may be any length within one segment.

    Returns:
        (y [mm], v [mm/s], a [mm/s^2]) at the end of the step.
    """
    a = a0_mm_s2 + jerk_mm_s3 * dt_s
    v = v0_mm_s + (a + a0_mm_s2) / 2.0 * dt_s
    y = y0_mm + v0_mm_s * dt_s + (2.0 * a0_mm_s2 + a) * dt_s * dt_s / 6.0
    return y, v, a


def integrate_step_thesis_literal(y0_mm: float, v0_mm_s: float, a0_mm_s2: float,
                                  jerk_mm_s3: float, dt_s: float) -> tuple[float, float, float]:
    """The thesis' DECCEL update exactly as printed (kept for the tests that show its error).

    ``a = a0 + k*dt``, ``v = v0 + (a + a0)/2*dt``, ``y = y0 + (v0 + a*dt/2)*dt``.
    """
    a = a0_mm_s2 + jerk_mm_s3 * dt_s
    v = v0_mm_s + (a + a0_mm_s2) / 2.0 * dt_s
    y = y0_mm + (v0_mm_s + a * dt_s / 2.0) * dt_s
    return y, v, a


def thesis_decel_acceleration(t_s: float, jerk_mm_s3: float, half_time_s: float) -> float:
    """The thesis' DECCEL acceleration [mm/s^2] at ``t_s`` [s] after entering the state.

    ``a = -k*t`` for ``t <= T2``, ``a = k*t - Tr*k`` for ``t > T2`` with ``Tr = 2*T2``;
    0 outside ``[0, Tr]``.  ``jerk_mm_s3`` is k > 0; an ACCEL pulse is the negative of this.
    """
    tr = 2.0 * half_time_s
    if t_s <= 0.0 or t_s >= tr:
        return 0.0
    if t_s <= half_time_s:
        return -jerk_mm_s3 * t_s
    return jerk_mm_s3 * t_s - tr * jerk_mm_s3


# --------------------------------------------------------------------------------------------
# Profiles
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class Profile:
    """A planned axis motion: constant-jerk segments from ``start``.

    Attributes:
        start: state at time 0 of the profile.
        segments: the constant-jerk pieces in order, each labelled with its thesis phase.
        knots: the exact state at the start of each segment (``len(knots) == len(segments)``).
        end: the state at the end (``None`` for a velocity profile that cruises forever).
        target_mm: the commanded end position [mm] (``None`` for a velocity profile).  The
            integrated end differs from it only by float rounding (< 1e-9 mm); samplers put
            the axis exactly on it when the profile finishes.

    Build profiles with :func:`plan_rest_to_rest`, :func:`plan_position`,
    :func:`plan_velocity` or :func:`plan_stop`.
    """

    start: KinematicState
    segments: tuple[Segment, ...]
    knots: tuple[KinematicState, ...]
    end: KinematicState | None
    target_mm: float | None

    @property
    def duration_s(self) -> float:
        """Total duration [s] (``math.inf`` for a velocity profile)."""
        return math.fsum(s.duration_s for s in self.segments) if self.segments else 0.0

    def phase_duration_s(self, phase: Phase) -> float:
        """Summed duration [s] of the segments in ``phase``."""
        return math.fsum(s.duration_s for s in self.segments if s.phase is phase)

    @property
    def phases(self) -> tuple[Phase, ...]:
        """The phase sequence, consecutive repeats merged (zero-length CONST included)."""
        out: list[Phase] = []
        for seg in self.segments:
            if not out or out[-1] is not seg.phase:
                out.append(seg.phase)
        return tuple(out)

    def segment_index_at(self, t_s: float) -> int | None:
        """Index of the segment active at ``t_s`` [s] (right-continuous), ``None`` after the end."""
        t_start = 0.0
        for index, seg in enumerate(self.segments):
            t_end = t_start + seg.duration_s
            if t_s < t_end:
                return index
            t_start = t_end
        return None

    def state_at(self, t_s: float) -> KinematicState:
        """Exact state at ``t_s`` [s] after the start (closed form, for checks and plots)."""
        if t_s <= 0.0:
            return self.start
        t_start = 0.0
        for seg, knot in zip(self.segments, self.knots, strict=True):
            t_end = t_start + seg.duration_s
            if t_s < t_end:
                y, v, a = integrate_step(knot.position_mm, knot.velocity_mm_s,
                                         knot.acceleration_mm_s2, seg.jerk_mm_s3, t_s - t_start)
                return KinematicState(y, v, a)
            t_start = t_end
        assert self.end is not None
        return self.end

    def sample(self, sample_period_s: float, max_samples: int | None = None
               ) -> list[KinematicState]:
        """The profile sampled every ``sample_period_s`` [s], as :class:`ProfileFollower`
        produces it, from sample 1 (t = T) until it finishes (or ``max_samples``)."""
        follower = ProfileFollower(self, sample_period_s)
        out: list[KinematicState] = []
        while not follower.finished and (max_samples is None or len(out) < max_samples):
            out.append(follower.step().state)
        return out


@dataclass(frozen=True, slots=True)
class FollowerSample:
    """One sample of a :class:`ProfileFollower`.

    ``jerk_mm_s3`` and ``phase`` are those of the segment active at the sample time
    (right-continuous); after the end they are 0 and ``None``.
    """

    state: KinematicState
    jerk_mm_s3: float
    phase: Phase | None
    finished: bool


class ProfileFollower:
    """Steps a :class:`Profile` by whole samples of ``sample_period_s`` [s].

    Inside a segment it uses the thesis' iterative update (fixed, :func:`integrate_step`)
    from the previous sample; where a sample crosses a segment boundary it restarts from
    that segment's exact knot, so no rounding drift builds up across the move.  Sample i is
    at time ``i * T`` (integer counter, no accumulated time).  When the profile ends the
    state is set exactly to (target, 0, 0).
    """

    __slots__ = ("_ends", "_finished", "_index", "_period_s", "_profile", "_segment", "_state")

    def __init__(self, profile: Profile, sample_period_s: float) -> None:
        require_positive("ProfileFollower", "sample_period_s", sample_period_s, "s")
        self._profile = profile
        self._period_s = float(sample_period_s)
        self._index = 0
        self._segment = 0
        self._state = profile.start
        ends: list[float] = []
        t = 0.0
        for seg in profile.segments:
            t += seg.duration_s
            ends.append(t)
        self._ends = ends
        self._finished = False

    @property
    def profile(self) -> Profile:
        return self._profile

    @property
    def state(self) -> KinematicState:
        """State at the last sample (the profile's start before the first step)."""
        return self._state

    @property
    def samples(self) -> int:
        """Samples stepped so far."""
        return self._index

    @property
    def finished(self) -> bool:
        return self._finished

    def step(self) -> FollowerSample:
        """Advance one sample period and return the new sample."""
        profile = self._profile
        if self._finished:
            return FollowerSample(self._state, 0.0, None, True)
        t_prev = self._index * self._period_s
        self._index += 1
        t_new = self._index * self._period_s
        duration = self._ends[-1] if self._ends else 0.0
        if t_new >= duration - TIME_EPS_S:
            end = profile.end
            assert end is not None
            position = profile.target_mm if profile.target_mm is not None else end.position_mm
            self._state = KinematicState(position, 0.0, 0.0)
            self._finished = True
            return FollowerSample(self._state, 0.0, None, True)
        y, v, a = (self._state.position_mm, self._state.velocity_mm_s,
                   self._state.acceleration_mm_s2)
        segs = profile.segments
        while t_new >= self._ends[self._segment]:
            t_prev = self._ends[self._segment]
            self._segment += 1
            knot = profile.knots[self._segment]
            y, v, a = knot.position_mm, knot.velocity_mm_s, knot.acceleration_mm_s2
        seg = segs[self._segment]
        y, v, a = integrate_step(y, v, a, seg.jerk_mm_s3, t_new - t_prev)
        self._state = KinematicState(y, v, a)
        return FollowerSample(self._state, seg.jerk_mm_s3, seg.phase, False)


# --------------------------------------------------------------------------------------------
# Pulses (unlabelled pieces: (duration_s, jerk_mm_s3, cruise))
# --------------------------------------------------------------------------------------------

_Piece = tuple[float, float, bool]


def triangle_pulse(delta_v_mm_s: float, limits: Limits) -> tuple[float, float]:
    """Half-time T2 [s] and jerk k [mm/s^3] of a triangular pulse that changes the velocity by
    ``|delta_v_mm_s|`` starting and ending at zero acceleration (thesis ACCEL/DECCEL).

    ``T2 = max(sqrt(dv/J), dv/A)``, ``k = dv/T2^2`` (so ``k <= J`` and peak ``k*T2 <= A``);
    the pulse lasts ``Tr = 2*T2`` and covers ``(v_start + v_end)*T2`` of distance.
    """
    dv = abs(delta_v_mm_s)
    if dv == 0.0:
        return 0.0, 0.0
    t2_jerk = math.sqrt(dv / limits.jerk)
    t2_acc = dv / limits.acc
    if t2_jerk >= t2_acc:  # peak sqrt(dv*J) <= A: full jerk
        return t2_jerk, limits.jerk
    return t2_acc, min(limits.acc * limits.acc / dv, limits.jerk)


def _sign(x: float) -> float:
    return 1.0 if x > 0.0 else (-1.0 if x < 0.0 else 0.0)


def _pulse(v0: float, a0: float, v1: float, limits: Limits) -> list[_Piece]:
    """Pieces taking (v0, a0) to (v1, 0) within the limits (triangular pulses).

    From a0 = 0 this is one thesis triangle (:func:`triangle_pulse`).  From a0 != 0:
    if a0 already pushes the velocity towards v1 far enough, a truncated triangle
    a0 -> a_peak -> 0 with one jerk magnitude k <= J and |a_peak| <= A; otherwise a0 is first
    ramped to 0 at full jerk J (the smallest overshoot) and a fresh triangle follows.
    """
    jmax, amax = limits.jerk, limits.acc
    pieces: list[_Piece] = []
    dv = v1 - v0
    if a0 != 0.0:
        dv_ramp = a0 * abs(a0) / (2.0 * jmax)  # velocity change of ramping a0 to 0 at J
        if dv != 0.0 and ((a0 > 0.0 and dv >= dv_ramp) or (a0 < 0.0 and dv <= dv_ramp)):
            s = _sign(a0)
            m = abs(dv)
            a0m = abs(a0)
            k = min(jmax, (amax * amax - a0m * a0m / 2.0) / m)
            k = max(k, a0m * a0m / (2.0 * m))  # only binds for a start state beyond A
            a_peak = max(math.sqrt(k * m + a0m * a0m / 2.0), a0m)
            pieces.append(((a_peak - a0m) / k, s * k, False))
            pieces.append((a_peak / k, -s * k, False))
            return pieces
        pieces.append((abs(a0) / jmax, -_sign(a0) * jmax, False))
        dv -= dv_ramp
    t2, k = triangle_pulse(dv, limits)
    if t2 > 0.0:
        s = _sign(dv)
        pieces.append((t2, s * k, False))
        pieces.append((t2, -s * k, False))
    return pieces


def _displacement(v0: float, a0: float, pieces: list[_Piece]) -> float:
    y, v, a = 0.0, v0, a0
    for duration, jerk, _ in pieces:
        y, v, a = integrate_step(y, v, a, jerk, duration)
    return y


def _velocity_zero(v0: float, a0: float, jerk: float, duration: float) -> float | None:
    """Time in (0, duration) where the velocity of a piece changes sign, else ``None``.

    Every piece of ``_pulse`` ramps the acceleration between 0 and a peak without crossing
    zero, so the velocity is monotone on it and changes sign at most once.  Sign changes in a
    rounding-size tail (|v| below 1e-9 of the other end) do not count.
    """
    v1 = v0 + a0 * duration + jerk * duration * duration / 2.0
    if not v0 * v1 < 0.0:
        return None
    if min(abs(v0), abs(v1)) <= 1e-9 * max(abs(v0), abs(v1)):
        return None
    lo, hi = 0.0, duration  # bisection: v(lo) has the sign of v0
    for _ in range(_BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if (v0 + a0 * mid + jerk * mid * mid / 2.0) * v0 > 0.0:
            lo = mid
        else:
            hi = mid
    return hi


def _build(start: KinematicState, pieces: list[_Piece], target_mm: float | None) -> Profile:
    """Label pieces with thesis phases (split where the velocity changes sign) and knot them."""
    segments: list[Segment] = []
    knots: list[KinematicState] = []
    y, v, a = start.position_mm, start.velocity_mm_s, start.acceleration_mm_s2
    for duration, jerk, cruise in pieces:
        if cruise:
            a = 0.0  # the pulses end at a = 0 exactly; drop the rounding residue
            segments.append(Segment(Phase.CONST, duration, 0.0))
            knots.append(KinematicState(y, v, a))
            if math.isinf(duration):
                return Profile(start, tuple(segments), tuple(knots), None, None)
            y, v, a = integrate_step(y, v, a, 0.0, duration)
            continue
        if duration <= 0.0:
            continue
        t_zero = _velocity_zero(v, a, jerk, duration)
        cuts = [duration] if t_zero is None else [t_zero, duration]
        t_prev = 0.0
        for t_cut in cuts:
            dt = t_cut - t_prev
            _, vm, am = integrate_step(y, v, a, jerk, dt / 2.0)
            phase = Phase.DECEL if vm * am < 0.0 else Phase.ACCEL
            segments.append(Segment(phase, dt, jerk))
            knots.append(KinematicState(y, v, a))
            y, v, a = integrate_step(y, v, a, jerk, dt)
            t_prev = t_cut
    end = KinematicState(y, v, a)
    if target_mm is not None:
        end = KinematicState(y, 0.0, 0.0) if segments else start
    return Profile(start, tuple(segments), tuple(knots), end, target_mm)


# --------------------------------------------------------------------------------------------
# Planners
# --------------------------------------------------------------------------------------------

def _check_state(where: str, state: KinematicState) -> None:
    require_finite(where, "position_mm", state.position_mm, "mm")
    require_finite(where, "velocity_mm_s", state.velocity_mm_s, "mm/s")
    require_finite(where, "acceleration_mm_s2", state.acceleration_mm_s2, "mm/s^2")


def rest_to_rest_peak_velocity(distance_mm: float, limits: Limits) -> float:
    """Peak velocity [mm/s] of the rest-to-rest move over ``|distance_mm|`` (analytic).

    With symmetric triangles and no CONST the distance is ``2*vp*T2(vp)``:
    jerk-bound (``vp <= A^2/J``): ``d = 2*vp^(3/2)/sqrt(J)`` so ``vp = (d*sqrt(J)/2)^(2/3)``;
    acceleration-bound: ``d = 2*vp^2/A`` so ``vp = sqrt(d*A/2)``.  Capped at V (then a CONST
    phase covers the rest).
    """
    d = abs(distance_mm)
    vp = (d * math.sqrt(limits.jerk) / 2.0) ** (2.0 / 3.0)
    if vp > limits.jerk_bound_velocity:
        vp = math.sqrt(d * limits.acc / 2.0)
    return min(vp, limits.vel)


def plan_rest_to_rest(start_mm: float, target_mm: float, limits: Limits) -> Profile:
    """The thesis' nominal Sled_Y move from rest at ``start_mm`` to rest at ``target_mm`` [mm].

    ACCEL (triangle, T2) -> CONST (Tc, possibly 0 s) -> DECEL (triangle, T2), planned
    analytically (:func:`rest_to_rest_peak_velocity`, :func:`triangle_pulse`):
    ``Tc = d/vp - 2*T2``.  Short moves never reach V; very short ones never reach A either.
    The CONST segment is always present (0 s when not needed), as in the thesis, where the
    state machine passes through CONST_SY even when it makes no step there.

    Raises:
        ParameterError: a position is not finite.
    """
    require_finite("plan_rest_to_rest", "start_mm", start_mm, "mm")
    require_finite("plan_rest_to_rest", "target_mm", target_mm, "mm")
    start = KinematicState(float(start_mm))
    distance = target_mm - start_mm
    if distance == 0.0:
        return _build(start, [], float(target_mm))
    s = _sign(distance)
    d = abs(distance)
    vp = rest_to_rest_peak_velocity(d, limits)
    if vp == 0.0:  # a distance so small that vp underflows: the samplers just snap
        return _build(start, [], float(target_mm))
    t2, k = triangle_pulse(vp, limits)
    tc = max(0.0, d / vp - 2.0 * t2)
    pieces: list[_Piece] = [(t2, s * k, False), (t2, -s * k, False), (tc, 0.0, True),
                            (t2, -s * k, False), (t2, s * k, False)]
    return _build(start, pieces, float(target_mm))


def plan_position(start: KinematicState, target_mm: float, limits: Limits) -> Profile:
    """Plan from any state (p, v, a) to rest at ``target_mm`` [mm] (re-target mid-move).

    Not in the thesis (its Sled_Y only starts from rest).  From rest this is
    :func:`plan_rest_to_rest`.  Otherwise the move is

        pulse (v, a) -> (vp, 0)  ->  CONST at vp for Tc >= 0  ->  triangle vp -> 0

    with the pulses of ``_pulse`` (triangles, k <= J, |a| <= A) and the plateau velocity
    vp in [-V, V] found by bisection on the covered distance (continuous in vp).  A vp of
    the other sign than the current velocity means "brake first and reverse": when the new
    target lies behind, or closer than the stopping distance, the first pulse brakes through
    zero velocity and the axis comes back.  Limits hold for any start state that can itself
    stay within them (|v| + a^2/(2J) <= V, |a| <= A); the profile is not time-optimal.

    Raises:
        ParameterError: the start state or the target is not finite.
    """
    _check_state("plan_position.start", start)
    require_finite("plan_position", "target_mm", target_mm, "mm")
    if start.at_rest:
        return plan_rest_to_rest(start.position_mm, target_mm, limits)
    v0, a0 = start.velocity_mm_s, start.acceleration_mm_s2
    dist = target_mm - start.position_mm
    vmax = limits.vel

    def pieces_for(vp: float, tc: float) -> list[_Piece]:
        return _pulse(v0, a0, vp, limits) + [(tc, 0.0, True)] + _pulse(vp, 0.0, 0.0, limits)

    def covered(vp: float) -> float:
        return _displacement(v0, a0, pieces_for(vp, 0.0))

    d_hi = covered(vmax)
    d_lo = covered(-vmax)
    if dist >= d_hi:
        vp, tc = vmax, (dist - d_hi) / vmax
    elif dist <= d_lo:
        vp, tc = -vmax, (dist - d_lo) / -vmax
    else:
        lo, hi = -vmax, vmax
        for _ in range(_BISECTION_STEPS):
            mid = 0.5 * (lo + hi)
            if mid <= lo or mid >= hi:
                break
            if covered(mid) <= dist:
                lo = mid
            else:
                hi = mid
        # absorb the last rounding residual in a (tiny) CONST, keeping Tc >= 0
        vp, tc = lo, 0.0
        if lo > 1e-9:
            tc = (dist - covered(lo)) / lo
        elif hi < -1e-9:
            vp = hi
            tc = (dist - covered(hi)) / hi
        tc = max(tc, 0.0)
    return _build(start, pieces_for(vp, tc), float(target_mm))


def plan_velocity(start: KinematicState, velocity_mm_s: float, limits: Limits) -> Profile:
    """Plan from any state to cruise at ``velocity_mm_s`` [mm/s] forever (jog, homing search).

    One pulse (v, a) -> (velocity, 0) (see :func:`plan_position`), then an endless CONST.
    Reversing passes through zero velocity inside the pulse (DECEL, then ACCEL).

    Raises:
        ParameterError: the state is not finite, or ``|velocity_mm_s| > limits.vel``.
    """
    _check_state("plan_velocity.start", start)
    require_finite("plan_velocity", "velocity_mm_s", velocity_mm_s, "mm/s")
    if abs(velocity_mm_s) > limits.vel:
        raise ParameterError(
            f"plan_velocity.velocity_mm_s (={velocity_mm_s!r} mm/s) is out of range: "
            f"must be within [-{limits.vel}, {limits.vel}] mm/s (Limits.vel)")
    pieces = _pulse(start.velocity_mm_s, start.acceleration_mm_s2, float(velocity_mm_s), limits)
    return _build(start, pieces + [(math.inf, 0.0, True)], None)


def plan_stop(start: KinematicState, limits: Limits) -> Profile:
    """Plan the jerk-limited stop from any state (one pulse to (v, a) = (0, 0)).

    The profile's ``target_mm`` is where the axis comes to rest.

    Raises:
        ParameterError: the state is not finite.
    """
    _check_state("plan_stop.start", start)
    pieces = _pulse(start.velocity_mm_s, start.acceleration_mm_s2, 0.0, limits)
    stop_mm = start.position_mm + _displacement(start.velocity_mm_s,
                                                start.acceleration_mm_s2, pieces)
    return _build(start, pieces, stop_mm)


def stopping_distance_mm(state: KinematicState, limits: Limits) -> float:
    """Signed distance [mm] the axis travels during :func:`plan_stop` from ``state``."""
    pieces = _pulse(state.velocity_mm_s, state.acceleration_mm_s2, 0.0, limits)
    return _displacement(state.velocity_mm_s, state.acceleration_mm_s2, pieces)
