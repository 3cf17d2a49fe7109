"""The work cell on the bus (docs/spec/conveyor-extensions.md#5.1): ``.tracking.cell`` run by
the cycle with :class:`controller.canopen.apps.cell.CellSource` on the simulated devices, and
its identity with the offline simulator's run of the same cell.

The identity: the stepped bus run of examples/bus/cell_handoff.yml and the simulator's run of
its twin examples/cell_bus_handoff.yaml step the same pure core
(:class:`controller.cell.run.CellRun`).  Their master inputs differ by construction: the bus
estimates each belt from the encoder's counts (MasterInput: counts/40.96 -> mm, a quadratic
fit over 16 samples predicting the SYNC the drives reach the setpoint at, 1 + d cycles ahead);
the simulator's own encoder source fits counts over its window at the sample time.  So the
bus run records what it held in each frame and latched for each sensor, and the simulator is
fed exactly that (``replay_cell``): then every robot's setpoint of every sample, every item
record and every event are bit-identical, and the counts the bus sent to each drive are the
simulator's setpoints through the same counts converter.  The simulator on its own masters
agrees on every item's outcome, and its setpoints are those of the bus up to the belt travel
of the 1 + d cycles the bus looks ahead.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from controller.canopen.apps.cell import CellSource
from controller.conveyor.telemetry import ItemStatus
from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.config import load_config, parse_config
from controller.canopen.master.cycle import EXIT_ERROR, EXIT_OK, EXIT_REACTION, Controller
from controller.canopen.protocol.cia402 import State, decode_statusword
from controller.canopen.slave.world import SimWorld
from controller.cli import demo as cmd_demo
from controller.errors import ConfigError
from controller.simulate.cell import replay_cell, run_cell
from controller.simulate.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
BUS = ROOT / "examples" / "bus" / "cell_handoff.yml"
SCENARIO = ROOT / "examples" / "cell_bus_handoff.yaml"
TEXT = BUS.read_text()


def _real_time_text() -> str:
    """The example with a 10 ms cycle and generous supervision windows (heartbeat time-outs
    10 x 100 ms, time-outs of seconds, 20 silent cycles): real time on a loaded machine."""
    text = TEXT.replace("heartbeat_producer: 50", "heartbeat_producer: 100")
    for old, new in (("sync_period: 4000 ", "sync_period: 10000 "),
                     ("heartbeat_multiplier: 3.0", "heartbeat_multiplier: 10.0"),
                     ("timeouts: {boot_up_s: 2.0, sdo_s: 0.5, enable_s: 2.0}",
                      "timeouts: {boot_up_s: 4.0, sdo_s: 1.0, sdo_retries: 2, enable_s: 4.0}"),
                     ("counts_per_mm: 40.96}    # 4096", "counts_per_mm: 40.96, silent_cycles: 20}  #"),
                     ("belt_b: {node: enc_b, counts_per_mm: 40.96}",
                      "belt_b: {node: enc_b, counts_per_mm: 40.96, silent_cycles: 20}"),
                     ("../../eds/", str(ROOT / "eds") + "/")):
        assert old in text, old
        text = text.replace(old, new)
    return text


def _run(cfg, src, *, inject=None, max_cycles=None):
    with SimWorld(cfg) as world:
        ctl = Controller(cfg, world.transport, src, keep_trace=True)
        if inject is not None:
            inject(world)
        ctl.boot()
        ctl.start()
        ctl.run(max_cycles=max_cycles)
    return ctl


@pytest.fixture(scope="module")
def bus_run():
    cfg = load_config(BUS)
    sc = load_scenario(SCENARIO)
    src = CellSource(cfg.tracking.cell, duration_s=sc.duration_s, record=10**6,
                     keep_inputs=True)
    ctl = _run(cfg, src)
    return cfg, sc, src, ctl


def test_the_cell_runs_on_the_bus_and_ends_cleanly(bus_run):
    cfg, sc, src, ctl = bus_run
    assert ctl.exit_code() == EXIT_OK and ctl.failure is None
    assert src.run.k == sc.n_samples                         # 6 s of tracking, 1500 cycles
    kinds = [e.kind for e in ctl.events]
    assert kinds.count("enabled") == 1 and "handoff" in kinds
    # every drive of both robots is disabled at the end (shut down, holding)
    last = ctl.trace[-1]
    assert last.phase == "stopped" and len(last.statuswords) == 6
    assert all(decode_statusword(sw) is State.READY_TO_SWITCH_ON for sw in last.statuswords)
    r1, r2 = src.summaries["r1"], src.summaries["r2"]
    assert (r1.triggered, r1.caught, r1.missed, r1.handoffs) == (2, 2, 0, 1)
    assert (r2.triggered, r2.caught, r2.ignored, r2.handoffs) == (2, 1, 1, 0)
    # the drives follow their targets: |actual - target| well inside a count's worth of mm
    assert 0.0 < r1.max_error_mm < 0.01 and 0.0 < r2.max_error_mm < 0.01


#: robot r2 with a pick program on its frame B2 instead of timed MasterFrame changes: the
#: bus file's text and the scenario's, each as written there
PROGRAM = (("        master_frame:\n          - {time_s: 0.5, frame: B2}\n"
            "          - {time_s: 4.5, frame: none}\n",
            "        program: {frame: B2, approach_mm: 50, dwell_s: 0.1,\n"
            "                  place: [1000.0, 300.0, 100.0]}\n"),
           ("      master_frame:\n        - {time_s: 0.5, frame: B2}\n"
            "        - {time_s: 4.5, frame: none}\n",
            "      program: {frame: B2, approach_mm: 50, dwell_s: 0.1,\n"
            "                place: [1000.0, 300.0, 100.0]}\n"))


@pytest.fixture(scope="module")
def program_run(tmp_path_factory):
    """The cell with r2 picking by its program (on the bus and in the scenario)."""
    (b_old, b_new), (s_old, s_new) = PROGRAM
    d = tmp_path_factory.mktemp("program")
    # (r2 goes down onto the item at z = 0: its z may go below, as a quick stop from the
    # descent would)
    btext = TEXT.replace(b_old, b_new).replace(
        "z: {node: z2, counts_per_mm: 10000, min: 0, max: 200}",
        "z: {node: z2, counts_per_mm: 10000, min: -50, max: 200}")
    stext = SCENARIO.read_text().replace(s_old, s_new)
    assert btext != TEXT and stext != SCENARIO.read_text()
    (d / "bus.yml").write_text(btext)
    (d / "cell.yaml").write_text(stext)
    cfg = parse_config(btext, str(d / "bus.yml"), base_dir=BUS.parent)
    sc = load_scenario(d / "cell.yaml")
    src = CellSource(cfg.tracking.cell, duration_s=sc.duration_s, record=10**6,
                     keep_inputs=True)
    return cfg, sc, src, _run(cfg, src)


def test_a_robot_with_a_pick_program_on_the_bus(program_run):
    """r2 runs its pick program on the bus: the type-2 item is caught, picked and placed
    (the program's place reached), the type-1 item ignored."""
    cfg, sc, src, ctl = program_run
    assert ctl.exit_code() == EXIT_OK
    r2 = src.summaries["r2"]
    assert (r2.triggered, r2.caught, r2.picked, r2.ignored) == (2, 1, 1, 1)
    prog = src.run.programs["r2"]
    assert list(prog.picks) == [2] and not prog.unpicked
    assert src.traces["r2"].pos[-1] == pytest.approx((1000.0, 300.0, 100.0), abs=1e-6)


#: robot r2 following robot r1's TCP (a group frame, type 3: docs/spec/conveyor-extensions.md#4)
#: from 0.2 s to 1.0 s, its item 500 mm beside r1's TCP: (old, new) in the bus file, then in
#: the scenario (as written there)
GROUP = ((("      - name: B2                        # r2's own frame object on belt B\n",
           "      - name: on_r1                     # r1's TCP as r2's master\n"
           "        group: {robot: r1}\n"
           "        limits: {VelocityMaxTrans: 2000, AccelerationMaxTrans: 20000}\n"
           "      - name: B2                        # r2's own frame object on belt B\n"),
          ("        track_types: {B2: [2]}\n        master_frame:\n"
           "          - {time_s: 0.5, frame: B2}\n          - {time_s: 4.5, frame: none}\n",
           "        master_frame:\n          - {time_s: 0.2, frame: on_r1}\n"
           "          - {time_s: 1.0, frame: none}\n"),
          ("      - {frame: B2, robots: [r2], trigger_times: [0.3, 0.6], types: [1, 2]}\n",
           "      - {frame: on_r1, robots: [r2], trigger_times: [0.1],\n"
           "         offset: {position: [500, 100, 0]}}\n")),
         (("    - name: B2\n",
           "    - name: on_r1\n      group: {robot: r1}\n"
           "      limits: {VelocityMaxTrans: 2000, AccelerationMaxTrans: 20000}\n"
           "    - name: B2\n"),
          ("      track_types: {B2: [2]}\n      master_frame:\n"
           "        - {time_s: 0.5, frame: B2}\n        - {time_s: 4.5, frame: none}\n",
           "      master_frame:\n        - {time_s: 0.2, frame: on_r1}\n"
           "        - {time_s: 1.0, frame: none}\n"),
          ("    - {frame: B2, robots: [r2], trigger_times: [0.3, 0.6], types: [1, 2]}\n",
           "    - {frame: on_r1, robots: [r2], trigger_times: [0.1],\n"
           "       offset: {position: [500, 100, 0]}}\n")))


@pytest.fixture(scope="module")
def group_run(tmp_path_factory):
    """The cell with r2 following r1's TCP (on the bus and in the scenario)."""
    d = tmp_path_factory.mktemp("group")
    btext, stext = TEXT, SCENARIO.read_text()
    for old, new in GROUP[0]:
        assert old in btext, old
        btext = btext.replace(old, new)
    for old, new in GROUP[1]:
        assert old in stext, old
        stext = stext.replace(old, new)
    (d / "bus.yml").write_text(btext)
    (d / "cell.yaml").write_text(stext)
    cfg = parse_config(btext, str(d / "bus.yml"), base_dir=BUS.parent)
    sc = load_scenario(d / "cell.yaml")
    src = CellSource(cfg.tracking.cell, duration_s=2.0, record=10**6, keep_inputs=True)
    return cfg, sc, src, _run(cfg, src)


def test_a_robot_follows_another_robots_tcp_on_the_bus(group_run):
    """r2 tracks r1's TCP (group frame, its limits taken): synchronised at once (r1 at rest),
    then r2's x moves with r1's until the MasterFrame = none at 1.0 s."""
    cfg, sc, src, ctl = group_run
    assert ctl.exit_code() == EXIT_OK
    assert src.summaries["r2"].caught == 1
    T = cfg.period_s
    r1 = np.array(src.traces["r1"].pos)
    r2 = np.array(src.traces["r2"].pos)
    k = slice(round(0.5 / T), round(0.95 / T))        # r1 moving, r2 synchronised
    assert np.ptp(r1[k, 0]) > 50.0
    assert np.allclose(r2[k, 0] - r1[k, 0], 1000.0 - 300.0, atol=1e-6)   # slave 5: its offset


@pytest.mark.parametrize("which", ["timed", "program", "group"])
def test_bus_and_simulator_give_the_same_setpoints_and_items(which, request):
    """Bit-identical on the same inputs (see the module docstring); r2 by timed MasterFrame
    changes, by its pick program, following r1's TCP."""
    cfg, sc, src, ctl = request.getfixturevalue(f"{which}_run" if which != "timed"
                                                else "bus_run")
    tc = cfg.tracking
    assert sc.params == tc.tracker                  # the same tracker for every robot
    assert sc.frames == tc.cell.frames and sc.sensors == tc.cell.sensors
    assert sc.robots == tuple(r.spec for r in tc.cell.robots)
    sim = replay_cell(sc, src.inputs, src.latches)
    assert len(sim.time_s) == src.recorded == src.run.k + 1
    assert src.run.k == round(min(sc.duration_s, src.duration_s) / sc.sample_time_s)
    assert {n: p.picks for n, p in src.run.programs.items()} == \
        {n: tr.picks for n, tr in sim.robots.items() if tr.picks}
    for name, tr in sim.robots.items():
        bus = src.traces[name]
        assert np.array_equal(np.array(bus.pos), tr.setpoint_pos), name
        assert np.array_equal(np.array(bus.ori), tr.setpoint_ori), name
        assert bus.imfs == tr.imfs.tolist() and bus.mf == tr.master_frame
        assert bus.events == tr.events
        assert [r.as_dict() for r in src.records(name)] == [r.as_dict() for r in tr.records]
    assert src.run.triggers == sim.triggers
    # the counts on the bus are the simulator's setpoints through the drives' scales
    # (the start's cycle holds the drives where they were enabled; loop index n is the
    # cycle after it + n and sends sample n + 1)
    running = [r for r in ctl.trace if r.phase == "running"][1:]
    assert len(running) == src.run.k
    conv = ctl.counts
    for n, rec in enumerate(running):
        joints = []
        for rc in tc.cell.robots:
            joints.extend(sim.robots[rc.name].setpoint_pos[n + 1][:len(rc.axes)])
        assert rec.targets == tuple(conv.to_counts(joints)), n


def test_the_simulator_on_its_own_masters_agrees(bus_run):
    """The simulator's own belts (200 and 150 mm/s through its encoder source): the same
    item outcomes, synchronised within a few samples, the setpoints within the belt travel of
    the 1 + d cycles the bus predicts ahead (plus 0.1 mm of estimator and latch)."""
    cfg, sc, src, ctl = bus_run
    sim = run_cell(sc)
    T = sc.sample_time_s
    lead_s = (1 + cfg.tracking.drive_delay_cycles) * T
    for name, tr in sim.robots.items():
        bus = src.records(name)
        assert [(r.item_id, r.frame, r.item_type, r.status) for r in bus] == \
            [(r.item_id, r.frame, r.item_type, r.status) for r in tr.records], name
        for a, b in zip(bus, tr.records):
            if b.synced_s is not None:
                assert abs(a.synced_s - b.synced_s) <= 4 * T + 1e-9, (name, a, b)
    # following: the bus is ahead by lead_s of belt travel (r1 on A at 200 mm/s, r2 on B2
    # at 150 mm/s), in the direction of the belt
    for name, speed, d, (t0, t1) in (("r1", 200.0, 0, (0.8, 1.9)),
                                     ("r2", 150.0, 1, (1.5, 4.4))):
        k = slice(round(t0 / T), round(t1 / T))
        diff = np.array(src.traces[name].pos)[k] - sim.robots[name].setpoint_pos[k]
        assert np.all(np.abs(diff[:, d] - speed * lead_s) < 0.1), name
        assert np.all(np.abs(np.delete(diff, d, axis=1)) < 1e-9), name


def test_a_drive_fault_in_one_robot_stops_every_drive():
    """Drive y2 (robot r2) faults while r1 follows belt A: all six drives quick-stop (each
    confirmed by its statusword), none is left enabled, exit code 3."""
    cfg = load_config(BUS)
    src = CellSource(cfg.tracking.cell, duration_s=3.0)

    def inject(world):
        world.at(1.0, lambda: world.device("y2").inject_fault(0x2310))

    ctl = _run(cfg, src, inject=inject)
    stops = [e for e in ctl.events if e.reaction.startswith("quick stop")]
    assert len(stops) == 1 and "y2" in stops[0].source and stops[0].kind in ("emcy",
                                                                             "drive_fault")
    assert any(e.kind == "drive_fault" and "y2" in e.source for e in ctl.events)
    confirmed = {e.source for e in ctl.events if e.kind == "stop_confirmed"}
    assert len(confirmed) == 6, confirmed                  # every drive of both robots
    assert all(s.confirmed_cycle is not None for s in ctl.stops)
    assert all(decode_statusword(sw) is not State.OPERATION_ENABLED
               for sw in ctl.trace[-1].statuswords)
    assert ctl.exit_code() == EXIT_REACTION
    assert src.run.k < 3.0 / cfg.period_s                  # the run stopped early


def test_a_setpoint_beyond_an_axis_limit_stops_every_drive(tmp_path):
    """r1's x is limited to 600 mm: following belt A at 200 mm/s takes it there; the cycle's
    limit check on the cell's axis setpoints (target and quick-stop end) stops all drives."""
    text = TEXT.replace("x: {node: x1, counts_per_mm: 10000, min: -50, max: 1300}",
                        "x: {node: x1, counts_per_mm: 10000, min: -50, max: 600}")
    assert text != TEXT
    path = tmp_path / "bus.yml"
    path.write_text(text)
    cfg = parse_config(text, str(path), base_dir=BUS.parent)
    src = CellSource(cfg.tracking.cell, duration_s=3.0)
    ctl = _run(cfg, src)
    lim = [e for e in ctl.events if e.kind == "limit"]
    assert lim and "x1" in lim[0].source and "outside [-50, 600]" in lim[0].detail
    assert ctl.exit_code() == EXIT_REACTION
    assert all(s.confirmed_cycle is not None for s in ctl.stops)
    assert not _stalled_into_the_limit(*_stepped_telemetry(ctl))  # (a limit, no stall)


def test_a_source_for_one_belt_is_refused_by_a_cell():
    """A tool setpoint (one kinematics) for a cell of two robots: the cycle refuses it (the
    controlled stop, exit code 2, saying why), never sends one robot's joints to six drives."""
    cfg = load_config(BUS)
    with SimWorld(cfg) as world:
        ctl = Controller(cfg, world.transport, ConveyorFollow(end_cycle=50), keep_trace=True)
        ctl.boot()
        ctl.start()
        with pytest.raises(Exception, match="every drive's target"):
            ctl.run(max_cycles=200)
    assert ctl.exit_code() == EXIT_ERROR
    assert all(s.confirmed_cycle is not None for s in ctl.stops)


def test_a_robot_starts_where_its_drives_are(tmp_path):
    """Drive x2 is 5 mm off r2's start: r2 starts at its drives' pose (no jump), said in a
    start_pose event; the run is otherwise the same."""
    text = TEXT.replace("x2: {initial_counts: 10000000,", "x2: {initial_counts: 10050000,")
    assert text != TEXT
    path = tmp_path / "bus.yml"
    path.write_text(text)
    cfg = parse_config(text, str(path), base_dir=BUS.parent)
    src = CellSource(cfg.tracking.cell, duration_s=1.0, record=10**6)
    ctl = _run(cfg, src)
    ev = [e for e in ctl.events if e.kind == "start_pose"]
    assert len(ev) == 1 and "'r2'" in ev[0].detail and "x=1005.000" in ev[0].detail
    assert src.traces["r2"].pos[0] == (1005.0, 300.0, 100.0)
    running = [r for r in ctl.trace if r.phase == "running"]
    assert running[1].targets[3] == 10050000               # x2 held where it was
    assert ctl.exit_code() == EXIT_OK


def test_cantrack_demo_runs_the_cell(tmp_path, capsys):
    """``cantrack demo CELL.yml``: summary per robot, frame and item; telemetry with each
    robot's items and the counts per robot and frame; the plot."""
    out = tmp_path / "out"
    code = cmd_demo.main([str(BUS), "-q", "-o", str(out)])
    text = capsys.readouterr().out
    assert code == 0
    rows: dict[str, list[str]] = {}     # the first row of each name: the robot, frame tables
    for line in text.splitlines():
        if line.startswith(("r1 ", "r2 ", "A ", "B ", "B2 ")):
            rows.setdefault(line.split()[0], line.split())
    assert rows["r1"][1:7] == ["2", "2", "0", "0", "0", "1"]      # items .. hand-offs
    assert rows["r2"][1:7] == ["2", "1", "0", "0", "1", "0"]
    assert rows["B2"][1:5] == ["2", "1", "0", "1"]
    assert "2 robots, 3 frames, 2 encoders" in text
    lines = [json.loads(x) for x in (out / "telemetry.jsonl").read_text().splitlines()]
    assert lines[0]["type"] == "run" and lines[0]["cell"]["robots"] == {
        "r1": ["x", "y", "z"], "r2": ["x", "y", "z"]}
    assert len(lines[0]["axes"]) == 6
    items = [d for d in lines if d["type"] == "item"]
    assert sorted((d["robot"], d["item"], d["frame"], d["status"]) for d in items) == [
        ("r1", 1, "A", "caught"), ("r1", 2, "B", "caught"),
        ("r2", 1, "B2", "ignored"), ("r2", 2, "B2", "caught")]
    end = lines[-1]
    assert end["type"] == "end" and end["robots"]["r1"]["handoffs"] == 1
    assert end["frames"]["A"] == {"triggered": 1, "caught": 1, "missed": 0, "ignored": 0}
    assert (out / "demo.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert any(d["kind"] == "handoff" for d in lines if d["type"] == "event")


def test_cantrack_demo_refuses_the_photo_eye_options_for_a_cell(tmp_path):
    with pytest.raises(ConfigError, match="--items is for the demo's photo-eye"):
        cmd_demo.main([str(BUS), "-q", "--items", "3", "-o", str(tmp_path)])


def test_cantrack_demo_runs_the_cell_in_real_time(tmp_path, capsys):
    """``--realtime``: the same cell on the wall clock (a 10 ms cycle, so that a loaded
    machine keeps it), 2 s of tracking: r1 catches its item on belt A, r2 its type-2 item
    on B2, no reaction, exit 0; the real-time figures are taken."""
    path = tmp_path / "bus.yml"
    path.write_text(_real_time_text())
    out = tmp_path / "out"
    code = cmd_demo.main([str(path), "-q", "--no-plot", "--realtime", "--duration", "2.0",
                          "-o", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "SYNC jitter p50/p99/max" in text
    lines = [json.loads(x) for x in (out / "telemetry.jsonl").read_text().splitlines()]
    end = lines[-1]
    assert end["type"] == "end" and end["reactions"] == 0
    assert end["robots"]["r1"]["caught"] == 1 and end["robots"]["r2"]["caught"] == 1
    assert end["timing"]["sync_jitter_us"]["n"] >= 2.0 / 0.010   # measured every cycle


def test_a_silent_encoder_desyncs_only_the_robots_on_its_frames():
    """Belt B's encoder stops sending at 1.0 s: the cycle reports it (master_silent, de-sync)
    and the source stops r2, which was catching its item on B2 (fed by that encoder); r1 on
    belt A goes on following; no quick stop, the drives stay enabled to the end."""
    cfg = load_config(BUS)
    src = CellSource(cfg.tracking.cell, duration_s=1.9, record=10**6)

    def inject(world):
        world.at(1.0, lambda: world.device("enc_b").mute_pdos())

    ctl = _run(cfg, src, inject=inject)
    silent = [e for e in ctl.events if e.kind == "master_silent"]
    assert len(silent) == 1 and "enc_b" in silent[0].source
    assert "de-sync" in silent[0].reaction
    assert ctl.events.quick_stops == 0 and ctl.exit_code() == EXIT_REACTION
    n0 = silent[0].cycle - src.start_cycle            # (sample n is cycle start + n)
    r1, r2 = src.traces["r1"], src.traces["r2"]
    assert len(r1.imfs) > n0 + 100
    assert all(x == 1 for x in r1.imfs[n0 - 10:])     # r1 synchronised throughout
    assert src.summaries["r2"].caught == 0 and r2.imfs[-1] != 1
    assert any(e.kind.value == "leave" for e in r2.events)       # r2's link was left (STOP)


def test_a_robot_with_a_tool_axis_keeps_its_angle_without_a_turn(tmp_path):
    """r1 with a rotary tool axis c (deg) whose drive is at 350 deg: r1 starts there (its
    start has angle 0 = 360 deg, 10 deg away: a start_pose event) and c stays at 350 deg while
    it follows (the twist is unwrapped from the drive's angle, never sent as -10 deg)."""
    text = TEXT.replace("z2: {<<: *drive, node_id: 23}",
                        "z2: {<<: *drive, node_id: 23}\nc1: {<<: *drive, node_id: 14}")
    text = text.replace(
        "            z: {node: z1, counts_per_mm: 10000, min: 0, max: 200}\n",
        "            z: {node: z1, counts_per_mm: 10000, min: 0, max: 200}\n"
        "            c: {node: c1, counts_per_deg: 1000, min: 0, max: 720}\n")
    text = text.replace("  z2: {initial_counts: 1000000, max_velocity: 3.0e7}",
                        "  z2: {initial_counts: 1000000, max_velocity: 3.0e7}\n"
                        "  c1: {initial_counts: 350000, max_velocity: 3.0e7}")
    assert text.count("c1") == 3
    path = tmp_path / "bus.yml"
    path.write_text(text)
    cfg = parse_config(text, str(path), base_dir=BUS.parent)
    assert [a.name for a in cfg.tracking.cell.robots[0].axes] == ["x", "y", "z", "c"]
    src = CellSource(cfg.tracking.cell, duration_s=1.0)
    ctl = _run(cfg, src)
    assert ctl.exit_code() == EXIT_OK
    ev = [e for e in ctl.events if e.kind == "start_pose"]
    assert len(ev) == 1 and "c=350.000" in ev[0].detail and "c=360.000" in ev[0].detail
    running = [r for r in ctl.trace if r.phase == "running"][1:]
    c = [r.targets[3] for r in running]
    assert min(c) == max(c) == 350000                 # x moved with belt A, c did not turn
    assert running[-1].targets[0] > running[0].targets[0] + 1_000_000


def _cantrack_run_cell(tmp_path, attempt: int, *, raises: type[BaseException] | None = None):
    """``cantrack run CELL.yml`` against ``cantrack sim-devices`` (a thread) on a python-can
    virtual channel of its own, real time, 10 ms cycle: (exit code, telemetry) - with
    ``raises``, the run must raise it: (the exception, telemetry)."""
    import os
    import threading

    from controller.cli import run as cmd_run
    from controller.cli import sim_devices as cmd_sim
    from controller.testing.e2e import wait_file

    d = tmp_path / f"run{attempt}"
    d.mkdir()
    path = d / "bus.yml"
    path.write_text(_real_time_text())
    channel = f"cell-{os.getpid()}-{attempt}"
    ready = d / "ready.json"
    done = threading.Event()
    errors: list[BaseException] = []

    def devices():
        try:
            cmd_sim.main([str(path), "-i", "virtual", "-c", channel, "-q", "--duration", "8",
                          "--ready-file", str(ready)])
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)
        finally:
            done.set()

    th = threading.Thread(target=devices, daemon=True)
    th.start()
    wait_file(ready, [], 30, running=lambda: not done.is_set())
    tel = d / "t.jsonl"
    argv = [str(path), "-i", "virtual", "-c", channel, "-q", "--duration", "2.0",
            "--telemetry", str(tel)]
    if raises is None:
        code = cmd_run.main(argv)
    else:
        with pytest.raises(raises) as info:
            cmd_run.main(argv)
        code = info.value
    done.wait(15)
    assert not errors, errors
    return code, [json.loads(x) for x in tel.read_text().splitlines()]


def _stalled_into_the_limit(code: int, lines: list[dict]) -> bool:
    """The run's own telemetry shows the safe reaction to a stall: the 'limit' quick stop of
    x1 in the cycle after an overrun that slipped >= 3 periods (its detail names them), at
    the catch-up's speed, every drive stopped, exit 3 (:func:`_assert_stall_quick_stop`)."""
    if code != EXIT_REACTION or not lines or lines[-1].get("type") != "end":
        return False
    try:
        _assert_stall_quick_stop(*_split(lines))
    except (AssertionError, KeyError, AttributeError):
        return False
    return True


def _split(lines: list[dict]) -> tuple[list[dict], dict]:
    """A telemetry's events and its end line."""
    return [x for x in lines if x["type"] == "event"], lines[-1]


def _stepped_telemetry(ctl) -> tuple[int, list[dict]]:
    """A stepped run's exit code and its events and end line as ``cantrack run`` writes them
    to the telemetry (for :func:`_stalled_into_the_limit`)."""
    code = ctl.exit_code()
    events = [dict(type="event", **e.as_dict()) for e in ctl.events]
    end = {"type": "end", "exit_code": code, "events": ctl.events.total,
           "timing": {"overruns": ctl.timing.overruns}}
    return code, json.loads(json.dumps(events + [end]))


def _assert_telemetry_complete(lines: list[dict]) -> None:
    """The telemetry has its run line, a cycle line for every cycle, every event and the end
    line with the robots and the timing."""
    end = lines[-1]
    assert lines[0]["type"] == "run" and end["type"] == "end", (lines[0], end)
    assert {"robots", "timing", "exit_code"} <= set(end), end
    assert [x["cycle"] for x in lines if x["type"] == "cycle"] == list(range(end["cycles"]))
    assert sum(1 for x in lines if x["type"] == "event") == end["events"]


def test_cantrack_run_runs_the_cell_against_sim_devices(tmp_path, capsys):
    """``cantrack run CELL.yml`` on a python-can virtual channel against ``cantrack
    sim-devices`` (a thread: the virtual interface does not reach other processes), in real
    time with a 10 ms cycle: the cell's summary, each robot's items in the telemetry, exit 0.
    A loaded machine may stall the controller while r1 is synchronised (108 ms seen): the
    catch-up then exceeds x1's limit and the correct reaction is the limit quick stop of
    every drive, exit 3.  Only when the run's telemetry shows exactly that (the limit event
    naming the overrun's slipped periods, all drives stopped, exit 3) is it run once more;
    stalled again the same way, the safe reaction is asserted in full; any other outcome
    fails."""
    code, lines = _cantrack_run_cell(tmp_path, 0)
    out = capsys.readouterr().out
    if _stalled_into_the_limit(code, lines):
        code, lines = _cantrack_run_cell(tmp_path, 1)
        out = capsys.readouterr().out
        if code != EXIT_OK:
            assert code == EXIT_REACTION, out
            _assert_stall_quick_stop(*_split(lines))
            _assert_telemetry_complete(lines)
            return
    assert code == 0, out
    assert out.splitlines()[0].split() == ["robot", "items", "caught", "picked", "missed",
                                           "ignored", "hand-offs", "max", "err", "mm"]
    assert "items placed" not in out                       # (the cell prints its own items)
    end = lines[-1]
    assert end["type"] == "end" and end["exit_code"] == 0
    items = [{k: d[k] for k in ("robot", "item", "status", "trigger_s", "engaged_s", "synced_s")}
             for d in lines if d["type"] == "item"]
    assert end["robots"]["r1"]["caught"] == 1 and end["robots"]["r2"]["caught"] == 1, (
        f"robots {end['robots']}; items {items}; overruns "
        f"{end.get('timing', {}).get('overruns')}; events "
        f"{[(d['cycle'], d['source'], d['kind']) for d in lines if d['type'] == 'event']}")
    assert {(d["robot"], d["item"]) for d in lines if d["type"] == "item"} == {
        ("r1", 1), ("r1", 2), ("r2", 1), ("r2", 2)}


def test_cantrack_run_of_a_cell_that_fails_ends_its_telemetry_as_a_normal_end(tmp_path,
                                                                             monkeypatch):
    """``cantrack run CELL.yml`` whose cycle fails (the cell's source raises in the cycle the
    first item is triggered: an internal error, the controlled stop, the run raises it): the
    telemetry still gets the items pending then, each once, and the end line with the same
    keys in the same order as a normal end (exit code 2, every robot's summary, the frames'
    counts), as ``cantrack demo`` writes a cell's telemetry on every exit."""
    from controller.canopen.master.cycle import CycleError

    step = CellSource.step
    seen: list[tuple[str, int]] = []

    def failing_step(self, ctx):
        out = step(self, ctx)
        if not seen and sum(s.triggered for s in self.summaries.values()):
            seen.extend((robot, rec.item_id) for robot, rec in self.unfinished())
            raise RuntimeError("injected fault")
        return out

    monkeypatch.setattr(CellSource, "step", failing_step)
    exc, lines = _cantrack_run_cell(tmp_path, 0, raises=CycleError)
    assert "injected fault" in str(exc) and seen
    end = lines[-1]
    assert list(end) == ["type", "end", "error", "cycles", "t_s", "phase", "events",
                         "reactions", "timing", "exit_code", "robots", "frames"]
    assert (end["end"], end["exit_code"]) == ("error", EXIT_ERROR)
    assert "injected fault" in end["error"]
    assert set(end["robots"]) == {"r1", "r2"} and set(end["frames"]) == {"A", "B", "B2"}
    assert sum(r["triggered"] for r in end["robots"].values()) == len(seen)
    items = [(d["robot"], d["item"]) for d in lines if d["type"] == "item"]
    assert items == seen  # (pending when it failed: written once, at the end)


def test_cantrack_run_refuses_the_one_belt_options_for_a_cell():
    from controller.cli import run as cmd_run

    with pytest.raises(ConfigError, match="--engage-at is for one belt") as info:
        cmd_run.main([str(BUS), "-i", "virtual", "-c", "nobody", "--engage-at", "1"])
    assert info.value.key == ".tracking.cell"


def test_no_hand_off_onto_a_belt_whose_encoder_is_silent():
    """Belt B's encoder is silent from 1.0 s on: r1's hand-off to B at 2.0 s is refused (a
    command_error event: the belt would only be extrapolated) and r1 keeps following A."""
    cfg = load_config(BUS)
    src = CellSource(cfg.tracking.cell, duration_s=2.5, record=10**6)

    def inject(world):
        world.at(1.0, lambda: world.device("enc_b").mute_pdos())

    ctl = _run(cfg, src, inject=inject)
    refused = [e for e in ctl.events if e.kind == "command_error"]
    assert len(refused) == 1 and "r1" in refused[0].detail
    assert "MasterFrame = B refused: encoder 'belt_b' not ready" in refused[0].detail
    assert abs(refused[0].t_s - ctl.events.of_kind("enabled")[0].t_s - 2.0) < 0.01
    assert src.summaries["r1"].handoffs == 0
    assert src.traces["r1"].mf[-1] == "A" and src.traces["r1"].imfs[-1] == 1


def test_a_robot_base_frame_maps_the_world_setpoint_to_its_drives(tmp_path):
    """r2's base is 100 mm along x in the world: its drives get Robot_real = base⁻¹ :
    setpoint (x 100 mm less than the world TCP), its world setpoint is the same as without
    the base (its start is a world location) and it starts without a start_pose event."""
    text = TEXT.replace("        start: [1000.0, 300.0, 100.0]\n",
                        "        start: [1000.0, 300.0, 100.0]\n"
                        "        base: {position: [100.0, 0.0, 0.0]}\n")
    text = text.replace("x2: {initial_counts: 10000000,", "x2: {initial_counts: 9000000,")
    assert text.count("base: {position") == 1 and "initial_counts: 9000000" in text
    path = tmp_path / "bus.yml"
    path.write_text(text)
    cfg = parse_config(text, str(path), base_dir=BUS.parent)
    src = CellSource(cfg.tracking.cell, duration_s=2.0, record=10**6)
    ctl = _run(cfg, src)
    assert ctl.exit_code() == EXIT_OK and not ctl.events.of_kind("start_pose")
    ref = CellSource(load_config(BUS).tracking.cell, duration_s=2.0, record=10**6)
    _run(load_config(BUS), ref)
    assert src.traces["r2"].pos == ref.traces["r2"].pos        # the same world TCP
    running = [r for r in ctl.trace if r.phase == "running"][1:]
    world = np.array(src.traces["r2"].pos[1:])
    x2 = np.array([r.targets[3] for r in running])
    assert np.all(np.abs(x2 - (world[:, 0] - 100.0) * 10000) <= 0.5)
    assert np.ptp(world[:, 1]) > 50.0                            # r2 followed belt B2


class _Stall:
    """The cell source, and one stall: in its step ``at`` the cycle's computation takes
    ``stall_ns`` of the stepped clock (a loaded machine's pause); the velocities it gave are
    kept per step."""

    def __init__(self, inner: CellSource, clock, at: int, stall_ns: int) -> None:
        self.inner, self.clock, self.at, self.stall_ns = inner, clock, at, stall_ns
        self.n = 0
        self.velocities: list[tuple[float, ...]] = []

    def start(self, start):
        return self.inner.start(start)

    def step(self, ctx):
        out = self.inner.step(ctx)
        self.velocities.append(out.setpoint.velocities)
        if self.n == self.at:
            self.clock.advance_to(self.clock.now_ns() + self.stall_ns)
        self.n += 1
        return out


def _stalled_run(tmp_path, stall_ms: float):
    """The real-time test's cell (10 ms cycle), stepped, with one stall of ``stall_ms`` in
    step 60 (r1 synchronised on its item, following belt A at 200 mm/s)."""
    path = tmp_path / "bus.yml"
    path.write_text(_real_time_text())
    cfg = load_config(path)
    src = CellSource(cfg.tracking.cell, duration_s=2.0, record=10**6)
    with SimWorld(cfg) as world:
        stall = _Stall(src, world.clock, 60, round(stall_ms * 1e6))
        ctl = Controller(cfg, world.transport, stall, keep_trace=True)
        ctl.boot()
        ctl.start()
        ctl.run()
    return ctl, src, stall


#: belt A [mm/s] (the example's), r1's x velocity while it is synchronised
BELT_A_MM_S = 200.0


def _slip_periods(detail: str) -> int:
    return int(re.search(r"slipped by (\d+) period", detail).group(1))


def _limit_speed_mm_s(detail: str) -> float:
    return float(re.search(r" mm at (-?[\d.]+) mm/s", detail).group(1))


def _assert_stall_quick_stop(events: list[dict], end: dict) -> None:
    """The safe reaction to an overrun whose catch-up exceeds an axis limit, from the run's
    events (dicts as in the telemetry) and its end line: one 'limit' event of x1 in the cycle
    right after an overrun that slipped p >= 3 periods (two are ridden through), at about
    (p + 1) periods of belt A's travel in one period (the drive holds its target through the
    slip and then executes the whole catch-up between two SYNCs), a quick stop of all drives,
    every one of the six confirmed, the 'stopped' event, exit 3."""
    lim = [e for e in events if e["kind"] == "limit"]
    assert len(lim) == 1, lim
    p = _slip_periods(lim[0]["detail"])
    assert p >= 3, lim
    assert "x1" in lim[0]["source"] and lim[0]["reaction"] == "quick stop of all drives"
    v = _limit_speed_mm_s(lim[0]["detail"])
    assert 0.8 * (p + 1) * BELT_A_MM_S < v < 1.2 * (p + 1) * BELT_A_MM_S, (p, lim)
    assert events.index(lim[0]) == [e["reaction"] != "" for e in events].index(True)
    confirmed = {e["source"] for e in events if e["kind"] == "stop_confirmed"}
    assert len(confirmed) == 6, confirmed                  # every drive of both robots
    assert all(e["cycle"] >= lim[0]["cycle"] for e in events if e["kind"] == "stop_confirmed")
    assert [e["kind"] for e in events if e["kind"] in ("stopped", "stop_unconfirmed")] \
        == ["stopped"]
    assert end["type"] == "end" and end["exit_code"] == EXIT_REACTION
    assert end["timing"]["overruns"] >= 1


def test_a_long_stall_while_synchronised_quick_stops_every_drive(tmp_path):
    """One 108 ms stall while r1 is synchronised (the stall a loaded machine made in a full
    suite): the time base slips by 9 periods, no SYNC is sent for them and the CSP drives
    hold their last target; the belt estimate and r1 with it move on by the slipped periods,
    so the next target is the whole catch-up (10 periods of belt A, 20 mm) away, which the
    drive executes in one period: x1 at ~2000 mm/s, its quick stop ending outside
    [-50, 1300]: the limit check over one period sees it, and quick-stops every drive of
    both robots, each confirmed, exit 3 (the safe reaction)."""
    ctl, src, stall = _stalled_run(tmp_path, 108.0)
    assert ctl.timing.overruns == 1
    _assert_stall_quick_stop(*_split(_stepped_telemetry(ctl)[1]))
    assert _slip_periods(ctl.events.of_kind("limit")[0].detail) == 9
    assert all(s.confirmed_cycle is not None for s in ctl.stops)
    assert all(decode_statusword(sw) is not State.OPERATION_ENABLED
               for sw in ctl.trace[-1].statuswords)
    assert ctl.failure is None and ctl.exit_code() == EXIT_REACTION
    assert src.run.k < 2.0 / ctl.cfg.period_s              # the run stopped early
    assert _stalled_into_the_limit(*_stepped_telemetry(ctl))  # (the real-time test's cue)


def test_a_short_stall_within_the_axis_limits_is_ridden_through(tmp_path):
    """One 35 ms stall while r1 is synchronised: 2 slipped periods, the catch-up (3 periods
    of belt A, 6 mm, ~600 mm/s in one period) within the axis limits: no limit, no reaction,
    both items caught, exit 0; the velocity checked for the cycle after the slip is the
    catch-up's (3 x the belt's), the one the drive executes, not the belt's."""
    ctl, src, stall = _stalled_run(tmp_path, 35.0)
    assert ctl.timing.overruns == 1
    assert not ctl.events.of_kind("limit") and ctl.events.reactions == 0
    assert ctl.failure is None and ctl.exit_code() == EXIT_OK
    assert src.summaries["r1"].caught == 1 and src.summaries["r2"].caught == 1
    assert src.summaries["r1"].missed == 0 and src.summaries["r2"].missed == 0
    vx = [v[0] for v in stall.velocities]
    around = vx[55:61] + vx[62:67]
    assert all(abs(v - BELT_A_MM_S) < 5.0 for v in around)   # r1 moves with belt A
    assert abs(vx[61] - 3 * BELT_A_MM_S) < 15.0
    assert not _stalled_into_the_limit(*_stepped_telemetry(ctl))


def test_item_bookkeeping_per_cycle_is_bounded_by_the_open_items(tmp_path):
    """Issue 12 (O(1) work per cycle in long runs): 110 items on belt B2 in 28 s (every
    0.25 s, types 1 and 2 alternating; B2's window ends 300 mm downstream, r2 is given
    MasterFrame = B2 every 0.2 s, so it catches or misses each type-2 item and ignores the
    others): the cell's item bookkeeping looks at no more records in a cycle than the
    trigger buffer and the robot's links can hold, not at every record made so far (before:
    all of them, every cycle); its counts are those of a full recount of the records, and
    every item is reported once (``on_item``) or is unfinished at the end."""
    n = 110
    times = ", ".join(f"{0.3 + 0.25 * k:.2f}" for k in range(n))
    old = "{frame: B2, robots: [r2], trigger_times: [0.3, 0.6], types: [1, 2]}"
    assert old in TEXT
    text = TEXT.replace(old, "{frame: B2, robots: [r2], trigger_times: [" + times + "], "
                        "types: [" + ", ".join(str(1 + k % 2) for k in range(n)) + "]}")
    b2 = text.index("- name: B2")
    text = text[:b2] + text[b2:].replace("downstream: 1200}", "downstream: 300}", 1)
    old = "- {time_s: 0.5, frame: B2}\n          - {time_s: 4.5, frame: none}"
    assert old in text
    text = text.replace(old, "\n          ".join(
        f"- {{time_s: {0.5 + 0.2 * k:.1f}, frame: B2}}" for k in range(140))
        + "\n          - {time_s: 29.5, frame: none}")
    path = tmp_path / "bus.yml"
    path.write_text(text)
    cfg = parse_config(text, str(path), base_dir=BUS.parent)
    reported: list[tuple[str, int]] = []
    src = CellSource(cfg.tracking.cell, duration_s=30.0,
                     on_item=lambda name, rec: reported.append((name, rec.item_id)))
    _run(cfg, src)
    r2 = src.run.robots["r2"]
    assert len(r2.records) == n                           # each one triggered
    bound = r2.buffer.capacity + len(cfg.tracking.cell.frames) + 1
    assert 0 < src._items["r2"].touched_max <= bound < len(r2.records)
    for rc in cfg.tracking.cell.robots:
        recs = src.records(rc.name)
        sm = src.summaries[rc.name]
        assert (sm.triggered, sm.caught, sm.missed, sm.ignored) == (
            len(recs), sum(r.caught for r in recs),
            sum(r.status is ItemStatus.MISSED for r in recs),
            sum(r.status is ItemStatus.IGNORED for r in recs))
    assert len(reported) == len(set(reported))
    assert sorted(reported + [(name, r.item_id) for name, r in src.unfinished()]) == sorted(
        (rc.name, r.item_id) for rc in cfg.tracking.cell.robots for r in src.records(rc.name))
    assert src.summaries["r2"].ignored > 0 and src.summaries["r2"].caught > 0
