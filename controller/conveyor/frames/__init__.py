"""Frame geometries: where an item is for given per-DOF frame coordinates.

- :mod:`.linear` — type 0: NOF master sources, each along a direction vector.
- :mod:`.rotary` — type 1 (rotary) and type 2 (rotary decoupled): the arc through UpStream[1],
  ArcPoint and DownStream[1].
- :mod:`.group` — type 3: another robot group's TCP (position and a rotation about an axis)
  as a 4-DOF master; the item's location is taken at its TRIGGER.

A geometry is immutable and pure: ``point(c, cd, cdd, dr_mm)`` maps the item's coordinates
(displacement since its trigger, per DOF, in frame units: mm for linear DOFs, deg for the
rotary angle) and their rates to :class:`FramePoint` (``<MF>.here``, docs/spec/conveyor.md#3.3);
``item`` (the trigger entry) is used by the group geometry only.
"""

from .base import FramePoint
from .group import GroupGeometry
from .linear import LinearGeometry
from .rotary import ArcGeometry, RotaryGeometry, arc_from_points

__all__ = ["ArcGeometry", "FramePoint", "GroupGeometry", "LinearGeometry", "RotaryGeometry",
           "arc_from_points"]
