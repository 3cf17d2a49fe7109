"""Type 0, the linear moving frame (docs/spec/conveyor.md#3.3).

Each of the NOF master sources moves the frame along its own direction vector; a source value
m_i (source units: encoder counts, axis units, ...) is scaled to mm by ``scales[i]``
[mm per source unit].  For an item triggered at source values trig_i::

    c_i            = scales[i] * (m_i - trig_i)                 [mm]  (DOF coordinate)
    MF(t).pos      = origin.pos + sum_i directions[i] * c_i
    MF(t).ori      = origin.ori                                  (a linear frame does not turn)
    MF(0) = MF.zero = origin                                     (c = 0: the trigger point)

The directions need not be orthogonal (an XY table has two, a single belt one); they are
normalised.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from ...errors import ParameterError
from ...tracking.values import python_class
from ..location import Location, Vec3, v_unit, vec3
from .base import FramePoint


@python_class
@dataclass(frozen=True, slots=True)
class LinearGeometry:
    """``origin``: the trigger point's location (MF.zero); ``directions``: one unit vector per
    DOF; ``scales``: mm per source unit, one per DOF."""

    origin: Location
    directions: tuple[Vec3, ...]
    scales: tuple[float, ...]

    def __post_init__(self) -> None:
        if not self.directions:
            raise ParameterError("a linear moving frame needs at least one direction (NOF >= 1)")
        if len(self.scales) != len(self.directions):
            raise ParameterError(f"scales (={self.scales!r}) must give one value per direction "
                                 f"({len(self.directions)})")
        dirs = tuple(v_unit(d, f"directions[{i}]") for i, d in enumerate(self.directions))
        object.__setattr__(self, "directions", dirs)
        for i, s in enumerate(self.scales):
            if not (math.isfinite(s) and s != 0.0):
                raise ParameterError(f"scales[{i}] (={s!r}) must be a finite non-zero number "
                                     "[mm per source unit]")
        object.__setattr__(self, "scales", tuple(float(s) for s in self.scales))

    @property
    def nof(self) -> int:
        return len(self.directions)

    # (properties, not class attributes: compiled, a dataclass's class attributes would be
    # fields, docs/architecture.md "Compiled core")
    @property
    def units(self) -> str:
        return "mm"

    @property
    def rotates(self) -> bool:
        return False

    #: the local axis of the (always zero) angle channel
    local_axis: Vec3 = (0.0, 0.0, 1.0)

    def coords(self, values: Sequence[float], trigger: Sequence[float]) -> tuple[float, ...]:
        """DOF coordinates [mm] of source ``values`` for an item triggered at ``trigger``."""
        return tuple([k * (m - t) for k, m, t in zip(self.scales, values, trigger)])

    def rates(self, rates: Sequence[float]) -> tuple[float, ...]:
        """Source rates (units/s or units/s^2) to DOF rates (mm/s, mm/s^2)."""
        return tuple([k * r for k, r in zip(self.scales, rates)])

    def zero(self, dr_mm: float = 0.0, item: object = None) -> Location:
        """MF.zero: the item at its trigger (``dr_mm`` is ignored on a linear frame)."""
        return self.origin

    def point(self, c: Sequence[float], cd: Sequence[float], cdd: Sequence[float],
              dr_mm: float = 0.0, item: object = None) -> FramePoint:
        if len(self.directions) == 1 and len(c) == 1:  # one DOF: the loop written out
            (d0, d1, d2), = self.directions
            x, = c
            xd, = cd
            xdd, = cdd
            o0, o1, o2 = self.origin.pos
            return FramePoint(Location.trusted((o0 + d0 * x, o1 + d1 * x, o2 + d2 * x),
                                               self.origin.ori),
                              (0.0 + d0 * xd, 0.0 + d1 * xd, 0.0 + d2 * xd),
                              (0.0 + d0 * xdd, 0.0 + d1 * xdd, 0.0 + d2 * xdd))
        p = list(self.origin.pos)
        v = [0.0, 0.0, 0.0]
        a = [0.0, 0.0, 0.0]
        for d, x, xd, xdd in zip(self.directions, c, cd, cdd):
            for j in range(3):
                p[j] += d[j] * x
                v[j] += d[j] * xd
                a[j] += d[j] * xdd
        return FramePoint(Location.trusted(vec3(p), self.origin.ori), vec3(v), vec3(a))
