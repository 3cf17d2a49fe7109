"""Kinematic limits: the one value type every layer uses for velocity/acceleration/jerk bounds.

:class:`Limits` bounds one channel: a translation (the norm of a Cartesian vector, or one
linear axis) in mm/s, mm/s^2, mm/s^3, or a rotation (one angle) in deg/s, deg/s^2,
deg/s^3.  :class:`CartesianLimits` holds the two channels of a tool or a moving frame.

Users: the tracker's sync/de-sync limits, the robot's and the moving frame's maxima
(docs/spec/tracking.md#2.5, docs/spec/conveyor.md#3.5), the virtual robot's motions
(docs/spec/conveyor.md#6.1), an axis' moves, jog and homing (docs/spec/axis.md#1).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace
from typing import TypeGuard

from .errors import ParameterError

__all__ = ["CartesianLimits", "Limits"]


def _is_real(value: object) -> TypeGuard[float]:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def _check_bound(name: str, value: object, unit: str) -> None:
    if not (_is_real(value) and math.isfinite(value) and value > 0):
        raise ParameterError(
            f"Limits.{name} (={value!r} {unit}) is out of range: must be a finite number > 0")


@dataclass(frozen=True, slots=True)
class Limits:
    """Velocity, acceleration and jerk bounds of one channel (magnitudes, both directions).

    Attributes:
        vel: maximum |velocity| [mm/s] (rotation: [deg/s]).
        acc: maximum |acceleration| [mm/s^2] (rotation: [deg/s^2]).
        jerk: maximum |jerk| [mm/s^3] (rotation: [deg/s^3]).

    For a Cartesian translation the bounds apply to the norm of the vector.

    Raises:
        ParameterError: a bound is not a finite real number > 0 (a bool is not a number
            here); the message names the bound, its value and the allowed range.
    """

    vel: float
    acc: float
    jerk: float

    def __post_init__(self) -> None:
        _check_bound("vel", self.vel, "mm/s or deg/s")
        _check_bound("acc", self.acc, "mm/s^2 or deg/s^2")
        _check_bound("jerk", self.jerk, "mm/s^3 or deg/s^3")

    def scaled(self, vel: float = 1.0, acc: float = 1.0, jerk: float = 1.0) -> Limits:
        """These limits with each bound multiplied by a factor."""
        return Limits(self.vel * vel, self.acc * acc, self.jerk * jerk)

    def capped(self, other: Limits) -> Limits:
        """Component-wise minimum with ``other``."""
        return Limits(min(self.vel, other.vel), min(self.acc, other.acc),
                      min(self.jerk, other.jerk))

    def with_vel(self, vel: float) -> Limits:
        """These limits with another velocity bound [mm/s or deg/s] (e.g. a creep speed)."""
        return replace(self, vel=vel)

    @property
    def jerk_bound_velocity(self) -> float:
        """acc^2 / jerk [mm/s or deg/s]: the velocity change above which a triangular
        acceleration pulse at full jerk would exceed ``acc`` (docs/spec/axis.md#1)."""
        return self.acc * self.acc / self.jerk


@dataclass(frozen=True, slots=True)
class CartesianLimits:
    """The limits of a tool or a moving frame: translation and rotation about the tool axis.

    Attributes:
        trans: translation bounds [mm/s, mm/s^2, mm/s^3] (on the norm of the vector).
        rot: rotation bounds [deg/s, deg/s^2, deg/s^3].

    Raises:
        ParameterError: ``trans`` or ``rot`` is not a :class:`Limits`.
    """

    trans: Limits
    rot: Limits

    def __post_init__(self) -> None:
        for name in ("trans", "rot"):
            value = getattr(self, name)
            if not isinstance(value, Limits):
                raise ParameterError(
                    f"CartesianLimits.{name} (={value!r}) must be a Limits instance")
