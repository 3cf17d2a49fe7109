"""All simulated devices of a bus on one python-can bus (one participant of the bus).

The devices (slave-node engines) share one :class:`~controller.canopen.io.transport.Port` (no
Notifier thread): the rack hands every received frame to it, so the same rack runs in a
stepped world (:class:`~controller.canopen.io.transport.SteppedWorld` drains it) or in real time
(:class:`~controller.canopen.io.transport.DeviceThread`).  Frames are stamped with the rack's
clock (message time).  The devices do not hear each other's frames (one bus object), which
none of them needs.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable
from typing import TYPE_CHECKING

import can

from ..config.simulation import DriveParams, EncoderParams
from ..io.clock import Clock
from ..io.transport import Port
from ..protocol import od as odm
from .drive import SimDrive
from .encoder import SimEncoder
from .node import SimNode

if TYPE_CHECKING:
    from ..config import ControllerConfig


class DeviceRack:
    """Endpoint holding the simulated devices (``handle``/``next_timer_ns``/``on_timer``)."""

    def __init__(self, bus: can.BusABC, clock: Clock, frame_time: bool = False) -> None:
        self.bus = bus
        self.clock = clock
        # frames stamped with the clock, dispatched by COB-ID; ``frame_time``: the devices
        # get each frame's bus time (a SYNC served late is still sampled at its time)
        self.port = Port(bus, clock, frame_time)
        self.devices: dict[str, SimNode] = {}
        self._ahead: deque[can.Message] = deque()  # frames read ahead (frame_time)
        #: the devices' SYNC COB-IDs (fixed when a device is added)
        self._sync_cobs: set[int] = set()
        #: the earliest device timer, cached as the devices' own (SlaveEngine.next_timer_ns):
        #: (the _due_gen it was computed at, the time); a device whose timers may have
        #: changed calls retime()
        self._due_gen = 0
        self._due: tuple[int, int | None] = (-1, None)
        self._cache_timers = True

    def add(self, device: SimNode) -> SimNode:
        self.devices[device.name] = device
        if device.sync_cob_id is not None:
            self._sync_cobs.add(device.sync_cob_id)
        device.timer_host = self
        self._cache_timers = all(d.cache_timers for d in self.devices.values())
        self.retime()
        return device

    def retime(self) -> None:
        """A device's timers may have changed (see :meth:`next_timer_ns`)."""
        self._due_gen += 1

    def __getitem__(self, name: str) -> SimNode:
        return self.devices[name]

    def handle(self, msg: can.Message) -> None:
        if not self.port.frame_time:
            self.port.handle(msg)
            return
        # served late (a device thread): before a SYNC, the frames already received after
        # it; a later SYNC among them means this SYNC's answers would follow that SYNC on
        # the bus, where a real device never puts them (it answers within microseconds):
        # the devices leave them out (SlaveEngine.next_sync_ns) rather than have them
        # taken for the later SYNC's
        ahead = self._ahead
        ahead.append(msg)
        recv = self.bus.recv
        port = self.port
        while ahead:
            m = ahead.popleft()
            cob = m.arbitration_id
            if cob in self._sync_cobs:
                while (n := recv(0)) is not None:
                    ahead.append(n)
                later = next((x for x in ahead if x.arbitration_id == cob), None)
                t_next = None if later is None else \
                    round((later.timestamp - self.clock.epoch_s) * 1e9)
                for d in self.devices.values():
                    d.next_sync_ns = t_next
                port.handle(m)
                for d in self.devices.values():
                    d.next_sync_ns = None
            else:
                port.handle(m)

    def next_timer_ns(self) -> int | None:
        c = self._due
        gen = self._due_gen
        if c[0] == gen:
            return c[1]
        due = [t for d in self.devices.values() if (t := d.next_timer_ns()) is not None]
        best = min(due) if due else None
        if self._cache_timers:
            self._due = (gen, best)
        return best

    def on_timer(self, now_ns: int) -> None:
        for d in self.devices.values():
            t = d.next_timer_ns()
            if t is not None and t <= now_ns:
                d.on_timer(now_ns)

    @classmethod
    def from_config(cls, cfg: ControllerConfig, bus: can.BusABC, clock: Clock,
                    present: Iterable[str] | None = None,
                    frame_time: bool = False) -> DeviceRack:
        """One simulated device per slave of ``cfg`` (by the EDS's device profile).

        ``present``: the slave names to simulate (default all); parameters from the
        ``.simulation`` section (defaults otherwise); ``frame_time``: see :class:`Port`.
        """
        rack = cls(bus, clock, frame_time)
        sim = cfg.simulation
        names = list(cfg.slaves) if present is None else list(present)
        boot_delay = int((sim.boot_delay_s if sim is not None else 0.005) * 1e9)
        for name in names:
            slave = cfg.slaves[name]
            prof = odm.profile(cfg.ods[name])
            params = sim.devices.get(name) if sim is not None else None
            if prof == odm.PROFILE_DRIVE:
                rack.add(SimDrive(name, str(slave.dcf), slave.node_id, rack.port,
                                  params if isinstance(params, DriveParams) else None,
                                  boot_delay_ns=boot_delay))
            elif prof == odm.PROFILE_ENCODER:
                if not isinstance(params, EncoderParams):
                    params = _default_encoder(cfg)
                rack.add(SimEncoder(name, str(slave.dcf), slave.node_id, rack.port,
                                    params, boot_delay_ns=boot_delay))
            else:
                rack.add(SimNode(name, str(slave.dcf), slave.node_id, rack.port,
                                 boot_delay_ns=boot_delay))
        return rack


def _default_encoder(cfg: ControllerConfig) -> EncoderParams:
    t = cfg.tracking
    if t is not None:
        return EncoderParams(counts_per_mm=t.conveyor.counts_per_mm, sign=t.conveyor.sign)
    return EncoderParams()
