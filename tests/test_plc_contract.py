"""The commanding-node contract of the controller's own node (controller/canopen/slave/plc.py)
tested from another node on the bus, as a PLC -- or anyone on that bus -- would:

- the SDO client is python canopen's ``RemoteNode`` (an independent implementation), on its
  own python-can bus of the stepped world; each request is delivered at once (the world is
  drained, stepped time does not move), so the run stays deterministic;
- the PLC's heartbeat (700h + commander) comes from a small producer in the world;
- every refusal is checked for its SDO abort code, its event and the counters 2011h-2013h.
"""

from __future__ import annotations

import math
import struct
from contextlib import contextmanager
from dataclasses import replace

import can
import canopen
import pytest
from canopen.sdo import SdoAbortedError

from controller.canopen.config.plc import CommanderLoss, PlcConfig, TriggerOverflow
from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.master.cycle import Controller, Phase
from controller.canopen.master.plc_node import attach_plc_node
from controller.canopen.protocol import od as odm
from controller.canopen.slave.plc import EDS
from controller.canopen.slave.world import SimWorld
from controller.canopen.testing import load
from controller.tracking import Mode, TrackState

NODE = 1  # master.node_id of the test bus
PLC = 0x20  # the commander
OFFSET = (420.0, 30.0, 0.0)


class Heartbeat:
    """The PLC's heartbeat producer (700h + node, state OPERATIONAL) on the stepped clock."""

    def __init__(self, world, node: int, period_ms: int = 100) -> None:
        self.bus = world.new_bus()
        self.clock = world.clock
        self.node = node
        self.period_ns = period_ms * 1_000_000
        self.on = True
        self._next = self.clock.now_ns()

    def handle(self, msg) -> None:
        pass

    def next_timer_ns(self):
        return self._next if self.on else None

    def on_timer(self, now_ns: int) -> None:
        self.bus.send(can.Message(arbitration_id=0x700 + self.node, data=b"\x05",
                                  is_extended_id=False, timestamp=self.clock.stamp()))
        self._next = now_ns + self.period_ns


class SteppedNetwork(canopen.Network):
    """python canopen's Network as a participant of the stepped world: a request is sent
    and the world drained (the answer arrives before ``send_message`` returns)."""

    def __init__(self, world) -> None:
        super().__init__(world.new_bus())
        self.world = world

    # the world's Endpoint interface
    def handle(self, msg: can.Message) -> None:
        self.notify(msg.arbitration_id, msg.data, msg.timestamp)

    def next_timer_ns(self):
        return None

    def on_timer(self, now_ns: int) -> None:
        pass

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        self.bus.send(can.Message(arbitration_id=can_id, data=bytes(data),
                                  is_extended_id=False))
        self.world.drain()


@contextmanager
def cell(tmp_path, plc: PlcConfig | None = PlcConfig(commander=PLC), mode=Mode.ABSOLUTE,
         heartbeat: bool = True):
    cfg = load(tmp_path)
    app = ConveyorFollow(20, None, OFFSET, mode=mode)
    with SimWorld(cfg, record=True) as sim:
        world = sim.world
        ctl = Controller(cfg, sim.transport, app)
        node = attach_plc_node(ctl, config=plc if plc is not None else PlcConfig())
        hb = world.add(Heartbeat(world, PLC))
        hb.on = heartbeat
        net = world.add(SteppedNetwork(world))
        remote = canopen.RemoteNode(NODE, odm.load_od(EDS, NODE))
        net.add_node(remote)
        remote.sdo.MAX_RETRIES = 0
        ctl.boot()
        ctl.start()
        yield sim, ctl, node, remote, hb


def _steps(ctl, n: int) -> None:
    for _ in range(n):
        ctl.step()


def _abort(call) -> int:
    with pytest.raises(SdoAbortedError) as e:
        call()
    return e.value.code


def _write(remote, index, sub, value):
    var = remote.sdo[index] if sub is None else remote.sdo[index][sub]
    return lambda: setattr(var, "raw", value)


def _running(ctl):
    for _ in range(400):
        ctl.step()
        if ctl.phase is Phase.RUNNING and ctl.source.tracker.state is TrackState.SYNCED:
            return
    raise AssertionError("the tracker did not synchronise")


def test_without_the_commanders_heartbeat_every_motion_write_is_refused(tmp_path):
    with cell(tmp_path, heartbeat=False) as (sim, ctl, node, remote, hb):
        _running(ctl)
        assert remote.sdo[0x2011].raw == 0x01 | 0x04  # OPERATIONAL, no commander
        for index, value in ((0x2005, 0), (0x2005, 3), (0x2004, 1)):
            assert _abort(_write(remote, index, None, value)) == 0x08000021
        assert _abort(_write(remote, 0x2010, 1, 500.0)) == 0x08000021
        ctl.step()
        assert ctl.source.tracker.state is TrackState.SYNCED  # nothing happened
        assert remote.sdo[0x2012].raw == 4
        ev = ctl.events.of_kind("plc_no_commander")
        assert len(ev) == 1 and "node 32" in ev[0].detail and "refused" in ev[0].reaction
        # RPDO1 (engage 0, trigger 1) from anyone: dropped, counted
        remote.network.send_message(0x200 + NODE, bytes([0, 1]))
        ctl.step()
        assert ctl.source.tracker.state is TrackState.SYNCED and node.triggers == 0
        assert remote.sdo[0x2012].raw == 6
        assert remote.sdo[0x2005].raw == 0 and remote.sdo[0x2004].raw == 0


def test_no_commander_configured_refuses_motion_writes(tmp_path):
    with cell(tmp_path, plc=None) as (sim, ctl, node, remote, hb):
        _running(ctl)
        assert _abort(_write(remote, 0x2005, None, 0)) == 0x08000021
        assert remote.sdo[0x2020][1].raw == 0
        assert ctl.source.tracker.state is TrackState.SYNCED


def test_with_the_commanders_heartbeat_commands_act(tmp_path):
    with cell(tmp_path) as (sim, ctl, node, remote, hb):
        _running(ctl)
        assert remote.sdo[0x2011].raw == 0x07
        assert remote.sdo[0x2020][1].raw == PLC and remote.sdo[0x2020][2].raw == 1
        assert remote.sdo[0x1016][1].raw == (PLC << 16) | 300
        remote.sdo[0x2005].raw = 0  # de-sync on the path
        ctl.step()
        assert ctl.source.tracker.state is TrackState.DESYNCING
        assert remote.sdo[0x2012].raw == 0 and not ctl.events.of_kind("plc_no_commander")


def test_nmt_pre_operational_refuses_motion_writes(tmp_path):
    with cell(tmp_path) as (sim, ctl, node, remote, hb):
        _running(ctl)
        remote.nmt.send_command(0x80)  # enter PRE-OPERATIONAL (the controller node only)
        ctl.step()
        assert remote.sdo[0x2011].raw & 0x01 == 0
        n0 = len(sim.recorder.frames)
        _steps(ctl, 30)  # the controller's heartbeat says PRE-OPERATIONAL now
        assert [d for _, c, d in sim.recorder.frames[n0:] if c == 0x700 + NODE] == [b"\x7f"]
        assert _abort(_write(remote, 0x2005, None, 0)) == 0x08000022
        assert ctl.source.tracker.state is TrackState.SYNCED
        remote.nmt.send_command(0x01)
        ctl.step()
        remote.sdo[0x2005].raw = 0
        ctl.step()
        assert ctl.source.tracker.state is TrackState.DESYNCING
        kinds = [e.detail for e in ctl.events.of_kind("plc_nmt")]
        assert kinds == ["NMT OPERATIONAL -> PRE_OPERATIONAL", "NMT PRE_OPERATIONAL -> "
                         "OPERATIONAL"]


def test_command_window_after_the_sync(tmp_path):
    plc = PlcConfig(commander=PLC, command_window_us=300)
    with cell(tmp_path, plc=plc) as (sim, ctl, node, remote, hb):
        _running(ctl)
        # between two cycles the stepped clock stands at the SYNC: inside the window
        assert remote.sdo[0x2011].raw == 0x07
        # a request 1 ms after a SYNC (raw CiA 301 frame: 2005h = 0): outside
        answers = []
        remote.network.subscribe(0x580 + NODE, lambda c, d, t: answers.append(bytes(d)))
        peer = sim.world.new_bus()
        t_sync = ctl.t0 + ctl.k * ctl.period_ns
        sim.world.at(t_sync + 1_000_000, lambda: peer.send(can.Message(
            arbitration_id=0x600 + NODE, data=bytes([0x2F, 0x05, 0x20, 0x00, 0, 0, 0, 0]),
            is_extended_id=False)))
        ctl.step()
        ctl.step()
        assert answers and answers[0][0] == 0x80
        assert struct.unpack_from("<I", answers[0], 4)[0] == 0x08000022
        assert ctl.source.tracker.state is TrackState.SYNCED
        assert "command window (300 us" in ctl.events.of_kind("plc_outside_window")[0].detail
        peer.shutdown()


@pytest.mark.parametrize("reaction", list(CommanderLoss))
def test_loss_of_the_commanders_heartbeat(tmp_path, reaction):
    plc = PlcConfig(commander=PLC, on_commander_lost=reaction)
    with cell(tmp_path, plc=plc) as (sim, ctl, node, remote, hb):
        _running(ctl)
        hb.on = False
        t_off = sim.clock.now_ns()
        for _ in range(300):
            ctl.step()
            if ctl.events.of_kind("plc_commander_lost"):
                break
        ev = ctl.events.of_kind("plc_commander_lost")
        assert len(ev) == 1
        lost_after = sim.clock.now_ns() - t_off
        assert 200e6 <= lost_after <= 300e6 + 2 * ctl.period_ns  # 300 ms after the last one
        ctl.step()
        if reaction is CommanderLoss.CONTINUE:
            assert ctl.source.tracker.state is TrackState.SYNCED and ev[0].reaction.startswith(
                "continue")
        elif reaction is CommanderLoss.DESYNC:
            assert ctl.source.tracker.state is TrackState.DESYNCING
            assert ev[0].reaction == "de-sync on the path"
        else:
            assert ctl.phase in (Phase.STOPPING, Phase.STOPPED)
            assert ev[0].reaction == "quick stop of all drives"
        assert remote.sdo[0x2011].raw & 0x02 == 0
        if reaction is not CommanderLoss.STOP:
            hb.on = True
            hb._next = sim.clock.now_ns()
            _steps(ctl, 3)
            assert ctl.events.of_kind("plc_commander_back")
            assert remote.sdo[0x2011].raw == 0x07


def test_cob_id_writes_checked(tmp_path):
    with cell(tmp_path) as (sim, ctl, node, remote, hb):
        _steps(ctl, 5)
        tpdo1 = remote.sdo[0x1800][1]
        cob = tpdo1.raw
        assert cob == 0x180 + NODE
        # changing a valid PDO's CAN-ID: 06090030h (CANopenNode: disable first)
        assert _abort(_write(remote, 0x1800, 1, 0x000)) == 0x06090030
        tpdo1.raw = cob | 0x80000000
        cases = {0x000: 0x06090030,  # NMT: restricted
                 0x080: 0x08000000,  # the SYNC (a second SYNC producer)
                 0x08B: 0x08000000,  # drive x's EMCY
                 0x20B: 0x08000000,  # drive x's RPDO1 (it would leave OPERATION ENABLED)
                 0x18A: 0x08000000,  # the encoder's TPDO1
                 0x381: 0x08000000,  # our own TPDO3
                 0x581: 0x06090030, 0x70B: 0x06090030}
        for can_id, code in cases.items():
            assert _abort(_write(remote, 0x1800, 1, can_id)) == code, hex(can_id)
        assert len(ctl.events.of_kind("plc_cob_id_refused")) == len(cases) + 1
        assert "drive" not in ctl.events.of_kind("plc_cob_id_refused")[0].detail
        assert "RPDO1 of node 11 (x)" in [e.detail for e in
                                          ctl.events.of_kind("plc_cob_id_refused")][4]
        # the commander's RPDO1 is where our TPDO may point; a free ID is fine too
        tpdo1.raw = 0x200 + PLC
        tpdo1.raw = (0x200 + PLC) | 0x80000000
        tpdo1.raw = 0x3F0
        _steps(ctl, 60)
        assert any(c == 0x3F0 for _, c, _ in sim.recorder.frames)
        # RPDO1: not onto drive x's TPDO1 (18Bh); the commander's TPDO1 is fine
        rpdo1 = remote.sdo[0x1400][1]
        rpdo1.raw = (0x200 + NODE) | 0x80000000
        assert _abort(_write(remote, 0x1400, 1, 0x18B)) == 0x08000000
        rpdo1.raw = 0x180 + PLC


def test_trigger_rate_limit_never_aborts(tmp_path):
    """1000 trigger edges in 2 s over RPDO1 (the issue's flood): at most 100 per second are
    taken, the rest are dropped and counted (2013h); the controller goes on."""
    with cell(tmp_path) as (sim, ctl, node, remote, hb):
        _running(ctl)
        k0 = ctl.k
        for _i in range(1000):  # one edge every 2 ms: 0 then 1 in one cycle
            remote.network.send_message(0x200 + NODE, bytes([0, 0]))
            remote.network.send_message(0x200 + NODE, bytes([0, 1]))
            ctl.step()
        assert ctl.k - k0 == 1000 and ctl.phase is Phase.RUNNING
        assert node.triggers == 200 and node.triggers_dropped == 800
        assert remote.sdo[0x2013].raw == 800
        ev = ctl.events.of_kind("plc_trigger_dropped")
        assert 2 <= len(ev) <= 3  # at most one report per second
        assert "more than 100 trigger edges within 1 s" in ev[0].detail


def test_a_long_run_keeps_the_last_history_entries_and_counts_all(tmp_path):
    """Issue 12 (O(1) memory per cycle): a PLC that engages and disengages with every one of
    1100 accepted trigger edges (one per 6 cycles, 12 ms: within the 100/s limit), then loses
    its heartbeat and sends 1100 more frames, all refused.  The node's counters count every
    one; its histories (trigger times and types, engage commands, refusals) hold the newest
    HISTORY = 1000: the times those of the last 1000 edges, in order."""
    from controller.canopen.slave.plc import HISTORY

    with cell(tmp_path) as (sim, ctl, node, remote, hb):
        _running(ctl)
        cob = 0x200 + NODE
        edges: list[int] = []
        for i in range(1100):  # RPDO1: 2005h (engage: off / absolute), 2004h (edge)
            mode = int(Mode.ABSOLUTE) if i % 2 else int(Mode.OFF)
            remote.network.send_message(cob, bytes([mode, 0]))
            remote.network.send_message(cob, bytes([mode, 1]))
            edges.append(sim.world.clock.now_ns())
            _steps(ctl, 6)
        assert (node.triggers, node.triggers_dropped) == (1100, 0)
        assert len(node.trigger_times) == len(node.trigger_types) == HISTORY == 1000
        assert list(node.trigger_times) == edges[-HISTORY:]
        assert len(node.commands) == HISTORY
        assert [v for _, v in node.commands][-2:] == [int(Mode.OFF), int(Mode.ABSOLUTE)]
        hb.on = False
        _steps(ctl, 200)  # (the commander's heartbeat time-out: 300 ms)
        assert node.refusal() is not None
        refused0 = node.refused
        for _ in range(1100):
            remote.network.send_message(cob, bytes([0, 1]))
            ctl.step()
        assert node.refused == refused0 + 2200  # (2005h and 2004h of each frame)
        assert len(node.refusals) == HISTORY
        assert ctl.failure is None


def _translation(p):
    return p[:3]


@pytest.mark.parametrize("mode", [Mode.ABSOLUTE, Mode.RELATIVE])
def test_2007h_is_the_tracking_error_in_both_modes(tmp_path, mode):
    """While SYNCED the target of SYNC k is the setpoint computed for it (lead cycles
    before); 2007h = |actual(k) - target(k)| over x, y, z to 1e-6 mm, in both modes."""
    with cell(tmp_path, mode=mode) as (sim, ctl, node, remote, hb):
        _running(ctl)
        lead = ctl.master.lead
        seen = []
        for _ in range(80):
            ctl.step()
            seen.append((ctl.trace[-1], float(remote.sdo[0x2007].raw)))
        by_cycle = {r.cycle: r for r, _ in seen}
        checked = 0
        for rec, value in seen:
            src = by_cycle.get(rec.cycle - lead)
            if src is None or src.state != TrackState.SYNCED or rec.state != TrackState.SYNCED:
                continue
            target = _translation(src.setpoint)
            actual = _translation(rec.actual)
            expected = math.dist(actual, target)
            assert value == pytest.approx(expected, abs=1e-6)
            checked += 1
        assert checked >= 50
        assert max(v for _, v in seen) < 2.0  # (the issue: about 240 mm in relative mode)


def test_segmented_upload_of_the_device_name(tmp_path):
    with cell(tmp_path) as (sim, ctl, node, remote, hb):
        _steps(ctl, 3)
        assert remote.sdo[0x1008].raw == "cantrack controller"
        from controller import __version__
        assert remote.sdo[0x100A].raw == __version__
        assert remote.sdo[0x1009].raw == "software"


def test_config_owned_and_value_refusals(tmp_path):
    with cell(tmp_path) as (sim, ctl, node, remote, hb):
        _running(ctl)
        assert _abort(_write(remote, 0x1017, None, 100)) == 0x08000020
        assert _abort(_write(remote, 0x1016, 1, 0)) == 0x08000020
        assert _abort(_write(remote, 0x2005, None, 4)) == 0x06090030
        assert _abort(_write(remote, 0x2004, None, 2)) == 0x06090030
        assert _abort(_write(remote, 0x2000, None, 1)) == 0x06010002
        assert _abort(_write(remote, 0x2010, 1, 500.0)) == 0x08000022  # not OFF
        assert remote.sdo[0x2012].raw == 0  # (not contract refusals)
        assert replace(PlcConfig(), commander=PLC).commander == PLC


@contextmanager
def demo_cell(**plc_changes):
    """The demo's pick and place (photo-eye items) with the PLC node, the test PLC as its
    commander, python canopen's RemoteNode as its client."""
    from controller.canopen.apps.demo import PhotoEye, PickPlace
    from controller.canopen.config import load_config
    from controller.cli import demo as cmd_demo

    cfg = load_config(cmd_demo.DEFAULT_CONFIG)
    plc = replace(PlcConfig(commander=PLC), **plc_changes)
    app = PickPlace(replace(cfg.demo, items=1), trigger_overflow=plc.trigger_overflow)
    with SimWorld(cfg, record=False) as sim:
        world = sim.world
        ctl = Controller(cfg, sim.transport, app)
        node = attach_plc_node(ctl, plc)
        world.add(Heartbeat(world, PLC))
        net = world.add(SteppedNetwork(world))
        remote = canopen.RemoteNode(cfg.master.node_id,
                                    odm.load_od(EDS, cfg.master.node_id))
        net.add_node(remote)
        ctl.boot()
        ctl.start()
        app.eye = PhotoEye(sim.device(cfg.tracking.conveyor.node).profile, app.demo,
                           world.clock.now_ns() * 1e-9)
        yield sim, ctl, app, node, remote


@pytest.mark.parametrize("policy", ["drop_newest", "drop_oldest"])
def test_trigger_flood_into_a_full_buffer_never_aborts(policy):
    """The issue's flood into the demo: 1000 edges in 2 s over RPDO1.  200 pass the rate
    limit and become items; the robot's 32-entry trigger buffer overflows; the policy drops
    items, counts and reports them; the run goes on (it used to end with 'trigger buffer
    full', exit 2)."""

    with demo_cell(trigger_overflow=TriggerOverflow(policy)) as (sim, ctl, app, node, remote):
        while ctl.phase is not Phase.RUNNING:
            ctl.step()
        _steps(ctl, 10)
        cob = 0x200 + ctl.cfg.master.node_id
        for _ in range(1000):
            remote.network.send_message(cob, bytes([0, 0]))
            remote.network.send_message(cob, bytes([0, 1]))
            ctl.step()
        _steps(ctl, 5)
        assert ctl.phase is Phase.RUNNING and ctl.failure is None
        assert node.triggers == 200 and node.triggers_dropped == 800
        dropped = [i for i in app.items() if i.outcome == "dropped"]
        assert app.triggers_dropped == len(dropped) > 0
        assert len(app.robot.buffer) <= app.robot.buffer.capacity
        assert remote.sdo[0x2013].raw == 800 + len(dropped)
        ev = ctl.events.of_kind("trigger_dropped")
        assert ev and all(policy in e.reaction for e in ev)
        assert len(ev) <= 3  # at most one report per second
        if policy == "drop_newest":  # the new trigger never got into the buffer
            assert all(i.entry_id is None for i in dropped)
        else:  # a waiting item (in the buffer, not the one tracked) made room
            assert all(i.entry_id is not None for i in dropped)
            newest = max((i for i in app.items() if i.entry_id is not None),
                         key=lambda i: i.t_edge_ns)
            assert newest.outcome != "dropped"  # (the newest trigger is kept)


@pytest.mark.parametrize("section, message", [
    ("  commander_heartbeat_ms: 300\n", "'.plc.commander'"),
    ("  commander: 1\n", "controller's own node-ID"),
    ("  commander: 11\n", "slave 'x'"),
    ("  commander: 200\n", "'.plc.commander'"),
    ("  commander: 32\n  on_commander_lost: halt\n", "continue, desync, stop"),
    ("  commander: 32\n  command_window_us: 5000\n", "'.plc.command_window_us'"),
    ("  commander: 32\n  trigger_overflow: drop\n", "drop_newest, drop_oldest"),
    ("  commander: 32\n  comander_heartbeat_ms: 300\n", "comander_heartbeat_ms"),
])
def test_plc_section_errors_name_file_line_and_key(tmp_path, section, message):
    from controller.canopen.testing import bus_yml, bus_yml_text
    from controller.errors import ConfigError

    path = bus_yml(tmp_path, text=bus_yml_text() + "\n.plc:\n" + section)
    with pytest.raises(ConfigError) as e:
        load(tmp_path, text=path.read_text())
    text = str(e.value)
    assert "bus.yml" in text and ":" in text and message in text, text


def test_plc_section_parsed(tmp_path):
    from controller.canopen.testing import bus_yml_text

    cfg = load(tmp_path, text=bus_yml_text() + "\n.plc:\n  commander: 0x20\n"
               "  on_commander_lost: stop\n  command_window_us: 500\n"
               "  trigger_overflow: drop_oldest\n")
    assert cfg.plc == PlcConfig(commander=0x20, on_commander_lost=CommanderLoss.STOP,
                                command_window_us=500,
                                trigger_overflow=TriggerOverflow.DROP_OLDEST)
