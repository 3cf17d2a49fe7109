"""The small validators the motion package shares (a clear :class:`ParameterError` naming
the owner, the field, the value with its unit and the allowed range).

An axis' kinematic limits are :class:`controller.limits.Limits` (``vel`` [mm/s], ``acc``
[mm/s^2], ``jerk`` [mm/s^3]).  Spec: docs/spec/axis.md#1.  The thesis' task Sled_Y names a
maximum velocity ``Vm`` and a constant jerk ``k`` for its triangular acceleration pulses; it
names no acceleration bound.  We add one (``acc``) because a drive has one: a triangular
pulse whose peak would exceed it is made longer with a smaller jerk (see ``profile.py``).
"""

from __future__ import annotations

import math
import numbers
from typing import TypeGuard

from ..errors import ParameterError


def _is_real(value: object) -> TypeGuard[float]:
    return isinstance(value, numbers.Real) and not isinstance(value, bool)


def is_integer(value: object) -> bool:
    """True for an integral number (Python or numpy int), not a bool."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def require_positive(owner: str, name: str, value: object, unit: str) -> None:
    """Raise :class:`ParameterError` unless ``value`` is a finite number > 0.

    ``owner`` and ``name`` say where the value sits (``"AxisConfig"``, ``"sample_period_s"``),
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
