"""Hardware in the loop: the end-to-end checks of the vcan tier, against a rig.

Run on a rig (the nodes of ``rig.yml`` powered on the bus, nothing else driving it)::

    python -m pytest tests/test_hil.py -m hil --can-interface socketcan --can-channel can0 \\
        --bus-config rig.yml -v

The module reads the rig's bus configuration (node-IDs, SYNC period and counter, PDOs, axes)
and runs, each as its own process as an operator would:

1. ``cantrack check-bus rig.yml -i IF -c CH --no-pdos --json``: every configured node answers,
   its identity matches the EDS/bus.yml (the PDOs are not compared: before the boot they have
   their power-on values);
2. ``cantrack record -i IF -c CH -o bus.log --ready-file`` records the bus (from before
   check-bus), then ``cantrack run rig.yml -i IF -c CH --duration D --engage-at E
   --disengage-at X --report run.json --ready-file``: boot, enable, track (SYNCING ->
   SYNCED), de-sync (DESYNCING -> OFF), exit 0 with no supervision reaction;
3. the capture, decoded by tshark's CANopen dissector (or, where tshark is not installed, by
   the built-in CiA 301 decoder; ``--hil-decoder``): every frame clean CANopen, the boot on
   the bus, SYNC at the configured period with the counter, the controller's RPDOs and the
   slaves' TPDOs in every SYNC cycle.

``D``, ``E``, ``X``: ``--hil-duration`` (5 s), ``--hil-engage-at`` (1 s),
``--hil-disengage-at`` (3 s).  The drives MOVE: the rig must be safe to move within the
configured axis limits.  When ``check-bus`` fails, the controller is not started and every
test of the run fails with check-bus's output.

Without a rig: ``test_hil_module_on_vcan_against_sim_devices`` (marked ``vcan``: one VM boot)
runs this module with ``cantrack sim-devices examples/bus/vcan.yml`` as the rig on ``vcan0``,
with the built-in decoder inside the VM, and re-decodes the capture with tshark on the host.
``test_builtin_decoder_agrees_with_tshark`` needs neither.
"""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from controller.testing.capture import (
    Kind,
    classify_capture,
    decode_messages,
    kinds_count,
    pick_decoder,
    problems,
    read_log,
)
from controller.testing.e2e import (
    TRACK_CYCLE,
    boot_problems,
    cantrack_argv,
    pdo_cycles,
    running_states,
    sync_problems,
    wait_file,
)
from controller.testing.speed import scaled, window_factor

ROOT = Path(__file__).resolve().parents[1]
CANTRACK = cantrack_argv()
VCAN_CONFIG = ROOT / "examples" / "bus" / "vcan.yml"


def _tail(path: Path, n: int = 2500) -> str:
    return path.read_text(errors="replace")[-n:] if path.is_file() else "(none)"


# ---------------------------------------------------------------------------------------------
# the rig run (module fixtures: one check-bus, one record + run for all tests)

@dataclasses.dataclass
class CheckBus:
    returncode: int
    output: str
    result: dict | None

    def describe(self) -> str:
        return f"cantrack check-bus exited with {self.returncode}:\n{self.output[-3000:]}"


@dataclasses.dataclass
class RigRun:
    out: Path
    cfg: object
    run_returncode: int
    record_returncode: int
    ready: dict
    report: dict
    frames: list
    decoder: str

    def log(self) -> str:
        return (f"--- run ---\n{_tail(self.out / 'run.out')}\n--- record ---\n"
                f"{_tail(self.out / 'record.out', 800)}")


@pytest.fixture(scope="module")
def rig_cfg(hil_rig):
    return hil_rig.load_config()


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("hil")


@dataclasses.dataclass
class Recorder:
    """``cantrack record`` of the whole session (check-bus and run) into ``bus.log``."""

    proc: subprocess.Popen
    path: Path
    ready: Path
    log: object
    returncode: int | None = None

    def wait_ready(self, timeout_s: float = 60) -> None:
        wait_file(self.ready, [self.proc], timeout_s)

    def stop(self) -> int:
        if self.returncode is None:
            if self.proc.poll() is None:  # (record drains what it has received at SIGTERM)
                self.proc.send_signal(signal.SIGTERM)
            try:
                self.returncode = self.proc.wait(timeout=scaled(30))
            finally:
                if self.proc.poll() is None:
                    self.proc.kill()
                    self.proc.wait()
                self.log.close()
        return self.returncode


@pytest.fixture(scope="module")
def recorder(hil_rig, rig_dir):
    """Started first: its Python start-up overlaps check-bus's."""
    log = open(rig_dir / "record.out", "wb")  # noqa: SIM115
    proc = subprocess.Popen(CANTRACK + ["record", str(hil_rig.bus_config), *hil_rig.bus_args(),
                                        "-q", "-o", str(rig_dir / "bus.log"),
                                        "--ready-file", str(rig_dir / "record-ready.json")],
                            stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
    rec = Recorder(proc, rig_dir / "bus.log", rig_dir / "record-ready.json", log)
    yield rec
    rec.stop()


@pytest.fixture(scope="module")
def check_before(hil_rig, rig_cfg, rig_dir, recorder) -> CheckBus:
    if hil_rig.wait_nodes_s > 0:
        missing = hil_rig.wait_for_heartbeats(_slaves(rig_cfg).values(), hil_rig.wait_nodes_s)
        if missing:   # check-bus says more (does the node answer SDO at all?)
            print(f"no heartbeat from node(s) {sorted(missing)} in {hil_rig.wait_nodes_s} s")
    js = rig_dir / "check-bus.json"
    p = subprocess.run(CANTRACK + ["check-bus", str(hil_rig.bus_config), *hil_rig.bus_args(),
                                   "--no-pdos", "--json", str(js)],
                       capture_output=True, text=True, timeout=scaled(120), cwd=ROOT,
                       check=False)
    out = p.stdout + p.stderr
    (rig_dir / "check-bus.out").write_text(out)
    return CheckBus(p.returncode, out, json.loads(js.read_text()) if js.is_file() else None)


@pytest.fixture(scope="module")
def rig_run(hil_rig, rig_cfg, check_before, recorder, rig_dir) -> RigRun:
    if check_before.returncode != 0:
        pytest.fail(f"not run: the rig on {hil_rig.describe()} does not match "
                    f"{hil_rig.bus_config.name}; {check_before.describe()}", pytrace=False)
    decoder, tshark = pick_decoder(hil_rig.decoder)
    out = rig_dir
    run = None
    log = open(out / "run.out", "wb")  # noqa: SIM115
    try:
        recorder.wait_ready()
        run = subprocess.Popen(CANTRACK + [
            "run", str(hil_rig.bus_config), *hil_rig.bus_args(), "-q",
            "--duration", str(hil_rig.run_duration_s),
            "--engage-at", str(hil_rig.engage_at_s),
            "--disengage-at", str(hil_rig.disengage_at_s),
            "--report", str(out / "run.json"), "--ready-file", str(out / "run-ready.json")],
            stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)
        t = rig_cfg.tracking.timeouts if rig_cfg.tracking is not None else None
        budget = hil_rig.run_duration_s + scaled(120) + (
            t.boot_up_s + t.enable_s + 10 * t.sdo_s if t is not None else 60)
        ready_file, ready = out / "run-ready.json", {}
        try:  # (read while the run is on: it removes its ready-file when it ends)
            wait_file(ready_file, [run], 60)
            ready = json.loads(ready_file.read_text())
        except (RuntimeError, OSError, ValueError):
            pass  # (no ready-file: the report and the run's log say why)
        run_rc = run.wait(timeout=budget)
    finally:
        if run is not None and run.poll() is None:
            run.kill()
            run.wait()
        log.close()
        rec_rc = recorder.stop()
    report = out / "run.json"
    assert report.is_file(), (f"cantrack run (exit {run_rc}) wrote no report\n"
                              f"{_tail(out / 'run.out')}")
    frames = classify_capture(recorder.path, decoder=decoder, tshark=tshark)
    return RigRun(out, rig_cfg, run_rc, rec_rc, ready,
                  json.loads(report.read_text()), frames, decoder)


def _slaves(cfg) -> dict[str, int]:
    return {name: s.node_id for name, s in cfg.slaves.items() if s.boot}


def _period_s(cfg) -> float:
    return cfg.master.sync_period_us / 1e6


# ---------------------------------------------------------------------------------------------
# the hil tests

@pytest.mark.hil
def test_check_bus_every_node_present_identity_matches(hil_rig, rig_cfg, check_before):
    """``cantrack check-bus --no-pdos``: exit 0; every configured node answers, its identity
    (1000h, 1018h) matches the EDS and the bus.yml."""
    assert check_before.returncode == 0, (
        f"on {hil_rig.describe()}: {check_before.describe()}")
    res = check_before.result
    assert res is not None and res["ok"], check_before.describe()
    nodes = {n["node_id"]: n for n in res["nodes"]}
    for name, node in _slaves(rig_cfg).items():
        n = nodes.get(node)
        assert n is not None, f"node {node} ({name}) not in check-bus's result"
        assert n["name"] == name and n["answered"], (name, n)
        assert not n["differences"], (name, n["differences"])
        assert {"device type", "vendor-ID", "product code"} <= set(n["identity"]), n
    assert "all nodes match the configuration" in check_before.output, check_before.output


@pytest.mark.hil
def test_run_boots_enables_tracks_desyncs_exit_0(hil_rig, rig_run):
    """``cantrack run``: exit 0 at the end of ``--duration``; no supervision reaction; every
    slave booted with its identity; the drives enabled; the tracker went OFF, SYNCING
    (from --engage-at), SYNCED, DESYNCING (at --disengage-at), OFF; the drives disabled."""
    r, rep, cfg = rig_run, rig_run.report, rig_run.cfg
    assert r.run_returncode == 0 and rep["exit_code"] == 0, (r.run_returncode, r.log())
    assert rep["end"] == "duration" and rep["error"] is None, (rep["end"], rep["error"])
    reacted = [e for e in rep["events"] if e["reaction"]]
    assert rep["reactions"] == 0 and not reacted, reacted
    slaves = _slaves(cfg)
    assert rep["nodes"] == slaves and r.ready.get("nodes") == slaves, (rep["nodes"], r.ready)
    assert rep["master_node_id"] == cfg.master.node_id
    booted = {e["node"] for e in rep["events"] if e["kind"] == "boot"}
    assert booted == set(slaves.values()), rep["events"]
    assert [e for e in rep["events"] if e["kind"] == "enabled"], rep["events"]
    axes = {a["axis"]: a["node_id"] for a in rep["axes"]}
    assert axes == {a.name: cfg.slaves[a.node].node_id for a in cfg.tracking.axes}, rep["axes"]
    ch = rep["state_changes"]
    assert (ch[0]["phase"], ch[0]["state"]) == ("enabling", "OFF"), ch
    assert running_states(rep) == TRACK_CYCLE, ch
    assert rep["final_phase"] == "stopped", rep["final_phase"]
    run = [c for c in ch if c["phase"] == "running"]
    cyc = [c["cycle"] for c in run]
    period = _period_s(cfg)
    assert cyc[1] - cyc[0] >= round(hil_rig.engage_at_s / period), f"engaged early: {ch}"
    assert cyc[3] - cyc[0] == round(hil_rig.disengage_at_s / period), f"--disengage-at: {ch}"
    assert cyc[2] > cyc[1] and cyc[4] > cyc[3], ch


@pytest.mark.hil
def test_capture_is_clean_canopen(rig_run):
    """The recorder stopped cleanly; every frame is NMT, SYNC, PDO, SDO, EMCY or heartbeat as
    its COB-ID says, none malformed, none breaking a CiA 301 length rule."""
    r = rig_run
    assert r.record_returncode == 0, r.log()
    assert r.frames, "empty capture"
    bad = problems(r.frames)
    assert not bad, (f"{r.decoder}: {len(bad)} of {len(r.frames)} frames:\n"
                     + "\n".join(bad[:30]))
    assert set(kinds_count(r.frames)) >= {Kind.NMT, Kind.SYNC, Kind.PDO, Kind.SDO,
                                          Kind.HEARTBEAT}, kinds_count(r.frames)


@pytest.mark.hil
def test_boot_on_the_bus(rig_run):
    """NMT reset and start of each slave, its boot-up, the identity SDOs, the controller's
    boot-up and heartbeat before the first SYNC."""
    cfg = rig_run.cfg
    bad = boot_problems(rig_run.frames, _slaves(cfg), cfg.master.node_id,
                        master_heartbeat=bool(cfg.master.heartbeat_producer_ms))
    assert not bad, f"{rig_run.decoder}:\n" + "\n".join(bad)


@pytest.mark.hil
def test_sync_at_the_configured_period(rig_run):
    """SYNC count = the report's cycles, the counter 1..overflow without a gap, the period as
    configured (median within 10 %, mean within 25 %)."""
    cfg, rep = rig_run.cfg, rig_run.report
    assert rep["sync_period_us"] == cfg.master.sync_period_us
    assert rep["sync_overflow"] == cfg.master.sync_overflow
    bad = sync_problems(rig_run.frames, period_s=_period_s(cfg),
                        overflow=cfg.master.sync_overflow, cycles=rep["cycles"])
    assert not bad, f"{rig_run.decoder}:\n" + "\n".join(bad)


def _tpdo_every_sync(cfg) -> dict[int, str]:
    """COB-ID -> node name of every configured TPDO sent on every SYNC (transmission 1)."""
    out = {}
    for name, s in cfg.slaves.items():
        for n, pdo in s.tpdo.items():
            if pdo.enabled and pdo.transmission == 1:
                cob = pdo.cob_id if pdo.cob_id is not None else 0x80 + 0x100 * n + s.node_id
                out[cob & 0x7FF] = name
    return out


@pytest.mark.hil
def test_pdos_in_every_sync_cycle(rig_run):
    """After every SYNC: the controller's RPDO to each axis exactly once, in the axes' order
    (on the bus and in the report); while tracking, each slave's every-SYNC TPDO in at least
    90 % of the cycles - in its cycle, or on a machine slower than the reference up to
    ceil(w) - 1 cycles late (w: :func:`controller.testing.speed.window_factor`) (a device process on a busy machine answers late; the TPDO is
    there, the controller counts the cycle in ``timing.late_inputs``)."""
    rep = rig_run.report
    rpdos = tuple(a["rpdo_cob_id"] for a in rep["axes"])
    seqs = rep["sent_pdo_sequences"]  # every cycle, counted by sequence
    assert [tuple(s["cob_ids"]) for s in seqs] == [rpdos], seqs
    assert seqs[0]["cycles"] == rep["cycles"], seqs
    tpdos = _tpdo_every_sync(rig_run.cfg)
    cycles = pdo_cycles(rig_run.frames, set(rpdos) | set(tpdos))
    assert len(cycles) == rep["cycles"] and len(cycles) > 2, (len(cycles), rep["cycles"])
    window = cycles[:-1]   # the last one may be cut by the end of the run
    bad = [(i, c) for i, c in enumerate(window)
           if tuple(cob for cob in c if cob in rpdos) != rpdos]
    assert not bad, f"cycles without the RPDOs {[hex(c) for c in rpdos]} once each: {bad[:10]}"
    start = next(c["cycle"] for c in rep["state_changes"] if c["phase"] == "running")
    tracking = window[start + 1:]
    assert tracking, "no tracking cycle"
    late = math.ceil(window_factor()) - 1
    # (the last ones' frames may come after the run; at least half the cycles are checked)
    due = max(len(tracking) // 2, len(tracking) - late)
    for cob, name in tpdos.items():
        n = _served(cycles[start + 1:], cob, late, due)
        assert n >= 0.9 * due, (
            f"{name}'s TPDO {cob:03X}h in {n} of {due} tracking cycles (at most {late} "
            f"cycles late)")


def _served(cycles, cob: int, late: int, due: int | None = None) -> int:
    """Of the first ``due`` cycles (default all), those that got their ``cob`` frame: in the
    cycle, or up to ``late`` cycles after (each frame serves the oldest cycle still waiting;
    ``late`` 0: the frame's own cycle)."""
    due = len(cycles) if due is None else due
    waiting: list[int] = []
    served = 0
    for i, c in enumerate(cycles):
        waiting = [k for k in waiting if i - k <= late] + ([i] if i < due else [])
        for _ in range(c.count(cob)):
            if waiting:
                waiting.pop(0)
                served += 1
    return served


# ---------------------------------------------------------------------------------------------
# without a rig

def test_builtin_decoder_agrees_with_tshark(tshark_path, tmp_path):
    """The fall-back decoder (no tshark on the rig PC) gives the fields the hil checks read
    as tshark does, on every kind of frame of a controller session."""
    import can

    msgs = [can.Message(arbitration_id=i, data=bytes(d), is_extended_id=False, timestamp=t)
            for t, (i, d) in enumerate([
                (0x000, [0x81, 10]), (0x000, [0x01, 0]), (0x70A, [0x00]), (0x70A, [0x7F]),
                (0x70B, [0x05]), (0x080, [3]), (0x080, []), (0x60A, [0x40, 0x18, 0x10, 2, 0,
                                                                     0, 0, 0]),
                (0x58A, [0x43, 0x18, 0x10, 2, 1, 0, 2, 4]),
                (0x60B, [0x2B, 0xC2, 0x60, 1, 100, 0, 0, 0]), (0x58B, [0x60, 0xC2, 0x60, 1,
                                                                      0, 0, 0, 0]),
                (0x60B, [0x80, 0x00, 0x20, 0, 0, 0, 2, 6]),
                (0x18A, [1, 2, 3, 4]), (0x20B, [0x0F, 0, 0, 0, 0, 0]),
                (0x08B, [0x11, 0x86, 0x80, 0, 0, 0, 0, 0]), (0x08B, [0, 0, 0, 0, 0, 0, 0, 0]),
                (0x080, [1, 2]), (0x70C, [0x33]),
            ])]
    with can.Logger(str(tmp_path / "s.log")) as log:
        for m in msgs:
            log.on_message_received(m)
    ts = classify_capture(tmp_path / "s.log", tshark=tshark_path)
    bi = classify_capture(tmp_path / "s.log", decoder="builtin")
    assert decode_messages(read_log(tmp_path / "s.log")) == bi
    fields = ("can_id", "data", "kind", "expected_kind", "node_id", "pdo", "direction",
              "sync_counter", "nmt_state", "nmt_command", "nmt_target", "emcy_code",
              "emcy_register", "sdo_index", "sdo_subindex", "issues")
    assert len(ts) == len(bi) == len(msgs)
    for a, b in zip(ts, bi):
        diff = {f: (getattr(a, f), getattr(b, f)) for f in fields
                if getattr(a, f) != getattr(b, f)
                and not (f == "node_id" and a.kind in (Kind.NMT, Kind.SYNC))}
        assert not diff, (a.describe(), diff)
    assert [f.time_s for f in ts] == [f.time_s for f in bi]
    # the two bad frames are problems for both
    assert len(problems(ts)) == len(problems(bi)) == 2, (problems(ts), problems(bi))


def test_tpdo_served_in_its_cycle_or_late_within_the_window():
    """test_pdos_in_every_sync_cycle's count: a frame serves its own cycle, or (window > 0) the
    oldest cycle still waiting within the window; a cycle left out is not served later."""
    cyc = [(0x18A,), (), (0x18A, 0x18A), (0x18A,), (), (), (0x18A, 0x18A, 0x18A), (0x18A,)]
    assert _served(cyc, 0x18A, 0) == 5      # (the cycles that have one)
    assert _served(cyc, 0x18A, 1) == 7      # cycle 1 by cycle 2's 2nd frame, 5 by cycle 6's
    assert _served(cyc, 0x18A, 2) == 8      # cycle 4 too (2 cycles late)
    assert _served(cyc, 0x18B, 5) == 0
    assert _served(cyc, 0x18A, 2, due=5) == 5  # (cycle 4 by cycle 6's frames, not due beyond)


def test_e2e_checks_flag_what_is_wrong():
    """The shared checks on synthetic captures (built-in decoder): a clean boot and 100 ms
    SYNCs pass; a missing boot-up, a counter gap, a wrong period and a count that does not
    match the report are each named."""
    import can

    def frames(spec):
        return decode_messages([can.Message(arbitration_id=i, data=bytes(d), timestamp=t,
                                            is_extended_id=False) for t, i, d in spec])

    boot = [(0.00, 0x701, [0]), (0.01, 0x000, [0x81, 10]), (0.02, 0x70A, [0]),
            (0.03, 0x60A, [0x40, 0, 0x10, 0, 0, 0, 0, 0]),
            (0.04, 0x60A, [0x40, 0x18, 0x10, 1, 0, 0, 0, 0]),
            (0.05, 0x60A, [0x40, 0x18, 0x10, 2, 0, 0, 0, 0]),
            (0.06, 0x701, [5]), (0.07, 0x000, [0x01, 10])]
    syncs = [(0.1 + 0.1 * k, 0x080, [k % 3 + 1]) for k in range(9)]
    assert not boot_problems(frames(boot + syncs), {"enc": 10}, 1)
    assert not sync_problems(frames(boot + syncs), period_s=0.1, overflow=3, cycles=9)
    no_boot_up = [f for f in boot if f[1] != 0x70A]
    assert boot_problems(frames(no_boot_up + syncs), {"enc": 10}, 1) == [
        "node 10 (enc): no boot-up after the NMT reset"]
    gap = syncs[:4] + syncs[5:]
    assert any("counter" in p for p in sync_problems(frames(gap), period_s=0.1, overflow=3))
    bad = sync_problems(frames(syncs), period_s=0.05, overflow=3, cycles=10)
    assert len(bad) == 3 and "10 cycles" in bad[0] and "median" in bad[1], bad


@pytest.mark.vcan
def test_hil_module_on_vcan_against_sim_devices(vcan_runner, tshark_path, tmp_path):
    """This module's hil tests pass against ``cantrack sim-devices examples/bus/vcan.yml`` as
    the rig on a real SocketCAN vcan0 (one VM boot), decoding with the built-in decoder in the
    VM; the capture is then decoded again with tshark on the host and must be as clean.
    The rig's supervision windows (heartbeat time-outs, boot/SDO/stop time-outs) are
    stretched by the host's slowness measured now (:mod:`controller.testing.stretch`)."""
    from controller.testing.speed import ENV, fresh_factor
    from controller.testing.stretch import stretch_bus_config

    out = tmp_path / "hil"
    f = fresh_factor()
    config = stretch_bus_config(VCAN_CONFIG, tmp_path / "vcan.yml", window_factor(f))
    r = vcan_runner.run(["/bin/sh", "-c", GUEST, "sh", sys.executable, str(out),
                         str(config), str(Path(__file__).resolve()), vcan_runner.channel,
                         *VM_RUN, "--hil-wait-nodes", "60", "--hil-decoder", "builtin"],
                        timeout_s=300, env={ENV: f"{f:.3f}"}, scratch_dir=tmp_path, cwd=ROOT)
    detail = (f"({r.mode}, rc {r.returncode}, timed out {r.timed_out})\n"
              f"--- pytest ---\n{_tail(out / 'pytest.out', 6000)}\n"
              f"--- sim-devices ---\n{_tail(out / 'sim.out')}\n--- stderr ---\n"
              f"{r.stderr[-2000:]}")
    assert r.returncode == 0 and not r.timed_out, detail
    assert _tail(out / "pytest.rc").strip() == "0", detail
    assert _tail(out / "sim-was-ready").strip() == "yes", detail
    assert _tail(out / "sim.rc").strip() == "0", detail
    suite = ET.parse(out / "hil.xml").getroot()
    suite = suite if suite.tag == "testsuite" else suite.find("testsuite")
    cases = {c.get("name"): [x.tag for x in c] for c in suite.iter("testcase")}
    want = {n for n, f in globals().items() if n.startswith("test_") and callable(f)
            and any(m.name == "hil" for m in getattr(f, "pytestmark", []))}
    assert set(cases) == want and all(not v or v == ["system-out"] for v in cases.values()), (
        cases, detail)
    # the capture decoded again, by tshark this time (the VM used the built-in decoder)
    logs = list(out.glob("pt/**/bus.log"))
    assert len(logs) == 1, logs
    frames = classify_capture(logs[0], tshark=tshark_path)
    bad = problems(frames)
    assert not bad, "\n".join(bad[:30])
    report = json.loads((logs[0].parent / "run.json").read_text())
    assert not sync_problems(frames, period_s=0.1, overflow=10, cycles=report["cycles"])
    assert not boot_problems(frames, {"encoder": 10, "x": 11, "y": 12}, 1)


# ---------------------------------------------------------------------------------------------
# the VM side of test_hil_module_on_vcan_against_sim_devices

#: the run in the VM: the rig's duration, engaged earlier (defaults 5, 1, 3 s); vcan.yml's
#: SYNCING and DESYNCING take about 13 and 5 cycles of 100 ms: 30 cycles from the engage to
#: the de-sync (20 were not enough once under TCG on a loaded 2-core host, load 4.7: the
#: tracker was still SYNCING at the de-sync)
VM_RUN = ("--hil-duration", "5", "--hil-engage-at", "0.5", "--hil-disengage-at", "3.5")

#: the command in the VM (a shell, not Python: a Python start-up costs 10 s and more under
#: TCG): ``sim-devices vcan.yml`` (the rig) and, at the same time (their start-ups overlap;
#: ``--hil-wait-nodes`` waits for the devices' heartbeats), this module's hil tests against it;
#: then SIGTERM to sim-devices.  Arguments: python, out dir, config, test file, channel, then
#: the pytest options.  No plugin autoload and no conftest: the module needs only our plugin.
GUEST = r"""
py=$1 out=$2 cfg=$3 tests=$4 ch=$5; shift 5
mkdir -p "$out"
"$py" -m controller.cli sim-devices "$cfg" -i socketcan -c "$ch" -q \
    --ready-file "$out/sim-ready.json" > "$out/sim.out" 2>&1 &
sim=$!
PYTEST_DISABLE_PLUGIN_AUTOLOAD=1 "$py" -m pytest "$tests" -m hil \
    -p controller.testing.pytest_plugin --noconftest -p no:cacheprovider -q -rA \
    --can-interface socketcan --can-channel "$ch" --bus-config "$cfg" \
    --basetemp "$out/pt" --junitxml "$out/hil.xml" "$@" > "$out/pytest.out" 2>&1
echo $? > "$out/pytest.rc"
[ -f "$out/sim-ready.json" ] && echo yes > "$out/sim-was-ready"
kill -TERM $sim
wait $sim
echo $? > "$out/sim.rc"
"""
