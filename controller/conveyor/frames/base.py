"""The value a frame geometry produces: the item's location and its derivatives."""

from __future__ import annotations

from dataclasses import dataclass

from ...tracking.values import fast_init
from ..location import Location, Vec3


@fast_init
@dataclass(frozen=True, slots=True)
class FramePoint:
    """The moving frame at one sample for one item (``<MF>.here``) and its rates.

    ``here``: location [mm, quaternion]; ``vel`` [mm/s], ``acc`` [mm/s^2] of its position;
    ``ang`` [deg]: the rotation of ``here.ori`` since the item's zero about the frame's rotation
    axis (type 1 only; 0 for linear and rotary-decoupled frames), ``ang_vel`` [deg/s],
    ``ang_acc`` [deg/s^2].
    """

    here: Location
    vel: Vec3
    acc: Vec3
    ang: float = 0.0
    ang_vel: float = 0.0
    ang_acc: float = 0.0
