"""Triangular-pulse planner (controller/motion/profile.py): hand-computed moves, the fixed
DECCEL formula, exact ends, re-planning from arbitrary states, limits (property-based)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from controller.errors import ParameterError
from controller.limits import Limits
from controller.motion.profile import (
    KinematicState,
    Phase,
    ProfileFollower,
    integrate_step,
    integrate_step_thesis_literal,
    plan_position,
    plan_rest_to_rest,
    plan_stop,
    plan_velocity,
    rest_to_rest_peak_velocity,
    thesis_decel_acceleration,
    triangle_pulse,
)

PROPERTY = settings(derandomize=True, database=None, deadline=None, max_examples=80,
                    suppress_health_check=[HealthCheck.too_slow])


def seg_table(profile):
    return [(s.phase, s.duration_s, s.jerk_mm_s3) for s in profile.segments]


def profile_extremes(profile, n=400):
    """Max |v|, |a|, |j| of a profile: exact at knots and segment ends, plus a dense grid."""
    vmax = amax = jmax = 0.0
    t0 = 0.0
    for seg, knot in zip(profile.segments, profile.knots, strict=True):
        jmax = max(jmax, abs(seg.jerk_mm_s3))
        dur = seg.duration_s if math.isfinite(seg.duration_s) else 0.0
        for f in np.linspace(0.0, 1.0, 9):
            _, v, a = integrate_step(knot.position_mm, knot.velocity_mm_s,
                                     knot.acceleration_mm_s2, seg.jerk_mm_s3, f * dur)
            vmax, amax = max(vmax, abs(v)), max(amax, abs(a))
        t0 += dur
    return vmax, amax, jmax


# ------------------------------------------------------------------------------------------
# Hand-computed moves
# ------------------------------------------------------------------------------------------

def test_hand_computed_long_move_acceleration_bound_with_const():
    # V = 500 mm/s, A = 5000 mm/s^2, J = 1e5 mm/s^3, d = 150 mm.
    # A^2/J = 250 mm/s < V, so a triangle up to V is acceleration-bound:
    #   T2 = V/A = 0.1 s, k = V/T2^2 = 5e4 mm/s^3 (<= J), peak k*T2 = 5000 = A.
    #   ACCEL lasts 2*T2 = 0.2 s and covers (0 + 500)*0.1 = 50 mm; DECEL the same.
    #   CONST covers 150 - 100 = 50 mm at 500 mm/s: Tc = 0.1 s.  Total 0.5 s.
    limits = Limits(500.0, 5000.0, 1e5)
    p = plan_rest_to_rest(0.0, 150.0, limits)
    assert p.phases == (Phase.ACCEL, Phase.CONST, Phase.DECEL)
    assert p.phase_duration_s(Phase.ACCEL) == pytest.approx(0.2, abs=1e-12)
    assert p.phase_duration_s(Phase.CONST) == pytest.approx(0.1, abs=1e-12)
    assert p.phase_duration_s(Phase.DECEL) == pytest.approx(0.2, abs=1e-12)
    assert p.duration_s == pytest.approx(0.5, abs=1e-12)
    assert [abs(s.jerk_mm_s3) for s in p.segments if s.phase is not Phase.CONST] == \
        pytest.approx([5e4] * 4, rel=1e-12)
    assert p.state_at(0.1).acceleration_mm_s2 == pytest.approx(5000.0, rel=1e-12)
    assert p.state_at(0.2).position_mm == pytest.approx(50.0, abs=1e-9)
    assert p.state_at(0.2).velocity_mm_s == pytest.approx(500.0, abs=1e-9)
    assert p.state_at(0.3).position_mm == pytest.approx(100.0, abs=1e-9)
    assert abs(p.end.position_mm - 150.0) <= 1e-9
    assert p.end.velocity_mm_s == 0.0 and p.end.acceleration_mm_s2 == 0.0


def test_hand_computed_short_move_jerk_bound_never_reaches_full_speed():
    # V = 500, A = 2000, J = 1e4, d = 20 mm.
    # Jerk-bound guess: d = 2*vp^(3/2)/sqrt(J) -> vp = (20*100/2)^(2/3) = 1000^(2/3) = 100 mm/s
    # (<= A^2/J = 400, so the peak a = sqrt(vp*J) = 1000 < A holds).  T2 = sqrt(100/1e4)
    # = 0.1 s, k = J; ACCEL 0.2 s, CONST 0 s, DECEL 0.2 s: total 0.4 s, peak v 100 < V.
    limits = Limits(500.0, 2000.0, 1e4)
    assert rest_to_rest_peak_velocity(20.0, limits) == pytest.approx(100.0, rel=1e-12)
    p = plan_rest_to_rest(0.0, 20.0, limits)
    assert p.phases == (Phase.ACCEL, Phase.CONST, Phase.DECEL)  # CONST present, 0 s
    assert p.phase_duration_s(Phase.CONST) == pytest.approx(0.0, abs=1e-12)
    assert p.duration_s == pytest.approx(0.4, abs=1e-12)
    assert p.state_at(0.2).velocity_mm_s == pytest.approx(100.0, rel=1e-12)
    assert p.state_at(0.1).acceleration_mm_s2 == pytest.approx(1000.0, rel=1e-12)
    assert abs(p.end.position_mm - 20.0) <= 1e-9


def test_hand_computed_short_move_acceleration_bound():
    # V = 500, A = 2000, J = 1e5, d = 20 mm.  A^2/J = 40 mm/s.
    # Jerk-bound guess (20*sqrt(1e5)/2)^(2/3) = 215 > 40, so acceleration-bound:
    # d = 2*vp^2/A -> vp = sqrt(20*2000/2) = 141.42 mm/s; T2 = vp/A = 0.0707 s,
    # k = A/T2 = 28284 mm/s^3 < J; total 4*T2 = 0.28284 s.
    limits = Limits(500.0, 2000.0, 1e5)
    p = plan_rest_to_rest(0.0, 20.0, limits)
    assert p.duration_s == pytest.approx(4 * math.sqrt(20000.0) / 2000.0, rel=1e-12)
    assert abs(p.segments[0].jerk_mm_s3) == pytest.approx(2000.0 / (math.sqrt(20000.0) / 2000.0))
    assert p.state_at(p.duration_s / 4).acceleration_mm_s2 == pytest.approx(2000.0, rel=1e-12)
    assert abs(p.end.position_mm - 20.0) <= 1e-9


def test_negative_move_mirrors_positive():
    limits = Limits(300.0, 3000.0, 5e4)
    fwd = plan_rest_to_rest(10.0, 110.0, limits)
    back = plan_rest_to_rest(10.0, -90.0, limits)
    assert [(ph, d) for ph, d, _ in seg_table(fwd)] == [(ph, d) for ph, d, _ in seg_table(back)]
    assert [j for *_, j in seg_table(fwd)] == [-j for *_, j in seg_table(back)]


def test_triangle_pulse_shapes():
    limits = Limits(1000.0, 1000.0, 1e4)  # A^2/J = 100 mm/s
    t2, k = triangle_pulse(25.0, limits)  # jerk-bound: T2 = sqrt(25/1e4) = 0.05
    assert (t2, k) == (pytest.approx(0.05), pytest.approx(1e4))
    t2, k = triangle_pulse(400.0, limits)  # acc-bound: T2 = 400/1000 = 0.4, k = 2500
    assert (t2, k) == (pytest.approx(0.4), pytest.approx(2500.0))
    assert triangle_pulse(0.0, limits) == (0.0, 0.0)


def test_zero_move_is_empty():
    p = plan_rest_to_rest(5.0, 5.0, Limits(1, 1, 1))
    assert p.duration_s == 0.0 and p.segments == () and p.end.position_mm == 5.0


def test_planner_rejects_non_finite():
    limits = Limits(1, 1, 1)
    with pytest.raises(ParameterError, match="target_mm"):
        plan_rest_to_rest(0.0, math.nan, limits)
    with pytest.raises(ParameterError, match="velocity_mm_s"):
        plan_position(KinematicState(0.0, math.inf), 1.0, limits)
    with pytest.raises(ParameterError, match=r"\[-1, 1\]|\[-1.0, 1.0\]"):
        plan_velocity(KinematicState(0.0), 2.0, limits)


# ------------------------------------------------------------------------------------------
# The thesis' DECCEL formula: printed form vs fixed form
# ------------------------------------------------------------------------------------------

def _decel_pulse_exact(t, y0, v0, k, t2):
    """Closed-form DECCEL pulse (a = -k t, then k t - 2 T2 k), for reference."""
    if t <= t2:
        return y0 + v0 * t - k * t ** 3 / 6.0, v0 - k * t * t / 2.0
    ym = y0 + v0 * t2 - k * t2 ** 3 / 6.0
    vm = v0 - k * t2 * t2 / 2.0
    u = t - t2
    return ym + vm * u - k * t2 * u * u / 2.0 + k * u ** 3 / 6.0, vm - k * t2 * u + k * u * u / 2.0


def test_thesis_decel_acceleration_matches_profile():
    limits = Limits(500.0, 5000.0, 1e5)
    p = plan_rest_to_rest(0.0, 150.0, limits)
    t_dec = 0.3
    k = abs(p.segments[-1].jerk_mm_s3)
    for t in np.linspace(0.0, 0.2, 41):
        assert p.state_at(t_dec + t).acceleration_mm_s2 == pytest.approx(
            thesis_decel_acceleration(t, k, 0.1), abs=1e-8)


def test_literal_decel_position_is_off_iteratively_and_the_fix_is_exact():
    # DECCEL from v0 = 500 mm/s: k = 5e4 mm/s^3, T2 = 0.1 s, T = 5 ms (40 samples).
    k, t2, T, v0 = 5e4, 0.1, 0.005, 500.0
    y_fix = y_lit = 0.0
    v_fix = v_lit = v0
    a_prev = 0.0
    max_err_lit = max_err_fix = 0.0
    for i in range(1, 41):
        a = thesis_decel_acceleration(i * T, k, t2) if i < 40 else 0.0
        jerk = (a - a_prev) / T
        y_fix, v_fix, _ = integrate_step(y_fix, v_fix, a_prev, jerk, T)
        y_lit, v_lit, _ = integrate_step_thesis_literal(y_lit, v_lit, a_prev, jerk, T)
        y_ex, v_ex = _decel_pulse_exact(i * T, 0.0, v0, k, t2)
        # the velocity rule is the same and exact for both
        assert v_fix == pytest.approx(v_ex, abs=1e-9) and v_lit == pytest.approx(v_ex, abs=1e-9)
        # the printed position rule is off by (a - a_entry)*T^2/3 (telescoped per-step error)
        assert y_lit - y_ex == pytest.approx(a * T * T / 3.0, abs=1e-9)
        max_err_lit = max(max_err_lit, abs(y_lit - y_ex))
        max_err_fix = max(max_err_fix, abs(y_fix - y_ex))
        a_prev = a
    assert max_err_fix <= 1e-9
    # at the peak deceleration (5000 mm/s^2): 5000 * 25e-6 / 3 = 0.0417 mm, 4 % of a 1 mm
    # drive increment... and 42 counts at 1 um resolution
    assert max_err_lit == pytest.approx(5000.0 * T * T / 3.0, rel=1e-6)
    # the full pulse returns a to 0, where the printed form happens to be right again
    assert y_lit == pytest.approx(y_fix, abs=1e-9)


def test_literal_decel_position_drifts_when_read_from_state_entry():
    # The thesis writes t as "the time since entering the state": with t0 = entry,
    # y = y0 + (v0 + a*t/2)*t uses the current a for the whole time since entry.  In the
    # first half of the pulse the exact value is y0 + v0 t - k t^3/6; the printed form gives
    # y0 + v0 t - k t^3/2: an error k t^3/3 that grows with t (the move misses its target).
    k, t2, v0 = 5e4, 0.1, 500.0
    errors_lit, errors_fix = [], []
    for t in (0.02, 0.04, 0.06, 0.08, 0.1):
        a = thesis_decel_acceleration(t, k, t2)
        y_lit, _, _ = integrate_step_thesis_literal(0.0, v0, 0.0, a / t, t)
        y_fix, _, _ = integrate_step(0.0, v0, 0.0, a / t, t)
        y_ex, _ = _decel_pulse_exact(t, 0.0, v0, k, t2)
        errors_lit.append(y_ex - y_lit)
        errors_fix.append(abs(y_ex - y_fix))
    assert errors_lit == pytest.approx([k * t ** 3 / 3.0 for t in (0.02, 0.04, 0.06, 0.08, 0.1)],
                                       rel=1e-9)
    assert all(b > a for a, b in itertools.pairwise(errors_lit))  # it drifts
    assert errors_lit[-1] == pytest.approx(16.6667, rel=1e-4)  # 16.7 mm at the apex
    assert max(errors_fix) <= 1e-9


def test_follower_matches_closed_form_with_off_grid_boundaries():
    limits = Limits(437.0, 3123.0, 7.7e4)
    p = plan_rest_to_rest(-3.0, 97.3, limits)
    T = 0.001
    samples = p.sample(T)
    assert samples[-1] == KinematicState(97.3, 0.0, 0.0)
    for i, s in enumerate(samples[:-1], start=1):
        ref = p.state_at(i * T)
        assert s.position_mm == pytest.approx(ref.position_mm, abs=1e-9)
        assert s.velocity_mm_s == pytest.approx(ref.velocity_mm_s, abs=1e-9)
        assert s.acceleration_mm_s2 == pytest.approx(ref.acceleration_mm_s2, abs=1e-7)
    # the integrated end before the final snap is already on the target
    assert abs(p.end.position_mm - 97.3) <= 1e-9


# ------------------------------------------------------------------------------------------
# Properties over random moves and random start states
# ------------------------------------------------------------------------------------------

@st.composite
def limits_strategy(draw):
    vel = draw(st.floats(5.0, 2000.0))
    t_acc = draw(st.floats(0.005, 0.5))  # time to reach V at full A
    t_jerk = draw(st.floats(0.001, 0.3))  # time to reach A at full J
    acc = vel / t_acc
    return Limits(vel, acc, acc / t_jerk)


def _check_profile(p, limits, target):
    vmax, amax, jmax = profile_extremes(p)
    assert vmax <= limits.vel * (1 + 1e-9)
    assert amax <= limits.acc * (1 + 1e-9)
    assert jmax <= limits.jerk * (1 + 1e-9)
    assert abs(p.end.position_mm - target) <= 1e-9 * max(1.0, abs(target))
    assert all(s.duration_s >= 0.0 for s in p.segments)


@PROPERTY
@given(limits_strategy(), st.floats(-1000.0, 1000.0), st.floats(-1000.0, 1000.0))
def test_rest_to_rest_within_limits_and_exact(limits, start, target):
    p = plan_rest_to_rest(start, target, limits)
    _check_profile(p, limits, target)
    if start != target:
        assert p.phases == (Phase.ACCEL, Phase.CONST, Phase.DECEL)
    # the general planner from rest is the analytic one
    assert plan_position(KinematicState(start), target, limits) == p


@PROPERTY
@given(limits_strategy(), st.floats(-500.0, 500.0), st.floats(0.0, 1.0),
       st.floats(-800.0, 800.0))
def test_replan_from_mid_move_state_within_limits_and_exact(limits, distance, frac, new_target):
    first = plan_rest_to_rest(0.0, distance, limits)
    state = first.state_at(frac * first.duration_s)
    p = plan_position(state, new_target, limits)
    assert p.start == state
    _check_profile(p, limits, new_target)


@PROPERTY
@given(limits_strategy(), st.floats(-1.0, 1.0), st.floats(0.0, 1.0), st.floats(-1.0, 1.0))
def test_velocity_and_stop_profiles_within_limits(limits, v_frac, frac, v_new_frac):
    jog = plan_velocity(KinematicState(0.0), v_frac * limits.vel, limits)
    pulse = sum(s.duration_s for s in jog.segments[:-1])
    state = jog.state_at(frac * pulse)
    changed = plan_velocity(state, v_new_frac * limits.vel, limits)
    vmax, amax, jmax = profile_extremes(changed)
    assert vmax <= limits.vel * (1 + 1e-9)
    assert amax <= limits.acc * (1 + 1e-9) and jmax <= limits.jerk * (1 + 1e-9)
    cruise = changed.knots[-1]
    assert cruise.velocity_mm_s == pytest.approx(v_new_frac * limits.vel,
                                                 abs=1e-9 * limits.vel)
    assert abs(cruise.acceleration_mm_s2) <= 1e-9 * limits.acc
    stop = plan_stop(state, limits)
    _check_profile(stop, limits, stop.target_mm)
    if stop.segments:  # stopping never reverses
        assert all(k.velocity_mm_s * state.velocity_mm_s >= -1e-9 for k in stop.knots)


def test_replan_target_behind_brakes_and_reverses():
    limits = Limits(500.0, 5000.0, 1e5)
    first = plan_rest_to_rest(0.0, 150.0, limits)
    state = first.state_at(0.25)  # in CONST at 500 mm/s, position 75 mm
    p = plan_position(state, 20.0, limits)
    assert p.phases[:2] == (Phase.DECEL, Phase.ACCEL)  # brake to 0, then reverse
    velocities = [k.velocity_mm_s for k in p.knots]
    assert max(velocities) == pytest.approx(500.0) and min(velocities) < 0.0
    assert abs(p.end.position_mm - 20.0) <= 1e-9


def test_replan_mid_decel_to_slightly_farther_target_does_not_reverse():
    limits = Limits(500.0, 5000.0, 1e5)
    first = plan_rest_to_rest(0.0, 150.0, limits)
    for t in (0.32, 0.36, 0.42, 0.47):
        state = first.state_at(t)
        p = plan_position(state, 150.5, limits)
        samples = p.sample(0.0005)
        assert min(s.velocity_mm_s for s in samples) >= -1e-9
        assert max(s.position_mm for s in samples) <= 150.5 + 1e-9


def test_follower_time_is_sample_counter():
    p = plan_rest_to_rest(0.0, 1.0, Limits(10.0, 100.0, 1000.0))
    f = ProfileFollower(p, 0.01)
    for _ in range(7):
        f.step()
    assert f.samples == 7
    assert f.state.position_mm == pytest.approx(p.state_at(0.07).position_mm, abs=1e-12)


@PROPERTY
@given(limits_strategy(), st.floats(-1.0, 1.0), st.floats(0.0, 1.0))
def test_stop_duration_bound(limits, v_frac, frac):
    # the CAN shell waits at most 2 (V/A + A/J) for a stop (--max-time): any state reached
    # within the limits stops within that
    jog = plan_velocity(KinematicState(0.0), v_frac * limits.vel, limits)
    pulse = sum(s.duration_s for s in jog.segments[:-1])
    state = jog.state_at(frac * pulse)
    stop = plan_stop(state, limits)
    bound = 2.0 * (limits.vel / limits.acc + limits.acc / limits.jerk)
    assert stop.duration_s <= bound
