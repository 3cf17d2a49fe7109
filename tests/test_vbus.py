"""The fast virtual bus (controller/canopen/io/vbus.py): a Port's frame reaches every
receiver on the channel as python-can's own virtual bus delivers it."""

from __future__ import annotations

import time

import can
import pytest

from controller.canopen.io.clock import SteppedClock
from controller.canopen.io.transport import Port, virtual_bus
from controller.canopen.io.vbus import FastVirtualBus
from controller.errors import CanError

_FIELDS = [f for f in can.Message.__slots__ if f != "__weakref__"]


def _fields(msg: can.Message) -> dict:
    return {f: getattr(msg, f) for f in _FIELDS}


def test_a_ports_frame_is_the_message_a_plain_send_delivers():
    """Port.send on our bus (send_frame, no sender's message) and bus.send of the
    equivalent can.Message give every receiver -- ours and python-can's plain virtual bus
    -- the same message: fields, own bytearray, the sender's timestamp."""
    channel = f"vbus-{time.perf_counter_ns()}"
    sender = virtual_bus(channel)
    ours = virtual_bus(channel)
    plain = can.Bus(interface="virtual", channel=channel, preserve_timestamps=True)
    try:
        assert isinstance(sender, FastVirtualBus)
        clock = SteppedClock(1_250_000_000)
        port = Port(sender, clock)
        port.send(0x181, b"\x01\x02\x03")
        sender.send(can.Message(arbitration_id=0x181, data=b"\x01\x02\x03",
                                is_extended_id=False, timestamp=1.25))
        for rx in (ours, plain):
            a, b = rx.recv(1.0), rx.recv(1.0)
            assert a is not None and b is not None
            assert _fields(a) == _fields(b)
            assert a.timestamp == 1.25 and a.is_rx and not a.is_extended_id
            assert isinstance(a.data, bytearray) and a.data == bytearray(b"\x01\x02\x03")
            assert a.dlc == 3 and a.channel == channel
        assert port.sent == 1
        assert ours.recv(0) is None and plain.recv(0) is None  # nothing else, none to itself
    finally:
        for b in (sender, ours, plain):
            b.shutdown()


def test_a_closed_bus_is_a_can_error_naming_the_cob_id():
    bus = virtual_bus(f"vbus-closed-{time.perf_counter_ns()}")
    port = Port(bus, SteppedClock())
    bus.shutdown()
    with pytest.raises(CanError, match="cannot send 0x181"):
        port.send(0x181, b"\x00")
    assert port.sent == 0
