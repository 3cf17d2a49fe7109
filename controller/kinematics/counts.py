"""mm/deg <-> drive and encoder counts: the one place where counts exist.

Unit legend: ``_mm`` (or deg for a rotary axis) machine coordinates; ``counts`` integer
increments of a drive (607Ah/6064h) or an encoder (6004h).

Drive axis (:class:`AxisScale`)::

    counts = round(sign * (value - zero) * counts_per_unit)
    value  = zero + sign * counts / counts_per_unit

``zero`` is the machine coordinate at which the drive reads 0 counts.  Python's ``round``
(half to even) is deterministic, so the same setpoint always gives the same counts.

Conveyor encoder (:class:`EncoderScale`): 6004h wraps at ``modulus`` (6002h, CiA 406
total measuring range); :meth:`EncoderScale.belt_mm` unwraps against the previous count
(a step of more than modulus/2 is a wrap, :func:`controller.tracking.unwrap_counts`) and
scales: belt travel s = sign * (unwrapped - first) / counts_per_mm.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from ..errors import ParameterError
from ..tracking import unwrap_counts
from ..tracking.values import mypyc_attr, python_class

INT32_MIN, INT32_MAX = -0x80000000, 0x7FFFFFFF


def axis_unit(name: str) -> str:
    """The unit of an axis' positions: ``deg`` for the tool angle ``c``, else ``mm``."""
    return "deg" if name == "c" else "mm"


@python_class
@dataclass(frozen=True, slots=True)
class AxisScale:
    """One drive axis: ``counts_per_unit`` [counts/mm or counts/deg], ``zero`` [mm|deg],
    ``sign`` (+1 / -1), software limits ``min``/``max`` [mm|deg] of the machine coordinate."""

    name: str
    counts_per_unit: float
    zero: float = 0.0
    sign: int = 1
    min: float = -math.inf
    max: float = math.inf

    @property
    def unit(self) -> str:
        """``mm`` or ``deg`` (:func:`axis_unit`)."""
        return axis_unit(self.name)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.counts_per_unit) and self.counts_per_unit > 0):
            raise ParameterError(f"axis {self.name}: counts_per_unit "
                                 f"(={self.counts_per_unit!r}) must be > 0")
        if self.sign not in (1, -1):
            raise ParameterError(f"axis {self.name}: sign (={self.sign!r}) must be 1 or -1")
        if not self.min < self.max:
            raise ParameterError(f"axis {self.name}: min (={self.min}) must be < max "
                                 f"(={self.max})")

    def to_counts(self, value: float) -> int:
        c = round(self.sign * (value - self.zero) * self.counts_per_unit)
        if not INT32_MIN <= c <= INT32_MAX:
            raise ParameterError(f"axis {self.name}: {value} is {c} counts, outside INTEGER32")
        return c

    def from_counts(self, counts: int) -> float:
        return self.zero + self.sign * counts / self.counts_per_unit

    def velocity_counts(self, velocity: float) -> float:
        """A velocity [unit/s] in counts/s (not rounded)."""
        return self.sign * velocity * self.counts_per_unit

    def limit_counts(self) -> tuple[int, int]:
        """The software limits (607Dh sub1, sub2) in counts, clamped to INTEGER32."""
        ends = []
        for v in (self.min, self.max):
            c = self.sign * (v - self.zero) * self.counts_per_unit
            ends.append(int(max(INT32_MIN, min(INT32_MAX, round(c)))) if math.isfinite(c)
                        else (INT32_MAX if c > 0 else INT32_MIN))
        return min(ends), max(ends)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class CountsConverter:
    """All drive axes of a machine, in drive order."""

    def __init__(self, axes: Sequence[AxisScale]) -> None:
        self.axes = tuple(axes)
        #: per axis (sign, zero, counts_per_unit): AxisScale's conversions written out
        self._k = tuple((a.sign, a.zero, a.counts_per_unit) for a in self.axes)

    def to_counts(self, joints: Sequence[float]) -> tuple[int, ...]:
        try:
            out = [round(s * (v - z) * k) for (s, z, k), v in zip(self._k, joints)]
        except (ValueError, OverflowError):  # NaN/inf: as the axes report it, in order
            out = [INT32_MAX + 1]
        for c in out:
            if not INT32_MIN <= c <= INT32_MAX:  # (the axis names its own error)
                return tuple([a.to_counts(v) for a, v in zip(self.axes, joints)])
        return tuple(out)

    def from_counts(self, counts: Sequence[int]) -> tuple[float, ...]:
        return tuple([z + s * c / k for (s, z, k), c in zip(self._k, counts)])

    @property
    def factors(self) -> tuple[tuple[int, float, float], ...]:
        """Per axis (sign, zero [unit], counts per unit): ``from_counts`` is
        ``zero + sign * counts / counts_per_unit``, ``to_counts`` its rounded inverse."""
        return self._k

    def outside_limits(self, joints: Sequence[float]) -> list[tuple[str, float]]:
        return [(a.name, v) for a, v in zip(self.axes, joints) if not a.min <= v <= a.max]


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class EncoderScale:
    """The conveyor encoder: wrapped counts in, continuous belt travel [mm] out."""

    def __init__(self, counts_per_mm: float, modulus: int, sign: int = 1) -> None:
        if not (math.isfinite(counts_per_mm) and counts_per_mm > 0):
            raise ParameterError(f"counts_per_mm (={counts_per_mm!r}) must be > 0")
        if modulus < 0:
            raise ParameterError(f"modulus (={modulus}) must be >= 0 (0 = no wrap)")
        self.counts_per_mm = float(counts_per_mm)
        self.modulus = int(modulus)
        self.sign = 1 if sign >= 0 else -1
        self._first: int | None = None
        self._last: int | None = None

    def reset(self) -> None:
        self._first = self._last = None

    def unwrap(self, raw: int) -> int:
        """The continuous count of a raw 6004h value (first value = itself)."""
        if self._last is None:
            self._first = self._last = int(raw)
        else:
            self._last = unwrap_counts(self._last, int(raw), self.modulus)
        return self._last

    def belt_mm(self, raw: int) -> float:
        """Belt travel [mm] since the first sample."""
        u = self.unwrap(raw)
        assert self._first is not None  # set by the first unwrap()
        return self.sign * (u - self._first) / self.counts_per_mm
