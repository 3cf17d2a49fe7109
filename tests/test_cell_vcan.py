"""A work cell on a real SocketCAN vcan0: ``cantrack run`` of ``examples/bus/vcan_cell.yml``
(two belt encoders, two x, y, z gantries: eight nodes) against ``cantrack sim-devices``.

One command (one VM boot; natively where the kernel has vcan) runs this file as a script
(:func:`orchestrate`) with the file's supervision windows stretched by the host's measured
slowness (:mod:`controller.testing.stretch`):

1. ``candump -L vcan0`` records the bus;
2. ``sim-devices`` runs all eight nodes in one process (``--ready-file``);
3. ``cantrack run --duration 3 --report run.json --telemetry t.jsonl``: boot, enable the six
   drives, run the cell (r1 on belt A, hand-off to belt B at 2 s, r2 on its frame of belt B),
   disable; exit 0;
4. the devices get SIGTERM and exit 0.

On the host, tshark's CANopen dissector decodes the capture (independent of our code).

Cost: natively (a kernel with vcan) a few seconds.  In the test VM (TCG emulation, the
project's machines) the command takes about 2 minutes on a loaded 2-core host (measured:
devices booted after 47 s, the 3 s run done after 121 s, slowness 1.8; the controller's compute
p99 263 ms of the 100 ms cycle, so the cycle overruns and slips by whole periods), twice the
rest of the controller tier: in VM mode the module runs only with ``CANTRACK_VCAN_CELL=1``
(the skip says so).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from controller.testing.speed import scaled

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "examples" / "bus" / "vcan_cell.yml"
ENCODERS = (10, 20)
DRIVES = (11, 12, 13, 21, 22, 23)
DURATION_S = 3.0
CANTRACK = [sys.executable, "-m", "controller.cli"]


def orchestrate(out: Path, channel: str) -> int:
    from controller.testing.candump import CandumpCapture
    from controller.testing.e2e import wait_file
    from controller.testing.speed import window_factor
    from controller.testing.stretch import stretch_bus_config

    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    marks: dict[str, float] = {}

    def mark(name: str) -> None:
        marks[name] = round(time.monotonic() - t0, 3)

    f = window_factor()
    config = stretch_bus_config(CONFIG, out / "vcan_cell.yml", f)
    bus_args = ["-i", "socketcan", "-c", channel]
    result: dict = {"ok": False, "window_factor": f}
    cap = CandumpCapture(channel, out / "bus.log").start()
    logs = {n: open(out / f"{n}.out", "wb") for n in ("sim", "run")}  # noqa: SIM115
    sim = subprocess.Popen(CANTRACK + ["sim-devices", str(config), *bus_args, "-q",
                                       "--ready-file", str(out / "ready.json")],
                           stdout=logs["sim"], stderr=subprocess.STDOUT)
    run = None
    try:
        wait_file(out / "ready.json", [sim], 60)
        mark("devices_ready")
        run = subprocess.Popen(CANTRACK + ["run", str(config), *bus_args, "-q",
                                           "--duration", str(DURATION_S),
                                           "--report", str(out / "run.json"),
                                           "--telemetry", str(out / "t.jsonl")],
                               stdout=logs["run"], stderr=subprocess.STDOUT)
        result["run_returncode"] = run.wait(timeout=scaled(150))
        mark("run_done")
        sim.send_signal(signal.SIGTERM)
        result["sim_returncode"] = sim.wait(timeout=scaled(30))
        result["ok"] = True
    except Exception as exc:  # noqa: BLE001 -- in result.json; exit code 1
        result["error"] = f"{type(exc).__name__}: {exc}"
    finally:
        for p in (run, sim):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()
        info = cap.stop()
        for fh in logs.values():
            fh.close()
        mark("end")
        result.update({"capture_frames": info.frames, "capture_dropped": info.dropped,
                       "marks_s": marks})
        (out / "result.json").write_text(json.dumps(result, indent=1))
    return 0 if result["ok"] else 1


def _tail(path: Path) -> str:
    return path.read_text(errors="replace")[-2500:] if path.is_file() else "(none)"


@pytest.fixture(scope="module")
def session(vcan_runner, tshark_path, tmp_path_factory):
    from controller.testing.capture import classify_capture

    if vcan_runner.mode == "vm" and os.environ.get("CANTRACK_VCAN_CELL") != "1":
        pytest.skip("the cell over SocketCAN takes ~2 min in the TCG test VM (8 nodes, the "
                    "cycle's compute above its 100 ms period): set CANTRACK_VCAN_CELL=1 to run "
                    "it there (natively, on a kernel with vcan, it always runs)")
    scratch = tmp_path_factory.mktemp("vcan-cell")
    out = scratch / "cell"
    r = vcan_runner.run([sys.executable, str(Path(__file__).resolve()), "--out", str(out)],
                        timeout_s=scaled(240), scratch_dir=scratch, cwd=ROOT)
    assert r.returncode == 0 and not r.timed_out and (out / "run.json").is_file(), (
        f"orchestrator failed ({r.mode}, rc {r.returncode}, timed out {r.timed_out})\n"
        f"--- result.json ---\n{_tail(out / 'result.json')}\n--- stderr ---\n"
        f"{r.stderr[-3000:]}\n--- run ---\n{_tail(out / 'run.out')}\n--- sim ---\n"
        f"{_tail(out / 'sim.out')}")
    result = json.loads((out / "result.json").read_text())
    report = json.loads((out / "run.json").read_text())
    tel = [json.loads(x) for x in (out / "t.jsonl").read_text().splitlines()]
    return result, report, tel, classify_capture(out / "bus.log", tshark=tshark_path), out


@pytest.mark.vcan
def test_the_cell_runs_over_socketcan(session):
    result, report, tel, frames, out = session
    assert result["run_returncode"] == 0 and result["sim_returncode"] == 0, (
        _tail(out / "run.out"))
    assert report["reactions"] == 0 and report["final_phase"] == "stopped", report["events"]
    end = tel[-1]
    assert end["type"] == "end" and end["exit_code"] == 0
    r1, r2 = end["robots"]["r1"], end["robots"]["r2"]
    assert (r1["triggered"], r1["caught"], r1["handoffs"]) == (2, 2, 1)
    assert (r2["triggered"], r2["caught"], r2["missed"]) == (2, 1, 0)
    # every item in the telemetry (item 1 of r2, type 1, waits behind item 2: still pending)
    items = sorted((d["robot"], d["item"], d["frame"], d["status"]) for d in tel
                   if d["type"] == "item")
    assert items == [("r1", 1, "A", "caught"), ("r1", 2, "B", "caught"),
                     ("r2", 1, "B2", "pending"), ("r2", 2, "B2", "caught")], items
    assert any(e["kind"] == "handoff" for e in report["events"])


@pytest.mark.vcan
def test_every_sync_carries_both_encoders_and_all_six_drives(session):
    """tshark decodes every frame as CANopen; after each SYNC of the run both encoders'
    TPDOs and every drive's TPDO come in, and the controller sends the six drives' RPDOs
    (those it sent, from its own report); the drives of both robots moved."""
    from controller.testing.capture import Kind

    result, report, tel, frames, out = session
    assert not [f for f in frames if f.kind is Kind.UNKNOWN]
    rpdos = [0x200 + n for n in DRIVES]
    assert any(s["cob_ids"] == rpdos and s["cycles"] >= DURATION_S / 0.1
               for s in report["sent_pdo_sequences"]), report["sent_pdo_sequences"]
    syncs = [i for i, f in enumerate(frames) if f.kind is Kind.SYNC]
    assert len(syncs) >= DURATION_S / 0.1
    # the controller's six RPDOs after every SYNC (it computes by compute_at at the latest);
    # every node's TPDO once per SYNC (a busy VM delivers some after the next SYNC: counted,
    # not placed)
    for a, b in zip(syncs, syncs[1:]):
        ids = [f.can_id for f in frames[a + 1:b]]
        assert sorted(i for i in ids if 0x200 <= i < 0x280) == rpdos, (a, ids)
    n = len(syncs)
    for node in ENCODERS + DRIVES:
        got = sum(1 for f in frames if f.can_id == 0x180 + node)
        assert n - 3 <= got <= n + 1, (node, got, n)
    moved = {}
    for n in DRIVES:
        pos = [int.from_bytes(f.data[2:6], "little", signed=True) for f in frames
               if f.kind is Kind.PDO and f.can_id == 0x180 + n]
        moved[n] = max(pos) - min(pos)
    # r1 follows belt A in x, then belt B in y; r2 follows B2 in y; z stays
    assert moved[11] > 1_000_000 and moved[12] > 1_000_000 and moved[22] > 1_000_000, moved
    assert moved[13] == 0 and moved[23] == 0 and moved[21] == 0, moved


if __name__ == "__main__":
    import argparse

    ap = argparse.ArgumentParser(description="the vcan cell tier's orchestrator")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--channel", default=os.environ.get("CANTRACK_CAN_CHANNEL", "vcan0"))
    a = ap.parse_args()
    sys.path.insert(0, str(ROOT))
    sys.exit(orchestrate(a.out, a.channel))
