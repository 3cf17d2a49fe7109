"""The offline simulator: examples run, identity with the core, master generation, metrics,
summary and trace."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest
from helpers import conveyor, run_tracker

from controller.simulate import format_summary, load_scenario, run_scenario, write_trace
from controller.simulate.master import build_profile, master_states, speed_change_phases
from controller.simulate.summary import phase_rows
from controller.simulate.trace import INPUT_COLUMNS, TRACE_COLUMNS
from controller.tracking import Mode, Tracker, TrackError, TrackState
from controller.tracking.metrics import analyze

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
SOFTMC_EXAMPLES = ["linear_absolute", "relative_mode", "csv_master", "encoder_estimator"]


def base(**changes) -> dict:
    """A small valid scenario as a mapping (300 mm/s conveyor, robot offset)."""
    d = {
        "engage": 0.02,
        "duration_s": 1.0,
        "tracker": {"sample_time_s": 0.002, "planner": "softmc"},
        "robot": {"position": [-50.0, 40.0, 0.0]},
        "master": {"segments": [{"duration_s": 1.0, "velocity": 300.0}]},
    }
    d.update(changes)
    return d


# -- examples ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", SOFTMC_EXAMPLES)
def test_example_runs_and_synchronises(name):
    r = run_scenario(EXAMPLES / f"{name}.yaml")
    n = r.scenario.n_samples
    assert r.setpoint_pos.shape == (n + 1, 3) and r.state.shape == (n + 1,)
    assert r.state[0] == TrackState.OFF
    for c in r.cycles:
        assert c.synced_after_s is not None and c.synced_after_s < 1.0, (name, c.index)
        assert not c.errors, (name, c.errors)
        # during the approach the setpoint keeps the sync limits (1 % for rounding)
        assert c.trans.violations[0.01]["approach"] == 0


def test_example_accelerating_optimal():
    pytest.importorskip("controller.tracking.optimal")
    r = run_scenario(EXAMPLES / "accelerating_optimal.yaml")
    c = r.cycles[0]
    assert c.synced_after_s is not None and not c.errors
    assert c.time_to_sync_s is not None
    assert r.final_state == TrackState.OFF


def test_examples_cover_the_listed_files():
    names = {p.stem for p in EXAMPLES.glob("*.yaml")}
    assert set(SOFTMC_EXAMPLES) | {"accelerating_optimal"} <= names
    assert (EXAMPLES / "csv_master.csv").is_file()
    assert (EXAMPLES / "README.md").is_file()


# -- identity with the core ------------------------------------------------------------------
def _run_core(scenario, inputs):
    """The core called directly: same params, initial state, commands and master inputs."""
    tracker = Tracker(scenario.params, scenario.robot)
    engage, disengage = set(scenario.engage_samples), set(scenario.disengage_samples)
    out = [tracker.setpoint]
    states = [int(tracker.state)]
    for k in range(1, scenario.n_samples + 1):
        if k - 1 in engage:
            tracker.engage()
        if k - 1 in disengage:
            tracker.disengage()
        o = tracker.update(inputs[k - 1])
        out.append(o.setpoint)
        states.append(int(o.state))
    return out, states


@pytest.mark.parametrize("name", SOFTMC_EXAMPLES)
def test_setpoints_bit_identical_to_the_core(name):
    r = run_scenario(EXAMPLES / f"{name}.yaml")
    assert len(r.master_inputs) == r.scenario.n_samples
    sps, states = _run_core(r.scenario, r.master_inputs)
    assert np.array_equal(r.setpoint_pos, np.array([s.pos for s in sps]))
    assert np.array_equal(r.setpoint_vel, np.array([s.vel for s in sps]))
    assert np.array_equal(r.setpoint_acc, np.array([s.acc for s in sps]))
    assert np.array_equal(r.setpoint_ang, np.array([s.ang for s in sps]))
    assert np.array_equal(r.setpoint_ang_vel, np.array([s.ang_vel for s in sps]))
    assert np.array_equal(r.state, np.array(states))


def test_identity_with_an_independent_master_and_loop():
    """The shared test helpers (their own master function and loop) give the same bits."""
    sc = load_scenario(EXAMPLES / "linear_absolute.yaml")
    r = run_scenario(sc)
    ref = run_tracker(Tracker(sc.params, sc.robot), conveyor(v=300.0), sc.duration_s,
                      engage_at=sc.engage_samples[0], disengage_at=sc.disengage_samples[0])
    assert np.array_equal(r.master_pos, ref["mpos"])
    assert np.array_equal(r.setpoint_pos, ref["pos"])
    assert np.array_equal(r.setpoint_vel, ref["vel"])
    assert np.array_equal(r.state, ref["state"])


# -- master generation ----------------------------------------------------------------------
@pytest.mark.parametrize("v0,v1,acc,jerk", [(100, 400, 800, 8000), (400, 250, 800, 8000),
                                            (0, 10, 1000, 10000), (300, -300, 500, 2000)])
def test_speed_change_is_the_exact_s_curve(v0, v1, acc, jerk):
    phases = speed_change_phases(v0, v1, acc, jerk)
    dv = abs(v1 - v0)
    expected = dv / acc + acc / jerk if dv >= acc * acc / jerk else 2 * math.sqrt(dv / jerk)
    assert sum(d for d, _ in phases) == pytest.approx(expected, rel=1e-12)
    assert all(abs(j) == jerk for _, j in phases if j)
    sc = load_scenario(base(master={"segments": [
        {"duration_s": 0.1, "velocity": v0},
        {"speed_change": {"to": v1, "acc": acc, "jerk": jerk}},
        {"duration_s": 0.1}]}, duration_s=None))
    prof = build_profile(sc.master)
    assert prof.end_s == pytest.approx(0.2 + expected, rel=1e-12)
    t = np.linspace(0.0, prof.end_s, 4001)
    states = [prof.state(x) for x in t]
    v = np.array([s.vel[0] for s in states])
    a = np.array([s.acc[0] for s in states])
    p = np.array([s.pos[0] for s in states])
    assert v[-1] == pytest.approx(v1, abs=1e-9) and v[0] == v0
    assert np.max(np.abs(a)) <= acc * (1 + 1e-12)
    assert np.max(np.abs(a)) == pytest.approx(min(acc, math.sqrt(dv * jerk)), rel=1e-2)
    # position/velocity consistent (trapezoid integration of v) and continuous
    assert np.allclose(np.cumsum((v[1:] + v[:-1]) / 2 * np.diff(t)), p[1:] - p[0], atol=1e-4)
    assert np.max(np.abs(np.diff(a))) <= jerk * (t[1] - t[0]) * (1 + 1e-9)


def test_segment_master_directions_rotation_and_continuation():
    sc = load_scenario(base(master={
        "position": [10.0, 20.0, 30.0], "c": 5.0, "direction": [0, 3, 4],
        "segments": [{"duration_s": 0.5, "velocity": 100.0, "c_rate": 10.0},
                     {"duration_s": 0.25, "acceleration": 200.0, "direction": [1, 0, 0]}]},
        duration_s=1.0))
    prof = build_profile(sc.master)
    s = prof.state(0.5)
    assert s.pos == pytest.approx((10.0, 20.0 + 30.0, 30.0 + 40.0))
    assert s.ang == pytest.approx(10.0) and s.ang_vel == 10.0
    s = prof.state(0.75)
    assert s.pos[0] == pytest.approx(10.0 + 100 * 0.25 + 0.5 * 200 * 0.25 ** 2)
    assert s.vel == pytest.approx((150.0, 0.0, 0.0))
    s = prof.state(0.9)  # after the last segment: constant final speed
    assert s.vel == pytest.approx((150.0, 0.0, 0.0)) and s.acc == (0.0, 0.0, 0.0)
    s = prof.state(-0.1)  # before t = 0: the initial speed along the first direction
    assert s.pos == pytest.approx((10.0, 20.0 - 6.0, 30.0 - 8.0))


def test_encoder_estimator_quantises_delays_and_predicts():
    sc = load_scenario(base(estimator={"quantisation_mm": 0.037, "delay_samples": 2,
                                       "window": 8}))
    true, fed = master_states(sc)
    assert fed is not true and len(fed) == len(true) == sc.n_samples + 1
    err = np.array([f.pos[0] - t.pos[0] for f, t in zip(fed, true)])
    assert np.max(np.abs(err)) < 2 * 0.037     # about the quantisation step
    assert np.max(np.abs(err)) > 1e-3          # but not exact
    vel = np.array([f.vel[0] for f in fed])
    assert np.abs(vel - 300.0).max() < 30.0
    # without quantisation a constant-speed master is predicted exactly (rounding level)
    sc = load_scenario(base(estimator={"delay_samples": 2, "window": 8}))
    true, fed = master_states(sc)
    assert max(abs(f.pos[0] - t.pos[0]) for f, t in zip(fed, true)) < 1e-9


def test_csv_master_columns_and_estimation(tmp_path):
    T = 0.002
    rows = ["time_s,x,y,z,c,vx,vy,vz,vc"]
    for k in range(0, 251):
        t = k * T
        rows.append(f"{t!r},{100 * t!r},5,0,{2 * t!r},100,0,0,2")
    (tmp_path / "m.csv").write_text("\n".join(rows) + "\n")
    sc = load_scenario(base(master={"csv": "m.csv"}, duration_s=None), base_dir=tmp_path)
    assert sc.duration_s == pytest.approx(0.5)
    true, _ = master_states(sc)
    assert true[10].pos == pytest.approx((100 * 10 * T, 5.0, 0.0))
    assert true[10].vel == (100.0, 0.0, 0.0) and true[10].ang_vel == 2.0
    # without velocity columns: estimated (exact for a linear master after 2 samples)
    (tmp_path / "p.csv").write_text(
        "\n".join(["t,x_mm,y_mm,z_mm"] + [f"{k * T!r},{100 * k * T!r},0,0"
                                          for k in range(251)]) + "\n")
    sc = load_scenario(base(master={"csv": "p.csv", "window": 5}, duration_s=None),
                       base_dir=tmp_path)
    true, _ = master_states(sc)
    assert true[20].vel[0] == pytest.approx(100.0, rel=1e-9)
    r = run_scenario(sc)
    assert r.cycles[0].synced_after_s is not None


# -- metrics and summary --------------------------------------------------------------------
@pytest.mark.parametrize("name", ["linear_absolute", "relative_mode", "encoder_estimator"])
def test_cycle_metrics_are_analyze_of_the_trace(name):
    r = run_scenario(EXAMPLES / f"{name}.yaml")
    T = r.sample_time_s
    for c in r.cycles:
        rows = slice(c.first_row, c.last_row + 1)
        ref = r.reference_pos[rows].copy()
        ref[0] = r.master_pos[c.first_row] + np.array(c.offset_pos)
        m = analyze(r.setpoint_pos[rows], ref, r.state[rows], T, r.limits.sync_trans,
                    t0_s=c.first_row * T)
        assert m.time_to_sync_s == c.trans.time_to_sync_s
        for ph in ("approach", "switch", "after"):
            assert m.peak[ph] == c.trans.peak[ph]
            assert m.ratio[ph] == c.trans.ratio[ph]
        d = analyze(r.setpoint_pos[rows], ref, r.state[rows], T, r.limits.desync_trans,
                    t0_s=c.first_row * T)
        assert d.ratio["desync"] == c.trans.ratio["desync"]
        assert m.error_after_sync_mm == c.trans.error_after_sync_mm
        assert m.oscillation_flips == c.trans.oscillation_flips
        if c.mode == Mode.RELATIVE:
            assert c.offset_pos != (0.0, 0.0, 0.0)
            # after the sync the setpoint is the master plus the offset, exactly as the core
            after = np.nonzero(r.state[rows] == TrackState.SYNCED)[0] + c.first_row
            after = after[1:]  # the switch sample is the "middle" of robot and master
            assert np.allclose(r.setpoint_pos[after], r.reference_pos[after], atol=1e-9)


def test_summary_numbers_match_the_metrics():
    r = run_scenario(EXAMPLES / "linear_absolute.yaml")
    text = format_summary(r)
    c = r.cycles[0]
    assert f"{c.synced_after_s:.3f} s after engage" in text
    assert f"{c.time_to_sync_s:.3f} s after engage" in text
    assert c.time_to_sync_s == pytest.approx(c.trans.time_to_sync_s - 0.1)
    lines = text.splitlines()
    for row in phase_rows(c):
        line = next(ln for ln in lines if ln.split()[:2] == [row.channel, row.phase])
        cells = line.split()
        assert float(cells[2]) == pytest.approx(row.peak["vel"], rel=1e-3)
        assert cells[3] == f"{row.ratio['vel']:.3f}"
        assert float(cells[4]) == pytest.approx(row.peak["acc"], rel=1e-3)
        assert cells[7] == f"{row.ratio['jerk']:.3f}"
        assert int(cells[8]) == c.trans.violations[1e-6][row.phase]
        assert int(cells[9]) == c.trans.violations[0.01][row.phase]
        assert row.peak == c.trans.peak[row.phase]
    assert {row.phase for row in phase_rows(c)} == {"approach", "switch", "after", "desync"}
    assert "Final      state OFF" in text and "error NONE" in text


def test_errors_are_reported_per_cycle():
    # the master is faster than the moving frame's VelocityMax: MASTER_VELOCITY on engage
    r = run_scenario(base(tracker={"sample_time_s": 0.002, "planner": "softmc",
                                   "master_max_trans": {"vel": 200}}))
    c = r.cycles[0]
    assert c.errors and c.errors[0][1] == TrackError.MASTER_VELOCITY
    assert c.errors[0][0] == pytest.approx(0.022)
    assert r.final_error == TrackError.MASTER_VELOCITY
    assert "MASTER_VELOCITY at 0.022 s" in format_summary(r)


# -- trace ----------------------------------------------------------------------------------
def test_trace_csv_round_trips(tmp_path):
    r = run_scenario(EXAMPLES / "encoder_estimator.yaml")
    path = write_trace(r, tmp_path / "t.csv")
    with path.open() as fh:
        rows = list(csv.reader(fh))
    assert tuple(rows[0]) == TRACE_COLUMNS + INPUT_COLUMNS
    body = rows[1:]
    assert len(body) == r.scenario.n_samples + 1
    col = {name: i for i, name in enumerate(rows[0])}
    x = np.array([float(b[col["setpoint_x_mm"]]) for b in body])
    assert np.array_equal(x, r.setpoint_pos[:, 0])
    assert np.array_equal(np.array([float(b[col["master_vx_mm_s"]]) for b in body]),
                          r.master_vel[:, 0])
    assert np.array_equal(np.array([float(b[col["input_x_mm"]]) for b in body]),
                          r.input_pos[:, 0])
    assert body[0][col["state"]] == "OFF" and body[0][col["error"]] == "NONE"
    assert float(body[0][col["time_s"]]) == 0.0
    assert float(body[-1][col["time_s"]]) == pytest.approx(r.scenario.duration_s)
    assert {b[col["state"]] for b in body} == {"OFF", "SYNCING", "SYNCED", "DESYNCING"}
    assert {b[col["imfs"]] for b in body} == {"0", "1", "-1"}


def test_trace_without_estimator_has_the_base_columns(tmp_path):
    r = run_scenario(base())
    path = write_trace(r, tmp_path / "t.csv")
    assert path.read_text().splitlines()[0].split(",") == list(TRACE_COLUMNS)


def test_mapping_api_and_row0():
    r = run_scenario(base(robot={"position": [1.0, 2.0, 3.0], "c": 4.0,
                                 "velocity": [5.0, 0.0, 0.0]}))
    assert r.setpoint_pos[0].tolist() == [1.0, 2.0, 3.0]
    assert r.setpoint_ang[0] == 4.0 and r.setpoint_vel[0, 0] == 5.0
    # before the engage the robot continues its own motion (OFF extrapolates)
    assert r.setpoint_pos[1, 0] == pytest.approx(1.0 + 5.0 * 0.002)
    assert r.scenario.source is None
