"""FMU export of the tracker (``cantrack fmu build`` / ``cantrack fmu check``).

``CanTracker.fmu`` is an FMI 2.0 Co-Simulation FMU built with pythonfmu from
``controller/fmu/tracker_slave.py`` plus a copy of the tracker core; see ``build`` for what
is bundled and what the importing tool needs, ``tracker_slave`` for the variables and the
step semantics.  Building and checking need the optional dependencies (``cantrack[fmu]``:
pythonfmu, fmpy); importing this package does not.
"""

from .build import (CONVEYOR_MODEL, HOST_REQUIREMENTS, TRACKER3_MODEL, TRACKER_MODEL,
                    FmuBuildError, build_conveyor_fmu, build_tracker_fmu, build_tracker_fmu3,
                    core_files)

__all__ = ["CONVEYOR_MODEL", "HOST_REQUIREMENTS", "TRACKER3_MODEL", "TRACKER_MODEL",
           "FmuBuildError", "build_conveyor_fmu", "build_tracker_fmu", "build_tracker_fmu3",
           "core_files"]
