"""Jog: move an axis at a commanded velocity within its limits, with brake handling.

Units: mm, mm/s, mm/s^2, mm/s^3, s.  Pure; stepped by ``update()`` once per sample.

Not in the thesis (docs/spec/axis.md#4); built from the Sled_Y pieces (``ptp.py``) so
that a jog behaves like a point-to-point move whose CONST phase lasts until the next command:

    BRAKE_RELEASE -> ACCEL/DECEL (one triangular pulse to the new velocity) -> CONST ...
    stop: DECEL (jerk-limited) -> BRAKE_ENGAGE -> WAIT -> READY

A velocity change while moving starts a new pulse from the current (v, a)
(:func:`~controller.motion.profile.plan_velocity`); a reversal brakes through zero inside
that pulse.  ``set_velocity(0)`` is :meth:`Jog.stop`.  A command during BRAKE_ENGAGE/WAIT is
queued until READY, as for point-to-point moves.  There are no position limits here: the
caller (or the drive's software limits, 607Dh) bounds the travel.
"""

from __future__ import annotations

from ..errors import ParameterError
from .checks import require_finite
from .profile import plan_velocity
from .ptp import MOTION_STATES, AxisConfig, BrakedAxis, PtpState

__all__ = ["AxisConfig", "Jog"]


class Jog(BrakedAxis):
    """Jog an axis at a commanded velocity [mm/s] (start, change speed, stop; all
    jerk-limited).  States and outputs are those of :class:`~.ptp.PointToPoint`."""

    @property
    def velocity_command_mm_s(self) -> float:
        """The velocity being approached or held [mm/s] (0 when stopped or stopping)."""
        return self._velocity_command

    def __init__(self, config: AxisConfig, position_mm: float = 0.0) -> None:
        super().__init__(config, position_mm)
        self._velocity_command = 0.0

    def set_velocity(self, velocity_mm_s: float) -> None:
        """Start jogging, or change the jog velocity, to ``velocity_mm_s`` [mm/s].

        Raises:
            ParameterError: not finite, or ``|velocity_mm_s|`` above ``limits.vel``
                (the message names the allowed range).
        """
        require_finite("Jog", "velocity_mm_s", velocity_mm_s, "mm/s")
        limits = self._config.limits
        velocity = float(velocity_mm_s)
        if abs(velocity) > limits.vel:
            raise ParameterError(
                f"Jog.velocity_mm_s (={velocity!r} mm/s) is out of range: must be within "
                f"[-{limits.vel}, {limits.vel}] mm/s (Limits.vel)")
        if velocity == 0.0:
            self.stop()
            return
        if velocity == self._velocity_command and (
                self._state in MOTION_STATES or self._state is PtpState.BRAKE_RELEASE):
            return
        self._velocity_command = velocity
        self._command(lambda state: plan_velocity(state, velocity, limits))

    def stop(self) -> None:
        """Stop as soon as the limits allow (jerk-limited), then engage the brake."""
        self._velocity_command = 0.0
        self._cancel()
