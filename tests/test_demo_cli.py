"""``cantrack demo``, ``cantrack run`` and ``cantrack sim-devices`` from the command line.

The demo runs in stepped time (seconds); ``run`` and ``sim-devices`` are checked for their
errors and, in real time on an in-process virtual bus, against each other (threads: python-
can's virtual interface does not reach other processes).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
from pathlib import Path

import can

from controller.canopen.config import load_config
from controller.canopen.io.transport import RealtimeTransport, virtual_bus
from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.master.cycle import Controller
from controller.canopen.testing import bus_yml, bus_yml_text
from controller.cli import demo as cmd_demo
from controller.cli import sim_devices as cmd_sim
from controller.testing.e2e import wait_file

ROOT = Path(__file__).resolve().parents[1]


def cli(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "controller.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=120,
                          env={**os.environ, **(env or {})})


def test_demo_command(tmp_path):
    out = tmp_path / "demo-out"
    r = cli("demo", "-q", "--items", "2", "-o", out)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert "items placed 2, missed 0, of 2" in r.stdout
    assert (out / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # the bus log is candump format: python-can reads it back
    msgs = list(can.CanutilsLogReader(str(out / "bus.log")))
    ids = [m.arbitration_id for m in msgs]
    assert ids[:5] == [0x000] * 5 and all(m.data[0] == 0x81 for m in msgs[:5])  # NMT reset
    syncs = [m for m in msgs if m.arbitration_id == 0x80]
    assert [m.data[0] for m in syncs[:17]] == list(range(1, 17)) + [1]
    assert {0x18A, 0x18B, 0x20B, 0x20E, 0x701, 0x70E} <= set(ids)
    lines = [json.loads(line) for line in (out / "telemetry.jsonl").read_text().splitlines()]
    assert lines[0]["type"] == "run" and lines[0]["axes"] == ["x", "y", "z", "c"]
    cycles = [d for d in lines if d["type"] == "cycle"]
    assert lines[-1]["type"] == "end" and lines[-1]["end"] == "end"
    assert len(cycles) == lines[-1]["cycles"] and cycles[-1]["phase"] == "stopped"
    items = [d for d in lines if d["type"] == "item"]
    assert [i["outcome"] for i in items] == ["placed", "placed"]
    assert all(i["max_error_mm"] < 0.2 for i in items)
    # the demo runs on the conveyor model: per-item records of the robot group, its IMFS
    assert [i["model"]["status"] for i in items] == ["caught", "caught"]
    assert all(i["model"]["time_to_sync_s"] > 0 for i in items)
    assert {d["imfs"] for d in cycles if d["phase"] == "running"} == {0, 1, -1}
    assert {d["kind"] for d in lines if d["type"] == "event"} >= {"boot", "enabled"}


def test_demo_in_process_catches_follows_and_places(tmp_path, capsys):
    assert cmd_demo.main(["-q", "--no-plot", "--items", "3", "-o", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "items placed 3, missed 0, of 3" in out
    assert "bus load 55.3 % (1106 bit per 2 ms cycle" in out  # unchanged by the model
    table = out.splitlines()[1:4]
    for row in table:  # item, outcome, trigger, sync after, max error, u at pick
        fields = row.split()
        assert fields[1] == "placed"
        assert 0.2 < float(fields[3]) < 1.0  # time to synchronise [s]
        assert float(fields[4]) < 0.2  # tracking error while following [mm]
        assert 250 <= float(fields[5]) < 900  # picked inside the window


def test_demo_bad_config_is_one_line(tmp_path):
    p = bus_yml(tmp_path, text=bus_yml_text().replace("  sync_period: 2000",
                                                      "  sync_period: fast"))
    r = cli("demo", p, "-q")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines()[-1] == (
        f"cantrack: error: {p}:7, key 'master.sync_period': must be an integer, not the "
        "string 'fast'")
    assert "Traceback" not in r.stderr


def test_run_needs_an_interface(tmp_path):
    p = bus_yml(tmp_path)
    r = cli("run", p, "-q", cwd=tmp_path,
            env={"HOME": str(tmp_path), "CAN_INTERFACE": "", "CAN_CHANNEL": ""})
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "cantrack: error: no CAN interface: give -i/--interface" in r.stderr


def test_run_reports_a_missing_node(tmp_path):
    p = bus_yml(tmp_path)
    r = cli("run", p, "-q", "-i", "virtual", "-c", "nobody-here")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert ("cantrack: error: node 10 (encoder): no boot-up message within 0.1 s after NMT "
            "reset node") in r.stderr


def test_run_takes_the_interface_from_the_environment(tmp_path):
    p = bus_yml(tmp_path)
    r = cli("run", p, "-q", env={"CAN_INTERFACE": "virtual", "CAN_CHANNEL": "nobody",
                                 "HOME": str(tmp_path)})
    assert "no boot-up message" in r.stderr  # the bus opened from CAN_INTERFACE


def test_sim_devices_bad_injection(tmp_path):
    p = bus_yml(tmp_path)
    r = cli("sim-devices", p, "-i", "virtual", "-c", "x", "--inject", "1:q:fault")
    assert r.returncode == 2
    assert "unknown node 'q' (one of encoder, x, y)" in r.stderr


def _slow_yml(tmp_path: Path) -> Path:
    """10 ms cycle and generous time-outs: robust on a loaded machine."""
    text = bus_yml_text(period_us=10000).replace(
        "timeouts: {boot_up_s: 0.1, sdo_s: 0.05, enable_s: 0.2}",
        "timeouts: {boot_up_s: 2.0, sdo_s: 1.0, enable_s: 3.0}").replace(
        "    silent_cycles: 5", "    silent_cycles: 20")
    return bus_yml(tmp_path, text=text)


def test_controller_against_sim_devices_in_real_time(tmp_path):
    """sim-devices (a thread) and a real-time controller on one virtual channel."""
    yml = _slow_yml(tmp_path)
    channel = f"sim-{os.getpid()}"
    done = threading.Event()
    errors: list[BaseException] = []

    def devices():
        try:
            cmd_sim.main([str(yml), "-i", "virtual", "-c", channel, "-q", "--duration", "3",
                          "--inject", "0.0:encoder:noise:1", "--ready-file", str(ready)])
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)
        finally:
            done.set()

    ready = tmp_path / "ready.json"
    th = threading.Thread(target=devices, daemon=True)
    th.start()
    # the simulated devices have opened their bus and booted
    wait_file(ready, [], 30, running=lambda: not done.is_set())
    assert not errors, errors
    cfg = load_config(yml)
    transport = RealtimeTransport(virtual_bus(channel))
    ctl = Controller(cfg, transport, ConveyorFollow(5, None, (420.0, 30.0, 0.0),
                                                    end_cycle=60))
    try:
        ctl.boot()
        ctl.run(max_cycles=400)
    finally:
        transport.close()
    done.wait(5)
    assert not errors
    assert "enabled" in [e.kind for e in ctl.events]
    assert ctl.failure is None
    assert len(ctl.timing.sync_interval) > 50  # real-time figures were taken
    assert max(r.state for r in ctl.trace) >= 1  # the tracker engaged


def test_run_checks_the_bus_load_at_the_bitrate_given_on_the_command_line(tmp_path):
    """-b (or CAN_BITRATE / python-can's config) is what the bus runs at: the load is computed
    and refused there, before the bus is opened, not at master.baudrate."""
    p = bus_yml(tmp_path)  # 1000 kbit/s, 2 ms: 32 % load
    r = cli("run", p, "-q", "-i", "virtual", "-c", "bitrate-test", "-b", "125000")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "the bus runs at 125 kbit/s" in r.stderr
    assert "at 125 kbit/s) is above 90 %" in r.stderr
    r = cli("run", p, "-q", "-i", "virtual", "-c", "bitrate-test", env={"CAN_BITRATE": "12345"})
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr
    assert "bitrate 12345 bit/s" in r.stderr and "is not a CANopen bit rate" in r.stderr
