"""The working window of a moving frame (docs/spec/conveyor.md#4).

Per DOF a pair of limits relative to the trigger point, in frame units (mm for a linear DOF,
deg for the rotary angle): ``upstream`` (the lower limit, the one closer to the trigger point)
and ``downstream`` (the upper limit).  An item's DOF coordinate c_i is its displacement since
its trigger (``controller.conveyor.frames``).

- BEFORE: some c_i < upstream_i (the item has not reached the window yet);
- INSIDE: upstream_i <= c_i <= downstream_i for every DOF;
- AFTER:  some c_i > downstream_i (the item left the window downstream).

AFTER wins over BEFORE when DOFs disagree.  Tracking starts when the item is INSIDE and ends
when it is AFTER; while it is inside, every change of the conveyor's direction is tracked (an
item that goes back upstream out of the window is BEFORE again, tracking goes on).

Direction flag (``inverse``, given with the trigger): "An object might enter from the
downstream limit": the limits are mirrored, c_i is compared as -c_i.

softMC also says "Moving direction is from upper to lower", which contradicts "the lower
limit is closer to the trigger point" (an item moves away from its trigger, from the lower to
the upper limit).  We follow the limits' definition: items move from upstream to downstream.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Sequence

from ..errors import ParameterError
from ..tracking.values import python_class


class WindowPosition(IntEnum):
    BEFORE = -1
    INSIDE = 0
    AFTER = 1


@python_class
@dataclass(frozen=True, slots=True)
class Window:
    """Upstream/downstream limits per DOF [frame units], relative to the trigger point."""

    upstream: tuple[float, ...]
    downstream: tuple[float, ...]

    def __post_init__(self) -> None:
        up = tuple(float(x) for x in self.upstream)
        down = tuple(float(x) for x in self.downstream)
        if not up or len(up) != len(down):
            raise ParameterError(f"window: upstream (={up!r}) and downstream (={down!r}) must "
                                 "give one limit per DOF each")
        for i, (u, d) in enumerate(zip(up, down)):
            if not (math.isfinite(u) and math.isfinite(d) and u < d):
                raise ParameterError(f"window DOF {i}: upstream (={u!r}) must be below "
                                     f"downstream (={d!r}), both finite")
        object.__setattr__(self, "upstream", up)
        object.__setattr__(self, "downstream", down)

    @classmethod
    def single(cls, upstream: float, downstream: float) -> "Window":
        return cls((upstream,), (downstream,))

    @classmethod
    def unlimited(cls, nof: int = 1) -> "Window":
        """A window that every item is inside (tracking from the trigger on, never missed)."""
        return cls((-1e300,) * nof, (1e300,) * nof)

    @property
    def nof(self) -> int:
        return len(self.upstream)

    def classify(self, coords: Sequence[float], inverse: bool = False) -> WindowPosition:
        sign = -1.0 if inverse else 1.0
        before = False
        for c, u, d in zip(coords, self.upstream, self.downstream):
            c = sign * c
            if c > d:
                return WindowPosition.AFTER
            if c < u:
                before = True
        return WindowPosition.BEFORE if before else WindowPosition.INSIDE

    def time_to_leave(self, coords: Sequence[float], rates: Sequence[float],
                      inverse: bool = False) -> float:
        """Seconds until the item passes a downstream limit at constant ``rates`` (inf: never)."""
        sign = -1.0 if inverse else 1.0
        best = math.inf
        for c, r, d in zip(coords, rates, self.downstream):
            c, r = sign * c, sign * r
            if c > d:
                return 0.0
            if r > 0.0:
                best = min(best, (d - c) / r)
        return best

    def time_to_enter(self, coords: Sequence[float], rates: Sequence[float],
                      inverse: bool = False) -> float:
        """Seconds until every DOF is past its upstream limit at constant rates (inf: never)."""
        sign = -1.0 if inverse else 1.0
        worst = 0.0
        for c, r, u in zip(coords, rates, self.upstream):
            c, r = sign * c, sign * r
            if c >= u:
                continue
            if r <= 0.0:
                return math.inf
            worst = max(worst, (u - c) / r)
        return worst
