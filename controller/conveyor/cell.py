"""A work cell: moving frames and robot groups stepped together, one sample at a time.

Per sample k (time k*T): every frame reads its master sources (frames that use another frame
as a source after that frame), then every robot group computes its setpoint.  Commands
(TRIGGER, MasterFrame, MOVES, ...) given between two steps act in the next one; a TRIGGER
latches the master values of the last step.  Sample 0 (the frames' first read) happens at
construction, so triggers can be given before the first step.
"""

from __future__ import annotations

from typing import Sequence

from ..errors import ParameterError
from ..tracking.values import mypyc_attr
from .frame import MovingFrame
from .robot import RobotGroup, RobotOutput
from .sources import FrameSource


def _ordered(frames: Sequence[MovingFrame]) -> list[MovingFrame]:
    """Frames sorted so that a frame comes after the frames it uses as sources."""
    out: list[MovingFrame] = []
    pending = list(frames)
    while pending:
        progress = False
        for f in list(pending):
            deps = [s.frame for s in f.sources if isinstance(s, FrameSource)]
            if all(d in out or d not in frames for d in deps):
                out.append(f)
                pending.remove(f)
                progress = True
        if not progress:
            names = ", ".join(f.name for f in pending)
            raise ParameterError(f"moving frames use each other as master sources in a "
                                 f"cycle: {names}")
    return out


@mypyc_attr(allow_interpreted_subclasses=True)  # (copyable: deepcopy, snapshots)
class ConveyorCell:
    """Frames and robots on a common sample clock (``sample_time_s``).

    Order in a sample: the frames (a frame after the frames it uses as sources), then the
    robots - those whose TCP is a group frame's master first, each such group frame updated
    right after its master robot.
    """

    def __init__(self, frames: Sequence[MovingFrame], robots: Sequence[RobotGroup],
                 sample_time_s: float | None = None) -> None:
        group = [f for f in frames if f.group_source is not None]
        self.frames = _ordered([f for f in frames if f.group_source is None]) + group
        # group frames (a robot's TCP as master) update right after their master robot, and
        # the robots that are masters update first, so the TCP read is this sample's
        masters = [src.robot for f in group if (src := f.group_source) is not None]
        self.robots = [r for r in robots if r in masters] + \
            [r for r in robots if r not in masters]
        self._after: dict[str, list[MovingFrame]] = {}
        for f in group:
            if (src := f.group_source) is not None:
                self._after.setdefault(src.robot.name, []).append(f)
        T = sample_time_s if sample_time_s is not None else (
            self.robots[0].T if self.robots else None)
        if T is None:
            raise ParameterError("sample_time_s must be given for a cell without robots")
        for r in self.robots:
            if abs(r.T - T) > 1e-15:
                raise ParameterError(f"robot {r.name!r}: sample time {r.T!r} s differs from "
                                     f"the cell's {T!r} s")
        self.T = float(T)
        self.k = 0
        for f in self.frames:
            f.update(0, 0.0)

    def robot(self, name: str) -> RobotGroup:
        for r in self.robots:
            if r.name == name:
                return r
        raise KeyError(name)

    def frame(self, name: str) -> MovingFrame:
        for f in self.frames:
            if f.name == name:
                return f
        raise KeyError(name)

    def step(self) -> dict[str, RobotOutput]:
        """One sample: frames, then robots; returns each robot's output."""
        self.k += 1
        t = self.k * self.T
        for f in self.frames:
            if f.group_source is None:
                f.update(self.k, t)
        out = {}
        for r in self.robots:
            out[r.name] = r.update()
            for f in self._after.get(r.name, ()):
                f.update(self.k, t)
        return out

    def run(self, n: int) -> list[dict[str, RobotOutput]]:
        return [self.step() for _ in range(n)]
