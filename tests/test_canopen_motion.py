"""Axis motion on the CANopen controller (issue 7): GotoY / drive / no homing, moves, jog.

Everything runs through the CAN path: the embedded virtual bus, stepped clock, simulated
CiA 402 drives with slow-down, home and limit switches at configured positions (counts;
axis y: 10000 counts/mm, period 2 ms).  Deterministic.
"""

from __future__ import annotations

import itertools
import math
import struct
from pathlib import Path

import pytest
from controller.canopen.apps import axis_motion as am

from controller import cli
from controller.canopen.config import load_config
from controller.canopen.testing import bus_yml_text
from controller.errors import ConfigError

CPM = 10000.0  # counts/mm of axis y
T = 0.002
V, A = 200.0, 2000.0

TPDO2 = """    2:
      enabled: true
      transmission: 1
      mapping:
        - {index: 0x60FD, sub_index: 0}
"""
SWITCHES = ", slow_down: [-100000, 100000], home_switch: [-2000, 2000], negative_limit: -400000"
GOTOY = ("{method: gotoy, search_vel: 50, creep_vel: 10, push_in_counts: 500, back_off: 1.0, "
         "timeout_s: 10}")


def yml_text(*, initial: int = 300000, sim: str = SWITCHES, homing: str = GOTOY,
             motion: str = f"{{vel: {V}, acc: {A}, jerk: 50000}}", di: bool = True,
             x_homing: str | None = None) -> str:
    t = bus_yml_text(("x", "y"))
    if x_homing is not None:
        t = t.replace("      x: {node: x, counts_per_mm: 10000, zero: 0, min: -100, max: 1500}",
                      "      x: {node: x, counts_per_mm: 10000, zero: 0, min: -100, max: 1500,"
                      f" homing: {x_homing}}}")
    if di:
        t = t.replace("        - {index: 0x6064, sub_index: 0}\n",
                      "        - {index: 0x6064, sub_index: 0}\n" + TPDO2)
    t = t.replace("      y: {node: y, counts_per_mm: 10000, zero: 0, min: -100, max: 1500}",
                  "      y: {node: y, counts_per_mm: 10000, zero: 0, min: -100, max: 1500,\n"
                  f"          motion: {motion}, homing: {homing}}}")
    return t.replace("  y: {initial_counts: 1000000, max_velocity: 3.0e7}",
                     f"  y: {{initial_counts: {initial}, max_velocity: 3.0e7{sim}}}")


def cfg_of(tmp_path: Path, **kw):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text(**kw))
    return load_config(p)


def check_stream(r: am.MotionReport, vel: float = V, acc: float = A) -> None:
    """The 607Ah count stream never exceeds the velocity (+1 count of rounding) or the
    acceleration limit (+2 counts) in finite differences."""
    c = r.targets
    assert len(c) > 2
    dv = [b - a for a, b in itertools.pairwise(c)]
    assert max(abs(d) for d in dv) <= math.ceil(CPM * vel * T)
    da = [b - a for a, b in itertools.pairwise(dv)]
    assert max(abs(d) for d in da) <= CPM * acc * T * T + 2


def gotoy_part(r: am.MotionReport) -> am.MotionReport:
    """The report with the 607Ah stream of the GotoY motion only (without the cycles after
    the drive's position was set: those are in the new coordinate)."""
    n = len(r.targets)
    while n > 0 and r.targets[n - 1] == r.set_after_counts:
        n -= 1
    return am.MotionReport(r.kind, r.axis, targets=r.targets[:n])


# -- GotoY through the CAN path ----------------------------------------------------------------
@pytest.mark.parametrize("initial, states", [
    (300000, ["ACCEL", "CONST", "DEACCEL", "SMALL_V", "DOGE", "BACK", "STOP"]),  # no sensor
    (50000, ["SMALL_V", "DOGE", "BACK", "STOP"]),  # slow-down sensor only
    (1000, ["BACK", "SMALL_V", "DOGE", "BACK", "STOP"]),  # both: off the switch and back
])
def test_gotoy_start_conditions(tmp_path, initial, states):
    cfg = cfg_of(tmp_path, initial=initial)
    (r,) = am.home(cfg, "y")
    assert r.ok, r.message
    assert r.result == "FINISHED"
    # GotoY, then the drive's position is set (method 37) and the drive is back in CSP
    assert r.states == states + ["SET_POSITION", "CSP"]
    # exact end position: the drive stands on the last setpoint
    assert r.end_counts == round(r.setpoint_mm * CPM)
    # the position now is the homed coordinate (home = home_offset = 0)
    assert r.home_offset_mm == 0.0
    assert r.latched_mm is not None
    # latched near the home switch edge (0.2 mm) at the creep speed, from every start (on
    # the switch, 0.1 mm, it backs off and re-approaches: the start is not home)
    assert abs(r.latched_mm - 0.2) < 0.1
    assert r.set_after_counts == r.end_counts == round((r.set_before_mm - r.latched_mm) * CPM)
    # BACK ends back_off (1 mm) against the homing direction from the DOGE end, which is
    # beyond the latch by the push-in (0.05 mm) plus the creep stop
    assert 1.0 - 0.2 < r.homed_end_mm < 1.0 - 500 / CPM
    check_stream(gotoy_part(r))
    assert r.inputs and any(i & am.DI_HOME for i in r.inputs)


def test_gotoy_timeout(tmp_path):
    cfg = cfg_of(tmp_path, sim="", homing="{method: gotoy, search_vel: 50, creep_vel: 10, "
                                           "timeout_s: 0.5}")
    (r,) = am.home(cfg, "y")
    assert not r.ok
    assert r.result == "ERROR_TIMEOUT"
    assert r.states == ["ACCEL", "CONST", "ABORT", "STOP"]
    assert r.end_counts == r.targets[-1]  # stopped jerk-limited, at rest
    check_stream(r)


def test_gotoy_limit_switch_abort(tmp_path):
    # slow-down dog but no home switch: the creep runs into the negative limit switch
    cfg = cfg_of(tmp_path, initial=50000,
                 sim=", slow_down: [-100000, 100000], negative_limit: -20000")
    (r,) = am.home(cfg, "y")
    assert not r.ok
    assert r.result == "ERROR_LIMIT_SWITCH"
    assert "limit" in r.message.lower()
    assert "ABORT" in r.states
    assert r.end_mm >= -2.5  # stopped right after the switch (-2 mm)


def test_gotoy_needs_60fd_mapping(tmp_path):
    cfg = cfg_of(tmp_path, di=False)
    with pytest.raises(am.MotionError, match="60FDh"):
        am.home(cfg, "y")


# -- the drive's homing mode -------------------------------------------------------------------
def _device(holder):
    def setup(world):
        holder.append(world.device("y"))
    return setup


def test_drive_homing_success(tmp_path):
    cfg = cfg_of(tmp_path, homing="{method: drive, drive_method: 21, switch_vel: 20, "
                                   "timeout_s: 5, home_offset: 2}")
    devs = []
    (r,) = am.home(cfg, "y", setup=_device(devs))
    assert r.ok, r.message
    assert r.states == ["SETUP", "HOMING", "ATTAINED", "CSP"]
    assert r.end_counts == 20000  # 607Ch: the home switch edge reads 2 mm
    dev = devs[0]
    assert int(dev.load(0x6061, 0)) == 8  # back in CSP
    assert int(dev.load(0x6098, 0)) == 21
    assert int(dev.load(0x6099, 1)) == 200000
    # the home switch is where it physically was: 2 mm -> edge at 2000 counts physical
    assert dev.homing_status is None


def test_drive_homing_timeout(tmp_path):
    cfg = cfg_of(tmp_path, homing="{method: drive, drive_method: 21, switch_vel: 20, "
                                   "timeout_s: 0.5}")
    devs = []
    (r,) = am.home(cfg, "y", setup=_device(devs))
    assert not r.ok
    assert r.result == "ERROR_TIMEOUT"
    assert "0.5 s" in r.message
    assert r.states[-1] == "CSP"
    assert int(devs[0].load(0x6061, 0)) == 8
    assert 19.0 < r.end_mm < 21.0  # 0.5 s at 20 mm/s from 30 mm, then stopped


def test_drive_homing_error_bit13(tmp_path):
    # searching negative for the home switch, the negative limit switch comes first
    cfg = cfg_of(tmp_path, sim=", negative_limit: 250000",
                 homing="{method: drive, drive_method: 21, switch_vel: 20, timeout_s: 5}")
    (r,) = am.home(cfg, "y")
    assert not r.ok
    assert r.result == "ERROR_HOMING" and "bit 13" in r.message


def test_drive_homing_current_position_and_none(tmp_path):
    cfg = cfg_of(tmp_path, homing="{method: drive, drive_method: 35, timeout_s: 1}")
    (r,) = am.home(cfg, "y")
    assert r.ok and r.end_counts == 0
    cfg = cfg_of(tmp_path, homing="{method: none, home_offset: 3}")
    (r,) = am.home(cfg, "y")
    assert r.ok and r.home_offset_mm == 3.0 and r.end_mm == 30.0 and r.cycles == 1


def test_drive_homing_limit_switch_method(tmp_path):
    # method 17: the negative limit switch (at 25 mm) is home; 607Ch = 0
    cfg = cfg_of(tmp_path, sim=", negative_limit: 250000",
                 homing="{method: drive, drive_method: 17, switch_vel: 20, timeout_s: 5}")
    (r,) = am.home(cfg, "y")
    assert r.ok, r.message
    assert r.end_counts == 0
    assert 0.2 < r.time_s < 0.35  # 5 mm at 20 mm/s


def test_home_several_axes_in_one_session(tmp_path):
    cfg = cfg_of(tmp_path, x_homing="{method: drive, drive_method: 35, timeout_s: 1}")
    reports = am.home(cfg)  # every axis with a homing: section, in order: x, y
    assert [(r.axis, r.ok) for r in reports] == [("x", True), ("y", True)]
    assert reports[0].end_counts == 0  # x stays homed while y homes
    assert reports[1].states[-1] == "CSP"  # GotoY, then its position set
    # a failure ends the session: y is not homed after x failed
    cfg = cfg_of(tmp_path, x_homing="{method: drive, drive_method: 21, switch_vel: 20, "
                                    "timeout_s: 0.1}")
    reports = am.home(cfg, ["x", "y"])
    assert [(r.axis, r.result) for r in reports] == [("x", "ERROR_TIMEOUT")]


def test_homing_config_errors(tmp_path):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text(homing="{method: magic}"))
    with pytest.raises(ConfigError, match="method"):
        load_config(p)
    p.write_text(yml_text(homing="{method: drive, drive_method: 16}"))
    with pytest.raises(ConfigError, match="reserved"):
        load_config(p)
    p.write_text(yml_text(homing="{method: gotoy, search_vel: 500}"))
    with pytest.raises(ConfigError, match="search_vel"):
        load_config(p)


# -- moves -------------------------------------------------------------------------------------
@pytest.mark.parametrize("target", [80.0, 30.5, 12.3456])
def test_move_exact_end_and_limits(tmp_path, target):
    cfg = cfg_of(tmp_path)
    r = am.move(cfg, "y", target)
    assert r.ok and r.result == "FINISHED"
    assert r.setpoint_mm == target
    assert r.end_counts == round(target * CPM)
    assert r.targets[-1] == round(target * CPM)
    check_stream(r)


def test_move_brake_timing(tmp_path):
    cfg = cfg_of(tmp_path, motion=f"{{vel: {V}, acc: {A}, jerk: 50000, brake_release_s: 0.02, "
                                  "brake_engage_s: 0.03, stop_time_s: 0.01}")
    r = am.move(cfg, "y", 40.0)
    assert r.ok
    assert r.states == ["BRAKE_RELEASE", "ACCEL", "DECEL", "BRAKE_ENGAGE", "WAIT", "READY"]
    assert r.targets[:10] == [300000] * 10  # no motion before the release time (10 cycles)
    assert r.targets[10] == 300000 or r.targets[11] > 300000
    tail = r.targets[-21:]  # engage 15 + wait 5 cycles at rest on the target, then READY
    assert tail == [400000] * 21
    check_stream(r)


def test_move_retarget_midway(tmp_path):
    cfg = cfg_of(tmp_path)
    seen = []

    def on_cycle(ctl, rec):
        job = ctl.job
        if job.started and not seen and len(job.report.targets) == 60:
            seen.append(ctl.io.target)
            job.set_target(45.0)  # while moving towards 100 mm

    r = am.move(cfg, "y", 100.0, on_cycle=on_cycle)
    assert seen and 300000 < seen[0] < 1000000
    assert r.ok and r.setpoint_mm == 45.0 and r.end_counts == 450000
    assert max(r.targets) <= 1000000
    check_stream(r)


def test_move_outside_axis_limits(tmp_path):
    cfg = cfg_of(tmp_path)
    with pytest.raises(am.MotionError, match="outside the axis limits"):
        am.move(cfg, "y", 2000.0)
    with pytest.raises(am.MotionError, match="no axis"):
        am.move(cfg, "q", 1.0)


# -- jog ---------------------------------------------------------------------------------------
def test_jog_start_stop(tmp_path):
    cfg = cfg_of(tmp_path)
    r = am.jog(cfg, "y", -20.0, 0.5)
    assert r.ok and r.states == ["ACCEL", "CONST", "DECEL", "READY"]
    # symmetric jerk-limited start and stop: 20 mm/s for 0.5 s
    assert r.end_mm == pytest.approx(20.0, abs=1e-3)
    assert r.end_counts == r.targets[-1]
    check_stream(r, vel=20.0)


def test_jog_limit_switch_abort(tmp_path):
    cfg = cfg_of(tmp_path)
    r = am.jog(cfg, "y", -200.0, 5.0)
    assert not r.ok and r.result == "ERROR_LIMIT_SWITCH"
    assert "negative limit switch" in r.message
    assert -41.0 < r.end_mm < -40.0


def test_jog_stops_before_axis_min(tmp_path):
    cfg = cfg_of(tmp_path, sim="")
    r = am.jog(cfg, "y", -200.0, 5.0)
    assert r.ok and "axis limit" in r.message
    assert -100.0 <= min(t / CPM for t in r.targets)
    check_stream(r)


# -- command line ------------------------------------------------------------------------------
def test_cli_commands(tmp_path, capsys):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text())
    assert cli.main(["move", str(p), "--axis", "y", "--to", "35", "-q"]) == 0
    out = capsys.readouterr().out
    assert "move y: OK (FINISHED)" in out and "350000 counts" in out
    assert cli.main(["jog", str(p), "--axis", "y", "--speed", "10", "--time", "0.1", "-q"]) == 0
    assert cli.main(["home", str(p), "-q"]) == 0
    out = capsys.readouterr().out
    assert "home y: OK" in out and "DOGE" in out
    p.write_text(yml_text(sim=""))
    p2 = tmp_path / "b2.yml"
    p2.write_text(yml_text(sim="", homing="{method: gotoy, search_vel: 50, creep_vel: 10, "
                                           "timeout_s: 0.2}"))
    assert cli.main(["home", str(p2), "--axis", "y", "-q"]) == 1
    assert "ERROR_TIMEOUT" in capsys.readouterr().out


# -- the home offset set at the end of GotoY ---------------------------------------------------
def _physical(dev) -> int:
    """Where the simulated drive physically stands [counts] (its switches' coordinate)."""
    return round(dev.x - dev._home_shift)


@pytest.mark.parametrize("initial, offset", [(300000, 0.0), (50000, 2.5), (1000, -1.25)])
def test_gotoy_sets_the_drive_position(tmp_path, initial, offset):
    cfg = cfg_of(tmp_path, initial=initial,
                 homing=GOTOY.replace("}", f", home_offset: {offset}}}"))
    devs = []
    (r,) = am.home(cfg, "y", setup=_device(devs))
    assert r.ok, r.message
    dev = devs[0]
    # the latched home reads the home offset: 6064h = offset + distance from home [counts]
    distance = r.set_before_mm - r.latched_mm
    assert int(dev.load(0x6064, 0)) == round((offset + distance) * CPM) == r.set_after_counts
    assert r.end_counts == r.set_after_counts
    assert r.set_after_mm == pytest.approx(offset + distance, abs=1 / CPM)
    assert int(dev.load(0x6061, 0)) == 8 and int(dev.load(0x607A, 0)) == r.set_after_counts
    assert int(dev.load(0x6098, 0)) == 37
    assert int(dev.load(0x607C, 0)) == r.set_after_counts
    # the drive did not move for the set: it still stands where 6064h read before
    assert _physical(dev) == r.set_before_counts
    assert r.homed_end_mm == r.end_mm
    out = r.summary()
    assert "position set:" in out and f"{r.set_after_counts} counts" in out


@pytest.mark.parametrize("offset", [0.0, 2.5])
def test_move_to_home_after_gotoy_same_session(tmp_path, offset):
    # the simulated devices live as long as the session: home, then move in the same one
    from controller.canopen.slave.world import SimWorld
    cfg = cfg_of(tmp_path, homing=GOTOY.replace("}", f", home_offset: {offset}}}"))
    ax = am.axis_config(cfg, "y")
    with SimWorld(cfg) as world:
        dev = world.device("y")
        jobs = [am.GotoYJob(ax, cfg.period_s), am.MoveJob(ax, cfg.period_s, offset)]
        ctl = am.MotionController(cfg, world.transport, jobs)
        home, mv = am.run_jobs(ctl)
        assert home.ok and mv.ok, (home.message, mv.message)
        # the move starts where homing ended (new coordinate) and ends on the home offset
        assert mv.start_mm == home.set_after_mm == home.setpoint_mm
        assert mv.end_counts == mv.targets[-1] == round(offset * CPM)
        check_stream(mv)
        # physically at the latched home: near the home switch edge (2000 counts, passed at
        # the creep speed in the homing direction)
        assert abs(_physical(dev) - home.latched_mm * CPM) <= 1
        assert 2000 - 1000 < _physical(dev) <= 2000
        assert int(dev.load(0x60FD, 0)) & am.DI_HOME


def test_gotoy_set_position_error(tmp_path, monkeypatch):
    # the drive refuses the set (method 1 is not simulated: homing error, bit 13): the job
    # fails with a clear error, back in CSP; the latched position is still reported
    monkeypatch.setattr(am.GotoYJob, "SET_METHOD", 1)
    cfg = cfg_of(tmp_path, initial=50000)
    devs = []
    (r,) = am.home(cfg, "y", setup=_device(devs))
    assert not r.ok
    assert r.result == "ERROR_SET_POSITION" and "bit 13" in r.message
    assert r.states[-2:] == ["SET_POSITION", "CSP"]
    assert int(devs[0].load(0x6061, 0)) == 8
    assert r.latched_mm is not None and r.home_offset_mm == r.latched_mm
    assert r.set_after_counts == r.set_before_counts  # not moved, not set


# -- --max-time: a controlled stop, not a quick stop (audit gap 1) -----------------------------
def _session(cfg, jobs, max_time_s):
    """Run ``jobs`` on the simulated devices; (reports, controller)."""
    from controller.canopen.slave.world import SimWorld
    with SimWorld(cfg) as world:
        ctl = am.MotionController(cfg, world.transport, jobs)
        return am.run_jobs(ctl, max_time_s), ctl


def _reactions(ctl) -> list[str]:
    """Events the controller reacted to (quick stop, ...): none after a controlled stop."""
    return [str(e) for e in ctl.events if e.reaction]


def _at_rest_on_last_setpoint(r: am.MotionReport) -> None:
    # the setpoint stream came to rest (jerk-limited: the last steps are tiny)
    assert abs(r.targets[-1] - r.targets[-2]) <= 10
    assert r.end_counts == r.targets[-1]  # and the drive stands on it (no following error)
    assert r.setpoint_mm == pytest.approx(r.end_mm, abs=1 / CPM)


def test_move_max_time_stops_jerk_limited(tmp_path):
    cfg = cfg_of(tmp_path)
    ax = am.axis_config(cfg, "y")
    # 30 -> 1000 mm takes > 5 s at 200 mm/s: cut off at 1 s (at full speed)
    (r,), ctl = _session(cfg, [am.MoveJob(ax, cfg.period_s, 1000.0)], 1.0)
    assert not r.ok and r.result == "ERROR_TIMEOUT"
    assert "not done within 1 s" in r.message and "stopped (jerk-limited) at" in r.message
    assert f"{r.end_mm:.4f}" in r.message  # says where it stopped
    assert r.states[-2:] == ["DECEL", "READY"]
    assert _reactions(ctl) == []  # no following error, no quick stop
    _at_rest_on_last_setpoint(r)
    assert 40.0 < r.end_mm < 1000.0
    check_stream(r)  # the stop keeps the acceleration limit (no jump of the setpoint)
    assert ctl.phase.name == "STOPPED"  # and then the drives were disabled


def test_move_max_time_cli(tmp_path, capsys):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text())
    assert cli.main(["move", str(p), "--axis", "y", "--to", "1000", "--max-time", "1",
                     "-q"]) == 1
    out = capsys.readouterr()
    assert "move y: FAILED (ERROR_TIMEOUT): not done within 1 s: stopped (jerk-limited) at" \
        in out.out
    assert "following_error" not in out.err and "quick stop" not in out.err


def test_jog_max_time_stops_jerk_limited(tmp_path):
    cfg = cfg_of(tmp_path)
    ax = am.axis_config(cfg, "y")
    (r,), ctl = _session(cfg, [am.JogJob(ax, cfg.period_s, 100.0, 3.0)], 1.0)
    assert not r.ok and r.result == "ERROR_TIMEOUT" and "stopped" in r.message
    assert _reactions(ctl) == []
    _at_rest_on_last_setpoint(r)
    check_stream(r, vel=100.0)


def test_max_time_during_brake_release(tmp_path):
    # time is up while the brake opens: no motion at all, the brake engages again
    cfg = cfg_of(tmp_path, motion=f"{{vel: {V}, acc: {A}, jerk: 50000, brake_release_s: 0.5, "
                                  "brake_engage_s: 0.03}")
    ax = am.axis_config(cfg, "y")
    (r,), ctl = _session(cfg, [am.MoveJob(ax, cfg.period_s, 100.0)], 0.4)
    assert r.result == "ERROR_TIMEOUT" and _reactions(ctl) == []
    assert set(r.targets) == {300000} and r.end_counts == 300000
    assert r.states[:1] == ["BRAKE_RELEASE"] and r.states[-1] == "READY"


def test_max_time_while_enabling(tmp_path):
    cfg = cfg_of(tmp_path)
    r = am.move(cfg, "y", 50.0, max_time_s=0.004)  # before the drives are enabled
    assert not r.ok and r.result == "ERROR_TIMEOUT" and r.targets == []


def test_max_time_gotoy_and_drive_homing_of_several_axes(tmp_path):
    # x: the drive's "current position" homing (at once); y: GotoY, cut off while searching
    cfg = cfg_of(tmp_path, sim="", x_homing="{method: drive, drive_method: 35, timeout_s: 1}")
    reports, ctl = _session(
        cfg, [am.make_home_job(am.axis_config(cfg, n), cfg.period_s) for n in ("x", "y")], 1.0)
    x, y = reports
    assert x.ok and not y.ok and y.result == "ERROR_TIMEOUT" and "stopped" in y.message
    assert "ABORT" in y.states and y.states[-1] == "STOP"
    assert _reactions(ctl) == []
    _at_rest_on_last_setpoint(y)
    check_stream(y)
    # time up while x runs the drive's homing: interrupted, back in CSP; y does not run
    cfg = cfg_of(tmp_path, x_homing="{method: drive, drive_method: 21, switch_vel: 20, "
                                    "timeout_s: 5}")
    reports, ctl = _session(
        cfg, [am.make_home_job(am.axis_config(cfg, n), cfg.period_s) for n in ("x", "y")], 0.5)
    assert [(r.axis, r.result) for r in reports] == [("x", "ERROR_TIMEOUT")]
    assert _reactions(ctl) == []
    assert reports[0].states[-1] == "CSP"  # the drive's homing interrupted, back in CSP


def test_max_time_drive_homing(tmp_path):
    cfg = cfg_of(tmp_path, homing="{method: drive, drive_method: 21, switch_vel: 20, "
                                   "timeout_s: 5}")
    devs = []
    (r,) = am.home(cfg, "y", setup=_device(devs), max_time_s=0.6)
    assert not r.ok and r.result == "ERROR_TIMEOUT" and "0.6 s" in r.message
    assert "interrupted" in r.message and f"stopped at {r.end_mm:.4f} mm" in r.message
    assert r.states[-1] == "CSP" and int(devs[0].load(0x6061, 0)) == 8
    assert 15.0 < r.end_mm < 29.0 and r.end_counts == r.targets[-1]


def test_stop_between_jobs_next_not_started(tmp_path):
    # the stop is requested right after x is done: y does not start, and its report says so
    from controller.canopen.slave.world import SimWorld
    cfg = cfg_of(tmp_path, x_homing="{method: drive, drive_method: 35, timeout_s: 1}")

    def on_cycle(ctl, rec):
        if ctl.index == 0 and ctl.job.done and ctl.stop_reason is None:
            ctl.request_stop("ERROR_TIMEOUT", "time is up")

    with SimWorld(cfg) as world:
        jobs = [am.make_home_job(am.axis_config(cfg, n), cfg.period_s) for n in ("x", "y")]
        ctl = am.MotionController(cfg, world.transport, jobs, on_cycle=on_cycle)
        x, y = am.run_jobs(ctl)
    assert x.ok
    assert (y.ok, y.result, y.message) == (False, "ERROR_TIMEOUT", "time is up: not started")
    assert y.targets == [] and y.states == [] and _reactions(ctl) == []
    assert "not started" in y.summary()


@pytest.mark.parametrize("value", ["nan", "0", "-1", "inf"])
def test_cli_max_time_must_be_positive(tmp_path, capsys, value):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text())
    assert cli.main(["move", str(p), "--axis", "y", "--to", "35", "-q",
                     f"--max-time={value}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"cantrack: error: --max-time {float(value):g}: must be a finite number " \
                  "of seconds > 0"
    with pytest.raises(am.MotionError, match="finite number of seconds > 0"):
        am.move(load_config(p), "y", 35.0, max_time_s=float(value))


# -- homing needs a homing: section (audit gap 2) ----------------------------------------------
def test_home_axis_without_homing_section(tmp_path, capsys):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text())  # x has no homing: section
    cfg = load_config(p)
    node = cfg.slaves["x"].node_id
    msg = f"axis x (node {node}) has no homing: section in {p}"
    with pytest.raises(am.MotionError) as exc:
        am.home(cfg, "x")
    assert str(exc.value) == msg
    with pytest.raises(am.MotionError, match="has no homing: section"):
        am.home(cfg, ["y", "x"])  # before anything moves: y is not homed either
    with pytest.raises(am.MotionError, match="has no homing: section"):
        am.make_home_job(am.axis_config(cfg, "x"), cfg.period_s)
    assert cli.main(["home", str(p), "--axis", "x", "-q"]) == 2
    assert capsys.readouterr().err.strip() == f"cantrack: error: {msg}"


def test_home_all_skips_axes_without_homing(tmp_path, capsys):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text())
    reports = am.home(load_config(p))
    assert [(r.axis, r.ok, r.result) for r in reports] == [("y", True, "FINISHED"),
                                                          ("x", True, "SKIPPED")]
    assert reports[1].targets == [] and "no homing: section" in reports[1].message
    assert cli.main(["home", str(p), "-q"]) == 0
    out = capsys.readouterr().out
    assert f"home x: SKIPPED: not homed: no homing: section in {p}" in out
    p.write_text(yml_text().replace(f", homing: {GOTOY}", ""))
    with pytest.raises(am.MotionError, match="no axis has a homing: section"):
        am.home(load_config(p))


# -- the progress display (audit gap 3) --------------------------------------------------------
def test_cli_progress_shows_setpoint_and_target(tmp_path, capsys):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text())
    assert cli.main(["move", str(p), "--axis", "y", "--to", "35"]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("move y:")]
    assert lines
    for ln in lines:
        assert "setpoint" in ln and ln.endswith("target    35.0000")
    assert cli.main(["jog", str(p), "--axis", "y", "--speed", "-10", "--time", "1"]) == 0
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("jog y:")]
    assert lines and all("setpoint" in ln and ln.endswith("speed -10") for ln in lines)


# -- a limit switch: the setpoint stream stops where the drive stopped (audit gap 4) -----------
@pytest.mark.parametrize("speed", [-50.0, -100.0, -200.0])
def test_limit_switch_setpoint_ends_at_actual(tmp_path, speed):
    # the negative limit switch at 25 mm; the drive refuses to move into it and stops there
    cfg = cfg_of(tmp_path, sim=", negative_limit: 250000")
    r = am.jog(cfg, "y", speed, 5.0)
    assert r.result == "ERROR_LIMIT_SWITCH"
    assert 24.5 < r.end_mm <= 25.0
    # the last setpoint sent (with the quick stop) and reported is where the drive stands
    assert r.targets[-1] == r.end_counts
    assert abs(r.setpoint_mm - r.end_mm) <= 1 / CPM
    r = am.move(cfg, "y", 0.0)
    assert r.result == "ERROR_LIMIT_SWITCH" and r.targets[-1] == r.end_counts
    assert abs(r.setpoint_mm - r.end_mm) <= 1 / CPM


def test_gotoy_limit_switch_holds_at_actual(tmp_path):
    cfg = cfg_of(tmp_path, initial=50000,
                 sim=", slow_down: [-100000, 100000], negative_limit: -20000")
    (r,) = am.home(cfg, "y")
    assert r.result == "ERROR_LIMIT_SWITCH"
    assert r.targets[-1] == r.end_counts  # held where the drive stopped at the switch
    assert abs(r.setpoint_mm - r.end_mm) <= 1 / CPM


# -- GotoY with the drive's touch probe (homing.touch_probe) -----------------------------------
PROBE_SIM = SWITCHES + ", probe_input: home"  # the home switch also wired to the probe input
SWITCH_EDGE = 2000  # counts: the home switch [-2000, 2000] becomes active here (homing -1)


#: the probe's status and value in an event-driven TPDO (sent on change, inhibit 1 ms)
PROBE_TPDO = """    3:
      enabled: true
      transmission: 255
      inhibit_time: 10
      mapping:
        - {index: 0x60B9, sub_index: 0}
        - {index: 0x60BA, sub_index: 0}
"""


def _home_y(tmp_path, *, touch_probe: bool, initial: int = 300000, offset: float = 0.0,
            sim: str = PROBE_SIM, record: bool = False, probe_tpdo: bool = False):
    """Home y in a session of its own: (report, drive, recorded frames)."""
    from controller.canopen.slave.world import SimWorld
    homing = GOTOY.replace("}", f", home_offset: {offset}, "
                                f"touch_probe: {'true' if touch_probe else 'false'}}}")
    text = yml_text(initial=initial, homing=homing, sim=sim)
    if probe_tpdo:
        text = text.replace(TPDO2, TPDO2 + PROBE_TPDO)
    p = tmp_path / "bus.yml"
    p.write_text(text)
    cfg = load_config(p)
    with SimWorld(cfg, record=record) as world:
        ctl = am.MotionController(cfg, world.transport, [am.GotoYJob(am.axis_config(cfg, "y"),
                                                                     cfg.period_s)])
        (r,) = am.run_jobs(ctl)
        frames = world.recorder.frames if record else []
        return r, world.device("y"), frames


def _switch_error_counts(dev, offset: float) -> float:
    """Where the physical switch edge reads now, minus where it should (home offset)."""
    return SWITCH_EDGE + dev._home_shift - offset * CPM


@pytest.mark.parametrize("initial, offset", [(300000, 0.0), (50000, 2.5)])
def test_gotoy_touch_probe_latches_the_switch_edge(tmp_path, initial, offset):
    # without the probe: the sensor latch is the setpoint of the sample in which 60FDh bit 2
    # was read -- late by the drive's delay at the creep speed (10 mm/s * 2 ms = 200 counts
    # per sample): ~0.03-0.04 mm
    r0, dev0, _ = _home_y(tmp_path, touch_probe=False, initial=initial, offset=offset)
    assert r0.ok, r0.message
    assert r0.latch_source == "sensor" and r0.probe_latched_mm is None
    sensor_error = _switch_error_counts(dev0, offset)
    assert 200 < abs(sensor_error) < 600
    assert r0.latched_mm * CPM - SWITCH_EDGE == pytest.approx(-abs(sensor_error), abs=1)
    # with it: the drive's latch of 6064h at the edge (60BAh); home within 1 count
    r, dev, _ = _home_y(tmp_path, touch_probe=True, initial=initial, offset=offset)
    assert r.ok, r.message
    assert r.states[0] == "ARM_PROBE" and r.states[-3:] == ["STOP", "SET_POSITION", "CSP"]
    assert r.latch_source == "touch probe"
    assert abs(_switch_error_counts(dev, offset)) <= 1
    assert r.probe_latched_counts == SWITCH_EDGE
    assert r.latched_mm == r.probe_latched_mm == SWITCH_EDGE / CPM
    # the sensor latch is the same as without the probe (same motion), the difference is
    # reported in mm and counts
    assert r.sensor_latched_mm == r0.sensor_latched_mm == r0.latched_mm
    assert r.latch_difference_mm == pytest.approx(r.probe_latched_mm - r.sensor_latched_mm)
    assert r.latch_difference_counts == round(r.latch_difference_mm * CPM)
    assert abs(r.latch_difference_counts - abs(sensor_error)) <= 1
    # the set position makes the latched edge read the home offset, as before
    assert r.set_after_counts == round((offset + r.set_before_mm - r.latched_mm) * CPM)
    out = r.summary()
    assert "latch:    touch probe 0.2000 mm (60BAh 2000 counts); sensor" in out
    assert f"({r.latch_difference_counts:+d} counts)" in out
    check_stream(gotoy_part(r))


def test_gotoy_touch_probe_sdos_on_the_bus(tmp_path):
    r, _, frames = _home_y(tmp_path, touch_probe=True, record=True)
    assert r.ok, r.message
    node = 12  # y
    # frames in bus order, by index (the stepped clock gives SDOs no duration)
    requests = [(i, struct.unpack_from("<BHB", d), d) for i, (_, c, d) in enumerate(frames)
                if c == 0x600 + node]
    probe = [(i, cmd, index, d) for i, (cmd, index, sub), d in requests
             if index in (0x60B8, 0x60B9, 0x60BA)]
    # arm: 60B8h = 0 (clears), = 0011h (enable, single shot, positive edge, probe input),
    # check 60B9h; after DNP: read 60B9h and 60BAh -- 5 requests, in this order
    assert [(cmd, index) for _, cmd, index, _ in probe] == [
        (0x2B, 0x60B8), (0x2B, 0x60B8), (0x40, 0x60B9), (0x40, 0x60B9), (0x40, 0x60BA)]
    assert struct.unpack_from("<H", probe[0][3], 4)[0] == 0x0000
    assert struct.unpack_from("<H", probe[1][3], 4)[0] == 0x0011
    # the answers: armed (0001h), then stored (0003h) with 2000 counts
    responses = [d for _, c, d in frames if c == 0x580 + node]
    assert b"\x4b\xb9\x60\x00\x01\x00\x00\x00" in responses
    assert b"\x4b\xb9\x60\x00\x03\x00\x00\x00" in responses
    assert b"\x43\xba\x60\x00" + struct.pack("<i", SWITCH_EDGE) in responses
    # armed before the axis moves (607Ah in RPDO1 still the start), read once 60FDh bit 2
    # has been sent, while the push-in runs (607Ah still changing afterwards)
    rpdo = [(i, struct.unpack_from("<Hi", d)[1]) for i, (_, c, d) in enumerate(frames)
            if c == 0x200 + node]
    first_move = next(i for i, target in rpdo if target != rpdo[0][1])
    assert probe[2][0] < first_move
    home_seen = next(i for i, (_, c, d) in enumerate(frames)
                     if c == 0x280 + node and struct.unpack_from("<I", d)[0] & am.DI_HOME)
    assert home_seen < probe[3][0] < probe[4][0]
    later = [target for i, target in rpdo if i > probe[4][0]]
    assert len(set(later[:10])) > 1  # still moving (push-in / back-off) after the read


def test_gotoy_touch_probe_never_latches_is_an_error(tmp_path):
    # touch_probe: true, but the switch is not wired to the probe input: no edge stored
    r, dev, _ = _home_y(tmp_path, touch_probe=True, initial=50000, sim=SWITCHES)
    assert not r.ok
    assert r.result == "ERROR_SENSOR"
    assert "60B9h = 0001h, bit 1 clear" in r.message and "touch-probe-1 input" in r.message
    assert "stopped (jerk-limited)" in r.message
    assert r.states == ["ARM_PROBE", "SMALL_V", "DOGE", "ABORT", "STOP"]  # no position set
    assert r.latch_source is None and r.probe_latched_mm is None
    assert r.set_after_counts is None
    assert r.end_counts == r.targets[-1]  # at rest on the last setpoint
    assert int(dev.load(0x6061, 0)) == 8  # still CSP
    check_stream(r)


def test_gotoy_touch_probe_starting_on_the_switch_backs_off_and_latches_the_edge(tmp_path):
    # on both sensors at the start: GotoY backs off the switch and re-approaches it, so the
    # probe (armed on the active input) latches the re-approach's positive edge: home is the
    # switch edge to the count, not the start position
    r, dev, _ = _home_y(tmp_path, touch_probe=True, initial=1000)
    assert r.ok, r.message
    assert r.states[:5] == ["ARM_PROBE", "BACK", "SMALL_V", "DOGE", "BACK"]
    assert r.latch_source == "touch probe"
    assert abs(_switch_error_counts(dev, 0.0)) <= 1
    # without the probe: the sensor latch, late by the drive's delay as from any start
    # (it was the start position before: 1000 counts inside the switch)
    r0, dev0, _ = _home_y(tmp_path, touch_probe=False, initial=1000)
    assert r0.ok, r0.message
    assert r0.states[:4] == ["BACK", "SMALL_V", "DOGE", "BACK"]
    assert 200 < abs(_switch_error_counts(dev0, 0.0)) < 600


def test_touch_probe_config_errors(tmp_path, monkeypatch):
    p = tmp_path / "bus.yml"
    p.write_text(yml_text(homing="{method: gotoy, touch_probe: 1}"))
    with pytest.raises(ConfigError, match=r"bus.yml:\d+.*touch_probe.*true or false"):
        load_config(p)
    p.write_text(yml_text(homing="{method: drive, drive_method: 21, touch_probe: true}"))
    with pytest.raises(ConfigError, match=r"touch_probe.*only applies to method gotoy"):
        load_config(p)
    p.write_text(yml_text(homing="{method: gotoy, touch_prob: true}"))
    with pytest.raises(ConfigError, match="touch_prob.*did you mean 'touch_probe'"):
        load_config(p)
    from controller.canopen.config import tracking as tc
    monkeypatch.setattr(tc, "TOUCH_PROBE_OBJECTS",
                        tc.TOUCH_PROBE_OBJECTS + ((0x60BB, "touch probe 1 negative edge"),))
    p.write_text(yml_text(homing="{method: gotoy, touch_probe: true}"))
    with pytest.raises(ConfigError, match=r"touch_probe.*missing 60BBh"):
        load_config(p)
    p.write_text(yml_text(homing="{method: gotoy}"))
    assert am.axis_config(load_config(p), "y").homing.touch_probe is False


def test_max_time_while_arming_the_touch_probe(tmp_path):
    # time is up in the cycle the probe would be armed: nothing moved, the job ends there
    from controller.canopen.slave.world import SimWorld
    cfg = cfg_of(tmp_path, homing=GOTOY.replace("}", ", touch_probe: true}"), sim=PROBE_SIM)
    with SimWorld(cfg) as world:
        ctl = am.MotionController(cfg, world.transport, [am.GotoYJob(am.axis_config(cfg, "y"),
                                                                     cfg.period_s)])
        (r,) = am.run_jobs(ctl, 0.032)
        assert int(world.device("y").load(0x60B8, 0)) == 0  # never armed
    assert r.result == "ERROR_TIMEOUT" and r.message.endswith(": not started")
    assert r.states == ["ARM_PROBE"]
    assert r.end_counts == 300000 and not _reactions(ctl)


def test_gotoy_touch_probe_from_its_tpdo_needs_no_sdo_during_the_motion(tmp_path):
    """60B9h + 60BAh mapped in an event-driven TPDO: the latch comes with the edge; the only
    SDOs are the arming ones before the search (no round trips between SYNCs while moving)."""
    r, dev, frames = _home_y(tmp_path, touch_probe=True, record=True, probe_tpdo=True)
    assert r.result == "FINISHED", r.message
    assert r.probe_source == "TPDO" and r.probe_latched_counts == SWITCH_EDGE
    assert abs(_switch_error_counts(dev, 0.0)) <= 1
    probe_sdos = [struct.unpack_from("<H", d, 1)[0] for _, cid, d in frames
                  if cid == 0x600 + 12 and d[0] != 0x80
                  and struct.unpack_from("<H", d, 1)[0] in (0x60B8, 0x60B9, 0x60BA)]
    assert probe_sdos == [0x60B8, 0x60B8, 0x60B9]          # arming only
    r_sdo, _, _ = _home_y(tmp_path, touch_probe=True)      # not mapped: read by SDO
    assert r_sdo.probe_source == "SDO" and r_sdo.probe_latched_counts == SWITCH_EDGE
