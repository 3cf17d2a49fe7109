"""Boot: NMT reset -> boot-up -> identity (1018h) -> SDO configuration -> NMT start.

Against the simulated devices in stepped time; each failure names the node, the object and
(for an SDO abort) the abort code.
"""

from __future__ import annotations

import pytest

from controller.canopen.config import load_config
from controller.canopen.config.concise import concise_configuration
from controller.canopen.master.boot import BootError, cantrack_sdos, interpolation_period
from controller.canopen.protocol.sdo import SdoTimeoutError
from controller.canopen.slave.node import NMT_OPERATIONAL
from controller.canopen.testing import bus_yml, bus_yml_text, load


@pytest.fixture
def cfg(tmp_path):
    return load(tmp_path)



def test_interpolation_period():
    assert interpolation_period(2000) == (2, -3)
    assert interpolation_period(1000) == (1, -3)
    assert interpolation_period(1500) == (15, -4)
    assert interpolation_period(250) == (25, -5)
    with pytest.raises(ValueError):
        interpolation_period(2001 * 1000)


def test_boot_configures_every_node(stepped_controller, cfg):
    world, ctl = stepped_controller(cfg)
    result = ctl.boot()
    concise = concise_configuration(cfg)
    for name, nb in result.nodes.items():
        assert nb.sdo_writes == len(concise[name].sdos) + len(cantrack_sdos(cfg, name))
        assert nb.identity == (0x00CA7AC0, 0x04020001 if name != "encoder" else 0x04060001,
                               0x00010000, 0)
        dev = world.device(name)
        assert dev.nmt_state == NMT_OPERATIONAL
    assert result.missing == []
    x = world.device("x")
    assert (x.load(0x60C2, 1), x.load(0x60C2, 2)) == (2, -3)
    assert x.load(0x6060) == 8 and x.load(0x6061) == 8
    assert x.load(0x1016, 1) == (1 << 16) | 150  # master heartbeat 50 ms x 3
    assert x.load(0x1017) == 50
    assert [x.load(0x1600, i) for i in range(3)] == [2, 0x60400010, 0x607A0020]
    assert x.load(0x607A) == x.load(0x6064) == 4_000_000  # no jump at the enable
    assert (x.load(0x607D, 1), x.load(0x607D, 2)) == (-1_000_000, 15_000_000)
    assert x.load(0x6065) == 20000 and x.load(0x605A) == 2
    assert [e.kind for e in ctl.events] == ["boot"] * 3


def test_sync_window_is_written_to_1007h_of_every_sync_consumer(stepped_controller, tmp_path,
                                                               cfg):
    """``master.sync_window`` [us] -> 1007h of the encoder and the drives (dcfgen writes it
    into the master's DCF only); 0, the default, writes nothing: the nodes keep theirs."""
    assert not any(w.index == 0x1007 for n in cfg.slaves for w in cantrack_sdos(cfg, n))
    text = bus_yml_text().replace("  sync_overflow: 16", "  sync_window: 1000\n"
                                                          "  sync_overflow: 16")
    cfg_w = load_config(bus_yml(tmp_path, text=text, name="window.yml"))
    assert cfg_w.master.sync_window_us == 1000
    world, ctl = stepped_controller(cfg_w)
    ctl.boot()
    for name in ("encoder", "x", "y"):
        dev = world.device(name)
        assert dev.load(0x1007) == 1000 and dev.sync_window_ns == 1_000_000
    world0, ctl0 = stepped_controller(cfg)
    ctl0.boot()
    assert world0.device("x").load(0x1007) == 0 and world0.device("x").sync_window_ns == 0


def test_missing_node(stepped_controller, cfg):
    world, ctl = stepped_controller(cfg, present=["encoder", "x"])
    with pytest.raises(BootError, match=r"^node 12 \(y\): no boot-up message within 0.1 s "
                                        r"after NMT reset node"):
        ctl.boot()


def test_missing_optional_node_is_left_out(stepped_controller, tmp_path):
    text = bus_yml_text(("x", "y", "z"))
    text = "\n".join(line for line in text.splitlines()
                     if not line.startswith("      z: {node: z"))
    cfg = load_config(bus_yml(tmp_path, text=text))
    world, ctl = stepped_controller(cfg, present=["encoder", "x", "y"])
    result = ctl.boot()
    assert result.missing == ["z"]
    assert any(e.kind == "missing" and "node 13 (z)" in e.source for e in ctl.events)


@pytest.mark.parametrize("field, sub, value, text", [
    ("product", 2, 0x04020002, "product code 1018h:02 is 04020002h, the EDS "
                               "cantrack-servo.eds says 04020001h"),
    ("vendor", 1, 0x00000123, "vendor-ID 1018h:01 is 00000123h"),
    ("revision", 3, 0x00020000, "revision number 1018h:03 is 00020000h"),
])
def test_wrong_identity(stepped_controller, cfg, field, sub, value, text):
    world, ctl = stepped_controller(cfg)
    world.device("x").set_identity(**{field: value})
    with pytest.raises(BootError, match=r"node 11 \(x\): wrong identity: ") as info:
        ctl.boot()
    assert text in str(info.value)


def test_serial_number_from_bus_yml(stepped_controller, tmp_path):
    text = bus_yml_text().replace("  node_id: 12\n", "  node_id: 12\n  serial_number: 77\n")
    cfg = load_config(bus_yml(tmp_path, text=text))
    world, ctl = stepped_controller(cfg)
    with pytest.raises(BootError, match=r"node 12 \(y\): wrong identity: serial number "
                                        r"1018h:04 is 00000000h, bus.yml says 0000004Dh"):
        ctl.boot()


def test_sdo_abort_names_node_object_and_code(stepped_controller, cfg):
    world, ctl = stepped_controller(cfg)
    world.device("y").reject_sdo(0x60C2, 2, 0x06090030)
    with pytest.raises(BootError) as info:
        ctl.boot()
    msg = str(info.value)
    assert msg.startswith("node 12 (y): SDO abort 06090030h (Value range of parameter "
                          "exceeded) writing 60C2h:02")
    assert "value -3 from cantrack" in msg


def test_sdo_abort_of_a_bus_yml_write(stepped_controller, cfg):
    world, ctl = stepped_controller(cfg)
    world.device("x").reject_sdo(0x6065, 0, 0x06010002)
    with pytest.raises(BootError, match=r"node 11 \(x\): SDO abort 06010002h \(Attempt to write "
                                        r"a read only object\) writing 6065h:00 .*from bus.yml"):
        ctl.boot()


def test_sdo_timeout(stepped_controller, cfg):
    world, ctl = stepped_controller(cfg)
    world.device("encoder").mute_sdo(True)  # boots, but its SDO server does not answer
    with pytest.raises(SdoTimeoutError, match=r"node 10 \(encoder\): no SDO response within "
                                              r"0.05 s \(2 attempts\) reading 1000h:00"):
        ctl.boot()
