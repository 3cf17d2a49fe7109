"""The master conditioning through the shells: the simulator's ``conditioning:`` section, the
FMUs' raw-encoder input (``master_input=1``, CanTracker FMI 2 and CanTracker3 FMI 3) and the
CAN shell's ``conveyor.conditioning`` run the same core and give bit-identical results for
the same encoder samples."""

from __future__ import annotations

import math

import pytest

from controller.simulate import load_scenario
from controller.simulate.master import _quantise, build_profile, master_states
from controller.tracking.conditioning import ConditioningParams, EncoderModel, MasterConditioner


T = 0.002
Q = 0.01


def scenario(latency: int) -> dict:
    return {
        "engage": 0.1,
        "duration_s": 1.2,
        "tracker": {"sample_time_s": T, "planner": "optimal",
                    "master_max_trans": {"vel": 1000, "acc": 1000, "jerk": 5000}},
        "robot": {"position": [-40.0, 30.0, 0.0]},
        "master": {"segments": [{"duration_s": 0.3, "velocity": 300.0},
                                {"speed_change": {"to": 500, "acc": 800, "jerk": 5000}},
                                {"duration_s": 0.5}]},
        "conditioning": {"resolution_mm": Q, "latency_samples": latency},
    }


def warm_samples(sc) -> int:
    """The simulator's warm-up cycles before t = 0 (controller.simulate.master)."""
    p = ConditioningParams(T, EncoderModel(Q, sc.conditioning.latency_samples),
                           sc.params.master_max_trans)
    pr = ConditioningParams(T, EncoderModel(0.0, sc.conditioning.latency_samples),
                            sc.params.master_max_rot)
    return max(p.warmup, pr.warmup) + sc.conditioning.latency_samples + 2


def test_simulator_feeds_the_conditioner_what_the_encoder_gives():
    """The simulator's fed master is MasterConditioner on the quantised, late samples."""
    sc = load_scenario(scenario(1))
    true, fed = master_states(sc)
    warm = warm_samples(sc)
    prof = build_profile(sc.master)
    L = sc.conditioning.latency_samples
    c = MasterConditioner(ConditioningParams(T, EncoderModel(Q, L), sc.params.master_max_trans,
                                             lead_samples=0.0))
    for i in range(warm + sc.n_samples + 1):
        o = c.update(_quantise(prof.state((i - warm - L) * T).pos[0], Q), 0.0)
        if i >= warm:
            k = i - warm
            assert (fed[k].pos[0], fed[k].vel[0], fed[k].acc[0], fed[k].jerk[0]) == (
                o.pos, o.vel, o.acc, o.jerk), k
    # lag compensated: within a count of the true belt at constant speed
    assert max(abs(f.pos[0] - t.pos[0]) for f, t in zip(fed[:100], true[:100])) <= Q


# -------------------------------------------------------------- the FMUs
RES_DEG = 0.01


def fmu_scenario(jitter: float = 0.0) -> dict:
    """An S-curve belt along X with a rotating frame (both encoders quantised), latency 2,
    sampling instants off by up to ``jitter`` x T (known to the conditioner)."""
    sc = scenario(2)
    sc["master"]["segments"][0]["c_rate"] = 10.0
    sc["conditioning"]["resolution_deg"] = RES_DEG
    sc["conditioning"]["jitter"] = jitter
    return sc


def _sim_jitter(sc, warm: int):
    """The simulator's sampling-instant offsets per conditioner cycle [s]
    (controller.simulate.master: seeded, uniform in +-jitter*T)."""
    import numpy as np

    cs = sc.conditioning
    rng = np.random.default_rng(cs.seed)
    return rng.uniform(-cs.jitter, cs.jitter, sc.n_samples + 1 + warm) * T


def _sim_warm(sc) -> int:
    """The simulator's warm-up cycles before t = 0 (controller.simulate.master)."""
    cs = sc.conditioning
    p = ConditioningParams(T, EncoderModel(cs.resolution_mm, cs.latency_samples),
                           sc.params.master_max_trans)
    pr = ConditioningParams(T, EncoderModel(cs.resolution_deg, cs.latency_samples),
                            sc.params.master_max_rot)
    return max(p.warmup, pr.warmup) + cs.latency_samples + 2


def _encoder_start(L: int, **extra) -> dict:
    """FMU parameters of the simulator's conditioning with latency L (the FMU's latency is
    the samples' age at the step start, one less: its first setpoint is one sample on)."""
    return {"planner": 1, "sample_time": T, "master_input": 1, "encoder_resolution": Q,
            "encoder_resolution_rot": RES_DEG, "encoder_latency": L - 1,
            "jerk_max_master": 5000.0, "x0": -40.0, "y0": 30.0, **extra}


@pytest.fixture(params=["fmi2", "fmi3"])
def fmu_path(request):
    return request.getfixturevalue("fmu2_path" if request.param == "fmi2" else "fmu3_path")


def _optimal_or_skip() -> None:
    try:
        import controller.tracking.optimal  # noqa: F401
    except Exception:
        pytest.skip("the optimal planner needs ruckig")


@pytest.mark.parametrize("jitter", [0.0, 0.1])
def test_fmu_raw_encoder_input_is_bit_identical_to_the_simulator(fmu_path, jitter):
    """The FMU with master_input=1 fed the simulator's raw encoder samples (its warm-up
    history first, then the run; the unused velocity/acceleration inputs set to nonsense;
    with jitter, each sample's instant offset in encoder_time_offset) gives the simulator's
    setpoints, velocities, accelerations and states bit for bit, through the approach into
    SYNCED and an S-curve speed change."""
    pytest.importorskip("fmpy")
    _optimal_or_skip()
    from controller.fmu.runner import CoreRun, FmuTracker
    from controller.simulate.runner import simulate
    from controller.tracking import MotionState

    sc = load_scenario(fmu_scenario(jitter))
    res = simulate(sc)
    warm = _sim_warm(sc)
    prof = build_profile(sc.master)
    L = sc.conditioning.latency_samples
    ke = sc.engage_samples[0]
    delta = _sim_jitter(sc, warm)

    def at(j: int):  # FMU step j = conditioner cycle j = simulator sample j - warm
        st = prof.state((j - warm - L) * T + delta[j])
        return MotionState((_quantise(st.pos[0], Q), _quantise(st.pos[1], Q),
                            _quantise(st.pos[2], Q)), (1e4, -1e4, 7.0), (-3e5, 2e5, 1.0),
                           _quantise(st.ang, RES_DEG), 123.0, -456.0), j - warm > ke

    with FmuTracker(fmu_path, start_values=_encoder_start(L)) as fmu:
        got = CoreRun([], [])
        for j in range(warm + sc.n_samples):
            if jitter:
                fmu.set({"encoder_time_offset": float(delta[j])})
            step = fmu.run(at, 1, T, first_step=j)
            got.reals += step.reals
            got.ints += step.ints
        status, outliers = fmu.get_ints(["master_status", "master_outliers"])
        warnings = [m for m in fmu.messages if m[0] >= 1]
    n_cmp = 0
    for k in range(1, sc.n_samples):  # FMU step warm + k gives the simulator's sample k
        row, ints = got.reals[warm + k], got.ints[warm + k]
        assert row[0:3] == list(res.setpoint_pos[k]), k
        assert row[3] == res.setpoint_ang[k], k
        assert row[4:7] == list(res.setpoint_vel[k]) and row[7] == res.setpoint_ang_vel[k], k
        assert row[8:11] == list(res.setpoint_acc[k]) and row[11] == res.setpoint_ang_acc[k], k
        assert ints == [int(res.imfs[k]), int(res.state[k]), int(res.error[k])], k
        n_cmp += 1
    assert n_cmp == sc.n_samples - 1 and 2 in {int(s) for s in res.state}  # through SYNCED
    assert (status, outliers) == (1, 0) and warnings == []
    assert max(abs(res.setpoint_ang[k] - res.master_ang[k]) for k in range(400, 600)) < 0.01


def test_fmu_raw_encoder_through_fmpy_simulate_fmu(fmu2_path):
    """fmpy's ``simulate_fmu`` with the encoder parameters as start values and the raw
    encoder positions as an input table: the same setpoints as the simulator."""
    np = pytest.importorskip("numpy")
    pytest.importorskip("fmpy")
    _optimal_or_skip()
    from fmpy import simulate_fmu

    from controller.simulate.runner import simulate

    sc = load_scenario(fmu_scenario())
    res = simulate(sc)
    warm = _sim_warm(sc)
    prof = build_profile(sc.master)
    L = sc.conditioning.latency_samples
    ke = sc.engage_samples[0]
    n = warm + sc.n_samples
    rows = []
    for j in range(n + 1):
        st = prof.state((j - warm - L) * T)
        rows.append((j * T, _quantise(st.pos[0], Q), _quantise(st.ang, RES_DEG), j - warm > ke))
    signals = np.array(rows, dtype=[("time", float), ("master_x", float), ("master_c", float),
                                    ("engage", bool)])
    start = _encoder_start(L)
    start.pop("y0")  # the belt's y is 0 and the robot's 30: as the simulator's
    result = simulate_fmu(str(fmu2_path), start_values={**start, "y0": 30.0},
                          stop_time=n * T, output_interval=T, input=signals,
                          output=["x", "y", "c", "state", "master_status", "master_outliers"])
    assert len(result) == n + 1
    for k in range(1, sc.n_samples):
        r = result[warm + k + 1]  # row i: the outputs at time i*T, after FMU step i - 1
        assert (float(r["x"]), float(r["y"])) == tuple(res.setpoint_pos[k][:2]), k
        assert float(r["c"]) == res.setpoint_ang[k] and int(r["state"]) == res.state[k], k
    assert int(result["master_status"][0]) == 0  # STARTING before the first sample
    assert int(result["master_status"][-1]) == 1 and int(result["master_outliers"][-1]) == 0


def _belt(fmu_path, steps: int, glitch, start: dict, samples_per_step: int = 1):
    """A 300 mm/s belt (10 um counts, latency 0) through the FMU; ``glitch(j)`` [mm] is
    added to the sample of step j.  Returns (rows, ints, statuses, outliers, messages)."""
    from controller.fmu.runner import FmuTracker
    from controller.tracking import MotionState

    n = samples_per_step
    with FmuTracker(fmu_path, start_values={"sample_time": T, "master_input": 1,
                                            "encoder_resolution": Q, **start}) as fmu:
        rows, ints, status, outliers = [], [], [], []
        for j in range(steps):
            x = _quantise(300.0 * j * n * T, Q) + glitch(j)
            fmu.step(MotionState((x, 20.0, 0.0)), j * n * T >= 0.1, n * T)
            r, i = fmu.outputs()
            rows.append(r)
            ints.append(i)
            st, no = fmu.get_ints(["master_status", "master_outliers"])
            status.append(st)
            outliers.append(no)
        return rows, ints, status, outliers, list(fmu.messages)


def test_fmu_glitch_is_an_outlier_without_a_setpoint_jump(fmu_path):
    """A 5 mm one-sample glitch while SYNCED: counted (master_outliers 1), master_status
    COASTING for that step only, the tracker stays SYNCED without error, and the setpoint's
    velocity stays within the sync limit (the same run with the master as a state input
    copies the jump to the drives)."""
    from controller.tracking import TrackState

    planner = 1
    try:
        import controller.tracking.optimal  # noqa: F401
    except Exception:
        planner = 0
    g = 600
    rows, ints, status, outliers, messages = _belt(
        fmu_path, 900, lambda j: 5.0 if j == g else 0.0, {"planner": planner})
    assert ints[g - 1][1] == TrackState.SYNCED
    assert outliers[g - 1] == 0 and outliers[g:] == [1] * (900 - g)
    assert status[g] == 2 and status[g - 1] == status[g + 1] == 1
    assert all(i[1] == TrackState.SYNCED and i[2] == 0 for i in ints[g:])
    vel = [abs(r[4]) for r in rows[g - 5:g + 50]]
    assert max(vel) < 300.0 * 1.01, max(vel)  # the belt's speed: no 5 mm/T spike
    assert [m for m in messages if m[0] >= 1] == []


def test_fmu_permanent_jump_loses_the_master(fmu_path):
    """A permanent 20 mm jump of the encoder while SYNCED: encoder_max_outliers outliers in
    a row are a lost master: the tracker de-syncs with MASTER_LOST (error 6), one warning
    names it, master_status reads LOST, then STARTING while the conditioner warms up again,
    then OK; the engage (still high) does not re-engage by itself."""
    from controller.tracking import TrackError, TrackState

    g, m = 500, 4
    rows, ints, status, outliers, messages = _belt(
        fmu_path, 1200, lambda j: 20.0 if j >= g else 0.0,
        {"planner": 0, "encoder_max_outliers": m})
    assert ints[g - 1][1] == TrackState.SYNCED
    assert outliers[g + m - 2] == m - 1 and status[g + m - 2] == 2  # coasting so far
    assert status[g + m - 1] == 3 and ints[g + m - 1][2] == TrackError.MASTER_LOST
    assert ints[g + m - 1][1] == TrackState.DESYNCING
    assert status[g + m] == 0  # the conditioner starts again
    assert status[-1] == 1 and ints[-1][1] == TrackState.OFF
    assert ints[-1][2] == TrackError.MASTER_LOST  # kept until the next engage
    lost = [x for x in messages if x[0] == 1]
    assert len(lost) == 1 and "master lost" in lost[0][2] and "MASTER_LOST" in lost[0][2]
    assert "master_x" in lost[0][2] and "+20" in lost[0][2]


def test_fmu_engage_waits_for_the_warm_up(fmu_path):
    """engage high from the first step: the tracker stays OFF while the conditioner warms
    up (master_status 0, one warning saying why), and engages at the first step after."""
    from controller.fmu.runner import FmuTracker
    from controller.tracking import MotionState, TrackState

    with FmuTracker(fmu_path, start_values={"planner": 0, "sample_time": T, "master_input": 1,
                                            "encoder_resolution": Q}) as fmu:
        assert fmu.get_ints(["master_status"]) == [0]
        states, status = [], []
        for j in range(300):
            fmu.step(MotionState((_quantise(100.0 + 300.0 * j * T, Q), 0.0, 0.0)), True, T)
            states.append(fmu.outputs()[1][1])
            status.append(fmu.get_ints(["master_status"])[0])
        messages = [x for x in fmu.messages if x[0] >= 1]
    first_ok = status.index(1)
    assert first_ok > 5 and set(status[:first_ok]) == {0}
    assert set(states[:first_ok + 1]) == {TrackState.OFF}
    assert states[first_ok + 1] == TrackState.SYNCING and TrackState.SYNCED in states
    assert len(messages) == 1 and "waits" in messages[0][2] and "STARTING" in messages[0][2]


def test_fmu_non_finite_time_offset_is_refused_and_repeatable(fmu_path):
    """A NaN encoder_time_offset with master_input=1: the step is refused (Discard) before
    anything changes, naming the input; with a finite value the same step runs."""
    from fmpy.fmi1 import FMICallException

    from controller.fmu.runner import FmuTracker
    from controller.tracking import MotionState

    with FmuTracker(fmu_path, start_values={"planner": 0, "sample_time": T, "master_input": 1,
                                            "encoder_resolution": Q}) as fmu:
        for j in range(50):
            fmu.step(MotionState((_quantise(300.0 * j * T, Q), 0.0, 0.0)), False, T)
        before = fmu.outputs(), fmu.get_ints(["master_status", "master_outliers"])
        fmu.set({"encoder_time_offset": math.nan})
        with pytest.raises(FMICallException) as exc:
            fmu.step(MotionState((_quantise(300.0 * 50 * T, Q), 0.0, 0.0)), False, T)
        assert exc.value.status == 2
        assert (fmu.outputs(), fmu.get_ints(["master_status", "master_outliers"])) == before
        assert "non-finite encoder_time_offset=nan" in fmu.messages[-1][2]
        fmu.set({"encoder_time_offset": 0.0002})
        fmu.step(MotionState((_quantise(300.0 * 50 * T, Q), 0.0, 0.0)), False, T)
        assert fmu.time == pytest.approx(51 * T)
        assert len([m for m in fmu.messages if m[0] >= 1]) == 1  # the refusal only


def test_fmu_encoder_two_samples_per_step_and_state(fmu2_path):
    """Two samples per communication step: the step's raw positions go to the conditioner
    at its first sample and it coasts over the second (the core written out here gives the
    same numbers); an FMU state saved while SYNCED restores the conditioners too."""
    from controller.fmu.engine import VARIABLES, conditioners, tracker_params
    from controller.fmu.runner import FmuTracker
    from controller.tracking import MotionState, Tracker

    start = {"planner": 0, "sample_time": T, "master_input": 1, "encoder_resolution": Q,
             "encoder_latency": 1}
    values = {**{r[0]: r[4] for r in VARIABLES if r[2] == "parameter"}, **start}
    params = tracker_params(values)
    conds = conditioners(values, params)
    tracker = Tracker(params, MotionState.at())

    def raw(j: int) -> float:
        return _quantise(100.0 + 300.0 * (2 * j - 1) * T, Q)  # one sample old

    ref = []
    for j in range(400):
        if j == 150:  # after the warm-up (else the FMU's engage waits)
            tracker = Tracker(params, tracker.setpoint)
            tracker.engage()
        for i in range(2):
            o = [c.update(raw(j) if i == 0 and a < 3 else (0.0 if i == 0 else None))
                 for a, c in enumerate(conds)]
            out = tracker.update(MotionState((o[0].pos, o[1].pos, o[2].pos),
                                             (o[0].vel, o[1].vel, o[2].vel),
                                             (o[0].acc, o[1].acc, o[2].acc), o[3].pos,
                                             o[3].vel, o[3].acc,
                                             (o[0].jerk, o[1].jerk, o[2].jerk), o[3].jerk))
        sp = out.setpoint
        ref.append([*sp.pos, sp.ang, *sp.vel, sp.ang_vel, *sp.acc, sp.ang_acc])
    with FmuTracker(fmu2_path, start_values=start) as fmu:
        rows = []
        for j in range(400):
            fmu.step(MotionState((raw(j), raw(j), raw(j))), j >= 150, 2 * T)
            rows.append(fmu.outputs()[0])
            if j == 250:
                saved = fmu.get_state()
                data = fmu.serialize_state(saved)
                assert fmu.outputs()[1][1] in (1, 2)  # SYNCING or SYNCED
        assert rows == ref and [m for m in fmu.messages if m[0] >= 1] == []
        assert fmu.outputs()[1][1] == 2  # SYNCED
        assert fmu.get_ints(["master_status"]) == [1]  # after the step's own sample
        for restore in (lambda: saved, lambda: fmu.deserialize_state(data)):
            fmu.set_state(restore())
            fmu.time = 251 * 2 * T
            again = fmu.run(lambda j: (MotionState((raw(j),) * 3), True), 149, 2 * T,
                            first_step=251).reals
            assert again == rows[251:]


# -------------------------------------------------------------- the CAN shell
def _can_config(tmp_path, profile: str, planner: str = "optimal"):
    from controller.canopen.testing import bus_yml_text
    from controller.canopen.config import load_config
    text = bus_yml_text()
    text = text.replace("    estimator: {window: 16, degree: 2}\n",
                        "    conditioning: {jerk_max: 5000}\n")
    text = text.replace("    planner: softmc\n", f"    planner: {planner}\n"
                        "    master_max_trans: {vel: 1000, acc: 1000, jerk: 5000}\n")
    text = text.replace("    profile: [[0, 300]]\n", f"    profile: {profile}\n")
    assert "conditioning" in text and planner in text
    p = tmp_path / "bus.yml"
    p.write_text(text)
    return load_config(p)


def test_can_shell_with_conditioning_equals_the_offline_core(tmp_path):
    """The CAN controller (stepped time, simulated encoder on a belt that speeds up) with
    ``conveyor.conditioning``: the 607Ah values on the bus equal an offline
    MasterConditioner + Tracker fed the raw 6004h values the controller received, bit for
    bit; the tracking is within the sync limits and no outlier is reported."""
    import struct

    from controller.canopen.apps.follow import ConveyorFollow, belt_frame
    from controller.canopen.testing import stepped
    from controller.kinematics import CountsConverter, EncoderScale, create
    from controller.tracking import Limits, MasterEstimate, Tracker

    cfg = _can_config(tmp_path, "[[0, 300], [1.0, 300], [1.6, 600]]")
    tc = cfg.tracking
    T = cfg.period_s
    offset = (420.0, 30.0, 0.0)
    engage, disengage, end = 20, 600, 700
    app = ConveyorFollow(engage, disengage, offset, end_cycle=end)
    world, ctl = stepped(cfg, app, record=True)
    try:
        ctl.boot()
        ctl.run(max_cycles=3000)
        frames = world.recorder.frames
    finally:
        world.close()
    assert ctl.master.conditioner is not None and ctl.master.estimator is None
    assert not [e for e in ctl.events if e.kind in ("master_outlier", "master_lost")]
    sent, group = [], None
    for _, cid, d in frames:
        if cid == 0x80:
            if group is not None and len(group) == 2:
                sent.append((group[0x20B], group[0x20C]))
            group = {}
        elif group is not None and cid in (0x20B, 0x20C):
            group[cid] = struct.unpack("<Hi", d)[1]
    raw = [r.raw for r in ctl.trace]
    assert None not in raw
    start = next(i for i, r in enumerate(ctl.trace) if r.phase == "running")
    scale = EncoderScale(tc.conveyor.counts_per_mm, tc.conveyor.modulus)
    mt = tc.tracker.master_max_trans
    cond = MasterConditioner(ConditioningParams(
        T, EncoderModel(1.0 / tc.conveyor.counts_per_mm, 0), Limits(mt.vel, mt.acc, 5000.0),
        lead_samples=float(1 + tc.drive_delay_cycles)))
    kin = create("cartesian", ["x", "y"])
    conv = CountsConverter([a.scale for a in tc.axes])
    tracker = Tracker(tc.tracker, kin.pose(conv.from_counts(sent[start - 1])))
    offline, states = [], []
    for k, r in enumerate(raw):
        o = cond.update(scale.belt_mm(r), ctl.trace[k].sync_late_us * 1e-6
                        if ctl.trace[k].sync_late_us else 0.0)
        if k < start or ctl.trace[k].phase != "running":
            continue
        n = k - start
        if n == engage:
            tracker.engage()
        if n == disengage:
            tracker.disengage()
        m = belt_frame(tc.conveyor, MasterEstimate(o.pos, o.vel, o.acc, o.jerk), offset)
        out = tracker.update(m)
        states.append(out.state)
        offline.append(conv.to_counts(kin.joints(out.setpoint)))
    on_bus = sent[start:start + len(offline)]
    assert len(on_bus) == len(offline) == end + 1
    assert on_bus == offline
    assert 2 in {int(s) for s in states}  # synchronised (through the speed change)


@pytest.mark.parametrize("permanent", [False, True])
def test_can_shell_glitch_is_an_outlier_and_a_jump_loses_the_master(tmp_path, permanent):
    """A 5 mm one-sample glitch of the encoder while SYNCED: a master_outlier event naming
    its size, the tracker stays SYNCED without error.  A permanent 20 mm jump: max_outliers
    outliers, then master_lost and the de-sync with MASTER_LOST."""
    from controller.canopen.apps.follow import ConveyorFollow
    from controller.canopen.testing import stepped
    from controller.tracking import TrackError, TrackState

    cfg = _can_config(tmp_path, "[[0, 300]]")
    app = ConveyorFollow(20, None, (420.0, 30.0, 0.0), end_cycle=500)
    world, ctl = stepped(cfg, app)
    enc = world.device("encoder")
    size_mm = 20.0 if permanent else 5.0
    glitch = round(size_mm * cfg.tracking.conveyor.counts_per_mm)
    hit = {"n": 0}

    def sample(t_ns, c):  # (c: what the encoder's 6004h reads at SYNC)
        if ctl.source.tracker is not None and ctl.source.tracker.state == TrackState.SYNCED:
            hit["n"] += 1
            if hit["n"] >= 100 and (permanent or hit["n"] == 100):
                c += glitch
        return c

    enc.counts_hook = sample
    try:
        ctl.boot()
        ctl.run(max_cycles=2000)
    finally:
        world.close()
    kinds = [e.kind for e in ctl.events]
    outliers = [e for e in ctl.events if e.kind == "master_outlier"]
    assert outliers
    size = float(outliers[0].detail.split()[2])
    assert size == pytest.approx(size_mm, abs=0.05)
    if permanent:
        assert len(outliers) == cfg.tracking.conveyor.conditioning.max_outliers - 1
        assert "master_lost" in kinds
        assert ctl.source.tracker.error == TrackError.MASTER_LOST
    else:
        assert len(outliers) == 1 and "master_lost" not in kinds
        assert ctl.source.tracker.state == TrackState.SYNCED and ctl.source.tracker.error == TrackError.NONE
