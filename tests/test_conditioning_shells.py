"""The master conditioning through the shells: the simulator's ``conditioning:`` section and
the CAN shell's ``conveyor.conditioning`` run the same core and give bit-identical results
for the same encoder samples."""

from __future__ import annotations


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


# -------------------------------------------------------------- the CAN shell
def _can_config(tmp_path, profile: str, planner: str = "optimal"):
    from controller.canopen.testing import bus_yml_text
    from controller.canopen.config import load_bus_config
    text = bus_yml_text()
    text = text.replace("    estimator: {window: 16, degree: 2}\n",
                        "    conditioning: {jerk_max: 5000}\n")
    text = text.replace("    planner: softmc\n", f"    planner: {planner}\n"
                        "    master_max_trans: {vel: 1000, acc: 1000, jerk: 5000}\n")
    text = text.replace("    profile: [[0, 300]]\n", f"    profile: {profile}\n")
    assert "conditioning" in text and planner in text
    p = tmp_path / "bus.yml"
    p.write_text(text)
    return load_bus_config(p)


def test_can_shell_with_conditioning_equals_the_offline_core(tmp_path):
    """The CAN controller (stepped time, simulated encoder on a belt that speeds up) with
    ``conveyor.conditioning``: the 607Ah values on the bus equal an offline
    MasterConditioner + Tracker fed the raw 6004h values the controller received, bit for
    bit; the tracking is within the sync limits and no outlier is reported."""
    import struct

    from controller.canopen.master.app import ConveyorFollow, belt_frame
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
    from controller.canopen.master.app import ConveyorFollow
    from controller.canopen.testing import stepped
    from controller.tracking import TrackError, TrackState

    cfg = _can_config(tmp_path, "[[0, 300]]")
    app = ConveyorFollow(20, None, (420.0, 30.0, 0.0), end_cycle=500)
    world, ctl = stepped(cfg, app)
    enc = world.device("encoder")
    orig = enc.true_counts  # what the encoder's 6004h reads at SYNC
    size_mm = 20.0 if permanent else 5.0
    glitch = round(size_mm * cfg.tracking.conveyor.counts_per_mm)
    hit = {"n": 0}

    def sample(t_ns):
        c = orig(t_ns)
        if ctl.tracker is not None and ctl.tracker.state == TrackState.SYNCED:
            hit["n"] += 1
            if hit["n"] >= 100 and (permanent or hit["n"] == 100):
                c += glitch
        return c

    enc.true_counts = sample
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
        assert ctl.tracker.error == TrackError.MASTER_LOST
    else:
        assert len(outliers) == 1 and "master_lost" not in kinds
        assert ctl.tracker.state == TrackState.SYNCED and ctl.tracker.error == TrackError.NONE
