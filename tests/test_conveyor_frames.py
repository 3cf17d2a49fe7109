"""Moving frames: linear (type 0), rotary (type 1, "Theory of operation"), rotary decoupled
(type 2), the page's errors, limits, master sources and the window."""

from __future__ import annotations

import math
import random

import pytest

from controller.conveyor import (FRAME_LIMITS, ArcGeometryError, EncoderSource, FrameSource,
                                 Location, MovingFrame, RobotGroup, SimulatedAxis, SourceState,
                                 TriggerEntry, Window, WindowPosition, arc_from_points,
                                 frame_limits)
from controller.conveyor.frames import RotaryGeometry
from controller.conveyor.location import (q_axis_angle, q_mul, q_rotate, v_cross, v_dot, v_norm,
                                          v_sub)
from controller.errors import ParameterError, StateError
from controller.limits import CartesianLimits, Limits
from controller.tracking import TrackError, TrackerParams

T = 0.002


def item(values, dr=0.0, inverse=False, frame="cnv"):
    return TriggerEntry(1, frame, tuple(values), dr, inverse)


def rotary(type_=1, up_ori=None, **kw):
    up = Location((600.0, -400.0, 0.0), up_ori or q_axis_angle((0, 0, 1), 30.0))
    return MovingFrame("rot", [SimulatedAxis.constant_speed(20.0)], type=type_, upstream=up,
                       arc_point=(1000.0, 0.0, 0.0), downstream=(600.0, 400.0, 0.0),
                       up_master=0.0, down_master=180.0, **kw)


def random_arc(rng):
    """Three points on a random circle in a random plane, arc angle 20..340 deg."""
    c = tuple(rng.uniform(-500, 500) for _ in range(3))
    n = tuple(rng.gauss(0, 1) for _ in range(3))
    nn = v_norm(n)
    n = tuple(x / nn for x in n)
    a = v_cross(n, (1.0, 0.0, 0.0) if abs(n[0]) < 0.9 else (0.0, 1.0, 0.0))
    a = tuple(x / v_norm(a) for x in a)
    b = v_cross(n, a)
    r = rng.uniform(50, 2000)
    alpha = rng.uniform(20, 340)
    t0 = rng.uniform(0, 360)

    def at(t):
        t = math.radians(t0 + t)
        return tuple(ci + r * (ai * math.cos(t) + bi * math.sin(t)) for ci, ai, bi in
                     zip(c, a, b))
    return c, n, r, alpha, at(0.0), at(rng.uniform(0.1, 0.9) * alpha), at(alpha)


# -- Theory of operation: the arc -----------------------------------------------------------
def test_theory_of_operation_arc_from_three_points_center_radius_alpha():
    rng = random.Random(3)
    for _ in range(200):
        c, n, r, alpha, p1, p2, p3 = random_arc(rng)
        g = arc_from_points(p1, p2, p3)
        assert g.center == pytest.approx(c, abs=1e-6 * r)
        assert g.radius == pytest.approx(r, rel=1e-9)
        assert g.alpha_deg == pytest.approx(alpha, abs=1e-7)
        assert v_dot(g.axis, n) == pytest.approx(1.0)       # running direction P1 -> P2 -> P3
        assert v_dot(g.start, g.normal) == pytest.approx(0.0, abs=1e-12)
        assert v_cross(g.start, g.normal) == pytest.approx(g.axis)   # v = start x normal
        # UpStream[1].pos = center + R*start (x = 0); DownStream[1] at x = alpha
        assert g.position(0.0) == pytest.approx(p1, abs=1e-6)
        assert g.position(g.alpha_deg) == pytest.approx(p3, abs=1e-6)


def test_theory_of_operation_arc_reading_upstream_is_x0_not_the_literal_formula():
    """The page's MF = (R+dR)(start sin x + normal cos x) + center puts x = 0 at
    center + R*normal; we keep UpStream[1].pos = center + R*start (documented)."""
    f = rotary()
    g = f.geometry()
    it = item([0.0])
    here0 = f.point(it, [SourceState(0.0)]).here
    assert here0.pos == pytest.approx((600.0, -400.0, 0.0))
    literal = tuple(c + g.radius * (s * math.sin(0) + n * math.cos(0)) for c, s, n in
                    zip(g.center, g.start, g.normal))
    assert v_norm(v_sub(literal, here0.pos)) > 100.0
    assert f.center == pytest.approx((600.0, 0.0, 0.0))
    assert f.radius == pytest.approx(400.0) and f.alpha == pytest.approx(180.0)
    assert f.start == pytest.approx((0.0, -1.0, 0.0)) and f.normal == pytest.approx((1.0, 0, 0))


def test_theory_of_operation_orientation_is_q_of_x_plus_delta_about_v():
    delta = 30.0
    f = rotary(up_ori=q_axis_angle((0, 0, 1), delta))
    g: RotaryGeometry = f.geometry()
    assert g.axis == pytest.approx((0, 0, 1))
    assert g.delta_deg == pytest.approx(delta) and g.ori_about_axis
    for m in (0.0, 17.0, 90.0, 180.0):     # master 0..180 -> x 0..180 deg
        p = f.point(item([0.0]), [SourceState(m)])
        assert p.here.angle_to(Location((0, 0, 0), q_axis_angle(g.axis, m + delta))) < 1e-9
        assert p.ang == pytest.approx(m)


def test_theory_of_operation_rotary_frame_is_a_rigid_rotation_about_the_arc_axis():
    """Position and orientation turn together (a rotary table), also in a tilted plane and
    with an UpStream orientation that is not a rotation about v (Q(x, v)*UpStream.ori)."""
    rng = random.Random(7)
    c, n, r, alpha, p1, p2, p3 = random_arc(rng)
    up = Location.from_axis_angle(p1, (0.3, 0.5, 0.8), 70.0)
    f = MovingFrame("r", [SimulatedAxis.constant_speed(1.0)], type=1, upstream=up,
                    arc_point=p2, downstream=p3, deg_per_unit=1.0)
    g = f.geometry()
    assert not g.ori_about_axis
    for x in (0.0, 10.0, alpha / 2, alpha):
        q = q_axis_angle(g.axis, x)
        expected_pos = tuple(ci + d for ci, d in zip(g.center, q_rotate(q, v_sub(p1, g.center))))
        here = f.point(item([0.0]), [SourceState(x)]).here
        assert here.pos == pytest.approx(expected_pos, abs=1e-7)
        assert here.angle_to(Location((0, 0, 0), q_mul(q, up.ori))) < 1e-7


def test_theory_of_operation_radius_offset_dr_and_rates():
    f = rotary()
    it = item([0.0], dr=-50.0)
    p = f.point(it, [SourceState(45.0, 20.0, 4.0)])     # x = 45 deg, 20 deg/s, 4 deg/s^2
    assert v_norm(v_sub(p.here.pos, f.center)) == pytest.approx(350.0)
    w, wd = math.radians(20.0), math.radians(4.0)
    assert v_norm(p.vel) == pytest.approx(350.0 * w)
    radial = tuple(x / 350.0 for x in v_sub(p.here.pos, f.center))
    assert v_dot(p.acc, radial) == pytest.approx(-350.0 * w * w)    # centripetal
    assert v_norm(p.acc) == pytest.approx(math.hypot(350 * w * w, 350 * wd))
    assert p.ang_vel == 20.0 and p.ang_acc == 4.0
    assert f.zero(it).pos == pytest.approx((600.0, -350.0, 0.0))


def test_theory_of_operation_type_2_rotary_decoupled_orientation_does_not_follow_the_master():
    f = rotary(type_=2)
    p = f.point(item([0.0]), [SourceState(90.0, 20.0)])
    assert p.here.angle_to(f.upstream) < 1e-12
    assert p.ang == 0.0 and p.ang_vel == 0.0
    assert p.here.pos == pytest.approx((1000.0, 0.0, 0.0))


def test_theory_of_operation_running_angle_from_up_and_down_master():
    f = MovingFrame("r", [SimulatedAxis.constant_speed(1.0)], type=1, upstream=(0, -100, 0),
                    arc_point=(100, 0, 0), downstream=(0, 100, 0), up_master=1000.0,
                    down_master=5000.0)
    # x = alpha*(m - trig)/(Down - Up): 180 deg over 4000 units, from the trigger value
    assert f.coords(item([2500.0]), [SourceState(4500.0)])[0] == pytest.approx((90.0,))


# -- where the page puts the errors ----------------------------------------------------------
def collinear_frame():
    return MovingFrame("bad", [SimulatedAxis.constant_speed(1.0)], type=1,
                       upstream=(0, 0, 0), arc_point=(100, 0, 0), downstream=(300, 0, 0),
                       up_master=0.0, down_master=10.0)


def test_theory_of_operation_collinear_points_error_when_querying_center_unlinked():
    f = collinear_frame()          # constructing and setting type 1 is no error
    assert f.type == 1
    with pytest.raises(ArcGeometryError, match="collinear"):
        f.center
    with pytest.raises(ArcGeometryError):
        arc_from_points((0, 0, 0), (0, 0, 0), (1, 1, 0))


def test_theory_of_operation_collinear_points_error_when_assigned_to_masterframe():
    f = collinear_frame()
    robot = RobotGroup("r", TrackerParams(sample_time_s=T, planner="softmc"))
    with pytest.raises(ArcGeometryError):
        robot.master_frame = f
    assert robot.master_frame is None and robot.slave == 0 and f.engaged_by is None


def test_theory_of_operation_circle_precalculation_when_tracking_starts():
    """"At this moment also the circle pre-calculation will be activated (computing the
    circle center, start & normal vectors)": a linked frame keeps its pre-calculated circle."""
    f = rotary()
    robot = RobotGroup("r", TrackerParams(sample_time_s=T, planner="softmc"))
    robot.master_frame = f
    f.arc_point = (700.0, -400.0, 0.0)     # now collinear-ish with up/down? not: change shape
    f.downstream = (800.0, -400.0, 0.0)   # collinear with UpStream and ArcPoint
    assert f.center == pytest.approx((600.0, 0.0, 0.0))   # the pre-calculated circle
    robot.stop()
    robot.update()
    robot.update()   # the stop of a not-moving robot ends at once
    assert not f.linked
    with pytest.raises(ArcGeometryError):
        f.center


def test_type_change_while_engaged_is_an_error_and_rotary_needs_nof_1():
    f = MovingFrame("cnv", [SimulatedAxis.constant_speed(1.0)])
    robot = RobotGroup("r", TrackerParams(sample_time_s=T, planner="softmc"))
    robot.master_frame = f
    with pytest.raises(StateError, match="engaged"):
        f.type = 1
    two = MovingFrame("xy", [SimulatedAxis.constant_speed(1.0), SimulatedAxis.constant_speed(2.0)])
    for t in (1, 2):
        with pytest.raises(ParameterError, match="NOF = 1"):
            two.type = t
    with pytest.raises(ParameterError, match="must be 0"):
        two.type = 4
    with pytest.raises(ParameterError, match=r"type 3 \(group\) is made by MovingFrame.group"):
        two.type = 3
    with pytest.raises(StateError, match="rotary frames"):
        two.center


def test_functional_change_2_frame_limits_names_and_defaults():
    L = FRAME_LIMITS
    assert (L.trans.vel, L.trans.acc, L.trans.jerk) == (1000, 1000, 1000)
    assert (L.rot.vel, L.rot.acc, L.rot.jerk) == (100, 100, 100)
    assert MovingFrame("cnv").limits is FRAME_LIMITS
    assert frame_limits(JerkMaxRot=7.0, AccelerationMaxTrans=3.0) == CartesianLimits(
        Limits(1000.0, 3.0, 1000.0), Limits(100.0, 100.0, 7.0))
    with pytest.raises(ParameterError, match=r"<Moving Frame>\.VelocityMaxTrans \(=0\)"):
        frame_limits(VelocityMaxTrans=0)
    with pytest.raises(ParameterError, match="VelocityMaxTran: unknown limit"):
        frame_limits(VelocityMaxTran=1.0)
    with pytest.raises(ParameterError, match="must be a CartesianLimits"):
        MovingFrame("cnv", limits=Limits(1.0, 1.0, 1.0))  # type: ignore[arg-type]
    f = MovingFrame("cnv", [SimulatedAxis.constant_speed(1.0)], limits=frame_limits(
        VelocityMaxTrans=500.0))
    it = item([0.0])
    assert f.check_limits(f.point(it, [SourceState(0.0, 400.0)])) == TrackError.NONE
    assert f.check_limits(f.point(it, [SourceState(0.0, 600.0)])) == TrackError.MASTER_VELOCITY
    assert f.check_limits(f.point(it, [SourceState(0.0, 10.0, 2000.0)])) == \
        TrackError.MASTER_ACCELERATION
    r = rotary()
    assert r.check_limits(r.point(it, [SourceState(0.0, 150.0)])) == TrackError.MASTER_VELOCITY


# -- linear frames and sources ---------------------------------------------------------------
def test_linear_frame_nof_sources_along_directions_scaled_to_mm():
    xy = MovingFrame("xy", [SimulatedAxis.constant_speed(1.0), SimulatedAxis.constant_speed(1.0)],
                     directions=[(2, 0, 0), (0, 1, 1)], scales=[0.5, 2.0],
                     origin=Location.from_axis_angle((10, 20, 30), (0, 0, 1), 15))
    p = xy.point(item([100.0, 10.0]), [SourceState(300.0, 40.0), SourceState(20.0, -5.0, 1.0)])
    s = math.sqrt(0.5)
    assert p.here.pos == pytest.approx((10 + 100.0, 20 + 20 * s, 30 + 20 * s))
    assert p.vel == pytest.approx((20.0, -10 * s, -10 * s))
    assert p.acc == pytest.approx((0.0, 2 * s, 2 * s))
    assert p.here.angle_to(xy.origin) == 0.0 and xy.zero().isclose(xy.origin)


def test_encoder_source_counts_scaling_and_wraparound():
    modulus = 4096
    speed = 3000.0                                         # counts/s
    raw = [int(round(speed * k * T)) % modulus for k in range(400)]
    enc = EncoderSource(T, modulus=modulus, counts=raw, window=8)
    f = MovingFrame("cnv", [enc], scales=[0.1])             # 0.1 mm per count
    it = None
    for k in range(400):
        f.update(k, k * T)
        if k == 10:
            it = item(f.source_values())
    st = f.master[0]
    assert st.pos == pytest.approx(speed * 399 * T, abs=0.5)    # unwrapped past 4096 several times
    assert st.vel == pytest.approx(speed, rel=1e-3)
    assert f.point(it).here.pos[0] == pytest.approx(0.1 * speed * (399 - 10) * T, abs=0.1)
    assert enc.log == raw
    with pytest.raises(ParameterError):
        EncoderSource(T, modulus=-1)


def test_master_source_can_be_another_moving_frame():
    belt = MovingFrame("belt", [SimulatedAxis.constant_speed(100.0)], scales=[2.0])
    follower = MovingFrame("f", [FrameSource(belt)], directions=[(0, 1, 0)])
    for k in range(3):
        belt.update(k, k * T)
        follower.update(k, k * T)
    assert follower.master[0].pos == pytest.approx(2.0 * 100.0 * 2 * T)
    assert follower.master[0].vel == pytest.approx(200.0)


# -- the window ------------------------------------------------------------------------------
def test_window_declaration_limits_relative_to_trigger_and_direction_flag():
    w = Window.single(100.0, 500.0)
    assert w.classify((50.0,)) == WindowPosition.BEFORE
    assert w.classify((100.0,)) == WindowPosition.INSIDE
    assert w.classify((500.1,)) == WindowPosition.AFTER
    # direction flag: the item comes from the downstream side (negative displacement)
    assert w.classify((-300.0,), inverse=True) == WindowPosition.INSIDE
    assert w.classify((300.0,), inverse=True) == WindowPosition.BEFORE
    assert w.classify((-600.0,), inverse=True) == WindowPosition.AFTER
    assert w.time_to_enter((0.0,), (200.0,)) == pytest.approx(0.5)
    assert w.time_to_leave((0.0,), (200.0,)) == pytest.approx(2.5)
    assert math.isinf(w.time_to_leave((0.0,), (0.0,)))
    xy = Window((0.0, -50.0), (400.0, 50.0))
    assert xy.classify((10.0, 60.0)) == WindowPosition.AFTER
    assert xy.classify((10.0, -60.0)) == WindowPosition.BEFORE
    with pytest.raises(ParameterError, match="below"):
        Window.single(500.0, 100.0)
