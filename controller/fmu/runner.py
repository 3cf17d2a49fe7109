"""Drive ``CanTracker.fmu`` / ``CanTracker3.fmu`` with fmpy, and the same run with the core.

:class:`FmuTracker` wraps fmpy's ``FMU2Slave`` or ``FMU3Slave`` (chosen by the FMU's
fmiVersion; value references resolved by name, log messages captured); :func:`core_run` is
the reference: ``controller.tracking.Tracker`` fed the same master states, extrapolated the
same way (``MotionState.extrapolated(i*T)`` from the step start).  Used by ``cantrack fmu
check``, the cross-check generator, the FMU tests and ``benchmarks/fmu.py``.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import CantrackError
from ..tracking import MotionState, Tracker, TrackerParams

#: master inputs, in the order of :func:`master_values`
MASTER_INPUTS = ["master_x", "master_y", "master_z", "master_c", "master_vx", "master_vy",
                 "master_vz", "master_vc", "master_ax", "master_ay", "master_az", "master_ac"]
OUTPUT_REALS = ["x", "y", "z", "c", "vx", "vy", "vz", "vc", "ax", "ay", "az", "ac"]
OUTPUT_INTS = ["imfs", "state", "error"]

class FmuRunError(CantrackError):
    """Instantiating or initialising the FMU failed (the message has the FMU's log)."""


#: a master trajectory: step index k -> (master state at the step start, engage)
Scenario = Callable[[int], tuple[MotionState, bool]]


def master_values(m: MotionState) -> list[float]:
    """The master inputs (``MASTER_INPUTS`` order) of a master state."""
    return [m.pos[0], m.pos[1], m.pos[2], m.ang, m.vel[0], m.vel[1], m.vel[2], m.ang_vel,
            m.acc[0], m.acc[1], m.acc[2], m.ang_acc]


def setpoint_values(sp: MotionState) -> list[float]:
    """The real outputs (``OUTPUT_REALS`` order) of a setpoint."""
    return [sp.pos[0], sp.pos[1], sp.pos[2], sp.ang, sp.vel[0], sp.vel[1], sp.vel[2],
            sp.ang_vel, sp.acc[0], sp.acc[1], sp.acc[2], sp.ang_acc]


def conveyor_scenario(step_s: float, *, speed: float = 300.0, engage_s: float = 0.1,
                      release_s: float = 1.0, y: float = 50.0, c0: float = 10.0,
                      c_speed: float = 20.0) -> Scenario:
    """Constant-velocity master along X (+ rotation); engage from ``engage_s`` to ``release_s``."""

    def at(k: int) -> tuple[MotionState, bool]:
        t = k * step_s
        m = MotionState((100.0 + speed * t, y, 0.0), (speed, 0.0, 0.0), (0.0, 0.0, 0.0),
                        c0 + c_speed * t, c_speed, 0.0)
        return m, engage_s <= t < release_s

    return at


def circle_scenario(step_s: float, *, radius: float = 100.0, omega: float = 2.0,
                    windows: Iterable[tuple[float, float]] = ((0.05, 0.6), (0.7, 0.75),
                                                              (0.78, 1.3))) -> Scenario:
    """A master on a circle (|v| = r*w, |a| = r*w^2: all axes accelerate) with a bobbing Z and
    a swinging angle; engaged within the (start, end) windows [s] (re-engages, also during
    the de-sync)."""
    windows = tuple(windows)

    def at(k: int) -> tuple[MotionState, bool]:
        t = k * step_s
        cw, sw = math.cos(omega * t), math.sin(omega * t)
        r, w = radius, omega
        m = MotionState(
            (200.0 + r * cw, r * sw, 5.0 * sw),
            (-r * w * sw, r * w * cw, 5.0 * w * cw),
            (-r * w * w * cw, -r * w * w * sw, -5.0 * w * w * sw),
            20.0 * sw, 20.0 * w * cw, -20.0 * w * w * sw)
        return m, any(a <= t < b for a, b in windows)

    return at


@dataclass
class CoreRun:
    """Outputs of :func:`core_run`, one row per communication step."""

    reals: list[list[float]]
    ints: list[list[int]]


def core_run(params: TrackerParams, scenario: Scenario, n_steps: int,
             samples_per_step: int = 1, initial: MotionState | None = None) -> CoreRun:
    """The reference: the core ``Tracker`` with the FMU's stepping rules, no FMU.

    Step k: master = ``scenario(k)`` (its state at the step start); engage edges (against
    the previous step, ``False`` before the first) act at the first sample; sample i = 1..n
    gets ``master.extrapolated(i*T)``; the row is the setpoint after the last sample.
    """
    T = params.sample_time_s
    tracker = Tracker(params, initial if initial is not None else MotionState.at())
    engaged = False
    reals, ints = [], []
    for k in range(n_steps):
        master, engage = scenario(k)
        if engage != engaged:
            tracker.engage() if engage else tracker.disengage()
            engaged = engage
        for i in range(1, samples_per_step + 1):
            out = tracker.update(master.extrapolated(i * T))
        reals.append(setpoint_values(out.setpoint))
        ints.append([int(out.imfs), int(out.state), int(out.error)])
    return CoreRun(reals, ints)


class FmuTracker:
    """One ``CanTracker.fmu`` (``FMU2Slave``) or ``CanTracker3.fmu`` (``FMU3Slave``) instance
    in fmpy, as a context manager.

    ``start_values``: parameter values by name, set in initialisation mode.  An error of
    exitInitializationMode raises ``FmuRunError`` unless ``init_errors`` (then it is kept in
    ``init_error`` and the instance stays, to see what it does next).
    Log messages go to ``self.messages`` as (status, category, message).  ``self.slave`` is
    the fmpy object; :meth:`get_state` & co. and :meth:`reset` (reset and initialise again)
    hide the FMI 2 / FMI 3 name differences.
    """

    def __init__(self, fmu_path: str | Path, instance_name: str = "tracker",
                 start_values: dict | None = None, start_time: float = 0.0,
                 logging_on: bool = True, unzip_dir: str | Path | None = None,
                 init_errors: bool = False) -> None:
        from fmpy import extract, read_model_description

        self.path = Path(fmu_path)
        self.model_description = md = read_model_description(str(self.path))
        self.fmi3 = md.fmiVersion.startswith("3")
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.types = {v.name: v.type for v in md.modelVariables}
        self._own_dir = unzip_dir is None
        self.unzip_dir = extract(str(self.path)) if unzip_dir is None else str(unzip_dir)
        self.messages: list[tuple[int, str, str]] = []
        self._in_vrs = [self.vr[n] for n in MASTER_INPUTS]
        self._out_vrs = [self.vr[n] for n in OUTPUT_REALS]
        self._int_vrs = [self.vr[n] for n in OUTPUT_INTS]
        self._engage_vr = [self.vr["engage"]]
        self.slave = None
        self.time = start_time
        #: keep an error of exitInitializationMode in :attr:`init_error` instead of raising
        #: (at instantiation and at each :meth:`reset`)
        self.init_errors = init_errors
        #: the FMICallException of the last exitInitializationMode (kept when
        #: ``init_errors``), None when it was accepted
        self.init_error: Exception | None = None
        #: the parameter values set in initialisation mode (again by :meth:`reset`)
        self.start_values = dict(start_values or {})
        try:
            if self.fmi3:
                self._instantiate3(instance_name, logging_on, start_time)
            else:
                self._instantiate2(instance_name, logging_on, start_time)
            if start_values:
                self.set(start_values)
            self._exit_initialization()
        except Exception as exc:
            log = "\n".join(f"[{c}] {m}" for _, c, m in self.messages[-3:])
            # after fmi2Fatal pythonfmu crashes on any further call: leave the instance
            self.slave = None
            self.close()
            raise FmuRunError(f"{self.path}: instantiation/initialisation failed: {exc}"
                              + (f"\n{log}" if log else "")) from exc

    def _log(self, status, category, message) -> None:
        self.messages.append((int(status), (category or b"").decode(errors="replace"),
                              (message or b"").decode(errors="replace")))

    def _instantiate2(self, instance_name: str, logging_on: bool, start_time: float) -> None:
        from fmpy import calloc, free
        from fmpy.fmi2 import (
            FMU2Slave,
            fmi2CallbackAllocateMemoryTYPE,
            fmi2CallbackFreeMemoryTYPE,
            fmi2CallbackFunctions,
            fmi2CallbackLoggerTYPE,
        )

        md = self.model_description
        callbacks = fmi2CallbackFunctions()
        callbacks.logger = fmi2CallbackLoggerTYPE(
            lambda _env, _name, status, category, message: self._log(status, category, message))
        callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        try:
            from ctypes import byref

            from fmpy.logging import addLoggerProxy
            addLoggerProxy(byref(callbacks))
        except Exception:  # pragma: no cover - older fmpy: messages may keep '%' escapes
            pass
        self._callbacks = callbacks  # keep alive
        self.slave = slave = FMU2Slave(guid=md.guid, unzipDirectory=self.unzip_dir,
                                       modelIdentifier=md.coSimulation.modelIdentifier,
                                       instanceName=instance_name)
        self._set_real, self._set_int = slave.setReal, slave.setInteger
        self._get_real, self._get_int = slave.getReal, slave.getInteger
        slave.instantiate(callbacks=callbacks, loggingOn=logging_on)
        self._enter_initialization(start_time)

    def _instantiate3(self, instance_name: str, logging_on: bool, start_time: float) -> None:
        from fmpy.fmi3 import FMU3Slave

        md = self.model_description
        self.slave = slave = FMU3Slave(guid=md.guid, unzipDirectory=self.unzip_dir,
                                       modelIdentifier=md.coSimulation.modelIdentifier,
                                       instanceName=instance_name)
        self._set_real, self._set_int = slave.setFloat64, slave.setInt32
        self._get_real, self._get_int = slave.getFloat64, slave.getInt32
        slave.instantiate(loggingOn=logging_on, logMessage=(
            lambda _env, status, category, message: self._log(status, category, message)))
        self._enter_initialization(start_time)

    def _instance(self) -> Any:
        """The fmpy slave (``FMU2Slave`` or ``FMU3Slave``); :class:`FmuRunError` when there
        is none (closed, or left after a failed instantiation)."""
        slave: Any = self.slave
        if slave is None:
            raise FmuRunError(f"{self.path}: no FMU instance (closed)")
        return slave

    def _enter_initialization(self, start_time: float) -> None:
        """Initialisation mode at ``start_time`` [s] (FMI 2: setupExperiment, then
        enterInitializationMode; FMI 3: enterInitializationMode with the start time)."""
        slave = self._instance()
        if self.fmi3:
            slave.enterInitializationMode(startTime=start_time)
        else:
            slave.setupExperiment(startTime=start_time)
            slave.enterInitializationMode()

    def _exit_initialization(self) -> None:
        """exitInitializationMode; :attr:`init_error` is its error (kept when
        :attr:`init_errors`, else raised) or None."""
        self.init_error = None
        try:
            self._instance().exitInitializationMode()
        except Exception as exc:
            if not self.init_errors:
                raise
            self.init_error = exc

    def reset(self, start_values: dict | None = None, start_time: float = 0.0) -> None:
        """fmi2Reset / fmi3Reset, then initialise the instance again as at instantiation:
        initialisation mode at ``start_time`` [s] (FMI 2: setupExperiment first), the
        parameter values ``start_values`` (default: the instance's :attr:`start_values`, those
        given at instantiation), exitInitializationMode; :attr:`time` = ``start_time``.
        :attr:`init_error` is that exitInitializationMode's, as at instantiation: None when
        it is accepted (an earlier refusal is cleared), its error when it is refused and
        :attr:`init_errors` (else raised).  Any other refused call raises fmpy's
        ``FMICallException`` (a reset refused before anything else is called: FMI 3 after
        Fatal)."""
        slave = self._instance()
        slave.reset()
        self._enter_initialization(start_time)
        values = self.start_values if start_values is None else start_values
        if values:
            self.set(values)
        self._exit_initialization()
        self.time = start_time

    def set(self, values: dict) -> None:
        """Set variables by name (Real/Float64, Integer/Int32 or Boolean)."""
        for name, value in values.items():
            typ = self.types[name]
            if typ in ("Real", "Float64"):
                self._set_real([self.vr[name]], [float(value)])
            elif typ in ("Integer", "Int32"):
                self._set_int([self.vr[name]], [int(value)])
            elif typ == "Enumeration":  # FMI 2: an Integer; FMI 3: Int64
                setter = getattr(self.slave, "setInt64" if self.fmi3 else "setInteger")
                setter([self.vr[name]], [int(value)])
            elif typ == "Boolean":
                self.slave.setBoolean([self.vr[name]], [bool(value)])
            else:
                raise TypeError(f"{name}: unsupported type {typ}")

    def step(self, master: MotionState, engage: bool, step_size: float) -> None:
        """Set the master and engage, then one ``doStep`` from ``self.time``."""
        self._set_real(self._in_vrs, master_values(master))
        self.slave.setBoolean(self._engage_vr, [engage])
        self.slave.doStep(currentCommunicationPoint=self.time, communicationStepSize=step_size)
        self.time += step_size

    def outputs(self) -> tuple[list[float], list[int]]:
        return self._get_real(self._out_vrs), self._get_int(self._int_vrs)

    def get_ints(self, names: list[str]) -> list[int]:
        """Integer variables by name (e.g. ``master_status``, ``master_outliers``)."""
        return list(self._get_int([self.vr[n] for n in names]))

    # -- FMU state (FMI 2 and FMI 3 spell the calls differently) ---------------------------
    def get_state(self):
        return self.slave.getFMUState() if self.fmi3 else self.slave.getFMUstate()

    def set_state(self, state) -> None:
        self.slave.setFMUState(state) if self.fmi3 else self.slave.setFMUstate(state)

    def free_state(self, state) -> None:
        self.slave.freeFMUState(state) if self.fmi3 else self.slave.freeFMUstate(state)

    def serialize_state(self, state) -> bytes:
        return (self.slave.serializeFMUState(state) if self.fmi3
                else self.slave.serializeFMUstate(state))

    def deserialize_state(self, data: bytes):
        return (self.slave.deserializeFMUState(data) if self.fmi3
                else self.slave.deSerializeFMUstate(data))

    def run(self, scenario: Scenario, n_steps: int, step_size: float,
            first_step: int = 0) -> CoreRun:
        """Steps ``first_step .. first_step + n_steps - 1`` of a scenario; outputs per step."""
        reals, ints = [], []
        for k in range(first_step, first_step + n_steps):
            master, engage = scenario(k)
            self.step(master, engage, step_size)
            r, i = self.outputs()
            reals.append(r)
            ints.append(i)
        return CoreRun(reals, ints)

    def close(self) -> None:
        slave, self.slave = getattr(self, "slave", None), None
        if slave is not None:
            try:
                slave.terminate()
            except Exception:
                pass
            try:
                slave.freeInstance()
            except Exception:
                slave.freeLibrary()
        if self._own_dir:
            shutil.rmtree(self.unzip_dir, ignore_errors=True)

    def __enter__(self) -> FmuTracker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def bundled_module(fmu_path: str | Path, name: str):
    """The FMU's private copy of ``controller.<name>`` as imported in this process (after an
    instance of the FMU was created), e.g. ``bundled_module(fmu, "tracking.tracker")``:
    each FMU runs its own copy of the core under a private package name (see ``build``)."""
    import sys
    import zipfile

    with zipfile.ZipFile(fmu_path) as zf:
        module = zf.read("resources/slavemodule.txt").decode().strip()
    return sys.modules[f"_{module}.{name}"]
