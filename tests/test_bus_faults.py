"""Bus faults that cantrack did not make: frames, commands and devices of other actors.

Each test runs the controller in stepped time against the simulated devices and injects the
fault through an *intruder*: one more participant of the stepped bus that sends frames the
controller did not produce (another master, a broken device, a second SYNC producer).
"""

from __future__ import annotations

import random

import can
import pytest

from controller.canopen.master.app import ConveyorFollow
from controller.canopen.protocol.cia402 import State
from controller.canopen.config import load_bus_config
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
def make(tmp_path):
    worlds = []

    def _make(text: str | None = None, end_cycle: int = 600, **kw):
        cfg = load_bus_config(bus_yml(tmp_path, text=text)) if text else load(tmp_path)
        app = ConveyorFollow(10, None, OFFSET, end_cycle=end_cycle)
        world, ctl = stepped(cfg, app, **kw)
        worlds.append(world)
        ctl.boot()
        return world, ctl, Intruder(world)
    yield _make
    for w in worlds:
        w.close()


def enabled(world) -> list[str]:
    return [n for n in DRIVES if world.device(n).state is State.OPERATION_ENABLED]


# ---------------------------------------------------------------------------------------------
# the faults of issue 11's first list, as they are today (each flips when it is fixed)

ISSUE = "issue 11: "


@pytest.mark.xfail(strict=True, raises=Exception, reason=ISSUE + "a short frame on a consumed "
                   "PDO COB-ID raises struct.error in the receive callback")
def test_short_frame_on_the_encoder_tpdo_is_dropped_and_counted(make):
    world, ctl, intruder = make()
    world.at(T_FAULT, lambda: intruder.send(ENCODER_TPDO, b"\x01\x02"))
    ctl.run(max_cycles=2000)
    bad = ctl.events.of_kind("bad_frame")
    assert len(bad) == 1 and "18Ah" in bad[0].detail


@pytest.mark.xfail(strict=True, raises=Exception, reason=ISSUE + "random frames on the "
                   "controller's COB-IDs crash it")
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_random_frames_on_consumed_cob_ids_never_crash(make, seed):
    world, ctl, intruder = make()
    rng = random.Random(seed)
    ids = [ENCODER_TPDO, X_TPDO, 0x18C, 0x8A, 0x8B, 0x70A, 0x70B, 0x000, 0x080]
    for i in range(200):
        t = T_FAULT + i * 0.0013
        cob = rng.choice(ids)
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(9)))
        world.at(t, lambda c=cob, d=data: intruder.send(c, d))
    ctl.run(max_cycles=2000)
    assert not enabled(world)


@pytest.mark.xfail(strict=True, reason=ISSUE + "the quick stop after a foreign NMT stop goes "
                   "out as RPDOs which stopped nodes ignore: the drives stay enabled")
@pytest.mark.parametrize("command", [0x02, 0x80, 0x82])
def test_foreign_nmt_command_never_leaves_a_drive_enabled(make, command):
    world, ctl, intruder = make()
    world.at(T_FAULT, lambda: intruder.send(0x000, bytes((command, 0))))
    ctl.STOP_CYCLES_MAX = 500
    from controller.errors import CantrackError
    try:
        ctl.run(max_cycles=3000)
    except CantrackError as exc:  # a controlled failure of the run (its message)
        ctl.events.add(ctl.k, 0.0, "test", "run_failed", str(exc))
    assert not enabled(world), [world.device(n).state for n in DRIVES]
    assert ctl.events.of_kind("foreign_nmt")


@pytest.mark.xfail(strict=True, reason=ISSUE + "a second SYNC producer is not noticed")
def test_second_sync_producer_is_an_event(make):
    world, ctl, intruder = make()
    for i in range(20):
        world.at(T_FAULT + i * ctl.period_ns * 1e-9 + 0.0007,
                 lambda: intruder.send(0x080, b"\x05"))
    ctl.run(max_cycles=2000)
    assert ctl.events.of_kind("foreign_sync")


@pytest.mark.xfail(strict=True, reason=ISSUE + "EMCY 00xxh (not 0000h) is labelled "
                   "'Error Reset / No Error'")
def test_emcy_00xx_is_not_labelled_no_error():
    from controller.canopen.master.supervision import Emcy
    e = Emcy("node 11 (x)", 11, 0x0010, 0x01, b"\0" * 5, 0)
    assert "no error" not in str(e).lower()


@pytest.mark.xfail(strict=True, reason=ISSUE + "cantrack's text for 8240h is '(Monitoring)'")
def test_emcy_8240h_has_its_cia301_text():
    from controller.canopen.master.supervision import Emcy
    e = Emcy("node 4 (io)", 4, 0x8240, 0x11, b"\0" * 5, 0)
    assert "unexpected sync data length" in str(e).lower()


@pytest.mark.xfail(strict=True, reason=ISSUE + "the simulated devices log a traceback for an "
                   "SDO request shorter than 8 bytes and send no abort")
def test_short_sdo_request_to_a_simulated_device_is_aborted(make, caplog):
    _world, ctl, intruder = make()
    answers = []
    ctl.transport.subscribe(0x58B, lambda c, d, t: answers.append(d))
    intruder.send(0x60B, b"\x40\x18")
    ctl.transport.run_until(ctl.clock.now_ns() + 10_000_000)
    assert not [r for r in caplog.records if r.exc_info]
    assert len(answers) == 1 and answers[0][0] == 0x80


@pytest.mark.xfail(strict=True, reason=ISSUE + "the candump log names the channel "
                   "cantrack-sim-<pid>-<n> (more than 15 characters, canplayer refuses it)")
def test_bus_log_channel_name_fits_canplayer(tmp_path):
    from controller.canopen.slave.world import SimWorld
    cfg = load(tmp_path)
    log = tmp_path / "bus.log"
    with SimWorld(cfg, bus_log=log) as world:
        world.transport.send(0x000, b"\x81\x00")
        world.transport.run_until(1_000_000)
    names = {line.split()[1] for line in log.read_text().splitlines()}
    assert names and all(len(n) <= 15 for n in names), names


@pytest.mark.xfail(strict=True, reason=ISSUE + "event_deadline on an RPDO is accepted and "
                   "silently dropped")
def test_event_deadline_is_applied(tmp_path):
    from controller.canopen.config.concise import concise_configuration
    from controller.canopen.testing import bus_yml_text
    text = bus_yml_text().replace("  rpdo:\n    1:\n      enabled: true\n",
                                  "  rpdo:\n    1:\n      enabled: true\n"
                                  "      event_deadline: 20\n", 1)
    cfg = load_bus_config(bus_yml(tmp_path, text=text))
    writes = {(w.index, w.sub_index): w.value for w in concise_configuration(cfg)["x"].sdos}
    assert writes.get((0x1400, 5)) == 20


@pytest.mark.xfail(strict=True, reason=ISSUE + "bus.yml accepts restricted and foreign "
                   "COB-IDs")
@pytest.mark.parametrize("cob", [0x080, 0x70B, 0x58B, 0x60B, 0x181, 0x081, 0x201])
def test_restricted_or_foreign_cob_id_is_refused(tmp_path, cob):
    from controller.canopen.testing import bus_yml_text
    from controller.errors import CantrackError
    text = bus_yml_text().replace("  tpdo:\n    1:\n      enabled: true\n",
                                  f"  tpdo:\n    1:\n      enabled: true\n"
                                  f"      cob_id: 0x{cob:03X}\n", 1)
    with pytest.raises(CantrackError, match=r"bus.yml:\d+.*cob_id"):
        load_bus_config(bus_yml(tmp_path, text=text))


@pytest.mark.xfail(strict=True, reason=ISSUE + "1019h (sync_overflow) is never written to "
                   "the slaves")
def test_1019h_written_to_every_sync_consumer(tmp_path):
    from controller.canopen.config.concise import concise_configuration
    cfg = load(tmp_path)
    c = concise_configuration(cfg)
    for name in ("encoder", "x", "y"):
        writes = {(w.index, w.sub_index): w.value for w in c[name].sdos}
        assert writes.get((0x1019, 0)) == 16, (name, writes)
