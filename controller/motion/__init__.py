"""Pure axis-level motion: jerk-limited point-to-point moves with brake handling, homing, jog.

Units: mm, mm/s, mm/s^2, mm/s^3, s (see ``controller/__init__.py``); drive counts only in
:mod:`.quantize`.  Everything is stepped by an integer sample counter: each ``update()``
produces the setpoint of the next sample (time k*T).  No clocks, threads or I/O.

Spec: docs/spec/axis.md (the thesis' tasks Sled_Y and GotoY), with the DECCEL position
formula fixed (docs/spec/axis.md#2.2).

Modules:
    checks    -- the shared validators (an axis' limits: :class:`controller.limits.Limits`)
    profile   -- the triangular-pulse planner and the thesis' integration step (fixed)
    ptp       -- :class:`PointToPoint` (Sled_Y) with brake timing; :class:`AxisOutput`
    jog       -- :class:`Jog`
    homing    -- :class:`GotoY`, :class:`NoHoming`, :class:`DriveHomingConfig`
    quantize  -- :class:`CountQuantizer` (mm -> counts at the drive boundary)
"""

from .homing import (
    DriveHomingConfig,
    GotoY,
    HomingConfig,
    HomingOutput,
    HomingState,
    HomingTimeouts,
    NoHoming,
    NoHomingConfig,
)
from .jog import Jog
from .profile import (
    KinematicState,
    Phase,
    Profile,
    ProfileFollower,
    Segment,
    integrate_step,
    plan_position,
    plan_rest_to_rest,
    plan_stop,
    plan_velocity,
    triangle_pulse,
)
from .ptp import AxisConfig, AxisOutput, BrakedAxis, MotionResult, PointToPoint, PtpState
from .quantize import CountQuantizer

__all__ = [
    "AxisConfig", "AxisOutput", "BrakedAxis", "CountQuantizer",
    "DriveHomingConfig", "GotoY", "HomingConfig", "HomingOutput", "HomingState",
    "HomingTimeouts", "Jog", "KinematicState", "MotionResult", "NoHoming", "NoHomingConfig",
    "Phase", "PointToPoint", "Profile", "ProfileFollower", "PtpState", "Segment",
    "integrate_step", "plan_position", "plan_rest_to_rest", "plan_stop", "plan_velocity",
    "triangle_pulse",
]
