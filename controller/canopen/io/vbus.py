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
  nothing is logged), 10 % of a stepped run; with filters set it is python-can's.  An empty
  ``recv(0)`` (the poll before a SYNC deadline, the stepped world's drain) asks the queue
  whether it is empty instead of raising and catching ``queue.Empty``;
- :meth:`FastVirtualBus.send_frame` sends a standard data frame from its COB-ID, data and
  message time (what :class:`~.transport.Port` sends): the receivers' messages are built
  from them, with no sender's :class:`can.Message` in between;
- :meth:`FastVirtualBus.hold_sends`: what one thread (the device thread) sends is kept and
  delivered together when it is about to wait (:meth:`~FastVirtualBus.deliver_held`): a
  receiver blocked on its queue (the controller waiting for the devices' TPDOs) is woken
  once, when the GIL is about to be free, not by the first frame of a burst while the
  sender still runs (it woke, then slept again waiting for the GIL).
"""

from __future__ import annotations

import queue
import threading
import time
from typing import Any

import can
from can.interfaces import virtual as _virtual

_new = can.Message.__new__
_Message = can.Message
_get_ident = threading.get_ident


class FastVirtualBus(_virtual.VirtualBus):
    """A ``VirtualBus`` without the per-receiver deepcopy (see the module docstring)."""

    def __init__(self, channel: Any = None, **kwargs: Any) -> None:
        super().__init__(channel=channel, **kwargs)
        fast: queue.SimpleQueue = queue.SimpleQueue()
        with _virtual.channels_lock:
            i = next(i for i, q in enumerate(self.channel) if q is self.queue)
            self.channel[i] = fast  # type: ignore[call-overload]  # (SimpleQueue: same API)
        self.queue = fast  # type: ignore[assignment]
        #: the thread whose sends are held (:meth:`hold_sends`; None: every send goes out)
        self._holder: int | None = None
        #: its sends not delivered yet: (receiver's queue, message), in send order
        self._held: list[tuple[queue.Queue[can.Message], can.Message]] = []

    def hold_sends(self) -> None:
        """From now on what the calling thread sends on this bus reaches the receivers at
        its next :meth:`deliver_held` (each frame keeps its own timestamp, the send time);
        other threads' sends go out at once.  For a thread that serves frames in batches
        and calls :meth:`deliver_held` before each wait (:class:`~.transport.DeviceThread`)."""
        self._holder = _get_ident()

    def deliver_held(self) -> None:
        """Put the held frames into their receivers' queues (in send order)."""
        held = self._held
        if held:
            self._held = []
            for bus_queue, m in held:
                bus_queue.put(m)

    def release_sends(self) -> None:
        """Deliver what is held; every send goes out at once again."""
        self._holder = None
        self.deliver_held()

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self._open:  # (VirtualBus._check_if_open's test, its error when closed)
            self._check_if_open()
        timestamp = msg.timestamp if self.preserve_timestamps else time.time()
        own = self.queue
        data = msg.data
        held = self._held if self._holder is not None and self._holder == _get_ident() \
            else None
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
            if held is None:
                bus_queue.put(m)
            else:
                held.append((bus_queue, m))

    def send_frame(self, can_id: int, data: bytes | bytearray, timestamp: float) -> None:
        """Send the standard (11-bit) data frame ``can_id`` with ``data`` at message time
        ``timestamp`` [s]: what :meth:`send` does with ``can.Message(arbitration_id=can_id,
        data=data, is_extended_id=False, timestamp=timestamp)``, without building that
        message (each receiver gets its own, a new ``bytearray`` of the data)."""
        if not self._open:
            self._check_if_open()
        if not self.preserve_timestamps:
            timestamp = time.time()
        own = self.queue
        channel_id = self.channel_id
        dlc = len(data)
        held = self._held if self._holder is not None and self._holder == _get_ident() \
            else None
        for bus_queue in self.channel:
            if bus_queue is own and not self.receive_own_messages:
                continue
            m = _new(_Message)
            m.timestamp = timestamp
            m.arbitration_id = can_id
            m.is_extended_id = False
            m.is_remote_frame = False
            m.is_error_frame = False
            m.channel = channel_id
            m.dlc = dlc
            m.data = bytearray(data)
            m.is_fd = False
            m.is_rx = bus_queue is not own
            m.bitrate_switch = False
            m.error_state_indicator = False
            if held is None:
                bus_queue.put(m)
            else:
                held.append((bus_queue, m))

    def recv(self, timeout: float | None = None) -> can.Message | None:
        if self._filters is not None:
            return super().recv(timeout)
        if not self._open:
            self._check_if_open()
        q = self.queue
        if timeout == 0:
            # (one reader per queue: not empty now, not empty at the get)
            return None if q.empty() else q.get_nowait()
        try:
            return q.get(True, timeout)
        except queue.Empty:
            return None
