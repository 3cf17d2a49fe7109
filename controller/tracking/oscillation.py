"""Over-oscillation check of the approach (MOT_MASTER_OSC; docs/spec/tracking.md#4).

softMC counts sign flips of the velocity error (``dv0*dv < 0``, read as a dot product),
ignores the first sample (``flops == -1``), and reports MOT_MASTER_OSC when
``flops > maxFlops && flopstime > maxFlopsTime && |dv| > syncGain*sync_accT2``.
Read literally it cannot fire: ``flopstime`` is reset on every flip, so a sustained
oscillation that flips more often than maxFlopsTime never trips it
(docs/spec/tracking.md#4.1); and at a flip dv passes through zero, so ``|dv| > threshold``
at that moment rarely holds (``sync_accT2`` compares a velocity with a position threshold:
A*T is meant).

Our reading: a flip counts when the velocity error's peak magnitude since the previous flip
exceeded twice g*A*T (a half-swing of real amplitude, not the small decaying wobble of an
approach about to synchronise, whose |dv| is near the sync threshold g*A*T).  More than ``max_flops`` counted flips inside the last ``window_samples`` samples
(``max_flops_time_s``) is an over-oscillation.  A converging approach makes at most a few
large half-swings; a sustained oscillation keeps making them, whatever its period — slow
limit cycles of 0.5-1 s periods included (they go unnoticed by a short window or by the
published test).  The approach timeout is the backstop for anything slower.
"""

from __future__ import annotations

from collections import deque

from .values import mypyc_attr
from .vec import Vec, dot, norm


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: snapshots, FMU states)
class OscillationMonitor:
    """Counts large velocity-error sign flips; ``update()`` returns True on over-oscillation."""

    def __init__(self, max_flops: int, window_samples: int, dv_threshold: float) -> None:
        self.max_flops = int(max_flops)
        self.window = max(1, int(window_samples))
        self.dv_threshold = float(dv_threshold)
        self._flips: deque[int] = deque()
        self._dv0: Vec | None = None  # None: the first sample is ignored (softMC: flops = -1)
        self._peak = 0.0  # largest |dv| since the last flip

    def reset(self) -> None:
        self._flips.clear()
        self._dv0 = None
        self._peak = 0.0

    @property
    def flops(self) -> int:
        """Counted flips currently inside the window."""
        return len(self._flips)

    def update(self, sample: int, dv: Vec) -> bool:
        """Feed the velocity error of ``sample``; True when the approach over-oscillates."""
        dv0, self._dv0 = self._dv0, dv
        flips = self._flips
        while flips and flips[0] <= sample - self.window:
            flips.popleft()
        n = norm(dv)
        if dv0 is not None and dot(dv0, dv) < 0.0:
            if self._peak > 2.0 * self.dv_threshold:
                flips.append(sample)
            self._peak = n
        elif n > self._peak:
            self._peak = n
        return len(flips) > self.max_flops
