"""Clocks: one interface, a stepped (simulated) and a real-time implementation.

Time domains (named once, kept apart):

- *controller time* ``_ns``: integer nanoseconds since the clock was created; every deadline
  is computed on it (``t0 + k * period_ns``), never by sleeping a fixed period;
- *message time* (``timestamp`` of a python-can message, float seconds):
  ``epoch_s + now_ns / 1e9``.  The stepped clock's epoch is 0, so a stepped bus log starts at
  (0.000000); the real-time clock's epoch is the wall time when it was created.

Waiting is not the clock's job: a wait must process CAN frames meanwhile, so it lives in the
transports (:mod:`controller.canopen.io.transport`), which use :meth:`RealtimeClock.now_ns`
to spin on the last stretch before a deadline.
"""

from __future__ import annotations

import time
from typing import Protocol


class Clock(Protocol):
    #: message time of controller time 0 [s]
    epoch_s: float

    def now_ns(self) -> int:
        """Controller time [ns]."""
        ...

    def stamp(self) -> float:
        """The message time of now [s]."""
        ...


class SteppedClock:
    """Simulated time: stands still until :meth:`advance_to` moves it (deterministic)."""

    realtime = False

    def __init__(self, start_ns: int = 0) -> None:
        self._now = int(start_ns)
        self.epoch_s = 0.0

    def now_ns(self) -> int:
        return self._now

    def advance_to(self, t_ns: int) -> None:
        if t_ns < self._now:
            raise ValueError(f"stepped clock cannot go back from {self._now} to {t_ns} ns")
        self._now = int(t_ns)

    def stamp(self) -> float:
        return self._now * 1e-9


class RealtimeClock:
    """Monotonic wall-clock time (``time.perf_counter_ns``) since creation."""

    realtime = True

    def __init__(self) -> None:
        self._t0 = time.perf_counter_ns()
        self.epoch_s = time.time()

    def now_ns(self) -> int:
        return time.perf_counter_ns() - self._t0

    def stamp(self) -> float:
        return self.epoch_s + (time.perf_counter_ns() - self._t0) * 1e-9
