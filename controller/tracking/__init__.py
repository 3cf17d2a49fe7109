"""The tracking core: pure, deterministic, no I/O, threads or clocks.

Public API::

    from controller.tracking import Tracker, TrackerParams, MotionState, Limits
    tracker = Tracker(TrackerParams(sample_time_s=0.002, planner="softmc"), MotionState.at(0, 0, 0))
    tracker.engage()
    out = tracker.update(master_state)      # once per sample

``Limits`` is :class:`controller.limits.Limits` (the one limits type of every layer),
exported here too because ``TrackerParams`` takes it.

Compiled core (docs/architecture.md "Compiled core"): the install compiles this package's
modules with mypyc where it can (setup.py).  ``NATIVE`` tells whether the compiled modules are
the ones running; ``CANTRACK_PURE=1`` in the environment forces the Python source.  The build
records the hash of each compiled source (``_native_manifest.json``): a source changed since
(an editable checkout edited after ``pip install -e .``) makes the package run the Python
source, with one warning naming the file, instead of the old compiled code.
"""

import hashlib as _hashlib
import importlib.machinery as _machinery
import importlib.util as _util
import json as _json
import os as _os
import sys as _sys
import warnings as _warnings


class _PureFinder:
    """Meta-path finder: the submodules of this package from their ``.py`` source (never a
    compiled extension module beside it)."""

    def __init__(self, package: str, directory: str) -> None:
        self.prefix = package + "."
        self.directory = directory

    def find_spec(self, fullname, path=None, target=None):  # noqa: ANN001 -- importlib's API
        if not fullname.startswith(self.prefix):
            return None
        name = fullname[len(self.prefix):]
        source = _os.path.join(self.directory, name + ".py")
        if "." in name or not _os.path.isfile(source):
            return None
        return _util.spec_from_file_location(
            fullname, source, loader=_machinery.SourceFileLoader(fullname, source))


def _stale_source(directory: str) -> "str | None":
    """The first compiled module whose source differs from the build's manifest (or that has
    no compiled module), or None when the build matches the sources; "" without a build."""
    try:
        with open(_os.path.join(directory, "_native_manifest.json"), encoding="utf-8") as f:
            recorded = _json.load(f)["sources"]
    except (OSError, ValueError, KeyError, TypeError):
        return ""
    for name, digest in sorted(recorded.items()):
        source = _os.path.join(directory, name)
        try:
            with open(source, "rb") as f:
                if _hashlib.sha256(f.read()).hexdigest() != digest:
                    return source
        except OSError:
            return source
    return None


def _choose() -> str:
    """"pure" (forced), "stale" (a changed source: pure) or "auto" (the finders' choice)."""
    if _os.environ.get("CANTRACK_PURE", "") not in ("", "0"):
        return "pure"
    directory = _os.path.dirname(__file__)
    stale = _stale_source(directory)
    if stale:
        _warnings.warn(
            f"{stale}: changed since the tracking core was compiled: running the Python "
            f"source instead (rebuild with pip install -e .)", RuntimeWarning, stacklevel=3)
        return "stale"
    return "auto"


_MODE = _choose()
if _MODE != "auto" and not any(isinstance(f, _PureFinder) and f.prefix == __name__ + "."
                               for f in _sys.meta_path):
    _sys.meta_path.insert(0, _PureFinder(__name__, _os.path.dirname(__file__)))

from .estimator import MasterEstimate, MasterEstimator, unwrap_counts  # noqa: E402
from .planner import PLANNER_CODES, PLANNERS, planner_factory  # noqa: E402
from .tracker import Tracker  # noqa: E402
from ..limits import Limits  # noqa: E402
from .types import (Imfs, Mode, MotionState, Rates, SoftMcOptions, TrackError,  # noqa: E402
                    TrackerOutput, TrackerParams, TrackState)
from . import tracker as _tracker_module  # noqa: E402

#: True when the compiled (mypyc) modules run, False for the Python source
NATIVE: bool = not str(getattr(_tracker_module, "__file__", "")).endswith(".py")

__all__ = [
    "Imfs", "Limits", "MasterEstimate", "MasterEstimator", "Mode", "MotionState", "NATIVE",
    "PLANNERS", "PLANNER_CODES", "Rates", "SoftMcOptions", "TrackError", "Tracker",
    "TrackerOutput", "TrackerParams", "TrackState", "planner_factory", "unwrap_counts",
]
