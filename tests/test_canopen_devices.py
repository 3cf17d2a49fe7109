"""The simulated devices behave like real ones (raw frames from a minimal test master).

Stepped time on a python-can virtual bus; the devices are canopen LocalNodes built from the
EDS files.  A controller that skips a 402 step, or enables with a stale 607Ah, fails.
"""

from __future__ import annotations

import struct

import pytest

from controller.canopen.protocol import cia402
from controller.canopen.protocol.cia402 import State
from controller.canopen.protocol.sdo import SdoAbortError, SdoClient
from controller.canopen.slave.world import SimWorld
from controller.canopen.testing import load

MS = 1_000_000


class RawMaster:
    """A test master: raw NMT/SYNC/RPDO frames and an SDO client, frames recorded."""

    def __init__(self, world: SimWorld) -> None:
        self.world = world
        self.t = world.transport
        self.frames: list[tuple[int, int, bytes]] = []
        for cob in list(range(0x080, 0x100)) + list(range(0x180, 0x500)) + \
                list(range(0x700, 0x780)):
            self.t.subscribe(cob, self._rec)

    def _rec(self, can_id: int, data: bytes, t_ns: int) -> None:
        self.frames.append((t_ns, can_id, data))

    def sdo(self, node_id: int) -> SdoClient:
        return SdoClient(self.t, node_id, f"node {node_id}", 0.05)

    def nmt(self, cmd: int, node: int = 0) -> None:
        self.t.send(0, bytes((cmd, node)))
        self.run(0)

    def run(self, ms: float) -> None:
        self.t.run_until(self.t.clock.now_ns() + int(ms * MS))

    def sync(self, rpdos: dict[int, bytes] | None = None, period_ms: float = 2.0) -> None:
        """Send SYNC (without counter: the devices' 1019h is 0 as in their EDS, CiA 301),
        then the RPDOs (applied at the next SYNC), then wait one period."""
        self.t.send(0x80, b"")
        self.run(0)
        for cob, data in (rpdos or {}).items():
            self.t.send(cob, data)
        self.run(period_ms)

    def of(self, cob: int) -> list[bytes]:
        return [d for _, c, d in self.frames if c == cob]


@pytest.fixture
def bus(tmp_path):
    cfg = load(tmp_path)
    world = SimWorld(cfg)
    master = RawMaster(world)
    master.run(10)  # power-on boot-up at 5 ms
    yield world, master
    world.close()


def rpdo(cw: int, target: int) -> bytes:
    return struct.pack("<Hi", cw, target)


def configure_csp(m: RawMaster, node: int = 11) -> None:
    sdo = m.sdo(node)
    sdo.download(0x60C2, 1, b"\x02")
    sdo.download(0x60C2, 2, struct.pack("<b", -3))
    sdo.download(0x6060, 0, b"\x08")


def enable(m: RawMaster, cob: int, target: int, sequence=(0x06, 0x07, 0x0F)) -> None:
    for cw in sequence:
        m.sync({cob: rpdo(cw, target)})
    m.sync({cob: rpdo(sequence[-1], target)})


def enabled_x(world, m: RawMaster, target: int):
    """Drive x (node 11) in CSP, NMT started and enabled at ``target`` [counts]: the
    drive."""
    configure_csp(m)
    m.nmt(0x01, 11)
    enable(m, 0x20B, target)
    return world.device("x")


def test_a_drive_keeps_its_last_1000_transitions_and_emcys(bus):
    """Issue 12 (``cantrack sim-devices`` runs as long as the plant): a drive disabled and
    enabled again 400 times (1203 CiA 402 transitions) and 1100 EMCYs sent keep the newest
    1000 of each, in order."""
    world, m = bus
    drive = enabled_x(world, m, 0)
    for _ in range(400):
        for cw in (0x06, 0x07, 0x0F):  # shutdown (8), switch on (3), enable operation (4)
            m.sync({0x20B: rpdo(cw, 0)})
    m.sync({0x20B: rpdo(0x0F, 0)})  # (an RPDO acts at the next SYNC)
    assert drive.state is State.OPERATION_ENABLED
    numbers = [n for n, _, _ in drive.transitions]
    assert len(numbers) == 1000 and numbers[-6:] == [8, 3, 4, 8, 3, 4]
    for i in range(1100):
        drive.send_emcy(0x5000 + i)
    assert len(drive.emcy_sent) == 1000
    assert [c for c, _ in drive.emcy_sent] == [0x5000 + i for i in range(100, 1100)]


def test_boot_up_heartbeat_and_nmt(bus):
    world, m = bus
    assert list(m.of(0x70B)) == [b"\x00"]  # boot-up of node 11 after power-on
    m.sdo(11).download(0x1017, 0, struct.pack("<H", 20))
    m.run(100)
    hb = m.of(0x70B)[1:]
    assert len(hb) == 5 and set(hb) == {bytes((127,))}  # pre-operational every 20 ms
    m.nmt(0x01, 11)
    m.run(20)
    assert m.of(0x70B)[-1] == bytes((5,))
    world.device("x").stop_heartbeat()
    n = len(m.of(0x70B))
    m.run(100)
    assert len(m.of(0x70B)) == n


def test_reset_node_restores_defaults_and_sends_boot_up(bus):
    world, m = bus
    sdo = m.sdo(11)
    sdo.download(0x6065, 0, struct.pack("<I", 1234))
    assert sdo.upload_uint(0x6065, 0) == 1234
    m.nmt(0x81, 11)
    m.run(10)
    assert m.of(0x70B)[-1] == b"\x00"
    assert sdo.upload_uint(0x6065, 0) == 0x00020000  # EDS default
    assert world.device("x").state is State.SWITCH_ON_DISABLED


def test_pdo_mapping_follows_cia301(bus):
    world, m = bus
    sdo = m.sdo(11)
    with pytest.raises(SdoAbortError, match="06040043"):  # mapping while the PDO is valid
        sdo.download(0x1A00, 1, struct.pack("<I", 0x60640020))
    sdo.download(0x1800, 1, struct.pack("<I", 0x8000018B))
    with pytest.raises(SdoAbortError, match="06040043"):  # sub0 must be 0 first
        sdo.download(0x1A00, 1, struct.pack("<I", 0x60640020))
    sdo.download(0x1A00, 0, b"\x00")
    with pytest.raises(SdoAbortError, match="06040041"):  # 6065h is not mappable
        sdo.download(0x1A00, 1, struct.pack("<I", 0x60650020))
    sdo.download(0x1A00, 1, struct.pack("<I", 0x60640020))
    sdo.download(0x1A00, 0, b"\x01")
    sdo.download(0x1800, 1, struct.pack("<I", 0x18B))
    m.nmt(0x01, 11)
    m.sync()
    assert m.of(0x18B) == [struct.pack("<i", 4_000_000)]  # 6064h only


def test_rpdo_mapping_refuses_a_read_only_object(bus):
    """CiA 301: an RPDO writes the objects it maps, so a read-only one (6064h, position
    actual value, PDOMapping=1) is refused with 0604 0041h; a writable one (607Ah) is taken."""
    world, m = bus
    sdo = m.sdo(11)
    sdo.download(0x1400, 1, struct.pack("<I", 0x8000020B))  # RPDO1 invalid, then sub0 = 0
    sdo.download(0x1600, 0, b"\x00")
    with pytest.raises(SdoAbortError, match="06040041"):
        sdo.download(0x1600, 1, struct.pack("<I", 0x60640020))
    sdo.download(0x1600, 1, struct.pack("<I", 0x607A0020))
    sdo.download(0x1600, 0, b"\x01")
    assert sdo.upload_uint(0x1600, 1) == 0x607A0020


def test_encoder_tpdo_on_sync_wraps_at_6002h(bus):
    world, m = bus
    enc = world.device("encoder")
    m.sync()
    assert m.of(0x18A) == []  # pre-operational: no PDO
    m.nmt(0x01, 10)
    m.sdo(10).download(0x6003, 0, struct.pack("<I", 16777216 - 100))  # preset near the wrap
    for _ in range(10):
        m.sync()
    values = [struct.unpack("<Ih", d)[0] for d in m.of(0x18A)]  # EDS default: 6004h + 6030h
    assert len(values) == 10
    # 300 mm/s * 40.96 counts/mm = 12288 counts/s = 24.6 counts per 2 ms
    steps = [(b - a) % 16777216 for a, b in zip(values, values[1:])]
    assert set(steps) <= {24, 25} and sum(steps) == pytest.approx(9 * 24.576, abs=1)
    assert values[0] >= 16777216 - 100 and values[-1] < 200  # wrapped at 6002h
    speed = struct.unpack("<Ih", m.of(0x18A)[-1])[1]
    assert speed == round(300 * 40.96)
    enc.mute_pdos(True)
    m.sync()
    assert len(m.of(0x18A)) == 10
    enc.noise_counts = 5.0
    enc.mute_pdos(False)
    m.sync()
    assert len(m.of(0x18A)) == 11


def _late_sync(world, m, late_ns: int, syncs_ns: tuple[int, ...] = (0,)) -> int:
    """SYNCs that were on the bus at t + each of ``syncs_ns`` (their message times), served
    together ``late_ns`` after t (what a device thread waiting for the interpreter does);
    returns t."""
    import can
    clock = world.clock
    t = clock.now_ns()
    clock.advance_to(t + late_ns)
    raw = world.world.new_bus()
    try:
        for dt in syncs_ns:
            raw.send(can.Message(arbitration_id=0x80, data=b"", is_extended_id=False,
                                 timestamp=(t + dt) * 1e-9))
    finally:
        raw.shutdown()
    m.run(0)
    return t


@pytest.mark.parametrize("window_us, sent", [(1000, False), (2000, True), (0, True)])
def test_a_sync_served_late_is_sampled_at_its_bus_time_and_kept_to_1007h(bus, window_us,
                                                                         sent):
    """With the port's frame time (the real-time device thread's), the encoder latches
    6004h at the SYNC's time on the bus, not when its host got to the frame; served after
    the synchronous window (1007h) it sends no synchronous TPDO (CiA 301; CANopenNode
    discards them): a late answer must not be taken for the next SYNC's."""
    world, m = bus
    enc = world.device("encoder")
    world.rack.port.frame_time = True
    m.nmt(0x01, 10)
    m.sdo(10).download(0x1007, 0, struct.pack("<I", window_us))
    m.sync()
    n = len(m.of(0x18A))
    t = _late_sync(world, m, 1_500_000)
    at_sync = enc.true_counts(t) % 16777216
    assert enc.true_counts(t + 1_500_000) - enc.true_counts(t) >= 18  # 1.5 ms: 18.4 counts
    assert enc.load(0x6004) == at_sync
    frames = m.of(0x18A)[n:]
    if sent:
        assert [struct.unpack("<Ih", d)[0] for d in frames] == [at_sync]
        assert enc.sync_tpdos_discarded == 0
    else:
        assert frames == [] and enc.sync_tpdos_discarded == 1
    # served at once, the next SYNC is answered (the window counts from each SYNC)
    m.sync()
    assert len(m.of(0x18A)) == n + len(frames) + 1


def test_a_sync_served_after_the_next_one_is_on_the_bus_is_not_answered(bus):
    """Two SYNCs 2 ms apart served together 0.3 ms after the second (no window: 1007h = 0):
    an answer to the first would follow the second SYNC on the bus, where a real device
    never puts it, and be taken for the second's; the first is left unanswered (counted),
    the second answered with the belt at its time."""
    world, m = bus
    enc = world.device("encoder")
    world.rack.port.frame_time = True
    m.nmt(0x01, 10)
    m.sync()
    n = len(m.of(0x18A))
    t = _late_sync(world, m, 2_300_000, (0, 2_000_000))
    assert [struct.unpack("<Ih", d)[0] for d in m.of(0x18A)[n:]] == \
        [enc.true_counts(t + 2_000_000) % 16777216]
    assert enc.sync_tpdos_discarded == 1 and enc.next_sync_ns is None


def test_without_frame_time_a_device_samples_when_it_serves_the_sync(bus):
    """The default port (stepped worlds, a device host on a real bus): the handling time."""
    world, m = bus
    enc = world.device("encoder")
    m.nmt(0x01, 10)
    m.sync()
    t = _late_sync(world, m, 1_500_000)
    assert enc.load(0x6004) == enc.true_counts(t + 1_500_000) % 16777216


def test_402_enable_sequence(bus):
    world, m = bus
    drive = enabled_x(world, m, 4_000_000)
    assert drive.state is State.OPERATION_ENABLED
    assert [n for n, _, _ in drive.transitions] == [1, 2, 3, 4]
    sw = struct.unpack("<Hi", m.of(0x18B)[-1])
    assert cia402.decode_statusword(sw[0]) is State.OPERATION_ENABLED
    assert sw[0] & cia402.SW_FOLLOWS_TARGET and not sw[0] & cia402.SW_FOLLOWING_ERROR
    assert sw[1] == 4_000_000
    # CSP: 607Ah is applied at the next SYNC, the servo reaches it one period later
    m.sync({0x20B: rpdo(0x0F, 4_001_000)})
    assert drive.demand == 4_000_000
    m.sync({0x20B: rpdo(0x0F, 4_001_000)})
    assert drive.demand == 4_001_000
    m.sync({0x20B: rpdo(0x0F, 4_001_000)})
    assert abs(drive.x - 4_001_000) < 20


@pytest.mark.parametrize("sequence", [(0x0F,), (0x07, 0x0F), (0x0F, 0x07)])
def test_skipping_a_402_step_fails(bus, sequence):
    """Without "shutdown" (transition 2) first, the drive stays SWITCH ON DISABLED."""
    world, m = bus
    configure_csp(m)
    m.nmt(0x01, 11)
    drive = world.device("x")
    for _ in range(5):
        enable(m, 0x20B, 4_000_000, sequence)
    assert drive.state is State.SWITCH_ON_DISABLED
    assert [n for n, _, _ in drive.transitions] == [1]


def test_switch_on_and_enable_in_one_command(bus):
    """From READY TO SWITCH ON, 0Fh is "switch on + enable operation" (3 and 4): allowed."""
    world, m = bus
    configure_csp(m)
    m.nmt(0x01, 11)
    enable(m, 0x20B, 4_000_000, (0x06, 0x0F))
    assert world.device("x").state is State.OPERATION_ENABLED


def test_enable_with_stale_target_faults_with_following_error(bus):
    world, m = bus
    configure_csp(m)
    m.nmt(0x01, 11)
    drive = world.device("x")
    # a controller that never set 607A = 6064: its old target (0) is 400 mm away
    enable(m, 0x20B, 0)
    for _ in range(10):
        m.sync({0x20B: rpdo(0x0F, 0)})
    assert drive.state is State.FAULT_REACTION_ACTIVE  # ramping down at 6085h
    for _ in range(1000):
        if drive.state is State.FAULT:
            break
        m.sync({0x20B: rpdo(0x0F, 0)})
    assert drive.state is State.FAULT
    assert drive.load(0x603F) == 0x8611
    emcy = m.of(0x8B)
    assert emcy and struct.unpack_from("<H", emcy[0])[0] == 0x8611
    bits = [struct.unpack("<Hi", d)[0] for d in m.of(0x18B)]
    assert any(b & cia402.SW_FOLLOWING_ERROR for b in bits)  # bit 13 before the fault


def test_quick_stop_ramps_then_switch_on_disabled(bus):
    world, m = bus
    drive = enabled_x(world, m, 4_000_000)
    target = 4_000_000
    for _ in range(50):  # move at 0.5 m/s (5000 counts per 2 ms)
        target += 5000
        m.sync({0x20B: rpdo(0x0F, target)})
    assert drive.v == pytest.approx(2.5e6, rel=1e-3)
    m.sync({0x20B: rpdo(0x02, target)})
    m.sync({0x20B: rpdo(0x02, target)})
    assert drive.state is State.QUICK_STOP_ACTIVE
    for _ in range(100):
        m.sync({0x20B: rpdo(0x02, target)})
    assert drive.state is State.SWITCH_ON_DISABLED
    assert [n for n, _, _ in drive.transitions][-2:] == [11, 12]
    # 6085h = 20971520 counts/s^2: 2.5e6 counts/s stops in 0.12 s over ~149000 counts
    assert drive.x - target == pytest.approx(2.5e6 ** 2 / (2 * 20971520), rel=0.05)


def test_fault_reset_needs_a_rising_edge(bus):
    world, m = bus
    drive = enabled_x(world, m, 4_000_000)
    m.sync({0x20B: rpdo(0x80, 4_000_000)})  # bit 7 already high when the fault comes
    m.sync({0x20B: rpdo(0x80, 4_000_000)})  # (an RPDO acts at the next SYNC)
    assert drive.state is State.OPERATION_ENABLED  # 80h alone is no 402 command
    drive.inject_fault(0x2310)
    for _ in range(10):
        m.sync({0x20B: rpdo(0x80, 4_000_000)})
    assert drive.state is State.FAULT
    m.sync({0x20B: rpdo(0x00, 4_000_000)})
    m.sync({0x20B: rpdo(0x80, 4_000_000)})
    m.sync({0x20B: rpdo(0x80, 4_000_000)})
    assert drive.state is State.SWITCH_ON_DISABLED
    codes = [struct.unpack_from("<H", d)[0] for d in m.of(0x8B)]
    assert codes == [0x2310, 0x0000]


def test_lost_controller_heartbeat_quick_stops(bus):
    world, m = bus
    configure_csp(m)
    m.sdo(11).download(0x1016, 1, struct.pack("<I", (1 << 16) | 30))
    m.nmt(0x01, 11)
    drive = world.device("x")
    for _ in range(4):
        m.t.send(0x701, b"\x05")
        enable(m, 0x20B, 4_000_000)
    assert drive.state is State.OPERATION_ENABLED
    for _ in range(30):  # no more controller heartbeats: 30 ms later 6007h = 3 acts
        m.sync({0x20B: rpdo(0x0F, 4_000_000)})
    assert drive.state in (State.QUICK_STOP_ACTIVE, State.SWITCH_ON_DISABLED)
    assert 0x8130 in [struct.unpack_from("<H", d)[0] for d in m.of(0x8B)]


def test_touch_probe_latches_position(bus):
    world, m = bus
    sdo = m.sdo(11)
    m.nmt(0x01, 11)
    drive = world.device("x")
    sdo.download(0x60B8, 0, struct.pack("<H", 0x0011))  # enable probe 1, positive edge
    assert sdo.upload_uint(0x60B9, 0) == 0x0001
    drive.x = 1_234_567.0
    drive.set_probe_input(True)
    assert sdo.upload_uint(0x60B9, 0) & 0x0003 == 0x0003
    assert sdo.upload_int(0x60BA, 0) == 1_234_567
    assert sdo.upload_uint(0x60FD, 0) & (1 << 17)
    m.run(2)
    assert m.of(0x28B)[-1] == struct.pack("<Hi", 0x0003, 1_234_567)  # TPDO2, on change
    drive.set_probe_input(False)
    drive.x = 2_000_000.0
    drive.set_probe_input(True)  # single shot: not latched again
    assert sdo.upload_int(0x60BA, 0) == 1_234_567


def _enabled_x_drive(tmp_path, **sim_changes):
    """The x drive (node 11) with these simulation parameters changed, configured for CSP,
    started and enabled at 4,000,000 counts -> (world, master, drive)."""
    from dataclasses import replace
    cfg = load(tmp_path)
    sim = cfg.simulation
    devices = dict(sim.devices)
    devices["x"] = replace(devices["x"], **sim_changes)
    object.__setattr__(cfg, "simulation", replace(sim, devices=devices))
    world = SimWorld(cfg)
    m = RawMaster(world)
    m.run(10)
    return world, m, enabled_x(world, m, 4_000_000)


def test_limit_switches_and_home_on_60fd(tmp_path):
    world, m, drive = _enabled_x_drive(tmp_path, positive_limit=4_010_000,
                                       home_switch=(3_990_000, 4_001_000))
    assert drive.load(0x60FD) == 1 << 2  # on the home switch
    for target in range(4_002_000, 4_030_000, 2000):
        m.sync({0x20B: rpdo(0x0F, target)})
    assert drive.load(0x60FD) == 1 << 1  # positive limit switch
    assert 4_010_000 <= drive.x < 4_013_000  # motion into the limit refused
    assert drive.statusword() & cia402.SW_INTERNAL_LIMIT
    assert drive.state is State.OPERATION_ENABLED  # no following-error fault
    world.close()


def test_unsupported_mode_is_refused(bus):
    world, m = bus
    with pytest.raises(SdoAbortError, match="06090030"):
        m.sdo(11).download(0x6060, 0, b"\x03")  # PV: 6502h has PP, HM and CSP only
    m.sdo(11).download(0x6060, 0, b"\x08")
    assert m.sdo(11).upload_int(0x6061, 0) == 8


@pytest.mark.parametrize("switch", [(4_003_333, 4_100_000),  # a wide switch: entered
                                    (4_003_333, 4_003_500)])  # passed within one step
def test_touch_probe_wired_to_home_switch_latches_the_exact_edge(tmp_path, switch):
    # probe_input: home: the probe input follows the home switch; the latch is where the
    # servo path crosses the switch edge within the step, not the position at the SYNC
    world, m, drive = _enabled_x_drive(tmp_path, home_switch=switch, probe_input="home")
    sdo = m.sdo(11)
    sdo.download(0x60B8, 0, struct.pack("<H", 0x0011))  # probe 1, single shot, positive edge
    assert sdo.upload_uint(0x60B9, 0) == 0x0001
    samples = []
    for target in range(4_002_000, 4_012_000, 2000):  # 2000 counts per SYNC
        m.sync({0x20B: rpdo(0x0F, target)})
        samples.append(drive.x)
    assert all(abs(x - switch[0]) > 100 for x in samples)  # no sample near the edge
    assert sdo.upload_uint(0x60B9, 0) & 0x0003 == 0x0003
    assert sdo.upload_int(0x60BA, 0) == switch[0]  # exact, not a sample position
    on = switch[0] <= drive.x <= switch[1]
    assert bool(drive.load(0x60FD) & (1 << 17)) == on == bool(drive.load(0x60FD) & (1 << 2))
    # back out and in again: single shot, the first latch stays
    for target in (3_990_000, 3_990_000, 4_010_000, 4_010_000):
        m.sync({0x20B: rpdo(0x0F, target)})
    assert sdo.upload_int(0x60BA, 0) == switch[0]
    world.close()


def test_probe_input_home_in_the_simulation_section(tmp_path):
    from controller.canopen.config import load_config
    from controller.canopen.testing import bus_yml_text
    from controller.errors import ConfigError
    text = bus_yml_text(("x",))
    assert "  x: {initial_counts: " in text
    p = tmp_path / "bus.yml"
    p.write_text(text.replace("  x: {initial_counts: ",
                              "  x: {home_switch: [0, 10], probe_input: home, initial_counts: "))
    assert load_config(p).simulation.devices["x"].probe_input == "home"
    p.write_text(text.replace("  x: {initial_counts: ", "  x: {probe_input: home, initial_counts: "))
    with pytest.raises(ConfigError, match="probe_input.*home_switch"):
        load_config(p)
    p.write_text(text.replace("  x: {initial_counts: ", "  x: {probe_input: homr, initial_counts: "))
    with pytest.raises(ConfigError, match=r"bus.yml:\d+.*probe_input.*did you mean"):
        load_config(p)


def test_cached_timers_follow_every_change(bus):
    """The devices' next timer is cached (the rack asks after every frame batch): after
    fault injection, SDO writes, NMT commands and SYNCs it is what it computes afresh."""
    world, m = bus
    rack = world.rack

    def check():
        fresh = {n: d._next_timer() for n, d in rack.devices.items()}
        assert {n: d.next_timer_ns() for n, d in rack.devices.items()} == fresh
        due = [t for t in fresh.values() if t is not None]
        assert rack.next_timer_ns() == (min(due) if due else None)

    drive = enabled_x(world, m, 4_000_000)
    check()
    m.sdo(11).download(0x1017, 0, struct.pack("<H", 40))  # heartbeat time
    check()
    m.sdo(11).download(0x1802, 5, struct.pack("<H", 5))  # TPDO3's event timer: first
    check()
    m.sync({0x20B: rpdo(0x0F, 4_000_000)})  # (the PDOs read again at the SYNC)
    check()
    drive.mute_pdos(True)
    check()
    drive.pdos_muted = False
    check()
    drive.silent = True
    check()
    drive.silence(False)
    m.sync({0x20B: rpdo(0x0F, 4_000_000)})
    check()
    m.sdo(11).download(0x1802, 5, struct.pack("<H", 0))  # (no event timer: quiet)
    target = 4_000_000
    for _ in range(20):  # moving at 0.5 m/s: the fault reaction ramps down from there
        target += 5000
        m.sync({0x20B: rpdo(0x0F, target)})
    drive.inject_fault(0x2310)  # the fault reaction's ramp runs on the drive's timer
    check()
    for _ in range(3):  # SYNCs step the ramp: its timer (2 periods) from each step
        m.sync({0x20B: rpdo(0x0F, target)}, period_ms=1.0)
        assert drive.state is State.FAULT_REACTION_ACTIVE
        check()
    for _ in range(3):
        m.run(3)
        check()
    drive.power_off()
    check()
    drive.powered = True
    m.nmt(0x02, 11)
    check()
    m.nmt(0x82, 11)  # reset communication: boot-up after the boot delay
    check()
    m.run(10)
    check()


def test_a_drive_publishes_its_model_again_over_any_other_write(bus):
    """The drive packs a published value (6041h, 6064h, ...) only when it changed; an object
    written by someone else (the application's store, a reset) still gets the model's value
    at the next SYNC."""
    world, m = bus
    drive = enabled_x(world, m, 4_000_000)
    m.sync({0x20B: rpdo(0x0F, 4_000_000)})
    x = round(drive.x)
    assert drive.load(0x6064) == x
    drive.store(0x6064, 0, x + 12345)
    drive.store(0x60F4, 0, 777)
    m.sync({0x20B: rpdo(0x0F, 4_000_000)})
    assert drive.load(0x6064) == round(drive.x) == x and drive.load(0x60F4) == 0
    assert m.of(0x18B)[-1][2:6] == struct.pack("<i", x)  # (TPDO1: 6041h, 6064h)
    m.nmt(0x81, 11)  # reset node: every object to its default, then the model again
    assert drive.load(0x6064) == x
