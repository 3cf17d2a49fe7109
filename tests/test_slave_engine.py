"""The one slave-node engine (controller/canopen/slave/engine.py) against independent clients.

- SDO: python canopen's ``RemoteNode`` (its own SDO client: expedited, segmented, block) on
  a second python-can virtual bus, the engine in a real-time device thread;
- NMT, heartbeat consumer and PDO timing: in a stepped world, frames injected and observed
  by a plain port (the tests build every frame by hand from CiA 301, not with our code).
"""

from __future__ import annotations

import struct
import uuid
from collections.abc import Iterator
from contextlib import contextmanager

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError

from controller.canopen.io.clock import RealtimeClock
from controller.canopen.io.transport import DeviceThread, Port, SteppedWorld, virtual_bus
from controller.canopen.protocol.sdo import (
    ABORT_COMMAND,
    ABORT_GENERAL,
    ABORT_LENGTH,
    ABORT_NO_OBJECT,
    ABORT_NO_SUB,
    ABORT_READ_ONLY,
    ABORT_VALUE_RANGE,
)
from controller.canopen.slave.engine import Nmt, SlaveEngine, restricted_can_id
from controller.resources import data_path

SERVO = data_path("eds", "cantrack-servo.eds")
CONTROLLER = data_path("eds", "cantrack-controller.eds")
NODE = 11


class Host:
    """An endpoint holding one engine on its own port (what the device rack does)."""

    def __init__(self, bus: can.BusABC, clock, eds=SERVO, engine_cls=SlaveEngine, **kw):
        self.bus = bus
        self.port = Port(bus, clock)
        self.engine = engine_cls("dut", eds, NODE, self.port, **kw)

    def handle(self, msg: can.Message) -> None:
        self.port.handle(msg)

    def next_timer_ns(self):
        return self.engine.next_timer_ns()

    def on_timer(self, now_ns: int) -> None:
        self.engine.on_timer(now_ns)


class Peer:
    """A bus participant that records what it hears and sends raw frames."""

    def __init__(self, world: SteppedWorld) -> None:
        self.bus = world.new_bus()
        self.port = Port(self.bus, world.clock)
        self.frames: list[tuple[int, int, bytes]] = []
        self.clock = world.clock

    def handle(self, msg: can.Message) -> None:
        self.frames.append((self.clock.now_ns(), msg.arbitration_id, bytes(msg.data)))

    def next_timer_ns(self):
        return None

    def on_timer(self, now_ns: int) -> None:
        pass

    def send(self, can_id: int, data: bytes) -> None:
        self.port.send(can_id, data)

    def ids(self, can_id: int, since: int = 0) -> list[bytes]:
        return [d for _, c, d in self.frames[since:] if c == can_id]


@contextmanager
def stepped(eds=SERVO, engine_cls=SlaveEngine, **kw) -> Iterator[tuple]:
    world = SteppedWorld(f"engine-{uuid.uuid4().hex[:8]}")
    host = world.add(Host(world.new_bus(), world.clock, eds, engine_cls, **kw))
    peer = world.add(Peer(world))
    try:
        world.run_until(world.clock.now_ns() + 10_000_000)  # boot-up after 5 ms
        yield world, host.engine, peer
    finally:
        world.close()


def _expedited(peer: Peer, world, index: int, sub: int, data: bytes) -> bytes:
    n = len(data)
    peer.send(0x600 + NODE, bytes([0x23 | ((4 - n) << 2)]) + struct.pack("<HB", index, sub)
              + data + bytes(4 - n))
    k = len(peer.frames)
    world.run_until(world.clock.now_ns() + 1_000_000)
    answers = peer.ids(0x580 + NODE, k)
    return answers[-1] if answers else b""


@contextmanager
def remote(eds=SERVO, engine_cls=SlaveEngine, **kw) -> Iterator[tuple]:
    """The engine in a real-time device thread; a python canopen RemoteNode on another bus."""
    channel = f"engine-rt-{uuid.uuid4().hex[:8]}"
    clock = RealtimeClock()
    host = Host(virtual_bus(channel), clock, eds, engine_cls, boot_delay_ns=0, **kw)
    thread = DeviceThread(host, clock).start()
    net = canopen.Network(can.Bus(interface="virtual", channel=channel))
    net.connect()
    node = canopen.RemoteNode(NODE, canopen.import_od(str(eds), NODE))
    net.add_node(node)
    node.sdo.RESPONSE_TIMEOUT = 2.0  # (a busy machine: the answer is a cue, not a sleep)
    try:
        yield node, host.engine
    finally:
        net.disconnect()
        thread.stop()
        host.bus.shutdown()


def _abort(call) -> int:
    with pytest.raises(SdoAbortedError) as e:
        call()
    return e.value.code


# ------------------------------------------------------------------------------- SDO
def test_restricted_can_ids_as_cia301():
    allowed = [0x100, 0x181, 0x1FF, 0x200 + NODE, 0x4FF, 0x57F, 0x580, 0x600,
               0x680, 0x6DF, 0x700]
    refused = [0x000, 0x001, 0x07F, 0x101, 0x180, 0x581, 0x5FF, 0x601, 0x67F, 0x6E0,
               0x6FF, 0x701, 0x7FF]
    assert not any(restricted_can_id(c) for c in allowed)
    assert all(restricted_can_id(c) for c in refused)


def test_sdo_expedited_and_segmented_with_canopen_client():
    with remote() as (node, eng):
        # boot-up at once (boot delay 0) -> PRE-OPERATIONAL: SDO is served
        assert node.sdo[0x1018][1].raw == 0x00CA7AC0
        # 1008h (VISIBLE_STRING, 14 bytes): a segmented upload (2 segments)
        assert node.sdo[0x1008].raw == "cantrack servo"
        assert node.sdo[0x100A].raw == eng.load(0x100A) == "0.1.0"
        # a 4-byte object written by a forced segmented download, read back expedited
        node.sdo.download(0x6065, 0, struct.pack("<I", 12345), force_segment=True)
        assert eng.load(0x6065) == 12345
        assert node.sdo[0x6065].raw == 12345


def test_sdo_refusals_with_canopen_client():
    with remote() as (node, eng):
        assert _abort(lambda: node.sdo.upload(0x2999, 0)) == ABORT_NO_OBJECT
        assert _abort(lambda: node.sdo.upload(0x1018, 9)) == ABORT_NO_SUB
        assert _abort(lambda: node.sdo.download(0x1018, 1, b"\1\0\0\0")) == ABORT_READ_ONLY
        # a read-only object refused by a segmented download at its first frame
        assert _abort(lambda: node.sdo.download(0x1008, 0, b"another name",
                                                force_segment=True)) == ABORT_READ_ONLY
        assert eng.load(0x1008) == "cantrack servo"
        assert _abort(lambda: node.sdo.download(0x6065, 0, b"\1\0")) == ABORT_LENGTH
        # block transfers: refused (CiA 301 lets a server refuse them)
        with pytest.raises(SdoAbortedError) as e:
            with node.sdo[0x1008].open("rb", block_transfer=True) as f:
                f.read()
        assert e.value.code == ABORT_COMMAND


def test_pdo_cob_id_writes_follow_canopennode():
    class Guarded(SlaveEngine):
        def cob_id_conflict(self, kind, number, can_id):
            return "drive x's RPDO1" if can_id == 0x20B else None

    with remote(engine_cls=Guarded) as (node, eng):
        cob = node.sdo[0x1800][1].raw
        assert not cob & 0x80000000
        # a valid PDO: its CAN-ID cannot change (disable first)
        assert _abort(lambda: node.sdo[0x1800][1].__setattr__("raw", 0x3A0)) == \
            ABORT_VALUE_RANGE
        node.sdo[0x1800][1].raw = cob | 0x80000000
        # (080h, the SYNC, is not restricted by CiA 301: the controller node refuses it as
        #  "in use", test_plc_contract.py)
        for bad in (0x000, 0x07F, 0x101, 0x180, 0x585, 0x605, 0x6E0, 0x70B, 0x7FF):
            assert _abort(lambda b=bad: node.sdo[0x1800][1].__setattr__("raw", b)) == \
                ABORT_VALUE_RANGE, hex(bad)
        assert _abort(lambda: node.sdo[0x1800][1].__setattr__("raw", 0x1000 | 0x3A0)) == \
            ABORT_VALUE_RANGE  # bit 12: not an 11-bit identifier
        assert _abort(lambda: node.sdo[0x1800][1].__setattr__("raw", 0x20B)) == ABORT_GENERAL
        assert eng.load(0x1800, 1) == cob | 0x80000000  # nothing refused was stored
        # a PDO without mapping cannot be made valid
        node.sdo[0x1A00][0].raw = 0
        assert _abort(lambda: node.sdo[0x1800][1].__setattr__("raw", 0x3A0)) == \
            ABORT_VALUE_RANGE
        node.sdo[0x1A00][0].raw = 1
        node.sdo[0x1800][1].raw = 0x3A0  # a free identifier: accepted
        assert eng.load(0x1800, 1) == 0x3A0
        # transmission types 241-253 (RTR) refused, 0 and 254 accepted
        assert _abort(lambda: node.sdo[0x1800][2].__setattr__("raw", 241)) == \
            ABORT_VALUE_RANGE
        assert _abort(lambda: node.sdo[0x1800][2].__setattr__("raw", 253)) == \
            ABORT_VALUE_RANGE
        node.sdo[0x1800][2].raw = 0
        node.sdo[0x1800][2].raw = 254


def test_stray_segment_and_short_frame():
    with stepped() as (world, eng, peer):
        k = len(peer.frames)
        peer.send(0x600 + NODE, bytes([0x00]) + bytes(7))  # download segment, no transfer
        peer.send(0x600 + NODE, bytes([0x60]) + bytes(7))  # upload segment, no transfer
        peer.send(0x600 + NODE, bytes([0x40, 0x18, 0x10, 0x01]))  # 4 bytes: aborted too
        world.run_until(world.clock.now_ns() + 1_000_000)
        answers = peer.ids(0x580 + NODE, k)
        assert [struct.unpack_from("<I", a, 4)[0] for a in answers] == [ABORT_COMMAND] * 3
        assert all(a[0] == 0x80 for a in answers)
        assert answers[2][1:4] == bytes([0x18, 0x10, 0x01])  # (the index bytes it had)


# ------------------------------------------------------------------------------- NMT
def test_nmt_states_gate_sdo_and_pdos():
    with stepped() as (world, eng, peer):
        assert peer.ids(0x700 + NODE) == [b"\x00"]  # boot-up
        assert eng.nmt_state is Nmt.PRE_OPERATIONAL
        assert _expedited(peer, world, 0x1017, 0, b"\x64\x00")[0] == 0x60
        peer.send(0x000, bytes([0x02, NODE]))  # stop
        world.run_until(world.clock.now_ns() + 1_000_000)
        assert eng.nmt_state is Nmt.STOPPED
        assert _expedited(peer, world, 0x1017, 0, b"\x64\x00") == b""  # no SDO in STOPPED
        peer.send(0x000, bytes([0x01, 0x00]))  # start all
        world.run_until(world.clock.now_ns() + 1_000_000)
        assert eng.nmt_state is Nmt.OPERATIONAL
        hb = list(peer.ids(0x700 + NODE))
        world.run_until(world.clock.now_ns() + 250_000_000)
        assert peer.ids(0x700 + NODE)[len(hb):] == [b"\x05", b"\x05"]  # 100 ms producer
        peer.send(0x000, bytes([0x82, NODE]))  # reset communication: boot-up again
        world.run_until(world.clock.now_ns() + 10_000_000)
        assert peer.ids(0x700 + NODE)[-1] == b"\x00"
        assert eng.nmt_state is Nmt.PRE_OPERATIONAL
        assert eng.load(0x1017) == 100  # back to the EDS default (was written 100: same)


def test_heartbeat_consumer_present_lost_back():
    events = []

    class Watch(SlaveEngine):
        def on_heartbeat_lost(self, producer):
            events.append(("lost", producer, self.clock.now_ns()))

        def on_heartbeat_back(self, producer):
            events.append(("back", producer, self.clock.now_ns()))

    with stepped(engine_cls=Watch) as (world, eng, peer):
        assert _expedited(peer, world, 0x1016, 1, struct.pack("<I", (0x21 << 16) | 50))[0] \
            == 0x60
        assert not eng.heartbeat_present(0x21)  # never heard: not present
        t0 = world.clock.now_ns()
        for i in range(5):  # every 40 ms
            world.at(t0 + i * 40_000_000, lambda: peer.send(0x721, b"\x05"))
        world.run_until(t0 + 170_000_000)
        assert eng.heartbeat_present(0x21) and not events
        world.run_until(t0 + 300_000_000)
        assert not eng.heartbeat_present(0x21)
        assert events == [("lost", 0x21, t0 + 160_000_000 + 50_000_000)]
        peer.send(0x721, b"\x05")
        world.run_until(world.clock.now_ns() + 1_000_000)
        assert eng.heartbeat_present(0x21) and events[-1][0] == "back"


# ------------------------------------------------------------------------------- PDOs
def _start(world, peer):
    peer.send(0x000, bytes([0x01, NODE]))
    world.run_until(world.clock.now_ns() + 1_000_000)


def _sync(world, peer, counter: int | None = None, n: int = 1, period_ns: int = 2_000_000):
    for _ in range(n):
        peer.send(0x080, b"" if counter is None else bytes([counter]))
        world.run_until(world.clock.now_ns() + period_ns)
        if counter is not None:
            counter = counter % 16 + 1


def test_tpdo_transmission_type_0_only_after_a_change():
    with stepped() as (world, eng, peer):
        cob = eng.load(0x1800, 1) & 0x7FF
        assert _expedited(peer, world, 0x1800, 2, b"\x00")[0] == 0x60
        _start(world, peer)
        k = len(peer.frames)
        _sync(world, peer, n=5)
        first = peer.ids(cob, k)
        assert len(first) == 1  # the first SYNC in OPERATIONAL: the data is new
        k = len(peer.frames)
        _sync(world, peer, n=5)
        assert peer.ids(cob, k) == []  # nothing changed: nothing sent
        mapped = eng.load(0x1A00, 1)
        index, sub = mapped >> 16, (mapped >> 8) & 0xFF
        eng.store(index, sub, (int(eng.load(index, sub)) + 1) & 0xFF)
        k = len(peer.frames)
        world.run_until(world.clock.now_ns() + 5_000_000)
        assert peer.ids(cob, k) == []  # a change alone: waits for the SYNC
        _sync(world, peer, n=3)
        assert len(peer.ids(cob, k)) == 1


def test_tpdo_every_nth_sync_from_the_start_value():
    """Type 3 with SYNC start value 5 (written while the PDO is invalid, as CANopenNode
    requires): sent at the SYNC whose counter is 5, then at every 3rd."""
    with stepped() as (world, eng, peer):
        cob = eng.load(0x1800, 1) & 0x7FF
        assert _expedited(peer, world, 0x1800, 2, b"\x03")[0] == 0x60
        refused = _expedited(peer, world, 0x1800, 6, b"\x05")  # valid PDO: refused
        assert refused[0] == 0x80 and struct.unpack_from("<I", refused, 4)[0] == \
            ABORT_VALUE_RANGE
        assert _expedited(peer, world, 0x1800, 1, struct.pack("<I", cob | 0x80000000))[0] \
            == 0x60
        assert _expedited(peer, world, 0x1800, 6, b"\x05")[0] == 0x60
        assert _expedited(peer, world, 0x1800, 1, struct.pack("<I", cob))[0] == 0x60
        assert _expedited(peer, world, 0x1019, 0, b"\x10")[0] == 0x60  # SYNCs with a counter
        _start(world, peer)
        k = len(peer.frames)
        sent_at = []
        c = 1
        for _ in range(14):
            n0 = len(peer.ids(cob, k))
            _sync(world, peer, c)
            if len(peer.ids(cob, k)) > n0:
                sent_at.append(c)
            c = c % 16 + 1
        assert sent_at == [5, 8, 11, 14]


def test_rpdo_synchronous_applied_at_the_next_sync():
    with stepped() as (world, eng, peer):
        _start(world, peer)
        cob = eng.load(0x1400, 1) & 0x7FF
        mapped = [eng.load(0x1600, i) for i in range(1, eng.load(0x1600, 0) + 1)]
        size = sum(m & 0xFF for m in mapped) // 8
        index, sub = mapped[0] >> 16, (mapped[0] >> 8) & 0xFF
        before = eng.load(index, sub)
        assert eng.load(0x1400, 2) <= 240
        data = bytes([0x0F]) + bytes(size - 1)
        peer.send(cob, data)
        world.run_until(world.clock.now_ns() + 1_000_000)
        assert eng.load(index, sub) == before  # waits for the SYNC
        _sync(world, peer)
        assert eng.load(index, sub) == 0x0F
        peer.send(cob, bytes([0x06]))  # too short: not processed
        _sync(world, peer)
        assert eng.load(index, sub) == 0x0F


def test_event_tpdo_keeps_its_inhibit_time_and_event_timer():
    """Type 255, inhibit time 5 ms (18xxh:3 = 50 x 100 us), event timer 20 ms (18xxh:5): a
    mapped object changing every 1 ms goes out at most every 5 ms, each frame with the
    newest value; unchanged, the PDO repeats every 20 ms (CiA 301 7.2.2.6.1)."""
    with stepped() as (world, eng, peer):
        cob = eng.load(0x1800, 1) & 0x7FF
        assert _expedited(peer, world, 0x1800, 2, b"\xff")[0] == 0x60
        assert _expedited(peer, world, 0x1800, 3, struct.pack("<H", 50))[0] == 0x60
        assert _expedited(peer, world, 0x1800, 5, struct.pack("<H", 20))[0] == 0x60
        mapped = eng.load(0x1A00, 1)
        index, sub, bits = mapped >> 16, (mapped >> 8) & 0xFF, mapped & 0xFF
        _start(world, peer)
        t0 = world.clock.now_ns()
        k = len(peer.frames)
        for i in range(1, 31):  # a change every 1 ms for 30 ms, served by the node's timers
            def change(i=i):
                eng.store(index, sub, i)
                eng.service_event_pdos(world.clock.now_ns())
            world.at(t0 + i * 1_000_000, change)
        world.run_until(t0 + 31_000_000)
        changing = [(t, d) for t, c, d in peer.frames[k:] if c == cob]
        gaps = [b[0] - a[0] for a, b in zip(changing, changing[1:])]
        assert len(changing) >= 5 and min(gaps) >= 5_000_000
        last = int.from_bytes(changing[-1][1][:bits // 8], "little")
        assert last >= 25  # (the newest value: the changes never stopped the PDO)
        k = len(peer.frames)
        world.run_until(world.clock.now_ns() + 70_000_000)
        quiet = [t for t, c, _ in peer.frames[k:] if c == cob]
        assert len(quiet) == 3 and [b - a for a, b in zip(quiet, quiet[1:])] == \
            [20_000_000, 20_000_000]
