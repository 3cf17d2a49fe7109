"""Type 3, a robot group's TCP as the master (the softMC overview's "phase 3": "If the master
source is another moving frame (e.g., TCP-coordinates of any other kinematics with more than
2 axes), the offset/transformation between the tracking kinematics and the tracked
kinematics is considered ... the offset must be taken into consideration in TRIGGER").

The master is the TCP location L(t) of another robot group, in the tracking robot's world
(``transform : TCP``, :class:`controller.conveyor.sources.GroupSource`).  Its four DOF
coordinates are the TCP's position displacement and its rotation about the frame ``axis``
(world, a unit vector) since the item's trigger::

    c = (Δx, Δy, Δz, Δθ)   [mm, mm, mm, deg]

At TRIGGER the item's full location W0 (position and orientation, world) is taken: the
master TCP's location then composed with the given offset P (``W0 = L0 : P``; P = identity:
the item sits at the TCP), or given directly.  The item stays rigidly attached to the TCP::

    MF(t).ori = Q(Δθ, axis) · W0.ori
    MF(t).pos = L0.pos + Δp + Q(Δθ, axis) · (W0.pos - L0.pos)
    MF(0) = MF.zero = W0

so ``MF(t) = M(t) : W0`` with the TCP's motion since the trigger ``M = L(t) : L0⁻¹`` (exact
when the TCP turns about ``axis`` only: the frame's one rotation channel; a rotation about
other axes is not followed).  Velocity and acceleration are those of a rigid body:
``v = v_p + ω × r``, ``a = a_p + α × r + ω × (ω × r)``, ``r = Q(Δθ)·(W0 - L0)``,
``ω = θ'·axis``.  Spec: docs/spec/conveyor-extensions.md#4.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Sequence

from ...errors import ParameterError, StateError
from ...tracking.values import python_class
from ..location import (Location, Vec3, q_axis_angle, q_conj, q_mul, q_rotate, v_add, v_cross,
                        v_scale, v_sub, v_unit)
from .base import FramePoint

if TYPE_CHECKING:
    from ..triggers import TriggerEntry


@python_class
@dataclass(frozen=True, slots=True)
class GroupGeometry:
    """A robot group's TCP as a 4-DOF frame: ``axis`` (world, normalised) of the rotation
    DOF; ``master_dimension``: the master robot's world-frame dimension (for the kinematic
    check)."""

    axis: Vec3 = (0.0, 0.0, 1.0)
    master_dimension: int = 6

    def __post_init__(self) -> None:
        object.__setattr__(self, "axis", v_unit(self.axis, "group frame axis"))

    # (properties, not class attributes: compiled, a dataclass's class attributes would be
    # fields, docs/architecture.md "Compiled core")
    @property
    def nof(self) -> int:
        return 4

    @property
    def units(self) -> str:
        return "mm, mm, mm, deg"

    @property
    def rotates(self) -> bool:
        return True

    @property
    def local_axis(self) -> Vec3:
        """The angle channel's axis for an item whose zero has identity orientation."""
        return self.axis

    def local_axis_for(self, item: "TriggerEntry") -> Vec3:
        """The rotation axis of ``MF(0) ⊖ MF(t)`` for ``item``: W0.ori⁻¹ · axis."""
        return q_rotate(q_conj(_w0(item).ori), self.axis)

    def coords(self, values: Sequence[float], trigger: Sequence[float]) -> tuple[float, ...]:
        """(Δx, Δy, Δz, Δθ) [mm, deg] of the TCP since the trigger."""
        return tuple(m - t for m, t in zip(values, trigger))

    def rates(self, rates: Sequence[float]) -> tuple[float, ...]:
        return tuple(rates)

    def zero(self, dr_mm: float = 0.0, item: "TriggerEntry | None" = None) -> Location:
        """MF.zero: the item's location at its trigger (W0)."""
        if item is None:
            raise StateError("a group frame's zero is the item's location at its trigger: "
                             "give the item")
        return _w0(item)

    def point(self, c: Sequence[float], cd: Sequence[float], cdd: Sequence[float],
              dr_mm: float = 0.0, item: "TriggerEntry | None" = None) -> FramePoint:
        if item is None:
            raise StateError("a group frame's here needs the item (its location at TRIGGER)")
        w0 = _w0(item)
        l0 = tuple(item.values[:3])
        a = self.axis
        q = q_axis_angle(a, c[3])
        r = q_rotate(q, v_sub(w0.pos, l0))
        pos = v_add(v_add(l0, c[:3]), r)
        w = v_scale(a, math.radians(cd[3]))
        al = v_scale(a, math.radians(cdd[3]))
        vel = v_add(cd[:3], v_cross(w, r))
        acc = v_add(v_add(cdd[:3], v_cross(al, r)), v_cross(w, v_cross(w, r)))
        return FramePoint(Location(pos, q_mul(q, w0.ori)), vel, acc, c[3], cd[3], cdd[3])


def _w0(item: "TriggerEntry") -> Location:
    if item.zero is None:
        raise ParameterError(f"item {item.id} of group frame {item.frame!r} has no location "
                             "at its trigger")
    return item.zero
