"""A simulated CiA 406 conveyor encoder (cantrack-encoder.eds).

The belt moves with a piecewise-linear speed profile v(t) [mm/s] through the points
(t_i, v_i) (held before the first and after the last point); its travel s(t) [mm] is the
exact integral (trapezoids), evaluated at each SYNC, so there is no integration drift.

    6004h = (initial_counts + floor(sign * s * counts_per_mm) + noise) mod 6002h
    6030h sub1 = v * counts_per_mm, rounded and saturated to INTEGER16

6002h (total measuring range) and 6003h (preset: sets the current position) are honoured
when written over SDO.  The TPDOs go out on SYNC as configured (base class).

Fault injection (besides the base class's): ``silence(True)`` (no frames at all),
``mute_pdos(True)`` (heartbeat goes on, PDOs stop: "encoder silent"), ``noise_counts``
(seeded Gaussian noise, standard deviation in counts, added to each sample),
``counts_hook`` (a function of the belt's count: glitches).  ``sync_hook`` replaces the belt
model (a recorded stream played back).  (Hooks, not methods patched on the instance: the
class is compiled, docs/architecture.md "Compiled core".)
"""

from __future__ import annotations

import bisect
import math
import random
from collections.abc import Callable
from typing import Any

from ...tracking.values import mypyc_attr
from ..config.simulation import EncoderParams
from ..protocol.sdo import ABORT_VALUE_RANGE, SdoAbortError
from .node import SimNode

_UNREAD = object()  #: no raw value read yet (the cache of 6002h)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: the demo's PhotoEye holds one)
class SpeedProfile:
    """Piecewise-linear speed through points; exact travel s(t) [mm]."""

    def __init__(self, points: tuple[tuple[float, float], ...]) -> None:
        if not points:
            points = ((0.0, 0.0),)
        self.t = [float(p[0]) for p in points]
        self.v = [float(p[1]) for p in points]
        self.s = [0.0]
        for i in range(1, len(self.t)):
            self.s.append(self.s[-1] + 0.5 * (self.v[i] + self.v[i - 1]) * (self.t[i] - self.t[i - 1]))
        # travel before the first point at constant v[0]
        self._s0 = -self.v[0] * self.t[0]
        #: the travel at t = 0 from the first point (what travel() subtracts)
        self._at0 = self._travel(0.0)

    def speed(self, t: float) -> float:
        i = bisect.bisect_right(self.t, t)
        if i == 0:
            return self.v[0]
        if i >= len(self.t):
            return self.v[-1]
        t0, t1 = self.t[i - 1], self.t[i]
        return self.v[i - 1] + (self.v[i] - self.v[i - 1]) * (t - t0) / (t1 - t0)

    def travel(self, t: float) -> float:
        """Travel since t = 0 [mm]."""
        return self._travel(t) - self._at0

    def _travel(self, t: float) -> float:
        i = bisect.bisect_right(self.t, t)
        if i == 0:
            return self.v[0] * (t - self.t[0])
        if i >= len(self.t):
            return self.s[-1] + self.v[-1] * (t - self.t[-1])
        t0 = self.t[i - 1]
        vt = self.speed(t)
        return self.s[i - 1] + 0.5 * (self.v[i - 1] + vt) * (t - t0)


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable; subclassed in Python)
class SimEncoder(SimNode):
    kind = "encoder"

    def __init__(self, name: str, eds: str, node_id: int, bus: Any,
                 params: EncoderParams | None = None, boot_delay_ns: int = 5_000_000) -> None:
        # (the keyword written out: mypyc 2.4 passed a ``**kw`` on as the first optional
        #  positional argument, boot_delay_ns = the dict)
        super().__init__(name, eds, node_id, bus, boot_delay_ns=boot_delay_ns)
        clock = self.clock
        self.params = params or EncoderParams()
        self.profile = SpeedProfile(self.params.profile)
        self.noise_counts = self.params.noise_counts
        self._rng = random.Random(self.params.seed)
        self._offset = 0  # from a preset (6003h)
        #: 6002h as last decoded: (the stored bytes object, its value)
        self._modulus_raw: object = _UNREAD
        self._modulus = 0
        self._sample_plan = self.store_plan(((0x6004, 0), (0x6030, 1)))
        #: fault injection: ``counts_hook(t_ns, counts)`` gives the count sampled at ``t_ns``
        #: instead of the belt's ``counts`` (:meth:`true_counts`), e.g. a glitch
        self.counts_hook: Callable[[int, int], int] | None = None
        #: at each SYNC instead of the belt model when set: ``sync_hook(now_ns)`` sets the
        #: objects (a recording played back: :class:`controller.canopen.apps.record.StreamPlayer`)
        self.sync_hook: Callable[[int], None] | None = None
        self.sample(clock.now_ns())

    def true_counts(self, t_ns: int) -> int:
        """The unwrapped count of the belt at ``t_ns`` (without noise)."""
        p = self.params
        s = self.profile.travel(t_ns * 1e-9)
        return p.initial_counts + self._offset + math.floor(p.sign * s * p.counts_per_mm)

    def sample(self, t_ns: int) -> int:
        """6004h and 6030h:1 at ``t_ns`` (6004h from :meth:`true_counts`)."""
        p = self.params
        counts = self.true_counts(t_ns)
        hook = self.counts_hook
        if hook is not None:
            counts = hook(t_ns, counts)
        if self.noise_counts:
            counts += round(self._rng.gauss(0.0, self.noise_counts))
        d = self.node.data_store.get(0x6002)
        stored = d.get(0) if d is not None else None
        if stored is not self._modulus_raw:  # (decoded when the stored bytes change)
            self._modulus = int(self.load(0x6002, 0))
            self._modulus_raw = stored
        modulus = self._modulus
        raw = counts % modulus if modulus > 0 else counts & 0xFFFFFFFF
        speed = round(self.profile.speed(t_ns * 1e-9) * p.counts_per_mm * p.sign)
        self.store_all(self._sample_plan, (raw, max(-0x8000, min(0x7FFF, speed))))
        return raw

    def on_sync(self, now_ns: int) -> None:
        hook = self.sync_hook
        if hook is not None:
            hook(now_ns)
        else:
            self.sample(now_ns)

    def on_write(self, index: int, sub: int, value: Any) -> None:
        if index == 0x6003:
            modulus = int(self.load(0x6002, 0))
            if modulus and not 0 <= value < modulus:
                raise SdoAbortError(ABORT_VALUE_RANGE)
            self._offset += value - self.true_counts(self.clock.now_ns())
