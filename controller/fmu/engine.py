"""The FMU-independent part of the CanTracker FMUs: variables, stepping, errors, state.

Used by the FMI 2.0 slave (``tracker_slave.py``, pythonfmu) and the FMI 3.0 slave
(``tracker3_slave.py``, pythonfmu3); bundled into both FMUs as ``fmu/engine.py`` of the
FMU's private package next to the tracker core (see ``build``).  No pythonfmu import here.
Statuses: the engine logs each refusal with the status of the call (``report(msg, level)``);
the FMUs' front library (``front.c``) returns the worst status logged during a call, since
pythonfmu can return only OK or Fatal from most calls.

Variables: ``VARIABLES`` (the FMU contract), value reference = position in the table; the
values live in one list ``TrackerEngine.v`` indexed by value reference, which the slaves'
get/set calls index directly (pythonfmu's generic path costs a lambda call per value).

Time: one internal sample per ``sample_time`` T [s] on the grid t0 + k*T (t0 = the start
time).  A communication step must start where the previous one ended and end on the grid
(both within ``STEP_TOLERANCE`` * T); it runs the samples up to its grid point, a step that
reaches no new one is a no-op (``do_step``); anything else is refused (``Discard``).  The
master inputs are sampled at the step
start t and extrapolated at constant acceleration (``MotionState.extrapolated``) to each
internal sample time t + i*T, i = 1..n; the tracker computes the setpoint of that time
(``Tracker.update``).  The outputs at the end of the step are the setpoint at t + n*T.
Before the first step the outputs are the robot at (x0, y0, z0, c0), at rest, state OFF.

Raw encoder input (``master_input=1``, docs/spec/master-conditioning.md): master_x,
master_y, master_z [mm] and master_c [deg] are what a conveyor encoder gives -- positions in
counts of ``encoder_resolution`` (``encoder_resolution_rot``), sampled ``encoder_latency``
samples before the step start -- and the velocity and acceleration inputs are not used.
Each axis has a ``MasterConditioner`` (Kalman estimator on the constant-jerk model, outlier
gate, coasting, output within the frame's VelocityMax/AccelerationMax/JerkMax =
vel_max_master/acc_max_master/jerk_max_master at exitInitializationMode; for the rotation
the core's default master_max_rot), made at exitInitializationMode: it gets the step's
positions at the step's first internal sample and coasts over the others (one encoder
sample per communication step), and gives the tracker the belt's position, velocity,
acceleration and jerk at each setpoint's time (lag compensated by prediction).  The same
conditioner as the simulator's ``conditioning:`` section (latency_samples =
encoder_latency + 1) and the CAN shell's ``conveyor.conditioning``: for the same samples
the setpoints are bit-identical (tests/test_conditioning_shells.py).  The input
``encoder_time_offset`` [s] says how much later than nominal the step's sample was taken
(known arrival jitter, as the simulator's ``jitter`` and the CAN shell's SYNC lateness;
non-finite: the step is refused, Discard, nothing changed).  Outputs:
``master_status`` (0 STARTING: warming up, 1 OK, 2 COASTING: the step's sample was rejected,
3 LOST; the worst axis) and ``master_outliers`` (samples rejected so far).  A rising edge of
``engage`` while the status is 0 or 3 waits (one warning) and acts at the first step after
the status is 1 or 2.  ``encoder_max_outliers`` outliers in a row are a lost master: a
tracking tracker de-syncs with error MASTER_LOST (one warning naming the axis and the size),
and the conditioner starts again from the next sample.  ``master_input=0`` (the default):
the master's state as below, master_status 1.

Engage: a rising edge of ``engage`` (seen at a step start, compared with the value at the
previous step start; ``false`` before the first step) creates a new ``Tracker`` from the
current parameters, starting from the current setpoint, and engages it with ``mode``; a
falling edge starts the de-sync.  Both act at the first internal sample of the step.  So
tunable parameters take effect at the next engage.

Fixed parameters (``variability=fixed``: sample_time, mode, planner, x0, y0, z0, c0, the
master input and encoder parameters) are
frozen at exitInitializationMode; every engage uses the frozen values plus the current
tunables.  Setting a fixed parameter afterwards is refused: logged as an error naming the
variable and the value (the call returns Error through the front library; an exception
would be Fatal in pythonfmu) and ignored; setting it to the value it already has is
accepted silently.  Reset the instance to change them.

Master inputs must be finite: a step that starts with a NaN or infinite master input is
refused (``Discard`` in FMI 2 and FMI 3) before anything changes, with an error naming the
inputs and their values; outputs, tracker state, engage edge and time stay as they were, so
the importer can set finite values and repeat the step (or restore a saved FMU state).  The
instance is not failed.  (Not treated as a lost master, ``MASTER_LOST``: a non-finite value
in a co-simulation is a modelling or connection fault the importer should see, not a
physical event to ride through.)

State: ``get_state`` / ``set_state`` save and restore *all* internal state (the whole
``Tracker`` incl. planners, every variable value, the last engage value, the failure flag);
a state can be restored any number of times.  The serialized form is a pickle (trust only
states you saved yourself).

Errors: every message goes to the FMI logger (category ``logStatus<level>``) and to the
Python logger ``cantrack.fmu``.  FMI 2 (pythonfmu) forwards messages only when the importer
instantiated with loggingOn=true, which the slave cannot see: the Python logger gets them at
ERROR (a Python host without logging configuration prints them on stderr).  FMI 3
(pythonfmu3) forwards errors and warnings whatever loggingOn: the Python logger gets them at
DEBUG only (no second copy on stderr).  Messages carry no trailing line break.

An exception inside a step is logged with its traceback and the step is refused
(``Error``); the instance then
refuses further steps (each refusal repeats the first error) until a saved FMU state is set
or it is reset, because its internal state may be half-updated.  An invalid tunable parameter
at an engage edge is found before anything changes: that step is refused (``Discard``) and
may be repeated after fixing the value.  Invalid parameters at initialisation (checked
against their declared ranges, ``parameter_errors``; planner 1 without ruckig) are one
logged error line, no traceback: exitInitializationMode returns Error (front library) and
every step is refused with that line.  They are not raised, because pythonfmu turns an
exception into ``Fatal`` and then crashes the process on ``Terminate`` / ``FreeInstance``
(pythonfmu 0.7.0, pythonfmu3 0.3.4).
"""

from __future__ import annotations

import copy
import logging
import math
import pickle
import traceback
from collections.abc import Callable
from enum import IntEnum
from math import isfinite

from ..errors import ParameterError
from ..tracking import (
    PLANNER_CODES,
    Imfs,
    Limits,
    Mode,
    MotionState,
    Tracker,
    TrackerParams,
    TrackError,
    TrackState,
)
from ..tracking import softmc as _softmc  # noqa: F401  (import eagerly, see below)
from ..tracking.conditioning import (
    ConditionedMaster,
    ConditioningParams,
    EncoderModel,
    EventKind,
    MasterConditioner,
    MasterStatus,
)
from ..tracking.types import MAX_FACTOR
from .runtime import EngineStateMixin, track_instance

__all__ = ["EngineStateMixin", "TrackerEngine", "VARIABLES", "VR", "tracker_params"]

# The planners are imported lazily by the core (planner_factory).  Import them now, while the
# FMU's resources folder is on sys.path, so a later instance never needs a folder that the
# importer may have deleted meanwhile.  The optimal planner needs ruckig; if it cannot be
# imported here, instantiation warns (``runtime.ruckig_warning``) and exitInitializationMode
# refuses planner=1.
try:
    from ..tracking import optimal as _optimal  # noqa: F401
    OPTIMAL_IMPORT_ERROR: str | None = None
except Exception as _exc:
    OPTIMAL_IMPORT_ERROR = f"{type(_exc).__name__}: {' '.join(str(_exc).split())}"

#: Python-side logger: pythonfmu forwards FMI log messages only when the importer instantiated
#: the FMU with loggingOn=true, so errors also go here (a Python host shows them on stderr).
LOG = logging.getLogger("cantrack.fmu")

#: relative tolerance of "a communication step is a whole multiple of sample_time"
STEP_TOLERANCE = 1e-6
#: format of the pickled FMU state
STATE_FORMAT = 1

_DEFAULTS = TrackerParams()


class MasterInput(IntEnum):
    """What the master inputs carry (parameter ``master_input``)."""

    STATE = 0  #: the master's position, velocity and acceleration at the step start
    ENCODER = 1  #: raw encoder positions, through the master conditioner


#: the largest ``encoder_latency`` [samples]: the conditioner's latency is one more (the
#: step's first setpoint is one sample after the step start) and at most 100
MAX_ENCODER_LATENCY = 99


def _enum_doc(enum) -> str:
    return ", ".join(f"{int(m)} {m.name}" for m in enum)


#: Units: name -> (exponents of SI base units, factor to the SI unit)
UNITS: dict[str, tuple[dict[str, int], float]] = {
    "1": ({}, 1.0),  # dimensionless (filter_factor, damping_factor)
    "s": ({"s": 1}, 1.0),
    "mm": ({"m": 1}, 1e-3),
    "mm/s": ({"m": 1, "s": -1}, 1e-3),
    "mm/s2": ({"m": 1, "s": -2}, 1e-3),
    "mm/s3": ({"m": 1, "s": -3}, 1e-3),
    "deg": ({"rad": 1}, math.pi / 180.0),
    "deg/s": ({"rad": 1, "s": -1}, math.pi / 180.0),
    "deg/s2": ({"rad": 1, "s": -2}, math.pi / 180.0),
    "deg/s3": ({"rad": 1, "s": -3}, math.pi / 180.0),
}

_sync, _rot = _DEFAULTS.sync_trans, _DEFAULTS.sync_rot

#: ``min`` of the parameters that must be > 0.  FMI bounds are inclusive, so the declared
#: minimum is a small positive floor, not 0: the FMU accepts exactly the declared range
#: (``parameter_errors``), and the core accepts every value in it.
POSITIVE_FLOOR = 1e-9
_POSITIVE = {"min": repr(POSITIVE_FLOOR)}

#: The FMU's variables, in value-reference order: (name, type, causality, variability, start,
#: unit, description, extra XML attributes).  Outputs have no start (initial=calculated).
VARIABLES: list[tuple] = [
    # -- fixed parameters
    ("sample_time", "Real", "parameter", "fixed", 0.001, "s",
     "Tracker sample period T; every communication step must be a whole multiple of it",
     {"min": "1e-05", "max": "0.1"}),
    ("mode", "Integer", "parameter", "fixed", int(Mode.ABSOLUTE), None,
     "Approach mode used at each engage (<robot>.slave): 3 absolute (onto the master), "
     "5 relative (keep the offset to the master at engage)",
     {"min": "3", "max": "5", "enumeration": "Mode"}),
    ("planner", "Integer", "parameter", "fixed", 1, None,
     "Approach planner: " + ", ".join(f"{k} {v}" for k, v in sorted(PLANNER_CODES.items()))
     + " (1 = the default planner, needs ruckig)", {"min": "0", "max": "1"}),
    # -- tunable parameters (take effect at the next engage)
    ("vel_sync", "Real", "parameter", "tunable", _sync.vel, "mm/s",
     "VelocitySyncTran: translation velocity limit while synchronising (next engage)", _POSITIVE),
    ("acc_sync", "Real", "parameter", "tunable", _sync.acc, "mm/s2",
     "AccelerationSyncTran: translation acceleration limit while synchronising", _POSITIVE),
    ("jerk_sync", "Real", "parameter", "tunable", _sync.jerk, "mm/s3",
     "JerkSyncTran: translation jerk limit while synchronising", _POSITIVE),
    ("vel_desync", "Real", "parameter", "tunable", _sync.vel, "mm/s",
     "VelocityDeSyncTran: translation velocity limit of the de-sync", _POSITIVE),
    ("acc_desync", "Real", "parameter", "tunable", _sync.acc, "mm/s2",
     "AccelerationDeSyncTran: translation deceleration of the de-sync", _POSITIVE),
    ("jerk_desync", "Real", "parameter", "tunable", _sync.jerk, "mm/s3",
     "JerkDeSyncTran: translation jerk of the de-sync", _POSITIVE),
    ("vel_sync_rot", "Real", "parameter", "tunable", _rot.vel, "deg/s",
     "VelocitySyncRot: rotation velocity limit while synchronising", _POSITIVE),
    ("acc_sync_rot", "Real", "parameter", "tunable", _rot.acc, "deg/s2",
     "AccelerationSyncRot: rotation acceleration limit while synchronising", _POSITIVE),
    ("jerk_sync_rot", "Real", "parameter", "tunable", _rot.jerk, "deg/s3",
     "JerkSyncRot: rotation jerk limit while synchronising", _POSITIVE),
    ("vel_desync_rot", "Real", "parameter", "tunable", _rot.vel, "deg/s",
     "VelocityDeSyncRot: rotation velocity limit of the de-sync", _POSITIVE),
    ("acc_desync_rot", "Real", "parameter", "tunable", _rot.acc, "deg/s2",
     "AccelerationDeSyncRot: rotation deceleration of the de-sync", _POSITIVE),
    ("jerk_desync_rot", "Real", "parameter", "tunable", _rot.jerk, "deg/s3",
     "JerkDeSyncRot: rotation jerk of the de-sync", _POSITIVE),
    ("filter_factor", "Real", "parameter", "tunable", _DEFAULTS.filter_factor, "1",
     f"MF.FilterFactor g (> 0, <= {MAX_FACTOR:g}): synchronised when |dv| <= g*A*T and "
     "|dp| <= g*A*T^2", {**_POSITIVE, "max": repr(MAX_FACTOR)}),
    ("damping_factor", "Real", "parameter", "tunable", _DEFAULTS.damping_factor, "1",
     f"MF.DampingFactor (> 0, <= {MAX_FACTOR:g}): multiplies the softmc time-to-reach "
     "estimate", {**_POSITIVE, "max": repr(MAX_FACTOR)}),
    ("max_flops", "Integer", "parameter", "tunable", _DEFAULTS.max_flops, None,
     "MF.MaxFlops (>= 1): more large velocity-error sign flips than this within "
     f"{_DEFAULTS.max_flops_time_s:g} s during the approach is an over-oscillation (error 3)",
     {"min": "1"}),
    ("vel_max_master", "Real", "parameter", "tunable", _DEFAULTS.master_max_trans.vel, "mm/s",
     "MF.VelocityMaxTrans: a faster master is error 1 and starts the de-sync", _POSITIVE),
    ("acc_max_master", "Real", "parameter", "tunable", _DEFAULTS.master_max_trans.acc, "mm/s2",
     "MF.AccelerationMaxTrans: a master accelerating harder is error 2 and starts the de-sync",
     _POSITIVE),
    ("x0", "Real", "parameter", "fixed", 0.0, "mm", "Robot X before tracking (initial setpoint)",
     {}),
    ("y0", "Real", "parameter", "fixed", 0.0, "mm", "Robot Y before tracking (initial setpoint)",
     {}),
    ("z0", "Real", "parameter", "fixed", 0.0, "mm", "Robot Z before tracking (initial setpoint)",
     {}),
    ("c0", "Real", "parameter", "fixed", 0.0, "deg",
     "Robot tool-axis angle C before tracking (initial setpoint)", {}),
    # -- inputs: the master (moving frame), sampled at the step start
    *[(f"master_{ax}", "Real", "input", "continuous", 0.0, "mm",
       f"Master (moving frame) position {ax.upper()} at the step start", {}) for ax in "xyz"],
    ("master_c", "Real", "input", "continuous", 0.0, "deg",
     "Master angle C at the step start", {}),
    *[(f"master_v{ax}", "Real", "input", "continuous", 0.0, "mm/s",
       f"Master velocity along {ax.upper()} at the step start (extrapolates across the step)",
       {}) for ax in "xyz"],
    ("master_vc", "Real", "input", "continuous", 0.0, "deg/s",
     "Master angular velocity C at the step start", {}),
    *[(f"master_a{ax}", "Real", "input", "continuous", 0.0, "mm/s2",
       f"Master acceleration along {ax.upper()} at the step start (held across the step)",
       {}) for ax in "xyz"],
    ("master_ac", "Real", "input", "continuous", 0.0, "deg/s2",
     "Master angular acceleration C at the step start", {}),
    ("engage", "Boolean", "input", "discrete", False, None,
     "Rising edge: start synchronising (with mode); falling edge: start the de-sync. Edges "
     "act at the first internal sample of the step; false before the first step", {}),
    # -- outputs: the setpoint at the end of the step
    *[(ax, "Real", "output", "continuous", None, "mm",
       f"Robot setpoint position {ax.upper()}", {}) for ax in "xyz"],
    ("c", "Real", "output", "continuous", None, "deg", "Robot setpoint angle C", {}),
    *[(f"v{ax}", "Real", "output", "continuous", None, "mm/s",
       f"Robot setpoint velocity along {ax.upper()}", {}) for ax in "xyz"],
    ("vc", "Real", "output", "continuous", None, "deg/s", "Robot setpoint angular velocity C",
     {}),
    *[(f"a{ax}", "Real", "output", "continuous", None, "mm/s2",
       f"Robot setpoint acceleration along {ax.upper()}", {}) for ax in "xyz"],
    ("ac", "Real", "output", "continuous", None, "deg/s2",
     "Robot setpoint angular acceleration C", {}),
    ("imfs", "Integer", "output", "discrete", None, None,
     "IsMovingFrameSynchronized: " + _enum_doc(Imfs), {}),
    ("state", "Integer", "output", "discrete", None, None,
     "Tracker state: " + _enum_doc(TrackState), {}),
    ("error", "Integer", "output", "discrete", None, None,
     "Tracker error (kept until the next engage): " + _enum_doc(TrackError), {}),
    # -- master conditioning (appended: the value references above stay as they were)
    ("master_input", "Integer", "parameter", "fixed", int(MasterInput.STATE), None,
     "What the master inputs are: 0 state (master_x..master_ac: the master's position, "
     "velocity and acceleration); 1 encoder (master_x, master_y, master_z, master_c: raw "
     "encoder positions, the velocity and acceleration inputs unused, through the master "
     "conditioner of docs/spec/master-conditioning.md, one per axis)",
     {"enumeration": "MasterInput"}),
    ("encoder_resolution", "Real", "parameter", "fixed", 0.0, "mm",
     "master_input=1: one count of the raw positions master_x/y/z (0: not quantised)",
     {"min": "0", "max": "1000"}),
    ("encoder_resolution_rot", "Real", "parameter", "fixed", 0.0, "deg",
     "master_input=1: one count of the raw angle master_c (0: not quantised)",
     {"min": "0", "max": "360"}),
    ("encoder_latency", "Integer", "parameter", "fixed", 0, None,
     "master_input=1: age of the raw positions at the step start in samples (0: sampled "
     "at the step start); the conditioner predicts them to each setpoint's time",
     {"min": "0", "max": str(MAX_ENCODER_LATENCY)}),
    ("jerk_max_master", "Real", "parameter", "fixed", _DEFAULTS.master_max_trans.jerk,
     "mm/s3", "MF.JerkMaxTrans: the conveyor's jerk envelope; with vel_max_master and "
     "acc_max_master (values at exitInitializationMode) the conditioner's envelope "
     "(master_input=1)", {**_POSITIVE, "max": "1e9"}),
    ("encoder_outlier", "Real", "parameter", "fixed", 0.0, "mm",
     "master_input=1: outlier gate base (a sample further than this plus JerkMax*dt^3/6 "
     "from the prediction is rejected); 0: max(0.25 mm, 5 counts)",
     {"min": "0", "max": "1000000"}),
    ("encoder_max_outliers", "Integer", "parameter", "fixed", 10, None,
     "master_input=1: this many outliers in a row are a lost master (error "
     f"{int(TrackError.MASTER_LOST)} MASTER_LOST, de-sync)", {"min": "1", "max": "100000"}),
    ("master_status", "Integer", "output", "discrete", None, None,
     "Conditioned master after the step's sample (master_input=1): " + _enum_doc(MasterStatus)
     + " (the worst axis; an engage waits while 0 or 3); 1 with master_input=0", {}),
    ("master_outliers", "Integer", "output", "discrete", None, None,
     "Encoder samples rejected as outliers since initialisation, all axes (master_input=1)",
     {}),
    ("encoder_time_offset", "Real", "input", "continuous", 0.0, "s",
     "master_input=1: how much later than its nominal instant (the step start minus "
     "encoder_latency samples) the step's raw positions were sampled: the known arrival "
     "jitter, e.g. a measured SYNC lateness (0: on time)", {}),
]

#: value reference of each variable (its position in VARIABLES)
VR: dict[str, int] = {row[0]: i for i, row in enumerate(VARIABLES)}
#: the master inputs, contiguous in VARIABLES: x y z c, vx vy vz vc, ax ay az ac
_MASTER_FIRST = VR["master_x"]
_MASTER_END = _MASTER_FIRST + 12
assert [row[0] for row in VARIABLES[_MASTER_FIRST:_MASTER_END]] == [
    f"master_{n}" for n in ("x", "y", "z", "c", "vx", "vy", "vz", "vc", "ax", "ay", "az", "ac")]
_OUT_FIRST = VR["x"]  # x y z c vx vy vz vc ax ay az ac imfs state error, contiguous
_OUT_END = VR["error"] + 1
assert [row[0] for row in VARIABLES[_OUT_FIRST:_OUT_END]] == [
    "x", "y", "z", "c", "vx", "vy", "vz", "vc", "ax", "ay", "az", "ac", "imfs", "state", "error"]
_VR_MSTATUS, _VR_MOUTLIERS = VR["master_status"], VR["master_outliers"]
_VR_TOFF = VR["encoder_time_offset"]
_PARAMETER_NAMES = [row[0] for row in VARIABLES if row[2] == "parameter"]
#: fixed parameters: settable only until ``exitInitializationMode``
_FIXED = [(i, row[0]) for i, row in enumerate(VARIABLES) if row[3] == "fixed"]
_FIXED_VRS = frozenset(i for i, _ in _FIXED)
_TUNABLE_NAMES = [row[0] for row in VARIABLES if row[2] == "parameter" and row[3] != "fixed"]
_VR_ENGAGE = VR["engage"]
#: The front library (front.c, point 6) serves the inputs and outputs of the importer's
#: fmiXSet/Get calls from its own copy and moves them to and from ``TrackerEngine.v``
#: itself, through Python's C API: it sets an input as Python's fast path does
#: (``v[vr] = value``, a float; a bool for Booleans), reads the outputs as doubles.  So the
#: list must stay the same object for the engine's life (it does: values are replaced in
#: place).  References from ``PRIVATE_BASE`` on are the front's, refused from importers:
#: a get of ``VALUE_LIST_VR`` (Real) returns the list's address, ``id(v)``, as a float
#: (exact: below 2**53).
PRIVATE_BASE = 1 << 30
VALUE_LIST_VR = PRIVATE_BASE + (1 << 29)
#: (value references, types r/i/b) of the inputs and outputs the front library keeps
CACHED_INPUTS = [(i, row[1][0].lower()) for i, row in enumerate(VARIABLES)
                 if row[2] == "input"]
CACHED_OUTPUTS = [(i, row[1][0].lower()) for i, row in enumerate(VARIABLES)
                  if row[2] == "output"]
#: outputs whose initial value depends on a parameter (InitialUnknowns dependencies)
INITIAL_DEPENDENCIES = {"x": "x0", "y": "y0", "z": "z0", "c": "c0",
                        "master_status": "master_input"}


#: Enumeration types of the model description: name -> ((item name, value), ...).  ``mode``
#: is an Enumeration (FMI 2: accessed with fmi2Get/SetInteger; FMI 3: Int64): its declared
#: values are exactly the accepted ones (an Integer 3..5 would declare 4 valid).
ENUMERATIONS: dict[str, tuple[tuple[str, int], ...]] = {
    "Mode": (("absolute", int(Mode.ABSOLUTE)), ("relative", int(Mode.RELATIVE))),
    "MasterInput": tuple((m.name.lower(), int(m)) for m in MasterInput),
}


def parameter_errors(values: dict) -> list[str]:
    """What is wrong with a set of parameter values (by FMU name), one phrase per value.

    Checks each parameter against its declared range (``min``/``max`` of ``VARIABLES``,
    inclusive, as FMI defines them) or enumeration and requires finite Reals, so that
    declared and accepted ranges are the same.
    """
    errors = []
    for name, typ, causality, _var, _start, unit, _desc, extra in VARIABLES:
        if causality != "parameter" or name not in values:
            continue
        value = values[name]
        u = f" {unit}" if unit and unit != "1" else ""
        if typ == "Real" and not math.isfinite(value):
            errors.append(f"{name}={value!r} must be finite")
        elif "enumeration" in extra:
            items = ENUMERATIONS[extra["enumeration"]]
            if value not in {v for _, v in items}:
                errors.append(f"{name}={value!r} must be one of "
                              + ", ".join(f"{v} ({n})" for n, v in items))
        elif "min" in extra or "max" in extra:
            lo = float(extra.get("min", "-inf"))
            hi = float(extra.get("max", "inf"))
            if not lo <= value <= hi:
                lo_s, hi_s = extra.get("min", "-inf"), extra.get("max", "inf")
                errors.append(f"{name}={value!r}{u} is outside its declared range "
                              f"[{lo_s}, {hi_s}]")
    return errors


def tracker_params(v: dict) -> TrackerParams:
    """The ``TrackerParams`` of a set of FMU parameter values (by FMU variable name).

    Translation limits in mm/s, mm/s^2, mm/s^3; rotation in deg/s, ...; the master's jerk and
    rotation maxima keep the ``TrackerParams`` defaults (the FMU does not expose them).
    Raises ``ParameterError`` (naming the value and the allowed range) for bad values.
    """
    planner = int(v["planner"])
    if planner not in PLANNER_CODES:
        raise ParameterError(f"planner (={planner}) must be one of "
                             + ", ".join(f"{k} ({n})" for k, n in sorted(PLANNER_CODES.items())))
    return TrackerParams(
        sample_time_s=float(v["sample_time"]),
        mode=int(v["mode"]),
        planner=PLANNER_CODES[planner],
        sync_trans=Limits(float(v["vel_sync"]), float(v["acc_sync"]), float(v["jerk_sync"])),
        desync_trans=Limits(float(v["vel_desync"]), float(v["acc_desync"]),
                            float(v["jerk_desync"])),
        sync_rot=Limits(float(v["vel_sync_rot"]), float(v["acc_sync_rot"]),
                        float(v["jerk_sync_rot"])),
        desync_rot=Limits(float(v["vel_desync_rot"]), float(v["acc_desync_rot"]),
                          float(v["jerk_desync_rot"])),
        filter_factor=float(v["filter_factor"]),
        damping_factor=float(v["damping_factor"]),
        max_flops=int(v["max_flops"]),
        master_max_trans=Limits(float(v["vel_max_master"]), float(v["acc_max_master"]),
                                float(v.get("jerk_max_master",
                                            _DEFAULTS.master_max_trans.jerk))),
    )


def conditioners(v: dict, params: TrackerParams) -> tuple[MasterConditioner, ...] | None:
    """The master conditioners (x, y, z, c) of ``master_input=1`` (else None) for a set of
    FMU parameter values (by name) and the tracker parameters made of them.

    The raw inputs at a step start t were sampled ``encoder_latency`` samples before t, and
    the step's first setpoint is for t + T: the conditioner's latency is encoder_latency + 1
    cycles and its lead 0 (its output is the belt at the setpoint's time; one conditioner
    cycle per internal sample, docs/spec/master-conditioning.md#1).  Envelope: the moving
    frame's VelocityMax/AccelerationMax/JerkMax (vel_max_master, acc_max_master,
    jerk_max_master; the rotation's ``TrackerParams.master_max_rot``).  As the simulator's
    ``conditioning:`` section builds them (controller.simulate.master), so both give the
    same numbers for the same samples.
    """
    if MasterInput(int(v["master_input"])) != MasterInput.ENCODER:
        return None
    latency = int(v["encoder_latency"]) + 1
    gate = float(v["encoder_outlier"])

    def cparams(resolution: float, frame: Limits) -> ConditioningParams:
        return ConditioningParams(params.sample_time_s, EncoderModel(resolution, latency), frame,
                                  lead_samples=0.0, outlier_mm=gate if gate > 0.0 else None,
                                  max_outliers=int(v["encoder_max_outliers"]))

    trans = cparams(float(v["encoder_resolution"]), params.master_max_trans)
    rot = cparams(float(v["encoder_resolution_rot"]), params.master_max_rot)
    return (MasterConditioner(trans), MasterConditioner(trans), MasterConditioner(trans),
            MasterConditioner(rot))


#: ``master_status`` of several axes: the worst (LOST, then STARTING, COASTING, OK)
_STATUS_RANK = {MasterStatus.OK: 0, MasterStatus.COASTING: 1, MasterStatus.STARTING: 2,
                MasterStatus.LOST: 3}


def combined_status(outs: tuple[ConditionedMaster, ...]) -> MasterStatus:
    """The worst status of the axes' conditioned masters (``_STATUS_RANK``)."""
    return max((o.status for o in outs), key=_STATUS_RANK.__getitem__)


#: step outcomes and log levels (the FMI status values, the same in FMI 2 and FMI 3)
OK, WARNING, DISCARD, ERROR = 0, 1, 2, 3


class TrackerEngine:
    """The tracker behind one FMU instance (FMI-version independent).

    ``report(message, warning)`` logs to the importer; the engine also logs to ``LOG``, at
    ERROR/WARNING unless ``importer_sees_errors`` (the FMI wrapper forwards every error and
    warning to the importer's logger whatever loggingOn: pythonfmu3), then at DEBUG only, so
    a Python importer does not print each message twice.
    ``do_step`` returns ``OK``, ``DISCARD`` (refused, nothing changed or failed earlier) or
    ``ERROR`` (an exception: logged with its traceback; the instance is failed).
    """

    def __init__(self, instance_name: str, build_id: str,
                 report: Callable[[str, int], None], importer_sees_errors: bool = False) -> None:
        self.instance_name = instance_name
        self.build_id = build_id
        self._fmi_report = report
        self._log_levels = ((logging.DEBUG, logging.DEBUG) if importer_sees_errors
                            else (logging.ERROR, logging.WARNING))
        self.v: list = [row[4] for row in VARIABLES]
        self.by_type: dict[str, frozenset[int]] = {
            t: frozenset(i for i, row in enumerate(VARIABLES) if row[1] == t)
            for t in ("Real", "Integer", "Boolean")}
        #: value references the importer may set now, per type (updated in place: the slaves
        #: keep a reference to this dict); fixed parameters leave it at exitInitializationMode
        self.settable: dict[str, frozenset[int]] = {}
        self.initialized = False
        #: the fixed parameter values frozen at exitInitializationMode (name -> value)
        self.fixed: dict[str, object] | None = None
        self._update_settable()
        self.t0 = 0.0
        self.time = 0.0
        #: False until the start time is known (FMI 2 setupExperiment; FMI 3: the front
        #: library sets ``time`` before initialisation, else the first step's start)
        self.t0_known = False
        #: internal samples done since t0 (the communication grid is t0 + k*T)
        self.k = 0
        self.terminated = False
        self.failed: str | None = None
        self.engage_prev = False
        self.tracker: Tracker | None = None
        self.params: TrackerParams | None = None
        #: the master conditioners (x, y, z, c) with master_input=1, else None
        self.conditioners: tuple[MasterConditioner, ...] | None = None
        #: the conditioned master is usable (warmed up, not lost) after the last step
        self.master_ready = True
        #: an engage edge is waiting for the conditioned master (its warning logged)
        self.engage_held = False
        self.T = float(self.v[VR["sample_time"]])
        self._write_outputs(self._initial_setpoint(), 0, 0, 0)
        self.v[_VR_MSTATUS], self.v[_VR_MOUTLIERS] = int(MasterStatus.OK), 0
        track_instance(self)

    # -- logging ----------------------------------------------------------------------
    def report(self, msg: str, level: int = 3) -> None:
        """Log ``msg`` with the FMI status ``level`` (``WARNING``, ``DISCARD``, ``ERROR``):
        the status of the call that logs it (the FMU's front library returns the worst
        status logged during a call, see ``build``)."""
        msg = msg.rstrip()  # one line break at the end is the importer's / handler's job
        self._fmi_report(msg, level)
        LOG.log(self._log_levels[1 if level == WARNING else 0], msg)

    def _log_error(self, what: str) -> str:
        msg = f"{self.instance_name}: {what}\n{traceback.format_exc()}"
        self.report(msg)
        return msg

    # -- helpers ------------------------------------------------------------------------
    def _initial_setpoint(self) -> MotionState:
        v = self.v
        return MotionState.at(v[VR["x0"]], v[VR["y0"]], v[VR["z0"]], v[VR["c0"]])

    def _write_outputs(self, sp: MotionState, imfs: int, state: int, error: int) -> None:
        p, vel, a = sp.pos, sp.vel, sp.acc
        self.v[_OUT_FIRST:_OUT_END] = (p[0], p[1], p[2], sp.ang, vel[0], vel[1], vel[2],
                                       sp.ang_vel, a[0], a[1], a[2], sp.ang_acc, int(imfs),
                                       int(state), int(error))

    def current_params(self) -> TrackerParams:
        """The fixed parameters as frozen at initialisation (current values before it) plus
        the current tunable parameters."""
        v = self.v
        values = {n: v[VR[n]] for n in _TUNABLE_NAMES}
        values.update(self.fixed if self.fixed is not None
                      else {n: v[vr] for vr, n in _FIXED})
        errors = parameter_errors(values)
        if errors:  # named as the FMU names them (the core would name its own fields)
            raise ParameterError("; ".join(errors))
        return tracker_params(values)

    def _update_settable(self) -> None:
        excluded = _FIXED_VRS if self.initialized else frozenset()
        self.settable.update({
            t: frozenset(i for i, row in enumerate(VARIABLES)
                         if row[1] == t and row[2] != "output" and i not in excluded)
            for t in ("Real", "Integer", "Boolean")})

    def _freeze(self, initialized: bool) -> None:
        self.initialized = initialized
        self.fixed = {n: self.v[vr] for vr, n in _FIXED} if initialized else None
        self._update_settable()

    def set_values(self, kind: str, vrs, values, convert) -> None:
        """The slow path of setXXX (a reference that is not settable now): a fixed parameter
        after initialisation is refused -- logged as an error naming it, the value ignored
        (pythonfmu/pythonfmu3 turn any exception in a setter into Fatal, so no error status
        can be returned); setting it to the value it has is accepted silently.  Any other
        reference that is not a settable ``kind`` raises TypeError (Fatal)."""
        v = self.v
        for vr, value in zip(vrs, values):
            if vr in self.settable[kind]:
                v[vr] = convert(value)
                continue
            if self.initialized and vr in _FIXED_VRS and vr in self.by_type[kind]:
                value = convert(value)
                if value != v[vr]:
                    name = VARIABLES[vr][0]
                    self.report(f"{self.instance_name}: {name}={value!r} refused and ignored: "
                                f"{name} is a fixed parameter, settable only before "
                                f"exitInitializationMode; the instance keeps {name}="
                                f"{v[vr]!r} (reset the instance to change it)")
                continue
            self.check(kind, [vr], settable=True)

    def private_get(self, vrs) -> list[float]:
        """A get of the front library's private reference (``VALUE_LIST_VR``: the address of
        ``v``); anything else raises TypeError (not a variable)."""
        if list(vrs) != [VALUE_LIST_VR]:
            raise TypeError(f"valueReferences {list(vrs)} are not variables")
        address = id(self.v)
        assert float(address) == address  # exact as a double (x86_64: 47-bit addresses)
        return [float(address)]

    def refresh_initial(self) -> None:
        """Before initialisation ends the outputs follow x0..c0 and master_input
        (InitialUnknowns)."""
        if self.tracker is None:
            self._write_outputs(self._initial_setpoint(), 0, 0, 0)
            self.v[_VR_MSTATUS] = int(MasterStatus.STARTING if self.v[VR["master_input"]]
                                      == MasterInput.ENCODER else MasterStatus.OK)

    def check(self, kind: str, vrs, settable: bool = False) -> None:
        """Raise TypeError naming the first reference that is not a (settable) ``kind``."""
        table = self.settable if settable else self.by_type
        for vr in vrs:
            if vr not in table[kind]:
                name = VARIABLES[vr][0] if 0 <= vr < len(VARIABLES) else "?"
                raise TypeError(f"valueReference={vr} ({name}) is not a "
                                f"{'settable ' if settable else ''}{kind} variable")

    # -- life cycle -------------------------------------------------------------------
    def setup(self, start_time: float) -> None:
        """The start time [s] (setupExperiment / enterInitializationMode)."""
        if self.initialized:
            return
        self.t0 = self.time = float(start_time)
        self.t0_known = True

    def terminate(self) -> None:
        """fmiXTerminate: later steps are refused (FMI: only reset or free are allowed)."""
        self.terminated = True

    def exit_initialization(self) -> None:
        """Freeze the fixed parameters, validate all parameters and create the tracker.

        Invalid values fail the instance with one logged line naming each bad parameter, its
        value and the declared range (no traceback); ``planner=1`` without ruckig likewise.
        Not raised: pythonfmu turns an exception into Fatal and then crashes the host on
        Terminate/FreeInstance; the FMU's front library returns the logged error as the
        call's status (see ``build``).
        """
        self._freeze(True)
        values = {n: self.v[VR[n]] for n in _PARAMETER_NAMES}
        values.update(self.fixed or {})
        errors = parameter_errors(values)
        if not errors and int(values["planner"]) == 1 and OPTIMAL_IMPORT_ERROR is not None:
            errors.append(f"planner=1 (optimal) needs ruckig, which cannot be imported "
                          f"({OPTIMAL_IMPORT_ERROR}): install ruckig for the Python running "
                          f"this FMU or set planner=0 (softmc)")
        try:
            if errors:
                raise ParameterError("; ".join(errors))
            params = self.current_params()
            tracker = Tracker(params, self._initial_setpoint())
            conds = conditioners(values, params)
        except ParameterError as exc:
            self.failed = (f"{self.instance_name}: exitInitializationMode refused the "
                           f"parameters: {exc}")
            self.report(self.failed)
            return
        except Exception as exc:
            self.failed = self._log_error(f"initialisation failed: {exc}")
            return
        self.tracker, self.params, self.T = tracker, params, params.sample_time_s
        self.conditioners = conds
        self.master_ready = conds is None
        self.engage_held = False
        self.engage_prev = False
        self.failed = None
        self._write_outputs(tracker.setpoint, tracker.imfs, tracker.state, tracker.error)
        self.v[_VR_MSTATUS] = int(MasterStatus.OK if conds is None else MasterStatus.STARTING)
        self.v[_VR_MOUTLIERS] = 0

    def release(self) -> None:
        """Drop the tracker and the conditioners (their planners hold ruckig objects): at
        the host's interpreter exit for instances the host never freed (``runtime``), so
        that no compiled object outlives the interpreter's own clean-up.  Later steps are
        refused like after terminate."""
        self.tracker = None
        self.conditioners = None
        self.terminated = True

    def do_step(self, current_time: float, step_size: float) -> int:
        """One communication step [current_time, current_time + step_size] [s].

        Time grid: the step must start where the previous one ended and end on the grid
        t0 + k*T, both within ``STEP_TOLERANCE`` * T (importers accumulate times with
        rounding noise: libcosim counts ns, OMSimulator adds step sizes); it runs the samples
        up to that grid point.  A step that reaches no new grid point within the tolerance
        (the ~5e-14 s remainder an accumulating importer sends at the stop time) is a no-op.
        """
        if self.terminated or self.failed is not None:
            return self._refuse_dead(current_time)
        T = self.T
        tol = STEP_TOLERANCE * T
        if not self.t0_known:  # FMI 3 without the front library: the first step's start
            self.t0 = self.time = float(current_time)
            self.t0_known = True
        if abs(current_time - self.time) > tol:
            return self._refuse_start(current_time)
        end = current_time + step_size
        t0 = self.t0
        k_end = round((end - t0) / T)
        n = k_end - self.k
        if n < 0 or abs(end - (t0 + k_end * T)) > tol:
            return self._refuse_grid(current_time, step_size)
        if n == 0:  # covers no sample: a no-op (outputs as they are)
            self.time = end
            return OK
        v = self.v
        master = v[_MASTER_FIRST:_MASTER_END]
        if not isfinite(sum(master)):  # one test for all; the sum overflows rarely
            bad = [f"{VARIABLES[vr][0]}={x!r}" for vr, x in enumerate(master, _MASTER_FIRST)
                   if not isfinite(x)]
            if bad:
                self.report(f"{self.instance_name}: step at t={current_time!r} s refused: "
                            f"non-finite master input {', '.join(bad)}; nothing changed "
                            f"(outputs and tracker state as at t={self.time!r} s): set finite "
                            f"values and repeat the step, or restore a saved FMU state", DISCARD)
                return DISCARD
        if self.conditioners is not None and not isfinite(v[_VR_TOFF]):
            self.report(f"{self.instance_name}: step at t={current_time!r} s refused: "
                        f"non-finite encoder_time_offset={v[_VR_TOFF]!r}; nothing "
                        f"changed: set a finite value and repeat the step", DISCARD)
            return DISCARD
        try:
            self._step(n, T, master)
        except ParameterError as exc:
            # raised before any state changed: the step can be repeated with a valid value
            self.report(f"{self.instance_name}: step at t={current_time!r} s refused, a "
                        f"tunable parameter is invalid at engage: {exc}", DISCARD)
            return DISCARD
        except Exception as exc:
            self.failed = self._log_error(
                f"exception in the step at t={current_time!r} s, step size {step_size!r} s: "
                f"{exc!r}")
            return ERROR
        self.time = end
        self.k = k_end
        return OK

    def _refuse_dead(self, current_time: float) -> int:
        if self.terminated:
            self.report(f"{self.instance_name}: doStep at t={current_time!r} s refused: the "
                        f"instance is terminated (only reset or free it)")
        else:
            self.report(f"{self.instance_name}: step at t={current_time!r} s refused: the "
                        f"instance failed earlier (set a saved FMU state or reset it). First "
                        f"error: {self.failed}")
        return ERROR

    def _refuse_start(self, current_time: float) -> int:
        self.report(f"{self.instance_name}: step at t={current_time!r} s refused: the "
                    f"previous step ended at t={self.time!r} s (a communication step "
                    f"starts where the last one ended; restore a saved FMU state to go "
                    f"back); nothing changed", DISCARD)
        return DISCARD

    def _refuse_grid(self, current_time: float, step_size: float) -> int:
        T = self.T
        self.report(f"{self.instance_name}: communication step size {step_size!r} s at "
                    f"t={current_time!r} s refused: steps must end on the sample grid "
                    f"t0 + k*sample_time (t0={self.t0!r} s, sample_time={T!r} s, "
                    f"tolerance {STEP_TOLERANCE * T:.3g} s), i.e. be whole multiples of "
                    f"sample_time; use stepSize {T!r} s (DefaultExperiment) or a multiple",
                    DISCARD)
        return DISCARD

    def _step(self, n: int, T: float, master_values: list[float]) -> None:
        """The samples of a step; ``master_values``: the master inputs (x y z c, vx vy vz
        vc, ax ay az ac)."""
        tracker = self.tracker
        v = self.v
        engage = bool(v[_VR_ENGAGE])
        if engage != self.engage_prev or self.engage_held:
            tracker = self._engage_edge(engage, tracker)
        if self.conditioners is not None:
            return self._step_encoder(n, tracker, master_values)
        mx, my, mz, mc, mvx, mvy, mvz, mvc, max_, may, maz, mac = master_values
        assert tracker is not None  # initialised (before it a step fails like an exception)
        advance = tracker.advance  # (update without its output record: read back below)
        if n == 1:
            # MotionState(...).extrapolated(T) written out (the same operations in the same
            # order: bit-identical), one MotionState per sample instead of two
            h = 0.5 * T * T
            advance(MotionState(
                (mx + mvx * T + max_ * h, my + mvy * T + may * h, mz + mvz * T + maz * h),
                (mvx + max_ * T, mvy + may * T, mvz + maz * T), (max_, may, maz),
                mc + mvc * T + mac * h, mvc + mac * T, mac))
        else:
            master = MotionState((mx, my, mz), (mvx, mvy, mvz), (max_, may, maz), mc, mvc, mac)
            for i in range(1, n + 1):
                advance(master.extrapolated(i * T))
        sp = tracker.setpoint
        state = tracker.state
        # the enums are ints (IntEnum): stored as they are
        v[_OUT_FIRST:_OUT_END] = (*sp.pos, sp.ang, *sp.vel, sp.ang_vel, *sp.acc, sp.ang_acc,
                                  tracker.imfs, state, tracker.error)

    def _engage_edge(self, engage: bool, tracker: Tracker | None) -> Tracker | None:
        """An engage edge (or an engage waiting for the conditioned master) at the step
        start: the tracker the step runs (a new one at a rising edge).  Raises
        ParameterError (nothing changed) for an invalid tunable at a rising edge."""
        v = self.v
        if engage and not self.master_ready:
            # the conditioned master is not usable yet: the edge waits (engage_prev stays
            # False, so the next step sees it again)
            if not self.engage_held:
                self.engage_held = True
                self.report(f"{self.instance_name}: engage at t={self.time!r} s waits: "
                            f"the conditioned master is "
                            f"{MasterStatus(v[_VR_MSTATUS]).name} (master_status="
                            f"{v[_VR_MSTATUS]}); it acts at the first step after "
                            f"master_status is 1 or 2", WARNING)
        elif engage:
            assert tracker is not None
            params = self.current_params()  # may raise ParameterError: nothing changed yet
            tracker = Tracker(params, tracker.setpoint)
            tracker.engage()
            self.tracker, self.params = tracker, params
            self.engage_prev, self.engage_held = True, False
        elif self.engage_prev:
            assert tracker is not None
            tracker.disengage()
            self.engage_prev = False
        else:  # engage fell while it waited
            self.engage_held = False
        return tracker

    def _step_encoder(self, n: int, tracker: Tracker | None,
                      master_values: list[float]) -> None:
        """The samples of a step with raw encoder inputs (master_input=1): the step's
        positions go to the conditioners at its first sample, the others coast (one sample
        per communication step: docs/spec/master-conditioning.md#3.2); each sample's
        conditioned belt (position..jerk at that setpoint's time) goes to the tracker.  A
        lost master de-syncs with MASTER_LOST, as the CAN shell does."""
        conds = self.conditioners
        assert conds is not None and tracker is not None  # initialised: the caller checked
        cx, cy, cz, cc = conds
        raw = master_values[0], master_values[1], master_values[2], master_values[3]
        off = float(self.v[_VR_TOFF])
        update = tracker.update
        for i in range(n):
            if i == 0:
                outs = (cx.update(raw[0], off), cy.update(raw[1], off), cz.update(raw[2], off),
                        cc.update(raw[3], off))
                status = combined_status(outs)
                if status == MasterStatus.LOST:
                    self._master_lost(tracker, outs)
            else:
                outs = (cx.update(None), cy.update(None), cz.update(None), cc.update(None))
            ox, oy, oz, oc = outs
            out = update(MotionState((ox.pos, oy.pos, oz.pos), (ox.vel, oy.vel, oz.vel),
                                     (ox.acc, oy.acc, oz.acc), oc.pos, oc.vel, oc.acc,
                                     (ox.jerk, oy.jerk, oz.jerk), oc.jerk))
        v = self.v
        sp = out.setpoint
        p, vel, a = sp.pos, sp.vel, sp.acc
        v[_OUT_FIRST:_OUT_END] = (p[0], p[1], p[2], sp.ang, vel[0], vel[1], vel[2], sp.ang_vel,
                                  a[0], a[1], a[2], sp.ang_acc, out.imfs, out.state, out.error)
        v[_VR_MSTATUS] = int(status)
        v[_VR_MOUTLIERS] = cx.n_outliers + cy.n_outliers + cz.n_outliers + cc.n_outliers
        self.master_ready = status == MasterStatus.OK or status == MasterStatus.COASTING

    def _master_lost(self, tracker: Tracker, outs: tuple[ConditionedMaster, ...]) -> None:
        """An axis's conditioner lost the master at this sample: de-sync if engaged."""
        for axis, o in zip("xyzc", outs):
            if o.event is None or o.event.kind != EventKind.LOST:
                continue
            engaged = tracker.state in (TrackState.SYNCING, TrackState.SYNCED)
            if engaged:
                tracker.disengage(TrackError.MASTER_LOST)
            self.report(f"{self.instance_name}: master lost at t={self.time!r} s: "
                        f"{self.v[VR['encoder_max_outliers']]} encoder samples of master_"
                        f"{axis} in a row off what the belt can do (last {o.event.size_mm:+.6g} "
                        f"{'deg' if axis == 'c' else 'mm'}); "
                        + ("de-sync with MASTER_LOST" if engaged else "not engaged")
                        + "; the conditioner starts again from the next sample", WARNING)
            return

    # -- FMU state ------------------------------------------------------------------------
    def get_state(self) -> dict:
        """Everything: all variable values, the whole tracker (deep copy), edge memory."""
        return {"format": STATE_FORMAT, "build": self.build_id, "values": list(self.v),
                "tracker": None if self.tracker is None else self.tracker.snapshot(),
                "conditioners": copy.deepcopy(self.conditioners),
                "master_ready": self.master_ready, "engage_held": self.engage_held,
                "params": self.params, "engage_prev": self.engage_prev, "t0": self.t0,
                "time": self.time, "failed": self.failed, "initialized": self.initialized,
                "k": self.k, "t0_known": self.t0_known, "terminated": self.terminated}

    def set_state(self, state: dict) -> None:
        """Restore a state of ``get_state`` (copied: it can be restored again).  An unusable
        state is logged and fails the instance (not raised, see ``exit_initialization``)."""
        if not isinstance(state, dict) or state.get("format") != STATE_FORMAT or len(
                state.get("values", ())) != len(VARIABLES):
            self.failed = (f"{self.instance_name}: SetFMUState got an unusable state "
                           f"(expected format {STATE_FORMAT} with {len(VARIABLES)} values)"
                           + (f": {state['error']}" if isinstance(state, dict)
                              and state.get("error") else ""))
            self.report(self.failed)
            return
        if state.get("build") != self.build_id:
            self.report(f"{self.instance_name}: FMU state saved by build "
                        f"{state.get('build')!r}, restored into {self.build_id!r}", WARNING)
        self.v[:] = state["values"]
        tracker = state["tracker"]
        self.tracker = None if tracker is None else tracker.snapshot()
        self.conditioners = copy.deepcopy(state.get("conditioners"))
        self.master_ready = state.get("master_ready", self.conditioners is None)
        self.engage_held = state.get("engage_held", False)
        self.params = state["params"]
        self.T = self.params.sample_time_s if self.params else float(
            self.v[VR["sample_time"]])
        self.engage_prev = state["engage_prev"]
        self.t0, self.time = state["t0"], state["time"]
        self.k = state.get("k", round((self.time - self.t0) / self.T))
        self.t0_known = state.get("t0_known", True)
        self.terminated = state.get("terminated", False)
        self.failed = state["failed"]
        # states of builds without the flag were saved after initialisation (a tracker)
        self._freeze(bool(state.get("initialized", tracker is not None)))

    @staticmethod
    def state_to_bytes(state: dict) -> bytes:
        return pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)

    @staticmethod
    def state_from_bytes(data: bytes) -> dict:
        try:
            return pickle.loads(data)
        except Exception as exc:
            return {"format": None, "error": f"cannot deserialize: {exc!r}"}
