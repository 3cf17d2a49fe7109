"""The CanTracker FMU slave (FMI 2.0 Co-Simulation, pythonfmu).

This file is the pythonfmu slave script.  ``cantrack fmu build`` copies it into the FMU under
a content-hashed module name (``cantracker_<hash>.py``, see ``controller.fmu.build``), its
``controller``/``pythonfmu`` imports pointed at the FMU's private package, which holds the
tracker core and ``fmu/engine.py`` (the variables, the step semantics, the error handling
and the FMU state: see its docstring).  This class maps pythonfmu's calls onto the engine
and writes the model description extras pythonfmu lacks (units incl. "1" for the
dimensionless factors, min/max, the ``Mode`` enumeration, output dependencies,
``InitialUnknowns``: pythonfmu issue #193).

FMI 2 statuses: pythonfmu returns OK or Discard from a step; the FMU's front library turns a
step whose logged status is Error (failed or terminated instance, exception) into
``fmi2Error`` (see ``front.c``); the message says which.
"""

from __future__ import annotations

from xml.etree.ElementTree import Element, SubElement

# Only the standard library, pythonfmu and ``runtime`` (standard library) at the top: the
# engine needs numpy and is imported when an instance is created, so that a missing numpy is
# a clear instantiation error (see ``runtime``).  ``cantrack fmu build`` rewrites these
# absolute imports to the FMU's private package (``_cantrack_<hash>.pythonfmu``, ...).
from pythonfmu import (
    Boolean,
    DefaultExperiment,
    Fmi2Causality,
    Fmi2Slave,
    Fmi2Variability,
    Integer,
    Real,
)
from pythonfmu.enums import Fmi2Status

from controller import __version__
from controller.fmu.runtime import EngineStateMixin, load_engine, ruckig_warning

__all__ = ["CanTracker"]

_TYPES = {"Real": Real, "Integer": Integer, "Boolean": Boolean}


class CanTracker(EngineStateMixin, Fmi2Slave):
    """Conveyor tracking (softMC moving-frame synchronisation) of one robot on one master."""

    author = "cantrack"
    description = ("cantrack conveyor tracker (softMC moving-frame synchronisation): robot "
                   "setpoint from the master's state; units mm, deg, s")
    version = __version__
    license = "MIT"
    # stop 1 s: fmpy keeps the 1 ms step for runs of at most 1000 steps
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=1.0, step_size=0.001)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        eng = self._eng = load_engine("CanTracker")  # raises FmuDependencyError (one line)
        engine = self._engine = eng.TrackerEngine(self.instance_name, __name__, self._fmi_log)
        v = self._v = engine.v
        for vr, (name, typ, causality, variability, _start, _unit, desc, _x) in enumerate(
                eng.VARIABLES):
            var = _TYPES[typ](name, causality=getattr(Fmi2Causality, causality),
                              variability=getattr(Fmi2Variability, variability),
                              description=desc, getter=(lambda vr=vr: v[vr]),
                              setter=None if causality == "output" else (
                                  lambda value, vr=vr: v.__setitem__(vr, value)))
            self.register_variable(var)
            assert var.value_reference == vr
        self._real = engine.by_type["Real"]
        self._int = engine.by_type["Integer"]
        self._bool = engine.by_type["Boolean"]
        self._settable = engine.settable  # changes at exitInitializationMode (fixed ones)
        #: what the front library calls for a step (do_step's own semantics: the FMI status)
        self._direct_step = engine.do_step
        warning = ruckig_warning("CanTracker", eng.OPTIMAL_IMPORT_ERROR)
        if warning:
            engine.report(warning, eng.WARNING)

    def _fmi_log(self, msg: str, level: int) -> None:
        self.log(msg, Fmi2Status(level))

    # -- model description ------------------------------------------------------------
    def to_xml(self, model_options: dict | None = None) -> Element:
        """pythonfmu's description plus units, min/max, output dependencies and the
        ``InitialUnknowns`` (pythonfmu issue #193)."""
        root = super().to_xml(model_options or {})
        eng = self._eng
        VARIABLES, VR, UNITS = eng.VARIABLES, eng.VR, eng.UNITS
        specs = {row[0]: (row[5], row[7]) for row in VARIABLES}
        units = Element("UnitDefinitions")
        for name in sorted({unit for unit, _ in specs.values() if unit}):
            exps, factor = UNITS[name]
            attrs = {k: str(e) for k, e in exps.items()}
            if factor != 1.0:
                attrs["factor"] = repr(factor)
            SubElement(SubElement(units, "Unit", {"name": name}), "BaseUnit", attrs)
        root.insert(list(root).index(root.find("CoSimulation")) + 1, units)
        types = Element("TypeDefinitions")
        for name, items in eng.ENUMERATIONS.items():
            enum = SubElement(SubElement(types, "SimpleType", {"name": name}), "Enumeration")
            for item, value in items:
                SubElement(enum, "Item", {"name": item, "value": str(value)})
        root.insert(list(root).index(units) + 1, types)
        for sv in root.find("ModelVariables"):
            unit, extra = specs[sv.get("name")]
            extra = dict(extra)
            if unit:
                sv[0].set("unit", unit)
            enum = extra.pop("enumeration", None)
            if enum:  # accessed with fmi2Get/SetInteger; its items are the accepted values
                sv[0].tag = "Enumeration"
                sv[0].set("declaredType", enum)
                extra.pop("min", None)
                extra.pop("max", None)
            for k, val in extra.items():
                sv[0].set(k, val)
        structure = root.find("ModelStructure")
        for unknown in structure.find("Outputs"):
            unknown.set("dependencies", "")  # no direct feed-through: outputs are states
        initial = SubElement(structure, "InitialUnknowns")
        for row in VARIABLES:
            if row[2] == "output":
                dep = eng.INITIAL_DEPENDENCIES.get(row[0])
                SubElement(initial, "Unknown", {
                    "index": str(VR[row[0]] + 1),
                    "dependencies": str(VR[dep] + 1) if dep else ""})
        return root

    # -- life cycle -------------------------------------------------------------------
    def setup_experiment(self, start_time: float, *args) -> None:
        self._engine.setup(start_time)

    def exit_initialization_mode(self) -> None:
        self._engine.exit_initialization()

    def terminate(self) -> None:
        self._engine.terminate()

    def do_step(self, current_time: float, step_size: float) -> bool:
        return self._engine.do_step(current_time, step_size) == self._eng.OK

    # -- variable access --------------------------------------------------------------
    def get_real(self, vrs):
        if not self._real.issuperset(vrs):
            if vrs and vrs[0] >= self._eng.PRIVATE_BASE:  # the front library's
                return self._private_get(vrs)
            self._engine.check("Real", vrs)
        if self._engine.tracker is None:
            self._engine.refresh_initial()
        v = self._v
        return [v[vr] for vr in vrs]

    def _private_get(self, vrs):
        """The front library's private references: the engine's value list, its step
        (called by the front directly, see front.c fmi2DoStep) and pythonfmu's log queue,
        each object's address as a float (``engine.VALUE_LIST_VR`` + 0, 1, 2)."""
        base = self._eng.VALUE_LIST_VR
        if len(vrs) != 3 or list(vrs) != [base, base + 1, base + 2]:
            return self._engine.private_get(vrs)
        return [self._engine.private_get([base])[0], float(id(self._direct_step)),
                float(id(self.log_queue))]

    get_integer = EngineStateMixin._get_integers
    get_boolean = EngineStateMixin._get_booleans
    set_real = EngineStateMixin._set_reals
    set_integer = EngineStateMixin._set_integers
    set_boolean = EngineStateMixin._set_booleans
