"""The virtual robot's small motions: jerk-limited profile, absolute/relative, superposition,
shift (V ⊕ c)."""

from __future__ import annotations

import numpy as np
import pytest

from controller.conveyor import MOTION_LIMITS, Location, Motion, SCurve, VirtualRobot
from controller.conveyor.location import q_axis_angle

T = 0.002


@pytest.mark.parametrize("dist", [0.001, 1.0, 30.0, 500.0, 5000.0])
def test_scurve_reaches_the_distance_within_its_limits(dist):
    V, A, J = 800.0, 5000.0, 100000.0
    c = SCurve(dist, V, A, J)
    t = np.linspace(0.0, c.duration, 4001)
    s = np.array([c.at(x) for x in t])
    assert s[-1, 0] == dist and s[-1, 1] == 0.0
    assert s[:, 1].max() <= V * (1 + 1e-9) and np.abs(s[:, 2]).max() <= A * (1 + 1e-9)
    assert np.all(np.diff(s[:, 0]) >= -1e-12)
    jerk = np.abs(np.diff(s[:, 2]) / np.diff(t))
    assert jerk.max() <= J * (1 + 1e-6)


def test_virtual_robot_absolute_relative_superposed_and_shift():
    v = VirtualRobot(Location.at(0, 0, 0), T, MOTION_LIMITS)
    target = Location((100.0, 50.0, 0.0), q_axis_angle((0, 0, 1), 30.0))
    v.enter(Motion(target))
    v.enter(Motion(Location.at(0, 0, 20), relative=True, superpose=True))
    for _ in range(2):                       # both start together (the second superposed)
        for m in v.due():
            v.start(m)
        v.step()
    v.shift(Location.at(5, 0, 0))            # V ← V ⊕ c: current location and motion ends move
    while v.busy:
        for m in v.due():
            v.start(m)
        v.step()
    assert v.location.pos == pytest.approx((105.0, 50.0, 20.0), abs=1e-9)
    assert v.location.angle_to(target) < 1e-9
    assert v.velocity == (0.0, 0.0, 0.0)
    v.enter(Motion(Location.at(0, 0, 0)))    # absolute target after a shift: reached exactly
    while v.busy:
        for m in v.due():
            v.start(m)
        v.step()
    assert v.location.isclose(Location.at(0, 0, 0), 1e-9)
