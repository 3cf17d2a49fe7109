"""End to end in stepped time: boot, 402 enable, track a belt point, de-sync; the RPDO
setpoints equal an offline Tracker's for the same encoder stream; SYNC, RPDO timing."""

from __future__ import annotations

import struct

import pytest

from controller.canopen.apps.follow import ConveyorFollow
from controller.canopen.master.cycle import Phase
from controller.canopen.protocol import cia402
from controller.canopen.protocol.cia402 import State
from controller.canopen.testing import load, stepped
from controller.kinematics import CountsConverter, EncoderScale, create
from controller.tracking import MasterEstimator, MotionState, Tracker, TrackState

OFFSET = (420.0, 30.0, 0.0)  # the belt point followed (mm, at belt travel 0)
ENGAGE, DISENGAGE, END = 20, 320, 420  # cycles after the start of tracking


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """One recorded run shared by the tests of this module (x, y drives)."""
    cfg = load(tmp_path_factory.mktemp("cycle"))
    app = ConveyorFollow(ENGAGE, DISENGAGE, OFFSET, end_cycle=END)
    world, ctl = stepped(cfg, app, record=True)
    ctl.boot()
    ctl.run(max_cycles=2000)
    yield cfg, world, ctl, app
    world.close()


def _cycles(frames):
    """Frames grouped by cycle: each SYNC (80h) starts a new group."""
    groups: list[list] = []
    for t, cid, data in frames:
        if cid == 0x80:
            groups.append([])
        if groups:
            groups[-1].append((t, cid, data))
    return groups


def test_boot_enable_track_desync(run):
    cfg, world, ctl, app = run
    assert ctl.failure is None
    assert [e.kind for e in ctl.events if e.reaction] == []  # no supervision reaction
    assert [e.kind for e in ctl.events] == ["boot"] * 3 + ["enabled"]
    states = [r.state for r in ctl.trace if r.phase == "running"]
    assert TrackState.SYNCED in states and TrackState.DESYNCING in states
    assert states[-1] == TrackState.OFF
    synced = [r for r in ctl.trace if r.state == TrackState.SYNCED]
    # once synchronised the axes follow the belt point to well under a tenth of a mm
    late = synced[20:]
    assert late and max(r.tracking_error for r in late) < 0.05
    for name in ("x", "y"):
        drive = world.device(name)
        assert [n for n, _, _ in drive.transitions] == [1, 1, 2, 3, 4, 8]  # ... shutdown at end
        assert drive.state is State.READY_TO_SWITCH_ON
    assert ctl.phase is Phase.STOPPED


def test_enable_without_jump(run):
    cfg, world, ctl, app = run
    enabling = [r for r in ctl.trace if r.phase == "enabling"]
    assert 3 <= len(enabling) <= 20
    for r in enabling:  # while enabling, every target is where the drive stands
        assert r.targets == tuple(round(a) for a in
                                  CountsConverter([a.scale for a in cfg.tracking.axes])
                                  .to_counts(r.actual))
    first = next(r for r in ctl.trace if r.phase == "running")
    assert first.targets == (4_000_000, 1_000_000)


def test_sync_counter_and_rpdos_before_the_next_sync(run):
    cfg, world, ctl, app = run
    frames = world.recorder.frames
    counters = [d[0] for _, cid, d in frames if cid == 0x80]
    assert counters[:20] == list(range(1, 17)) + [1, 2, 3, 4]
    period = cfg.period_ns
    sync_t = [t for t, cid, _ in frames if cid == 0x80]
    assert {b - a for a, b in zip(sync_t, sync_t[1:])} == {period}
    for group in _cycles(frames)[:-1]:
        ids = [cid for _, cid, _ in group]
        # SYNC, the TPDOs (encoder 18Ah, drives 18Bh, 18Ch), then the two RPDOs
        assert ids.index(0x20B) > ids.index(0x18A) and ids.index(0x20C) > ids.index(0x18C)
        t_sync = group[0][0]
        assert all(t < t_sync + period for t, cid, _ in group if cid in (0x20B, 0x20C))
    hb = [t for t, cid, _ in frames if cid == 0x701]
    assert {b - a for a, b in zip(hb, hb[1:])} == {50_000_000}


def test_setpoints_equal_the_offline_trackers(run):
    """Identity: the 607Ah values on the bus are the offline Tracker's setpoints, converted
    to counts, for the same encoder stream (raw 6004h values as received)."""
    cfg, world, ctl, app = run
    tc = cfg.tracking
    T = cfg.period_s
    sent = []  # per cycle: (x, y) targets from the RPDO frames
    for group in _cycles(world.recorder.frames):
        tg = {cid: struct.unpack("<Hi", d)[1] for _, cid, d in group if cid in (0x20B, 0x20C)}
        if len(tg) == 2:
            sent.append((tg[0x20B], tg[0x20C]))
    raw = [r.raw for r in ctl.trace]
    assert None not in raw
    start = next(i for i, r in enumerate(ctl.trace) if r.phase == "running")
    scale = EncoderScale(tc.conveyor.counts_per_mm, tc.conveyor.modulus)
    est = MasterEstimator(T, tc.conveyor.window, lead_samples=1 + tc.drive_delay_cycles,
                          degree=tc.conveyor.degree)
    kin = create("cartesian", ["x", "y"])
    conv = CountsConverter([a.scale for a in tc.axes])
    hold = sent[start - 1]
    tracker = Tracker(tc.tracker, kin.pose(conv.from_counts(hold)))
    offline = []
    for k, r in enumerate(raw):
        est.push(scale.belt_mm(r))
        if k < start or ctl.trace[k].phase != "running":
            continue
        n = k - start
        if n == ENGAGE:
            tracker.engage()
        if n == DISENGAGE:
            tracker.disengage()
        e = est.estimate()
        m = MotionState((OFFSET[0] + e.pos, OFFSET[1], OFFSET[2]), (e.vel, 0.0, 0.0),
                        (e.acc, 0.0, 0.0))
        offline.append(conv.to_counts(kin.joints(tracker.update(m).setpoint)))
    on_bus = sent[start:start + len(offline)]
    assert len(on_bus) == len(offline) == END + 1
    assert on_bus == offline
    assert len(set(on_bus)) > 300  # the axes did move


def test_encoder_noise_still_tracks(tmp_path):
    cfg = load(tmp_path)
    app = ConveyorFollow(10, None, OFFSET, end_cycle=350)
    world, ctl = stepped(cfg, app)
    world.device("encoder").noise_counts = 2.0  # +-0.05 mm
    ctl.boot()
    ctl.run(max_cycles=1000)
    synced = [r for r in ctl.trace if r.state == TrackState.SYNCED]
    assert len(synced) > 100
    assert max(r.tracking_error for r in synced[20:]) < 0.5
    assert not [e for e in ctl.events if e.reaction]
    world.close()


def test_statusword_decoding_is_total():
    for sw in range(0x80):
        cia402.decode_statusword(sw)  # never raises
    assert cia402.decode_statusword(0x0237) is State.OPERATION_ENABLED
    assert cia402.decode_statusword(0x0250) is State.SWITCH_ON_DISABLED
    # the look-up table is the CiA 402 table (mask, value per state) for every statusword
    for sw in range(0x10000):
        want = [st for mask, value, st in cia402._DECODE if sw & mask == value]
        assert cia402.decode_statusword(sw) is (want[0] if want else None), hex(sw)

