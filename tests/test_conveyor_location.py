"""Locations and the overview page's operators ⊕, ⊖, ':' ("Theory of operation" -> "Tracking",
"Proof of concept"), checked exactly and algebraically."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.conveyor.location import (Location, q_axis_angle, q_conj, q_inv, q_mul,
                                          q_rotate, q_slerp, q_to_axis_angle, q_twist_angle)
from controller.errors import ParameterError

finite = st.floats(-1000, 1000, allow_nan=False)
vec = st.tuples(finite, finite, finite)
axis = st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)).filter(
    lambda a: math.sqrt(sum(x * x for x in a)) > 0.1)
angle = st.floats(-360, 360, allow_nan=False)


@st.composite
def locations(draw):
    return Location.from_axis_angle(draw(vec), draw(axis), draw(angle))


def close(a: Location, b: Location, tol=1e-9) -> bool:
    scale = 1.0 + max(abs(x) for x in a.pos + b.pos)
    return a.distance_to(b) <= tol * scale and a.angle_to(b) <= 1e-6


def test_theory_of_operation_oplus_ominus_exactly_as_the_page():
    a = Location.from_axis_angle((1, 2, 3), (0, 0, 1), 30)
    b = Location.from_axis_angle((10, -20, 5), (1, 0, 0), 45)
    c = a.oplus(b)
    assert c.pos == (11.0, -18.0, 8.0)                      # C.pos = A.pos + B.pos
    assert c.ori == pytest.approx(q_mul(a.ori, b.ori))     # C.ori = A.ori * B.ori
    d = a.ominus(b)
    assert d.pos == (-9.0, 22.0, -2.0)                      # C.pos = A.pos - B.pos
    assert d.ori == pytest.approx(q_mul(q_inv(b.ori), a.ori))   # C.ori = B.ori^-1 * A.ori


def test_compound_is_the_rigid_transform_composition():
    a = Location.from_axis_angle((100, 0, 0), (0, 0, 1), 90)
    b = Location.at(10, 0, 0)
    c = a.compound(b)
    assert c.pos == pytest.approx((100, 10, 0))
    assert a.compound(a.inverse()).isclose(Location())
    assert a.inverse().compound(a).isclose(Location())


@given(locations(), locations(), locations())
def test_oplus_associative_and_ominus_undoes_it_from_the_left(a, b, c):
    assert close(a.oplus(b).oplus(c), a.oplus(b.oplus(c)))
    # the Q.E.D. step: A ⊕ (B ⊖ A) = B
    assert close(a.oplus(b.ominus(a)), b)
    # A ⊖ B = B⁻ ⊕ A
    assert close(a.ominus(b), b.oplus_inverse().oplus(a))


def test_ominus_is_not_a_right_inverse_of_oplus_in_general():
    a = Location.from_axis_angle((0, 0, 0), (0, 0, 1), 90)
    b = Location.from_axis_angle((0, 0, 0), (1, 0, 0), 90)
    assert not a.oplus(b).ominus(b).isclose(a)   # documented: B⁻¹·A·B ≠ A


@given(locations(), locations(), locations(), locations())
def test_proof_of_concept_qed_identity_with_base_and_tool(base, tool, mf0, mft):
    """setpoint := base:Robot_real:tool with Robot_real = base⁻¹:(base:Rv:tool ⊕ [MF(t) ⊖
    MF(0)]):tool⁻¹ and Robot_virtual := base⁻¹:cmd:tool⁻¹, cmd = MF(0): setpoint = MF(t)."""
    cmd = mf0
    robot_virtual = base.inverse().compound(cmd).compound(tool.inverse())
    inner = base.compound(robot_virtual).compound(tool).oplus(mft.ominus(mf0))
    robot_real = base.inverse().compound(inner).compound(tool.inverse())
    setpoint = base.compound(robot_real).compound(tool)
    assert close(setpoint, mft, 1e-8)


def test_proof_of_concept_compound_formula_leaves_the_path_but_the_page_formula_does_not():
    """'Proof of concept': Robot_virtual : [MF(t) : MF(0)⁻¹] moves the end point according to
    the virtual robot's orientation (off the conveyor path); ⊕/⊖ does not."""
    mf0 = Location.at(0, 0, 0)
    mft = Location.at(100, 0, 0)
    rv = Location.from_axis_angle((0, 0, 0), (0, 0, 1), 90)   # robot turned by 90 deg
    via_compound = rv.compound(mft.compound(mf0.inverse()))
    via_page = rv.oplus(mft.ominus(mf0))
    assert via_page.pos == pytest.approx(mft.pos)
    assert via_compound.pos == pytest.approx((0, 100, 0))


def test_quaternion_helpers():
    q = q_axis_angle((0, 0, 1), 90)
    assert q_rotate(q, (1, 0, 0)) == pytest.approx((0, 1, 0))
    ax, ang = q_to_axis_angle(q)
    assert ax == pytest.approx((0, 0, 1)) and ang == pytest.approx(90)
    assert q_twist_angle(q_mul(q_axis_angle((0, 0, 1), 40), q_axis_angle((1, 0, 0), 0)),
                         (0, 0, 1)) == pytest.approx(40)
    assert q_slerp((1, 0, 0, 0), q, 0.5) == pytest.approx(q_axis_angle((0, 0, 1), 45))
    assert q_mul(q, q_conj(q)) == pytest.approx((1, 0, 0, 0))


def test_location_validation_names_the_value():
    with pytest.raises(ParameterError, match="unit quaternion"):
        Location((0, 0, 0), (2, 0, 0, 0))
    with pytest.raises(ParameterError, match="3 finite numbers"):
        Location((0, math.nan, 0))
    with pytest.raises(ParameterError, match="rotation axis"):
        Location.from_axis_angle((0, 0, 0), (0, 0, 0), 10)
