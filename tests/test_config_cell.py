"""``.tracking.cell`` of bus.yml (controller.canopen.config.cell): several encoders, frames and
robots, read with the cell scenarios' readers (controller.cell) -- the example bus cell and its
offline scenario read to the same frames, robots and sensors; bad cells are errors naming
file, line and key."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from controller.canopen.config import load_config, parse_config
from controller.canopen.config.cell import robot_kinematics
from controller.conveyor import Kinematics
from controller.errors import ConfigError, ParameterError
from controller.simulate.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[1]
BUS = ROOT / "examples" / "bus" / "cell_handoff.yml"
SCENARIO = ROOT / "examples" / "cell_bus_handoff.yaml"
TEXT = BUS.read_text()


def test_the_example_cell_has_its_encoders_frames_and_robots():
    cfg = load_config(BUS)
    t = cfg.tracking
    cell = t.cell
    assert {k: e.node for k, e in cell.encoders.items()} == {"belt_a": "enc_a",
                                                             "belt_b": "enc_b"}
    assert [e.counts_per_mm for e in t.encoders] == [40.96, 40.96]
    assert t.conveyor == cell.encoders["belt_a"]
    assert [f.name for f in cell.frames] == ["A", "B", "B2"]
    assert [f.masters for f in cell.frames] == [("belt_a",), ("belt_b",), ("belt_b",)]
    # each robot its own drives, named within the robot; all drives boot
    assert [(a.robot, a.name, a.node) for a in t.axes] == [
        ("r1", "x", "x1"), ("r1", "y", "y1"), ("r1", "z", "z1"),
        ("r2", "x", "x2"), ("r2", "y", "y2"), ("r2", "z", "z2")]
    assert t.drive_nodes == ("x1", "y1", "z1", "x2", "y2", "z2")
    r1, r2 = cell.robots
    assert r1.spec.kinematics == Kinematics("cartesian", 3)
    assert [(c.time_s, c.frame) for c in r1.spec.changes] == [(0.1, "A"), (2.0, "B"),
                                                              (4.5, None)]
    assert r2.spec.track_types == (("B2", frozenset({2})),)
    assert [s.types for s in cell.sensors] == [(0,), (0,), (1, 2)]
    with pytest.raises(TypeError):                       # read-only, as the whole config
        cell.encoders["belt_c"] = cell.encoders["belt_a"]  # type: ignore[index]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cell.robots = ()  # type: ignore[misc]
    # the simulated encoders take each cell encoder's scale
    assert cfg.simulation.devices["enc_b"].counts_per_mm == 40.96
    assert cfg.simulation.devices["enc_b"].profile == ((0.0, 150.0),)


def test_the_bus_cell_and_its_scenario_read_alike():
    """Same readers: the frames, robots (start, slave, types, MasterFrame changes, the type
    and dimension from the drives) and sensors of the bus cell equal the scenario's."""
    cell = load_config(BUS).tracking.cell
    sc = load_scenario(SCENARIO)
    assert cell.frames == sc.frames
    assert tuple(r.spec for r in cell.robots) == sc.robots
    assert cell.sensors == sc.sensors
    assert set(cell.encoders) == set(sc.masters)
    for name, enc in cell.encoders.items():
        assert sc.masters[name].encoder.counts_per_unit == enc.counts_per_mm


def test_the_offline_twin_runs_the_hand_off_and_the_second_robot():
    """examples/cell_bus_handoff.yaml: r1 catches its item on A, then (hand-off at 2.0 s)
    the one on B; r2 ignores the type-1 item on its frame B2 and catches the type-2 one."""
    from controller.simulate import run_scenario

    r = run_scenario(SCENARIO)
    r1, r2 = r.robots["r1"], r.robots["r2"]
    assert [(x.frame, x.status.value) for x in r1.records] == [("A", "caught"),
                                                               ("B", "caught")]
    assert [(x.item_type, x.status.value) for x in r2.records] == [(1, "ignored"),
                                                                   (2, "caught")]
    assert "B" in r1.master_frame and r1.master_frame[-1] == ""


def test_robot_kinematics_from_the_drives():
    assert robot_kinematics("cartesian", ("x", "y")) == Kinematics("cartesian", 2)
    assert robot_kinematics("cartesian", ("x", "y", "z")) == Kinematics("cartesian", 3)
    assert robot_kinematics("cartesian", ("x", "y", "z", "c")) == Kinematics("cartesian", 4)
    with pytest.raises(ParameterError):
        robot_kinematics("delta", ("x", "y", "z"))


# name: (old, new, the error's line: a fragment of the mutated text, key, message regex)
BAD = {
    "unknown master": ("masters: [belt_a]", "masters: [belt_c]", "masters: [belt_c]",
                       ".tracking.cell.frames[0].masters[0]", "unknown master 'belt_c'"),
    "drive of two robots": ("x: {node: x2,", "x: {node: x1,", "x: {node: x1, counts_per_mm: "
                            "10000, min: 600", ".tracking.cell.robots[1].kinematics.axes",
                            "drive 'x1' already belongs to robot 'r1'"),
    "encoder is a drive": ("belt_b: {node: enc_b,", "belt_b: {node: x1,", "belt_b: {node: x1,",
                           ".tracking.cell.encoders.belt_b.node", "CiA 406 encoder"),
    "encoder twice": ("belt_b: {node: enc_b,", "belt_b: {node: enc_a,", "belt_b: {node: enc_a,",
                      ".tracking.cell.encoders.belt_b.node", "already the encoder 'belt_a'"),
    "encoder with a direction": ("belt_a: {node: enc_a, counts_per_mm: 40.96}",
                                 "belt_a: {node: enc_a, counts_per_mm: 40.96, "
                                 "direction: [1, 0, 0]}", "belt_a: {node: enc_a",
                                 ".tracking.cell.encoders.belt_a.direction", "frame places"),
    "unknown frame in a change": ("{time_s: 2.0, frame: B}", "{time_s: 2.0, frame: C}",
                                  "{time_s: 2.0, frame: C}",
                                  ".tracking.cell.robots[0].master_frame[1].frame",
                                  "unknown frame 'C'"),
    "robot typo": ("start: [300.0, 200.0, 100.0]", "strat: [300.0, 200.0, 100.0]",
                   "strat: [300.0", ".tracking.cell.robots[0].strat", "unknown key"),
    "robot twice": ("- name: r2", "- name: r1", "- name: r1\n        kinematics",
                    ".tracking.cell.robots[1]", "robot name 'r1' is used twice"),
    "unknown sensor robot": ("robots: [r2]", "robots: [r3]", "robots: [r3]",
                             ".tracking.cell.sensors[2].robots[0]", "unknown robot 'r3'"),
    "bad axis name": ("z: {node: z2,", "q: {node: z2,", "x: {node: x2,",
                      ".tracking.cell.robots[1].kinematics.axes", "cartesian axes"),
    "a window beside a cell": ("  tracker:\n    planner: softmc",
                               "  window: {start: 0, end: 100}\n  tracker:\n    planner: softmc",
                               "  window: {start: 0", ".tracking.window", "key of one belt"),
    "a time past the end": ("{time_s: 4.5, frame: none}", "{time_s: -1, frame: none}",
                            "{time_s: -1, frame: none}",
                            ".tracking.cell.robots[0].master_frame[2].time_s", "out of range"),
}


def _lines(text: str, fragment: str) -> list[int]:
    """The lines where ``fragment`` (may span lines) starts."""
    out, pos = [], text.find(fragment)
    while pos >= 0:
        out.append(text.count("\n", 0, pos) + 1)
        pos = text.find(fragment, pos + 1)
    return out


@pytest.mark.parametrize("name", sorted(BAD))
def test_a_bad_cell_names_file_line_and_key(tmp_path, name):
    old, new, fragment, key, message = BAD[name]
    assert old in TEXT, old
    text = TEXT.replace(old, new, 1)
    path = tmp_path / "bus.yml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        parse_config(text, str(path), base_dir=BUS.parent)
    err = info.value
    assert err.file == str(path) and err.key == key, str(err)
    assert re.search(message, err.bare_message), str(err)
    assert err.line in _lines(text, fragment), str(err)


def test_a_demo_section_beside_a_cell_is_refused_at_its_key(tmp_path):
    text = TEXT + "\n.demo:\n  items: 2\n"
    path = tmp_path / "bus.yml"
    path.write_text(text)
    with pytest.raises(ConfigError, match="one belt and one robot") as info:
        parse_config(text, str(path), base_dir=BUS.parent)
    assert info.value.key == ".demo" and info.value.line == _lines(text, ".demo:")[0]


def test_each_cell_encoder_is_its_own_master_input_on_the_stepped_bus():
    """Gap 1 of the cell on the bus, its I/O: one MasterInput per cell encoder on one
    transport, each decoding its own node's TPDO (the simulated belts run 200 and 150 mm/s)
    into its own estimate."""
    from controller.canopen.master.masterio import MasterInput
    from controller.canopen.slave.world import SimWorld

    cfg = load_config(BUS)
    cell = cfg.tracking.cell
    period_ns = cfg.period_ns
    with SimWorld(cfg) as w:
        tr = w.transport
        inputs = {name: MasterInput(cfg, tr, encoder=enc)
                  for name, enc in cell.encoders.items()}
        booted: set[int] = set()
        for enc in cell.encoders.values():
            node_id = cfg.slaves[enc.node].node_id
            tr.subscribe(0x700 + node_id, lambda cid, data, t: booted.add(cid - 0x700))
        ids = {cfg.slaves[e.node].node_id for e in cell.encoders.values()}
        tr.run_until(tr.clock.now_ns() + 10**9, lambda: ids <= booted)
        assert ids <= booted, booted
        tr.send(0x000, bytes([0x01, 0x00]))           # NMT start all
        t = tr.clock.now_ns()
        for k in range(60):
            for m in inputs.values():
                m.cycle = k
            tr.send(0x080, b"")                       # SYNC: the encoders sample and send
            t += period_ns
            tr.run_until(t)                           # one period of stepped time
            assert all(m.fresh(k) for m in inputs.values()), k
            est = {n: m.update(k)[1] for n, m in inputs.items()}
    assert all(m.ready for m in inputs.values())
    # each its own belt: 200 and 150 mm/s, to the quantisation of 1/40.96 mm per count
    assert est["belt_a"].vel == pytest.approx(200.0, abs=1.0)
    assert est["belt_b"].vel == pytest.approx(150.0, abs=1.0)
    assert inputs["belt_a"].label != inputs["belt_b"].label


def test_each_robot_has_its_own_kinematics_over_its_own_drives():
    """Gap 2 of the cell on the bus: per robot a kinematics over its axes (both named x, y,
    z) and a counts converter for its drives; each robot's start pose in counts is where
    .simulation puts its drives (the example is consistent)."""
    from controller.tracking import MotionState

    cfg = load_config(BUS)
    for robot in cfg.tracking.cell.robots:
        joints = robot.machine().joints(MotionState.at(*robot.spec.robot.start.pos))
        counts = robot.counts().to_counts(joints)
        assert counts == tuple(cfg.simulation.devices[a.node].initial_counts
                               for a in robot.axes), robot.name
    r1, r2 = cfg.tracking.cell.robots
    assert r1.machine().joints(MotionState.at(1.0, 2.0, 3.0)) == (1.0, 2.0, 3.0)
    assert r2.counts().to_counts((1.0, 2.0, 3.0)) == (10000, 20000, 30000)
