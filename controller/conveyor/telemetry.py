"""Per-item telemetry: time to sync, peak tracking error, oscillation count, caught/missed.

Not part of the softMC model (docs/spec/conveyor.md#1; issue 3).  One :class:`ItemRecord`
per trigger entry a robot worked on, filled by the robot's frame link each sample (pure
bookkeeping, no clock: sample indices; times = sample * T).

- ``entered_sample``: the first sample the robot's link saw the item inside the window (later
  than the item's real entry when the robot was not engaged to the frame then);
  ``engaged_sample``: the tracker's engage for this item.
- ``time_to_sync_s``: from the tracker's engage (the item inside the window with the robot
  engaged) to the tracker's switch into SYNCED.
- ``peak_error_approach_mm``: the largest |target - setpoint| of the frame's contribution
  while approaching (SYNCING); ``peak_error_synced_mm`` the same while SYNCED (0 for the
  core's exact copy of the master; non-zero only with an estimator or numerical effects).
- ``oscillations``: sign flips of the velocity error (dot product of consecutive errors,
  softMC's ``dv0*dv < 0``, docs/spec/tracking.md#4.1) during the approach, the first sample ignored.
- ``status``: PENDING (not reached yet), TRACKING, CAUGHT (synchronised), MISSED (left the
  window before it was caught: error 30238), SKIPPED (NEXTITEM / slave = 0 / a hand-off
  before it was caught), LOST (an error other than "item missed" ended the approach),
  IGNORED (a type the robot does not track on that frame: never engaged, never "missed").
- ``item_type``: the trigger's item type.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from ..tracking.values import python_class
from enum import Enum


class ItemStatus(str, Enum):
    PENDING = "pending"
    TRACKING = "tracking"
    CAUGHT = "caught"
    MISSED = "missed"
    SKIPPED = "skipped"
    LOST = "lost"
    IGNORED = "ignored"


@python_class
@dataclass
class ItemRecord:
    """Telemetry of one item (see the module docstring).  Samples are the robot's."""

    item_id: int
    frame: str
    robot: str
    sample_time_s: float
    trigger_sample: int
    entered_sample: int | None = None
    engaged_sample: int | None = None
    synced_sample: int | None = None
    left_sample: int | None = None
    missed_sample: int | None = None
    status: ItemStatus = ItemStatus.PENDING
    peak_error_approach_mm: float = 0.0
    peak_error_synced_mm: float = 0.0
    peak_error_approach_deg: float = 0.0
    oscillations: int = 0
    error: str = ""
    item_type: int = 0
    _dv_prev: tuple | None = field(default=None, repr=False)

    @property
    def caught(self) -> bool:
        return self.synced_sample is not None

    @property
    def missed(self) -> bool:
        return self.status == ItemStatus.MISSED

    @property
    def time_to_sync_s(self) -> float | None:
        if self.synced_sample is None or self.engaged_sample is None:
            return None
        return (self.synced_sample - self.engaged_sample) * self.sample_time_s

    def _t(self, k: int | None) -> float | None:
        return None if k is None else k * self.sample_time_s

    @property
    def trigger_s(self) -> float | None:
        return self._t(self.trigger_sample)

    @property
    def entered_s(self) -> float | None:
        return self._t(self.entered_sample)

    @property
    def engaged_s(self) -> float | None:
        return self._t(self.engaged_sample)

    @property
    def synced_s(self) -> float | None:
        return self._t(self.synced_sample)

    @property
    def left_s(self) -> float | None:
        return self._t(self.left_sample)

    def observe(self, synced: bool, err_pos: tuple, err_ang: float, dv: tuple) -> None:
        """One sample of the approach (``synced`` False) or of following (True)."""
        e = math.sqrt(sum(x * x for x in err_pos))
        if synced:
            self.peak_error_synced_mm = max(self.peak_error_synced_mm, e)
            return
        self.peak_error_approach_mm = max(self.peak_error_approach_mm, e)
        self.peak_error_approach_deg = max(self.peak_error_approach_deg, abs(err_ang))
        if self._dv_prev is not None and sum(a * b for a, b in zip(self._dv_prev, dv)) < 0.0:
            self.oscillations += 1
        self._dv_prev = dv

    def as_dict(self) -> dict:
        return {"item": self.item_id, "frame": self.frame, "robot": self.robot,
                "status": self.status.value, "trigger_s": self.trigger_s,
                "entered_s": self.entered_s, "engaged_s": self.engaged_s,
                "synced_s": self.synced_s, "left_s": self.left_s,
                "time_to_sync_s": self.time_to_sync_s,
                "peak_error_approach_mm": self.peak_error_approach_mm,
                "peak_error_synced_mm": self.peak_error_synced_mm,
                "oscillations": self.oscillations, "error": self.error,
                "item_type": self.item_type}
