"""The default approach planner ``optimal`` (controller/tracking/optimal.py).

Behaviour through the public Tracker (planner="optimal"), measured like the benchmark: the
setpoint stream including row 0 (the sample before the engage) goes through
``controller.tracking.metrics.analyze``.  Tolerance for limit checks: 1e-6 relative (the
planner uses its limits at 1 - 1e-9).  Random scenarios are hypothesis-generated with the
derandomised "ci" profile (tests/conftest.py), so every run checks the same cases.
"""

from __future__ import annotations

import copy
import math
import pickle
import statistics

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from controller.tracking import (
    Limits,
    Mode,
    MotionState,
    Tracker,
    TrackerParams,
    TrackError,
    TrackState,
    planner_factory,
)
from controller.tracking.metrics import analyze
from controller.tracking.optimal import OptimalPlanner, RuckigReference, create
from controller.tracking.planner import PLANNERS

LIMITS = {"A": Limits(2000.0, 2.0e4, 4.0e5), "B": Limits(1000.0, 5000.0, 5.0e4)}
ROT = Limits(360.0, 3600.0, 72000.0)  # TrackerParams' default sync_rot
TOL = 1e-6
PHASES = ("approach", "switch", "after")


# --------------------------------------------------------------------------- helpers
def master_fn(vel, acc=(0.0, 0.0, 0.0), ang_vel=0.0, pos0=(0.0, 0.0, 0.0)):
    """A constant-acceleration master: t [s] -> MotionState (mm, deg)."""
    def at(t: float) -> MotionState:
        h = 0.5 * t * t
        return MotionState(tuple(p + v * t + a * h for p, v, a in zip(pos0, vel, acc)),
                           tuple(v + a * t for v, a in zip(vel, acc)), tuple(acc),
                           ang_vel * t, ang_vel, 0.0)
    return at


def params(T=0.001, lim="A", planner="optimal", **kw) -> TrackerParams:
    return TrackerParams(sample_time_s=T, planner=planner, sync_trans=LIMITS[lim],
                         desync_trans=LIMITS[lim], **kw)


def run(p: TrackerParams, initial: MotionState, master, seconds: float) -> dict:
    """Engage at once and run; arrays include row 0 (the state before the engage)."""
    tr = Tracker(p, initial)
    T = p.sample_time_s
    n = round(seconds / T)
    sp, ms, st_ = [initial], [master(0.0)], [int(TrackState.OFF)]
    tr.engage()
    for k in range(1, n + 1):
        m = master(k * T)
        out = tr.update(m)
        sp.append(out.setpoint)
        ms.append(m)
        st_.append(int(out.state))
    return {"tracker": tr, "T": T, "state": np.array(st_),
            "pos": np.array([s.pos for s in sp]), "mpos": np.array([m.pos for m in ms]),
            "ang": np.array([s.ang for s in sp]), "mang": np.array([m.ang for m in ms]),
            "sp": sp, "ms": ms}


def check_run(r: dict, lim: Limits, dim: int, within_s: float = 2.0,
              exact_after: bool = True) -> None:
    """Synchronised within ``within_s``; no vel/acc/jerk norm over the limits by more than
    1e-6 in approach/switch/after; no oscillation; master copied after sync.  Same for the
    rotation channel."""
    tr = r["tracker"]
    T = r["T"]
    assert tr.error == TrackError.NONE
    assert tr.state == TrackState.SYNCED and tr.synced_at * T <= within_s + 1e-9
    m = analyze(r["pos"][:, :dim], r["mpos"][:, :dim], r["state"], T, lim)
    assert m.synced and m.time_to_sync_s <= within_s
    assert {ph: m.violations[TOL][ph] for ph in PHASES} == dict.fromkeys(PHASES, 0), m.ratio
    assert not m.oscillating, m.oscillation_flips
    assert m.error_after_sync_mm <= (0.0 if exact_after else 1e-6)
    after = r["state"] == TrackState.SYNCED
    if exact_after:
        assert np.array_equal(r["pos"][after], r["mpos"][after])
    mr = analyze(r["ang"], r["mang"], r["state"], T, ROT)
    assert {ph: mr.violations[TOL][ph] for ph in PHASES} == dict.fromkeys(PHASES, 0)
    assert mr.synced and not mr.oscillating
    assert np.array_equal(r["ang"][after], r["mang"][after])


def case(T: float, lim: str, vel, acc=(0.0, 0.0, 0.0), off=(0.0, 0.0, 0.0),
         rv=(0.0, 0.0, 0.0), ang_vel: float = 0.0, ang0: float = 0.0) -> dict:
    """A scenario: master from the origin with (vel, acc) [mm/s, mm/s^2] and ang_vel
    [deg/s]; robot at ``off`` [mm] moving with ``rv`` [mm/s], at angle ang0 [deg]."""
    return {"T": T, "lim": lim, "vel": tuple(vel), "acc": tuple(acc), "off": tuple(off),
            "rv": tuple(rv), "ang_vel": ang_vel, "ang0": ang0}


@st.composite
def scenarios(draw, dim: int):
    """Benchmark-like cases: T 1/2/4 ms, limit set A or B, conveyor 50-800 mm/s (3-D: any
    direction), half accelerating (speed kept in 50-800 mm/s for 2.5 s), offset up to
    300 mm per axis, robot at rest or moving up to 300 mm/s, rotation 40 deg off."""
    T = draw(st.sampled_from([0.001, 0.002, 0.004]))
    lim = draw(st.sampled_from(["A", "B"]))
    speed = draw(st.floats(50.0, 800.0))
    acc = 0.0
    if draw(st.booleans()):
        lo, hi = max(-500.0, (50.0 - speed) / 2.5), min(500.0, (800.0 - speed) / 2.5)
        acc = draw(st.floats(lo, hi))

    def unit(x):
        return tuple(c / math.sqrt(sum(y * y for y in x)) for c in x)

    comp = st.floats(-1.0, 1.0)
    if dim == 1:
        u = (1.0, 0.0, 0.0)
        off = (draw(st.floats(-300.0, 300.0)), 0.0, 0.0)
        rv = (draw(st.sampled_from([0.0, 1.0])) * draw(st.floats(-300.0, 300.0)), 0.0, 0.0)
    else:
        d = draw(st.tuples(comp, comp, comp).filter(lambda x: sum(c * c for c in x) > 0.04))
        u = unit(d)
        off = draw(st.tuples(*[st.floats(-300.0, 300.0)] * 3))
        rv = (0.0, 0.0, 0.0)
        if draw(st.booleans()):
            e = unit(draw(st.tuples(comp, comp, comp).filter(
                lambda x: sum(c * c for c in x) > 0.04)))
            s = draw(st.floats(0.0, 300.0))
            rv = tuple(s * c for c in e)
    ang_vel = draw(st.floats(-20.0, 20.0))
    ang0 = draw(st.floats(-40.0, 40.0))
    return case(T, lim, [speed * c for c in u], [acc * c for c in u], off, rv, ang_vel, ang0)


def run_scenario(sc: dict, planner: str = "optimal", seconds: float = 2.5) -> dict:
    master = master_fn(sc["vel"], sc["acc"], sc["ang_vel"])
    initial = MotionState(sc["off"], sc["rv"], (0.0, 0.0, 0.0), sc["ang0"], 0.0, 0.0)
    return run(params(sc["T"], sc["lim"], planner), initial, master, seconds)


# --------------------------------------------------------------------------- tests
def test_registered_default_planner():
    assert TrackerParams().planner == "optimal"
    assert planner_factory("optimal") is create
    p = create(LIMITS["A"], TrackerParams())
    assert isinstance(p, OptimalPlanner) and p.name == "optimal"


@settings(max_examples=80)
@given(scenarios(dim=1))
def test_random_1d_synchronises_within_limits(sc):
    r = run_scenario(sc)
    check_run(r, LIMITS[sc["lim"]], 1, exact_after=not any(sc["acc"]))
    assert np.all(r["pos"][:, 1:] == 0.0)  # 1-D along x stays on x


@settings(max_examples=150)
@given(scenarios(dim=3))
def test_random_3d_synchronises_within_vector_norm_limits(sc):
    check_run(run_scenario(sc), LIMITS[sc["lim"]], 3, exact_after=not any(sc["acc"]))


def test_1d_is_time_optimal_like_the_per_cycle_reference(monkeypatch):
    """In 1-D the plan is the time-optimal one: same time to sync as Ruckig re-planned every
    cycle (also with an accelerating master: the loosening velocity bound is followed)."""
    monkeypatch.setitem(PLANNERS, "ruckig-ref", "controller.tracking.optimal:create_reference")
    cases = [
        case(0.001, "A", (300.0, 0, 0), off=(-100.0, 0, 0)),
        case(0.004, "B", (671.0, 0, 0), (-250.0, 0, 0), (-185.0, 0, 0)),
        case(0.002, "B", (100.0, 0, 0), (280.0, 0, 0), (-150.0, 0, 0), (-300.0, 0, 0)),
    ]
    for sc in cases:
        tts = []
        for planner in ("optimal", "ruckig-ref"):
            r = run_scenario(sc, planner)
            m = analyze(r["pos"][:, :1], r["mpos"][:, :1], r["state"], sc["T"],
                        LIMITS[sc["lim"]])
            tts.append(m.time_to_sync_s)
        assert tts[0] <= tts[1] + sc["T"] + 1e-12


def test_3d_keeps_the_norm_where_the_per_axis_reference_breaks_it(monkeypatch):
    monkeypatch.setitem(PLANNERS, "ruckig-ref", "controller.tracking.optimal:create_reference")
    s2 = 1.0 / math.sqrt(2.0)
    sc = case(0.002, "A", (500 * s2, 500 * s2, 0.0), off=(-200.0, 150.0, 100.0))
    lim = LIMITS["A"]
    ro, rr = run_scenario(sc), run_scenario(sc, "ruckig-ref")
    mo = analyze(ro["pos"], ro["mpos"], ro["state"], sc["T"], lim)
    mr = analyze(rr["pos"], rr["mpos"], rr["state"], sc["T"], lim)
    assert max(mr.ratio["approach"].values()) > 1.3  # the per-axis baseline: up to sqrt(3)
    assert max(mo.ratio["approach"].values()) <= 1.0 + TOL
    assert mo.time_to_sync_s <= 1.2 * mr.time_to_sync_s


def test_faster_than_softmc_and_no_switch_spike():
    rng = np.random.default_rng(5)
    t_opt, t_soft = [], []
    for i in range(12):
        dim = 1 if i % 2 == 0 else 3
        u = np.array([1.0, 0, 0]) if dim == 1 else rng.normal(size=3)
        u /= np.linalg.norm(u)
        off = rng.uniform(-300, 300, 3) * (u != 0 if dim == 1 else 1)
        sc = case(float(rng.choice([0.001, 0.004])), str(rng.choice(["A", "B"])),
                  u * rng.uniform(100, 700), off=off)
        lim = LIMITS[sc["lim"]]
        for planner, out in (("optimal", t_opt), ("softmc", t_soft)):
            r = run_scenario(sc, planner)
            m = analyze(r["pos"][:, :dim], r["mpos"][:, :dim], r["state"], sc["T"], lim)
            out.append(m.time_to_sync_s if m.synced else math.inf)
            if planner == "optimal":
                assert m.ratio["switch"]["jerk"] <= 1.0 + TOL  # no spike at the switch
    assert statistics.median(t_opt) < statistics.median(t_soft)


def test_rotation_channel_synchronises():
    """Translation already on the master; only the angle (40 deg off, master at 15 deg/s)."""
    master = master_fn((200.0, 0.0, 0.0), ang_vel=15.0)
    initial = MotionState((0.0, 0.0, 0.0), (200.0, 0.0, 0.0), (0.0, 0.0, 0.0), 40.0, 0.0,
                          0.0)
    r = run(params(0.002), initial, master, 2.0)
    check_run(r, LIMITS["A"], 3)
    assert np.array_equal(r["pos"][1:], r["mpos"][1:])  # translation untouched
    k = r["tracker"].synced_at
    assert 0.15 < k * 0.002 < 0.5  # time-optimal for 40 deg at 360 deg/s, 3600 deg/s^2


def test_constant_acceleration_master_is_followed_after_sync():
    master = master_fn((150.0, -80.0, 40.0), (220.0, -110.0, 60.0))
    initial = MotionState.at(-120.0, 90.0, 30.0)
    r = run(params(0.001, "B"), initial, master, 2.5)
    check_run(r, LIMITS["B"], 3, exact_after=False)
    after = r["state"] == TrackState.SYNCED
    assert np.abs(r["pos"][after] - r["mpos"][after]).max() <= 1e-6


def test_plans_once_for_a_master_that_moves_as_predicted():
    """The plan is sampled, not re-made, while the master moves as predicted (1-D)."""
    r = run(params(0.001), MotionState.at(-100.0), master_fn((300.0, 0.0, 0.0)), 1.0)
    pl_t = r["tracker"]._planners[0]
    assert pl_t.n_plans == 1 and pl_t.n_fallback == 0
    assert r["tracker"].state == TrackState.SYNCED


def test_master_with_jerk_is_followed_smoothly():
    """A master whose speed varies (300 +- 50 mm/s at 1 Hz) is re-planned every sample; the
    robot still synchronises, never oscillates and keeps v, a within the norm limits; its
    jerk exceeds J by at most the master's own jerk (2*pi^2*50 = 987 mm/s^3)."""
    def master(t: float) -> MotionState:
        w = 2.0 * math.pi
        s = 300.0 * t - 50.0 / w * math.cos(w * t) + 50.0 / w
        return MotionState((s, 0.5 * s, 0.0), (300.0 + 50.0 * math.sin(w * t),
                                                0.5 * (300.0 + 50.0 * math.sin(w * t)), 0.0),
                           (50.0 * w * math.cos(w * t), 25.0 * w * math.cos(w * t), 0.0))
    lim = LIMITS["A"]
    r = run(params(0.001), MotionState.at(-150.0, 60.0, -40.0), master, 2.0)
    tr = r["tracker"]
    assert tr.state == TrackState.SYNCED and tr.synced_at * 0.001 < 1.0
    m = analyze(r["pos"], r["mpos"], r["state"], 0.001, lim)
    for ph in ("approach", "switch"):
        assert m.ratio[ph]["vel"] <= 1.0 + TOL and m.ratio[ph]["acc"] <= 1.0 + TOL
        assert m.peak[ph]["jerk"] <= lim.jerk * (1.0 + TOL) + 987.0 * 1.12
    assert not m.oscillating


@pytest.mark.parametrize("name", ["1d-accelerating", "3d-accelerating", "3d-constant"])
def test_snapshot_restore_is_bit_identical(name):
    """A deep copy (FMU save) and a pickle round trip taken mid-approach continue exactly
    like the original (Ruckig objects are rebuilt from the stored plan inputs)."""
    if name == "1d-accelerating":
        sc = case(0.001, "B", (671.0, 0, 0), (-250.0, 0, 0), (-185.0, 0, 0), ang_vel=10.0,
                  ang0=-20.0)
    elif name == "3d-accelerating":
        sc = case(0.004, "B", (700.0, 0, 0), (-300.0, 0, 0), (-150.0, 250.0, -100.0),
                  (0.0, 0.0, 300.0), 5.0, 30.0)
    else:
        sc = case(0.002, "B", (492.0, -508.0, 209.0), off=(-186.0, 169.0, -33.0),
                  rv=(0.0, 50.0, 0.0), ang0=10.0)
    T = sc["T"]
    master = master_fn(sc["vel"], sc["acc"], sc["ang_vel"])
    tr = Tracker(params(T, sc["lim"]),
                 MotionState(sc["off"], sc["rv"], (0, 0, 0), sc["ang0"], 0.0, 0.0))
    tr.engage()
    k_mid = round(0.15 / T)
    for k in range(1, k_mid + 1):
        tr.update(master(k * T))
    assert tr.state == TrackState.SYNCING and tr._planners[0].plan is not None
    copies = [tr.snapshot(), copy.deepcopy(tr), pickle.loads(pickle.dumps(tr))]
    for k in range(k_mid + 1, round(2.0 / T) + 1):
        m = master(k * T)
        ref = tr.update(m)
        for c in copies:
            assert c.update(m) == ref
    assert tr.state == TrackState.SYNCED


def test_relative_mode_keeps_the_engage_offset():
    master = master_fn((300.0, 0.0, 50.0))
    initial = MotionState((-120.0, 40.0, 10.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 5.0, 0.0,
                          0.0)
    r = run(params(0.001, mode=Mode.RELATIVE), initial, master, 1.5)
    tr = r["tracker"]
    assert tr.state == TrackState.SYNCED and tr.error == TrackError.NONE
    m0 = master(0.0)
    offset = np.array(initial.pos) - np.array(m0.pos)
    after = r["state"] == TrackState.SYNCED
    assert np.abs(r["pos"][after] - r["mpos"][after] - offset).max() <= 1e-9
    assert np.abs(r["ang"][after] - r["mang"][after] - 5.0).max() <= 1e-9
    shifted = r["mpos"] + offset
    m = analyze(r["pos"], shifted, r["state"], 0.001, LIMITS["A"])
    assert {ph: m.violations[TOL][ph] for ph in PHASES} == dict.fromkeys(PHASES, 0)


def test_robot_already_on_the_master_syncs_on_the_first_sample():
    master = master_fn((300.0, 0.0, 0.0))
    m0 = master(0.0)
    r = run(params(0.001), MotionState(m0.pos, m0.vel, m0.acc), master, 0.05)
    assert r["tracker"].synced_at == 1
    assert np.array_equal(r["pos"], r["mpos"])


def test_deterministic():
    sc = case(0.002, "B", (400.0, 300.0, 0.0), (60.0, 45.0, 0.0), (150.0, -200.0, 80.0),
              (0.0, -100.0, 100.0), 3.0, -10.0)
    a, b = run_scenario(sc, seconds=1.5), run_scenario(sc, seconds=1.5)
    assert a["sp"] == b["sp"]


def test_infeasible_master_never_raises_and_recovers():
    """A master faster than the sync velocity limit (800 mm/s > V = 500): the planner falls
    back (never synchronised, norms kept); once the master slows to 300 mm/s it tracks."""
    lim = Limits(500.0, 5000.0, 5.0e4)

    def master(t: float) -> MotionState:
        if t < 0.3:
            return MotionState((800.0 * t, 0.0, 0.0), (800.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        if t < 0.5:
            u = t - 0.3
            return MotionState((240.0 + 800.0 * u - 1250.0 * u * u, 0.0, 0.0),
                               (800.0 - 2500.0 * u, 0.0, 0.0), (-2500.0, 0.0, 0.0))
        u = t - 0.5
        return MotionState((350.0 + 300.0 * u, 0.0, 0.0), (300.0, 0.0, 0.0), (0.0, 0.0, 0.0))

    T = 0.001
    p = TrackerParams(sample_time_s=T, sync_trans=lim, desync_trans=lim,
                      master_max_trans=Limits(1000.0, 3000.0, 1e6))
    r = run(p, MotionState.at(-50.0, 20.0, 0.0), master, 2.5)
    tr = r["tracker"]
    assert tr._planners[0].n_fallback > 0
    assert tr.state == TrackState.SYNCED and tr.error == TrackError.NONE
    assert tr.synced_at * T > 0.5
    appr = r["state"] == TrackState.SYNCING
    v = np.diff(r["pos"], axis=0) / T
    a = np.diff(v, axis=0) / T
    j = np.diff(a, axis=0) / T
    assert np.linalg.norm(v[appr[1:]], axis=1).max() <= lim.vel * (1 + TOL)
    assert np.linalg.norm(a[appr[2:]], axis=1).max() <= lim.acc * (1 + TOL)
    assert np.linalg.norm(j[appr[3:]], axis=1).max() <= lim.jerk * (1 + TOL)


def test_planner_alone_n1_and_n3_and_reference():
    """The protocol directly: the same class for 1 and 3 components; the reference baseline
    re-plans every sample and is not norm-safe by design (documented)."""
    for n in (1, 3):
        for cls in (OptimalPlanner, RuckigReference):
            p = cls(Limits(2000.0, 2.0e4, 4.0e5), 0.001)
            p.reset((-50.0,) * n, (0.0,) * n, (0.0,) * n)
            synced = False
            for k in range(1, 1000):
                t = k * 0.001
                pos, vel, acc, synced = p.step((300.0 * t,) * n, (300.0,) * n, (0.0,) * n)
                assert len(pos) == len(vel) == len(acc) == n
                if synced:
                    assert pos == (300.0 * t,) * n
                    break
            assert synced


@pytest.mark.parametrize("T,q,v", [(0.002, 1 / 409.6, 237.3), (0.001, 1 / 409.6, 300.0),
                                   (0.004, 0.01, 555.5)])
def test_synchronises_with_an_estimated_quantised_master(T, q, v):
    """An encoder master through the estimator never matches a plan's prediction exactly:
    the planner re-plans every sample and must still finish (snap within SNAP_SAMPLES)."""
    import math as _m
    from controller.tracking import MasterEstimator
    est = MasterEstimator(T, window=16, lead_samples=2.0)
    tr = Tracker(TrackerParams(sample_time_s=T, planner="optimal"), MotionState.at(100.0, 0, 0))
    for k in range(1, int(1.0 / T)):
        if k == 16:
            tr.engage()  # once the estimator's window is full
        est.push(_m.floor(v * (k - 1) * T / q) * q)
        e = est.estimate()
        tr.update(MotionState((e.pos, 0.0, 0.0), (e.vel, 0.0, 0.0), (e.acc, 0.0, 0.0)))
    assert tr.state == TrackState.SYNCED and tr.error == TrackError.NONE
    assert tr.synced_at * T < 0.4
