"""Point-to-point axis moves with brake handling: the thesis' task Sled_Y.

Units: mm, mm/s, mm/s^2, mm/s^3, s.  Pure and deterministic: the object is stepped by
``update()`` once per sample of period T; sample k is at time k*T (integer counter).

Spec: docs/spec/axis.md#3, the thesis' task Sled_Y (states #3.1):

    STOP_SY -> BRAKE_SY (wait Tbrake) -> ACCEL_SY -> CONST_SY -> DEACCEL_SY -> BRAKE_SY
            -> WAIT (Tstop) -> READY

The thesis' STEP_SY (advance one time step dt) is the ``update()`` call itself.

Readings chosen where the thesis is silent or ambiguous (docs/spec/axis.md#3.2):

* The thesis' one BRAKE_SY state (it remembers the previous state to know whether it is
  releasing or engaging) is two states here, :attr:`PtpState.BRAKE_RELEASE` and
  :attr:`PtpState.BRAKE_ENGAGE`, so the state alone says what the brake does.
* Timed states last whole samples: ``n = ceil(t/T)`` (release, engage, stop time).  After a
  command at sample k0 the samples k0+1 .. k0+n_release are BRAKE_RELEASE with the position
  held; motion time 0 is sample k0+n_release, so no motion happens before the release time
  has passed.  The first sample at rest on the target is the first BRAKE_ENGAGE sample;
  n_engage BRAKE_ENGAGE samples, n_stop WAIT samples, then READY.
* STOP is the initial idle state (result IDLE); READY the idle state after a move (result
  FINISHED).  Both accept commands.  A target equal to the current position while idle
  finishes at once, without a brake cycle.
* A new target during ACCEL/CONST/DECEL is re-planned from the current (p, v, a)
  (:func:`~controller.motion.profile.plan_position`), during BRAKE_RELEASE it replaces the
  plan, during BRAKE_ENGAGE/WAIT it is queued and started when the wait is over (the brake is
  then released again).  The same target again is ignored (no re-plan).
* The position is integrated with the thesis' formulas as fixed in ``profile.py`` and is
  set exactly on the target (velocity and acceleration exactly 0) when the profile ends.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum, IntEnum

from ..errors import ParameterError
from ..limits import Limits
from .checks import require_finite, require_non_negative, require_positive
from .profile import (
    KinematicState,
    Phase,
    Profile,
    ProfileFollower,
    plan_position,
    plan_stop,
)

#: Tolerance for turning a time [s] into whole samples: ceil(t/T - this).
_SAMPLE_ROUNDING = 1e-9


def samples_for(duration_s: float, sample_period_s: float) -> int:
    """Whole samples needed to cover ``duration_s`` [s] at period ``sample_period_s`` [s]."""
    if duration_s <= 0.0:
        return 0
    return max(0, math.ceil(duration_s / sample_period_s - _SAMPLE_ROUNDING))


class MotionResult(IntEnum):
    """Result code of one cyclic ``update()`` (Ruckig style: >= 0 ok, < 0 error)."""

    WORKING = 0  #: a command is being executed
    FINISHED = 1  #: the last command is done (axis at rest, brake engaged)
    IDLE = 2  #: nothing has been commanded yet
    ERROR = -1  #: generic error
    ERROR_LIMIT_SWITCH = -2  #: a limit switch became active (the message says which)
    ERROR_TIMEOUT = -3  #: a phase or the whole procedure took too long
    ERROR_SENSOR = -4  #: the sensors contradict each other or the expected sequence
    ERROR_ABORTED = -5  #: stopped by command before completion


class PtpState(Enum):
    """States of Sled_Y (thesis table 2.3), BRAKE_SY split by direction."""

    STOP = "STOP"  #: STOP_SY: initial idle state, brake engaged
    BRAKE_RELEASE = "BRAKE_RELEASE"  #: BRAKE_SY coming from STOP: wait for the brake to open
    ACCEL = "ACCEL"  #: ACCEL_SY: triangular acceleration pulse
    CONST = "CONST"  #: CONST_SY: constant velocity (may last 0 s)
    DECEL = "DECEL"  #: DEACCEL_SY / DECCEL: triangular deceleration pulse
    BRAKE_ENGAGE = "BRAKE_ENGAGE"  #: BRAKE_SY coming from DECCEL: wait for the brake to close
    WAIT = "WAIT"  #: WAIT: hold for the stop time Tstop
    READY = "READY"  #: READY: move done


_PHASE_STATE = {Phase.ACCEL: PtpState.ACCEL, Phase.CONST: PtpState.CONST,
                Phase.DECEL: PtpState.DECEL}
MOTION_STATES = frozenset({PtpState.ACCEL, PtpState.CONST, PtpState.DECEL})
_IDLE_STATES = frozenset({PtpState.STOP, PtpState.READY})


@dataclass(frozen=True, slots=True)
class AxisOutput:
    """What one ``update()`` returns: the setpoint of sample ``sample`` (time sample*T).

    Attributes:
        sample: sample index k (the object's integer counter; time k*T).
        state: the state machine's state at this sample (an Enum of the producing class).
        result: :class:`MotionResult` code.
        position_mm, velocity_mm_s, acceleration_mm_s2: the setpoint [mm, mm/s, mm/s^2].
        jerk_mm_s3: jerk of the segment active at this sample [mm/s^3] (0 at rest).
        brake_released: True while the brake is commanded open (from the first release
            sample to the last motion sample).
        message: human-readable detail for error results ("" otherwise).
    """

    sample: int
    state: Enum
    result: MotionResult
    position_mm: float
    velocity_mm_s: float
    acceleration_mm_s2: float
    jerk_mm_s3: float
    brake_released: bool
    message: str = ""


@dataclass(frozen=True, slots=True)
class AxisConfig:
    """Parameters of a braked axis (Sled_Y and jog).

    Attributes:
        limits: velocity/acceleration/jerk bounds.
        sample_period_s: sample period T [s] of ``update()`` (> 0).
        brake_release_s: time the brake needs to open [s] (thesis ``Ttormoz``), >= 0.
        brake_engage_s: time the brake needs to close [s], >= 0.
        stop_time_s: hold time after the brake closed [s] (thesis WAIT ``Tstop``), >= 0.
    """

    limits: Limits
    sample_period_s: float
    brake_release_s: float = 0.0
    brake_engage_s: float = 0.0
    stop_time_s: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.limits, Limits):
            raise ParameterError(
                f"AxisConfig.limits (={self.limits!r}) must be a Limits instance")
        require_positive("AxisConfig", "sample_period_s", self.sample_period_s, "s")
        require_non_negative("AxisConfig", "brake_release_s", self.brake_release_s, "s")
        require_non_negative("AxisConfig", "brake_engage_s", self.brake_engage_s, "s")
        require_non_negative("AxisConfig", "stop_time_s", self.stop_time_s, "s")

    @property
    def release_samples(self) -> int:
        return samples_for(self.brake_release_s, self.sample_period_s)

    @property
    def engage_samples(self) -> int:
        return samples_for(self.brake_engage_s, self.sample_period_s)

    @property
    def stop_samples(self) -> int:
        return samples_for(self.stop_time_s, self.sample_period_s)


Planner = Callable[[KinematicState], Profile]


class BrakedAxis:
    """The Sled_Y machinery shared by :class:`PointToPoint` and :class:`~.jog.Jog`.

    Commands hand in a *planner* (a function from the current state to a
    :class:`~controller.motion.profile.Profile`); the machine releases the brake, follows the
    profile sample by sample, engages the brake, waits and reports READY.
    """

    def __init__(self, config: AxisConfig, position_mm: float = 0.0) -> None:
        if not isinstance(config, AxisConfig):
            raise ParameterError(f"config (={config!r}) must be an AxisConfig instance")
        require_finite(type(self).__name__, "position_mm", position_mm, "mm")
        self._config = config
        self._n_release = config.release_samples
        self._n_engage = config.engage_samples
        self._n_stop = config.stop_samples
        self._sample = 0
        self._state = PtpState.STOP
        self._count = 0  # samples already spent in the current timed state
        self._kin = KinematicState(float(position_mm))
        self._jerk = 0.0
        self._profile: Profile | None = None
        self._follower: ProfileFollower | None = None
        self._pending: Planner | None = None
        self._output = self._make_output()

    # ---- read-only views -------------------------------------------------------------------
    @property
    def config(self) -> AxisConfig:
        return self._config

    @property
    def state(self) -> PtpState:
        return self._state

    @property
    def sample(self) -> int:
        """Index of the last sample produced (0 before the first ``update()``)."""
        return self._sample

    @property
    def kinematic_state(self) -> KinematicState:
        """Setpoint at the last sample."""
        return self._kin

    @property
    def profile(self) -> Profile | None:
        """The profile being (or about to be) followed, ``None`` when idle."""
        return self._profile

    @property
    def output(self) -> AxisOutput:
        """The last output (the initial state before the first ``update()``)."""
        return self._output

    # ---- commands ----------------------------------------------------------------------------
    def _command(self, planner: Planner) -> None:
        state = self._state
        if state in _IDLE_STATES:
            profile = planner(self._kin)
            if profile.duration_s == 0.0:
                return  # nothing to do: no brake cycle
            self._profile = profile
            self._follower = None
            self._state = PtpState.BRAKE_RELEASE
            self._count = 0
        elif state is PtpState.BRAKE_RELEASE:
            self._profile = planner(self._kin)
        elif state in MOTION_STATES:
            self._start_profile(planner(self._kin))
        else:  # BRAKE_ENGAGE, WAIT: queue until READY
            self._pending = planner

    def _cancel(self) -> None:
        """Stop request: jerk-limited stop, then the brake cycle (queued commands dropped)."""
        self._pending = None
        state = self._state
        if state is PtpState.BRAKE_RELEASE:
            self._profile = None
            self._follower = None
            self._state = PtpState.BRAKE_ENGAGE
            self._count = 0
        elif state in MOTION_STATES:
            self._start_profile(plan_stop(self._kin, self._config.limits))

    def _start_profile(self, profile: Profile) -> None:
        self._profile = profile
        self._follower = ProfileFollower(profile, self._config.sample_period_s)

    # ---- cyclic ------------------------------------------------------------------------------
    def update(self) -> AxisOutput:
        """Advance one sample and return its setpoint (never raises for valid commands)."""
        self._sample += 1
        self._process()
        self._output = self._make_output()
        return self._output

    def _process(self) -> None:
        self._jerk = 0.0
        if self._state is PtpState.BRAKE_RELEASE:
            if self._count < self._n_release:
                self._count += 1
                return
            assert self._profile is not None
            self._start_profile(self._profile)
            self._state = PtpState.ACCEL  # provisional: the first step below sets the phase
        if self._state in MOTION_STATES:
            assert self._follower is not None
            step = self._follower.step()
            self._kin = step.state
            if not step.finished:
                assert step.phase is not None
                self._jerk = step.jerk_mm_s3
                self._state = _PHASE_STATE[step.phase]
                return
            self._profile = None
            self._follower = None
            self._state = PtpState.BRAKE_ENGAGE
            self._count = 0
        if self._state is PtpState.BRAKE_ENGAGE:
            if self._count < self._n_engage:
                self._count += 1
                return
            self._state = PtpState.WAIT
            self._count = 0
        if self._state is PtpState.WAIT:
            if self._count < self._n_stop:
                self._count += 1
                return
            self._state = PtpState.READY
            if self._pending is not None:
                planner, self._pending = self._pending, None
                self._command(planner)
                if self._state is PtpState.BRAKE_RELEASE:
                    self._process()  # this sample is the first of the release wait

    def _result(self) -> MotionResult:
        if self._state is PtpState.STOP:
            return MotionResult.IDLE
        if self._state is PtpState.READY:
            return MotionResult.FINISHED
        return MotionResult.WORKING

    def _make_output(self) -> AxisOutput:
        kin = self._kin
        released = self._state is PtpState.BRAKE_RELEASE or self._state in MOTION_STATES
        return AxisOutput(self._sample, self._state, self._result(), kin.position_mm,
                          kin.velocity_mm_s, kin.acceleration_mm_s2, self._jerk, released)


class PointToPoint(BrakedAxis):
    """Thesis task Sled_Y: move to a commanded coordinate Yc with brake handling.

    Example::

        axis = PointToPoint(AxisConfig(Limits(500, 5000, 1e5), 0.001, 0.05, 0.05, 0.1))
        axis.set_target(150.0)
        while (out := axis.update()).result is MotionResult.WORKING:
            send(out.position_mm)
    """

    @property
    def target_mm(self) -> float | None:
        """The target being approached [mm] (``None`` when idle)."""
        return self._profile.target_mm if self._profile is not None else None

    def set_target(self, target_mm: float) -> None:
        """Command a move to ``target_mm`` [mm] (thesis Yc); see the module doc for each state.

        Raises:
            ParameterError: ``target_mm`` is not a finite number.
        """
        require_finite("PointToPoint", "target_mm", target_mm, "mm")
        target = float(target_mm)
        moving = self._state in MOTION_STATES or self._state is PtpState.BRAKE_RELEASE
        if moving and self.target_mm == target:
            return
        limits = self._config.limits
        self._command(lambda state: plan_position(state, target, limits))

    def stop(self) -> None:
        """Stop as soon as the limits allow (jerk-limited), then engage the brake."""
        self._cancel()
