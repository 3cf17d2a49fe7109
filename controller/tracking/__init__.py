"""The tracking core: pure, deterministic, no I/O, threads or clocks.

Public API::

    from controller.tracking import Tracker, TrackerParams, MotionState, Limits
    tracker = Tracker(TrackerParams(sample_time_s=0.002, planner="softmc"), MotionState.at(0, 0, 0))
    tracker.engage()
    out = tracker.update(master_state)      # once per sample

``Limits`` is :class:`controller.limits.Limits` (the one limits type of every layer),
exported here too because ``TrackerParams`` takes it.
"""

from .estimator import MasterEstimate, MasterEstimator, unwrap_counts
from .planner import PLANNER_CODES, PLANNERS, planner_factory
from .tracker import Tracker
from ..limits import Limits
from .types import (Imfs, Mode, MotionState, Rates, SoftMcOptions, TrackError,
                    TrackerOutput, TrackerParams, TrackState)

__all__ = [
    "Imfs", "Limits", "MasterEstimate", "MasterEstimator", "Mode", "MotionState", "PLANNERS",
    "PLANNER_CODES", "Rates", "SoftMcOptions", "TrackError", "Tracker", "TrackerOutput",
    "TrackerParams", "TrackState", "planner_factory", "unwrap_counts",
]
