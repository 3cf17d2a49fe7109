"""Supervision paths, each in stepped time against the simulated devices.

A drive fault, a drive EMCY, a lost heartbeat, the following-error bit, a silent drive and a
setpoint outside an axis limit stop all drives (quick stop); a silent encoder makes the
tracker de-sync on the extrapolated master.  Every reaction is an event with its cycle.
"""

from __future__ import annotations

import math

import pytest

from controller.canopen.master.cycle import EnableError, Phase
from controller.canopen.protocol.cia402 import State
from controller.canopen.testing import bus_yml_text
from controller.tracking import TrackState

OFFSET = (420.0, 30.0, 0.0)
T_FAULT = 0.5  # s (tracking starts at about 0.04 s, SYNCED at about 0.3 s)


@pytest.fixture
def make(booted_follow):
    return booted_follow


def reactions(ctl):
    return [e for e in ctl.events if e.reaction]


def assert_all_stopped(world, ctl, names=("x", "y")):
    assert ctl.phase is Phase.STOPPED
    for name in names:
        d = world.device(name)
        assert d.state in (State.SWITCH_ON_DISABLED, State.FAULT), (name, d.state)
        assert abs(d.v) == 0.0


def first_cycle_after(ctl, t_s):
    """The first cycle whose SYNC comes after simulated time ``t_s``."""
    return math.ceil((t_s * 1e9 - ctl.t0) / ctl.period_ns)


def test_lost_heartbeat_quick_stops_all_drives(make):
    world, ctl = make()
    world.at(T_FAULT, lambda: world.device("y").stop_heartbeat())
    ctl.run(max_cycles=2000)
    first = reactions(ctl)[0]
    assert (first.source, first.kind, first.reaction) == ("node 12 (y)", "heartbeat_lost",
                                                         "quick stop of all drives")
    # last heartbeat <= 0.5 s, time-out 50 ms x 3: lost between 0.6 and 0.66 s after start
    assert 0.6 < first.t_s + ctl.t0 * 1e-9 < 0.7
    assert "time-out 150 ms" in first.detail
    assert_all_stopped(world, ctl)
    assert [n for n, _, _ in world.device("x").transitions][-2:] == [11, 12]


def test_heartbeat_consumer_is_asked_only_when_a_time_out_may_be_due(make):
    """The cycle asks the heartbeat consumer only when a time-out may have passed or a
    heartbeat showed another NMT state (``quiet_until_ns``; before, every cycle): 500
    cycles at 2 ms with heartbeats every 50 ms (time-out 150 ms) ask it some 10 times."""
    world, ctl = make()
    hb = ctl.heartbeats
    asked = []
    check = hb.check
    hb.check = lambda now_ns: asked.append(now_ns) or check(now_ns)
    ctl.run(max_cycles=500)
    assert not reactions(ctl)
    assert 1 <= len(asked) <= 25, len(asked)
    # a heartbeat that shows another state makes the next cycle ask at once
    hb._on_heartbeat(0x700 + 12, bytes((0x7F,)), ctl.clock.now_ns())
    assert hb.quiet_until_ns == -math.inf
    n = len(asked)
    ctl.step()
    assert len(asked) == n + 1
    assert ("node 12 (y)", "nmt_state") in [(e.source, e.kind) for e in ctl.events]


def test_drive_fault_quick_stops_the_others(make):
    world, ctl = make()
    world.at(T_FAULT, lambda: world.device("x").inject_fault(0x2310))
    ctl.run(max_cycles=2000)
    first = reactions(ctl)[0]
    assert first.kind == "emcy" and first.source == "node 11 (x)"
    assert "EMCY 2310h (continuous over-current)" in first.detail
    assert first.cycle == first_cycle_after(ctl, T_FAULT)  # EMCY seen in that cycle
    kinds = {e.kind for e in ctl.events}
    assert "drive_fault" in kinds
    assert world.device("x").state is State.FAULT
    assert world.device("y").state is State.SWITCH_ON_DISABLED
    assert [n for n, _, _ in world.device("y").transitions][-2:] == [11, 12]
    assert_all_stopped(world, ctl)


def test_drive_emcy_without_fault_stops(make):
    world, ctl = make()
    world.at(T_FAULT, lambda: world.device("y").send_emcy(0x4210))
    ctl.run(max_cycles=2000)
    first = reactions(ctl)[0]
    assert (first.kind, first.source) == ("emcy", "node 12 (y)")
    assert "4210h (excess temperature device)" in first.detail
    assert_all_stopped(world, ctl)


def test_encoder_emcy_is_reported_only(make):
    world, ctl = make(end_cycle=400)
    world.at(T_FAULT, lambda: world.device("encoder").send_emcy(0x5000))
    ctl.run(max_cycles=2000)
    ev = [e for e in ctl.events if e.kind == "emcy"]
    assert len(ev) == 1 and ev[0].reaction == "reported"
    assert ctl.phase is Phase.STOPPED and world.device("x").state is State.READY_TO_SWITCH_ON


def test_a_node_that_keeps_sending_emcys_fills_no_memory(make):
    """Issue 12: 1100 EMCYs of the encoder (reported, no stop): the controller's EMCY log
    keeps the newest EmcyMonitor.LOG = 1000, which is what a boot error would name."""
    world, ctl = make(end_cycle=400)
    enc = world.device("encoder")

    def burst():
        for i in range(1100):
            enc.send_emcy(0x5000 + i)
    world.at(T_FAULT, burst)
    ctl.run(max_cycles=2000)
    assert ctl.emcy.LOG == 1000 and len(ctl.emcy.log) == 1000
    assert [e.code for e in ctl.emcy.of_node(enc.node_id)] == [0x5000 + i
                                                                for i in range(100, 1100)]
    assert ctl.phase is Phase.STOPPED and world.device("x").state is State.READY_TO_SWITCH_ON


def test_following_error_bit_stops(make):
    world, ctl = make()
    world.at(T_FAULT, lambda: world.device("x").disturb(200_000))  # 20 mm push
    ctl.run(max_cycles=2000)
    first = reactions(ctl)[0]
    assert (first.kind, first.source) == ("following_error", "node 11 (x)")
    assert "bit 13" in first.detail
    assert_all_stopped(world, ctl)


def test_silent_drive_stops(make):
    world, ctl = make()
    world.at(T_FAULT, lambda: world.device("y").mute_pdos(True))
    ctl.run(max_cycles=2000)
    first = reactions(ctl)[0]
    assert (first.kind, first.source) == ("drive_silent", "node 12 (y)")
    assert first.cycle == first_cycle_after(ctl, T_FAULT) + 4  # 5th cycle without TPDO
    assert world.device("x").state is State.SWITCH_ON_DISABLED


def test_silent_encoder_desyncs_on_the_extrapolated_master(make):
    world, ctl = make(end_cycle=500)
    enc = world.device("encoder")
    world.at(T_FAULT, lambda: enc.mute_pdos(True))
    world.at(T_FAULT + 0.2, lambda: enc.mute_pdos(False))
    ctl.run(max_cycles=2000)
    ev = [e for e in ctl.events if e.kind.startswith("master_")]
    assert [e.kind for e in ev] == ["master_silent", "master_back"]
    assert ev[0].reaction == "de-sync on the extrapolated master"
    assert ev[0].cycle == first_cycle_after(ctl, T_FAULT) + 4
    states = [r.state for r in ctl.trace if r.cycle >= ev[0].cycle]
    assert states[0] == TrackState.DESYNCING and TrackState.OFF in states
    assert not [e for e in ctl.events if e.reaction.startswith("quick stop")]
    # the stop is smooth: the setpoint velocity along x falls monotonically to 0
    xs = [r.setpoint[0] for r in ctl.trace if ev[0].cycle <= r.cycle and r.setpoint]
    v = [(b - a) / ctl.cfg.period_s for a, b in zip(xs, xs[1:])]
    stop = v[: v.index(0.0) + 1] if 0.0 in v else v
    assert 280 < stop[0] < 320 and all(b <= a + 1e-6 for a, b in zip(stop, stop[1:]))
    assert ctl.phase is Phase.STOPPED and world.device("x").state is State.READY_TO_SWITCH_ON


def test_setpoint_outside_the_axis_limit_stops(make):
    text = bus_yml_text().replace("      x: {node: x, counts_per_mm: 10000, zero: 0, min: -100, "
                                  "max: 1500}",
                                  "      x: {node: x, counts_per_mm: 10000, zero: 0, min: -100, "
                                  "max: 520}")
    world, ctl = make(text)
    ctl.run(max_cycles=2000)
    first = reactions(ctl)[0]
    assert first.kind == "limit" and first.source == "node 11 (x)"
    assert "setpoint x = " in first.detail and "outside [-100, 520]" in first.detail
    assert "(a quick stop at 20000 mm/s^2 ends at 520." in first.detail
    assert world.device("x").x <= 5_201_000  # stopped before the limit
    assert_all_stopped(world, ctl)


def test_enable_timeout_names_the_drive(make):
    world, ctl = make()
    world.device("y").set_enable_input(False)  # STO: stays in SWITCH ON DISABLED
    with pytest.raises(EnableError, match=r"node 12 \(y\): could not enable within 0.2 s: "
                                          r"statusword 0240h \(switch on disabled\), last "
                                          r"controlword 0006h"):
        ctl.run(max_cycles=2000)
    assert ctl.phase is Phase.STOPPED
    assert [e.kind for e in ctl.events if e.reaction] == ["enable_timeout"]


def test_event_kinds_are_an_enum_and_an_unknown_kind_is_refused():
    from controller.canopen.master.events import EventKind, EventLog
    log = EventLog()
    e = log.add(3, 0.3, "node 11 (x)", "heartbeat_lost", "no heartbeat", "quick stop")
    assert e.kind is EventKind.HEARTBEAT_LOST
    assert e.as_dict()["kind"] == "heartbeat_lost" and "heartbeat_lost: no heartbeat" in str(e)
    assert log.of_kind(EventKind.HEARTBEAT_LOST) == [e]
    with pytest.raises(ValueError, match="unknown event kind 'heartbeat_lsot'"):
        log.add(3, 0.3, "node 11 (x)", "heartbeat_lsot", "typo")


def test_job_results_are_an_enum():
    from controller.canopen.apps.axis_motion import JobResult, MotionReport
    r = MotionReport("home", "y", ok=True, result="SKIPPED")
    assert r.result is JobResult.SKIPPED and "SKIPPED" in r.summary()
    with pytest.raises(ValueError):
        MotionReport("move", "y", result="ERROR_TYPO")
