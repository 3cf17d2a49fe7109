"""Kinematics (Cartesian gantry) and the one place where mm/deg become counts."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.errors import ParameterError
from controller.kinematics import AxisScale, CountsConverter, EncoderScale, create
from controller.tracking import MotionState


def test_cartesian_joints_and_pose():
    kin = create("cartesian", ["x", "y", "z", "c"])
    pose = MotionState((1.0, 2.0, 3.0), (4.0, 5.0, 6.0), (0.0, 0.0, 0.0), 7.0, 8.0, 0.0)
    assert kin.joints(pose) == (1.0, 2.0, 3.0, 7.0)
    assert kin.joint_velocities(pose) == (4.0, 5.0, 6.0, 8.0)
    assert kin.pose((1.0, 2.0, 3.0, 7.0)) == MotionState.at(1, 2, 3, 7)
    sub = create("cartesian", ["y", "x"])
    assert sub.joints(pose) == (2.0, 1.0)
    assert sub.pose((2.0, 1.0)) == MotionState.at(1, 2, 0, 0)


def test_registry_errors():
    with pytest.raises(ParameterError, match="must be one of cartesian"):
        create("delta", ["x"])
    with pytest.raises(ParameterError, match="distinct names"):
        create("cartesian", ["x", "x"])


def test_axis_scale_sign_zero_and_rounding():
    a = AxisScale("x", 10000.0, zero=100.0, sign=-1, min=0.0, max=500.0)
    assert a.to_counts(100.0) == 0
    assert a.to_counts(100.25) == -2500
    assert a.from_counts(-2500) == pytest.approx(100.25)
    assert a.limit_counts() == (-4_000_000, 1_000_000)
    assert a.velocity_counts(10.0) == -100000.0
    with pytest.raises(ParameterError, match="outside INTEGER32"):
        AxisScale("x", 1e9).to_counts(10.0)
    with pytest.raises(ParameterError, match="sign"):
        AxisScale("x", 1.0, sign=0)
    conv = CountsConverter([AxisScale("x", 10.0), AxisScale("c", 1000.0, min=-180, max=180)])
    assert conv.to_counts((1.05, -90.0)) == (10, -90000)  # round half to even
    assert conv.outside_limits((0.0, 190.0)) == [("c", 190.0)]


@given(st.integers(-2**30, 2**30), st.floats(1.0, 1e5), st.floats(-1e3, 1e3),
       st.sampled_from([1, -1]))
def test_counts_round_trip(counts, cpu, zero, sign):
    a = AxisScale("x", cpu, zero=zero, sign=sign)
    assert a.to_counts(a.from_counts(counts)) == counts


def test_encoder_unwrap_across_6002h():
    enc = EncoderScale(40.96, 16777216)
    raw = 16777216 - 100
    assert enc.belt_mm(raw) == 0.0
    assert enc.belt_mm(50) == pytest.approx(150 / 40.96)  # forward over the wrap
    assert enc.belt_mm(16777216 - 10) == pytest.approx(90 / 40.96)  # and back
    rev = EncoderScale(10.0, 1000, sign=-1)
    rev.belt_mm(995)
    assert rev.belt_mm(5) == pytest.approx(-1.0)
