"""De-sync on the path: the sine-acceleration stop (hand-computed cases and invariants)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, strategies as st

from controller.tracking.desync import Desync, LinearPath, SineStop


def sample(stop: SineStop, dt: float = 1e-4):
    t = np.arange(0.0, stop.duration + 5 * dt, dt)
    s, v, a = np.array([stop.at(x) for x in t]).T
    return t, s, v, a


def test_short_stop_hand_computed():
    # v0 = 300 mm/s, a0 = 0, A = 2e4, J = 4e5: no plateau; two sine ramps to
    # a_p = -sqrt(2*J*v0/pi) = -8740.387 mm/s^2; duration = sqrt(2*pi*v0/J) = 0.0686479 s;
    # the speed falls symmetrically, so the distance is v0*duration/2 = 10.2972 mm.
    stop = SineStop(300.0, 0.0, 2e4, 4e5)
    assert len(stop.segments) == 2
    assert stop.segments[0].a_end == pytest.approx(-math.sqrt(2 * 4e5 * 300 / math.pi))
    assert stop.duration == pytest.approx(math.sqrt(2 * math.pi * 300 / 4e5), rel=1e-12)
    assert stop.end_position == pytest.approx(300 * stop.duration / 2, rel=1e-12)


def test_long_stop_has_a_plateau_hand_computed():
    # v0 = 2000 mm/s: sqrt(2*J*v0/pi) = 22568 > A -> ramps to -A of pi*A/(2J) = 0.0785398 s
    # each, losing A*0.0785398 = 1570.80 mm/s together; plateau (2000 - 1570.80)/A = 0.0214602 s.
    stop = SineStop(2000.0, 0.0, 2e4, 4e5)
    ramp = math.pi * 2e4 / (2 * 4e5)
    assert [round(s.duration, 9) for s in stop.segments] == [
        round(ramp, 9), round((2000 - 2e4 * ramp) / 2e4, 9), round(ramp, 9)]
    assert stop.duration == pytest.approx(2 * ramp + (2000 - 2e4 * ramp) / 2e4)


@given(v0=st.floats(0.0, 3000.0), a0=st.floats(-3e4, 3e4),
       acc=st.floats(1e3, 5e4), jerk=st.floats(1e4, 1e6))
def test_stop_is_smooth_and_within_limits(v0, a0, acc, jerk):
    stop = SineStop(v0, a0, acc, jerk)
    t, s, v, a = sample(stop, dt=max(stop.duration, 1e-3) / 4000)
    # ends at rest
    end = stop.at(stop.duration)
    assert end[1] == 0.0 and end[2] == 0.0
    last = stop.segments[-1] if stop.segments else None
    if last is not None:
        s_end, v_end, a_end = last.at(last.duration)
        assert abs(v_end) <= 1e-9 * max(1.0, v0) + 1e-9
        assert abs(a_end) <= 1e-9 * max(1.0, abs(a0)) + 1e-9
    # acceleration within max(A, |a0|); jerk within J (finite differences of a)
    assert np.abs(a).max() <= max(acc, abs(a0)) * (1 + 1e-9) + 1e-9
    dt = t[1] - t[0]
    j = np.diff(a) / dt
    assert np.abs(j).max() <= jerk * (1 + 1e-6) + 1e-6
    # velocity and position continuous (no jumps larger than the acceleration allows)
    assert np.abs(np.diff(v)).max() <= max(acc, abs(a0)) * dt * 1.001 + 1e-9
    # a0 = 0 stops go monotonically forward
    if a0 == 0.0:
        assert (np.diff(s) >= -1e-12).all()


def test_linear_path_stops_along_the_master_direction():
    d = Desync.linear((10.0, 20.0, 30.0), (300.0, 400.0, 0.0), (0.0, 0.0, 0.0), 2e4, 4e5)
    assert d.path.direction == pytest.approx((0.6, 0.8, 0.0))
    p, v, a = d.state(d.stop.duration + 1.0)
    dist = d.stop.end_position
    assert p == pytest.approx((10 + 0.6 * dist, 20 + 0.8 * dist, 30.0))
    assert v == (0.0, 0.0, 0.0) and a == (0.0, 0.0, 0.0)
    p0, v0, a0 = d.state(0.0)
    assert p0 == pytest.approx((10.0, 20.0, 30.0)) and v0 == pytest.approx((300.0, 400.0, 0.0))


def test_initial_acceleration_reading():
    # from the current acceleration (algorithm page) vs from zero (overview page)
    cur = Desync.linear((0.0,), (300.0,), (500.0,), 2e4, 4e5, from_current_acceleration=True)
    zero = Desync.linear((0.0,), (300.0,), (500.0,), 2e4, 4e5, from_current_acceleration=False)
    assert cur.state(0.0)[2] == pytest.approx((500.0,))
    assert zero.state(0.0)[2] == pytest.approx((0.0,))
    assert cur.stop.end_position > zero.stop.end_position  # it keeps speeding up a little


def test_path_protocol_accepts_other_paths():
    # an arc path (as the rotary conveyor will supply) plugs into Desync unchanged
    class Arc:
        def evaluate(self, s, sd, sdd):
            R = 100.0
            x = s / R
            return ((R * math.cos(x), R * math.sin(x), 0.0),
                    (-sd * math.sin(x), sd * math.cos(x), 0.0),
                    (-sdd * math.sin(x) - sd * sd / R * math.cos(x),
                     sdd * math.cos(x) - sd * sd / R * math.sin(x), 0.0))
    d = Desync(Arc(), SineStop(100.0, 0.0, 2e4, 4e5))
    p, v, _ = d.state(d.stop.duration)
    assert math.hypot(p[0], p[1]) == pytest.approx(100.0)
    assert isinstance(LinearPath((0.0,), (1.0,)).evaluate(2.0, 1.0, 0.0), tuple)
