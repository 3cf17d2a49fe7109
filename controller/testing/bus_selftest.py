"""A CANopen bus self-test on a real SocketCAN interface, captured with candump.

Run on ``vcan0`` (inside the VM harness or natively)::

    python -m controller.testing.bus_selftest run --channel vcan0 --out DIR

Two processes talk CANopen over python-can's ``socketcan`` interface (canopen 2.x):

- the **device** process (``bus_selftest device``): two :class:`canopen.LocalNode` built from the
  project's EDS files, the encoder (``eds/cantrack-encoder.eds``, node 1) and the servo
  (``eds/cantrack-servo.eds``, node 2).  Each sends its boot-up, goes pre-operational and
  produces its heartbeat (1017 = 100 ms, through the kernel's broadcast manager); SDO server;
  NMT slave; on each SYNC while operational it transmits the encoder's TPDO1 (0x181) and then
  the servo's TPDO1 (0x182); the servo receives RPDO1 (0x202); the servo sends an EMCY
  (0x8611 following error) at its 10th operational SYNC and the EMCY reset at its 20th.
- the **master** (this ``run`` process): starts ``candump -L`` on the interface, starts the
  device process, waits for both pre-operational heartbeats (the boot-ups may come before the
  master listens: the capture has them), reads 1000 and
  1018sub1..4 of both nodes by SDO upload (expedited), writes 6060 = 8 to the servo (SDO
  download), starts all nodes (NMT 0x01 to all), produces SYNC with a counter (1..overflow) at
  the configured period through the broadcast manager (a sequence of SYNC frames, one per
  period), answers each SYNC with the servo's RPDO1, stops SYNC after ``--sync-count`` SYNCs,
  stops node 2 (NMT 0x02), puts all nodes pre-operational (NMT 0x80), stops the device process
  and candump.

Output in ``--out``: ``bus.log`` (candump ``-L``), ``result.json`` (what the master saw: states,
SDO values, EMCYs, PDO counts, SYNC count, capture drops, the configuration) and
``device.json`` (what the device saw).  Exit code 0 when the run completed; the checks of the
bus itself are done on the capture by :mod:`controller.testing.capture` (tshark), not here.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from ..resources import data_path
from .candump import CandumpCapture
from .speed import scaled

EDS_DIR = data_path("eds")
ENCODER_EDS = EDS_DIR / "cantrack-encoder.eds"
SERVO_EDS = EDS_DIR / "cantrack-servo.eds"
ENCODER_ID, SERVO_ID = 1, 2
EMCY_CODE = 0x8611          # following error (CiA 402)
EMCY_AT_SYNC, EMCY_RESET_AT_SYNC = 10, 20
STATE_NAMES = {0: "boot-up", 4: "stopped", 5: "operational", 127: "pre-operational"}


def _connect(channel: str):
    import canopen
    net = canopen.Network()
    net.connect(interface="socketcan", channel=channel)
    return net


# ---------------------------------------------------------------------------------------------
# device process

def device_main(channel: str, out: Path) -> int:
    import canopen

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    net = _connect(channel)
    enc = canopen.LocalNode(ENCODER_ID, str(ENCODER_EDS))
    servo = canopen.LocalNode(SERVO_ID, str(SERVO_EDS))
    net.add_node(enc)
    net.add_node(servo)
    for n in (enc, servo):
        n.tpdo.read(from_od=True)
        n.rpdo.read(from_od=True)
    seen: dict[str, Any] = {"syncs": 0, "operational_syncs": 0, "counters": [], "rpdo1": 0,
            "last_target": None, "emcy": [], "nmt_states": {ENCODER_ID: [], SERVO_ID: []}}
    lock = threading.Lock()

    def on_rpdo(pdo_map):
        with lock:
            seen["rpdo1"] += 1
            seen["last_target"] = pdo_map[1].raw

    servo.rpdo[1].add_callback(on_rpdo)

    def on_sync(can_id, data, timestamp):
        with lock:
            seen["syncs"] += 1
            seen["counters"].append(data[0] if data else None)
            if servo.nmt.state != "OPERATIONAL":
                return
            seen["operational_syncs"] += 1
            k = seen["operational_syncs"]
            tp = enc.tpdo[1]
            tp[0].raw = (k * 100) & 0xFFFFFFFF       # 6004 position value
            tp[1].raw = 100                          # 6030sub1 speed
            tp.transmit()
            ts = servo.tpdo[1]
            ts[0].raw = 0x1237                       # 6041 statusword: operation enabled
            ts[1].raw = seen["last_target"] or 0     # 6064 position actual = last target
            ts.transmit()
            if k == EMCY_AT_SYNC:
                servo.emcy.send(EMCY_CODE, 0x01)
                seen["emcy"].append(EMCY_CODE)
            elif k == EMCY_RESET_AT_SYNC:
                servo.emcy.reset()
                seen["emcy"].append(0)

    net.subscribe(0x80, on_sync)
    for n in (enc, servo):
        n.nmt.send_command(0x81)   # reset node: state INITIALISING -> boot-up frame
        n.nmt.send_command(0x80)   # -> PRE-OPERATIONAL, heartbeat from 1017
    while not stop.wait(0.05):
        pass
    for n in (enc, servo):
        n.nmt.stop_heartbeat()
        seen["nmt_states"][n.id] = n.nmt.state
    net.disconnect()
    (out / "device.json").write_text(json.dumps(seen, indent=1))
    return 0


# ---------------------------------------------------------------------------------------------
# master process

class _Watch:
    """Thread-safe record of heartbeat states and SYNC/PDO/EMCY arrivals seen by the master."""

    def __init__(self):
        self.cv = threading.Condition()
        self.states: dict[int, list[int]] = {ENCODER_ID: [], SERVO_ID: []}
        self.syncs = 0
        self.tpdo = {ENCODER_ID: 0, SERVO_ID: 0}
        self.emcy: list[dict] = []

    def heartbeat(self, node_id):
        def cb(state):
            with self.cv:
                self.states[node_id].append(state)
                self.cv.notify_all()
        return cb

    def wait(self, pred, timeout_s: float, what: str):
        with self.cv:
            if not self.cv.wait_for(pred, timeout=timeout_s):
                raise TimeoutError(f"timed out after {timeout_s:.0f} s waiting for {what}; "
                                   f"heartbeat states so far {self.states}")

    def saw(self, node_id, state) -> bool:
        return state in self.states[node_id]

    def last(self, node_id):
        s = self.states[node_id]
        return s[-1] if s else None


def run_main(channel: str, out: Path, *, sync_period_s: float, sync_overflow: int,
             sync_count: int, wait_s: float) -> int:
    out.mkdir(parents=True, exist_ok=True)
    t_start = time.monotonic()
    marks: dict[str, float] = {}

    def mark(name):
        marks[name] = round(time.monotonic() - t_start, 3)

    cap = CandumpCapture(channel, out / "bus.log").start()
    mark("candump_ready")
    # the device process starts while this one imports canopen (both take seconds in the VM);
    # its boot-up may come before our network is up: candump has it, we wait for heartbeats
    with open(out / "device.out", "wb") as dev_log:
        device = subprocess.Popen([sys.executable, "-m", "controller.testing.bus_selftest",
                                   "device", "--channel", channel, "--out", str(out)],
                                  stdout=dev_log, stderr=subprocess.STDOUT)
    import can
    import canopen

    net = _connect(channel)
    enc = canopen.RemoteNode(ENCODER_ID, str(ENCODER_EDS))
    servo = canopen.RemoteNode(SERVO_ID, str(SERVO_EDS))
    net.add_node(enc)
    net.add_node(servo)
    servo.rpdo.read(from_od=True)
    enc.tpdo.read(from_od=True)
    servo.tpdo.read(from_od=True)
    w = _Watch()
    for n in (enc, servo):
        n.nmt.add_heartbeat_callback(w.heartbeat(n.id))

    def on_tpdo(node_id):
        def cb(_map):
            with w.cv:
                w.tpdo[node_id] += 1
        return cb

    enc.tpdo[1].add_callback(on_tpdo(ENCODER_ID))
    servo.tpdo[1].add_callback(on_tpdo(SERVO_ID))

    def on_emcy(node_id):
        def cb(err):
            with w.cv:
                w.emcy.append({"node": node_id, "code": err.code, "register": err.register})
                w.cv.notify_all()
        return cb

    enc.emcy.add_callback(on_emcy(ENCODER_ID))
    servo.emcy.add_callback(on_emcy(SERVO_ID))

    def on_sync(can_id, data, timestamp):
        with w.cv:
            w.syncs += 1
            n = w.syncs
            w.cv.notify_all()
        if servo.nmt.state == "OPERATIONAL":
            rp = servo.rpdo[1]
            rp[0].raw = 0x000F            # 6040 controlword: enable operation
            rp[1].raw = n * 10            # 607A target position
            rp.transmit()

    net.subscribe(0x80, on_sync)
    mark("master_ready")
    result: dict = {"channel": channel, "sync_period_s": sync_period_s,
                    "sync_overflow": sync_overflow, "sync_count": sync_count,
                    "nodes": {"encoder": ENCODER_ID, "servo": SERVO_ID},
                    "emcy_code": EMCY_CODE}
    ok = False
    try:
        both = (ENCODER_ID, SERVO_ID)
        w.wait(lambda: all(w.last(i) == 127 for i in both), wait_s,
               "pre-operational heartbeats")
        mark("preop")
        sdo = {}
        for n in (enc, servo):
            vals = {"1000": n.sdo[0x1000].raw}
            for sub in (1, 2, 3, 4):
                vals[f"1018sub{sub}"] = n.sdo[0x1018][sub].raw
            sdo[str(n.id)] = vals
        servo.sdo[0x6060].raw = 8
        sdo["2"]["6060_readback"] = servo.sdo[0x6060].raw
        result["sdo"] = sdo
        mark("sdo")
        net.nmt.send_command(0x01)                        # start all nodes
        w.wait(lambda: all(w.last(i) == 5 for i in both), wait_s, "operational heartbeats")
        mark("operational")
        frames = [can.Message(arbitration_id=0x80, data=[c], is_extended_id=False)
                  for c in range(1, sync_overflow + 1)]
        task = net.bus.send_periodic(frames, sync_period_s)   # kernel BCM: one frame per period
        mark("sync_started")
        w.wait(lambda: w.syncs >= sync_count, wait_s + sync_count * sync_period_s * 10,
               f"{sync_count} SYNC")
        task.stop()
        mark("sync_stopped")
        time.sleep(max(0.3, 5 * sync_period_s))       # let the last PDOs arrive
        servo.nmt.send_command(0x02)                   # stop node 2
        w.wait(lambda: w.last(SERVO_ID) == 4, wait_s, "node 2 stopped heartbeat")
        net.nmt.send_command(0x80)                     # all pre-operational
        w.wait(lambda: all(w.last(i) == 127 for i in both), wait_s,
               "pre-operational heartbeats at the end")
        mark("preop_end")
        ok = True
    except Exception as exc:  # noqa: BLE001 -- recorded in result.json; exit code 1
        result["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        device.send_signal(signal.SIGTERM)
        try:
            device.wait(timeout=wait_s)
        except subprocess.TimeoutExpired:
            device.kill()
            device.wait()
        time.sleep(0.2)
        net.disconnect()
        info = cap.stop()
        mark("done")
        with w.cv:
            result.update({
                "ok": ok, "device_returncode": device.returncode,
                "heartbeat_states": {str(k): v for k, v in w.states.items()},
                "syncs_seen": w.syncs, "tpdo1_received": {str(k): v for k, v in w.tpdo.items()},
                "emcy": w.emcy, "capture_frames": info.frames, "capture_dropped": info.dropped,
                "candump_returncode": info.returncode, "marks_s": marks,
                "mode": os.environ.get("CANTRACK_VCAN_MODE", "")})
        (out / "result.json").write_text(json.dumps(result, indent=1))
    return 0 if ok else 1


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m controller.testing.bus_selftest",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("role", choices=("run", "device"), nargs="?", default="run")
    p.add_argument("--channel", default=os.environ.get("CANTRACK_CAN_CHANNEL", "vcan0"))
    p.add_argument("--out", type=Path,
                   default=Path(os.environ.get("CANTRACK_SCRATCH", ".")) / "selftest")
    p.add_argument("--sync-period-ms", type=float, default=50.0,
                   help="SYNC period [ms] (default 50: generous for an emulated VM)")
    p.add_argument("--sync-overflow", type=int, default=10,
                   help="SYNC counter overflow value 2..240 (1019), default 10")
    p.add_argument("--sync-count", type=int, default=40, help="SYNCs to produce, default 40")
    p.add_argument("--wait-s", type=float, default=60.0,
                   help="time-out of each wait for the other process [s] (x the machine's "
                        "measured slowness, controller.testing.speed)")
    a = p.parse_args(argv)
    if not 2 <= a.sync_overflow <= 240:
        p.error(f"--sync-overflow {a.sync_overflow}: allowed 2..240 (CiA 301 object 1019)")
    if a.role == "device":
        return device_main(a.channel, a.out)
    return run_main(a.channel, a.out, sync_period_s=a.sync_period_ms / 1e3,
                    sync_overflow=a.sync_overflow, sync_count=a.sync_count,
                    wait_s=scaled(a.wait_s))


if __name__ == "__main__":
    sys.exit(main())
