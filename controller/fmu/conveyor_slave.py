"""The CanConveyor FMU slave: a conveyor master axis with a trapezoidal speed profile.

A test master for ``CanTracker.fmu`` in co-simulation (``fmu/OspSystemStructure.xml``).
Self-contained (standard library + pythonfmu only); ``cantrack fmu build`` copies it into the
FMU as ``canconveyor_<hash>.py``.

Profile along the travel direction (unit vector at ``angle`` deg in the XY plane), s in mm:
at rest until ``t_start``; accelerate at ``acc`` [mm/s^2] to ``speed`` [mm/s]; run; from
``t_stop`` decelerate at ``acc`` to rest.  Every segment has constant acceleration, so the
tracker's constant-acceleration extrapolation of a sampled state is exact within a segment.
The acceleration is right-continuous (at a switching time it is the new segment's).

Time: the outputs at the end of a step [t, t + h] are the state at t + h, rounded to the
``sample_time`` grid (k*T with k = round((t + h)/T)), so co-simulation masters whose times
carry rounding noise (libcosim counts nanoseconds) give the same values as an offline run at
k*T.  ``engage`` (an item sensor) is true for ``t_engage <= t < t_release``.
"""

from __future__ import annotations

import math
from xml.etree.ElementTree import Element, SubElement

from pythonfmu import Boolean, DefaultExperiment, Fmi2Causality, Fmi2Slave, Fmi2Variability, Real
from pythonfmu.enums import Fmi2Status

UNITS = {"s": ({"s": 1}, 1.0), "mm": ({"m": 1}, 1e-3), "mm/s": ({"m": 1, "s": -1}, 1e-3),
         "mm/s2": ({"m": 1, "s": -2}, 1e-3), "deg": ({"rad": 1}, math.pi / 180.0)}

#: declared minimum of the parameters that must be > 0 (FMI bounds are inclusive: the FMU
#: accepts exactly the declared range)
POSITIVE_FLOOR = 1e-9

#: (name, type, causality, variability, start, unit, description)
VARIABLES: list[tuple] = [
    ("sample_time", "Real", "parameter", "fixed", 0.001, "s",
     "Grid the output times are rounded to (the tracker's sample time, > 0)"),
    ("speed", "Real", "parameter", "fixed", 300.0, "mm/s", "Conveyor speed (> 0)"),
    ("acc", "Real", "parameter", "fixed", 500.0, "mm/s2",
     "Acceleration of the speed ramps (> 0)"),
    ("t_start", "Real", "parameter", "fixed", 0.0, "s", "Time the ramp-up starts"),
    ("t_stop", "Real", "parameter", "fixed", 1e6, "s",
     "Time the ramp-down starts (>= t_start + speed/acc)"),
    ("angle", "Real", "parameter", "fixed", 0.0, "deg",
     "Travel direction in the XY plane (0: along +X)"),
    ("x0", "Real", "parameter", "fixed", 0.0, "mm", "Position X at rest before t_start"),
    ("y0", "Real", "parameter", "fixed", 0.0, "mm", "Position Y at rest before t_start"),
    ("z0", "Real", "parameter", "fixed", 0.0, "mm", "Position Z (constant)"),
    ("t_engage", "Real", "parameter", "fixed", 0.5, "s", "Item sensor on (engage rises)"),
    ("t_release", "Real", "parameter", "fixed", 2.5, "s", "Item sensor off (engage falls)"),
    *[(ax, "Real", "output", "continuous", None, "mm", f"Master position {ax.upper()}")
      for ax in "xyz"],
    *[(f"v{ax}", "Real", "output", "continuous", None, "mm/s",
       f"Master velocity along {ax.upper()}") for ax in "xyz"],
    *[(f"a{ax}", "Real", "output", "continuous", None, "mm/s2",
       f"Master acceleration along {ax.upper()}") for ax in "xyz"],
    ("engage", "Boolean", "output", "discrete", None, None,
     "Item sensor: true for t_engage <= t < t_release (connect to CanTracker.engage)"),
]
VR = {row[0]: i for i, row in enumerate(VARIABLES)}
#: declared minimum (``min`` attribute) per parameter
MINIMUM = {"sample_time": POSITIVE_FLOOR, "speed": POSITIVE_FLOOR, "acc": POSITIVE_FLOOR}


def parameter_errors(p: dict) -> list[str]:
    """What is wrong with the parameters ``p`` (by name), one phrase per problem."""
    errors = [f"{name}={p[name]!r} must be finite" for name in p if not math.isfinite(p[name])]
    if errors:
        return errors
    errors = [f"{name}={p[name]!r} {VARIABLES[VR[name]][5]} is outside its declared range "
              f"[{lo!r}, inf]" for name, lo in MINIMUM.items() if p[name] < lo]
    if not errors and p["t_stop"] < p["t_start"] + p["speed"] / p["acc"]:
        errors.append(f"t_stop={p['t_stop']!r} s must be >= t_start + speed/acc "
                      f"(={p['t_start'] + p['speed'] / p['acc']!r} s: the ramp-up must end "
                      f"before the ramp-down starts)")
    return errors


def profile(t: float, speed: float, acc: float, t_start: float,
            t_stop: float) -> tuple[float, float, float]:
    """Travel s [mm], speed [mm/s] and acceleration [mm/s^2] at time t [s]."""
    t_ramp = speed / acc
    if t < t_start:
        return 0.0, 0.0, 0.0
    u = t - t_start
    if u < t_ramp:  # ramp up
        return 0.5 * acc * u * u, acc * u, acc
    s_ramp = 0.5 * acc * t_ramp * t_ramp
    if t < t_stop:  # cruise
        return s_ramp + speed * (u - t_ramp), speed, 0.0
    s_stop = s_ramp + speed * (t_stop - t_start - t_ramp)
    w = t - t_stop
    if w < t_ramp:  # ramp down
        return s_stop + speed * w - 0.5 * acc * w * w, speed - acc * w, -acc
    return s_stop + s_ramp, 0.0, 0.0


def master_state(t: float, p: dict) -> tuple[tuple[float, ...], tuple[float, ...],
                                            tuple[float, ...], bool]:
    """(pos, vel, acc, engage) of the conveyor with parameters ``p`` (by name) at time t.

    ``t`` is rounded to the ``sample_time`` grid first (see the module docstring).
    """
    T = p["sample_time"]
    t = round(t / T) * T
    s, v, a = profile(t, p["speed"], p["acc"], p["t_start"], p["t_stop"])
    rad = math.radians(p["angle"])
    ux, uy = math.cos(rad), math.sin(rad)
    pos = (p["x0"] + ux * s, p["y0"] + uy * s, p["z0"])
    return pos, (ux * v, uy * v, 0.0), (ux * a, uy * a, 0.0), p["t_engage"] <= t < p["t_release"]


class CanConveyor(Fmi2Slave):
    """Conveyor master axis with a trapezoidal speed profile and an item sensor."""

    author = "cantrack"
    description = "Conveyor master axis (trapezoidal speed profile, item sensor); mm, s"
    version = "0.1.0"
    license = "MIT"
    default_experiment = DefaultExperiment(start_time=0.0, stop_time=3.0, step_size=0.001)

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self._t0 = 0.0
        #: why steps are refused (invalid parameters at initialisation, or terminated)
        self._refusal: str | None = None
        for name, typ, causality, variability, start, _unit, desc in VARIABLES:
            setattr(self, name, start if start is not None else (False if typ == "Boolean"
                                                                 else 0.0))
            cls = Real if typ == "Real" else Boolean
            self.register_variable(cls(name, causality=getattr(Fmi2Causality, causality),
                                       variability=getattr(Fmi2Variability, variability),
                                       description=desc))
        self._update(0.0)

    def _params(self) -> dict:
        return {row[0]: float(getattr(self, row[0])) for row in VARIABLES
                if row[2] == "parameter"}

    def _update(self, t: float) -> None:
        pos, vel, acc, engage = master_state(t, self._params())
        self.x, self.y, self.z = pos
        self.vx, self.vy, self.vz = vel
        self.ax, self.ay, self.az = acc
        self.engage = engage

    def to_xml(self, model_options: dict | None = None) -> Element:
        """Add units and the InitialUnknowns (pythonfmu issue #193)."""
        root = super().to_xml(model_options or {})
        units = Element("UnitDefinitions")
        for name in sorted({row[5] for row in VARIABLES if row[5]}):
            exps, factor = UNITS[name]
            attrs = {k: str(e) for k, e in exps.items()}
            if factor != 1.0:
                attrs["factor"] = repr(factor)
            SubElement(SubElement(units, "Unit", {"name": name}), "BaseUnit", attrs)
        root.insert(list(root).index(root.find("CoSimulation")) + 1, units)
        for sv in root.find("ModelVariables"):
            unit = VARIABLES[VR[sv.get("name")]][5]
            if unit:
                sv[0].set("unit", unit)
            if sv.get("name") in MINIMUM:
                sv[0].set("min", repr(MINIMUM[sv.get("name")]))
        structure = root.find("ModelStructure")
        initial = SubElement(structure, "InitialUnknowns")
        for unknown in structure.find("Outputs"):
            SubElement(initial, "Unknown", {"index": unknown.get("index")})
        return root

    def setup_experiment(self, start_time: float, *args) -> None:
        self._t0 = float(start_time)

    def exit_initialization_mode(self) -> None:
        """Validate the parameters: invalid ones are one logged error line (status Error:
        the FMU's front library returns it as the call's status) and every step is refused.
        Not raised: pythonfmu turns an exception into Fatal ("unknown error") and then
        crashes the host on fmi2FreeInstance."""
        p = self._params()
        errors = parameter_errors(p)
        if errors:
            self._refusal = (f"{self.instance_name}: exitInitializationMode refused the "
                             f"parameters: {'; '.join(errors)}")
            self.log(self._refusal, Fmi2Status.error)
            return
        self._update(self._t0)

    def terminate(self) -> None:
        self._refusal = f"{self.instance_name}: the instance is terminated (only reset or free it)"

    def do_step(self, current_time: float, step_size: float) -> bool:
        if self._refusal is not None:
            self.log(f"doStep at t={current_time!r} s refused: {self._refusal}",
                     Fmi2Status.error)
            return False
        self._update(current_time + step_size)
        return True
