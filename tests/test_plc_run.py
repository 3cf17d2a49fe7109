"""``cantrack run`` with a ``.plc`` section: a PLC commands the controller on the bus, in real
time (python-can's virtual bus; the simulated devices and the PLC in threads of the same
process, since a virtual bus does not cross processes).

The PLC is python canopen: a ``Network`` with its heartbeat (``send_periodic``, 700h + 20h)
and a ``RemoteNode`` of the controller's EDS (SDO client, TPDO1 decoded from the EDS).  It
waits for 2011h = 7 (commands accepted), engages relative, waits for TPDO1 to say SYNCED,
sends three trigger edges over RPDO1, disengages, waits for OFF and ends the run with
SIGTERM.  Every wait is on a cue (an SDO answer, a TPDO), with a generous wall-clock limit.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "examples" / "bus" / "vcan.yml"

_PROGRAM = """
import json, os, signal, sys, threading, time
import canopen
from controller.cli import run as cmd_run
from controller.canopen.io.clock import RealtimeClock
from controller.canopen.config import load_config
from controller.canopen.slave.rack import DeviceRack
from controller.canopen.io.transport import DeviceThread, virtual_bus
from controller.resources import data_path

cfg = load_config(sys.argv[1])
clock = RealtimeClock()
rack = DeviceRack.from_config(cfg, virtual_bus("plc-run"), clock)
th = DeviceThread(rack, clock).start()
seen = {}


def plc():
    try:
        net = canopen.Network(virtual_bus("plc-run"))
        net.connect()
        net.send_periodic(0x720, b"\\x05", 0.1)  # the PLC's heartbeat, 100 ms
        node = canopen.RemoteNode(1, str(data_path("eds", "cantrack-controller.eds")))
        net.add_node(node)
        node.sdo.RESPONSE_TIMEOUT = 2.0
        node.tpdo.read(from_od=True)
        tp1 = node.tpdo[1]

        def until(what, pred, limit_s=60.0):
            t_end = time.monotonic() + limit_s
            while not pred():
                if time.monotonic() > t_end:
                    raise RuntimeError("no " + what)
                time.sleep(0.02)  # (polling a cue: each pass reads the bus)

        def access():
            try:
                return node.sdo[0x2011].raw
            except canopen.SdoCommunicationError:
                return None  # (the controller is not on the bus yet)

        until("2011h = 7", lambda: access() == 7)
        seen["access"] = node.sdo[0x2011].raw
        seen["name"] = node.sdo[0x1008].raw
        def engaged():
            try:
                node.sdo[0x2005].raw = 5
                return True
            except canopen.SdoAbortedError as exc:
                if exc.code != 0x08000022:
                    raise
                return False  # (the controller is still enabling its drives: docs/plc.md)

        until("engage taken", engaged)
        until("SYNCED", lambda: node.sdo[0x2000].raw == 2)
        tp1.wait_for_reception(5.0)
        seen["tpdo1_state"] = tp1["Tracker state"].raw
        for _ in range(3):
            net.send_message(0x201, bytes([5, 1]))
            time.sleep(0.06)  # (three cycles apart: one edge each)
            net.send_message(0x201, bytes([5, 0]))
            time.sleep(0.06)
        until("3 items", lambda: node.sdo[0x2003].raw == 3)
        seen["items"] = node.sdo[0x2003].raw
        net.send_message(0x201, bytes([0, 0]))
        until("OFF", lambda: node.sdo[0x2000].raw == 0)
        seen["refused"] = node.sdo[0x2012].raw
        seen["dropped"] = node.sdo[0x2013].raw
        err = node.sdo[0x2007].raw
        seen["error_mm"] = err
        net.disconnect()
    except Exception as exc:
        seen["error"] = repr(exc)
    finally:
        json.dump(seen, open(sys.argv[3], "w"))
        os.kill(os.getpid(), signal.SIGTERM)


threading.Thread(target=plc, daemon=True).start()
rc = cmd_run.main([sys.argv[1], "-i", "virtual", "-c", "plc-run", "-q",
                   "--report", sys.argv[2]])
th.stop()
sys.exit(rc)
"""


def test_run_with_a_plc_section_is_commanded_by_the_plc(tmp_path):
    text = CONFIG.read_text().replace("../../eds/", f"{ROOT / 'eds'}/")
    text = text.replace("sync_period: 100000", "sync_period: 20000")
    text += ("\n.plc:\n  commander: 0x20\n  commander_heartbeat_ms: 600\n"
             "  on_commander_lost: desync\n")
    cfg = tmp_path / "bus.yml"
    cfg.write_text(text)
    report, seen_file = tmp_path / "run.json", tmp_path / "plc.json"
    out = subprocess.run([sys.executable, "-c", _PROGRAM, str(cfg), str(report),
                          str(seen_file)], capture_output=True, text=True, cwd=ROOT,
                         timeout=300)
    seen = json.loads(seen_file.read_text())
    assert "error" not in seen, (seen, out.stdout, out.stderr)
    assert out.returncode == 0, out.stdout + out.stderr
    assert "plc node: id 1, SDO 601h/581h, RPDO1 201h, RPDO2 301h, TPDO1 181h, TPDO2 281h, TPDO3 381h; " \
        "commander node 32 (heartbeat 600 ms, on loss: desync)" in out.stderr
    assert seen["access"] == 7 and seen["name"] == "cantrack controller"
    assert seen["tpdo1_state"] in (1, 2) and seen["items"] == 3
    assert seen["refused"] == 0 and seen["dropped"] == 0
    assert seen["error_mm"] == 0.0  # OFF
    assert "plc node: 3 triggers taken, 0 dropped, 0 commands refused" in out.stdout
    rep = json.loads(report.read_text())
    assert rep["end"] == "sigterm" and rep["exit_code"] == 0
    states = [c["state"] for c in rep["state_changes"]]
    assert "SYNCED" in states and states[-1] in ("OFF", "DESYNCING")
