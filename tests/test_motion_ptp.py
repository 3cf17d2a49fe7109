"""Sled_Y point-to-point axis (controller/motion/ptp.py): brake timing, state sequence, exact
ends, re-targeting mid-move, limits on the sampled stream (property-based)."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.errors import ParameterError
from controller.limits import Limits
from controller.motion import (
    AxisConfig,
    MotionResult,
    PointToPoint,
    PtpState,
)
from controller.motion.profile import KinematicState, plan_position, plan_stop

PROPERTY = settings(derandomize=True, database=None, deadline=None, max_examples=100,
                    suppress_health_check=[HealthCheck.too_slow])


def run(axis, max_samples=20_000, commands=None):
    """Step until idle (FINISHED/IDLE) with no command left; ``commands`` maps a sample index
    to a callable run before the update that produces the next sample."""
    outs = []
    commands = commands or {}
    last_command = max(commands, default=-1)
    for _ in range(max_samples):
        if axis.sample in commands:
            commands[axis.sample](axis)
        out = axis.update()
        outs.append(out)
        if out.result in (MotionResult.FINISHED, MotionResult.IDLE) and \
                axis.sample > last_command:
            return outs
    raise AssertionError("did not finish")


def assert_stream_within_limits(outs, limits, period_s, start_mm=None):
    """Reported v/a/j within limits, and finite differences of the position stream too."""
    v = np.array([o.velocity_mm_s for o in outs])
    a = np.array([o.acceleration_mm_s2 for o in outs])
    j = np.array([o.jerk_mm_s3 for o in outs])
    assert np.max(np.abs(v)) <= limits.vel * (1 + 1e-9)
    assert np.max(np.abs(a)) <= limits.acc * (1 + 1e-9)
    assert np.max(np.abs(j)) <= limits.jerk * (1 + 1e-9)
    p = np.array(([start_mm] if start_mm is not None else []) + [o.position_mm for o in outs])
    tol = 1e-10 * max(1.0, float(np.max(np.abs(p))))  # position rounding [mm]
    T = period_s
    for order, bound in ((1, limits.vel), (2, limits.acc), (3, limits.jerk)):
        worst = np.max(np.abs(np.diff(p, order)), initial=0.0) / T**order
        assert worst <= bound * (1 + 1e-9) + 2**order * tol / T**order, (order, worst, bound)


def states(outs):
    seq = []
    for o in outs:
        if not seq or seq[-1] is not o.state:
            seq.append(o.state)
    return seq


LIMITS = Limits(500.0, 5000.0, 1e5)


# ------------------------------------------------------------------------------------------
# Hand-computed sequence with brake timing
# ------------------------------------------------------------------------------------------

def test_hand_computed_move_with_brake_timing():
    # d = 150 mm with V=500, A=5000, J=1e5: ACCEL 0.2 s, CONST 0.1 s, DECEL 0.2 s (see
    # test_motion_profile).  T = 10 ms: release 30 ms = 3 samples, motion 50 samples,
    # engage 20 ms = 2 samples, WAIT 50 ms = 5 samples, READY at sample 3+50+2+5 = 60.
    axis = PointToPoint(AxisConfig(LIMITS, 0.01, brake_release_s=0.03, brake_engage_s=0.02,
                                   stop_time_s=0.05))
    assert axis.output.state is PtpState.STOP and axis.output.result is MotionResult.IDLE
    axis.set_target(150.0)
    outs = run(axis)
    by_sample = {o.sample: o for o in outs}
    assert [by_sample[k].state for k in (1, 2, 3)] == [PtpState.BRAKE_RELEASE] * 3
    assert all(by_sample[k].position_mm == 0.0 and by_sample[k].brake_released
               for k in (1, 2, 3))
    assert [by_sample[k].state for k in range(4, 23)] == [PtpState.ACCEL] * 19
    assert by_sample[23].state is PtpState.CONST  # t = 0.2 s: ACCEL done
    assert by_sample[23].position_mm == pytest.approx(50.0, abs=1e-9)
    assert by_sample[33].state is PtpState.DECEL  # t = 0.3 s
    assert by_sample[33].position_mm == pytest.approx(100.0, abs=1e-9)
    assert by_sample[52].state is PtpState.DECEL
    for k in (53, 54):  # t = 0.5 s: at rest on the target, brake closing
        o = by_sample[k]
        assert o.state is PtpState.BRAKE_ENGAGE and not o.brake_released
        assert (o.position_mm, o.velocity_mm_s, o.acceleration_mm_s2) == (150.0, 0.0, 0.0)
    assert [by_sample[k].state for k in range(55, 60)] == [PtpState.WAIT] * 5
    assert by_sample[60].state is PtpState.READY
    assert by_sample[60].result is MotionResult.FINISHED
    assert all(o.result is MotionResult.WORKING for o in outs[:-1])
    assert states(outs) == [PtpState.BRAKE_RELEASE, PtpState.ACCEL, PtpState.CONST,
                            PtpState.DECEL, PtpState.BRAKE_ENGAGE, PtpState.WAIT,
                            PtpState.READY]
    assert_stream_within_limits(outs, LIMITS, 0.01, start_mm=0.0)


def test_short_move_skips_const_samples_but_ends_exactly():
    limits = Limits(500.0, 2000.0, 1e4)  # 20 mm: ACCEL 0.2 s, CONST 0 s, DECEL 0.2 s
    axis = PointToPoint(AxisConfig(limits, 0.001))
    axis.set_target(20.0)
    outs = run(axis)
    # CONST lasts 0 s (to rounding): at most the one sample that lands on its start
    assert [s for s in states(outs) if s is not PtpState.CONST] == \
        [PtpState.ACCEL, PtpState.DECEL, PtpState.READY]
    assert sum(o.state is PtpState.CONST for o in outs) <= 1
    assert axis.profile is None
    assert outs[-1].position_mm == 20.0
    assert outs[-1].sample == 400  # 0.4 s at 1 ms; zero brake/stop times
    assert max(o.velocity_mm_s for o in outs) == pytest.approx(100.0, rel=1e-4)  # < V


def test_zero_brake_times_and_zero_length_command():
    axis = PointToPoint(AxisConfig(LIMITS, 0.004), position_mm=12.5)
    axis.set_target(12.5)  # already there: no brake cycle
    out = axis.update()
    assert out.state is PtpState.STOP and out.result is MotionResult.IDLE
    axis.set_target(13.0)
    out = axis.update()
    assert out.state is PtpState.ACCEL and out.brake_released and out.position_mm > 12.5


def test_brake_release_wait_rounds_up_to_whole_samples():
    # 25 ms at T = 10 ms: 3 samples (no motion before 25 ms have passed)
    axis = PointToPoint(AxisConfig(LIMITS, 0.01, brake_release_s=0.025))
    axis.set_target(-1.0)
    outs = [axis.update() for _ in range(4)]
    assert [o.state for o in outs[:3]] == [PtpState.BRAKE_RELEASE] * 3
    assert all(o.position_mm == 0.0 for o in outs[:3])
    assert outs[3].position_mm < 0.0


def test_set_target_rejects_non_finite():
    axis = PointToPoint(AxisConfig(LIMITS, 0.001))
    with pytest.raises(ParameterError, match="target_mm"):
        axis.set_target(math.inf)


# ------------------------------------------------------------------------------------------
# Re-targeting
# ------------------------------------------------------------------------------------------

def test_retarget_mid_const_behind_brakes_and_reverses():
    axis = PointToPoint(AxisConfig(LIMITS, 0.001, 0.01, 0.01, 0.02))
    axis.set_target(150.0)
    # sample 10 + 250: 0.25 s into the move (CONST at 500 mm/s, 75 mm)
    outs = run(axis, commands={260: lambda a: a.set_target(20.0)})
    seq = states(outs)
    assert seq == [PtpState.BRAKE_RELEASE, PtpState.ACCEL, PtpState.CONST, PtpState.DECEL,
                   PtpState.ACCEL, PtpState.CONST, PtpState.DECEL, PtpState.BRAKE_ENGAGE,
                   PtpState.WAIT, PtpState.READY]
    v = [o.velocity_mm_s for o in outs]
    assert max(v) == pytest.approx(500.0) and min(v) < -100.0
    assert outs[-1].position_mm == 20.0
    assert_stream_within_limits(outs, LIMITS, 0.001, start_mm=0.0)


def test_retarget_during_brake_release_replaces_the_plan():
    axis = PointToPoint(AxisConfig(LIMITS, 0.001, brake_release_s=0.05))
    axis.set_target(100.0)
    outs = run(axis, commands={20: lambda a: a.set_target(-30.0)})
    assert all(o.position_mm == 0.0 for o in outs[:50])
    assert outs[50].position_mm < 0.0
    assert outs[-1].position_mm == -30.0


def test_retarget_during_wait_is_queued_until_ready():
    axis = PointToPoint(AxisConfig(LIMITS, 0.01, 0.03, 0.02, 0.05))
    axis.set_target(150.0)
    outs = run(axis, commands={55: lambda a: a.set_target(0.0)})  # sample 55: first WAIT
    seq = states(outs)
    assert seq == [PtpState.BRAKE_RELEASE, PtpState.ACCEL, PtpState.CONST, PtpState.DECEL,
                   PtpState.BRAKE_ENGAGE, PtpState.WAIT, PtpState.BRAKE_RELEASE, PtpState.ACCEL,
                   PtpState.CONST, PtpState.DECEL, PtpState.BRAKE_ENGAGE, PtpState.WAIT,
                   PtpState.READY]
    by_sample = {o.sample: o for o in outs}
    # the whole WAIT (5 samples) is kept, then 3 release samples without motion
    assert [by_sample[k].state for k in range(55, 60)] == [PtpState.WAIT] * 5
    assert [by_sample[k].state for k in (60, 61, 62)] == [PtpState.BRAKE_RELEASE] * 3
    assert all(by_sample[k].position_mm == 150.0 for k in range(53, 63))
    assert outs[-1].position_mm == 0.0
    # the sample that would have been READY (60) is the first release sample of the queued
    # move: 60..62 release, 63..112 motion (0.5 s), 112..113 engage, 114..118 WAIT
    assert outs[-1].sample == 119


def test_same_target_again_does_not_replan():
    axis = PointToPoint(AxisConfig(LIMITS, 0.001))
    axis.set_target(150.0)
    for _ in range(100):
        axis.update()
    profile = axis.profile
    axis.set_target(150.0)
    assert axis.profile is profile


def test_stop_mid_move_is_jerk_limited_then_brakes():
    axis = PointToPoint(AxisConfig(LIMITS, 0.001, 0.0, 0.01, 0.01))
    axis.set_target(150.0)
    for _ in range(250):  # 0.25 s: CONST at 500 mm/s
        axis.update()
    expected = plan_stop(axis.kinematic_state, LIMITS).target_mm
    axis.stop()
    outs = run(axis)
    assert states(outs) == [PtpState.DECEL, PtpState.BRAKE_ENGAGE, PtpState.WAIT,
                            PtpState.READY]
    assert outs[-1].position_mm == expected < 150.0
    assert_stream_within_limits(outs, LIMITS, 0.001)


def test_deterministic():
    def once():
        axis = PointToPoint(AxisConfig(LIMITS, 0.002, 0.01, 0.01, 0.01))
        axis.set_target(77.7)
        return run(axis, commands={60: lambda a: a.set_target(-12.0)})
    assert once() == once()


# ------------------------------------------------------------------------------------------
# Properties
# ------------------------------------------------------------------------------------------

@st.composite
def axis_case(draw):
    vel = draw(st.floats(5.0, 2000.0))
    acc = vel / draw(st.floats(0.01, 0.4))
    limits = Limits(vel, acc, acc / draw(st.floats(0.002, 0.2)))
    period = draw(st.sampled_from([0.001, 0.002, 0.004]))
    brake = draw(st.sampled_from([0.0, 0.003, 0.02]))
    config = AxisConfig(limits, period, brake, brake, draw(st.sampled_from([0.0, 0.01])))
    start = draw(st.floats(-500.0, 500.0))
    # distances up to ~1 s of travel at V keep the runs short
    sign = draw(st.sampled_from([-1.0, 1.0]))
    target = start + sign * draw(st.floats(1e-3, 1.0)) * vel
    return config, start, target


@PROPERTY
@given(axis_case())
def test_random_moves_within_limits_and_exact(case):
    config, start, target = case
    axis = PointToPoint(config, position_mm=start)
    axis.set_target(target)
    outs = run(axis)
    assert outs[-1].state is PtpState.READY or start == target
    assert outs[-1].position_mm == target
    assert outs[-1].velocity_mm_s == 0.0 and outs[-1].acceleration_mm_s2 == 0.0
    n_rel = config.release_samples
    assert all(o.position_mm == start for o in outs[:n_rel])  # no motion before release
    assert_stream_within_limits(outs, config.limits, config.sample_period_s, start_mm=start)


@PROPERTY
@given(axis_case(), st.lists(st.tuples(st.floats(0.05, 0.95), st.floats(-1.0, 1.0)),
                             min_size=1, max_size=3))
def test_random_retargets_within_limits_and_exact(case, retargets):
    config, start, target = case
    axis = PointToPoint(config, position_mm=start)
    axis.set_target(target)
    profile = axis.profile
    n_motion = (int(profile.duration_s / config.sample_period_s) if profile is not None else 0)
    commands = {}
    targets = {}
    for frac, rel in retargets:
        k = config.release_samples + int(frac * n_motion)
        targets[k] = start + rel * config.limits.vel
        commands[k] = functools.partial(PointToPoint.set_target, target_mm=targets[k])
    final = targets[max(targets)] if targets else target
    outs = run(axis, commands=commands)
    assert outs[-1].position_mm == final
    assert outs[-1].velocity_mm_s == 0.0 and outs[-1].acceleration_mm_s2 == 0.0
    assert_stream_within_limits(outs, config.limits, config.sample_period_s, start_mm=start)


@PROPERTY
@given(axis_case(), st.floats(0.0, 1.0))
def test_integrated_end_is_exact_before_the_snap(case, frac):
    config, start, target = case
    first = PointToPoint(config, position_mm=start)
    first.set_target(target)
    if first.profile is None:
        return
    mid = first.profile.state_at(frac * first.profile.duration_s)
    p = plan_position(mid, start, config.limits)
    samples = p.sample(config.sample_period_s)
    assert abs(p.end.position_mm - start) <= 1e-9 * max(1.0, abs(start))
    if len(samples) >= 2:  # the last sample before the end is close to the target already
        last = samples[-2]
        remaining = abs(last.position_mm - start)
        assert remaining <= config.limits.vel * config.sample_period_s * (1 + 1e-9)
    if samples:
        assert samples[-1] == KinematicState(start, 0.0, 0.0)


def test_seeded_random_sweep_with_retargets():
    """200 random moves, each re-targeted up to three times at random samples (seeded)."""
    rng = np.random.default_rng(20_241_122)
    for _ in range(200):
        vel = rng.uniform(5.0, 2000.0)
        acc = vel / rng.uniform(0.01, 0.4)
        limits = Limits(vel, acc, acc / rng.uniform(0.002, 0.2))
        period = float(rng.choice([0.001, 0.002, 0.004]))
        config = AxisConfig(limits, period, float(rng.choice([0.0, 0.01])), 0.0, 0.0)
        start = rng.uniform(-500.0, 500.0)
        axis = PointToPoint(config, position_mm=start)
        axis.set_target(start + rng.uniform(-1.0, 1.0) * vel)
        n_motion = int(axis.profile.duration_s / period)
        samples = sorted(set(config.release_samples + rng.integers(0, n_motion + 1,
                                                                   rng.integers(1, 4))))
        targets = {int(k): start + rng.uniform(-1.0, 1.0) * vel for k in samples}
        commands = {k: functools.partial(PointToPoint.set_target, target_mm=t)
                    for k, t in targets.items()}
        outs = run(axis, commands=commands)
        assert outs[-1].position_mm == targets[max(targets)]
        assert_stream_within_limits(outs, limits, period, start_mm=start)
