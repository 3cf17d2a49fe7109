"""python-can's ``virtual`` interface, made cheap enough for a 1 ms cycle in Python.

Profiled (cProfile, stepped demo, 4 drives + encoder + bus log): 40 % of the run was
``VirtualBus.send``: it ``copy.deepcopy``\\ s the message for every receiver (~25 us each,
through ``Message.__deepcopy__`` and ``bytearray.__reduce_ex__``), and its
``queue.Queue`` takes a lock and a condition per put and get.  :class:`FastVirtualBus`
changes only those two things and stays a ``VirtualBus`` on the same channels (a plain
``can.Bus(interface="virtual")`` on the channel still sees every frame and vice versa):

- a receiver gets its own :class:`can.Message` built field by field (a new ``bytearray``
  of the data; no deepcopy machinery);
- its receive queue is a ``queue.SimpleQueue`` (C, lock-free put; unbounded, as the
  default ``rx_queue_size=0`` is);
- ``recv`` without receive filters takes the queue directly: ``BusABC.recv`` calls
  ``time.time()`` twice and logs every frame at level 9 (``LOG.log`` is ~1.5 us even when
  nothing is logged), 10 % of a stepped run; with filters set it is python-can's.
"""

from __future__ import annotations

import queue
import time
from typing import Any

import can
from can.interfaces import virtual as _virtual

_new = can.Message.__new__
_Message = can.Message


class FastVirtualBus(_virtual.VirtualBus):
    """A ``VirtualBus`` without the per-receiver deepcopy (see the module docstring)."""

    def __init__(self, channel: Any = None, **kwargs: Any) -> None:
        super().__init__(channel=channel, **kwargs)
        fast: queue.SimpleQueue = queue.SimpleQueue()
        with _virtual.channels_lock:
            i = next(i for i, q in enumerate(self.channel) if q is self.queue)
            self.channel[i] = fast  # type: ignore[call-overload]  # (SimpleQueue: same API)
        self.queue = fast  # type: ignore[assignment]

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:  # (VirtualBus._check_if_open's test, its error when closed)
            self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        own = self.queue
        data = msg.data
        for bus_queue in self.channel:
            if bus_queue is own and not self.receive_own_messages:
                continue
            m = _new(_Message)
            m.timestamp = timestamp
            m.arbitration_id = msg.arbitration_id
            m.is_extended_id = msg.is_extended_id
            m.is_remote_frame = msg.is_remote_frame
            m.is_error_frame = msg.is_error_frame
            m.channel = self.channel_id
            m.dlc = msg.dlc
            m.data = bytearray(data)
            m.is_fd = msg.is_fd
            m.is_rx = bus_queue is not own
            m.bitrate_switch = msg.bitrate_switch
            m.error_state_indicator = msg.error_state_indicator
            bus_queue.put(m)

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._filters is not None:
            return super().recv(timeout)
        if not self._open:
            self._check_if_open()
        try:
            if timeout == 0:
                return self.queue.get_nowait()
            return self.queue.get(True, timeout)
        except queue.Empty:
            return None
