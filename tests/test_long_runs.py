"""Long runs: bounded timing statistics, rotating output files with retention, files that
survive SIGKILL (controller.canopen.master.timing, controller.canopen.io.rotating)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path
import time

import can
import numpy as np
import pytest

from controller.canopen.io.rotating import BusLog, JsonLines, rotated_files
from controller.canopen.master.timing import BUCKETS, Histogram, Ring, Run


def test_histogram_percentiles_within_half_a_percent_of_numpy():
    rng = np.random.default_rng(3)
    # cycle-like figures: 80 us compute with a long tail, a few 10 ms host stalls
    v = np.concatenate([rng.lognormal(np.log(80e3), 0.3, 50_000),
                        rng.uniform(5e6, 2e7, 40)]).astype(np.int64)
    h = Histogram()
    for x in v.tolist():
        h.add(x)
    assert len(h) == v.size and h.max == v.max() and h.min == v.min()
    for q in (50, 90, 99, 99.9):
        # within a bucket (1 %) of the order statistics around the rank
        lo, hi = np.percentile(v, q, method="lower"), np.percentile(v, q, method="higher")
        assert lo * 0.99 <= h.percentile(q) <= hi * 1.01, q
        assert h.percentile(q) == pytest.approx(np.percentile(v, q), rel=0.02), q
    assert h.percentile(100) == v.max()
    s = h.summary_us()
    assert s["n"] == v.size and s["max"] == v.max() / 1e3
    assert h.counts.itemsize * BUCKETS < 20_000  # bounded: the same for 1 or 1e9 cycles


def test_histogram_empty_and_tiny_values():
    h = Histogram()
    assert np.isnan(h.percentile(50)) and h.summary_us()["n"] == 0
    for x in (0, 5, 50):
        h.add(x)
    assert h.percentile(0) == 0 and h.max == 50


def test_ring_keeps_the_last_values_in_order_and_runs_count_streaks():
    r = Ring(4)
    for i in range(3):
        r.add(i)
    assert list(r) == [0, 1, 2]
    for i in range(3, 11):
        r.add(i)
    assert list(r) == [7, 8, 9, 10] and len(r) == 4
    run = Run()
    for hit in (1, 1, 0, 1, 1, 1, 0):
        run.hit() if hit else run.miss()
    assert (run.longest, run.runs, run.current) == (3, 2, 0)


def _lines(paths):
    out = []
    for p in paths:
        for line in p.read_text().splitlines():
            out.append(json.loads(line))
    return out


def test_json_lines_rotate_by_size_keep_n_and_repeat_the_header(tmp_path):
    path = tmp_path / "telemetry.jsonl"
    w = JsonLines(path, max_bytes=2000, keep=2, header={"type": "run", "n": 0})
    for i in range(500):
        w.write({"type": "cycle", "cycle": i, "x": 0.5 * i}, t_s=i * 0.002)
    w.close()
    rotated = rotated_files(path)
    assert len(rotated) == 2  # retention: older files deleted
    assert w.rollover_count > 2
    for p in rotated + [path]:
        assert p.stat().st_size <= 2000 + 100  # the limit + one line
        recs = _lines([p])
        assert recs[0] == {"type": "run", "n": 0}  # each file reads on its own
    cycles = [r["cycle"] for r in _lines(rotated + [path]) if r["type"] == "cycle"]
    assert cycles == list(range(cycles[0], 500))  # the newest, in order, none lost


def test_json_lines_rotate_by_machine_time(tmp_path):
    path = tmp_path / "t.jsonl"
    with JsonLines(path, max_age_s=1.0) as w:
        for i in range(1000):  # 2 s at 2 ms
            w.write({"type": "cycle", "t_s": i * 0.002}, t_s=i * 0.002)
    assert len(rotated_files(path)) == 1
    assert len(_lines([path])) == 500


def test_json_lines_are_strict_json(tmp_path):
    path = tmp_path / "t.jsonl"
    with JsonLines(path) as w:
        w.write({"type": "x", "v": float("nan"), "w": float("inf")})
    assert json.loads(path.read_text()) == {"type": "x", "v": None, "w": None}


def _msg(i: int) -> can.Message:
    return can.Message(timestamp=i * 0.002, arbitration_id=0x180 + i % 4, is_extended_id=False,
                       data=i.to_bytes(4, "little"))


@pytest.mark.parametrize("suffix", [".log", ".asc", ".csv"])
def test_bus_log_rotates_by_size_and_time_with_retention(tmp_path, suffix):
    base = tmp_path / f"bus{suffix}"
    log = BusLog(base, max_bytes=3000, keep=3)
    for i in range(2000):
        log.on_message_received(_msg(i))
    log.stop()
    rotated = rotated_files(base)
    assert len(rotated) == 3 and log.rollover_count > 3
    frames = []
    for p in rotated + [base]:
        assert p.stat().st_size <= 3000 + 200
        frames += [int.from_bytes(m.data, "little") for m in can.LogReader(str(p))]
    assert frames == list(range(frames[0], 2000))
    tlog = BusLog(tmp_path / f"t{suffix}", max_age_s=1.0)
    for i in range(1000):
        tlog.on_message_received(_msg(i))
    tlog.stop()
    assert len(rotated_files(tmp_path / f"t{suffix}")) == 1


WRITER = textwrap.dedent("""
    import sys, time, can
    from controller.canopen.io.rotating import BusLog, JsonLines
    log = BusLog(sys.argv[1], flush_s=0.05)
    tel = JsonLines(sys.argv[2], flush_s=0.05)
    i = 0
    while True:
        log.on_message_received(can.Message(timestamp=i * 0.002, arbitration_id=0x181,
                                            is_extended_id=False, data=bytes(8)))
        tel.write({"type": "cycle", "cycle": i})
        i += 1
        if i % 100 == 0:
            time.sleep(0.001)
""")


@pytest.mark.parametrize("suffix", [".log", ".asc", ".csv"])
def test_line_based_files_survive_sigkill_but_for_the_last_line(tmp_path, suffix):
    """The README's claim: after SIGKILL the line-based bus logs and the telemetry read back
    whole but for their last line."""
    bus, tel = tmp_path / f"bus{suffix}", tmp_path / "telemetry.jsonl"
    proc = subprocess.Popen([sys.executable, "-c", WRITER, str(bus), str(tel)],
                            env=dict(os.environ))
    try:
        # the cue: the writer has flushed 50 kB of telemetry (it flushes every 50 ms)
        t_end = time.monotonic() + 120
        while not (tel.is_file() and tel.stat().st_size > 50_000):
            assert proc.poll() is None, "the writer ended"
            assert time.monotonic() < t_end, "no 50 kB of telemetry within 120 s"
            time.sleep(0.02)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    lines = tel.read_text().split("\n")
    body = lines[:-1]  # the last piece may be cut mid-line
    assert len(body) > 100
    assert [json.loads(x)["cycle"] for x in body] == list(range(len(body)))
    # the log without its last (maybe cut) line reads back whole: every frame, in order
    whole = tmp_path / f"whole{suffix}"
    text = bus.read_text()
    whole.write_text(text[:text.rstrip("\n").rfind("\n") + 1])
    frames = list(can.LogReader(str(whole)))
    assert len(frames) > 100
    assert [round(m.timestamp / 0.002) for m in frames] == list(range(len(frames)))


BLF_WRITER = textwrap.dedent("""
    import sys, time, can
    from controller.canopen.io.rotating import BusLog
    log = BusLog(sys.argv[1], flush_s=0.05)
    i = 0
    while True:
        log.on_message_received(can.Message(timestamp=i * 0.002, arbitration_id=0x181,
                                            is_extended_id=False, data=bytes(8)))
        i += 1
        if i % 100 == 0:
            print(i, flush=True)  # (written at least this many)
            time.sleep(0.001)
""")


def test_blf_after_sigkill_keeps_its_completed_containers_only(tmp_path):
    """The README's claim for ``.blf``: after SIGKILL python-can reads the frames of the
    completed (compressed) containers, from the first without a gap; the frames of the last,
    open container are lost (128 KiB of objects: about 1,800 frames of 8 bytes), not just a
    line's worth."""
    blf, out = tmp_path / "bus.blf", tmp_path / "writer.out"
    with open(out, "w") as log:
        proc = subprocess.Popen([sys.executable, "-c", BLF_WRITER, str(blf)], stdout=log,
                                env=dict(os.environ))
        try:
            # the cue: two compressed containers on disk
            t_end = time.monotonic() + 120
            while not (blf.is_file() and blf.stat().st_size > 200_000):
                assert proc.poll() is None, "the writer ended"
                assert time.monotonic() < t_end, "no 200 kB of .blf within 120 s"
                time.sleep(0.02)
        finally:
            proc.send_signal(signal.SIGKILL)
            proc.wait()
    written = int(out.read_text().split()[-1])
    ticks = [round(m.timestamp / 0.002) for m in can.LogReader(str(blf))]
    assert len(ticks) > 1000 and ticks == list(range(len(ticks)))
    assert written - 2100 <= len(ticks) < written, (len(ticks), written)


def test_demo_killed_keeps_its_telemetry_and_bus_log(tmp_path):
    """``cantrack demo`` killed with SIGKILL (no handler can run): telemetry.jsonl and
    bus.log read back whole but for their last line, the items done so far among them."""
    out = tmp_path / "demo"
    proc = subprocess.Popen([sys.executable, "-m", "controller.cli", "demo", "-o", str(out),
                             "--duration", "3600", "--no-plot", "-q"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    tel = out / "telemetry.jsonl"
    try:
        # the cue: an item line flushed (every item is flushed as it is done)
        t_end = time.monotonic() + 300
        while not (tel.is_file() and '"type": "item"' in tel.read_text(errors="replace")):
            assert proc.poll() is None, "the demo ended"
            assert time.monotonic() < t_end, "no item in the telemetry within 300 s"
            time.sleep(0.05)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    lines = tel.read_text().split("\n")[:-1]  # (the last piece may be cut)
    records = [json.loads(x) for x in lines]
    assert records[0]["type"] == "run" and any(r["type"] == "item" for r in records)
    assert not any(r["type"] == "end" for r in records)  # (killed: no end line)
    text = (out / "bus.log").read_text()
    whole = tmp_path / "whole.log"
    whole.write_text(text[:text.rstrip("\n").rfind("\n") + 1])
    stamps = [m.timestamp for m in can.LogReader(str(whole))]
    assert len(stamps) > 100 and stamps == sorted(stamps)


def test_speed_factor_follows_the_environment_and_stretches_limits(monkeypatch):
    from controller.testing import speed
    monkeypatch.setattr(speed, "_factor", None)
    monkeypatch.setenv(speed.ENV, "3")
    assert speed.speed_factor() == 3.0 and speed.scaled(10) == 30.0
    monkeypatch.setattr(speed, "_factor", None)
    monkeypatch.setenv(speed.ENV, "0.2")  # never shorter than written
    assert speed.scaled(10) == 10.0
    monkeypatch.setattr(speed, "_factor", None)
    monkeypatch.delenv(speed.ENV)
    f = speed.speed_factor()  # measured: within its bounds, passed on to sub-processes
    assert 1.0 <= f <= speed.MAX_FACTOR and float(os.environ[speed.ENV]) == pytest.approx(f,
                                                                                          abs=1e-3)
    monkeypatch.setattr(speed, "_factor", None)


def test_soak_tail_follows_rotations_when_inodes_are_used_again(tmp_path):
    """benchmarks/soak.py's reader of the streaming telemetry: with a retention of one
    rotated file, each new live file may get the inode of the file just deleted; every item
    is still read once, in order (before, the deleted file's offset was applied to the new
    file, and the display stopped)."""
    import importlib.util

    from controller.canopen.io.rotating import JsonLines

    spec = importlib.util.spec_from_file_location(
        "soak", Path(__file__).resolve().parents[1] / "benchmarks" / "soak.py")
    assert spec is not None and spec.loader is not None
    soak = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(soak)
    w = JsonLines(tmp_path / "telemetry.jsonl", max_bytes=1500, keep=1, header={"type": "run"})
    tail = soak.TelemetryTail(tmp_path)
    inodes = set()
    for i in range(400):
        w.write({"type": "item", "outcome": "placed", "index": i, "t_s": 0.5 * i,
                 "max_error_mm": 0.01}, 0.5 * i)
        w.flush()
        inodes.add((tmp_path / "telemetry.jsonl").stat().st_ino)
        if i % 7 == 0:   # (sometimes one rotation between two polls, sometimes none)
            tail.poll()
    w.write({"type": "end", "t_s": 200.0})
    w.close()
    tail.poll()
    assert w.rollover_count > 20 and len(inodes) < w.rollover_count  # inodes used again
    assert [d["index"] for d in tail.items] == list(range(400))
    assert tail.t_s == 200.0 and tail.end is not None and tail.run is not None
