"""GotoY homing (controller/motion/homing.py): state sequence per start condition, latch and
home offset, time-outs, limit-switch abort, sensor errors; NoHoming; DriveHomingConfig."""

from __future__ import annotations

import numpy as np
import pytest

from controller.errors import ParameterError, StateError
from controller.limits import Limits
from controller.motion import (
    DriveHomingConfig,
    GotoY,
    HomingConfig,
    HomingState,
    HomingTimeouts,
    MotionResult,
    NoHoming,
    NoHomingConfig,
)

S = HomingState
LIMITS = Limits(500.0, 5000.0, 1e5)
T = 0.001


def config(**overrides):
    base = {"limits": LIMITS, "sample_period_s": T, "search_vel_mm_s": 200.0, "creep_vel_mm_s": 5.0,
                "push_in_counts": 100, "counts_per_mm": 1000.0, "back_off_mm": 2.0, "direction": -1,
                "brake_release_s": 0.01, "brake_engage_s": 0.02}
    base.update(overrides)
    return HomingConfig(**base)


class World:
    """Sensors as a function of the axis position (homing towards negative positions):
    slow-down dog at x <= dss_mm, home switch at x <= dnp_mm, limit switches beyond."""

    def __init__(self, dss_mm=20.0, dnp_mm=5.0, neg_limit_mm=-50.0, pos_limit_mm=500.0,
                 dss_works=True, dnp_works=True):
        self.dss_mm, self.dnp_mm = dss_mm, dnp_mm
        self.neg_limit_mm, self.pos_limit_mm = neg_limit_mm, pos_limit_mm
        self.dss_works, self.dnp_works = dss_works, dnp_works

    def run(self, homing, max_samples=100_000):
        outs = []
        for _ in range(max_samples):
            x = homing.output.position_mm  # sensors see the last setpoint
            out = homing.update(slow_down=self.dss_works and x <= self.dss_mm,
                                home=self.dnp_works and x <= self.dnp_mm,
                                limit_neg=x <= self.neg_limit_mm,
                                limit_pos=x >= self.pos_limit_mm)
            outs.append(out)
            if out.state is S.STOP:
                return outs
        raise AssertionError("homing did not end")


def states(outs):
    seq = [S.STOP]
    for o in outs:
        if seq[-1] is not o.state:
            seq.append(o.state)
    return seq


def assert_within_limits(outs, limits, start_mm):
    v = np.array([o.velocity_mm_s for o in outs])
    a = np.array([o.acceleration_mm_s2 for o in outs])
    j = np.array([o.jerk_mm_s3 for o in outs])
    assert np.max(np.abs(v)) <= limits.vel * (1 + 1e-9)
    assert np.max(np.abs(a)) <= limits.acc * (1 + 1e-9)
    assert np.max(np.abs(j)) <= limits.jerk * (1 + 1e-9)
    p = np.array([start_mm] + [o.position_mm for o in outs])
    tol = 1e-10 * max(1.0, float(np.max(np.abs(p))))
    for order, bound in ((1, limits.vel), (2, limits.acc), (3, limits.jerk)):
        worst = np.max(np.abs(np.diff(p, order)), initial=0.0) / T**order
        assert worst <= bound * (1 + 1e-9) + 2**order * tol / T**order, (order, worst, bound)


# ------------------------------------------------------------------------------------------
# Start conditions (thesis: BRAKE decides from the sensors)
# ------------------------------------------------------------------------------------------

def test_neither_sensor_full_sequence():
    homing = GotoY(config(), position_mm=100.0)
    assert homing.output.result is MotionResult.IDLE
    homing.start()
    outs = World().run(homing)
    assert states(outs) == [S.STOP, S.BRAKE, S.ACCEL, S.CONST, S.DEACCEL, S.SMALL_V, S.DOGE,
                            S.BACK, S.BRAKE, S.STOP]
    last = outs[-1]
    assert last.result is MotionResult.FINISHED and last.message == ""
    # latched where DNP was first read true: within one creep step past the switch
    assert 5.0 - 5.0 * T - 1e-12 <= homing.latched_mm <= 5.0
    assert last.home_offset_mm == homing.latched_mm == homing.home_offset_mm
    # DOGE pushes in exactly 100 counts / 1000 counts/mm = 0.1 mm, BACK backs off 2 mm
    doge_end = next(o for o in outs if o.state is S.BACK).position_mm
    assert doge_end == pytest.approx(homing.latched_mm - 0.1, abs=1e-9)
    assert last.position_mm == pytest.approx(doge_end + 2.0, abs=1e-9)
    assert last.velocity_mm_s == 0.0 and last.acceleration_mm_s2 == 0.0
    # creep speed in SMALL_V, search speed in CONST
    assert all(o.velocity_mm_s == pytest.approx(-5.0) for o in outs if o.state is S.SMALL_V)
    assert all(o.velocity_mm_s == pytest.approx(-200.0) for o in outs if o.state is S.CONST)
    assert max(abs(o.velocity_mm_s) for o in outs if o.state in (S.DOGE, S.BACK)) <= 5.0 + 1e-9
    assert_within_limits(outs, LIMITS, 100.0)


def test_brake_timing_in_homing():
    homing = GotoY(config(), position_mm=100.0)
    homing.start()
    outs = World().run(homing)
    # release 10 ms = 10 samples with the brake open and no motion
    assert [o.state for o in outs[:10]] == [S.BRAKE] * 10
    assert all(o.brake_released and o.position_mm == 100.0 for o in outs[:10])
    assert outs[10].state is S.ACCEL and outs[10].position_mm < 100.0
    # engage 20 ms = 20 samples at rest with the brake closing, then STOP
    tail = outs[-21:]
    assert [o.state for o in tail] == [S.BRAKE] * 20 + [S.STOP]
    assert not any(o.brake_released for o in tail)
    assert len({o.position_mm for o in tail}) == 1


def test_slow_down_only_at_start_goes_to_small_v():
    homing = GotoY(config(), position_mm=10.0)
    homing.start()
    outs = World().run(homing)
    assert states(outs) == [S.STOP, S.BRAKE, S.SMALL_V, S.DOGE, S.BACK, S.BRAKE, S.STOP]
    assert outs[-1].result is MotionResult.FINISHED
    assert 5.0 - 5.0 * T - 1e-12 <= outs[-1].home_offset_mm <= 5.0
    assert_within_limits(outs, LIMITS, 10.0)


def test_both_sensors_at_start_backs_off_and_re_approaches_the_edge():
    """Started 2 mm inside the home switch: BACK off it, SMALL_V back, DOGE at the edge
    (the thesis' rule "both -> DOGE" took the start, 3.0 mm, as home: off by 2 mm)."""
    homing = GotoY(config(), position_mm=3.0)
    homing.start()
    outs = World().run(homing)
    assert states(outs) == [S.STOP, S.BRAKE, S.BACK, S.SMALL_V, S.DOGE, S.BACK, S.BRAKE,
                            S.STOP]
    assert outs[-1].result is MotionResult.FINISHED
    assert 5.0 - 5.0 * T - 1e-12 <= outs[-1].home_offset_mm <= 5.0
    # off the switch within one creep step after the edge, then back_off_mm further
    assert 5.0 < homing.cleared_mm <= 5.0 + 5.0 * T + 1e-12
    assert max(o.position_mm for o in outs) == pytest.approx(homing.cleared_mm + 2.0, abs=1e-9)
    assert outs[-1].position_mm == pytest.approx(outs[-1].home_offset_mm - 0.1 + 2.0, abs=1e-9)
    assert_within_limits(outs, LIMITS, 3.0)


@pytest.mark.parametrize("back_off_mm", [0.0, 0.001, 2.0])
@pytest.mark.parametrize("start", [4.999, 4.0, 0.5, -20.0])
def test_home_within_one_sample_of_the_edge_from_every_start_on_the_switch(start, back_off_mm):
    """Any depth into the switch and any back-off (0: stop right after the edge, shorter
    than the stopping distance): home is the edge within one creep step."""
    homing = GotoY(config(back_off_mm=back_off_mm), position_mm=start)
    homing.start()
    outs = World(neg_limit_mm=-50.0).run(homing)
    assert outs[-1].result is MotionResult.FINISHED, outs[-1].message
    assert 5.0 - 5.0 * T - 1e-12 <= outs[-1].home_offset_mm <= 5.0
    assert_within_limits(outs, LIMITS, start)


def test_slow_down_during_accel_skips_const():
    # 30 mm before the dog at up to 400 mm/s: DSS fires while still accelerating
    homing = GotoY(config(search_vel_mm_s=400.0), position_mm=30.0)
    homing.start()
    outs = World(dss_mm=20.0, dnp_mm=-40.0, neg_limit_mm=-200.0).run(homing)
    assert states(outs) == [S.STOP, S.BRAKE, S.ACCEL, S.DEACCEL, S.SMALL_V, S.DOGE, S.BACK,
                            S.BRAKE, S.STOP]
    assert_within_limits(outs, LIMITS, 30.0)


def test_positive_direction():
    homing = GotoY(config(direction=1), position_mm=-100.0)
    homing.start()
    outs = []
    while True:
        x = homing.output.position_mm
        out = homing.update(slow_down=x >= 0.0, home=x >= 10.0)
        outs.append(out)
        if out.result is not MotionResult.WORKING:
            break
    assert out.result is MotionResult.FINISHED
    assert 10.0 <= out.home_offset_mm <= 10.0 + 5.0 * T + 1e-12
    assert out.position_mm == pytest.approx(out.home_offset_mm + 0.1 - 2.0, abs=1e-9)


# ------------------------------------------------------------------------------------------
# Errors: result codes with messages, never exceptions in update()
# ------------------------------------------------------------------------------------------

def test_home_without_slow_down_at_start_is_a_sensor_error():
    homing = GotoY(config(), position_mm=3.0)
    homing.start()
    outs = World(dss_works=False).run(homing)
    last = outs[-1]
    assert last.result is MotionResult.ERROR_SENSOR
    assert "slow-down" in last.message and "3 mm" in last.message
    assert last.home_offset_mm is None
    assert all(o.position_mm == 3.0 for o in outs)  # never moved
    assert states(outs)[-1] is S.STOP


def test_home_sensor_before_creep_speed_is_a_sensor_error():
    homing = GotoY(config(), position_mm=100.0)
    homing.start()
    outs = World(dss_mm=5.5, dnp_mm=5.0).run(homing)  # dog far too short to slow down
    last = outs[-1]
    assert last.result is MotionResult.ERROR_SENSOR
    assert "above the creep speed" in last.message
    assert S.ABORT in states(outs)
    assert_within_limits(outs, LIMITS, 100.0)


def test_small_v_timeout():
    # the home switch never fires; SMALL_V may last 0.5 s = 500 samples
    homing = GotoY(config(timeouts=HomingTimeouts(small_v_s=0.5)), position_mm=10.0)
    homing.start()
    outs = World(dnp_works=False).run(homing)
    last = outs[-1]
    assert last.result is MotionResult.ERROR_TIMEOUT
    assert "SMALL_V" in last.message and "small_v_s" in last.message
    assert sum(o.state is S.SMALL_V for o in outs) == 500
    assert states(outs)[-4:] == [S.SMALL_V, S.ABORT, S.BRAKE, S.STOP]
    assert last.velocity_mm_s == 0.0 and last.home_offset_mm is None
    assert_within_limits(outs, LIMITS, 10.0)


def test_total_timeout():
    # slow-down dog never seen: the whole procedure may take 0.3 s = 300 samples
    homing = GotoY(config(timeouts=HomingTimeouts(total_s=0.3)), position_mm=100.0)
    homing.start()
    outs = World(dss_works=False, dnp_works=False, neg_limit_mm=-1e9).run(homing)
    last = outs[-1]
    assert last.result is MotionResult.ERROR_TIMEOUT and "total_s" in last.message
    first_abort = next(i for i, o in enumerate(outs) if o.state is S.ABORT)
    assert first_abort == 300  # samples 1..300 were allowed
    assert outs[first_abort].result is MotionResult.ERROR_TIMEOUT
    assert_within_limits(outs, LIMITS, 100.0)


def test_negative_limit_switch_aborts_with_jerk_limited_stop():
    homing = GotoY(config(), position_mm=100.0)
    homing.start()
    outs = World(dss_works=False, dnp_works=False, neg_limit_mm=-50.0).run(homing)
    last = outs[-1]
    assert last.result is MotionResult.ERROR_LIMIT_SWITCH
    assert "negative limit switch" in last.message and "CONST" in last.message
    abort = [o for o in outs if o.state is S.ABORT]
    assert abort and abort[0].position_mm <= -50.0 + 200.0 * T  # detected at once
    assert all(o.result is MotionResult.ERROR_LIMIT_SWITCH for o in abort)
    assert states(outs)[-3:] == [S.ABORT, S.BRAKE, S.STOP]
    assert last.home_offset_mm is None and last.velocity_mm_s == 0.0
    assert_within_limits(outs, LIMITS, 100.0)


def test_limit_switch_during_release_wait_never_moves():
    homing = GotoY(config(), position_mm=0.0)
    homing.start()
    out = homing.update(slow_down=False, home=False, limit_pos=True)
    assert out.result is MotionResult.ERROR_LIMIT_SWITCH and "positive" in out.message
    while out.state is not S.STOP:
        out = homing.update(slow_down=False, home=False)
        assert out.position_mm == 0.0
    assert out.result is MotionResult.ERROR_LIMIT_SWITCH


def test_stop_command_aborts_and_start_while_running_raises():
    homing = GotoY(config(), position_mm=100.0)
    homing.start()
    for _ in range(50):
        homing.update(slow_down=False, home=False)
    with pytest.raises(StateError, match="already running"):
        homing.start()
    homing.stop()
    outs = World().run(homing)
    assert outs[-1].result is MotionResult.ERROR_ABORTED
    assert homing.state is S.STOP
    homing.start()  # may be restarted after an error
    assert World().run(homing)[-1].result is MotionResult.FINISHED


def test_deterministic():
    def once():
        homing = GotoY(config(), position_mm=100.0)
        homing.start()
        return World().run(homing)
    assert once() == once()


# ------------------------------------------------------------------------------------------
# Configuration
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("overrides, text", [
    ({"search_vel_mm_s": 600.0}, "search_vel_mm_s"),
    ({"creep_vel_mm_s": 300.0}, "creep_vel_mm_s"),
    ({"creep_vel_mm_s": 0.0}, "creep_vel_mm_s"),
    ({"push_in_counts": -1}, "push_in_counts"),
    ({"push_in_counts": 1.5}, "push_in_counts"),
    ({"counts_per_mm": 0.0}, "counts_per_mm"),
    ({"back_off_mm": -1.0}, "back_off_mm"),
    ({"direction": 0}, "direction"),
    ({"brake_release_s": float("nan")}, "brake_release_s"),
    ({"sample_period_s": 0.0}, "sample_period_s"),
])
def test_config_validation(overrides, text):
    with pytest.raises(ParameterError, match=text):
        config(**overrides)


def test_timeouts_validation():
    with pytest.raises(ParameterError, match="HomingTimeouts.const_s"):
        HomingTimeouts(const_s=0.0)
    assert HomingTimeouts(total_s=None).total_s is None
    assert HomingTimeouts(doge_s=2.0).for_state(S.DOGE) == 2.0


def test_no_homing_for_absolute_encoders():
    homing = NoHoming(NoHomingConfig(home_offset_mm=12.5), position_mm=40.0)
    assert homing.update().result is MotionResult.IDLE
    homing.start()
    out = homing.update()
    assert out.result is MotionResult.FINISHED and out.home_offset_mm == 12.5
    assert out.position_mm == 40.0 and not out.brake_released
    with pytest.raises(ParameterError, match="home_offset_mm"):
        NoHomingConfig(home_offset_mm=float("inf"))


def test_drive_homing_config():
    cfg = DriveHomingConfig(method=35, timeout_s=20.0)
    assert cfg.MODE_OF_OPERATION == 6 and cfg.timeout_ms == 20000
    assert DriveHomingConfig(method=-3, timeout_s=1.0).manufacturer_specific
    DriveHomingConfig(method=17, timeout_s=5.0, switch_search_vel_mm_s=20.0,
                      zero_search_vel_mm_s=2.0, acc_mm_s2=100.0, home_offset_mm=-1.5)
    with pytest.raises(ParameterError, match="NoHoming"):
        DriveHomingConfig(method=0, timeout_s=1.0)
    for bad in (15, 16, 31, 32, 36, 38, 127):
        with pytest.raises(ParameterError, match="reserved"):
            DriveHomingConfig(method=bad, timeout_s=1.0)
    with pytest.raises(ParameterError, match="6098h"):
        DriveHomingConfig(method=200, timeout_s=1.0)
    with pytest.raises(ParameterError, match="timeout_s"):
        DriveHomingConfig(method=1, timeout_s=0.0)
    with pytest.raises(ParameterError, match="zero_search_vel_mm_s"):
        DriveHomingConfig(method=1, timeout_s=1.0, zero_search_vel_mm_s=-1.0)


def test_seeded_random_homing_sweep():
    """100 random layouts (seeded): either FINISHED with the latch within one creep step of
    the home switch, or a clear error; always within the limits and ending at rest."""
    rng = np.random.default_rng(402)
    finished = 0
    for _ in range(100):
        creep = rng.uniform(5.0, 20.0)
        cfg = config(search_vel_mm_s=rng.uniform(creep, 500.0), creep_vel_mm_s=creep,
                     back_off_mm=rng.uniform(0.0, 5.0), push_in_counts=int(rng.integers(0, 500)),
                     brake_release_s=float(rng.choice([0.0, 0.005])),
                     brake_engage_s=float(rng.choice([0.0, 0.005])),
                     timeouts=HomingTimeouts(total_s=10.0))
        dnp = rng.uniform(-20.0, 20.0)
        dss = dnp + rng.uniform(0.5, 30.0)
        start = rng.uniform(dnp - 2.0, dss + 200.0)
        homing = GotoY(cfg, position_mm=start)
        homing.start()
        outs = World(dss_mm=dss, dnp_mm=dnp, neg_limit_mm=dnp - 30.0).run(homing)
        last = outs[-1]
        assert last.state is S.STOP and last.velocity_mm_s == 0.0
        assert_within_limits(outs, LIMITS, start)
        if last.result is MotionResult.FINISHED:
            finished += 1
            # from every start (before, on the dog, on the switch): within one creep step
            assert dnp - creep * T - 1e-9 <= last.home_offset_mm <= dnp
        else:
            assert last.result is MotionResult.ERROR_SENSOR and last.message
    assert finished >= 50


# ------------------------------------------------------------------------------------------
# refine_latch: a more precise latch (e.g. the drive's touch probe) replaces the sensor's
# ------------------------------------------------------------------------------------------

def _run_until(homing, world, state, max_samples=100_000):
    """Feed ``world``'s sensors until ``homing`` is in ``state``; the outputs so far."""
    outs = []
    for _ in range(max_samples):
        x = homing.output.position_mm
        outs.append(homing.update(slow_down=x <= world.dss_mm, home=x <= world.dnp_mm,
                                  limit_neg=x <= world.neg_limit_mm,
                                  limit_pos=x >= world.pos_limit_mm))
        if homing.state is state:
            return outs
    raise AssertionError(f"never reached {state}")


@pytest.mark.parametrize("when", [S.DOGE, S.BACK])
def test_refine_latch_replaces_the_home_offset(when):
    world = World()
    homing = GotoY(config(), position_mm=100.0)
    with pytest.raises(StateError, match="STOP"):
        homing.refine_latch(5.0)  # not started
    homing.start()
    with pytest.raises(StateError, match="BRAKE"):
        homing.refine_latch(5.0)  # nothing latched yet
    outs = _run_until(homing, world, S.SMALL_V)
    with pytest.raises(StateError, match="SMALL_V"):
        homing.refine_latch(5.0)  # home not seen yet
    outs += _run_until(homing, world, when)
    sensor = homing.latched_mm
    assert sensor == homing.sensor_latched_mm and sensor < 5.0  # one creep step late
    with pytest.raises(ParameterError, match="position_mm"):
        homing.refine_latch(float("nan"))
    homing.refine_latch(5.0)  # the exact switch position
    assert homing.latched_mm == 5.0 and homing.sensor_latched_mm == sensor
    outs += world.run(homing)
    last = outs[-1]
    assert last.result is MotionResult.FINISHED
    assert last.home_offset_mm == homing.home_offset_mm == 5.0
    # the motion is not re-planned: push-in from the sensor latch, then back-off
    doge_end = next(o for o in outs if o.state is S.BACK).position_mm
    assert doge_end == pytest.approx(sensor - 0.1, abs=1e-9)
    assert last.position_mm == pytest.approx(doge_end + 2.0, abs=1e-9)
    with pytest.raises(StateError, match="STOP"):
        homing.refine_latch(4.0)  # finished: too late
    assert homing.home_offset_mm == 5.0
    # a new run starts without either latch
    homing.start()
    assert homing.latched_mm is None and homing.sensor_latched_mm is None


def test_refine_latch_not_after_an_abort():
    homing = GotoY(config(), position_mm=100.0)
    homing.start()
    _run_until(homing, World(), S.DOGE)
    homing.stop()
    assert homing.state is S.ABORT
    with pytest.raises(StateError, match="ABORT"):
        homing.refine_latch(5.0)
