"""Kinematic limits of one axis, and the small validators the motion package shares.

Units: mm/s, mm/s^2, mm/s^3 (the project's unit legend, see ``controller/__init__.py``).

Spec: docs/spec/axis.md#1.  The thesis' task Sled_Y names a maximum velocity
``Vm`` and a constant jerk ``k`` for its triangular acceleration pulses; it names no
acceleration bound.  We add one (``max_acc``) because a drive has one: a triangular pulse
whose peak would exceed it is made longer with a smaller jerk (see ``profile.py``).
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, replace
from typing import TypeGuard

from ..errors import ParameterError


def _is_real(value: object) -> TypeGuard[float]:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_integer(value: object) -> bool:
    """True for an integral number (Python or numpy int), not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def require_positive(owner: str, name: str, value: object, unit: str) -> None:
    """Raise :class:`ParameterError` unless ``value`` is a finite number > 0.

    ``owner`` and ``name`` say where the value sits (``"AxisLimits"``, ``"max_vel"``),
    ``unit`` is printed with it.
    """
    if not (_is_real(value) and math.isfinite(value) and value > 0):
        raise ParameterError(
            f"{owner}.{name} (={value!r} {unit}) is out of range: must be a finite number > 0")


def require_non_negative(owner: str, name: str, value: object, unit: str) -> None:
    """Raise :class:`ParameterError` unless ``value`` is a finite number >= 0."""
    if not (_is_real(value) and math.isfinite(value) and value >= 0):
        raise ParameterError(
            f"{owner}.{name} (={value!r} {unit}) is out of range: must be a finite number >= 0")


def require_finite(owner: str, name: str, value: object, unit: str) -> None:
    """Raise :class:`ParameterError` unless ``value`` is a finite number."""
    if not (_is_real(value) and math.isfinite(value)):
        raise ParameterError(
            f"{owner}.{name} (={value!r} {unit}) is out of range: must be a finite number")


@dataclass(frozen=True, slots=True)
class AxisLimits:
    """Velocity, acceleration and jerk bounds of one axis (magnitudes, both directions).

    Attributes:
        max_vel: maximum |velocity| [mm/s] (the thesis' ``Vm``).
        max_acc: maximum |acceleration| [mm/s^2] (not in the thesis, see the module doc).
        max_jerk: maximum |jerk| [mm/s^3] (the thesis' constant ``k`` is at most this).

    Raises:
        ParameterError: a bound is not a finite number > 0 (the message names it and its
            allowed range).
    """

    max_vel: float
    max_acc: float
    max_jerk: float

    def __post_init__(self) -> None:
        require_positive("AxisLimits", "max_vel", self.max_vel, "mm/s")
        require_positive("AxisLimits", "max_acc", self.max_acc, "mm/s^2")
        require_positive("AxisLimits", "max_jerk", self.max_jerk, "mm/s^3")

    def with_max_vel(self, max_vel: float) -> AxisLimits:
        """These limits with another velocity bound [mm/s] (e.g. a creep speed)."""
        return replace(self, max_vel=max_vel)

    @property
    def jerk_bound_velocity(self) -> float:
        """max_acc^2 / max_jerk [mm/s]: the velocity change above which a triangular pulse
        at full jerk would exceed ``max_acc`` (so its jerk is lowered instead)."""
        return self.max_acc * self.max_acc / self.max_jerk
