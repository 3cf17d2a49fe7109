"""Homing: the thesis' task GotoY, a "no homing" method, and the drive's own homing mode.

Units: mm, mm/s, mm/s^2, mm/s^3, s.  Pure: :class:`GotoY` is fed the sensor booleans once
per sample (``update()``); no clocks, no I/O.

Spec: docs/spec/axis.md#5, the thesis' task GotoY.  Same motion algorithm as Sled_Y
(``profile.py``), different transitions; the position is unknown, so only ACCEL is planned
ahead and the rest follows two sensors, the slow-down sensor DSS (``slow_down``) and the
home-position sensor DNP (``home``):

    STOP -> BRAKE (release) -> ACCEL -> CONST -> DEACCEL -> SMALL_V -> DOGE -> BACK
         -> BRAKE (engage) -> STOP

Start rules (in BRAKE once the release time has passed): neither sensor -> ACCEL; DSS only
-> SMALL_V; both -> BACK off the switch, then SMALL_V again (see below).  ACCEL -> DEACCEL when DSS fires, -> CONST at the search speed;
CONST -> DEACCEL on DSS; DEACCEL slows to the creep speed -> SMALL_V; SMALL_V -> DOGE on
DNP; DOGE makes m increments (``push_in_counts``) at the creep speed -> BACK.

Readings chosen where the thesis is silent (docs/spec/axis.md#5.2):

* BACK (only named in the thesis) moves ``back_off_mm`` against the homing direction at
  the creep speed, from rest, then the brake engages.
* Started on the home switch (DSS and DNP active; the thesis' rule "both -> DOGE" would take
  the start position as home, off by the depth into the switch): BACK is used first to back
  off the switch -- against the homing direction at the creep speed until DNP goes inactive,
  then ``back_off_mm`` further (at least the stopping distance) to rest -- and the axis
  re-approaches at the creep speed (SMALL_V), so DOGE latches the switch edge as from every
  other start: STOP -> BRAKE -> BACK -> SMALL_V -> DOGE -> BACK -> BRAKE -> STOP.  The
  back-off runs under the BACK time-out; a touch probe sees the re-approach's edge.
* Home is *latched* at the setpoint held when ``update()`` receives the first true DNP
  reading, i.e. the previous sample's setpoint, where the sensor was read; resolution one
  sample (creep*T).  The CAN shell may refine it with the drive's touch probe (60B8h):
  :meth:`GotoY.refine_latch` replaces the latched position (and so the home offset) while
  the push-in or the back-off runs (DOGE, BACK), e.g. with the drive's hardware latch of
  6064h at the switch edge (60BAh), which has no sample delay.
  At the end ``home_offset_mm`` = the latched position: afterwards the axis coordinate is
  ``position - home_offset_mm``, so the home switch is at 0.
* DNP without DSS at the start, or DNP before the creep speed is reached (in ACCEL, CONST
  or DEACCEL), aborts with ``ERROR_SENSOR``: the slow-down dog must cover the home switch and
  the distance between them must be enough to slow down.
* A limit switch (either one, in any moving state or during the release wait) aborts with
  ``ERROR_LIMIT_SWITCH``.  Aborts are result codes with a message, never exceptions:
  the axis stops jerk-limited with the full limits (state ABORT), the brake engages, STOP.
* Time-outs: per state (samples spent in that state; ACCEL and CONST count separately) and
  overall (from ``start()``), see :class:`HomingTimeouts`; ``ERROR_TIMEOUT`` names which.
* BRAKE keeps the thesis' single state for both directions; ``brake_released`` in the output
  says which (True while releasing, False while engaging).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import Enum
from typing import ClassVar

from ..errors import ParameterError, StateError
from ..limits import Limits
from .checks import (
    is_integer,
    require_finite,
    require_non_negative,
    require_positive,
)
from .profile import (
    KinematicState,
    Phase,
    Profile,
    ProfileFollower,
    plan_position,
    plan_stop,
    plan_velocity,
    stopping_distance_mm,
)
from .ptp import AxisOutput, MotionResult, samples_for


class HomingState(Enum):
    """States of GotoY (thesis names; ABORT added for the error stop)."""

    STOP = "STOP"  #: idle (initial, done, or after an error)
    BRAKE = "BRAKE"  #: waiting for the brake (release at the start, engage at the end)
    ACCEL = "ACCEL"  #: speeding up to the search speed
    CONST = "CONST"  #: search speed until the slow-down sensor
    DEACCEL = "DEACCEL"  #: slowing down to the creep speed
    SMALL_V = "SMALL_V"  #: creep speed until the home sensor
    DOGE = "DOGE"  #: push-in: m increments at the creep speed, then stop
    BACK = "BACK"  #: back off the switch
    ABORT = "ABORT"  #: jerk-limited stop after an error (not in the thesis)


_MOVING = frozenset({HomingState.ACCEL, HomingState.CONST, HomingState.DEACCEL,
                     HomingState.SMALL_V, HomingState.DOGE, HomingState.BACK,
                     HomingState.ABORT})

_TIMEOUT_FIELDS = {
    HomingState.BRAKE: "brake_s", HomingState.ACCEL: "accel_s", HomingState.CONST: "const_s",
    HomingState.DEACCEL: "deaccel_s", HomingState.SMALL_V: "small_v_s",
    HomingState.DOGE: "doge_s", HomingState.BACK: "back_s",
}


@dataclass(frozen=True, slots=True)
class HomingTimeouts:
    """Time-outs [s] of GotoY; ``None`` means no limit for that state.

    Attributes:
        total_s: from ``start()`` until the axis is back at rest with the brake closing.
        brake_s: the release wait (only useful if shorter than a misconfigured release time).
        accel_s, const_s, deaccel_s, small_v_s, doge_s, back_s: time in each state.
    """

    total_s: float | None = 60.0
    brake_s: float | None = None
    accel_s: float | None = None
    const_s: float | None = None
    deaccel_s: float | None = None
    small_v_s: float | None = None
    doge_s: float | None = None
    back_s: float | None = None

    def __post_init__(self) -> None:
        for name in ("total_s",) + tuple(_TIMEOUT_FIELDS.values()):
            value = getattr(self, name)
            if value is not None:
                require_positive("HomingTimeouts", name, value, "s")

    def for_state(self, state: HomingState) -> float | None:
        """The time-out [s] of ``state`` (``None`` if unlimited or not a timed state)."""
        name = _TIMEOUT_FIELDS.get(state)
        return getattr(self, name) if name is not None else None


@dataclass(frozen=True, slots=True)
class HomingConfig:
    """Parameters of GotoY.

    Attributes:
        limits: axis limits (ACCEL/DEACCEL pulses and the abort stop use them in full).
        sample_period_s: sample period T [s].
        search_vel_mm_s: CONST speed [mm/s], 0 < search <= limits.vel.
        creep_vel_mm_s: the user-set low speed of SMALL_V, DOGE and BACK [mm/s],
            0 < creep <= search.
        push_in_counts: m, the DOGE push-in in drive increments (>= 0).
        counts_per_mm: drive increments per mm, to turn m into mm (> 0).
        back_off_mm: BACK distance [mm] (>= 0).
        direction: -1 homes towards negative positions, +1 towards positive.
        brake_release_s, brake_engage_s: brake times [s] (>= 0).
        timeouts: :class:`HomingTimeouts`.
    """

    limits: Limits
    sample_period_s: float
    search_vel_mm_s: float
    creep_vel_mm_s: float
    push_in_counts: int
    counts_per_mm: float
    back_off_mm: float
    direction: int = -1
    brake_release_s: float = 0.0
    brake_engage_s: float = 0.0
    timeouts: HomingTimeouts = field(default_factory=HomingTimeouts)

    def __post_init__(self) -> None:
        if not isinstance(self.limits, Limits):
            raise ParameterError(
                f"HomingConfig.limits (={self.limits!r}) must be a Limits instance")
        require_positive("HomingConfig", "sample_period_s", self.sample_period_s, "s")
        require_positive("HomingConfig", "search_vel_mm_s", self.search_vel_mm_s, "mm/s")
        if self.search_vel_mm_s > self.limits.vel:
            raise ParameterError(
                f"HomingConfig.search_vel_mm_s (={self.search_vel_mm_s!r} mm/s) is out of "
                f"range: must be in (0, {self.limits.vel}] mm/s (Limits.vel)")
        require_positive("HomingConfig", "creep_vel_mm_s", self.creep_vel_mm_s, "mm/s")
        if self.creep_vel_mm_s > self.search_vel_mm_s:
            raise ParameterError(
                f"HomingConfig.creep_vel_mm_s (={self.creep_vel_mm_s!r} mm/s) is out of "
                f"range: must be in (0, {self.search_vel_mm_s}] mm/s (search_vel_mm_s)")
        if not is_integer(self.push_in_counts) or self.push_in_counts < 0:
            raise ParameterError(
                f"HomingConfig.push_in_counts (={self.push_in_counts!r}) must be an "
                f"integer >= 0")
        require_positive("HomingConfig", "counts_per_mm", self.counts_per_mm, "counts/mm")
        require_non_negative("HomingConfig", "back_off_mm", self.back_off_mm, "mm")
        if self.direction not in (-1, 1) or isinstance(self.direction, bool):
            raise ParameterError(
                f"HomingConfig.direction (={self.direction!r}) must be -1 or +1")
        require_non_negative("HomingConfig", "brake_release_s", self.brake_release_s, "s")
        require_non_negative("HomingConfig", "brake_engage_s", self.brake_engage_s, "s")
        if not isinstance(self.timeouts, HomingTimeouts):
            raise ParameterError(
                f"HomingConfig.timeouts (={self.timeouts!r}) must be a HomingTimeouts instance")

    @property
    def push_in_mm(self) -> float:
        """DOGE distance [mm]: push_in_counts / counts_per_mm."""
        return self.push_in_counts / self.counts_per_mm

    @property
    def creep_limits(self) -> Limits:
        """The axis limits with the velocity capped at the creep speed (DOGE, BACK)."""
        return self.limits.with_vel(self.creep_vel_mm_s)


@dataclass(frozen=True, slots=True)
class HomingOutput(AxisOutput):
    """:class:`~.ptp.AxisOutput` plus the homing result.

    ``home_offset_mm``: the latched home position [mm], set when homing finished (result
    FINISHED), ``None`` before and after a failure.
    """

    home_offset_mm: float | None = None


class GotoY:
    """Thesis task GotoY: dog homing with a slow-down and a home sensor.

    Example::

        homing = GotoY(config, position_mm=actual_mm)
        homing.start()
        while (out := homing.update(slow_down=dss, home=dnp,
                                    limit_neg=ln, limit_pos=lp)).result is MotionResult.WORKING:
            send(out.position_mm)
        if out.result is MotionResult.FINISHED:
            offset = out.home_offset_mm
    """

    def __init__(self, config: HomingConfig, position_mm: float = 0.0) -> None:
        if not isinstance(config, HomingConfig):
            raise ParameterError(f"config (={config!r}) must be a HomingConfig instance")
        require_finite("GotoY", "position_mm", position_mm, "mm")
        self._config = config
        period = config.sample_period_s
        self._n_release = samples_for(config.brake_release_s, period)
        self._n_engage = samples_for(config.brake_engage_s, period)
        self._n_total = (samples_for(config.timeouts.total_s, period)
                         if config.timeouts.total_s is not None else None)
        self._sample = 0
        self._state = HomingState.STOP
        self._releasing = False
        self._count = 0  # samples already reported in the current state
        self._total = 0  # samples since start()
        self._kin = KinematicState(float(position_mm))
        self._jerk = 0.0
        self._follower: ProfileFollower | None = None
        self._result = MotionResult.IDLE
        self._message = ""
        self._latched_mm: float | None = None
        self._sensor_latched_mm: float | None = None
        self._home_offset_mm: float | None = None
        #: backing off the home switch it started on (BACK before the re-approach); the
        #: position [mm] where DNP went inactive once it has
        self._off_switch = False
        self._cleared_mm: float | None = None
        self._output = self._make_output()

    # ---- views -------------------------------------------------------------------------------
    @property
    def config(self) -> HomingConfig:
        return self._config

    @property
    def state(self) -> HomingState:
        return self._state

    @property
    def output(self) -> HomingOutput:
        return self._output

    @property
    def latched_mm(self) -> float | None:
        """Where the home sensor was latched [mm] in the current run (``None`` until then)."""
        return self._latched_mm

    @property
    def home_offset_mm(self) -> float | None:
        """The home offset [mm] of the last successful run (``None`` otherwise)."""
        return self._home_offset_mm

    @property
    def sensor_latched_mm(self) -> float | None:
        """The latch from the sensor reading (setpoint of the sample DNP was first read true)
        [mm], kept when :meth:`refine_latch` replaced :attr:`latched_mm` (``None`` until then)."""
        return self._sensor_latched_mm

    #: states in which :meth:`refine_latch` is allowed (home seen, homing not yet finished)
    REFINE_STATES: ClassVar[frozenset[HomingState]] = frozenset({HomingState.DOGE,
                                                                 HomingState.BACK})

    def refine_latch(self, position_mm: float) -> None:
        """Replace the latched home by a more precise ``position_mm`` [mm] (e.g. the drive's
        touch-probe latch of the switch edge), in the same coordinate as the setpoints.

        Allowed once home has been latched and until the back-off has ended (states DOGE and
        BACK of a running homing): the home offset at the end is then ``position_mm``.  The
        motion is not re-planned (push-in and back-off go on from where they are).  The
        sensor latch stays available as :attr:`sensor_latched_mm`.

        Raises:
            ParameterError: ``position_mm`` is not finite.
            StateError: not in DOGE or BACK (nothing latched yet, already finished, or
                aborted); the message names the state.
        """
        require_finite("GotoY.refine_latch", "position_mm", position_mm, "mm")
        if self._state not in self.REFINE_STATES or self._latched_mm is None \
                or self._result is not MotionResult.WORKING:
            raise StateError(f"GotoY.refine_latch(): only while the push-in or back-off runs "
                             f"(DOGE, BACK), not in state {self._state.name}")
        self._latched_mm = float(position_mm)

    @property
    def profile(self) -> Profile | None:
        return self._follower.profile if self._follower is not None else None

    # ---- commands ----------------------------------------------------------------------------
    def start(self, position_mm: float | None = None) -> None:
        """The "go to zero" command (thesis: STOP -> BRAKE).

        ``position_mm`` [mm] optionally re-seeds the position (e.g. the drive's actual).

        Raises:
            StateError: homing is already running (the message names the state).
        """
        if self._state is not HomingState.STOP:
            raise StateError(f"GotoY.start(): homing already running (state {self._state.name})")
        if position_mm is not None:
            require_finite("GotoY.start", "position_mm", position_mm, "mm")
            self._kin = KinematicState(float(position_mm))
        self._state = HomingState.BRAKE
        self._releasing = True
        self._count = 0
        self._total = 0
        self._result = MotionResult.WORKING
        self._message = ""
        self._latched_mm = None
        self._sensor_latched_mm = None
        self._home_offset_mm = None
        self._follower = None
        self._off_switch = False
        self._cleared_mm = None

    @property
    def cleared_mm(self) -> float | None:
        """Started on the home switch: where it went inactive while backing off [mm]
        (``None`` otherwise)."""
        return self._cleared_mm

    def stop(self) -> None:
        """Abort a running homing (result ``ERROR_ABORTED``; jerk-limited stop, brake)."""
        if self._state is HomingState.STOP or self._state is HomingState.ABORT:
            return
        if self._state is HomingState.BRAKE and not self._releasing:
            return
        self._abort(MotionResult.ERROR_ABORTED,
                    f"homing stopped by command in state {self._state.name} "
                    f"at {self._kin.position_mm:.6g} mm")

    # ---- cyclic ------------------------------------------------------------------------------
    def update(self, slow_down: bool, home: bool, *, limit_neg: bool = False,
               limit_pos: bool = False) -> HomingOutput:
        """Advance one sample with this sample's sensor readings; return its setpoint.

        Args:
            slow_down: slow-down sensor DSS active.
            home: home-position sensor DNP active.
            limit_neg, limit_pos: negative / positive limit switch active.

        Never raises; errors come back as ``result`` (< 0) and ``message``.
        """
        self._sample += 1
        self._jerk = 0.0
        before = (self._state, self._releasing)
        if self._state is not HomingState.STOP:
            self._supervise(limit_neg, limit_pos)
            self._process(bool(slow_down), bool(home))
            self._total += 1
        self._count = self._count + 1 if (self._state, self._releasing) == before else 1
        self._output = self._make_output()
        return self._output

    # ---- internals ---------------------------------------------------------------------------
    def _supervised(self) -> bool:
        if self._state is HomingState.ABORT:
            return False
        return not (self._state is HomingState.BRAKE and not self._releasing)

    def _supervise(self, limit_neg: bool, limit_pos: bool) -> None:
        if not self._supervised():
            return
        if limit_neg or limit_pos:
            which = " and ".join(name for name, on in (("negative", limit_neg),
                                                        ("positive", limit_pos)) if on)
            self._abort(MotionResult.ERROR_LIMIT_SWITCH,
                        f"{which} limit switch active at {self._kin.position_mm:.6g} mm "
                        f"in state {self._state.name}: homing aborted")
            return
        period = self._config.sample_period_s
        if self._n_total is not None and self._total >= self._n_total:
            self._abort(MotionResult.ERROR_TIMEOUT,
                        f"homing not finished within {self._config.timeouts.total_s} s "
                        f"(HomingTimeouts.total_s); stopped in state {self._state.name} "
                        f"at {self._kin.position_mm:.6g} mm")
            return
        limit_s = self._config.timeouts.for_state(self._state)
        if limit_s is not None and self._count >= samples_for(limit_s, period):
            name = _TIMEOUT_FIELDS[self._state]
            self._abort(MotionResult.ERROR_TIMEOUT,
                        f"homing state {self._state.name} timed out after "
                        f"{self._count * period:.6g} s (HomingTimeouts.{name} = {limit_s} s) "
                        f"at {self._kin.position_mm:.6g} mm")

    def _abort(self, code: MotionResult, message: str) -> None:
        self._result = code
        self._message = message
        self._state = HomingState.ABORT
        self._follower = ProfileFollower(plan_stop(self._kin, self._config.limits),
                                         self._config.sample_period_s)

    def _follow(self, profile: Profile, state: HomingState) -> None:
        self._follower = ProfileFollower(profile, self._config.sample_period_s)
        self._state = state

    def _velocity(self, speed_mm_s: float, state: HomingState) -> None:
        cfg = self._config
        self._follow(plan_velocity(self._kin, cfg.direction * speed_mm_s, cfg.limits), state)

    def _enter_doge(self) -> None:
        """Latch home here and push in ``push_in_mm`` at the creep speed, ending at rest."""
        cfg = self._config
        self._latched_mm = self._sensor_latched_mm = self._kin.position_mm
        target = self._latched_mm + cfg.direction * cfg.push_in_mm
        ahead = cfg.direction * (target - self._kin.position_mm)
        if ahead >= cfg.direction * stopping_distance_mm(self._kin, cfg.limits):
            profile = plan_position(self._kin, target, cfg.creep_limits)
        else:  # push-in shorter than the stopping distance: just stop (no reversal)
            profile = plan_stop(self._kin, cfg.limits)
        self._follow(profile, HomingState.DOGE)

    def _enter_engage(self) -> None:
        self._follower = None
        self._state = HomingState.BRAKE
        self._releasing = False
        if self._n_engage == 0:
            self._finish()

    def _finish(self) -> None:
        self._state = HomingState.STOP
        self._follower = None
        if self._result is MotionResult.WORKING:
            self._result = MotionResult.FINISHED
            self._home_offset_mm = self._latched_mm

    def _process(self, dss: bool, dnp: bool) -> None:
        state = self._state
        cfg = self._config
        if state is HomingState.BRAKE and not self._releasing:
            if self._count >= self._n_engage:
                self._finish()
            return
        if state is HomingState.BRAKE:
            if self._count < self._n_release:
                return
            if dnp and not dss:
                self._abort(MotionResult.ERROR_SENSOR,
                            "home sensor active without the slow-down sensor at the start "
                            f"({self._kin.position_mm:.6g} mm): check the sensors")
            elif dnp:
                # on the home switch: back off it first, then re-approach its edge
                self._off_switch = True
                self._velocity(cfg.creep_vel_mm_s * -1.0, HomingState.BACK)
            elif dss:
                self._velocity(cfg.creep_vel_mm_s, HomingState.SMALL_V)
            else:
                self._velocity(cfg.search_vel_mm_s, HomingState.ACCEL)
        elif state in (HomingState.ACCEL, HomingState.CONST, HomingState.DEACCEL):
            if dnp:
                self._abort(MotionResult.ERROR_SENSOR,
                            f"home sensor reached in state {state.name} at "
                            f"{self._kin.velocity_mm_s:.6g} mm/s, above the creep speed "
                            f"{cfg.creep_vel_mm_s} mm/s: the slow-down sensor must fire "
                            f"earlier (at {self._kin.position_mm:.6g} mm)")
            elif dss and state is not HomingState.DEACCEL:
                self._velocity(cfg.creep_vel_mm_s, HomingState.DEACCEL)
        elif state is HomingState.SMALL_V and dnp:
            self._enter_doge()
        elif state is HomingState.BACK and self._off_switch and self._cleared_mm is None \
                and not dnp:
            # off the switch: on to rest ``back_off_mm`` further (at least the stopping
            # distance), so that the re-approach reaches the creep speed before the edge
            self._cleared_mm = self._kin.position_mm
            back = self._kin.position_mm - cfg.direction * cfg.back_off_mm
            ahead = -cfg.direction * (back - self._kin.position_mm)
            if ahead > 0.0 and ahead >= -cfg.direction * stopping_distance_mm(
                    self._kin, cfg.creep_limits):
                profile = plan_position(self._kin, back, cfg.creep_limits)
            else:
                profile = plan_stop(self._kin, cfg.creep_limits)
            self._follow(profile, HomingState.BACK)
        if self._state not in _MOVING:
            return
        assert self._follower is not None
        step = self._follower.step()
        self._kin = step.state
        self._jerk = step.jerk_mm_s3
        state = self._state
        if state is HomingState.ACCEL and step.phase is Phase.CONST:
            self._state = HomingState.CONST
        elif state is HomingState.DEACCEL and step.phase is Phase.CONST:
            self._state = HomingState.SMALL_V
        elif step.finished:
            if state is HomingState.DOGE:
                back = self._kin.position_mm - cfg.direction * cfg.back_off_mm
                self._follow(plan_position(self._kin, back, cfg.creep_limits),
                             HomingState.BACK)
            elif state is HomingState.BACK and self._off_switch:
                self._off_switch = False
                self._velocity(cfg.creep_vel_mm_s, HomingState.SMALL_V)
            elif state in (HomingState.BACK, HomingState.ABORT):
                self._enter_engage()

    def _make_output(self) -> HomingOutput:
        kin = self._kin
        released = self._state in _MOVING or (self._state is HomingState.BRAKE
                                               and self._releasing)
        return HomingOutput(self._sample, self._state, self._result, kin.position_mm,
                            kin.velocity_mm_s, kin.acceleration_mm_s2, self._jerk, released,
                            self._message, self._home_offset_mm)


# --------------------------------------------------------------------------------------------
# No homing (absolute encoders) and the drive's own homing mode (executed by the CAN shell)
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, slots=True)
class NoHomingConfig:
    """"No homing" for axes with an absolute encoder: the offset is known in advance.

    Attributes:
        home_offset_mm: the raw position [mm] that is the axis' 0 (axis coordinate =
            raw - home_offset_mm), finite.
    """

    home_offset_mm: float = 0.0

    def __post_init__(self) -> None:
        require_finite("NoHomingConfig", "home_offset_mm", self.home_offset_mm, "mm")


class NoHoming:
    """Homing method "none": no motion, no brake cycle; FINISHED at the first update after
    ``start()`` with the configured offset.  Same interface as :class:`GotoY`."""

    def __init__(self, config: NoHomingConfig, position_mm: float = 0.0) -> None:
        if not isinstance(config, NoHomingConfig):
            raise ParameterError(f"config (={config!r}) must be a NoHomingConfig instance")
        require_finite("NoHoming", "position_mm", position_mm, "mm")
        self._config = config
        self._position_mm = float(position_mm)
        self._sample = 0
        self._started = False

    @property
    def state(self) -> HomingState:
        return HomingState.STOP

    def start(self, position_mm: float | None = None) -> None:
        if position_mm is not None:
            require_finite("NoHoming.start", "position_mm", position_mm, "mm")
            self._position_mm = float(position_mm)
        self._started = True

    def stop(self) -> None:
        """Nothing to stop."""

    def update(self, slow_down: bool = False, home: bool = False, *, limit_neg: bool = False,
               limit_pos: bool = False) -> HomingOutput:
        """One sample: at rest; FINISHED with the configured offset once started."""
        self._sample += 1
        result = MotionResult.FINISHED if self._started else MotionResult.IDLE
        offset = self._config.home_offset_mm if self._started else None
        return HomingOutput(self._sample, HomingState.STOP, result, self._position_mm, 0.0,
                            0.0, 0.0, False, "", offset)


#: CiA 402 homing method values (6098h) that CiA 402-2 reserves.
RESERVED_HOMING_METHODS = frozenset({15, 16, 31, 32, 36})


@dataclass(frozen=True, slots=True)
class DriveHomingConfig:
    """The drive's own homing mode (CiA 402 modes of operation 6060h = 6), run by the CAN
    shell: it writes these objects, switches to mode 6, sets controlword bit 4 and waits for
    statusword bits 10/12 (target reached / homing attained) or 13 (homing error).

    Units are mm here; the shell converts to counts at the drive boundary
    (:class:`~controller.motion.quantize.CountQuantizer`).  ``None`` leaves the drive's
    stored value untouched.

    Attributes:
        method: 6098h homing method (INTEGER8): 1..35 and 37 as in CiA 402-2 (1-14 switches
            with index pulse, 17-30 without, 33/34 index pulse only, 35/37 current
            position), -128..-1 manufacturer-specific.  0 ("no homing") is rejected: use
            :class:`NoHoming`.  15, 16, 31, 32, 36 are reserved.
        timeout_s: how long the shell waits for "homing attained" [s] (> 0).
        switch_search_vel_mm_s: 6099h:01 speed during search for switch [mm/s] (> 0).
        zero_search_vel_mm_s: 6099h:02 speed during search for zero [mm/s] (> 0).
        acc_mm_s2: 609Ah homing acceleration [mm/s^2] (> 0).
        home_offset_mm: 607Ch home offset [mm] (finite).
    """

    MODE_OF_OPERATION: ClassVar[int] = 6  #: 6060h value of the homing mode

    method: int
    timeout_s: float
    switch_search_vel_mm_s: float | None = None
    zero_search_vel_mm_s: float | None = None
    acc_mm_s2: float | None = None
    home_offset_mm: float | None = None

    def __post_init__(self) -> None:
        method = self.method
        if not is_integer(method) or not -128 <= method <= 127:
            raise ParameterError(
                f"DriveHomingConfig.method (={method!r}, object 6098h) must be an integer "
                f"in [-128, 127] (INTEGER8)")
        if method == 0:
            raise ParameterError(
                "DriveHomingConfig.method (=0, object 6098h) means 'no homing': use "
                "NoHoming instead of the drive's homing mode")
        if method in RESERVED_HOMING_METHODS or method > 37:
            raise ParameterError(
                f"DriveHomingConfig.method (={method}, object 6098h) is reserved by "
                f"CiA 402-2: allowed 1..14, 17..30, 33..35, 37, or -128..-1 "
                f"(manufacturer-specific)")
        require_positive("DriveHomingConfig", "timeout_s", self.timeout_s, "s")
        for name, unit in (("switch_search_vel_mm_s", "mm/s"), ("zero_search_vel_mm_s", "mm/s"),
                           ("acc_mm_s2", "mm/s^2")):
            value = getattr(self, name)
            if value is not None:
                require_positive("DriveHomingConfig", name, value, unit)
        if self.home_offset_mm is not None:
            require_finite("DriveHomingConfig", "home_offset_mm", self.home_offset_mm, "mm")

    @property
    def manufacturer_specific(self) -> bool:
        """True for negative (manufacturer-specific) methods."""
        return self.method < 0

    @property
    def timeout_ms(self) -> int:
        """``timeout_s`` in whole milliseconds (rounded up), for the shell's supervision."""
        return math.ceil(self.timeout_s * 1000.0 - 1e-9)
