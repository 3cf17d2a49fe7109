"""The CanTracker3 FMU slave (FMI 3.0 Co-Simulation, pythonfmu3).

The same engine as the FMI 2.0 FMU (``controller/fmu/engine.py``: variables, step semantics,
errors, FMU state), with FMI 3 types: Real -> Float64 (with units), Integer -> Int32,
Boolean -> Boolean, plus the independent variable ``time`` [s] (value reference 52, after the
52 variables of the FMI 2.0 FMU, which keep their value references).  pythonfmu3 writes the
units, ``InitialUnknown`` and ``Output`` entries itself.

FMI 3 statuses: a refused step (step size, non-finite master input, invalid tunable at
engage) gives ``fmi3Discard`` -- the FMU is in the state it had before the call and the step
can be repeated; an exception in a step gives ``fmi3Error`` (logged with its traceback);
see the engine for when steps are refused.  Errors reach the importer through its
logMessage callback (pythonfmu3 forwards them whatever loggingOn), so the engine's Python
logger ``cantrack.fmu`` records them at DEBUG only.
"""

from __future__ import annotations

from pythonfmu3 import (Boolean, DefaultExperiment, Float64, Fmi3Causality, Fmi3Slave,
                        Fmi3Status, Fmi3StepResult, Fmi3Variability, Int32, Unit)

import controller
from controller.fmu.engine import (DISCARD, OK, UNITS, VARIABLES, EngineStateMixin,
                                   TrackerEngine)

_TYPES = {"Real": Float64, "Integer": Int32, "Boolean": Boolean}
VR_TIME = len(VARIABLES)
_RESULTS = {OK: Fmi3StepResult(), DISCARD: Fmi3StepResult(status=Fmi3Status.discard)}
_ERROR = Fmi3StepResult(status=Fmi3Status.error)


class CanTracker3(EngineStateMixin, Fmi3Slave):
    """Conveyor tracking (softMC moving-frame synchronisation) of one robot on one master."""

    author = "cantrack"
    description = ("cantrack conveyor tracker (softMC moving-frame synchronisation), FMI 3.0: "
                   "robot setpoint from the master's state; units mm, deg, s")

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.author = CanTracker3.author
        self.description = CanTracker3.description
        self.version = controller.__version__
        self.license = "MIT"
        self.default_experiment = DefaultExperiment(start_time=0.0, step_size=0.001)
        # pythonfmu3 forwards every non-debug message to the importer's logMessage, whatever
        # loggingOn: the engine's Python logger then stays quiet (DEBUG) -- no double print
        engine = self._engine = TrackerEngine(self.instance_name, __name__, self._fmi_log,
                                              importer_sees_errors=True)
        v = self._v = engine.v
        used = sorted({row[5] for row in VARIABLES if row[5]} | {"s"})
        self.register_units([Unit(name, factor=UNITS[name][1], **UNITS[name][0])
                             for name in used])
        for vr, (name, typ, causality, variability, _start, unit, desc, _x) in enumerate(
                VARIABLES):
            kw = dict(causality=getattr(Fmi3Causality, causality),
                      variability=getattr(Fmi3Variability, variability), description=desc,
                      getter=(lambda vr=vr: v[vr]),
                      setter=None if causality == "output" else (
                          lambda value, vr=vr: v.__setitem__(vr, value)))
            if typ == "Real" and unit:
                kw["unit"] = unit
            var = _TYPES[typ](name, **kw)
            self.register_variable(var)
            assert var.value_reference == vr
        time = Float64("time", causality=Fmi3Causality.independent,
                       variability=Fmi3Variability.continuous, unit="s",
                       description="Simulation time", getter=lambda: engine.time)
        self.register_variable(time)
        assert time.value_reference == VR_TIME
        self._real = engine.by_type["Real"]
        self._int = engine.by_type["Integer"]
        self._bool = engine.by_type["Boolean"]
        self._settable = engine.settable  # changes at exitInitializationMode (fixed ones)

    def to_xml(self, model_options: dict | None = None):
        """pythonfmu3's description plus the min/max attributes of the parameters."""
        root = super().to_xml(model_options or {})
        extras = {row[0]: row[7] for row in VARIABLES}
        for el in root.find("ModelVariables"):
            for k, val in extras.get(el.get("name"), {}).items():
                el.set(k, val)
        return root

    def _fmi_log(self, msg: str, warning: bool) -> None:
        self.log(msg, Fmi3Status.warning if warning else Fmi3Status.error)

    # -- life cycle (pythonfmu3 passes no start time: ``time`` is 0 until the first step) ---
    def exit_initialization_mode(self) -> None:
        self._engine.exit_initialization()

    def do_step(self, current_time: float, step_size: float) -> Fmi3StepResult:
        return _RESULTS.get(self._engine.do_step(current_time, step_size), _ERROR)

    # -- variable access --------------------------------------------------------------
    def get_float64(self, vrs):
        if not self._real.issuperset(vrs):
            return [self._engine.time if vr == VR_TIME else self._get_checked("Real", vr)
                    for vr in vrs]
        if self._engine.tracker is None:
            self._engine.refresh_initial()
        v = self._v
        return [v[vr] for vr in vrs]

    def _get_checked(self, kind: str, vr: int):
        self._engine.check(kind, [vr])
        return self._v[vr]

    get_int32 = EngineStateMixin._get_integers
    get_boolean = EngineStateMixin._get_booleans
    set_float64 = EngineStateMixin._set_reals
    set_int32 = EngineStateMixin._set_integers
    set_boolean = EngineStateMixin._set_booleans
