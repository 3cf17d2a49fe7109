"""``cantrack record`` / ``cantrack replay``: a session's bus in python-can log formats, and a
recorded encoder stream replayed into the controller in stepped time, setpoints bit-exact."""

from __future__ import annotations

import json
import re
import threading
import time
from pathlib import Path

import can
import pytest
from controller.canopen.apps import record as rr

from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.master.cycle import Controller
from controller.canopen.slave.world import SimWorld
from controller.canopen.testing import bus_yml, load
from controller.cli import main as cli_main
from controller.cli import record as cmd_record
from controller.cli import replay as cmd_replay
from controller.errors import CanError
from controller.testing.e2e import wait_file
from controller.tracking import Mode

ROOT = Path(__file__).resolve().parents[1]


def _app():
    return ConveyorFollow(100, 600, (0.0, 0.0, 0.0), Mode.RELATIVE, end_cycle=900)


def _record(cfg, path, noise=2.0):
    """A stepped run (belt follower, noisy encoder) with its bus logged to ``path``."""
    with SimWorld(cfg, bus_log=path) as w:
        w.device("encoder").noise_counts = noise
        ctl = Controller(cfg, w.transport, _app())
        ctl.boot()
        ctl.start()
        ctl.run()
    return ctl


@pytest.mark.parametrize("ext", ["log", "asc", "blf"])
def test_replay_reproduces_setpoints_bit_exact(tmp_path, ext):
    cfg = load(tmp_path)
    path = tmp_path / f"bus.{ext}"
    ctl = _record(cfg, path)
    frames = rr.read_frames(path)
    stream = rr.encoder_stream(cfg, frames)
    assert len(stream) == ctl.k and all(v is not None for v in stream)
    recorded = rr.drive_setpoints(cfg, frames)
    # the drives did follow the belt: many distinct targets
    assert len({sp[1] for sp in recorded["x"] if sp}) > 400
    ctl2, replayed_frames = rr.replay(cfg, stream, _app())
    result = rr.compare(recorded, rr.drive_setpoints(cfg, replayed_frames))
    assert result.exact, result.format()
    assert result.cycles == ctl.k and result.setpoints >= 2 * (ctl.k - 20)
    # the replay's own record agrees with the recorded run's cycle records
    assert [r.targets for r in ctl2.trace] == [r.targets for r in ctl.trace]


def test_replay_follows_the_stream_not_the_simulation(tmp_path):
    """Negative control: one sample changed by a few counts -> the setpoints after it differ
    (the simulated encoder's own, noise-free profile is not what is replayed)."""
    cfg = load(tmp_path)
    path = tmp_path / "bus.log"
    _record(cfg, path)
    frames = rr.read_frames(path)
    stream = rr.encoder_stream(cfg, frames)
    stream[300] += 40
    _, rep = rr.replay(cfg, stream, _app())
    result = rr.compare(rr.drive_setpoints(cfg, frames), rr.drive_setpoints(cfg, rep))
    assert not result.exact
    assert min(k for _, k, _, _ in result.mismatches) >= 300


def test_stream_gap_is_replayed_as_silence(tmp_path):
    """A SYNC without an encoder sample in the recording: the replayed encoder stays silent
    then too (same master_silent handling), still bit-exact."""
    cfg = load(tmp_path)
    path = tmp_path / "bus.log"
    with SimWorld(cfg, bus_log=path) as w:
        enc = w.device("encoder")
        ctl = Controller(cfg, w.transport, _app())
        ctl.boot()
        ctl.start()
        t = ctl.t0 * 1e-9 + (200.25) * cfg.period_s   # between SYNC 200 and 201
        w.at(t, lambda: enc.mute_pdos(True))
        w.at(t + 4 * cfg.period_s, lambda: enc.mute_pdos(False))
        ctl.run()
    frames = rr.read_frames(path)
    stream = rr.encoder_stream(cfg, frames)
    assert stream.count(None) >= 3
    _, rep = rr.replay(cfg, stream, _app())
    result = rr.compare(rr.drive_setpoints(cfg, frames), rr.drive_setpoints(cfg, rep))
    assert result.exact, result.format()


def test_demo_record_and_replay_cli(tmp_path, capsys):
    """``cantrack demo`` logs its bus (candump .log); ``cantrack replay --demo`` reproduces
    every 607Ah of it."""
    out = tmp_path / "demo"
    cfg = ROOT / "examples" / "bus" / "demo.yml"
    assert cli_main(["demo", str(cfg), "-o", str(out), "--items", "1", "--duration", "2",
                     "--no-plot", "-q"]) == 0
    capsys.readouterr()
    rc = cmd_replay.main([str(cfg), str(out / "bus.log"), "--demo", "--items", "1",
                          "--duration", "2"])
    text = capsys.readouterr().out
    assert rc == 0, text
    assert "all identical (bit-exact 6040h and 607Ah)" in text


def test_replay_cli_reports_differences(tmp_path, capsys):
    """Replayed with other application parameters than recorded: exit 1 and the first
    differing setpoints."""
    path = bus_yml(tmp_path)
    cfg = load(tmp_path)
    _record(cfg, tmp_path / "bus.log")
    rc = cmd_replay.main([str(path), str(tmp_path / "bus.log"), "--engage-at", "0.2",
                          "--disengage-at", "1.2", "--duration", "1.8"])
    text = capsys.readouterr().out
    assert rc == 0, text  # 100/600/900 cycles at 2 ms: the recorded run's parameters
    rc = cmd_replay.main([str(path), str(tmp_path / "bus.log"), "--engage-at", "0.4",
                          "--disengage-at", "1.2", "--duration", "1.8"])
    text = capsys.readouterr().out
    assert rc == 1 and "differ" in text and "SYNC" in text, text


@pytest.mark.parametrize("ext", ["log", "asc", "blf"])
def test_record_command(tmp_path, ext):
    """``cantrack record`` on a (virtual) bus: every frame, in the format of the extension."""
    out = tmp_path / f"rec.{ext}"
    chan = f"rec-test-{ext}"
    rc: list = []
    ready = tmp_path / "ready.json"
    t = threading.Thread(target=lambda: rc.append(cmd_record.main(
        ["-i", "virtual", "-c", chan, "-o", str(out), "--duration", "2.0", "-q",
         "--ready-file", str(ready)])))
    t.start()
    wait_file(ready, [], 30, running=t.is_alive)
    assert json.loads(ready.read_text())["output"] == str(out)
    sender = can.Bus(interface="virtual", channel=chan)
    try:
        for i in range(20):
            sender.send(can.Message(arbitration_id=0x180 + i % 3, data=bytes([i, 1, 2]),
                                    is_extended_id=False))
            time.sleep(0.005)
    finally:
        t.join(timeout=10)
        sender.shutdown()
    assert rc == [0]
    frames = rr.read_frames(out)
    assert frames == [(0x180 + i % 3, bytes([i, 1, 2])) for i in range(20)]


@pytest.mark.parametrize("name,content,needle", [
    ("session.yml", b"master: {}\n", 'unknown log format ".yml"'),
    ("garbage.log", b"garbage line\n", "cannot read it as a CAN log"),
    ("corrupt.blf", b"LOGG" + bytes(200), "cannot read it as a CAN log"),
])
def test_replay_of_a_file_that_is_no_can_log_is_a_clear_error(tmp_path, name, content, needle):
    bad = tmp_path / name
    bad.write_bytes(content)
    rc = cli_main(["replay", str(ROOT / "examples" / "bus" / "demo.yml"), str(bad)])
    assert rc == 2
    with pytest.raises(CanError, match=re.escape(needle)) as info:
        rr.read_frames(bad)
    assert str(bad) in str(info.value) and ".blf" in str(info.value)


def test_record_to_an_unknown_format_is_a_clear_error(tmp_path):
    with pytest.raises(CanError, match=r'out\.foo: .*"\.foo".*formats: \.log \(candump\)'):
        cmd_record.main(["-i", "virtual", "-c", "rec-bad-ext", "-o", str(tmp_path / "out.foo")])


def test_record_keeps_what_arrived_before_sigterm(tmp_path):
    """Frames already received when SIGTERM comes are written (drained), not dropped: 2000
    frames sent in a burst by another thread, then SIGTERM at once.  (record runs in the main
    thread here, where its SIGTERM handler is installed.)"""
    import os
    import signal

    out = tmp_path / "burst.log"
    ready = tmp_path / "ready.json"
    chan = "rec-burst"
    n = 2000
    errors: list = []

    def send_then_terminate():
        try:
            wait_file(ready, [], 30)
            sender = can.Bus(interface="virtual", channel=chan)
            for i in range(n):
                sender.send(can.Message(arbitration_id=0x181, data=i.to_bytes(2, "little"),
                                        is_extended_id=False))
            os.kill(os.getpid(), signal.SIGTERM)  # record's handler sets its stop flag
            sender.shutdown()
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    th = threading.Thread(target=send_then_terminate)
    th.start()
    rc = cmd_record.main(["-i", "virtual", "-c", chan, "-o", str(out), "-q",
                          "--duration", "60", "--ready-file", str(ready)])
    th.join(timeout=30)
    assert rc == 0 and not errors, errors
    assert [d for _, d in rr.read_frames(out)] == [i.to_bytes(2, "little") for i in range(n)]
