"""Jog (controller/motion/jog.py): start, change speed, reverse, stop; all within the limits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.errors import ParameterError
from controller.limits import Limits
from controller.motion import AxisConfig, Jog, MotionResult, PtpState

PROPERTY = settings(derandomize=True, database=None, deadline=None, max_examples=60,
                    suppress_health_check=[HealthCheck.too_slow])
LIMITS = Limits(500.0, 5000.0, 1e5)


def steps(axis, n):
    return [axis.update() for _ in range(n)]


def settle(axis, max_samples=20_000):
    outs = []
    for _ in range(max_samples):
        outs.append(axis.update())
        if outs[-1].result in (MotionResult.FINISHED, MotionResult.IDLE):
            return outs
    raise AssertionError("jog did not stop")


def assert_stream_within_limits(outs, limits, period_s, start_mm):
    v = np.array([o.velocity_mm_s for o in outs])
    a = np.array([o.acceleration_mm_s2 for o in outs])
    j = np.array([o.jerk_mm_s3 for o in outs])
    assert np.max(np.abs(v)) <= limits.vel * (1 + 1e-9)
    assert np.max(np.abs(a)) <= limits.acc * (1 + 1e-9)
    assert np.max(np.abs(j)) <= limits.jerk * (1 + 1e-9)
    p = np.array([start_mm] + [o.position_mm for o in outs])
    tol = 1e-10 * max(1.0, float(np.max(np.abs(p))))
    T = period_s
    for order, bound in ((1, limits.vel), (2, limits.acc), (3, limits.jerk)):
        worst = np.max(np.abs(np.diff(p, order)), initial=0.0) / T**order
        assert worst <= bound * (1 + 1e-9) + 2**order * tol / T**order, (order, worst, bound)


def test_start_change_reverse_stop():
    axis = Jog(AxisConfig(LIMITS, 0.001, 0.005, 0.005, 0.01), position_mm=10.0)
    axis.set_velocity(100.0)
    outs = steps(axis, 300)
    assert [o.state for o in outs[:5]] == [PtpState.BRAKE_RELEASE] * 5
    assert all(o.position_mm == 10.0 for o in outs[:5])
    # 100 mm/s from rest: jerk-bound triangle, T2 = sqrt(100/1e5) = 31.6 ms -> 63 ms ACCEL
    assert outs[5 + 62].state is PtpState.ACCEL and outs[5 + 64].state is PtpState.CONST
    assert outs[-1].state is PtpState.CONST
    assert outs[-1].velocity_mm_s == pytest.approx(100.0, abs=1e-9)
    assert axis.velocity_command_mm_s == 100.0
    outs += steps(axis, 0)
    axis.set_velocity(400.0)
    outs += steps(axis, 300)
    assert outs[-1].velocity_mm_s == pytest.approx(400.0, abs=1e-9)
    axis.set_velocity(-250.0)  # reverse: brakes through zero inside one pulse
    more = steps(axis, 400)
    seen = [o.state for o in more]
    assert PtpState.DECEL in seen and seen[-1] is PtpState.CONST
    assert more[-1].velocity_mm_s == pytest.approx(-250.0, abs=1e-9)
    outs += more
    axis.stop()
    tail = settle(axis)
    outs += tail
    states = []
    for o in tail:
        if not states or states[-1] is not o.state:
            states.append(o.state)
    assert states == [PtpState.DECEL, PtpState.BRAKE_ENGAGE, PtpState.WAIT, PtpState.READY]
    assert tail[-1].velocity_mm_s == 0.0 and tail[-1].acceleration_mm_s2 == 0.0
    assert axis.velocity_command_mm_s == 0.0
    assert_stream_within_limits(outs, LIMITS, 0.001, 10.0)


def test_set_velocity_zero_is_stop_and_limits_are_checked():
    axis = Jog(AxisConfig(LIMITS, 0.002))
    axis.set_velocity(-50.0)
    steps(axis, 100)
    axis.set_velocity(0.0)
    assert settle(axis)[-1].state is PtpState.READY
    with pytest.raises(ParameterError, match=r"velocity_mm_s.*\[-500.0, 500.0\]"):
        axis.set_velocity(500.1)
    with pytest.raises(ParameterError, match="velocity_mm_s"):
        axis.set_velocity(float("nan"))


@PROPERTY
@given(st.lists(st.tuples(st.integers(0, 400), st.floats(-1.0, 1.0)), min_size=1, max_size=6),
       st.sampled_from([0.001, 0.004]))
def test_random_jog_commands_within_limits(commands, period):
    limits = Limits(300.0, 2000.0, 3e4)
    axis = Jog(AxisConfig(limits, period, 0.004, 0.004, 0.0), position_mm=0.0)
    outs = []
    for wait, frac in commands:
        axis.set_velocity(frac * limits.vel)
        outs += steps(axis, wait)
    axis.stop()
    outs += settle(axis)
    assert outs[-1].state in (PtpState.READY, PtpState.STOP)
    assert outs[-1].velocity_mm_s == 0.0 and outs[-1].acceleration_mm_s2 == 0.0
    assert_stream_within_limits(outs, limits, period, 0.0)
