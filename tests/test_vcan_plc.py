"""The controller's PLC node on a real SocketCAN vcan0, commanded by CANopenNode.

CANopenLinux's ``canopend`` (built by the harness from ../shared/vendor,
:mod:`controller.testing.vendor`) is the PLC: node 32, the ``commander`` of the ``.plc``
section, its heartbeat set to 100 ms (1017h written through its own gateway); ``cocomm``
(CANopenLinux's command-line client of canopend's gateway) is the independent SDO client.
A second ``canopend`` (node 33, no heartbeat) is "any other node on the bus".

One command (one VM boot for the module; natively where the kernel has vcan) runs this file
as a script (:func:`orchestrate`):

1. ``candump -L vcan0`` records the bus; ``sim-devices`` (encoder, x, y) and canopend 32;
2. ``cantrack run`` with ``examples/bus/vcan.yml`` plus a ``.plc`` section (commander 32,
   consumer time 3 s, reaction ``desync``), ``--engage-at`` not given: the PLC engages;
   every supervision window (the heartbeat time-outs, the gateways' SDO client time-out of
   500 ms) stretched by the host's measured slowness (:mod:`controller.testing.stretch`);
3. cocomm through canopend 32: 2011h until 7, 1008h (segmented), engage 2005h = 5, a value
   refused (06090030h), COB-ID writes (restricted 06090030h, a drive's RPDO 08000000h), a
   configuration object (08000020h), NMT pre-operational (08000022h), start again; the
   item types (2014h, 2015h:2 written and read back, 2015h:0 read-only);
4. cocomm through canopend 33 while 32 is silenced (its 1017h = 0): the commander's heartbeat
   is lost -> the controller de-syncs (event) and every motion write is refused (08000021h);
5. SIGTERM to the run: exit 3 (a fault was seen and handled: the commander's heartbeat
   lost), the report lists the PLC node's events.

On the host the capture is decoded by tshark's CANopen dissector.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
VCAN_YML = ROOT / "examples" / "bus" / "vcan.yml"
MASTER, PLC, OTHER = 1, 32, 33
CANTRACK = [sys.executable, "-m", "controller.cli"]


#: the PLC's heartbeat [ms] and the controller's time-out of it on an idle machine [ms]
PLC_HEARTBEAT_MS, COMMANDER_TIMEOUT_MS = 100, 3000
#: the heartbeat multiplier on an idle machine (the slaves' and the drives' time-outs 3 s:
#: this tier is about the contract, not the timing; x the window factor on a busy one)
HEARTBEAT_MULTIPLIER = 15.0
#: canopend's SDO client time-out (its gateway's default) on an idle machine [ms]
SDO_TIMEOUT_MS = 500


def plc_yml(out: Path, factor: float) -> Path:
    """vcan.yml plus the .plc section, its windows stretched by ``factor``."""
    from controller.testing.stretch import stretch_bus_config

    text = VCAN_YML.read_text().replace("../../eds/", f"{ROOT / 'eds'}/")
    assert "heartbeat_multiplier: 4.0" in text
    text = text.replace("heartbeat_multiplier: 4.0", f"heartbeat_multiplier: {HEARTBEAT_MULTIPLIER}")
    text += (f"\n.plc:\n  commander: {PLC}\n  commander_heartbeat_ms: {COMMANDER_TIMEOUT_MS}\n"
             "  on_commander_lost: desync\n")
    p = out / "plc-idle.yml"
    p.write_text(text)
    return stretch_bus_config(p, out / "plc.yml", factor)


# ---------------------------------------------------------------------------------------------
# the orchestrator (runs inside the VM / on the native vcan0)

class Gateway:
    """canopend with its command socket (on a tmpfs: a unix socket cannot live on 9p)."""

    def __init__(self, canopend: Path, cocomm: Path, channel: str, node: int, out: Path):
        self.cocomm = cocomm
        self.dir = Path(tempfile.mkdtemp(dir="/run" if os.access("/run", os.W_OK) else None))
        self.sock = self.dir / "co.sock"
        storage = out / f"gw{node}-storage"
        storage.mkdir(exist_ok=True)
        self.log = open(out / f"canopend{node}.out", "wb")  # noqa: SIM115
        self.proc = subprocess.Popen([str(canopend), channel, "-i", str(node),
                                      "-s", f"{storage}/", "-c", f"local-{self.sock}"],
                                     stdout=self.log, stderr=subprocess.STDOUT)
        self.seq = 0
        self.done: list[dict] = []

    def ready(self, timeout_s: float = 30.0) -> None:
        from controller.testing.speed import scaled

        t_end = time.monotonic() + scaled(timeout_s)
        while not self.sock.exists():
            if self.proc.poll() is not None or time.monotonic() > t_end:
                raise RuntimeError(f"canopend: no command socket {self.sock}")
            time.sleep(0.05)

    def __call__(self, command: str, tag: str | None = None) -> dict:
        for _ in range(3):  # (cocomm's own SDO time-out, 05040000h, on a loaded VM: again)
            self.seq += 1
            line = f"[{self.seq}] {command}"
            r = subprocess.run([str(self.cocomm), "-s", str(self.sock), line],
                               capture_output=True, timeout=30, check=False)
            res = {"tag": tag or command, "cmd": line, "rc": r.returncode,
                   "out": r.stdout.decode(errors="replace").strip(),
                   "err": r.stderr.decode(errors="replace").strip()}
            self.done.append(res)
            if "ERROR:0x05040000" not in res["err"]:
                break
        return res

    def until(self, command: str, value: str, timeout_s: float, tag: str) -> dict:
        from controller.testing.speed import scaled

        timeout_s = scaled(timeout_s)
        t_end = time.monotonic() + timeout_s
        while True:
            r = self(command, tag)
            if r["rc"] == 0 and r["out"] == value:
                return r
            if time.monotonic() > t_end:
                raise RuntimeError(f"{command}: not {value} within {timeout_s} s ({r})")
            time.sleep(0.5)  # (each pass is an SDO round trip: the cue is the answer)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
        self.log.close()


def orchestrate(out: Path, channel: str, canopend: Path, cocomm: Path) -> int:
    from controller.testing.candump import CandumpCapture
    from controller.testing.e2e import wait_file
    from controller.testing.speed import scaled, speed_factor, window_factor

    out.mkdir(parents=True, exist_ok=True)
    # (the windows' factor from the harness's measurement on the host, CANTRACK_SPEED_FACTOR)
    f = window_factor()
    cfg = plc_yml(out, f)
    bus = ["-i", "socketcan", "-c", channel]
    res: dict = {"ok": False, "speed_factor": speed_factor(), "window_factor": f}
    cap = CandumpCapture(channel, out / "bus.log").start()
    sim_log = open(out / "sim.out", "wb")  # noqa: SIM115
    run_log = open(out / "run.out", "wb")  # noqa: SIM115
    sim = subprocess.Popen(CANTRACK + ["sim-devices", str(cfg), *bus, "-q",
                                       "--ready-file", str(out / "ready.json")],
                           stdout=sim_log, stderr=subprocess.STDOUT)
    plc = Gateway(canopend, cocomm, channel, PLC, out)
    other = None
    run = None
    try:
        plc.ready()
        plc(f"set sdo_timeout {round(SDO_TIMEOUT_MS * f)}", "plc sdo time-out")
        plc(f"{PLC} write 0x1017 0 u16 {PLC_HEARTBEAT_MS}", "plc heartbeat on")  # (local)
        wait_file(out / "ready.json", [sim], 90)
        run = subprocess.Popen(CANTRACK + ["run", str(cfg), *bus, "-q", "--duration", "120",
                                           "--report", str(out / "run.json")],
                               stdout=run_log, stderr=subprocess.STDOUT)
        plc.until(f"{MASTER} read 0x2011 0 u8", "7", 120, "access")
        plc(f"{MASTER} read 0x1008 0 vs", "name")
        plc(f"{MASTER} read 0x2020 1 u8", "commander")
        # (2011h = 7 already while the drives are enabled; the engage is taken (and answered
        #  OK) once tracking runs: 08000022h before)
        t_end = time.monotonic() + scaled(60)
        while plc(f"{MASTER} write 0x2005 0 u8 5", "engage")["rc"] != 0:
            if time.monotonic() > t_end:
                raise RuntimeError("the engage was never taken")
            time.sleep(0.5)
        plc.until(f"{MASTER} read 0x2000 0 u8", "2", 60, "synced")
        plc(f"{MASTER} write 0x2005 0 u8 0", "disengage")  # (before x reaches its limit)
        plc(f"{MASTER} write 0x2005 0 u8 4", "bad engage value")
        plc(f"{MASTER} write 0x1800 1 u32 0x20B", "cob-id change while valid")
        plc(f"{MASTER} write 0x1800 1 u32 0x80000181", "tpdo1 off")
        plc(f"{MASTER} write 0x1800 1 u32 0x000", "cob-id nmt")
        plc(f"{MASTER} write 0x1800 1 u32 0x20B", "cob-id drive x rpdo1")
        plc(f"{MASTER} write 0x1800 1 u32 0x181", "tpdo1 on")
        plc(f"{MASTER} write 0x1017 0 u16 10", "config owned")
        plc(f"{MASTER} preop", "nmt preop")
        plc.until(f"{MASTER} read 0x2011 0 u8", "6", 30, "access preop")
        plc(f"{MASTER} write 0x2005 0 u8 0", "disengage in preop")
        plc(f"{MASTER} start", "nmt start")
        plc.until(f"{MASTER} read 0x2011 0 u8", "7", 30, "access again")
        plc(f"{MASTER} write 0x2014 0 u8 3", "trigger type")  # item types (2014h, 2015h)
        plc(f"{MASTER} read 0x2014 0 u8", "trigger type read")
        plc(f"{MASTER} write 0x2015 2 u32 5", "tracked types")
        plc(f"{MASTER} read 0x2015 2 u32", "tracked types read")
        plc(f"{MASTER} write 0x2015 0 u8 8", "tracked types sub0")
        # the commander falls silent; another node tries
        other = Gateway(canopend, cocomm, channel, OTHER, out)
        other.ready()
        other(f"set sdo_timeout {round(SDO_TIMEOUT_MS * f)}", "other sdo time-out")
        plc(f"{PLC} write 0x1017 0 u16 0", "plc heartbeat off")
        other.until(f"{MASTER} read 0x2011 0 u8", "5", 30, "access lost")
        other(f"{MASTER} read 0x2000 0 u8", "state after loss")
        other(f"{MASTER} write 0x2005 0 u8 5", "engage by another node")
        other(f"{MASTER} write 0x2004 0 u8 1", "trigger by another node")
        other(f"{MASTER} write 0x2015 1 u32 0", "types by another node")
        other(f"{MASTER} read 0x2012 0 u32", "refused count")
        run.send_signal(signal.SIGTERM)
        res["run_rc"] = run.wait(timeout=scaled(60))
        res["ok"] = True
    except Exception as exc:  # noqa: BLE001 -- in result.json; exit code 1
        res["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        res["cocomm"] = plc.done + (other.done if other is not None else [])
        for g in (plc, other):
            if g is not None:
                g.stop()
        for p in (run, sim):
            if p is not None and p.poll() is None:
                p.send_signal(signal.SIGTERM)
                try:
                    p.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    p.kill()
        sim_log.close()
        run_log.close()
        info = cap.stop()
        res["capture_frames"] = info.frames
        (out / "result.json").write_text(json.dumps(res, indent=1))
    return 0 if res["ok"] else 1


# ---------------------------------------------------------------------------------------------
# the tests

pytestmark = pytest.mark.vcan


def _tail(path: Path) -> str:
    return path.read_text(errors="replace")[-2500:] if path.is_file() else "(none)"


@pytest.fixture(scope="module")
def session(canopen_stack, vcan_runner, tmp_path_factory) -> dict:
    scratch = tmp_path_factory.mktemp("vcan-plc")
    out = scratch / "plc"
    r = vcan_runner.run([sys.executable, str(Path(__file__).resolve()), "--out", str(out),
                         "--canopend", str(canopen_stack.canopend),
                         "--cocomm", str(canopen_stack.cocomm)],
                        timeout_s=400, scratch_dir=scratch, cwd=ROOT)
    res = out / "result.json"
    ok = r.returncode == 0 and not r.timed_out and res.is_file()
    assert ok, (f"orchestrator failed ({r.mode}, rc {r.returncode}, timed out {r.timed_out})\n"
                f"--- result.json ---\n{_tail(res)}\n--- stderr ---\n{r.stderr[-3000:]}\n"
                f"--- run ---\n{_tail(out / 'run.out')}\n--- sim ---\n{_tail(out / 'sim.out')}")
    result = json.loads(res.read_text())
    result["report"] = json.loads((out / "run.json").read_text())
    result["out"] = out
    return result


def _c(session) -> dict[str, dict]:
    out: dict[str, dict] = {}
    for c in session["cocomm"]:
        out[c["tag"]] = c  # (the last of a polled command)
    return out


def _abort(c: dict) -> str:
    return c["err"].split("ERROR:")[-1].split()[0] if "ERROR:" in c["err"] else ""


def test_plc_commands_the_controller_through_cocomm(session):
    c = _c(session)
    assert c["plc sdo time-out"]["rc"] == 0 and c["other sdo time-out"]["rc"] == 0
    assert c["access"]["out"] == "7"
    assert c["name"]["out"] == '"cantrack controller"'  # segmented upload
    assert c["commander"]["out"] == str(PLC)
    assert c["engage"]["rc"] == 0 and c["synced"]["out"] == "2"
    # the commander's heartbeat was lost (step 4): a fault seen and handled -> exit 3
    assert session["run_rc"] == 3
    assert session["report"]["exit_code"] == 3


def test_refusals_seen_by_cocomm(session):
    c = _c(session)
    assert _abort(c["bad engage value"]) == "0x06090030"
    assert _abort(c["cob-id change while valid"]) == "0x06090030"
    assert c["tpdo1 off"]["rc"] == 0 and c["tpdo1 on"]["rc"] == 0
    assert _abort(c["cob-id nmt"]) == "0x06090030"
    assert _abort(c["cob-id drive x rpdo1"]) == "0x08000000"
    assert _abort(c["config owned"]) == "0x08000020"
    assert _abort(c["disengage in preop"]) == "0x08000022"
    assert c["access preop"]["out"] == "6" and c["access again"]["out"] == "7"
    assert c["trigger type"]["rc"] == 0 and c["trigger type read"]["out"] == "3"
    assert c["tracked types"]["rc"] == 0 and c["tracked types read"]["out"] == "5"
    assert _abort(c["tracked types sub0"]) == "0x06010002"  # read-only


def test_commander_lost_desyncs_and_other_nodes_are_refused(session):
    c = _c(session)
    assert c["access lost"]["out"] == "5"  # OPERATIONAL, in the window, no commander
    assert c["state after loss"]["out"] in ("3", "0")  # DESYNCING or already OFF
    assert _abort(c["engage by another node"]) == "0x08000021"
    assert _abort(c["trigger by another node"]) == "0x08000021"
    assert _abort(c["types by another node"]) == "0x08000021"
    assert int(c["refused count"]["out"]) >= 3  # (pre-op + the two above)
    kinds = [e["kind"] for e in session["report"]["events"]]
    assert "plc_commander_lost" in kinds and "plc_no_commander" in kinds
    lost = [e for e in session["report"]["events"] if e["kind"] == "plc_commander_lost"][0]
    assert lost["reaction"] == "de-sync on the path"


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser()
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--canopend", type=Path, required=True)
    ap.add_argument("--cocomm", type=Path, required=True)
    ap.add_argument("--channel", default=os.environ.get("CANTRACK_CAN_CHANNEL", "vcan0"))
    a = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    sys.exit(orchestrate(a.out, a.channel, a.canopend, a.cocomm))
