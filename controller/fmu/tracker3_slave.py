"""The CanTracker3 FMU slave (FMI 3.0 Co-Simulation, pythonfmu3).

The same engine as the FMI 2.0 FMU (``controller/fmu/engine.py``: variables, step semantics,
errors, FMU state), with FMI 3 types: Real -> Float64 (with units), Integer -> Int32,
Boolean -> Boolean, ``mode`` and ``master_input`` Enumerations (Int64), plus the independent
variable ``time`` [s] (its value reference is len(VARIABLES), after the variables of the
FMI 2.0 FMU, which keep their value references).  pythonfmu3 writes the units, ``InitialUnknown`` and ``Output`` entries;
``to_xml`` adds their dependencies, min/max, the enumeration and fixedInternalStepSize.

FMI 3 statuses: a refused step (step size, non-finite master input, invalid tunable at
engage) gives ``fmi3Discard`` -- the FMU is in the state it had before the call and the step
can be repeated; an exception in a step gives ``fmi3Error`` (logged with its traceback);
see the engine for when steps are refused.  Errors reach the importer through its
logMessage callback (pythonfmu3 forwards them whatever loggingOn), so the engine's Python
logger ``cantrack.fmu`` records them at DEBUG only.
"""

from __future__ import annotations

from xml.etree.ElementTree import Element, SubElement

# Only the standard library, pythonfmu3 and ``runtime`` at the top (see tracker_slave.py);
# ``cantrack fmu build`` rewrites these imports to the FMU's private package.
from pythonfmu3 import (Boolean, DefaultExperiment, Float64, Fmi3Causality, Fmi3Slave,
                        Fmi3Status, Fmi3StepResult, Fmi3Variability, Int32, Unit)

from controller import __version__
from controller.fmu.runtime import EngineStateMixin, load_engine, ruckig_warning

_TYPES = {"Real": Float64, "Integer": Int32, "Boolean": Boolean}
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
        self.version = __version__
        self.license = "MIT"
        self.default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0,
                                                    step_size=0.001)
        eng = self._eng = load_engine("CanTracker3")  # raises FmuDependencyError (one line)
        VARIABLES, UNITS = eng.VARIABLES, eng.UNITS
        self._results = {eng.OK: Fmi3StepResult(),
                         eng.DISCARD: Fmi3StepResult(status=Fmi3Status.discard)}
        # pythonfmu3 forwards every non-debug message to the importer's logMessage, whatever
        # loggingOn: the engine's Python logger then stays quiet (DEBUG) -- no double print
        engine = self._engine = eng.TrackerEngine(self.instance_name, __name__, self._fmi_log,
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
        self._vr_time = len(VARIABLES)
        time = Float64("time", causality=Fmi3Causality.independent,
                       variability=Fmi3Variability.continuous, unit="s",
                       description="Simulation time", getter=lambda: engine.time)
        self.register_variable(time)
        assert time.value_reference == self._vr_time
        self._real = engine.by_type["Real"]
        self._int = engine.by_type["Integer"]
        self._bool = engine.by_type["Boolean"]
        self._settable = engine.settable  # changes at exitInitializationMode (fixed ones)
        warning = ruckig_warning("CanTracker3", eng.OPTIMAL_IMPORT_ERROR)
        if warning:
            engine.report(warning, eng.WARNING)

    def to_xml(self, model_options: dict | None = None):
        """pythonfmu3's description plus the min/max attributes of the parameters, ``mode``
        as an Enumeration, the output dependencies (none: no direct feed-through) and the
        internal step size."""
        root = super().to_xml(model_options or {})
        eng = self._eng
        rows = {row[0]: row for row in eng.VARIABLES}
        root.find("CoSimulation").set("fixedInternalStepSize",
                                      repr(rows["sample_time"][4]))
        types = Element("TypeDefinitions")
        for name, items in eng.ENUMERATIONS.items():
            et = SubElement(types, "EnumerationType", {"name": name})
            for item, value in items:
                SubElement(et, "Item", {"name": item, "value": str(value)})
        root.insert(list(root).index(root.find("UnitDefinitions")) + 1, types)
        for el in root.find("ModelVariables"):
            row = rows.get(el.get("name"))
            extra = dict(row[7]) if row else {}
            enum = extra.pop("enumeration", None)
            if enum:  # accessed with fmi3Get/SetInt64; its items are the accepted values
                el.tag = "Enumeration"
                el.set("declaredType", enum)
                extra.pop("min", None)
                extra.pop("max", None)
            for k, val in extra.items():
                el.set(k, val)
        for el in root.find("ModelStructure"):
            if el.tag == "Output":
                el.set("dependencies", "")  # outputs are states: no direct feed-through
            elif el.tag == "InitialUnknown":
                name = eng.VARIABLES[int(el.get("valueReference"))][0]
                dep = eng.INITIAL_DEPENDENCIES.get(name)
                el.set("dependencies", str(eng.VR[dep]) if dep else "")
        return root

    def _fmi_log(self, msg: str, level: int) -> None:
        self.log(msg, Fmi3Status(level))

    # -- life cycle.  pythonfmu3 passes no start time to Python: the FMU's front library
    #    sets ``time`` (value reference len(VARIABLES)) to fmi3EnterInitializationMode's
    #    startTime just before it (independent variables are not settable by the importer;
    #    see build.py).
    #    Without the front library ``time`` is the first step's start.
    def exit_initialization_mode(self) -> None:
        self._engine.exit_initialization()

    def terminate(self) -> None:
        self._engine.terminate()

    def do_step(self, current_time: float, step_size: float) -> Fmi3StepResult:
        return self._results.get(self._engine.do_step(current_time, step_size), _ERROR)

    # -- variable access --------------------------------------------------------------
    def get_float64(self, vrs):
        if not self._real.issuperset(vrs):
            if vrs and vrs[0] >= self._eng.PRIVATE_BASE:  # the front library's
                return self._engine.private_get(vrs)
            return [self._engine.time if vr == self._vr_time else self._get_checked("Real", vr)
                    for vr in vrs]
        if self._engine.tracker is None:
            self._engine.refresh_initial()
        v = self._v
        return [v[vr] for vr in vrs]

    def _get_checked(self, kind: str, vr: int):
        self._engine.check(kind, [vr])
        return self._v[vr]

    get_int32 = EngineStateMixin._get_integers
    get_int64 = EngineStateMixin._get_integers  # Enumeration (mode)
    set_int64 = EngineStateMixin._set_integers
    get_boolean = EngineStateMixin._get_booleans
    def set_float64(self, vrs, values):
        if self._vr_time in vrs:  # the start time from the front library (see above)
            self._engine.setup(values[list(vrs).index(self._vr_time)])
            pairs = [(vr, x) for vr, x in zip(vrs, values) if vr != self._vr_time]
            vrs, values = [p[0] for p in pairs], [p[1] for p in pairs]
        return self._set_reals(vrs, values)

    set_int32 = EngineStateMixin._set_integers
    set_boolean = EngineStateMixin._set_booleans
