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


def test_held_sends_reach_the_receivers_at_delivery_in_order():
    """hold_sends: the holding thread's frames wait for deliver_held (in send order, with
    their send times); another thread's send goes out at once; release_sends delivers
    what is held and ends the hold."""
    import threading

    channel = f"vbus-held-{time.perf_counter_ns()}"
    sender = virtual_bus(channel)
    rx = virtual_bus(channel)
    try:
        assert isinstance(sender, FastVirtualBus)
        port = Port(sender, SteppedClock(2_000_000_000))
        sender.hold_sends()
        port.send(0x181, b"\x01")
        sender.send(can.Message(arbitration_id=0x182, data=b"\x02", is_extended_id=False,
                                timestamp=2.0))
        assert rx.recv(0) is None  # held
        other = threading.Thread(target=lambda: sender.send(can.Message(
            arbitration_id=0x183, data=b"\x03", is_extended_id=False, timestamp=2.5)))
        other.start()
        other.join()
        m = rx.recv(0)
        assert m is not None and m.arbitration_id == 0x183  # not the holder's: at once
        assert rx.recv(0) is None
        sender.deliver_held()
        got = [rx.recv(0), rx.recv(0)]
        assert [(m.arbitration_id, bytes(m.data), m.timestamp) for m in got if m] == \
            [(0x181, b"\x01", 2.0), (0x182, b"\x02", 2.0)]
        assert rx.recv(0) is None
        port.send(0x184, b"\x04")
        sender.release_sends()
        m = rx.recv(0)
        assert m is not None and m.arbitration_id == 0x184
        port.send(0x185, b"\x05")  # no longer held
        m = rx.recv(0)
        assert m is not None and m.arbitration_id == 0x185
    finally:
        sender.shutdown()
        rx.shutdown()


def test_a_device_threads_answers_go_out_when_it_is_about_to_wait():
    """DeviceThread on our virtual bus: what the endpoint sends while it serves a batch
    reaches the other receivers only once the batch is done (then all of it)."""
    from controller.canopen.io.clock import RealtimeClock
    from controller.canopen.io.transport import DeviceThread

    channel = f"vbus-thread-{time.perf_counter_ns()}"
    controller = virtual_bus(channel)
    seen_while_serving: list[bool] = []

    class Echo:
        def __init__(self) -> None:
            self.bus = virtual_bus(channel)
            self.port = Port(self.bus, RealtimeClock())

        def handle(self, msg: can.Message) -> None:
            self.port.send(0x181, b"\x01")
            self.port.send(0x281, b"\x02")
            seen_while_serving.append(controller.recv(0) is not None)

        def next_timer_ns(self) -> int | None:
            return None

        def on_timer(self, now_ns: int) -> None:
            pass

    echo = Echo()
    thread = DeviceThread(echo, RealtimeClock()).start()
    try:
        Port(controller, RealtimeClock()).send(0x80, b"")
        first = controller.recv(2.0)
        second = controller.recv(0)
        assert first is not None and second is not None
        assert (first.arbitration_id, second.arbitration_id) == (0x181, 0x281)
        assert seen_while_serving == [False]
    finally:
        thread.stop()
        echo.bus.shutdown()
        controller.shutdown()
