"""Over-oscillation check of the approach (algorithm page 1.2.5.8, MOT_MASTER_OSC).

The page counts sign flips of the velocity error (``dv0*dv < 0``, read as a dot product),
ignores the first sample (``flops == -1``), and reports MOT_MASTER_OSC when
``flops > maxFlops && flopstime > maxFlopsTime && |dv| > syncGain*sync_accT2``.
Read literally it cannot fire: ``flopstime`` is reset on every flip, so a sustained
oscillation that flips more often than maxFlopsTime never trips it (notes item 10), and
``sync_accT2`` compares a velocity with a position threshold (A*T is meant).

Our reading: count the flips inside a sliding window of ``max_flops_time_s``; more than
``max_flops`` flips in the window while |dv| > g*A*T is an over-oscillation.  A converging
approach flips a few times near the end with a small |dv| and never trips it.
"""

from __future__ import annotations

from collections import deque

from .vec import Vec, dot, norm


class OscillationMonitor:
    """Counts velocity-error sign flips per sample; ``update()`` returns True on oscillation."""

    def __init__(self, max_flops: int, window_samples: int, dv_threshold: float) -> None:
        self.max_flops = int(max_flops)
        self.window = max(1, int(window_samples))
        self.dv_threshold = float(dv_threshold)
        self._flips: deque[int] = deque()
        self._dv0: Vec | None = None  # None: the first sample is ignored (page: flops = -1)

    def reset(self) -> None:
        self._flips.clear()
        self._dv0 = None

    @property
    def flops(self) -> int:
        """Flips currently inside the window."""
        return len(self._flips)

    def update(self, sample: int, dv: Vec) -> bool:
        dv0, self._dv0 = self._dv0, dv
        flips = self._flips
        while flips and flips[0] <= sample - self.window:
            flips.popleft()
        if dv0 is not None and dot(dv0, dv) < 0.0:
            flips.append(sample)
        return len(flips) > self.max_flops and norm(dv) > self.dv_threshold
