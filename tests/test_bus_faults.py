"""Bus faults that cantrack did not make: frames, commands and devices of other actors.

Each test runs the controller in stepped time against the simulated devices and injects the
fault through an *intruder*: one more participant of the stepped bus that sends frames the
controller did not produce (another master, a broken device, a second SYNC producer).
"""

from __future__ import annotations

import random

import can
import pytest

from controller.canopen.config import load_config
from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.protocol.cia402 import State
from controller.canopen.testing import bus_yml, load, stepped

OFFSET = (420.0, 30.0, 0.0)
T_FAULT = 0.5  # s: tracking (SYNCED) by then
ENCODER_TPDO, X_TPDO = 0x18A, 0x18B
DRIVES = ("x", "y")


class Intruder:
    """A participant of a stepped world that only sends (another actor on the bus)."""

    def __init__(self, world) -> None:
        self.world = world.world
        self.clock = world.clock
        self.bus = self.world.new_bus()
        self.world.add(self)

    def send(self, can_id: int, data: bytes) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False,
                                  timestamp=self.clock.stamp()))

    def handle(self, msg) -> None:
        pass

    def next_timer_ns(self) -> int | None:
        return None

    def on_timer(self, now_ns: int) -> None:
        pass


@pytest.fixture
def make(booted_follow):
    """(world, controller, intruder): ``booted_follow``'s bus with an intruder on it."""
    def _make(text: str | None = None, end_cycle: int = 600, **kw):
        world, ctl = booted_follow(text, end_cycle, **kw)
        return world, ctl, Intruder(world)
    return _make


def enabled(world) -> list[str]:
    return [n for n in DRIVES if world.device(n).state is State.OPERATION_ENABLED]


# ---------------------------------------------------------------------------------------------
# the faults of issue 11's first list, as they are today (each flips when it is fixed)

ISSUE = "issue 11: "


def test_short_frame_on_the_encoder_tpdo_is_dropped_and_counted(make):
    """18Ah#0102 (2 of 4 bytes) while tracking: not processed (CiA 301), counted, one event;
    the cycle goes on (the sample of that cycle is missing, like a lost frame)."""
    world, ctl, intruder = make()
    world.at(T_FAULT, lambda: intruder.send(ENCODER_TPDO, b"\x01\x02"))
    ctl.run(max_cycles=2000)
    bad = ctl.events.of_kind("bad_frame")
    assert len(bad) == 1 and bad[0].detail.startswith("18Ah (TPDO1 of node 10 (encoder)) "
                                                      "with 2 bytes [01 02]: shorter")
    assert "EMCY 8210h" in bad[0].detail and bad[0].reaction == "reported"
    assert ctl.hygiene.counts == {ENCODER_TPDO: 1}
    assert not [e for e in ctl.events if e.reaction.startswith("quick stop")]
    # the run ends normally (drives disabled), exit 3: never 0 after a fault
    assert ctl.exit_code() == 3 and ctl.phase.value == "stopped"


def test_long_pdo_is_used_and_counted(make):
    """A TPDO longer than its mapping: the first bytes are used (CiA 301), counted."""
    world, ctl, intruder = make()
    world.at(T_FAULT, lambda: intruder.send(X_TPDO, bytes(8)))
    ctl.run(max_cycles=2000)
    (bad,) = ctl.events.of_kind("bad_frame")
    assert "longer than expected" in bad.detail and "8220h" in bad.detail
    assert ctl.hygiene.counts == {X_TPDO: 1}


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_frames_on_consumed_cob_ids_never_crash(make, seed):
    """200 random frames (random COB-ID of the controller's, 0-8 random bytes): no
    exception; bad ones counted; the drives end stopped (a foreign NMT/SYNC among them
    stops them as configured), never enabled; the exit code is not 0 after a reaction."""
    world, ctl, intruder = make()
    rng = random.Random(seed)
    ids = [ENCODER_TPDO, X_TPDO, 0x18C, 0x8A, 0x8B, 0x70A, 0x70B, 0x000, 0x080]
    for i in range(200):
        t = T_FAULT + i * 0.0013
        cob = rng.choice(ids)
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        world.at(t, lambda c=cob, d=data: intruder.send(c, d))
    ctl.run(max_cycles=3000)
    assert not enabled(world)
    assert ctl.hygiene.total > 0 and ctl.events.of_kind("bad_frame")
    assert not ctl.events.of_kind("internal_error")
    reacted = [e for e in ctl.events if e.reaction.startswith("quick stop")]
    assert reacted and ctl.exit_code() in (3, 4)


@pytest.mark.parametrize("command", [0x02, 0x80, 0x82])
def test_foreign_nmt_command_never_leaves_a_drive_enabled(make, command):
    """Another master's NMT stop / pre-operational / reset communication to all nodes: an
    event at once, the quick stop; the drives that ignore RPDOs now are escalated (NMT
    start + quick stop) and their stop confirmed by their statusword."""
    world, ctl, intruder = make()
    world.at(T_FAULT, lambda: intruder.send(0x000, bytes((command, 0))))
    ctl.run(max_cycles=3000)
    (ev,) = ctl.events.of_kind("foreign_nmt")
    assert ev.reaction == "quick stop of all drives" and ev.source == "another NMT master"
    assert f"({command:02X}h) to all nodes" in ev.detail
    assert not enabled(world), [world.device(n).state for n in DRIVES]
    assert all(s.confirmed_cycle is not None for s in ctl.stops), ctl.stops
    assert ctl.exit_code() == 3


def test_second_sync_producer_is_an_event(make):
    world, ctl, intruder = make()
    times = [T_FAULT + i * ctl.period_ns * 1e-9 + 0.0007 for i in range(20)]
    for t in times:
        world.at(t, lambda: intruder.send(0x080, b"\x05"))
    ctl.run(max_cycles=2000)
    sent = sum(1 for t in times if t * 1e9 <= ctl.clock.now_ns())
    (ev,) = ctl.events.of_kind("foreign_sync")
    assert ev.detail == "SYNC (080h) with counter 5 not sent by the controller"
    assert ev.reaction == "quick stop of all drives"
    assert ctl.actors.counts["foreign_sync"] == sent >= 2  # all counted, one event
    assert not enabled(world) and ctl.exit_code() == 3


def test_emcy_00xx_is_an_error_reset(make):
    """CiA 301: 00xxh is "error reset or no error" for every xx: named so, no reaction."""
    world, ctl, _ = make()
    world.at(T_FAULT, lambda: world.device("x").send_emcy(0x0010))
    ctl.run(max_cycles=2000)
    (ev,) = ctl.events.of_kind("emcy")
    assert "EMCY 0010h (error reset or no error (0010h))" in ev.detail and not ev.reaction
    assert ctl.exit_code() == 0


def test_emcy_texts_of_cia301_and_cia402():
    from controller.canopen.master.supervision import Emcy
    from controller.canopen.protocol.emcy_codes import describe
    e = Emcy("node 4 (io)", 4, 0x8240, 0x11, b"\0" * 5, 0)
    assert str(e) == "EMCY 8240h (unexpected SYNC data length), error register 11h"
    assert describe(0x8611, 402) == "following error"
    assert describe(0x8611) == "protocol error - generic (device specific 8611h)" or \
        describe(0x8611).startswith("monitoring")
    assert describe(0x5000) == "device hardware - generic error"
    assert describe(0x2315, 402) == "continuous over-current (device specific 2315h)"
    assert describe(0xFF42) == "device specific - generic error (device specific FF42h)"


@pytest.mark.parametrize("request_bytes", [b"\x40\x18", b"", b"\x40\x18\x10\x01\x00"])
def test_short_sdo_request_to_a_simulated_device_is_aborted(make, caplog, request_bytes):
    """CiA 301: an SDO frame has 8 bytes; a shorter one gets abort 05040001h (command
    specifier not valid) with what index/sub-index bytes there are; no traceback."""
    _world, ctl, intruder = make()
    answers = []
    ctl.transport.subscribe(0x58B, lambda c, d, t: answers.append(d))
    intruder.send(0x60B, request_bytes)
    ctl.transport.run_until(ctl.clock.now_ns() + 10_000_000)
    assert not [r for r in caplog.records if r.exc_info]
    head = request_bytes[1:4].ljust(3, b"\0")
    assert answers == [b"\x80" + head + bytes.fromhex("01000405")]


def test_bus_log_channel_name_fits_canplayer(tmp_path):
    """The candump log of a simulated bus names a 15-character-safe interface, vcan0."""
    from controller.canopen.slave.world import LOG_CHANNEL, SimWorld
    cfg = load(tmp_path)
    log = tmp_path / "bus.log"
    with SimWorld(cfg, bus_log=log) as world:
        world.transport.send(0x000, b"\x81\x00")
        world.transport.run_until(1_000_000)
    names = {line.split()[1] for line in log.read_text().splitlines()}
    assert names == {LOG_CHANNEL} == {"vcan0"}


def _pdo_text(extra: str, kind: str = "rpdo") -> str:
    from controller.canopen.testing import bus_yml_text
    return bus_yml_text().replace(f"  {kind}:\n    1:\n      enabled: true\n",
                                  f"  {kind}:\n    1:\n      enabled: true\n{extra}", 1)


def test_event_deadline_is_applied(tmp_path):
    """RPDO event_deadline -> 1400h:05 (the drive's deadline monitoring) in the boot."""
    from controller.canopen.config.concise import concise_configuration
    cfg = load_config(bus_yml(tmp_path, text=_pdo_text("      event_deadline: 20\n")))
    writes = [(w.index, w.sub_index, w.value) for w in concise_configuration(cfg)["x"].sdos]
    assert (0x1400, 5, 20) in writes
    assert writes.index((0x1400, 5, 20)) < writes.index((0x1400, 1, 0x20B))  # before enable


def test_event_deadline_on_a_tpdo_is_refused(tmp_path):
    from controller.errors import ConfigError
    with pytest.raises(ConfigError, match=r"bus.yml:\d+, key 'encoder.tpdo.1.event_deadline':"
                                          r" is an RPDO setting"):
        load_config(bus_yml(tmp_path, text=_pdo_text("      event_deadline: 20\n",
                                                         "tpdo")))


@pytest.mark.parametrize("cob, why", [
    (0x080, "is the SYNC COB-ID"),
    (0x70B, "restricted CAN-ID"), (0x58B, "restricted CAN-ID"), (0x60B, "restricted CAN-ID"),
    (0x001, "restricted CAN-ID"), (0x6E5, "restricted CAN-ID"), (0x7E5, "restricted CAN-ID"),
    (0x181, "default TPDO1 COB-ID of the master"), (0x081, "default EMCY COB-ID of the master"),
    (0x201, "default RPDO1 COB-ID of the master"), (0x08C, "default EMCY COB-ID of node 12"),
    (0x28C, "default TPDO2 COB-ID of node 12"), (0x50A, "default RPDO4 COB-ID of node 10")])
def test_restricted_or_foreign_cob_id_is_refused(tmp_path, cob, why):
    """CiA 301's restricted CAN-IDs and the predefined-set IDs of the *other* nodes on the
    bus (the master included) are refused with file, line and key."""
    from controller.errors import ConfigError
    with pytest.raises(ConfigError, match=rf"bus.yml:\d+, key 'x.rpdo.1.cob_id': COB-ID "
                                          rf"0x{cob:03X} of x RPDO 1 .*{why}"):
        load_config(bus_yml(tmp_path, text=_pdo_text(f"      cob_id: 0x{cob:03X}\n")))


@pytest.mark.parametrize("cob", [0x20B, 0x2F0, 0x680, 0x1F0, 0x18F])
def test_own_or_free_cob_ids_are_accepted(tmp_path, cob):
    """The node's own predefined IDs and IDs of node-IDs nobody on the bus has."""
    cfg = load_config(bus_yml(tmp_path, text=_pdo_text(f"      cob_id: 0x{cob:03X}\n")))
    assert cfg.slaves["x"].rpdo[1].cob_id == cob


def test_1019h_written_to_every_sync_consumer(tmp_path):
    """1019h = sync_overflow to every slave that consumes SYNC and has 1019h (cantrack's own
    write: dcfgen's concise DCF has none); our simulated devices then check the counter."""
    from controller.canopen.master.boot import cantrack_sdos
    cfg = load(tmp_path)
    for name in ("encoder", "x", "y"):
        writes = {(w.index, w.sub_index): w.value for w in cantrack_sdos(cfg, name)}
        assert writes.get((0x1019, 0)) == 16, (name, writes)


def test_a_sync_consumer_with_a_wrong_1019h_sends_8240h(make):
    """A drive whose 1019h does not match the SYNC (here: set back to 0 by SDO while
    running): EMCY 8240h, pre-operational (as CANopenNode): the controller stops."""
    world, ctl, intruder = make()
    world.at(T_FAULT, lambda: intruder.send(0x60B, bytes.fromhex("2F19100000000000")))
    ctl.run(max_cycles=2000)
    first = [e for e in ctl.events if e.reaction.startswith("quick stop")][0]
    assert (first.kind, first.source) == ("emcy", "node 11 (x)")
    assert "EMCY 8240h (unexpected SYNC data length)" in first.detail
    assert not enabled(world) and ctl.exit_code() in (3, 4)


def test_boot_error_names_the_emcy_sent_before_refusing_start(tmp_path):
    """A node that refuses NMT start after an EMCY (CANopenNode without storage: 5000h)."""
    from controller.canopen.master.boot import BootError
    cfg = load(tmp_path)
    world, ctl = stepped(cfg)
    with world:
        world.device("y").refuse_start = 0x5000
        with pytest.raises(BootError, match=r"node 12 \(y\): NMT start not confirmed: its "
                           r"heartbeat shows state 7Fh .*; during the boot the node sent EMCY "
                           r"5000h \(device hardware - generic error\)"):
            ctl.boot()
        assert [e.kind for e in ctl.events if e.source == "node 12 (y)"][-1] == "emcy"


# ---------------------------------------------------------------------------------------------
# the last line of defence: an unexpected exception inside the cycle

class _Boom(ConveyorFollow):
    """The source raises in cycle ``at`` (a bug injected into the cycle)."""

    def __init__(self, at: int, times: int = 1) -> None:
        super().__init__(10, None, OFFSET, end_cycle=600)
        self.at, self.times = at, times

    def step(self, ctx):
        if ctx.cycle >= self.at and self.times > 0:
            self.times -= 1
            raise ZeroDivisionError("injected")
        return super().step(ctx)


def test_unexpected_exception_in_the_cycle_stops_the_drives_and_fails(tmp_path):
    from controller.canopen.master.cycle import CycleError
    cfg = load(tmp_path)
    world, ctl = stepped(cfg, _Boom(at=200))
    with world:
        ctl.boot()
        with pytest.raises(CycleError, match=r"internal error in cycle \d+: ZeroDivisionError"
                                             r": injected \(test_bus_faults.py:\d+ in step\)"):
            ctl.run(max_cycles=2000)
        (ev,) = ctl.events.of_kind("internal_error")
        assert ev.reaction == "quick stop of all drives"
        assert not enabled(world)
        assert all(s.confirmed_cycle is not None for s in ctl.stops)
        assert ctl.exit_code() == 2


def test_exceptions_in_every_cycle_end_in_the_emergency_stop(tmp_path):
    """The cycle code keeps failing: after 3 cycles the emergency stop (quick stop + NMT
    stop without the cycle code), the run ends, drives not enabled."""
    from controller.canopen.master.cycle import CycleError, Phase
    cfg = load(tmp_path)
    world, ctl = stepped(cfg, _Boom(at=200))
    with world:
        ctl.boot()
        ctl._stop_step = lambda k: 1 / 0  # the stop code itself broken
        with pytest.raises(CycleError):
            ctl.run(max_cycles=2000)
        kinds = [e.kind for e in ctl.events if e.kind == "internal_error"]
        assert len(kinds) == 3 and ctl.phase is Phase.STOPPED
        assert "emergency stop" in ctl.events.of_kind("internal_error")[-1].reaction
        world.world.run_until(ctl.clock.now_ns() + 200_000_000)  # the drives react
        assert not enabled(world)


def test_exception_in_a_receive_callback_is_caught_and_stops(make):
    world, ctl, intruder = make()
    x = ctl.axes[0]

    def broken(can_id, data, t_ns):
        raise KeyError("injected in a callback")
    ctl.transport.subscribe(0x123, broken)
    world.at(T_FAULT, lambda: intruder.send(0x123, b"\x01"))
    from controller.canopen.master.cycle import CycleError
    with pytest.raises(CycleError, match="KeyError"):
        ctl.run(max_cycles=2000)
    (ev,) = ctl.events.of_kind("internal_error")
    assert "123h [01]" in ev.detail and ev.reaction == "quick stop of all drives"
    assert not enabled(world) and x.input is not None


_RUN_WITH_BUG = """
import sys
from controller.canopen.io.clock import RealtimeClock
from controller.canopen.config import load_config
from controller.canopen.apps import follow
from controller.canopen.slave.rack import DeviceRack
from controller.canopen.io.transport import DeviceThread, virtual_bus
from controller.cli import run as cmd_run
cfg = load_config(sys.argv[1])
clock = RealtimeClock()
rack = DeviceRack.from_config(cfg, virtual_bus("bug"), clock)
th = DeviceThread(rack, clock).start()
real = follow.ConveyorFollow.step
def step(self, ctx):
    if ctx.cycle == self.start_cycle + 20:
        raise ZeroDivisionError("injected")
    return real(self, ctx)
follow.ConveyorFollow.step = step
try:
    rc = cmd_run.main([sys.argv[1], "-i", "virtual", "-c", "bug", "-q", "--duration", "3",
                       "--report", sys.argv[2], "--cpu-latency", "0"])
except Exception as exc:  # the CLI turns a CantrackError into exit 2 and one line
    print(f"cantrack: error: {exc}", file=sys.stderr)
    rc = 2
th.stop()
states = {n: d.state.value for n, d in rack.devices.items() if hasattr(d, "inject_fault")}
print("STATES", states)
sys.exit(rc)
"""


def test_run_with_an_injected_exception_writes_the_report_and_exits_2(tmp_path):
    """``cantrack run`` (real time, virtual bus, the devices in a thread): an exception in the
    cycle -> the controlled stop, the report with each drive's final state, exit 2."""
    import json
    import subprocess
    import sys
    from pathlib import Path
    cfg = Path(__file__).resolve().parents[1] / "examples" / "bus" / "vcan.yml"
    report = tmp_path / "run.json"
    r = subprocess.run([sys.executable, "-c", _RUN_WITH_BUG, str(cfg), str(report)],
                       capture_output=True, text=True, timeout=300, check=False)
    assert r.returncode == 2, r.stderr[-3000:]
    assert "internal error in cycle" in r.stderr and "Traceback" not in r.stderr, r.stderr
    rep = json.loads(report.read_text())
    assert rep["exit_code"] == 2 and rep["end"] == "error"
    assert "ZeroDivisionError: injected" in rep["error"]
    assert [e["kind"] for e in rep["events"] if e["reaction"]][:1] == ["internal_error"]
    assert {d["drive"]: d["confirmed"] for d in rep["drives"]} == {"node 11 (x)": True,
                                                                  "node 12 (y)": True}
    assert all(d["state"] != "operation enabled" for d in rep["drives"])
    assert "'operation enabled'" not in r.stdout.split("STATES", 1)[1]
    # what the run had of the real-time settings, as the kernel says: the CPU latency request
    # held (as root, where the PM QoS device is) or a warning saying why not
    import os
    rt = rep["realtime"]
    assert rt["policy"] == "SCHED_OTHER" and rt["cpus"] == sorted(os.sched_getaffinity(0))
    if os.access("/dev/cpu_dma_latency", os.W_OK):
        assert rt["cpu_latency_us"] == {"requested": 0, "effective": 0}, rt
    else:
        assert rt["cpu_latency_us"] is None and "--cpu-latency 0: /dev/cpu_dma_latency" in r.stderr
