"""Position quantisation to drive counts: the one place where mm become counts.

Units: mm on the controller side, counts (INTEGER32, CiA 402 objects 607Ah target position,
6064h actual position) on the drive side.

Spec: docs/spec/axis.md#6.  The thesis' Sled_Y CONST/DECCEL: "each time the integrated
position reaches the next whole step, one step of the output link is made".  The thesis
drove a stepper; we send a position in counts every sample instead, so its "one step at each
whole increment" becomes rounding the integrated position to the nearest count at the drive
boundary (error <= 1/2 count, no drift: the position is integrated in mm, never in counts).

Jump bound: with ``c = round(x*cpm)`` and |x_k - x_{k-1}| <= V*T, one sample's count change
is at most ``ceil(cpm*V*T)`` (:meth:`CountQuantizer.max_step_counts`): rounding two numbers
whose difference is d changes them by at most ceil(d).  Over any window of n samples the
change is at most ``ceil(n*cpm*V*T)``, so the counts never run ahead of the velocity limit by
more than one count.  A smaller bound (floor) is impossible at full speed without lagging.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import ParameterError
from .checks import is_integer, require_finite, require_positive

INT32_MIN = -(2 ** 31)
INT32_MAX = 2 ** 31 - 1


@dataclass(frozen=True, slots=True)
class CountQuantizer:
    """Maps an axis position [mm] to drive counts and back.

    ``counts = offset_counts + round_half_up(sign * counts_per_mm * position_mm)``

    Attributes:
        counts_per_mm: drive counts per mm of axis travel (> 0).
        sign: +1 if drive counts grow with the axis coordinate, -1 if they shrink.
        offset_counts: the count value at 0 mm (INTEGER32).

    Raises:
        ParameterError: an attribute is out of range (message names it and the range).
    """

    counts_per_mm: float
    sign: int = 1
    offset_counts: int = 0

    def __post_init__(self) -> None:
        require_positive("CountQuantizer", "counts_per_mm", self.counts_per_mm, "counts/mm")
        if self.sign not in (1, -1) or isinstance(self.sign, bool):
            raise ParameterError(f"CountQuantizer.sign (={self.sign!r}) must be +1 or -1")
        if not is_integer(self.offset_counts) or not INT32_MIN <= self.offset_counts <= INT32_MAX:
            raise ParameterError(
                f"CountQuantizer.offset_counts (={self.offset_counts!r}) must be an integer "
                f"in [{INT32_MIN}, {INT32_MAX}] (INTEGER32)")

    def to_counts(self, position_mm: float) -> int:
        """Counts for ``position_mm`` [mm] (nearest count, halves rounded up).

        Raises:
            ParameterError: not finite, or the count is outside INTEGER32 (object 607Ah).
        """
        require_finite("CountQuantizer", "position_mm", position_mm, "mm")
        counts = int(self.offset_counts) + math.floor(
            self.sign * self.counts_per_mm * position_mm + 0.5)
        if not INT32_MIN <= counts <= INT32_MAX:
            lo, hi = self.range_mm()
            raise ParameterError(
                f"position {position_mm!r} mm -> {counts} counts is outside INTEGER32 "
                f"[{INT32_MIN}, {INT32_MAX}] (object 607Ah); representable range "
                f"[{lo:.6g}, {hi:.6g}] mm")
        return counts

    def to_mm(self, counts: int) -> float:
        """Position [mm] of ``counts`` (exact inverse of :meth:`to_counts` on whole counts)."""
        return (counts - self.offset_counts) / (self.sign * self.counts_per_mm)

    def velocity_to_counts_s(self, velocity_mm_s: float) -> float:
        """Velocity [mm/s] in counts/s (signed, not rounded)."""
        return self.sign * self.counts_per_mm * velocity_mm_s

    def max_step_counts(self, max_vel_mm_s: float, sample_period_s: float) -> int:
        """Largest count change in one sample for a position stream within ``max_vel_mm_s``
        [mm/s] sampled every ``sample_period_s`` [s]: ``ceil(counts_per_mm * V * T)``."""
        require_positive("CountQuantizer", "max_vel_mm_s", max_vel_mm_s, "mm/s")
        require_positive("CountQuantizer", "sample_period_s", sample_period_s, "s")
        return math.ceil(self.counts_per_mm * max_vel_mm_s * sample_period_s)

    def range_mm(self) -> tuple[float, float]:
        """The axis range [mm] whose counts fit INTEGER32 (low, high)."""
        a = self.to_mm(INT32_MIN)
        b = self.to_mm(INT32_MAX)
        return (min(a, b), max(a, b))

    def quantize_stream(self, positions_mm: list[float]) -> list[int]:
        """Counts for each sample of a position stream [mm]."""
        return [self.to_counts(p) for p in positions_mm]
