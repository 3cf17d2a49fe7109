"""Machine kinematics: Cartesian tool pose (mm, deg) <-> joint positions, per machine type.

Klipper style: one small module per machine type, each with the same factory
``create(axes) -> Kinematics``, chosen by name from the configuration through
:data:`KINEMATICS` (imported lazily, python-can style).  Drive counts exist only after
:mod:`controller.kinematics.counts`, the one place where mm/deg become counts and back.

Unit legend: pose and joints in mm (x, y, z) and deg (c, the tool angle); counts are the
drive's increments (integers).
"""

from __future__ import annotations

# first: controller.tracking chooses compiled or pure for this package's modules too
# (docs/architecture.md "Compiled core"), before one of them is loaded
from .. import tracking as _tracking  # noqa: F401
import importlib
from collections.abc import Callable, Sequence
from typing import Protocol

from ..errors import ParameterError
from ..tracking import MotionState
from .counts import AxisScale, CountsConverter, EncoderScale

__all__ = [
    "KINEMATICS",
    "AxisScale",
    "CountsConverter",
    "EncoderScale",
    "Kinematics",
    "create",
]


class Kinematics(Protocol):
    """A machine type.  Pure: no state beyond its configuration."""

    name: str
    #: joint names in drive order (e.g. ("x", "y", "z", "c"))
    axes: tuple[str, ...]

    def joints(self, pose: MotionState) -> tuple[float, ...]:
        """Inverse kinematics: the joint positions [mm | deg] for a tool pose."""
        ...

    def joint_velocities(self, pose: MotionState) -> tuple[float, ...]:
        """Joint velocities [mm/s | deg/s] of a moving pose."""
        ...

    def pose(self, joints: Sequence[float]) -> MotionState:
        """Forward kinematics: the pose (at rest) of joint positions [mm | deg]."""
        ...


#: machine type -> "module:factory"; factory(axis names) -> Kinematics
KINEMATICS: dict[str, str] = {
    "cartesian": "controller.kinematics.cartesian:create",
}


def create(kind: str, axes: Sequence[str]) -> Kinematics:
    """The kinematics of machine type ``kind`` over the named ``axes``."""
    try:
        target = KINEMATICS[kind]
    except KeyError:
        raise ParameterError(f"kinematics type (={kind!r}) must be one of "
                             f"{', '.join(sorted(KINEMATICS))}") from None
    module_name, attr = target.split(":")
    factory: Callable[[Sequence[str]], Kinematics] = getattr(
        importlib.import_module(module_name), attr)
    return factory(axes)
