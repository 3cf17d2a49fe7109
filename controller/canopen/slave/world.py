"""A simulated bus: the devices of a bus.yml and the controller's transport, wired up.

Stepped (default): one :class:`~controller.canopen.io.transport.SteppedWorld` on a fresh
python-can ``virtual`` channel; the device rack and the optional bus logger are its
participants and the controller gets a :class:`SteppedTransport`.  Real time: the rack runs
in a :class:`DeviceThread`, the logger behind a python-can ``Notifier``, the controller
gets a :class:`RealtimeTransport`; all on one virtual channel in this process.
"""

from __future__ import annotations

import copy
import itertools
import os
from collections.abc import Iterable
from pathlib import Path
from typing import TYPE_CHECKING

import can

from ..io.clock import RealtimeClock, SteppedClock
from ..io.transport import (
    DeviceThread,
    RealtimeTransport,
    SteppedTransport,
    SteppedWorld,
    virtual_bus,
)
from .rack import DeviceRack

if TYPE_CHECKING:
    from ..config import ControllerConfig

_channels = itertools.count()


#: the channel name written into the bus log of a simulated bus.  Not the virtual
#: channel's own name (``cantrack-sim-<pid>-<n>``: more than the 15 characters of a Linux
#: interface name, which can-utils' ``canplayer`` refuses), and a *virtual* interface's
#: name, so that a ``canplayer -I bus.log`` without an interface assignment replays a
#: simulation onto vcan0, never onto a real bus by accident (``can0=vcan0`` to mean it).
LOG_CHANNEL = "vcan0"


class _Renamed(can.Listener):
    """Passes each message on with ``channel`` = :data:`LOG_CHANNEL`."""

    def __init__(self, writer: can.Listener) -> None:
        self.writer = writer

    def on_message_received(self, msg: can.Message) -> None:
        # a copy: python-can's virtual bus hands the same message object to every receiver
        renamed = copy.copy(msg)
        renamed.channel = LOG_CHANNEL
        self.writer.on_message_received(renamed)

    def stop(self) -> None:
        self.writer.stop()


class _LogEndpoint:
    """The bus logger as a stepped-world participant."""

    def __init__(self, bus: can.BusABC, writer: can.Listener) -> None:
        self.bus = bus
        self.writer = _Renamed(writer)

    def handle(self, msg: can.Message) -> None:
        self.writer.on_message_received(msg)

    def next_timer_ns(self) -> int | None:
        return None

    def on_timer(self, now_ns: int) -> None:
        pass


class FrameRecorder:
    """Every frame on the bus as (t_ns, can_id, data), for tests (stepped worlds)."""

    def __init__(self, bus: can.BusABC) -> None:
        self.bus = bus
        self.frames: list[tuple[int, int, bytes]] = []

    def handle(self, msg: can.Message) -> None:
        self.frames.append((round((msg.timestamp * 1e9)), msg.arbitration_id,
                            bytes(msg.data)))

    def next_timer_ns(self) -> int | None:
        return None

    def on_timer(self, now_ns: int) -> None:
        pass


class SimWorld:
    """Simulated devices + the controller's transport (+ a candump-format bus log)."""

    def __init__(self, cfg: ControllerConfig, *, realtime: bool = False,
                 present: Iterable[str] | None = None,
                 bus_log: str | Path | can.Listener | None = None,
                 channel: str | None = None, record: bool = False,
                 spin_ns: int | None = None, inline: bool = False) -> None:
        """``realtime``: wall-clock time, the devices in a :class:`DeviceThread`; with
        ``inline`` too: the devices served in the controller's thread, paced in real time
        (a :class:`SteppedWorld` on a :class:`RealtimeClock`).  ``bus_log``: a file name
        (``can.Logger`` by its extension) or a listener (e.g. a rotating
        :class:`~.io.rotating.BusLog`), stopped by :meth:`close`."""
        self.cfg = cfg
        self.realtime = realtime
        self.channel = channel or f"cantrack-sim-{os.getpid()}-{next(_channels)}"
        self._logger: can.Listener | None = None
        self._notifier: can.Notifier | None = None
        self._thread: DeviceThread | None = None
        if realtime and not inline:
            self.clock = RealtimeClock()
            self.world = None
            # frame_time: the device thread serves a SYNC when the interpreter lets it,
            # up to milliseconds late on a busy machine; the devices sample at the SYNC's
            # bus time and keep to the synchronous window (1007h) from it
            self.rack = DeviceRack.from_config(cfg, virtual_bus(self.channel), self.clock,
                                               present, frame_time=True)
            if bus_log is not None:
                self._logger = bus_log if isinstance(bus_log, can.Listener) \
                    else can.Logger(str(bus_log))
                self._log_bus = virtual_bus(self.channel)
                self._notifier = can.Notifier(self._log_bus, [_Renamed(self._logger)],
                                              timeout=0.05)
            self.transport = RealtimeTransport(virtual_bus(self.channel), self.clock,
                                               **({} if spin_ns is None else
                                                  {"spin_ns": spin_ns}))
            self._thread = DeviceThread(self.rack, self.clock).start()
        else:
            self.clock = RealtimeClock() if realtime else SteppedClock()
            self.world = SteppedWorld(self.channel, self.clock,
                                      **({} if spin_ns is None else {"spin_ns": spin_ns}))
            self.rack = self.world.add(DeviceRack.from_config(cfg, self.world.new_bus(),
                                                              self.clock, present))
            if bus_log is not None:
                self._logger = bus_log if isinstance(bus_log, can.Listener) \
                    else can.Logger(str(bus_log))
                self.world.add(_LogEndpoint(self.world.new_bus(), self._logger))
            self.recorder = self.world.add(FrameRecorder(self.world.new_bus())) \
                if record else None
            self.transport = SteppedTransport(self.world)

    def device(self, name: str):
        return self.rack.devices[name]

    def at(self, t_s: float, action) -> None:
        """Schedule ``action`` at simulated time ``t_s`` (stepped worlds only)."""
        if self.world is None:
            raise RuntimeError("scheduled actions need a stepped world")
        self.world.at(int(t_s * 1e9), action)

    def close(self) -> None:
        if self._thread is not None:
            self._thread.stop()
            self._thread = None
        if self._notifier is not None:
            self._notifier.stop()
            self._log_bus.shutdown()
            self._notifier = None
        if self.world is not None:
            self.world.close()
        else:
            self.rack.bus.shutdown()
            self.transport.close()
        if self._logger is not None:
            self._logger.stop()
            self._logger = None

    def __enter__(self) -> SimWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
