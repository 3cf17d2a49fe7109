"""Item types through the controller's own node (controller/canopen/slave/plc.py): the PLC's
trigger carries a type (2014h, with 2004h in RPDO2 or written before it by SDO), the set of
tracked types (2015h:1-8, 256 bits) is readable and writable, untracked items are counted
in 2016h and never picked or missed.  The PLC side is python canopen's RemoteNode: its SDO
client and its RPDO maps read from the EDS (the frames it encodes are the ones a PLC sends)."""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import replace

import canopen
import pytest
from canopen.sdo import SdoAbortedError
from test_plc_contract import PLC, Heartbeat, SteppedNetwork

from controller.canopen.apps.demo import PhotoEye, PickPlace, Step
from controller.canopen.config import load_config
from controller.canopen.config.plc import PlcConfig
from controller.canopen.master.cycle import Controller, Phase
from controller.canopen.master.plc_node import attach_plc_node
from controller.canopen.protocol import od as odm
from controller.canopen.slave.plc import EDS, bits_types, type_bits
from controller.canopen.slave.world import SimWorld
from controller.cli import demo as cmd_demo


@contextmanager
def demo_cell(heartbeat: bool = True, track_types: frozenset[int] | None = None,
              **demo_changes):
    """The demo's pick and place with the PLC node; the PLC is python canopen's RemoteNode
    (SDO client, RPDO maps from the EDS) -> (ctl, app, node, remote)."""
    cfg = load_config(cmd_demo.DEFAULT_CONFIG)
    if track_types is not None:
        cfg = replace(cfg, tracking=replace(cfg.tracking, track_types=track_types))
    app = PickPlace(replace(cfg.demo, **demo_changes))
    with SimWorld(cfg, record=False) as sim:
        world = sim.world
        ctl = Controller(cfg, sim.transport, app)
        node = attach_plc_node(ctl, PlcConfig(commander=PLC))
        hb = world.add(Heartbeat(world, PLC))
        hb.on = heartbeat
        net = world.add(SteppedNetwork(world))
        remote = canopen.RemoteNode(cfg.master.node_id, odm.load_od(EDS, cfg.master.node_id))
        net.add_node(remote)
        remote.sdo.MAX_RETRIES = 0
        remote.rpdo.read(from_od=True)
        ctl.boot()
        ctl.start()
        app.eye = PhotoEye(sim.device(cfg.tracking.conveyor.node).profile, app.demo,
                           world.clock.now_ns() * 1e-9)
        while ctl.phase is not Phase.RUNNING:
            ctl.step()
        yield ctl, app, node, remote


def _typed_trigger(remote, item_type: int, edge: int) -> None:
    """RPDO2 (300h + id) as python canopen encodes it from the EDS mapping: type and edge."""
    pdo = remote.rpdo[2]
    pdo["Trigger item type"].raw = item_type
    pdo["Item trigger input"].raw = edge
    pdo.transmit()


def _set_types(remote, types: frozenset[int]) -> None:
    """2015h:1-8 written by SDO, one sub-index after the other (as a PLC does)."""
    for sub, word in enumerate(type_bits(types), 1):
        remote.sdo[0x2015][sub].raw = word


def _run(ctl, app, max_cycles: int, each=lambda: None) -> None:
    while ctl.k < max_cycles:
        ctl.step()
        if ctl.source_done:
            return
        each()
    raise AssertionError(f"the demo did not end within {max_cycles} cycles")


def test_type_bits_round_trip():
    assert type_bits(None) == (0xFFFFFFFF,) * 8
    assert bits_types((0xFFFFFFFF,) * 8) is None
    bits = type_bits(frozenset({0, 2, 31, 32, 255}))
    assert bits == (0x80000005, 1, 0, 0, 0, 0, 0, 0x80000000)
    assert bits_types(bits) == {0, 2, 31, 32, 255}
    assert bits_types((0,) * 8) == frozenset()


def test_tracked_types_loaded_from_the_configuration_and_written_by_the_plc():
    with demo_cell(track_types=frozenset({1, 2, 40}), items=1) as (ctl, app, node, remote):
        assert [remote.sdo[0x2015][s].raw for s in range(1, 9)] == \
            [0b110, 1 << 8, 0, 0, 0, 0, 0, 0]
        assert app.robot.tracked_types(app.frame) == {1, 2, 40}
        remote.sdo[0x2015][2].raw = 0  # type 40 no longer
        remote.sdo[0x2015][8].raw = 1 << 31  # type 255 tracked
        ctl.step()  # (the source gets the new set with the next cycle's context)
        assert app.robot.tracked_types(app.frame) == {1, 2, 255}
        for s in range(1, 9):
            remote.sdo[0x2015][s].raw = 0xFFFFFFFF
        ctl.step()
        assert app.robot.tracked_types(app.frame) is None  # all bits: every type
        assert remote.sdo[0x2015][0].raw == 8
        with pytest.raises(SdoAbortedError) as e:
            remote.sdo[0x2015][0].raw = 8
        assert e.value.code == 0x06010002  # read-only


def test_typed_triggers_only_tracked_items_are_picked():
    """The photo-eye's item (type 2) and three PLC items: type 7 over RPDO2 (not tracked:
    ignored, 2016h), type 2 over RPDO2 and type 2 by SDO (2014h, then 2004h): placed."""
    with demo_cell(items=1, item_types=(2,), place_dwell_s=0.02) as (ctl, app, node, remote):
        _set_types(remote, frozenset({2}))
        ctl.step()  # (the source gets the new set with the next cycle's context)
        assert app.robot.tracked_types(app.frame) == {2}
        sent: list[int] = []

        def plc():
            if app.eye.detected >= 1 and not sent:
                sent.append(ctl.k)
                _typed_trigger(remote, 7, 1)  # an item of type 7: not tracked
            elif len(sent) == 1 and ctl.k >= sent[0] + 150:  # 0.3 s = 90 mm further
                sent.append(ctl.k)
                _typed_trigger(remote, 7, 0)
                _typed_trigger(remote, 2, 1)  # type 2 in the same frame as its edge
            elif len(sent) == 2 and ctl.k >= sent[1] + 600:
                sent.append(ctl.k)
                _typed_trigger(remote, 2, 0)
                remote.sdo[0x2014].raw = 2  # SDO: the type first, then the edge
                remote.sdo[0x2004].raw = 1
                remote.sdo[0x2004].raw = 0
        _run(ctl, app, 12000, plc)
        assert len(sent) == 3
        assert list(node.trigger_types) == [7, 2, 2]
        items = app.items()
        assert [(i.item_type, i.outcome) for i in items] == \
            [(2, "placed"), (7, "ignored"), (2, "placed"), (2, "placed")]
        ctl.step()
        assert remote.sdo[0x2003].raw == 4  # detected: every type
        assert remote.sdo[0x2016].raw == 1  # ignored: the type-7 item
        assert remote.sdo[0x2006].raw == 0  # ... and never missed
        assert remote.sdo[0x2014].raw == 2


def test_untracking_a_waiting_type_ignores_its_items():
    """Two photo-eye items (types 1, 2) wait; the PLC stops tracking type 2 while the robot
    approaches the first: the second is ignored at once, the first still placed."""
    with demo_cell(items=2, item_types=(1, 2), pitch_mm=(100, 100)) as (ctl, app, node, remote):
        done: list[int] = []

        def plc():
            if not done and app.eye.detected == 2 and app.stage is Step.APPROACH:
                done.append(ctl.k)
                _set_types(remote, frozenset({1}))
        _run(ctl, app, 8000, plc)
        assert done
        assert [(i.item_type, i.outcome) for i in app.items()] == [(1, "placed"),
                                                                   (2, "ignored")]
        ctl.step()
        assert remote.sdo[0x2016].raw == 1


def test_the_type_of_a_frame_applies_whatever_the_mapping_order():
    """RPDO2 remapped by the PLC to 2004h before 2014h (CiA 301 mapping over SDO): the type
    in a frame is still that frame's edge's."""
    with demo_cell(items=1) as (ctl, app, node, remote):
        m = remote.sdo[0x1601]
        cob = remote.sdo[0x1401][1].raw
        remote.sdo[0x1401][1].raw = cob | 0x80000000  # invalid while remapping
        m[0].raw = 0
        m[1].raw = 0x20040008
        m[2].raw = 0x20140008
        m[0].raw = 2
        remote.sdo[0x1401][1].raw = cob
        ctl.step()
        remote.network.send_message(cob, bytes([1, 9]))  # edge, then type 9
        ctl.step()
        assert list(node.trigger_types) == [9]
        assert remote.sdo[0x2014].raw == 9


def test_without_the_commander_type_writes_are_refused():
    with demo_cell(heartbeat=False, items=1) as (ctl, app, node, remote):
        for index, sub, value in ((0x2014, None, 3), (0x2015, 1, 0)):
            var = remote.sdo[index] if sub is None else remote.sdo[index][sub]
            with pytest.raises(SdoAbortedError) as e:
                var.raw = value
            assert e.value.code == 0x08000021
        _typed_trigger(remote, 4, 1)  # an RPDO: dropped, no trigger, no type
        ctl.step()
        assert node.triggers == 0 and remote.sdo[0x2014].raw == 0
        assert app.robot.tracked_types(app.frame) is None
        assert remote.sdo[0x2012].raw == 4  # 2 SDO writes + 2 RPDO values refused
