"""The controller as a CANopen node for a PLC (the PLC node on the slave engine), in stepped
time: a PLC (the project's SDO client on its own port of the same virtual bus, its heartbeat
from a producer in the world: the commander of ``.plc``) reads and writes the controller's
objects during a run; the event-driven TPDOs on the bus decode (with python canopen's own PDO
decoding of the EDS mapping) to the tracker's values.  The contract's refusals:
test_plc_contract.py."""

from __future__ import annotations

import itertools
import struct
from contextlib import contextmanager
from dataclasses import replace

import canopen
import pytest
from controller.canopen.apps.demo import PhotoEye, PickPlace

from controller.canopen.config import load_config
from controller.canopen.io.transport import SteppedTransport
from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.master.cycle import Controller, Phase
from controller.canopen.config.plc import PlcConfig
from controller.canopen.master.plc_node import attach_plc_node
from controller.canopen.slave.plc import EDS
from controller.canopen.protocol import od as odm
from controller.canopen.protocol.sdo import SdoAbortError, SdoClient
from controller.canopen.slave.world import SimWorld
from controller.canopen.testing import load, stepped
from controller.cli import demo as cmd_demo
from controller.tracking import TrackState

OFFSET = (420.0, 30.0, 0.0)
ENGAGE = 20  # cycles after the start of tracking
NODE = 1  # master.node_id of the test bus
PLC = 0x20  # the commander


class Heartbeat:
    """The PLC's heartbeat (700h + PLC, OPERATIONAL) every 100 ms on the world's clock."""

    def __init__(self, world) -> None:
        self.bus = world.new_bus()
        self.clock = world.clock
        self._next = self.clock.now_ns()

    def handle(self, msg) -> None:
        pass

    def next_timer_ns(self):
        return self._next

    def on_timer(self, now_ns: int) -> None:
        import can
        self.bus.send(can.Message(arbitration_id=0x700 + PLC, data=b"\x05",
                                  is_extended_id=False, timestamp=self.clock.stamp()))
        self._next = now_ns + 100_000_000


def _plc(ctl, world, app=None):
    """The PLC node with the test PLC as its commander (heartbeat in ``world``)."""
    world.add(Heartbeat(world))
    return attach_plc_node(ctl, PlcConfig(commander=PLC))


def _pdo_decoder(cob_id: int = 0x180 + NODE):
    """TPDO decoding by python canopen from the EDS mapping (no bus needed)."""
    node = canopen.RemoteNode(NODE, odm.load_od(EDS, NODE))
    canopen.Network().add_node(node)
    node.tpdo.read(from_od=True)
    maps = {m.cob_id: m for m in node.tpdo.map.values()}
    return maps[cob_id]


def _decode(pdo_map, data: bytes) -> dict[str, object]:
    pdo_map.on_message(pdo_map.cob_id, bytearray(data), 0.0)
    return {v.name: v.raw for v in pdo_map.map}


def _record_at(ctl: Controller, t_ns: int):
    """The cycle record of the cycle that was running at bus time ``t_ns``."""
    best = None
    for r in ctl.trace:
        if ctl.t0 + round(r.t_s * 1e9) <= t_ns:
            best = r
        else:
            break
    return best


@pytest.fixture
def rig(tmp_path):
    cfg = load(tmp_path)
    app = ConveyorFollow(ENGAGE, None, OFFSET)
    world, ctl = stepped(cfg, app, record=True)
    seen: list[int] = []
    ctl.on_cycle = lambda c, rec: seen.append(rec.cycle)  # an existing callback: chained
    plc = _plc(ctl, world.world)
    client = SdoClient(SteppedTransport(world.world), NODE, "plc", timeout_s=0.01)
    ctl.boot()
    ctl.start()
    yield cfg, world, ctl, plc, client, seen
    world.close()


def _step(ctl, n):
    for _ in range(n):
        ctl.step()


def test_sdo_reads_follow_the_tracker_and_engage_command_desyncs(rig):
    cfg, world, ctl, plc, client, seen = rig
    assert plc.node_id == NODE
    samples = []
    for _ in range(600):
        ctl.step()
        if ctl.phase is Phase.RUNNING:
            st = client.upload_uint(0x2000, 0)
            imfs = client.upload_int(0x2001, 0)
            err = client.upload_uint(0x2002, 0)
            samples.append((st, imfs, err))
            assert st == int(ctl.source.tracker.state)  # the SDO answer is this cycle's state
        if samples and samples[-1][0] == TrackState.SYNCED and len(samples) > ENGAGE + 30:
            break
    assert seen and seen[-1] == ctl.k - 1  # the callback that was there is still called
    states = [s for s, _, _ in samples]
    assert states[0] == TrackState.OFF
    assert TrackState.SYNCING in states and states[-1] == TrackState.SYNCED
    assert (int(TrackState.SYNCING), 0, 0) in samples and (int(TrackState.SYNCED), 1, 0) \
        in samples
    assert client.upload_uint(0x2003, 0) == 0  # no item yet
    vel = struct.unpack("<f", client.upload(0x2008, 0))[0]
    assert vel == pytest.approx(300.0, rel=0.02)  # the simulated belt: 300 mm/s
    err_mm = struct.unpack("<f", client.upload(0x2007, 0))[0]
    assert 0.0 <= err_mm < 1.0
    # the configuration's values, not the EDS defaults: the test bus has a SYNC counter
    assert client.upload_uint(0x1019, 0) == cfg.master.sync_overflow == 16
    assert client.upload_uint(0x1006, 0) == 2000
    assert client.upload_uint(0x1018, 1) == 0x00CA7AC0
    # the PLC disengages: 2005h = 0 -> the tracker de-syncs (stop on the path), then OFF
    client.download(0x2005, 0, b"\x00")
    ctl.step()
    assert ctl.source.tracker.state is TrackState.DESYNCING
    assert client.upload_uint(0x2000, 0) == TrackState.DESYNCING
    assert client.upload_int(0x2001, 0) == -1
    for _ in range(500):
        ctl.step()
        if ctl.source.tracker.state is TrackState.OFF:
            break
    assert client.upload_uint(0x2000, 0) == TrackState.OFF
    # and engages again over RPDO1 (200h + id: 2005h engage, 2004h trigger)
    client.transport.send(0x200 + NODE, bytes([5, 0]))
    ctl.step()
    assert ctl.source.tracker.state is TrackState.SYNCING
    assert ctl.source.tracker.mode == 5 or plc.commands[-1][1] == 5
    assert [v for _, v in plc.commands] == [0, 5]


def test_sdo_aborts(rig):
    cfg, world, ctl, plc, client, seen = rig
    with pytest.raises(SdoAbortError) as e:
        client.download(0x2005, 0, b"\x03")  # the tracker does not run yet
    assert e.value.code == 0x08000022
    _step(ctl, 30)
    assert ctl.phase is Phase.RUNNING
    cases = [
        (lambda: client.download(0x2000, 0, b"\x01"), 0x06010002),  # read-only
        (lambda: client.download(0x1018, 1, b"\x01\x00\x00\x00"), 0x06010002),
        (lambda: client.upload(0x2100, 0), 0x06020000),  # no such object
        (lambda: client.download(0x2999, 0, b"\x01"), 0x06020000),
        (lambda: client.upload(0x2010, 9), 0x06090011),  # no such sub-index
        (lambda: client.download(0x2005, 0, b"\x04"), 0x06090030),  # not 0, 3, 5
        (lambda: client.download(0x2005, 0, b"\x06"), 0x06090030),  # above HighLimit
        (lambda: client.download(0x2004, 0, b"\x02"), 0x06090030),
        (lambda: client.download(0x2005, 0, b"\x03\x00"), 0x06070010),  # length
        (lambda: client.download(0x1017, 0, b"\x64\x00"), 0x08000020),  # the config's
    ]
    for call, code in cases:
        with pytest.raises(SdoAbortError) as e:
            call()
        assert e.value.code == code, e.value
    assert client.upload_uint(0x2005, 0) == 0  # refused writes are not stored
    ctl.step()
    assert ctl.source.tracker.state is TrackState.OFF  # ... and did nothing


def test_tpdo1_content_inhibit_and_event_timer(rig):
    cfg, world, ctl, plc, client, seen = rig
    decoder = _pdo_decoder()
    _step(ctl, 20)
    # two PLC triggers over SDO (rising edges of 2004h bit 0) -> item count 2
    for v in (1, 0, 1):
        client.download(0x2004, 0, bytes([v]))
    ctl.step()  # (the status objects are this cycle's)
    assert plc.triggers == 2 and client.upload_uint(0x2003, 0) == 2
    _step(ctl, 200)
    frames = [(t, d) for t, cid, d in world.recorder.frames if cid == 0x180 + NODE]
    assert len(frames) >= 5
    assert all(len(d) == 8 for _, d in frames)
    times = [t for t, _ in frames]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert min(gaps) >= 2_000_000  # inhibit time 1800h:3 = 20 x 100 us
    assert max(gaps) <= 100_000_000 + ctl.period_ns  # event timer 1800h:5 = 100 ms
    changed = [d for (_, d), (_, prev) in zip(frames[1:], frames, strict=False) if d != prev]
    assert len(changed) >= 3  # SYNCING, SYNCED (and the item count) were sent on change
    for t, d in frames:
        dec = _decode(decoder, d)
        rec = _record_at(ctl, t)
        assert rec is not None
        assert dec["Tracker state"] == rec.state
        assert dec["IsMovingFrameSynchronized"] == rec.imfs
        assert dec["Tracking error code"] == rec.error
    last = _decode(decoder, frames[-1][1])
    assert last["Item count"] == 2 and last["Tracker state"] == TrackState.SYNCED
    assert last["IsMovingFrameSynchronized"] == 1
    # a longer inhibit time written by the PLC (1800h:3 = 10 ms): changes wait for it
    client.download(0x1800, 3, struct.pack("<H", 100))
    n0 = len(frames)
    for v in (0, 1, 0, 1, 0, 1):
        client.download(0x2004, 0, bytes([v]))
        ctl.step()
    _step(ctl, 20)
    frames = [(t, d) for t, cid, d in world.recorder.frames if cid == 0x180 + NODE]
    new = frames[n0 - 1:]
    assert min(b[0] - a[0] for a, b in itertools.pairwise(new)) >= 10_000_000
    assert _decode(decoder, frames[-1][1])["Item count"] == 5


def test_tpdo2_tpdo3_decode(rig):
    cfg, world, ctl, plc, client, seen = rig
    _step(ctl, 150)
    tp2 = _pdo_decoder(0x280 + NODE)
    frames = [(t, d) for t, cid, d in world.recorder.frames if cid == 0x280 + NODE]
    assert frames
    gaps = [b[0] - a[0] for a, b in itertools.pairwise(frames)]
    assert not gaps or min(gaps) >= 100_000_000  # TPDO2 inhibit 100 ms
    dec = _decode(tp2, frames[-1][1])
    assert dec["Conveyor velocity"] == pytest.approx(300.0, rel=0.02)
    tp3 = [d for _, cid, d in world.recorder.frames if cid == 0x380 + NODE]
    assert tp3 and struct.unpack("<I", tp3[-1])[0] == 0


def test_no_second_heartbeat(rig):
    cfg, world, ctl, plc, client, seen = rig
    _step(ctl, 100)
    hb = [t for t, cid, _ in world.recorder.frames if cid == 0x700 + NODE]
    gaps = [b - a for a, b in itertools.pairwise(hb)]
    assert gaps and min(gaps) >= cfg.master.heartbeat_producer_ms * 1_000_000


def test_demo_plc_trigger_and_item_count(tmp_path):
    """The pick and place with the PLC node: the photo-eye items and one item triggered by
    the PLC (2004h) are counted in 2003h; the PLC's item is caught and placed too."""
    cfg = load_config(cmd_demo.DEFAULT_CONFIG)
    from dataclasses import replace
    demo = replace(cfg.demo, items=1)
    app = PickPlace(demo)
    with SimWorld(cfg, record=True) as world:
        ctl = Controller(cfg, world.transport, app)
        _plc(ctl, world.world, app)
        client = SdoClient(SteppedTransport(world.world), cfg.master.node_id, "plc",
                           timeout_s=0.01)
        ctl.boot()
        ctl.start()
        app.eye = PhotoEye(world.device(cfg.tracking.conveyor.node).profile, demo,
                           world.clock.now_ns() * 1e-9)
        counts = []
        k_trigger = k_seen = None
        while ctl.k < 4000:
            ctl.step()
            if ctl.phase is Phase.ENABLING:
                continue
            assert ctl.phase is Phase.RUNNING
            if ctl.source_done:
                break
            if ctl.k % 25 == 0:
                counts.append(client.upload_uint(0x2003, 0))
            if k_seen is None and counts and counts[-1] == 1:
                k_seen = ctl.k  # the first item is seen
            if k_trigger is None and k_seen is not None and ctl.k >= k_seen + 600:
                k_trigger = ctl.k  # 1.2 s later (360 mm): the PLC reports a second one
                client.download(0x2004, 0, b"\x01")
                ctl.step()
                client.download(0x2004, 0, b"\x00")
        assert k_trigger is not None
        assert counts[0] == 0 and max(counts) == 2
        assert client.upload_uint(0x2003, 0) == 2 and client.upload_uint(0x2006, 0) == 0
    items = app.items()
    assert [i.outcome for i in items] == ["placed", "placed"]


def test_demo_cli_plc_node(tmp_path, capsys):
    assert cmd_demo.main(["-q", "--no-plot", "--items", "1", "--plc-node",
                          "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "items placed 1, missed 0, of 1" in out
    assert "plc node: id 1, SDO server 0x601/0x581, TPDOs sent 0x181 x" in out
    import can
    msgs = [m for m in can.CanutilsLogReader(str(tmp_path / "bus.log"))
            if m.arbitration_id == 0x181]
    dec = _decode(_pdo_decoder(), bytes(msgs[-1].data))
    assert dec["Item count"] == 1 and dec["Tracker state"] == TrackState.OFF


def test_tpdo_remap_over_sdo_follows_cia301(rig):
    cfg, world, ctl, plc, client, seen = rig
    _step(ctl, 10)
    with pytest.raises(SdoAbortError) as e:
        client.download(0x1A00, 0, b"\x00")  # the PDO is valid: no mapping change
    assert e.value.code == 0x06040043
    cob = client.upload_uint(0x1800, 1)
    assert cob == 0x180 + NODE
    client.download(0x1800, 1, struct.pack("<I", cob | 0x80000000))  # disable TPDO1
    client.download(0x1A00, 0, b"\x00")
    with pytest.raises(SdoAbortError) as e:
        client.download(0x1A00, 1, struct.pack("<I", 0x20100120))  # 2010h: not mappable
    assert e.value.code == 0x06040041
    client.download(0x1A00, 1, struct.pack("<I", 0x20030020))  # 2003h item count only
    client.download(0x1A00, 0, b"\x01")
    ctl.step()
    n_off = len(world.recorder.frames)
    _step(ctl, 60)  # disabled: nothing on 181h even after the event timer
    assert not [f for f in world.recorder.frames[n_off:] if f[1] == cob]
    client.download(0x1800, 1, struct.pack("<I", cob))
    client.download(0x2004, 0, b"\x01")
    _step(ctl, 3)
    frames = [d for _, cid, d in world.recorder.frames if cid == cob]
    assert frames[-1] == struct.pack("<I", 1)


@contextmanager
def _plc_demo(record: bool = False, **demo_changes):
    """The demo (PickPlace on the demo bus.yml, photo-eye items) with the PLC node and an SDO
    client of the PLC, booted and started -> (world, ctl, app, client)."""
    cfg = load_config(cmd_demo.DEFAULT_CONFIG)
    app = PickPlace(replace(cfg.demo, **demo_changes))
    with SimWorld(cfg, record=record) as world:
        ctl = Controller(cfg, world.transport, app)
        _plc(ctl, world.world, app)
        client = SdoClient(SteppedTransport(world.world), cfg.master.node_id, "plc",
                           timeout_s=0.01)
        ctl.boot()
        ctl.start()
        app.eye = PhotoEye(world.device(cfg.tracking.conveyor.node).profile, app.demo,
                           world.clock.now_ns() * 1e-9)
        yield world, ctl, app, client


def _run_demo(ctl, app, max_cycles: int, each_cycle) -> None:
    """Step the demo until it is done (or ``max_cycles``), calling ``each_cycle()`` after every
    running cycle."""
    while ctl.k < max_cycles:
        ctl.step()
        if ctl.phase is Phase.ENABLING:
            continue
        if ctl.source_done:
            break
        each_cycle()


def test_demo_items_missed(tmp_path):
    """Two items at nearly the same place (the PLC reports one right after the photo-eye's):
    the second leaves the window while the first is picked and placed (a long place dwell
    keeps the robot busy): 2006h counts it and TPDO3 reports it."""
    with _plc_demo(record=True, items=1, place_dwell_s=2.0) as (world, ctl, app, client):
        triggered = []

        def trigger_after_the_photo_eye():
            if not triggered and app.eye.detected == 1:
                triggered.append(ctl.k)
                client.download(0x2004, 0, b"\x01")
        _run_demo(ctl, app, 4000, trigger_after_the_photo_eye)
        assert triggered
        missed = [i for i in app.items() if i.outcome == "missed"]
        assert len(missed) >= 1
        assert client.upload_uint(0x2006, 0) == len(missed)
        assert client.upload_uint(0x2003, 0) == 2
        tp3 = [d for _, cid, d in world.recorder.frames if cid == 0x381]
        assert struct.unpack("<I", tp3[-1])[0] == len(missed)


def test_synchronous_tpdo(rig):
    cfg, world, ctl, plc, client, seen = rig
    _step(ctl, 5)
    client.download(0x1801, 2, b"\x02")  # TPDO2: every 2nd SYNC
    ctl.step()
    n0 = len(world.recorder.frames)
    _step(ctl, 20)
    frames = world.recorder.frames[n0:]
    syncs = [i for i, f in enumerate(frames) if f[1] == 0x80]
    tp2 = [i for i, f in enumerate(frames) if f[1] == 0x280 + NODE]
    assert len(syncs) == 20 and len(tp2) == 10


def test_demo_plc_disengage_misses_the_item(tmp_path):
    """The PLC disengages while the demo follows an item: that item is missed (de-synced),
    the next one is caught and placed."""
    from controller.canopen.apps.demo import Step
    with _plc_demo(items=2) as (world, ctl, app, client):
        sent = []

        def disengage_while_following():
            if not sent and app.stage is Step.FOLLOW:
                sent.append(ctl.k)
                client.download(0x2005, 0, b"\x00")
        _run_demo(ctl, app, 6000, disengage_while_following)
        assert sent
        assert client.upload_uint(0x2006, 0) == 1
    assert [i.outcome for i in app.items()] == ["missed", "placed"]
