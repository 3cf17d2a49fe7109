"""Value types of the tracking core: limits, parameters, master/robot states, outputs.

Units: translation in mm, mm/s, mm/s^2, mm/s^3; rotation (one angle about the tool
axis) in deg, deg/s, deg/s^2, deg/s^3; time in s.  All types are immutable.

Spec: docs/spec/tracking.md (the softMC tracking algorithm; states #2.1, modes #2.3, IMFS
#2.4, limits and rates #2.5, errors #2.6, the readings of ``SoftMcOptions`` #3.10).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from enum import IntEnum
from typing import Any, Protocol

from .values import as_stored, boolean, fast_init, integer, python_class, trusted
from ..errors import ParameterError
from ..limits import Limits

Vec3 = tuple[float, float, float]
ZERO3: Vec3 = (0.0, 0.0, 0.0)


class TrackState(IntEnum):
    """Tracker state (docs/spec/tracking.md#2.1)."""

    OFF = 0
    SYNCING = 1  #: approach (softMC's "tracking process")
    SYNCED = 2  #: full synchronisation: follow the master, all derivatives copied
    DESYNCING = 3  #: stopping on the path


class Mode(IntEnum):
    """``<robot>.slave``: 0 off, 3 absolute, 5 relative approach (docs/spec/tracking.md#2.3)."""

    OFF = 0
    ABSOLUTE = 3
    RELATIVE = 5


class SyncFollow(IntEnum):
    """How SYNCED follows the master (docs/spec/master-conditioning.md#6)."""

    COPY = 0  #: the published "copy all derivatives": the setpoint is the master
    LIMITED = 1  #: copy while that keeps the sync limits, else close the gap within them


class Imfs(IntEnum):
    """IsMovingFrameSynchronized (docs/spec/tracking.md#2.4)."""

    NOT_SYNCHRONIZED = 0  #: off, or approaching but not yet synchronised
    SYNCHRONIZED = 1  #: following the moving frame directly
    DESYNCING = -1  #: de-syncing from the moving frame
    HANDOFF = -2  #: de-syncing from one frame while catching (or already following) another


class TrackError(IntEnum):
    """Error outcomes of the tracker.  Every error starts the de-sync (stop on the path)."""

    NONE = 0
    MASTER_VELOCITY = 1  #: master velocity above the moving frame's VelocityMax
    MASTER_ACCELERATION = 2  #: master acceleration above the moving frame's AccelerationMax
    OVER_OSCILLATION = 3  #: MOT_MASTER_OSC: sustained oscillation during the approach
    APPROACH_TIMEOUT = 4  #: not synchronised within ``approach_timeout_s``
    ITEM_MISSED = 5  #: softMC error 30238 "Item missed" (conveyor model)
    MASTER_LOST = 6  #: master samples stopped arriving (controller shell)


@python_class
@dataclass(frozen=True, slots=True)
class Rates:
    """softMC rate overrides in percent (VRATE, ARATE, DRATE, JRATE), 0 < rate <= 100.

    softMC: "{vel|acc|jerk}{sync|desync}{tran|rot} = min({..}max{tran|rot}, {..}rate)"
    and "arate influences syncing while drate influences de-syncing".  softMC rates are
    percentages of the robot's maximum, so we read the formula (docs/spec/tracking.md#2.5) as
    ``effective = min(parameter, robot_max * rate / 100)`` with ARATE scaling the sync
    acceleration and DRATE the de-sync acceleration.
    """

    vel: float = 100.0
    acc: float = 100.0
    dec: float = 100.0
    jerk: float = 100.0

    def __post_init__(self) -> None:
        for name in ("vel", "acc", "dec", "jerk"):
            value = getattr(self, name)
            if not (0 < value <= 100):
                raise ParameterError(f"rate {name} (={value!r}) must be in (0...100] percent")


@python_class
@dataclass(frozen=True, slots=True)
class SoftMcOptions:
    """Fixes to the published softMC algorithm, each a named switch (default: the working
    reading).  ``SoftMcOptions.literal()`` reproduces the algorithm as published.  Each field
    names the section of docs/spec/tracking.md that explains it (table: #3.10).
    """

    #: docs/spec/tracking.md#3.2: K of the time-to-reach estimate, (K if |vm| > |v|, K
    #: otherwise); published: (4, 2).  The published comment: the robot must pass the
    #: master's speed and come back, "therefore the multiplication by 2".  A jerk-limited
    #: speed change by |dv| takes 2*sqrt(|dv|/J) = sqrt(4*|dv|/J); twice that is
    #: sqrt(16*|dv|/J).  The published (4, 2) is 2-3x shorter
    #: than the time-optimal duration (Ruckig: 0.092 s for dv = 200 mm/s, J = 4e5; published:
    #: 0.045 s) and makes the fixed algorithm limit-cycle whenever the velocity error dominates
    #: (relative mode always starts there): 33 of 120 random approaches failed; with (16, 16)
    #: none did.  Both cases use 16 because whether the overshoot is needed depends on the
    #: errors' directions, not on which speed is larger.
    time_to_reach_k: tuple[float, float] = (16.0, 16.0)
    #: docs/spec/tracking.md#3.2 (experimental): choose K by direction: the first K when the
    #: position and velocity errors point the same way (the robot must overshoot the
    #: master's speed).
    #: Measured no better than (16, 16) on the benchmark suite; off by default.
    directional_k: bool = False
    #: docs/spec/tracking.md#3.3: rendezvous acceleration = master acceleration
    #: (literal: ``pred_acc = 0``)
    pred_acc_from_master: bool = True
    #: docs/spec/tracking.md#3.9: dp0 = v0*T, ddp0 = a0*T^2 at engage (literal: not
    #: initialised, i.e. 0)
    init_increments_from_state: bool = True
    #: docs/spec/tracking.md#3.7 (the key defect): after a clamp feed back end-of-sample values
    #: v = (dp + ddp/2 + dddp/3)/T, a = (ddp + dddp)/T^2 (literal: dp/T and ddp/T^2)
    end_of_sample_feedback: bool = True
    #: docs/spec/tracking.md#3.6: cap the velocity step so that |v| + a^2/(2J) <= V
    #: (literal: |dp| <= V*T only)
    braking_distance_velocity: bool = True
    #: docs/spec/tracking.md#3.8: softMC's "take the middle" step when switching to SYNCED
    take_the_middle: bool = True
    #: docs/spec/tracking.md#3.8: sync thresholds g*A*T and g*A*T^2 (softMC's algorithm);
    #: False: its conveyor overview's "position error < 1/2*A*T^2", velocity threshold g*A*T
    unit_consistent_thresholds: bool = True

    def __post_init__(self) -> None:
        boolean(self, *_SOFTMC_SWITCHES)  # (a 0 or 1 given: what it means in an ``if``)

    @classmethod
    def literal(cls) -> "SoftMcOptions":
        """The softMC algorithm exactly as published (for regression tests and comparison)."""
        return cls(time_to_reach_k=(4.0, 2.0), pred_acc_from_master=False, init_increments_from_state=False,
                   end_of_sample_feedback=False, braking_distance_velocity=False,
                   take_the_middle=True, unit_consistent_thresholds=True)


#: the bool fields of :class:`SoftMcOptions`
_SOFTMC_SWITCHES = ("directional_k", "pred_acc_from_master", "init_increments_from_state",
                    "end_of_sample_feedback", "braking_distance_velocity", "take_the_middle",
                    "unit_consistent_thresholds")


#: sync/de-sync limits when neither they nor the robot's maxima are given
#: (mm/s, mm/s^2, mm/s^3 and deg/s, deg/s^2, deg/s^3)
DEFAULT_TRANS = Limits(2000.0, 20000.0, 400000.0)
DEFAULT_ROT = Limits(360.0, 3600.0, 72000.0)


#: the largest FilterFactor / DampingFactor accepted
MAX_FACTOR = 1000.0


@python_class
@dataclass(frozen=True, slots=True)
class TrackerParams:
    """Everything that configures one tracker (one robot group on one moving frame).

    Sync/de-sync limits are softMC's ``{Velocity|Acceleration|Jerk}{Sync|DeSync}{Tran|Rot}``;
    not given, they start at the robot's maxima (docs/spec/tracking.md#2.5; softMC:
    "default values set by ConfigGroup ... to the initial values of corresponding robot max
    properties"), or at :data:`DEFAULT_TRANS`/:data:`DEFAULT_ROT` without robot maxima.  The
    effective values are capped by the robot's maxima and rates (:meth:`effective`).
    ``master_max_*`` are the moving frame's ``VelocityMaxTrans``/``AccelerationMaxTrans``/...
    (softMC defaults 1000 mm/s, 1000 mm/s^2, 100 deg/s, 100 deg/s^2): a master above them is
    an error that starts the de-sync.  Only velocity and acceleration are monitored; the jerk
    field is kept for completeness (softMC lists JerkMax but monitors vel and acc;
    docs/spec/tracking.md#2.6).
    """

    sample_time_s: float = 0.001
    mode: Mode = Mode.ABSOLUTE
    planner: str = "optimal"
    #: ``None`` (not given): the robot's maxima when given (#2.5: ConfigGroup sets them to
    #: VMTran/AMTran/JMTran, VMRot/...), else :data:`DEFAULT_TRANS` / :data:`DEFAULT_ROT`
    sync_trans: Limits | None = None
    desync_trans: Limits | None = None
    sync_rot: Limits | None = None
    desync_rot: Limits | None = None
    robot_max_trans: Limits | None = None
    robot_max_rot: Limits | None = None
    rates: Rates = Rates()
    #: MF.FilterFactor (g): sync thresholds g*A*T and g*A*T^2 (softmc planner)
    filter_factor: float = 1.0
    #: MF.DampingFactor: multiplies the softmc time-to-reach estimate
    damping_factor: float = 1.0
    #: MF.MaxFlops: more large velocity-error sign flips (half-swings whose peak |dv| exceeds
    #: g*A*T) than this within ``max_flops_time_s`` is an over-oscillation
    max_flops: int = 6
    #: softMC's undocumented maxFlopsTime, read as the flip-counting window [s]
    #: (docs/spec/tracking.md#4.2)
    max_flops_time_s: float = 3.0
    #: not synchronised after this long [s] -> APPROACH_TIMEOUT
    approach_timeout_s: float = 5.0
    master_max_trans: Limits = Limits(1000.0, 1000.0, 1000.0)
    master_max_rot: Limits = Limits(100.0, 100.0, 100.0)
    softmc: SoftMcOptions = field(default_factory=SoftMcOptions)
    #: de-sync starts from the current acceleration (softMC's algorithm; jerk-limited,
    #: default) or from zero acceleration (its conveyor overview; an acceleration step if the
    #: master was accelerating): docs/spec/tracking.md#5.3
    desync_from_current_acceleration: bool = True
    #: SYNCED following (and the switch into it): ``None`` -- LIMITED for the ``optimal``
    #: planner (the vector-norm limits hold in every phase), COPY for ``softmc`` (as published)
    synced_follow: SyncFollow | None = None

    def __post_init__(self) -> None:
        s = as_stored(self)  # (the values as passed: values.as_stored)
        # docs/spec/tracking.md#2.5: the sync/de-sync values start at the robot's maxima
        for name, robot, builtin in (("sync_trans", s.robot_max_trans, DEFAULT_TRANS),
                                     ("desync_trans", s.robot_max_trans, DEFAULT_TRANS),
                                     ("sync_rot", s.robot_max_rot, DEFAULT_ROT),
                                     ("desync_rot", s.robot_max_rot, DEFAULT_ROT)):
            if getattr(self, name) is None:
                object.__setattr__(self, name, robot if robot is not None else builtin)
        if not (math.isfinite(s.sample_time_s) and 1e-5 <= s.sample_time_s <= 0.1):
            raise ParameterError(
                f"sample_time_s (={s.sample_time_s!r}) must be in [1e-05...0.1] s")
        follow = s.synced_follow
        if follow is None:
            follow = SyncFollow.COPY if s.planner == "softmc" else SyncFollow.LIMITED
        try:
            object.__setattr__(self, "synced_follow", SyncFollow(follow))
        except ValueError:
            raise ParameterError(f"synced_follow (={s.synced_follow!r}) must be 0 (copy) or "
                                 f"1 (limited)") from None
        try:
            object.__setattr__(self, "mode", Mode(s.mode))
        except ValueError:
            raise ParameterError(
                f"mode (={s.mode!r}) must be 3 (absolute) or 5 (relative)") from None
        if s.mode == Mode.OFF:
            raise ParameterError("mode (=0) must be 3 (absolute) or 5 (relative)")
        # (<= MAX_FACTOR: beyond it the softmc thresholds and time-to-reach overflow to
        #  inf/NaN; DampingFactor 1..10 is the useful range)
        if not (0 < s.filter_factor <= MAX_FACTOR):
            raise ParameterError(f"filter_factor (={s.filter_factor!r}) must be > 0 "
                                 f"and <= {MAX_FACTOR:g}")
        if not (0 < s.damping_factor <= MAX_FACTOR):
            raise ParameterError(f"damping_factor (={s.damping_factor!r}) must be > 0 "
                                 f"and <= {MAX_FACTOR:g}")
        integer(self, "max_flops", 1)
        boolean(self, "desync_from_current_acceleration")
        if not s.max_flops_time_s > 0:
            raise ParameterError(f"max_flops_time_s (={s.max_flops_time_s!r}) must be > 0")
        if not s.approach_timeout_s > 0:
            raise ParameterError(
                f"approach_timeout_s (={s.approach_timeout_s!r}) must be > 0")

    def with_(self, **changes) -> "TrackerParams":
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)

    def _effective(self, value: Limits | None, robot_max: Limits | None,
                   accel_rate: float) -> Limits:
        assert value is not None  # __post_init__ filled in the defaults
        if robot_max is None:
            return value
        r = self.rates
        cap = Limits(robot_max.vel * r.vel / 100.0, robot_max.acc * accel_rate / 100.0,
                     robot_max.jerk * r.jerk / 100.0)
        return value.capped(cap)

    def effective(self) -> "EffectiveLimits":
        """Sync/de-sync limits after the robot maxima and rates (ARATE sync, DRATE de-sync)."""
        return EffectiveLimits(
            sync_trans=self._effective(self.sync_trans, self.robot_max_trans, self.rates.acc),
            desync_trans=self._effective(self.desync_trans, self.robot_max_trans, self.rates.dec),
            sync_rot=self._effective(self.sync_rot, self.robot_max_rot, self.rates.acc),
            desync_rot=self._effective(self.desync_rot, self.robot_max_rot, self.rates.dec),
        )


@python_class
@dataclass(frozen=True, slots=True)
class EffectiveLimits:
    """The limits a tracker runs with: each channel's sync and de-sync :class:`Limits` after
    the robot's maxima and the rates (:meth:`TrackerParams.effective`,
    docs/spec/tracking.md#2.5)."""

    sync_trans: Limits
    desync_trans: Limits
    sync_rot: Limits
    desync_rot: Limits


def _plain3(v: Any) -> bool:
    """Whether ``v`` is a tuple of 3 Python floats or ints (what the compiled core reads as a
    ``Vec3`` without a TypeError)."""
    if type(v) is not tuple or len(v) != 3:
        return False
    x, y, z = v
    return ((type(x) is float or type(x) is int) and (type(y) is float or type(y) is int)
            and (type(z) is float or type(z) is int))


def _vec3(name: str, v: Any) -> Vec3:
    """The 3-vector ``name`` given as any sequence of 3 numbers (list, numpy array, tuple of
    numpy scalars) as a tuple of Python floats."""
    try:
        x, y, z = v
        return (float(x), float(y), float(z))
    except (TypeError, ValueError):
        raise ParameterError(f"MotionState {name} (={v!r}) must be 3 numbers") from None


@fast_init
@dataclass(frozen=True, slots=True)
class MotionState:
    """Position, velocity and acceleration of a Cartesian point plus one tool-axis angle.

    Used for both the master (moving frame) and the robot setpoint.
    ``pos`` mm, ``vel`` mm/s, ``acc`` mm/s^2; ``ang`` deg, ``ang_vel`` deg/s, ``ang_acc`` deg/s^2.
    ``jerk`` mm/s^3 and ``ang_jerk`` deg/s^3: the master's jerk when known (a conditioned
    master, :mod:`.conditioning`), else 0; the tracker plans against it
    (docs/spec/master-conditioning.md#6).
    """

    pos: Vec3 = ZERO3
    vel: Vec3 = ZERO3
    acc: Vec3 = ZERO3
    ang: float = 0.0
    ang_vel: float = 0.0
    ang_acc: float = 0.0
    jerk: Vec3 = ZERO3
    ang_jerk: float = 0.0

    def __post_init__(self) -> None:
        # a list, a numpy array or a tuple of numpy scalars for a vector: stored as a tuple
        # of floats (the compiled core reads the fields as tuple[float, float, float]);
        # tuples of Python floats and ints are kept as given
        s = as_stored(self)
        if not _plain3(s.pos):
            object.__setattr__(self, "pos", _vec3("pos", s.pos))
        if not _plain3(s.vel):
            object.__setattr__(self, "vel", _vec3("vel", s.vel))
        if not _plain3(s.acc):
            object.__setattr__(self, "acc", _vec3("acc", s.acc))
        if not _plain3(s.jerk):
            object.__setattr__(self, "jerk", _vec3("jerk", s.jerk))

    @classmethod
    def at(cls, x: float = 0.0, y: float = 0.0, z: float = 0.0, c: float = 0.0) -> "MotionState":
        """A state at rest at (x, y, z) mm and angle c deg."""
        return cls((float(x), float(y), float(z)), ZERO3, ZERO3, float(c), 0.0, 0.0)

    def extrapolated(self, dt_s: float) -> "MotionState":
        """This state moved on by ``dt_s`` seconds at constant acceleration."""
        h = 0.5 * dt_s * dt_s
        p, v, a = self.pos, self.vel, self.acc
        return MotionState(
            (p[0] + v[0] * dt_s + a[0] * h, p[1] + v[1] * dt_s + a[1] * h,
             p[2] + v[2] * dt_s + a[2] * h),
            (v[0] + a[0] * dt_s, v[1] + a[1] * dt_s, v[2] + a[2] * dt_s),
            a,
            self.ang + self.ang_vel * dt_s + self.ang_acc * h,
            self.ang_vel + self.ang_acc * dt_s,
            self.ang_acc,
        )


class _MakeMotionState(Protocol):
    def __call__(self, pos: Vec3, vel: Vec3, acc: Vec3, ang: float, ang_vel: float,
                 ang_acc: float, jerk: Vec3 = ZERO3, ang_jerk: float = 0.0) -> MotionState: ...


#: ``MotionState(...)`` for the core's own setpoints (values.trusted): the fields stored as
#: given, without ``__post_init__`` (no conversion, no validation; some 0.5 us less per
#: setpoint in the pure source, the FMU's).  Only for values the core computed from Python
#: floats or took from a ``MotionState`` already made (the vectors of a master, a planner's
#: tuples of Python floats): what a caller passes goes through ``MotionState``.
motion_state: _MakeMotionState = trusted(MotionState, "motion_state")


@fast_init
@dataclass(frozen=True, slots=True)
class TrackerOutput:
    """What one tracker update produces (one sample)."""

    setpoint: MotionState
    state: TrackState
    imfs: Imfs
    error: TrackError
    #: sample index k of this setpoint (time k*T since the tracker was created)
    sample: int
    #: True on the sample where the approach ended (switch into SYNCED)
    synchronized_now: bool = False
