"""The approach-planner interface and the registry of planners (python-can style, lazy).

An approach planner moves one channel (3-D translation in mm, or the 1-D rotation in deg)
from the robot's state to the master's.  The tracker calls ``reset(p, v, a)`` at engage with
the setpoint of the previous sample, then ``step(mp, mv, ma)`` once per sample with the
master's state at that sample; ``step`` returns the new setpoint (p, v, a) and whether the
channel is synchronised; ``mj``, the master's jerk, is given when known (conditioned master).  After that the tracker copies the master: planners never run in
SYNCED.  Planners are deterministic and deep-copyable (the FMU saves and restores them).
"""

from __future__ import annotations

import importlib
from typing import Callable, Protocol

from ..errors import ParameterError
from ..limits import Limits
from .types import TrackerParams
from .vec import Vec


class ChannelPlanner(Protocol):
    name: str

    def reset(self, p: Vec, v: Vec, a: Vec) -> None: ...

    def step(self, mp: Vec, mv: Vec, ma: Vec,
             mj: Vec | None = None) -> tuple[Vec, Vec, Vec, bool]: ...


#: planner name -> "module:factory"; factory(limits, params) -> ChannelPlanner.  The modules
#: are named relative to this package (not "controller.tracking..."), so the core also works
#: as a copy under another package name (the FMUs bundle it under a private name).
PLANNERS: dict[str, str] = {
    "softmc": f"{__package__}.softmc:create",
    "optimal": f"{__package__}.optimal:create",
}

#: FMU / CLI integer codes of the planners
PLANNER_CODES: dict[int, str] = {0: "softmc", 1: "optimal"}


def planner_factory(name: str) -> Callable[[Limits, TrackerParams], ChannelPlanner]:
    """The factory of the planner called ``name`` (imported on first use)."""
    try:
        target = PLANNERS[name]
    except KeyError:
        raise ParameterError(
            f"planner (={name!r}) must be one of {', '.join(sorted(PLANNERS))}") from None
    module_name, attr = target.split(":")
    return getattr(importlib.import_module(module_name), attr)
