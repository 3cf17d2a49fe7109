"""Batch stepping (controller.tracking.batch): bit-identical to N scalar softmc Trackers.

Seeded random suites of 30-60 trackers with different parameters (limits, robot maxima and
rates, FilterFactor, DampingFactor 0.3 which oscillates, MaxFlops windows, approach timeouts,
master maxima, relative/absolute mode, literal and default SoftMcOptions, de-sync from the
current or zero acceleration) run against moving masters with random engage / disengage /
re-engage commands; every sample of every output array must equal the scalar path bit for
bit (including the sign of zeros).  Each suite also checks that the paths it is meant to
cover actually occurred.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from controller import tracking
from controller.errors import ParameterError, StateError
from controller.tracking import (Limits, Mode, MotionState, Rates, SoftMcOptions, Tracker,
                                 TrackerParams, TrackError, TrackState)
from controller.tracking import batch as batch_mod
from controller.tracking.batch import BatchTracker

OPTION_FLAGS = ("pred_acc_from_master", "init_increments_from_state", "end_of_sample_feedback",
                "braking_distance_velocity", "take_the_middle", "unit_consistent_thresholds")
#: the options the core has (time_to_reach_k, directional_k are newer)
OPTION_FIELDS = {f.name for f in dataclasses.fields(SoftMcOptions)}
FIELDS = ("pos", "vel", "acc", "ang", "ang_vel", "ang_acc", "state", "imfs", "error",
          "synced_now")


def random_params(rng: np.random.Generator, n: int, T: float,
                  masters: Masters | None = None) -> list[TrackerParams]:
    out = []
    for i in range(n):
        mt = Limits(float(rng.uniform(800, 1500)), float(rng.uniform(800, 3000)), 1000.0)
        if masters is not None:
            # some masters go over their VelocityMax / AccelerationMax now and then
            j = min(i, len(masters.s) - 1)
            bw = masters.B[j, :3] * masters.w[j, :3]
            vpeak = float(np.linalg.norm(np.abs(masters.s[j, :3]) + bw))
            apeak = float(np.linalg.norm(bw * masters.w[j, :3]))
            r = rng.random()
            if r < 0.12 and vpeak > 50.0:
                mt = Limits(vpeak * float(rng.uniform(0.8, 0.97)), mt.acc, 1000.0)
            elif r < 0.24 and apeak > 50.0:
                mt = Limits(mt.vel, apeak * float(rng.uniform(0.8, 0.97)), 1000.0)
        flags = rng.random(6) < 0.8
        opts = (SoftMcOptions.literal() if rng.random() < 0.2 else SoftMcOptions(
            **{name: bool(f) for name, f in zip(OPTION_FLAGS, flags)}))
        if "time_to_reach_k" in OPTION_FIELDS and rng.random() < 0.5:
            opts = dataclasses.replace(opts, time_to_reach_k=tuple(
                float(x) for x in rng.choice([2.0, 4.0, 8.0, 16.0], 2)))
        if "directional_k" in OPTION_FIELDS and rng.random() < 0.3:
            opts = dataclasses.replace(opts, directional_k=True)
        vt = float(rng.uniform(800, 3000))
        at = float(rng.uniform(4e3, 3e4))
        jt = float(rng.uniform(5e4, 6e5))
        vr = float(rng.uniform(100, 400))
        robot_t = (Limits(float(rng.uniform(1500, 4000)), float(rng.uniform(5e3, 4e4)),
                          float(rng.uniform(1e5, 8e5))) if rng.random() < 0.3 else None)
        robot_r = (Limits(300.0, 3000.0, 60000.0) if rng.random() < 0.2 else None)
        rates = (Rates(float(rng.uniform(50, 100)), float(rng.uniform(30, 100)),
                       float(rng.uniform(30, 100)), float(rng.uniform(30, 100)))
                 if rng.random() < 0.3 else Rates())
        out.append(TrackerParams(
            sample_time_s=T, planner="softmc",
            mode=Mode.RELATIVE if rng.random() < 0.3 else Mode.ABSOLUTE,
            sync_trans=Limits(vt, at, jt),
            desync_trans=Limits(vt, float(rng.uniform(4e3, 3e4)), float(rng.uniform(5e4, 6e5))),
            sync_rot=Limits(vr, vr * 10.0, float(rng.uniform(2e4, 1e5))),
            desync_rot=Limits(vr, float(rng.uniform(1e3, 5e3)), float(rng.uniform(2e4, 1e5))),
            robot_max_trans=robot_t, robot_max_rot=robot_r, rates=rates,
            filter_factor=float(rng.choice([0.3, 0.5, 1.0, 1.0, 2.0, 3.0])) * float(
                rng.uniform(0.9, 1.1)),
            damping_factor=float(rng.choice([0.3, 0.3, 0.5, 1.0, 1.0, 1.5, 2.0])),
            max_flops=int(rng.integers(2, 12)),
            max_flops_time_s=float(rng.uniform(0.02, 1.0)),
            approach_timeout_s=float(rng.choice([0.04, 0.6, 5.0, 5.0, 5.0, 5.0, 5.0])),
            master_max_trans=mt,
            master_max_rot=Limits(float(rng.uniform(60, 150)), float(rng.uniform(60, 400)),
                                  100.0) if rng.random() < 0.8 else Limits(25.0, 60.0, 100.0),
            softmc=opts,
            desync_from_current_acceleration=bool(rng.random() < 0.7),
        ))
    return out


def random_initial(rng: np.random.Generator, n: int) -> list[MotionState]:
    out = []
    for _ in range(n):
        kind = rng.random()
        if kind < 0.4:
            out.append(MotionState.at(*rng.uniform(-200, 200, 4)))
        else:
            out.append(MotionState(tuple(rng.uniform(-300, 300, 3).tolist()),
                                   tuple(rng.uniform(-200, 200, 3).tolist()),
                                   tuple((rng.uniform(-50, 50, 3) * (kind < 0.8)).tolist()),
                                   float(rng.uniform(-90, 90)), float(rng.uniform(-30, 30)),
                                   float(rng.uniform(-5, 5))))
    return out


class Masters:
    """Per-tracker masters: p_j(t) = p0 + s t + B sin(w t + phi) on each axis and the angle."""

    def __init__(self, rng: np.random.Generator, n: int) -> None:
        self.p0 = rng.uniform(-300, 300, (n, 4))
        self.s = rng.uniform(-450, 450, (n, 4)) * (rng.random((n, 4)) < 0.6)
        self.s[:, 3] *= 0.1
        self.B = rng.uniform(0, 20, (n, 4)) * (rng.random((n, 4)) < 0.25)
        self.B[:, 3] *= 0.5
        self.w = rng.uniform(1, 6, (n, 4))
        self.phi = rng.uniform(0, 2 * np.pi, (n, 4))

    def at(self, t: float):
        arg = self.w * t + self.phi
        sn, cs = np.sin(arg), np.cos(arg)
        p = self.p0 + self.s * t + self.B * sn
        v = self.s + self.B * self.w * cs
        a = -self.B * self.w * self.w * sn
        return (np.ascontiguousarray(p[:, :3]), np.ascontiguousarray(v[:, :3]),
                np.ascontiguousarray(a[:, :3]), p[:, 3].copy(), v[:, 3].copy(),
                a[:, 3].copy())


def scalar_outputs(outs) -> dict[str, np.ndarray]:
    sp = [o.setpoint for o in outs]
    return {
        "pos": np.array([s.pos for s in sp], dtype=np.float64),
        "vel": np.array([s.vel for s in sp], dtype=np.float64),
        "acc": np.array([s.acc for s in sp], dtype=np.float64),
        "ang": np.array([s.ang for s in sp], dtype=np.float64),
        "ang_vel": np.array([s.ang_vel for s in sp], dtype=np.float64),
        "ang_acc": np.array([s.ang_acc for s in sp], dtype=np.float64),
        "state": np.array([int(o.state) for o in outs]),
        "imfs": np.array([int(o.imfs) for o in outs]),
        "error": np.array([int(o.error) for o in outs]),
        "synced_now": np.array([o.synchronized_now for o in outs]),
    }


def assert_identical(k: int, b, s: dict[str, np.ndarray]) -> None:
    for name in FIELDS:
        x = getattr(b, name)
        y = s[name]
        if x.dtype == np.float64:
            same = np.array_equal(x.view(np.int64), y.view(np.int64))  # bits, signed zeros
        else:
            same = np.array_equal(x.astype(np.int64), y.astype(np.int64))
        if not same:
            bad = np.flatnonzero(np.any((x != y).reshape(len(x), -1), axis=1)
                                 | np.any((np.signbit(x) != np.signbit(y)).reshape(len(x), -1),
                                          axis=1) if x.dtype == np.float64 else
                                 (x.astype(np.int64) != y.astype(np.int64)))
            i = int(bad[0]) if len(bad) else -1
            raise AssertionError(f"sample {k}: {name} differs for trackers {bad[:10].tolist()}; "
                                 f"tracker {i}: batch {x[i]!r} scalar {y[i]!r}")


def run_suite(seed: int, n: int, steps: int, T: float, *, p_engage=0.001, p_disengage=0.0005,
              broadcast: bool = False, configure=None):
    """Run N scalar Trackers and one BatchTracker side by side; return event counts."""
    rng = np.random.default_rng(seed)
    masters = Masters(rng, 1 if broadcast else n)
    params = random_params(rng, n, T, masters)
    initial = random_initial(rng, n)
    scalars = [Tracker(p, s) for p, s in zip(params, initial)]
    bt = BatchTracker(params, initial)
    if configure is not None:
        configure(bt)
    seen = {"errors": set(), "states": set(), "synced_now": 0, "relative_synced": 0,
            "reengage_desync": 0}
    for k in range(1, steps + 1):
        # commands (take effect at this update), including mode changes and re-engages
        eng = rng.random(n) < p_engage
        if k == 2:
            eng |= rng.random(n) < 0.7
        state = bt.state
        eng |= (state == TrackState.DESYNCING) & (rng.random(n) < 0.01)
        dis = rng.random(n) < p_disengage
        dis |= (state == TrackState.SYNCED) & (rng.random(n) < 0.003)
        modes = rng.choice([0, 0, 0, 3, 5], n)
        for mode in (0, 3, 5):
            mask = eng & (modes == mode)
            if mask.any():
                bt.engage(mask, None if mode == 0 else mode)
        for i in np.flatnonzero(eng):
            scalars[i].engage(None if modes[i] == 0 else int(modes[i]))
            if scalars[i].state == TrackState.DESYNCING:
                seen["reengage_desync"] += 1
        if dis.any():
            bt.disengage(dis)
        for i in np.flatnonzero(dis):
            scalars[i].disengage()
        mp, mv, ma, mang, mangv, manga = masters.at(k * T)
        if broadcast:
            out = bt.update(mp[0], mv[0], ma[0], float(mang[0]), float(mangv[0]),
                            float(manga[0]))
            m_all = MotionState(tuple(mp[0].tolist()), tuple(mv[0].tolist()),
                                tuple(ma[0].tolist()), float(mang[0]), float(mangv[0]),
                                float(manga[0]))
            souts = [tr.update(m_all) for tr in scalars]
        else:
            out = bt.update(mp, mv, ma, mang, mangv, manga)
            mpl, mvl, mal = mp.tolist(), mv.tolist(), ma.tolist()
            angl, angvl, angal = mang.tolist(), mangv.tolist(), manga.tolist()
            souts = [tr.update(MotionState(tuple(mpl[i]), tuple(mvl[i]), tuple(mal[i]),
                                           angl[i], angvl[i], angal[i]))
                     for i, tr in enumerate(scalars)]
        s = scalar_outputs(souts)
        assert out.sample == k == souts[0].sample
        assert_identical(k, out, s)
        seen["errors"].update(int(e) for e in s["error"])
        seen["states"].update(int(x) for x in s["state"])
        seen["synced_now"] += int(s["synced_now"].sum())
        seen["relative_synced"] += sum(1 for i, tr in enumerate(scalars)
                                       if s["synced_now"][i] and tr.mode == Mode.RELATIVE)
    return seen


@pytest.mark.parametrize("seed,n,steps,T", [
    (1, 48, 3000, 0.001),
    (2, 40, 2500, 0.002),
    (3, 30, 1500, 0.004),
    (4, 60, 2000, 0.001),
])
def test_batch_equals_scalar_trackers_bit_for_bit(seed, n, steps, T):
    seen = run_suite(seed, n, steps, T)
    assert seen["states"] == {0, 1, 2, 3}
    assert seen["synced_now"] >= n // 5
    assert seen["relative_synced"] > 0
    # master velocity/acceleration limits, over-oscillation and the approach timeout occurred
    assert {int(TrackError.MASTER_VELOCITY), int(TrackError.MASTER_ACCELERATION),
            int(TrackError.OVER_OSCILLATION),
            int(TrackError.APPROACH_TIMEOUT)} <= seen["errors"], seen["errors"]
    assert seen["reengage_desync"] > 0


@pytest.mark.parametrize("dense_min", [1, 10**9])
def test_dense_and_sparse_syncing_paths(dense_min):
    # dense: the softMC step on all columns, masked write-back; sparse: gather/scatter
    def configure(bt):
        bt._dense_min = dense_min

    seen = run_suite(21, 24, 1200, 0.002, configure=configure)
    assert seen["synced_now"] > 0 and seen["states"] == {0, 1, 2, 3}


def test_exact_pow_norm_fallback_path(monkeypatch):
    # every column "close" to a threshold: all sync decisions use the ``** 2`` norms
    monkeypatch.setattr(batch_mod, "_CLOSE_REL", math.inf)
    seen = run_suite(31, 20, 800, 0.002)
    assert seen["synced_now"] > 0


def test_batch_broadcast_single_master_equals_scalar():
    seen = run_suite(11, 36, 1500, 0.002, broadcast=True)
    assert seen["synced_now"] > 0 and 3 in seen["states"]


def test_broadcast_shapes_give_the_same_result():
    rng = np.random.default_rng(5)
    params = random_params(rng, 8, 0.001)
    a = BatchTracker(params)
    b = BatchTracker(params)
    a.engage()
    b.engage()
    for k in range(300):
        t = k * 0.001
        p = np.array([100.0 + 300.0 * t, 20.0, -5.0])
        v = np.array([300.0, 0.0, 0.0])
        oa = a.update(p, v, np.zeros(3), 10.0, 5.0, 0.0)
        ob = b.update(np.tile(p, (8, 1)), np.tile(v, (8, 1)), np.zeros((8, 3)),
                      np.full(8, 10.0), np.full(8, 5.0), np.zeros(8))
        for name in FIELDS:
            assert np.array_equal(getattr(oa, name), getattr(ob, name))
    # a MotionState master is broadcast too
    c = BatchTracker(params)
    c.engage()
    m = MotionState((100.0, 20.0, -5.0), (300.0, 0.0, 0.0), (0.0, 0.0, 0.0), 10.0, 5.0, 0.0)
    oc = c.update(m)
    assert oc.pos.shape == (8, 3) and oc.ang.shape == (8,)
    assert oc.state.tolist() == [int(TrackState.SYNCING)] * 8


def test_initial_as_arrays_and_output_helpers():
    params = [TrackerParams(planner="softmc", sample_time_s=0.002)] * 3
    pos = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]])
    bt = BatchTracker(params, {"pos": pos, "vel": [10.0, 0.0, 0.0], "ang": [1.0, 2.0, 3.0]})
    out = bt.update(np.zeros(3))
    tr = Tracker(params[1], MotionState((4.0, 5.0, 6.0), (10.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                                        2.0, 0.0, 0.0))
    assert out.setpoint(1) == tr.update(MotionState()).setpoint == bt.setpoint(1)
    assert out.state.tolist() == [0, 0, 0] and out.imfs.tolist() == [0, 0, 0]


def test_literal_options_and_relative_mode_all_trackers():
    # every tracker literal or relative, several FilterFactors, one master
    T = 0.001
    params = []
    for i in range(24):
        params.append(TrackerParams(
            sample_time_s=T, planner="softmc",
            mode=Mode.RELATIVE if i % 2 else Mode.ABSOLUTE,
            softmc=SoftMcOptions.literal() if i % 3 else SoftMcOptions(),
            filter_factor=[0.5, 1.0, 2.0, 4.0][i % 4], damping_factor=[0.3, 1.0][i % 2 == 0]))
    init = [MotionState.at(10.0 * i, -5.0 * i, 0.0, 3.0 * i) for i in range(24)]
    bt = BatchTracker(params, init)
    scalars = [Tracker(p, s) for p, s in zip(params, init)]
    bt.engage()
    for tr in scalars:
        tr.engage()
    for k in range(1, 1201):
        if k == 900:
            bt.disengage()
            for tr in scalars:
                tr.disengage()
        t = k * T
        m = MotionState((50.0 + 250.0 * t, 30.0, 0.0), (250.0, 0.0, 0.0), (0.0, 0.0, 0.0),
                        20.0 + 8.0 * t, 8.0, 0.0)
        out = bt.update(m)
        assert_identical(k, out, scalar_outputs([tr.update(m) for tr in scalars]))


def test_errors_name_the_index():
    good = TrackerParams(planner="softmc")
    with pytest.raises(ParameterError, match=r"batch stepping supports planner 'softmc'.*"
                                             r"params\[2\]"):
        BatchTracker([good, good, TrackerParams(), good])
    with pytest.raises(ParameterError, match=r"params\[1\]\.sample_time_s"):
        BatchTracker([good, good.with_(sample_time_s=0.002)])
    with pytest.raises(ParameterError, match=r"params\[1\]"):
        BatchTracker([good, "not params"])
    with pytest.raises(ParameterError, match="at least one"):
        BatchTracker([])
    with pytest.raises(ParameterError, match=r"initial\[1\]"):
        BatchTracker([good, good], [MotionState(), None])
    with pytest.raises(ParameterError, match="2 states given, 3 needed"):
        BatchTracker([good] * 3, [MotionState()] * 2)
    bt = BatchTracker([good] * 3)
    with pytest.raises(ParameterError, match=r"master_pos: shape \(2, 3\)"):
        bt.update(np.zeros((2, 3)))
    with pytest.raises(ParameterError, match=r"master_ang: shape \(4,\)"):
        bt.update(np.zeros(3), master_ang=np.zeros(4))
    with pytest.raises(ParameterError, match="index 7 out of range"):
        bt.engage([0, 7])
    with pytest.raises(ParameterError, match="mode"):
        bt.engage(mode=4)
    bt.engage([1])
    bt.update(np.zeros(3))
    with pytest.raises(StateError, match="tracker 1 is not OFF"):
        bt.set_robot_state(1, MotionState())


def test_engage_mode_zero_disengages_and_masks():
    params = [TrackerParams(planner="softmc")] * 4
    bt = BatchTracker(params)
    bt.engage(np.array([True, True, False, False]))
    o = bt.update(np.array([5.0, 0.0, 0.0]))
    assert o.state.tolist() == [1, 1, 0, 0]
    bt.engage([1], mode=0)
    o = bt.update(np.array([5.0, 0.0, 0.0]))
    assert o.state.tolist()[:2] in ([1, 3], [1, 0])


def py312_sum(xs, start=0):
    """The builtin sum() of floats of Python >= 3.12 (Neumaier compensation), in Python."""
    xs = list(xs)
    if not xs:
        return start
    f = start + xs[0]
    c = 0.0
    for x in xs[1:]:
        t = f + x
        c += (f - t) + x if abs(f) >= abs(x) else (x - t) + f
        f = t
    return f + c if c and math.isfinite(c) else f


def test_neumaier_sum_matches_python_312_algorithm():
    rng = np.random.default_rng(3)
    x = rng.standard_normal((3, 20000)) * np.exp(rng.uniform(-20, 20, (3, 20000)))
    x[:, :50] = [[1e16], [1.0], [-1e16]]
    got = batch_mod._neumaier([x[0], x[1], x[2]])
    want = np.array([py312_sum(col) for col in x.T.tolist()])
    assert np.array_equal(got, want)


@pytest.mark.skipif(tracking.NATIVE,
                    reason="emulates Python 3.12 by patching the modules' sum(), which the "
                           "compiled core does not look up (docs/architecture.md "
                           "\"Compiled core\"; CANTRACK_PURE=1 runs it)")
def test_python_312_compensated_sum_path(monkeypatch):
    # emulate Python >= 3.12 on any version: the scalar code's sum() compensated, and the
    # batch path switched to its Neumaier branch -- still bit-identical
    from controller.tracking import desync, softmc

    monkeypatch.setattr(softmc, "sum", py312_sum, raising=False)
    monkeypatch.setattr(desync, "sum", py312_sum, raising=False)
    monkeypatch.setattr(batch_mod, "_COMPENSATED_SUM", True)
    seen = run_suite(41, 20, 800, 0.002)
    assert seen["synced_now"] > 0


def test_sum_of_squares_matches_builtin_sum_and_pow_fallback():
    rng = np.random.default_rng(9)
    x = rng.standard_normal((3, 20000)) * np.exp(rng.uniform(-10, 10, (3, 20000)))
    got = batch_mod._pysumsq3(x)
    want = np.array([sum(c * c for c in col) for col in x.T.tolist()])
    assert np.array_equal(got, want)
    # the ``** 2`` norm of softmc.py, recomputed for columns close to a threshold
    err = np.zeros((2, x.shape[1]))
    zero = np.zeros_like(x)
    dims = np.where(np.arange(x.shape[1]) % 2, 3, 1)
    batch_mod._exact_norms(np.arange(x.shape[1]), x, zero, zero, x, dims, err)
    want = np.array([math.sqrt(sum(c ** 2 for c in col[:d]))
                     for col, d in zip(x.T.tolist(), dims.tolist())])
    assert np.array_equal(err[0], want) and np.array_equal(err[1], want)
    # ``** 2`` (libm pow) is not always x*x: that is why the fallback exists
    assert any(c ** 2 != c * c for c in x.ravel().tolist())
