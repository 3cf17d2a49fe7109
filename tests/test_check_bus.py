"""``cantrack check-bus``: identity, NMT state and PDO read-back against the configuration.

Against the simulated devices on python-can's virtual bus (stepped time, as the boot tests),
and the command end to end (real time, devices in a thread of the same process).
"""

from __future__ import annotations

import json

import pytest

from controller.canopen.config import load_config
from controller.canopen.io.clock import RealtimeClock
from controller.canopen.io.transport import DeviceThread, virtual_bus
from controller.canopen.master.checkbus import check_bus, parse_scan
from controller.canopen.slave.rack import DeviceRack
from controller.canopen.testing import bus_yml, load
from controller.cli import check_bus as cmd_check_bus


@pytest.fixture
def cfg(tmp_path):
    return load(tmp_path)


def _diffs(result, node_id):
    return [(d.what, d.obj) for d in result.node(node_id).differences]


def test_configured_bus_matches(stepped_controller, cfg):
    world, ctl = stepped_controller(cfg)
    ctl.boot()
    r = check_bus(cfg, world.transport)
    assert r.ok, r.format()
    assert [n.node_id for n in r.nodes] == [10, 11, 12]
    for n in r.nodes:
        assert n.answered and n.nmt_state == 5
        assert n.identity["vendor-ID"] == 0x00CA7AC0
    # the manufacturer's strings (1008h-100Ah, segmented uploads)
    assert r.node(11).names == {"device name": "cantrack servo", "hardware version": "sim",
                                "software version": "0.1.0"}
    assert r.node(10).names["device name"] == "cantrack encoder"
    assert "device name 'cantrack servo'" in r.format()
    assert r.format().endswith("all nodes match the configuration")


def test_unconfigured_bus_shows_what_the_boot_changes(stepped_controller, cfg):
    """Power-on values: the encoder's TPDO1 maps two objects (EDS), the bus.yml one."""
    world, _ = stepped_controller(cfg)
    r = check_bus(cfg, world.transport)
    assert not r.ok
    assert _diffs(r, 10) == [("pdo", "1A00h:00")]
    assert "expected TPDO1 1 mapped objects (bus.yml), found 2" in r.format()
    assert r.node(10).nmt_state == 127  # pre-operational


def test_wrong_identity(stepped_controller, cfg):
    world, ctl = stepped_controller(cfg)
    ctl.boot()
    world.device("x").set_identity(product=0x1234)
    r = check_bus(cfg, world.transport)
    assert not r.ok
    assert _diffs(r, 11) == [("identity", "1018h:02")]
    assert r.node(12).ok and r.node(10).ok
    text = r.format()
    assert ("node 11 (x): DIFFERS" in text and "identity 1018h:02: expected product code "
            "04020001h (EDS cantrack-servo.eds), found 00001234h" in text), text
    assert "1 of 3 node(s) differ" in text


def test_missing_node(stepped_controller, cfg):
    world, _ = stepped_controller(cfg, present=["encoder", "x"])
    r = check_bus(cfg, world.transport, pdos=False)
    y = r.node(12)
    assert not y.answered and y.nmt_state is None
    assert _diffs(r, 12) == [("missing", "")]
    assert r.node(10).ok and r.node(11).ok
    assert "node 12 (y): MISSING: no SDO answer (no heartbeat)" in r.format()


def test_wrong_pdo_mapping_and_cob_id(stepped_controller, cfg):
    world, ctl = stepped_controller(cfg)
    ctl.boot()
    y = world.device("y")
    # what a stale configuration would leave: TPDO1 disabled, another object mapped
    y.store(0x1800, 1, 0x80000000 | 0x18C)
    r = check_bus(cfg, world.transport)
    assert ("pdo", "1800h:01") in _diffs(r, 12), r.format()
    assert "TPDO1 COB-ID 0000018Ch (enabled)" in r.format()


def test_scan_reports_an_unexpected_node(stepped_controller, tmp_path):
    """A node answering on an ID the configuration does not have (here: x's device on a
    bus whose configuration lacks x) is reported with its identity."""
    (tmp_path / "all").mkdir()
    (tmp_path / "less").mkdir()
    cfg_all = load(tmp_path / "all")                   # encoder 10, x 11, y 12
    cfg_less = load(tmp_path / "less", axes=("y",))    # encoder 10, y 11
    world, _ = stepped_controller(cfg_all, present=["encoder", "x", "y"])
    r = check_bus(cfg_less, world.transport, scan=parse_scan("10-13"), pdos=False)
    ids = {n.node_id: n for n in r.nodes}
    assert set(ids) == {10, 11, 12}
    assert ids[12].name is None and ("unexpected", "") in _diffs(r, 12)
    assert ids[12].identity["product code"] == 0x04020001
    assert not r.ok


def test_parse_scan():
    assert parse_scan("1-127") == range(1, 128)
    assert parse_scan("5") == range(5, 6)
    with pytest.raises(ValueError):
        parse_scan("0-200")


def test_command_exit_codes(tmp_path, capsys):
    """``cantrack check-bus`` on a virtual bus with the devices in a thread: 1 before the boot
    (the encoder's mapping differs), 1 with a node missing."""
    path = bus_yml(tmp_path)
    cfg = load_config(path)
    clock = RealtimeClock()
    rack = DeviceRack.from_config(cfg, virtual_bus("cb-cmd"), clock, ["encoder", "x"])
    th = DeviceThread(rack, clock).start()
    try:
        rc = cmd_check_bus.main([str(path), "-i", "virtual", "-c", "cb-cmd", "--listen", "0.2",
                                 "--sdo-timeout", "0.2", "--json", str(tmp_path / "c.json")])
    finally:
        th.stop()
        rack.bus.shutdown()
    out = capsys.readouterr().out
    assert rc == 1
    assert "node 12 (y): MISSING" in out and "node 11 (x): OK" in out, out
    assert "pdo 1A00h:00" in out
    data = json.loads((tmp_path / "c.json").read_text())
    assert data["ok"] is False and [n["node_id"] for n in data["nodes"]] == [10, 11, 12]
