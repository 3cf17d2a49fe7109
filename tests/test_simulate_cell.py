"""Cell scenarios (issue 16, point 5): several frames and robots from one file, timed
MasterFrame changes - a hand-off between two belts, two robots sharing a belt each with its
own frame object, an XY (2-DOF) frame - with summary, trace and plot per robot and frame."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from controller.errors import ConfigError
from controller.simulate import format_summary, plot_result, run_scenario, write_trace
from controller.simulate.cell import CellResult
from controller.tracking import Imfs

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def kinds(tr):
    return [e.kind for e in tr.events]


@pytest.fixture(scope="module")
def handoff():
    return run_scenario(EXAMPLES / "cell_handoff.yaml")


def velocity(tr, k, T):
    return (tr.setpoint_pos[k + 1] - tr.setpoint_pos[k]) / T


def test_handoff_between_two_belts_from_a_file(handoff):
    r = handoff
    assert isinstance(r, CellResult)
    T = r.sample_time_s
    tr = r.robots["robot"]
    assert "handoff" in kinds(tr)
    k_hand = next(e.sample for e in tr.events if e.kind == "handoff")
    assert k_hand == round(2.0 / T)
    # both contributions at once: IMFS -2 after the hand-off, then synchronised to B
    assert int(Imfs.HANDOFF) in tr.imfs[k_hand:k_hand + 100].tolist()
    assert [rec.status.value for rec in tr.records] == ["caught", "caught"]
    assert tr.records[1].frame == "B"
    # following A before (+x at 200 mm/s), following B after (+y at 150 mm/s)
    assert velocity(tr, round(1.5 / T), T) == pytest.approx([200.0, 0.0, 0.0], abs=1e-6)
    assert velocity(tr, round(4.0 / T), T) == pytest.approx([0.0, 150.0, 0.0], abs=1e-6)
    assert tr.master_frame[round(1.0 / T)] == "A" and tr.master_frame[round(3.0 / T)] == "B"
    assert tr.slave[-1] == 0 and tr.master_frame[-1] == ""


def test_summary_trace_and_plot_show_every_robot_and_frame(handoff, tmp_path):
    text = format_summary(handoff)
    assert "Frame      'A' linear" in text and "Frame      'B' linear" in text
    assert "Robot      'robot'" in text and "handoff  B  from 'A'" in text
    out = write_trace(handoff, tmp_path / "t.csv")
    rows = list(csv.reader(out.read_text().splitlines()))
    assert rows[0][:3] == ["time_s", "A_master1", "B_master1"]
    assert "robot_master_frame" in rows[0]
    assert len(rows) == handoff.scenario.n_samples + 2
    png = plot_result(handoff, tmp_path / "t.png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_two_robots_share_a_belt_each_with_its_own_frame_and_item_types():
    r = run_scenario(EXAMPLES / "cell_two_robots.yaml")
    up, down = r.robots["up"], r.robots["down"]
    assert r.frames["belt_up"] is not r.frames["belt_down"]
    # the same belt: the same master values in both frame objects
    assert np.array_equal(r.master_values["belt_up"], r.master_values["belt_down"])
    for tr, mine in ((up, 1), (down, 2)):
        assert "item_missed" not in kinds(tr)
        for rec in tr.records:
            if rec.item_type != mine:
                assert rec.status.value in ("ignored", "pending")
                assert rec.engaged_sample is None
        assert any(rec.item_type == mine and rec.caught for rec in tr.records)
        assert tr.picks


def test_xy_2dof_frame():
    r = run_scenario(EXAMPLES / "cell_xy_frame.yaml")
    T = r.sample_time_s
    tr = r.robots["scara"]
    assert r.frames["xy"].nof == 2 and r.master_values["xy"].shape[1] == 2
    assert len(tr.picks) == 2
    for t_pick in tr.picks.values():   # gripping: synchronised, the robot's own motion done
        v = velocity(tr, round(t_pick / T) - 3, T)
        assert v == pytest.approx([120.0, 80.0, 0.0], abs=1e-6)


BASE = """
duration_s: 1.0
tracker: {sample_time_s: 0.002, planner: softmc}
cell:
  masters: {m: {speed: 100}}
  frames:
    - {name: a, masters: [m], window: {upstream: 0, downstream: 500}}
  robots:
    - name: r
      start: [0, 0, 0]
      master_frame: [{time_s: 0.1, frame: a}]
  sensors:
    - {frame: a, trigger_times: [0.0]}
"""


@pytest.mark.parametrize("change, key, match", [
    (("frame: a}]", "frame: b}]"), "cell.robots[0].master_frame[0].frame", "unknown frame 'b'"),
    (("masters: [m]", "masters: [n]"), "cell.frames[0].masters[0]", "unknown master 'n'"),
    (("frame: a, trigger", "frame: a, types: [1, 2], trigger"), "cell.sensors[0].types",
     "one value per trigger time"),
    (("masters: [m], window: {upstream: 0, downstream: 500}",
      "masters: [m, m], directions: [[1, 0, 0]], window: {upstream: [0, 0], "
      "downstream: [1, 1]}"), "cell.frames[0].directions", "must give 2 directions"),
])
def test_cell_errors_name_file_line_and_key(tmp_path, change, key, match):
    p = tmp_path / "c.yaml"
    p.write_text(BASE.replace(*change))
    with pytest.raises(ConfigError, match=match) as exc:
        run_scenario(p)
    assert exc.value.key == key and exc.value.file == str(p) and exc.value.line


def test_a_frame_whose_source_is_another_robots_tcp_from_a_file():
    """examples/cell_group_master.yaml: the worker (slave 3) ends on the point of the part
    the carrier holds - T : TCP_carrier : P, P the offset taken at TRIGGER - and stays on it
    while the carrier moves on the table."""
    from controller.conveyor import Location

    r = run_scenario(EXAMPLES / "cell_group_master.yaml")
    T = r.sample_time_s
    carrier, worker = r.robots["carrier"], r.robots["worker"]
    transform = Location.from_axis_angle((-2000.0, 500.0, 0.0), (0, 0, 1), 90.0)
    P = Location.from_axis_angle((80.0, 0.0, 10.0), (0, 0, 1), 30.0)
    k_sync = round(worker.records[0].synced_s / T)
    assert worker.records[0].frame == "on_carrier" and worker.records[0].caught
    for k in (k_sync + 10, k_sync + 300, len(r.time_s) - 1):
        tcp = Location(tuple(carrier.setpoint_pos[k]), tuple(carrier.setpoint_ori[k]))
        want = transform.compound(tcp).compound(P)
        got = Location(tuple(worker.setpoint_pos[k]), tuple(worker.setpoint_ori[k]))
        assert got.distance_to(want) < 1e-6 and got.angle_to(want) < 1e-6
    moved = np.linalg.norm(worker.setpoint_pos[-1] - worker.setpoint_pos[k_sync + 10])
    assert moved > 50.0
    assert r.master_values["on_carrier"].shape[1] == 4


def test_group_frame_errors(tmp_path):
    text = (EXAMPLES / "cell_group_master.yaml").read_text()
    p = tmp_path / "g.yaml"
    p.write_text(text.replace("robot: carrier\n", "robot: carier\n"))
    with pytest.raises(ConfigError, match="unknown robot 'carier'") as exc:
        run_scenario(p)
    assert exc.value.key == "cell.frames[1].group.robot" and exc.value.line
    p.write_text(text.replace("- {frame: table, robots: [carrier], trigger_times: [0.0]}",
                              "- {frame: table, robots: [carrier], trigger_times: [0.0], "
                              "offset: {position: [0, 0, 0]}}"))
    with pytest.raises(ConfigError, match="offset.*is for group frames|is for group frames"):
        run_scenario(p)
