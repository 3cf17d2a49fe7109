"""cantrack against an independent CANopen stack (CANopenNode) on a real SocketCAN vcan0.

The sources of CANopenNode, CANopenLinux and CANopenDemo (Apache-2.0) are built by the test
harness (:mod:`controller.testing.vendor`: ``$CANTRACK_VENDOR_DIR``, default
``../shared/vendor``; cached).  Where they are absent the tests are skipped with that message;
in CI (``CI=true`` or ``CANTRACK_VCAN_REQUIRED=1``) they fail instead.

One command (one VM boot for the whole module; natively where the kernel has vcan) runs this
file as a script (:func:`orchestrate`) with ``stack.yml``: ``examples/bus/vcan.yml`` (encoder
10, drives x 11, y 12 from ``cantrack sim-devices``, SYNC 100 ms with counter 1..10) plus
CANopenDemo's ``demoLinuxDevice`` as the I/O node ``io`` (node 4, heartbeat 200 ms), which
runs in a respawn loop (canopend-based devices exit on NMT reset node, as a device reboots):

1. ``candump -L vcan0`` records everything;
2. the demo device starts with an empty storage directory: it reports EMCY 5000h
   (non-volatile memory) and refuses NMT start; ``cantrack run`` must fail its boot naming
   that EMCY (exit 2);
3. its parameters are stored (1010h:01 = "save"), NMT reset node: it reboots cleanly;
4. ``cantrack check-bus``: every node answers with the EDS identity, the demo's 1008h
   (segmented SDO upload) is shown;
5. ``cantrack run --duration 4+4w --engage-at 1 --disengage-at 3``: boot (1019h = 10 written
   to the demo device, a SYNC consumer), enable, track; at the 40th SYNC the demo device is
   powered off (killed, no respawn): its heartbeat loss is an event with a reaction, exit 3;
6. ``canopend`` (node 3) with its command socket and ``cocomm`` as an independent SDO client:
   read and write our simulated devices (expedited and segmented), an abort for a missing
   object;
7. can-utils' ``canplayer`` replays the log of a ``cantrack demo`` (made on the host) onto
   vcan0, recorded by a second candump.

On the host the captures are decoded by tshark's CANopen dissector.  The supervision windows
(heartbeat time-outs 4 x 200 ms, SDO and stop time-outs, canopend's SDO client time-out of
500 ms) are stretched by ``w`` = :func:`controller.testing.speed.window_factor` of the host's
measured slowness (``CANTRACK_SPEED_FACTOR`` from the harness,
:mod:`controller.testing.stretch`), the orchestrator's limits by the slowness itself.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VCAN_YML = ROOT / "examples" / "bus" / "vcan.yml"
IO_NODE, GATEWAY_NODE, MASTER = 4, 3, 1
ENCODER, X, Y = 10, 11, 12
SYNC_OVERFLOW = 10
POWER_OFF_AT_SYNC = 40
SYNC_PERIOD_S = 0.1  # (vcan.yml)
#: the run's length after the power-off [s] (x w): time to see the heartbeat time-out
AFTER_POWER_OFF_S = 4.0
#: canopend's SDO client time-out (its gateway's default) on an idle machine [ms]
SDO_TIMEOUT_MS = 500
CANTRACK = [sys.executable, "-m", "controller.cli"]
#: "save" (CiA 301 1010h signature, little endian)
SAVE = b"save"


def stack_yml(out: Path, demo_eds: Path, factor: float) -> Path:
    """``vcan.yml`` (EDS paths made absolute) plus the demo device as slave ``io``, its
    supervision windows stretched by ``factor``."""
    from controller.testing.stretch import stretch_bus_config

    text = VCAN_YML.read_text().replace("../../eds/", f"{ROOT / 'eds'}/")
    # heartbeat time-outs of 10 x 200 ms on an idle machine: with more processes than the
    # controller tier (the demo device, its respawn loop) the VM stalls for up to a second
    # at times (every node's heartbeat late at once); x the window factor on a busy one
    assert "heartbeat_multiplier: 4.0" in text
    text = text.replace("heartbeat_multiplier: 4.0", "heartbeat_multiplier: 10.0", 1)
    io = (f"io:\n  dcf: {demo_eds}\n  node_id: {IO_NODE}\n  heartbeat_producer: 200\n\n")
    text = text.replace("\n.tracking:", "\n" + io + ".tracking:", 1)
    p = out / "stack-idle.yml"
    p.write_text(text)
    return stretch_bus_config(p, out / "stack.yml", factor)


# ---------------------------------------------------------------------------------------------
# the orchestrator (runs inside the VM / on the native vcan0)

class Respawn:
    """A canopend-based device that reboots (respawns) after NMT reset node, until
    :meth:`power_off`."""

    def __init__(self, argv: list[str], log: Path) -> None:
        self.argv = argv
        self.log = log.open("ab")
        self.proc: subprocess.Popen | None = None
        self.starts = 0
        self._off = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def start(self) -> Respawn:
        self._thread.start()
        return self

    def _loop(self) -> None:
        while not self._off.is_set():
            self.proc = subprocess.Popen(self.argv, stdout=self.log, stderr=subprocess.STDOUT)
            self.starts += 1
            self.proc.wait()

    def power_off(self) -> None:
        self._off.set()
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        self._thread.join(timeout=10)
        self.log.close()


class Watch:
    """The orchestrator's own socket: wait for a frame (a cue, never a sleep)."""

    def __init__(self, channel: str) -> None:
        import can
        # (the kernel filters: only what the waits look for reaches this process - SYNC, the
        #  demo device's SDO answers, boot-ups - a busy VM has no CPU to spare)
        ids = (0x80, 0x580 + IO_NODE, 0x700 + IO_NODE, 0x700 + GATEWAY_NODE)
        self.bus = can.Bus(interface="socketcan", channel=channel, receive_own_messages=False,
                           can_filters=[{"can_id": i, "can_mask": 0x7FF} for i in ids])

    def wait(self, pred, timeout_s: float, what: str, count: int = 1, proc=None):
        from controller.testing.speed import scaled

        timeout_s = scaled(timeout_s)
        t_end = time.monotonic() + timeout_s
        seen = 0
        while True:
            if proc is not None and proc.poll() is not None:
                raise RuntimeError(f"{proc.args[:4]} exited with {proc.returncode} while "
                                   f"waiting for {what}")
            if time.monotonic() > t_end:
                raise RuntimeError(f"no {what} within {timeout_s} s ({seen} of {count})")
            msg = self.bus.recv(0.2)
            if msg is not None and pred(msg):
                seen += 1
                if seen >= count:
                    return msg

    def send(self, can_id: int, data: bytes) -> None:
        import can
        self.bus.send(can.Message(arbitration_id=can_id, data=data, is_extended_id=False))

    def close(self) -> None:
        self.bus.shutdown()


def _bootup(node: int):
    return lambda m: m.arbitration_id == 0x700 + node and bytes(m.data) == b"\x00"


def _cmd(argv: list[str], log: Path, timeout_s: float) -> dict:
    from controller.testing.speed import scaled

    t0 = time.monotonic()
    r = subprocess.run(argv, capture_output=True, timeout=scaled(timeout_s), check=False)
    log.write_bytes(r.stdout + b"\n--- stderr ---\n" + r.stderr)
    return {"rc": r.returncode, "stdout": r.stdout.decode(errors="replace"),
            "stderr": r.stderr.decode(errors="replace"), "s": round(time.monotonic() - t0, 2)}


def orchestrate(out: Path, channel: str, stack_root: Path, demo_log: Path) -> int:
    from controller.testing.candump import CandumpCapture
    from controller.testing.speed import scaled, speed_factor, window_factor
    from controller.testing.vendor import stack_at

    stack = stack_at(stack_root, ())
    out.mkdir(parents=True, exist_ok=True)
    # (the windows' factor from the harness's measurement on the host, CANTRACK_SPEED_FACTOR)
    f = window_factor()
    cfg = stack_yml(out, stack.demo_eds, f)
    duration_s = POWER_OFF_AT_SYNC * SYNC_PERIOD_S + AFTER_POWER_OFF_S * f
    bus = ["-i", "socketcan", "-c", channel]
    res: dict = {"ok": False, "steps": {}, "speed_factor": speed_factor(),
                 "window_factor": f}
    steps = res["steps"]
    t0 = time.monotonic()
    marks: dict[str, float] = {}

    def mark(name: str) -> None:
        marks[name] = round(time.monotonic() - t0, 2)

    cap = CandumpCapture(channel, out / "bus.log").start()
    watch = Watch(channel)
    storage = out / "io-storage"
    storage.mkdir(exist_ok=True)
    sim_log = open(out / "sim.out", "wb")  # noqa: SIM115
    sim = subprocess.Popen(CANTRACK + ["sim-devices", str(cfg), *bus, "-q", "--only", "encoder",
                                       "x", "y", "--ready-file", str(out / "ready.json")],
                           stdout=sim_log, stderr=subprocess.STDOUT)
    io = Respawn([str(stack.demo_device), channel, "-i", str(IO_NODE), "-s", f"{storage}/"],
                 out / "io.out")
    gateway = None
    try:
        from controller.testing.e2e import wait_file
        io.start()
        watch.wait(_bootup(IO_NODE), 30, "boot-up of the demo device")
        wait_file(out / "ready.json", [sim], 90)
        mark("devices_ready")
        # 2. a fresh device (no storage files): EMCY 5000h, NMT start refused -> boot error
        steps["boot_fresh"] = _cmd(CANTRACK + ["run", str(cfg), *bus, "-q", "--duration", "2",
                                               "--report", str(out / "run_fresh.json")],
                                   out / "run_fresh.out", 120)
        mark("boot_fresh")
        # 3. store the parameters, NMT reset node: it reboots with its storage files
        watch.send(0x600 + IO_NODE, bytes((0x23, 0x10, 0x10, 0x01)) + SAVE)
        # (the answer to this download of 1010h:01, not a late one to the failed run's SDOs)
        ans = watch.wait(lambda m: m.arbitration_id == 0x580 + IO_NODE
                         and bytes(m.data[1:4]) == b"\x10\x10\x01", 10, "answer to 1010h")
        steps["save"] = bytes(ans.data).hex()
        starts = io.starts
        watch.send(0x000, bytes((0x81, IO_NODE)))
        watch.wait(_bootup(IO_NODE), 30, "boot-up after NMT reset node")
        steps["io_restarts"] = io.starts - starts
        # 4. check-bus: identity of every node, the demo device's name (segmented SDO)
        steps["check_bus"] = _cmd(CANTRACK + ["check-bus", str(cfg), *bus, "--no-pdos",
                                              "--json", str(out / "check-bus.json")],
                                  out / "check-bus.out", 120)
        mark("check_bus")
        # 5. the run; the demo device powered off at the 40th SYNC
        run_log = open(out / "run.out", "wb")  # noqa: SIM115
        run = subprocess.Popen(CANTRACK + ["run", str(cfg), *bus, "-q", "--duration",
                                           f"{duration_s:.1f}",
                                           "--engage-at", "1", "--disengage-at", "3",
                                           "--report", str(out / "run.json")],
                               stdout=run_log, stderr=subprocess.STDOUT)
        try:
            try:
                watch.wait(lambda m: m.arbitration_id == 0x80, 120, "SYNCs of the run",
                           count=POWER_OFF_AT_SYNC, proc=run)
                steps["io_powered_off"] = True
            except RuntimeError as exc:  # the run ended (or stalled) before the cue
                steps["io_powered_off"] = str(exc)
            io.power_off()
            mark("io_off")
        finally:
            steps["run_rc"] = run.wait(timeout=scaled(120))
            run_log.close()
        mark("run_done")
        # 6. cocomm through canopend (node 3) as an independent SDO client
        # (a unix socket cannot be bound on the VM's 9p share: a tmpfs instead)
        sock_dir = Path(tempfile.mkdtemp(dir="/run" if os.access("/run", os.W_OK) else None))
        sock = sock_dir / "co.sock"
        gw_storage = out / "gw-storage"
        gw_storage.mkdir(exist_ok=True)
        gateway = subprocess.Popen([str(stack.canopend), channel, "-i", str(GATEWAY_NODE),
                                    "-s", f"{gw_storage}/", "-c", f"local-{sock}"],
                                   stdout=open(out / "canopend.out", "wb"),  # noqa: SIM115
                                   stderr=subprocess.STDOUT)
        watch.wait(_bootup(GATEWAY_NODE), 30, "boot-up of canopend")
        t_end = time.monotonic() + scaled(30)
        while not sock.exists() and time.monotonic() < t_end:
            time.sleep(0.05)
        cocomm = []
        for line in (f"[0] set sdo_timeout {round(SDO_TIMEOUT_MS * f)}",
                     f"[1] {X} read 0x1018 1 u32",
                     f"[2] {X} read 0x1008 0 vs",
                     f"[3] {X} write 0x6065 0 u32 123456",
                     f"[4] {X} read 0x6065 0 u32",
                     f"[5] {ENCODER} read 0x1000 0 x32",
                     f"[6] {X} read 0x2FFF 0 u32",
                     f"[7] {IO_NODE} read 0x1000 0 x32"):
            r = subprocess.run([str(stack.cocomm), "-s", str(sock), line], capture_output=True,
                               timeout=scaled(30), check=False)
            cocomm.append({"cmd": line, "rc": r.returncode,
                           "out": r.stdout.decode(errors="replace").strip(),
                           "err": r.stderr.decode(errors="replace").strip()})
        steps["cocomm"] = cocomm
        gateway.send_signal(signal.SIGTERM)
        gateway.wait(timeout=scaled(10))
        mark("cocomm")
        sim.send_signal(signal.SIGTERM)
        steps["sim_rc"] = sim.wait(timeout=scaled(30))
        # 7. canplayer replays the demo's log (every frame, at its recorded times: 2 s)
        channels = sorted({line.split()[1] for line in demo_log.read_text().splitlines()
                           if line.startswith("(")})
        steps["demo_log_channels"] = channels
        with CandumpCapture(channel, out / "replayed.log") as _rep:
            assign = [f"{channel}={c}" for c in channels]
            steps["canplayer"] = _cmd(["canplayer", "-I", str(demo_log), *assign],
                                      out / "canplayer.out", 120)
            # the cue: candump has written every frame (it reads its socket behind), or its
            # file stopped growing (the rest is in its stdio buffer, flushed at its exit)
            n = sum(1 for line in demo_log.read_text().splitlines() if line.startswith("("))
            t_end, last, still = time.monotonic() + scaled(60), -1, 0
            while time.monotonic() < t_end and still < 20:
                text = (out / "replayed.log").read_text(errors="replace")
                if text.count("\n") >= n:
                    break
                still = still + 1 if len(text) == last else 0
                last = len(text)
                time.sleep(0.1)
        steps["replayed_dropped"] = _rep.info.dropped if _rep.info is not None else None
        mark("canplayer")
        res["ok"] = True
    except Exception as exc:  # noqa: BLE001 -- in result.json; exit code 1
        res["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        io.power_off() if not io._off.is_set() else None
        for p in (gateway, sim):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
        sim_log.close()
        watch.close()
        info = cap.stop()
        res.update({"capture_frames": info.frames, "capture_dropped": info.dropped,
                    "marks_s": marks})
        (out / "result.json").write_text(json.dumps(res, indent=1))
    return 0 if res["ok"] else 1


# ---------------------------------------------------------------------------------------------
# the tests

pytestmark = pytest.mark.vcan


def _tail(path: Path) -> str:
    return path.read_text(errors="replace")[-2500:] if path.is_file() else "(none)"


class Session:
    def __init__(self, out: Path, tshark: str) -> None:
        from controller.testing.capture import classify_capture
        self.out = out
        self.result = json.loads((out / "result.json").read_text())
        self.steps = self.result["steps"]
        self.frames = classify_capture(out / "bus.log", tshark=tshark)

    def report(self, name: str) -> dict:
        return json.loads((self.out / name).read_text())


@pytest.fixture(scope="module")
def session(canopen_stack, vcan_runner, tshark_path, tmp_path_factory) -> Session:
    scratch = tmp_path_factory.mktemp("independent-stack")
    demo = scratch / "demo"
    r = subprocess.run(CANTRACK + ["demo", "-o", str(demo), "--items", "1", "--duration", "2",
                                   "-q"], capture_output=True, cwd=ROOT, timeout=300,
                       check=False)
    assert r.returncode == 0, r.stderr[-2000:]
    out = scratch / "stack"
    r = vcan_runner.run([sys.executable, str(Path(__file__).resolve()), "--out", str(out),
                         "--stack", str(canopen_stack.root), "--demo-log",
                         str(demo / "bus.log")], timeout_s=400, scratch_dir=scratch, cwd=ROOT)
    res = out / "result.json"
    ok = r.returncode == 0 and not r.timed_out and res.is_file()
    assert ok, (f"orchestrator failed ({r.mode}, rc {r.returncode}, timed out {r.timed_out})\n"
                f"--- result.json ---\n{_tail(res)}\n--- stderr ---\n{r.stderr[-3000:]}\n"
                f"--- run ---\n{_tail(out / 'run.out')}\n--- io ---\n{_tail(out / 'io.out')}"
                f"\n--- sim ---\n{_tail(out / 'sim.out')}")
    s = Session(out, tshark_path)
    s.demo_log = demo / "bus.log"
    return s


def test_capture_is_clean_canopen(session):
    from controller.testing.capture import problems

    assert session.result["capture_dropped"] == 0
    bad = problems(session.frames)
    assert not bad, f"{len(bad)} of {len(session.frames)} frames:\n" + "\n".join(bad[:30])


def test_boot_error_names_the_emcy_of_a_node_that_refuses_start(session):
    step = session.steps["boot_fresh"]
    assert step["rc"] == 2, step
    err = step["stderr"] + step["stdout"]
    assert f"node {IO_NODE} (io)" in err and "NMT start not confirmed" in err, err
    # CANopenNode: 5000h with its error bit 2Fh (CO_EM_NON_VOLATILE_MEMORY) first
    assert "during the boot the node sent EMCY 5000h (device hardware - generic error)" \
        in err and "manufacturer bytes 2F" in err, err


def test_check_bus_against_canopennode_device(session):
    step = session.steps["check_bus"]
    assert step["rc"] == 0, step
    rep = json.loads((session.out / "check-bus.json").read_text())
    text = json.dumps(rep)
    assert "CANopenDemoLinux" in text, text[:3000]  # 1008h: a segmented SDO upload
    assert session.steps["save"][:2] == "60", session.steps["save"]  # 1010h:01 "save" ok
    assert session.steps["io_restarts"] == 1


def test_run_with_canopennode_device_and_its_power_off(session):
    rep = session.report("run.json")
    assert session.steps["io_powered_off"] is True, session.steps["io_powered_off"]
    assert session.steps["run_rc"] == 3, _tail(session.out / "run.out")
    reactions = [e for e in rep["events"] if e["reaction"]]
    assert reactions, rep["events"]
    first = reactions[0]
    assert (first["kind"], first["node"]) == ("io_node_lost", IO_NODE), reactions
    assert first["reaction"] == "quick stop of all drives"
    assert all(d["confirmed"] for d in rep["drives"]), rep["drives"]
    assert first["cycle"] >= POWER_OFF_AT_SYNC - 1, first
    assert not [e for e in rep["events"] if e["kind"] == "emcy"], rep["events"]
    # tracking ran (engaged at --engage-at 1) before the power-off
    assert ("running", "SYNCING") in [(c["phase"], c["state"]) for c in rep["state_changes"]]


def test_1019h_written_to_the_canopennode_device_at_boot(session):
    """The SDO download 1019h:00 = sync_overflow to node 4 during the boot of the run."""
    from controller.testing.capture import Kind
    writes = [f for f in session.frames if f.kind is Kind.SDO and f.node_id == IO_NODE
              and f.direction == "rx" and f.sdo_index == 0x1019]
    assert writes, "no SDO write of 1019h to node 4"
    assert all(f.data[4] == SYNC_OVERFLOW for f in writes), writes


def _cocomm(session) -> dict[str, dict]:
    return {c["cmd"].split("]")[0].lstrip("["): c for c in session.steps["cocomm"]}


def test_cocomm_reads_and_writes_our_simulated_devices(session):
    """cocomm prints the value on stdout, ``[seq] OK`` / ``[seq] ERROR:<abort code>`` on
    stderr."""
    c = _cocomm(session)
    assert c["0"]["rc"] == 0 and "[0] OK" in c["0"]["err"], c["0"]  # the stretched time-out
    assert (c["1"]["rc"], c["1"]["out"]) == (0, str(0x00CA7AC0)), c["1"]  # vendor-ID
    assert (c["2"]["rc"], c["2"]["out"]) == (0, '"cantrack servo"'), c["2"]  # segmented
    assert c["3"]["rc"] == 0 and "[3] OK" in c["3"]["err"], c["3"]
    assert (c["4"]["rc"], c["4"]["out"]) == (0, "123456"), c["4"]  # written, read back
    assert (c["5"]["rc"], c["5"]["out"]) == (0, "0x00020196"), c["5"]  # encoder device type
    assert c["6"]["rc"] == 1 and "ERROR:0x06020000" in c["6"]["err"], c["6"]  # no object
    # the demo device was powered off: nobody answers, cocomm's own SDO time-out
    assert c["7"]["rc"] == 1 and "ERROR:0x05040000" in c["7"]["err"], c["7"]


def test_canplayer_replays_the_demo_log(session):
    from controller.testing.capture import read_log
    step = session.steps["canplayer"]
    assert all(len(c) <= 15 for c in session.steps["demo_log_channels"]), session.steps
    assert step["rc"] == 0, step
    sent = [(m.arbitration_id, bytes(m.data)) for m in read_log(session.demo_log)]
    got = [(m.arbitration_id, bytes(m.data)) for m in read_log(session.out / "replayed.log")]
    assert got == sent


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--stack", type=Path, required=True)
    ap.add_argument("--demo-log", type=Path, required=True)
    ap.add_argument("--channel", default=os.environ.get("CANTRACK_CAN_CHANNEL", "vcan0"))
    a = ap.parse_args()
    sys.exit(orchestrate(a.out, a.channel, a.stack, a.demo_log))
