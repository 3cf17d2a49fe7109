"""The tracker state machine: states, IMFS, modes, errors, de-sync, invariants."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from controller.errors import ParameterError
from controller.tracking import (Imfs, Limits, Mode, MotionState, SoftMcOptions, TrackError,
                                 Tracker, TrackerParams, TrackState)
from controller.tracking.metrics import analyze

from helpers import conveyor, run_tracker

T = 0.002


def params(**kw):
    kw.setdefault("sample_time_s", T)
    kw.setdefault("planner", "softmc")
    return TrackerParams(**kw)


def test_full_cycle_off_syncing_synced_desyncing_off():
    tr = Tracker(params(), MotionState.at(50.0, 20.0, 0.0))
    r = run_tracker(tr, conveyor((1, 0, 0), 300.0), 2.0, disengage_at=600)
    states = [TrackState(s) for s in r["state"]]
    order = [s for i, s in enumerate(states) if i == 0 or s != states[i - 1]]
    assert order == [TrackState.OFF, TrackState.SYNCING, TrackState.SYNCED,
                     TrackState.DESYNCING, TrackState.OFF]
    imfs = {TrackState(o.state): o.imfs for o in r["outs"]}
    assert imfs == {TrackState.SYNCING: Imfs.NOT_SYNCHRONIZED, TrackState.SYNCED: Imfs.SYNCHRONIZED,
                    TrackState.DESYNCING: Imfs.DESYNCING, TrackState.OFF: Imfs.NOT_SYNCHRONIZED}
    assert sum(o.synchronized_now for o in r["outs"]) == 1
    # SYNCED copies the master exactly (absolute mode), after the switch sample ("the middle")
    synced = r["state"] == TrackState.SYNCED
    synced[1:][[o.synchronized_now for o in r["outs"]]] = False
    assert np.array_equal(r["pos"][synced], r["mpos"][synced])
    # after the de-sync the robot is at rest, ahead of where it disengaged, on the line y = 0
    assert tr.setpoint.vel == (0.0, 0.0, 0.0) and tr.setpoint.acc == (0.0, 0.0, 0.0)
    assert tr.setpoint.pos[1] == 0.0
    # de-sync jerk by finite differences within the de-sync jerk limit (+1 %)
    m = analyze(r["pos"], r["mpos"], r["state"], T, tr.limits.desync_trans)
    assert m.ratio["desync"]["jerk"] <= 1.01 and m.ratio["desync"]["acc"] <= 1.0


def test_relative_mode_keeps_the_engage_offset():
    start = MotionState.at(40.0, -25.0, 10.0, c=15.0)
    tr = Tracker(params(mode=Mode.RELATIVE), start)
    r = run_tracker(tr, conveyor((1, 1, 0), 200.0), 1.5)
    assert tr.state == TrackState.SYNCED
    # offset = robot - master at the engage time (t = 0: master at the origin, c = 0)
    offset = r["pos"][-1] - r["mpos"][-1]
    assert offset == pytest.approx([40.0, -25.0, 10.0], abs=1e-9)
    assert r["ang"][-1] - r["mang"][-1] == pytest.approx(15.0, abs=1e-9)


def test_engage_mode_argument_overrides_params():
    tr = Tracker(params(), MotionState.at(10.0, 0.0, 0.0))
    tr.engage(Mode.RELATIVE)
    m = conveyor((1, 0, 0), 100.0)
    for k in range(1, 500):
        tr.update(m(k * T))
    assert tr.mode == Mode.RELATIVE and tr.state == TrackState.SYNCED
    assert tr.setpoint.pos[0] - m(499 * T).pos[0] == pytest.approx(10.0, abs=1e-9)


def test_rotation_channel_synchronises_with_its_own_limits():
    tr = Tracker(params(sync_rot=Limits(90.0, 900.0, 18000.0)), MotionState.at(c=30.0))
    r = run_tracker(tr, conveyor((1, 0, 0), 100.0, ang_v=20.0), 2.0)
    assert tr.state == TrackState.SYNCED
    assert r["ang"][-1] == r["mang"][-1]
    w = np.diff(r["ang"]) / T
    assert np.abs(w[r["state"][1:] == TrackState.SYNCING]).max() <= 90.0 * 1.01


@pytest.mark.parametrize("field,value,code", [
    ("vel", 1200.0, TrackError.MASTER_VELOCITY),
    ("acc", 1500.0, TrackError.MASTER_ACCELERATION),
])
def test_master_over_frame_limits_is_an_error_that_starts_the_desync(field, value, code):
    tr = Tracker(params(), MotionState.at())
    master = conveyor((1, 0, 0), value if field == "vel" else 100.0,
                      a=value if field == "acc" else 0.0)
    out = None
    tr.engage()
    for k in range(1, 200):
        out = tr.update(master(k * T))
        if out.error:
            break
    assert out.error == code
    assert out.state in (TrackState.DESYNCING, TrackState.OFF)


def test_master_check_also_in_synced():
    tr = Tracker(params(), MotionState.at())
    slow = conveyor((1, 0, 0), 300.0)
    r = run_tracker(tr, slow, 1.0)
    assert tr.state == TrackState.SYNCED
    fast = MotionState((300.0, 0, 0), (1001.0, 0, 0), (0, 0, 0))
    out = tr.update(fast)
    assert out.error == TrackError.MASTER_VELOCITY and out.state == TrackState.DESYNCING
    # the de-sync starts from the last synced setpoint: continuous position
    assert out.setpoint.pos[0] == pytest.approx(r["pos"][-1][0] + 300.0 * T, abs=0.01)


def test_approach_timeout():
    # a robot 2 m away with low limits cannot synchronise within 0.5 s
    p = params(sync_trans=Limits(100.0, 1000.0, 10000.0), approach_timeout_s=0.5)
    tr = Tracker(p, MotionState.at(-2000.0))
    r = run_tracker(tr, conveyor((1, 0, 0), 50.0), 0.8)
    errors = [o.error for o in r["outs"]]
    first = errors.index(TrackError.APPROACH_TIMEOUT)
    assert first + 1 == round(0.5 / T)
    assert r["outs"][first].state == TrackState.DESYNCING


def test_over_oscillation_is_detected():
    # a low DampingFactor with the page's K makes the softMC approach oscillate (the overview
    # page warns of it)
    # page's K with a slow (period ~0.6 s) limit cycle of +-150 mm
    p = params(sample_time_s=0.004, damping_factor=0.3,
               softmc=SoftMcOptions(time_to_reach_k=(4.0, 2.0)))
    tr = Tracker(p, MotionState.at(100.0, 0, 0))
    r = run_tracker(tr, conveyor((1, 0, 0), 300.0), 3.0)
    errors = [o.error for o in r["outs"]]
    assert TrackError.OVER_OSCILLATION in errors
    # caught after max_flops + 1 = 7 large half-swings of ~0.3 s, well before the timeout
    assert errors.index(TrackError.OVER_OSCILLATION) * 0.004 < 2.5


def test_converging_approach_is_not_an_oscillation():
    p = params(sample_time_s=0.004, max_flops=1, max_flops_time_s=3.0)
    tr = Tracker(p, MotionState.at(100.0, 0, 0))
    run_tracker(tr, conveyor((1, 0, 0), 300.0), 2.0)
    assert tr.state == TrackState.SYNCED and tr.error == TrackError.NONE


def test_disengage_while_syncing_stops_the_robot():
    tr = Tracker(params(), MotionState.at(100.0, 0, 0))
    r = run_tracker(tr, conveyor((1, 0, 0), 300.0), 1.0, disengage_at=40)
    assert tr.state == TrackState.OFF
    assert tr.setpoint.vel == (0.0, 0.0, 0.0)
    v = np.diff(r["pos"][:, 0]) / T
    assert np.abs(np.diff(v) / T).max() <= 2e4 * 1.01


def test_engage_while_desyncing_restarts_the_approach():
    tr = Tracker(params(), MotionState.at(0, 0, 0))
    m = conveyor((1, 0, 0), 300.0)
    tr.engage()
    k = 0
    while tr.state != TrackState.SYNCED:
        k += 1
        tr.update(m(k * T))
    tr.disengage()
    k += 1
    tr.update(m(k * T))
    assert tr.state == TrackState.DESYNCING
    tr.engage()
    for _ in range(400):
        k += 1
        tr.update(m(k * T))
    assert tr.state == TrackState.SYNCED


def test_off_continues_the_robot_state():
    tr = Tracker(params(), MotionState((0, 0, 0), (100.0, 0, 0), (0, 0, 0)))
    out = tr.update(MotionState())
    assert out.state == TrackState.OFF
    assert out.setpoint.pos[0] == pytest.approx(100.0 * T)


def test_snapshot_replays_bit_identically():
    tr = Tracker(params(), MotionState.at(80.0, -30.0, 5.0))
    m = conveyor((1, 2, 0), 250.0, a=200.0)
    tr.engage()
    for k in range(1, 40):
        tr.update(m(k * T))
    twin = tr.snapshot()
    a = [tr.update(m(k * T)).setpoint for k in range(40, 400)]
    b = [twin.update(m(k * T)).setpoint for k in range(40, 400)]
    assert a == b


def test_effective_limits_apply_robot_max_and_rates():
    from controller.tracking import Rates
    p = TrackerParams(robot_max_trans=Limits(1500.0, 30000.0, 300000.0),
                      rates=Rates(vel=50.0, acc=50.0, dec=25.0, jerk=100.0))
    e = p.effective()
    assert e.sync_trans == Limits(750.0, 15000.0, 300000.0)
    assert e.desync_trans == Limits(750.0, 7500.0, 300000.0)
    assert e.sync_rot == p.sync_rot  # no robot rotation maximum given


@pytest.mark.parametrize("kw,needle", [
    ({"sample_time_s": 0.0}, "sample_time_s"),
    ({"mode": 4}, "mode (=4)"),
    ({"filter_factor": -1.0}, "filter_factor"),
    ({"max_flops": 0}, "max_flops"),
    ({"planner": "nope"}, "planner (='nope')"),
])
def test_bad_parameters_name_the_value(kw, needle):
    with pytest.raises(ParameterError, match=re.escape(needle)):
        Tracker(TrackerParams(**kw))


def test_limits_validation():
    with pytest.raises(ParameterError, match=r"Limits\.acc \(=-1\.0 mm/s\^2"):
        Limits(1.0, -1.0, 1.0)


import re  # noqa: E402  (used in the parametrised test above)


@settings(max_examples=40)
@given(v=st.floats(50.0, 800.0), ox=st.floats(-300.0, 300.0), oy=st.floats(-300.0, 300.0),
       oz=st.floats(-300.0, 300.0), ang=st.floats(0.0, 2 * math.pi),
       acc=st.sampled_from([0.0, 300.0, -200.0]), sample=st.sampled_from([0.001, 0.002, 0.004]),
       moving=st.booleans())
def test_softmc_invariants_over_random_scenarios(v, ox, oy, oz, ang, acc, sample, moving):
    """The fixed softMC reading: synchronises within 2 s, keeps V/A/J (+1 %) during the
    approach, and follows a constant-acceleration master to rounding error after sync."""
    p = params(sample_time_s=sample)
    v0 = (150.0 * math.cos(ang), 150.0 * math.sin(ang), 0.0) if moving else (0.0, 0.0, 0.0)
    tr = Tracker(p, MotionState((ox, oy, oz), v0, (0.0, 0.0, 0.0)))
    r = run_tracker(tr, conveyor((math.cos(ang), math.sin(ang), 0.0), v, a=acc), 2.2)
    m = analyze(r["pos"], r["mpos"], r["state"], sample, p.sync_trans)
    assert m.synced and m.time_to_sync_s <= 2.0
    for q in ("vel", "acc", "jerk"):
        assert m.ratio["approach"][q] <= 1.01, (q, m.ratio["approach"])
    assert m.error_after_sync_mm <= 1e-6


def test_disengage_with_a_reason_reports_it():
    tr = Tracker(params(), MotionState.at(0, 0, 0))
    m = conveyor((1, 0, 0), 300.0)
    tr.engage()
    for k in range(1, 200):
        tr.update(m(k * T))
    tr.disengage(TrackError.MASTER_LOST)
    out = tr.update(m(200 * T))
    assert out.state == TrackState.DESYNCING and out.error == TrackError.MASTER_LOST


def test_functional_change_2_sync_limits_start_at_the_robot_maxima():
    """Conveyor page, Functional Changes item 2: the sync/de-sync parameters' defaults are set
    by ConfigGroup "to the initial values of corresponding robot max properties (VMTran,
    VMRot, ...)"; given values stay; without robot maxima the built-in defaults apply."""
    from controller.tracking.types import DEFAULT_ROT, DEFAULT_TRANS

    fast = Limits(5000.0, 50000.0, 1.0e6)
    rot = Limits(720.0, 7200.0, 1.0e5)
    p = TrackerParams(robot_max_trans=fast, robot_max_rot=rot)
    assert (p.sync_trans, p.desync_trans, p.sync_rot, p.desync_rot) == (fast, fast, rot, rot)
    assert p.effective().sync_trans == fast  # rates 100 %: a 5000 mm/s robot syncs at 5000
    given = Limits(1000.0, 10000.0, 2.0e5)
    q = TrackerParams(robot_max_trans=fast, sync_trans=given)
    assert q.sync_trans == given and q.desync_trans == fast and q.sync_rot == DEFAULT_ROT
    r = TrackerParams()
    assert (r.sync_trans, r.desync_rot) == (DEFAULT_TRANS, DEFAULT_ROT)


def test_functional_change_2_partial_limits_in_files_start_at_the_robot_maxima(tmp_path):
    """The same rule in a scenario file and in bus.yml's .tracking.tracker: a partly given
    sync_trans keeps the robot's maxima for the fields it leaves out."""
    from controller.canopen.config import load_config
    from controller.canopen.testing import bus_yml_text
    from controller.simulate.scenario import load_scenario

    sc = load_scenario({
        "engage": 0.02, "duration_s": 0.1,
        "tracker": {"sample_time_s": 0.002, "planner": "softmc",
                    "robot_max_trans": {"vel": 5000, "acc": 50000, "jerk": 1.0e6},
                    "sync_trans": {"vel": 1000}},
        "robot": {"position": [0.0, 0.0, 0.0]},
        "master": {"segments": [{"duration_s": 0.1, "velocity": 300.0}]}})
    assert sc.params.sync_trans == Limits(1000.0, 50000.0, 1.0e6)
    assert sc.params.desync_trans == Limits(5000.0, 50000.0, 1.0e6)
    text = bus_yml_text().replace(
        "    planner: softmc\n",
        "    planner: softmc\n"
        "    robot_max_trans: {vel: 5000, acc: 50000, jerk: 1.0e6}\n"
        "    sync_trans: {vel: 1000}\n")
    path = tmp_path / "bus.yml"
    path.write_text(text)
    tp = load_config(path).tracking.tracker
    assert tp.sync_trans == Limits(1000.0, 50000.0, 1.0e6)
    assert tp.desync_trans == Limits(5000.0, 50000.0, 1.0e6)
    assert tp.sample_time_s == 0.002


# -- the SYNCED follower's copy test: the written-out 3-D and 1-D forms vs the reference loop --
def _follow_case(rng, jerk: bool):
    """A setpoint history on a master moving at constant acceleration (+ jerk), disturbed
    by a fraction of what the limits allow per sample: the copy test passes or fails."""
    from controller.tracking.follow import SyncFollower

    T = 0.001
    fo = SyncFollower(Limits(800.0, 8000.0, 80000.0), T)
    scale = rng.choice([0.0, 1e-9, 1e-7, 1e-6, 1e-5, 1e-3])
    v0 = rng.uniform(-400.0, 400.0, 3)
    a0 = rng.uniform(-4000.0, 4000.0, 3)
    j0 = rng.uniform(-40000.0, 40000.0, 3) if jerk else np.zeros(3)
    ts = np.array([-3 * T, -2 * T, -T, 0.0])
    pos = [tuple(float(x) for x in 100.0 + v0 * t + a0 * t * t / 2 + j0 * t ** 3 / 6
                 + rng.normal(0.0, 1.0, 3) * scale) for t in ts]
    vel = tuple(float(x) for x in v0 - a0 * T + j0 * T * T / 2
                + rng.normal(0.0, 1.0, 3) * scale * 1e3)
    acc = tuple(float(x) for x in a0 - j0 * T + rng.normal(0.0, 1.0, 3) * scale * 1e6)
    mj = tuple(float(x) for x in j0)
    if not jerk and rng.random() < 0.5:
        mj = (0.0, -0.0, 0.0)
    mp, mv, ma = pos[3], tuple(float(x) for x in v0), tuple(float(x) for x in a0)
    return fo, (pos[2], vel, acc, mp, mv, ma, pos[1], pos[0], mj)


@pytest.mark.parametrize("jerk", [False, True])
def test_follower_copy_test_written_out_forms_agree_with_the_loop(jerk):
    """``SyncFollower._copyable3`` / ``copyable1`` (written out, the jerk terms dropped for a
    master without jerk) give the reference loop's answer (``_copyable_n``) on every case:
    both answers occur."""
    rng = np.random.default_rng(7 + jerk)
    answers = []
    for _ in range(3000):
        fo, (p, v, a, mp, mv, ma, p2, p3, mj) = _follow_case(rng, jerk)
        ref = fo._copyable_n(p, v, a, mp, mv, ma, p2, p3, mj)
        assert fo._copyable3(p, v, a, mp, mv, ma, p2, p3, mj) == ref
        assert fo._copyable3(p, v, a, mp, mv, ma, p2, p3, None) == fo._copyable_n(
            p, v, a, mp, mv, ma, p2, p3, None)
        for i in range(3):
            one = fo.copyable1(p[i], v[i], a[i], mp[i], mv[i], ma[i], p2[i], p3[i], mj[i])
            assert one == fo._copyable_n((p[i],), (v[i],), (a[i],), (mp[i],), (mv[i],),
                                         (ma[i],), (p2[i],), (p3[i],), (mj[i],))
        answers.append(ref)
    assert 0.2 < sum(answers) / len(answers) < 0.95, sum(answers)
