"""Our simulated drive against an independent CiA 402 state machine: python canopen's
``BaseNode402``.

``BaseNode402`` reads the drive's PDO configuration by SDO (1400h-1A03h), decodes the
statusword with its own table (``State402.SW_MASK``) and commands the transitions with its
own controlwords (``State402.TRANSITIONTABLE``) through the RPDO that maps 6040h.  The
simulated devices run in real time in a :class:`DeviceThread` on a python-can virtual bus;
canopen's own SYNC producer and periodic RPDO task drive them (its transitions are blocking
and confirmed by its TPDO reception, with its own time-outs: the cues, no sleeps).
"""

from __future__ import annotations

import threading

import canopen
import pytest
from canopen.profiles.p402 import BaseNode402

from controller.canopen.config import load_config
from controller.canopen.io.clock import RealtimeClock
from controller.canopen.io.transport import DeviceThread, virtual_bus
from controller.canopen.slave.rack import DeviceRack
from controller.canopen.testing import EDS_DIR, bus_yml

SYNC_S = 0.01
X = 11


@pytest.fixture
def drive(tmp_path):
    cfg = load_config(bus_yml(tmp_path, axes=("x",), period_us=int(SYNC_S * 1e6)))
    channel = f"bn402-{tmp_path.name}"
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    node = BaseNode402(X, str(EDS_DIR / "cantrack-servo.eds"))
    net.add_node(node)
    booted = threading.Event()  # the cue: the simulated drive's boot-up message
    net.subscribe(0x700 + X, lambda can_id, data, t: booted.set() if data == b"\x00" else None)
    clock = RealtimeClock()
    rack = DeviceRack.from_config(cfg, virtual_bus(channel), clock, present=["x"])
    th = DeviceThread(rack, clock).start()
    assert booted.wait(10.0), "no boot-up of the simulated drive"
    # generous single-transition time-outs: the machine is shared (still cues: each returns
    # as soon as the statusword confirms)
    node.TIMEOUT_SWITCH_STATE_SINGLE = node.TIMEOUT_SWITCH_STATE_FINAL = 5.0
    node.TIMEOUT_CHECK_TPDO = node.TIMEOUT_SWITCH_OP_MODE = 5.0
    node.nmt.state = "PRE-OPERATIONAL"  # (what it is after its boot-up)
    node.setup_402_state_machine()
    net.sync.start(SYNC_S)
    rpdo = node.rpdo_pointers[0x6040].pdo_parent
    rpdo.start(SYNC_S)
    node.nmt.state = "OPERATIONAL"
    node.check_statusword()
    try:
        yield node, rack.devices["x"]
    finally:
        rpdo.stop()
        net.sync.stop()
        net.disconnect()
        th.stop()
        rack.bus.shutdown()


def _hold_position(node: BaseNode402) -> int:
    """607Ah = 6064h (from the TPDO) before enabling: no jump (the ecosystem's rule)."""
    node.check_statusword()
    actual = node.tpdo_values[0x6064]
    node.rpdo_pointers[0x607A].raw = actual
    return actual


def test_basenode402_walks_our_drive_to_operation_enabled_and_back(drive):
    node, sim = drive
    assert 0x6041 in node.tpdo_values and 0x6040 in node.rpdo_pointers  # found in the PDOs
    assert node.state == "SWITCH ON DISABLED"
    node.op_mode = "CYCLIC SYNCHRONOUS POSITION"  # SDO 6060h, confirmed by 6061h
    assert node.op_mode == "CYCLIC SYNCHRONOUS POSITION"
    actual = _hold_position(node)
    for target in ("READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED"):
        node.state = target
        assert node.state == target
        assert sim.state.value == target.lower()  # the simulation agrees
    assert abs(node.tpdo_values[0x6064] - actual) <= 1  # enabled without a jump
    node.state = "SWITCH ON DISABLED"  # disable voltage (BaseNode402's controlword 0000h)
    assert node.state == "SWITCH ON DISABLED"


def test_basenode402_quick_stop_and_fault_reset_on_our_drive(drive):
    node, sim = drive
    node.op_mode = "CYCLIC SYNCHRONOUS POSITION"
    node.sdo[0x605A].raw = 6  # quick stop option: ramp, then stay in QUICK STOP ACTIVE
    _hold_position(node)
    node.state = "OPERATION ENABLED"
    node.state = "QUICK STOP ACTIVE"  # BaseNode402's controlword 0002h
    assert sim.state.value == "quick stop active"
    node.state = "SWITCH ON DISABLED"  # transition 12 (disable voltage)
    assert sim.state.value == "switch on disabled"
    _hold_position(node)
    node.state = "OPERATION ENABLED"
    sim.inject_fault(0x2310)  # over-current
    for _ in range(50):  # the fault reaction ramps, then FAULT (each a fresh TPDO)
        node.check_statusword()
        if node.is_faulted():
            break
    assert node.is_faulted() and node.state == "FAULT"
    _hold_position(node)
    node.reset_from_fault()  # BaseNode402's rising edge of bit 7, then on to enabled
    assert node.state == "OPERATION ENABLED"
