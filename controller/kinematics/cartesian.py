"""Cartesian gantry: one linear drive per axis x, y, z (mm) and a rotary tool axis c (deg).

The joints are the pose's coordinates: joint x = pose x, ..., joint c = the tool angle.
A gantry may leave out axes (e.g. x and y only); a left-out coordinate is not driven.
Scale, zero offset and direction of each drive are the counts converter's business
(:mod:`controller.kinematics.counts`), not the kinematics'.
"""

from __future__ import annotations

from collections.abc import Sequence
from operator import itemgetter

from ..errors import ParameterError
from ..tracking import MotionState
from ..tracking.values import mypyc_attr

AXES = ("x", "y", "z", "c")


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class CartesianGantry:
    name = "cartesian"

    def __init__(self, axes: Sequence[str]) -> None:
        axes = tuple(axes)
        unknown = [a for a in axes if a not in AXES]
        if unknown or not axes or len(set(axes)) != len(axes):
            raise ParameterError(f"cartesian axes (={', '.join(axes)}) must be distinct "
                                 f"names out of {', '.join(AXES)}")
        self.axes = axes
        self._slot = tuple(AXES.index(a) for a in axes)
        #: the axes' values out of (x, y, z, c), as a tuple (one axis: a 1-tuple slice)
        i0 = self._slot[0]
        self._pick = itemgetter(*self._slot) if len(self._slot) > 1 else \
            itemgetter(slice(i0, i0 + 1))

    def joints(self, pose: MotionState) -> tuple[float, ...]:
        p = pose.pos
        return self._pick((p[0], p[1], p[2], pose.ang))

    def joint_velocities(self, pose: MotionState) -> tuple[float, ...]:
        v = pose.vel
        return self._pick((v[0], v[1], v[2], pose.ang_vel))

    def pose(self, joints: Sequence[float]) -> MotionState:
        full = [0.0, 0.0, 0.0, 0.0]
        for i, value in zip(self._slot, joints):
            full[i] = float(value)
        return MotionState.at(*full)


def create(axes: Sequence[str]) -> CartesianGantry:
    return CartesianGantry(axes)
