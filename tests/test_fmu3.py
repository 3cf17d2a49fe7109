"""CanTracker3.fmu (FMI 3.0 CS, pythonfmu3): validation, bit-identity with the core, FMU
state, refused step (fmi3Discard), exception (fmi3Error with the traceback)."""

from __future__ import annotations

import logging

import pytest

pytest.importorskip("pythonfmu3")
pytest.importorskip("fmpy")

from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi3 import FMU3Slave
from fmpy.validation import validate_fmu

from controller.fmu import build_tracker_fmu3
from controller.fmu.engine import VARIABLES, tracker_params
from controller.fmu.runner import (
    bundled_module,
    MASTER_INPUTS,
    OUTPUT_INTS,
    OUTPUT_REALS,
    conveyor_scenario,
    core_run,
    master_values,
)

T = 0.001
DEFAULTS = {row[0]: row[4] for row in VARIABLES if row[2] == "parameter"}


def _optimal_available() -> bool:
    try:
        import controller.tracking.optimal  # noqa: F401
    except Exception:  # noqa: BLE001
        return False
    return True


PLANNER = 1 if _optimal_available() else 0


@pytest.fixture(scope="session")
def fmu3(tmp_path_factory):
    """Built once per session (test_fmu_robustness.py uses the same folder)."""
    d = tmp_path_factory.getbasetemp() / "fmu3-build"
    if not (d / "CanTracker3.fmu").is_file():
        build_tracker_fmu3(d)
    return d / "CanTracker3.fmu"


class Fmu3:
    def __init__(self, path, name="t3", planner=PLANNER):
        self.md = md = read_model_description(str(path))
        self.vr = {v.name: v.valueReference for v in md.modelVariables}
        self.messages = []
        self.slave = FMU3Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                               modelIdentifier=md.coSimulation.modelIdentifier,
                               instanceName=name)
        self.slave.instantiate(loggingOn=True, logMessage=self._log)
        self.slave.enterInitializationMode(startTime=0.0)
        self.slave.setInt32([self.vr["planner"]], [planner])
        self.slave.exitInitializationMode()
        self.ins = [self.vr[n] for n in MASTER_INPUTS]
        self.outs = [self.vr[n] for n in OUTPUT_REALS]
        self.ints = [self.vr[n] for n in OUTPUT_INTS]

    def _log(self, _env, status, category, message):
        self.messages.append((int(status), message.decode(errors="replace")))

    def run(self, scenario, first, n):
        reals, ints = [], []
        for k in range(first, first + n):
            m, e = scenario(k)
            self.slave.setFloat64(self.ins, master_values(m))
            self.slave.setBoolean([self.vr["engage"]], [e])
            self.slave.doStep(currentCommunicationPoint=k * T, communicationStepSize=T)
            reals.append(self.slave.getFloat64(self.outs))
            ints.append(self.slave.getInt32(self.ints))
        return reals, ints

    def close(self):
        self.slave.terminate()
        self.slave.freeInstance()


def test_fmi3_validates(fmu3):
    assert validate_fmu(str(fmu3)) == []
    md = read_model_description(str(fmu3))
    assert md.fmiVersion == "3.0" and md.coSimulation.canGetAndSetFMUstate
    v = {x.name: x for x in md.modelVariables}
    assert v["time"].causality == "independent"
    assert (v["vel_sync"].unit, v["master_ac"].unit, v["x"].unit) == ("mm/s", "deg/s2", "mm")
    assert v["state"].type == "Int32" and v["engage"].type == "Boolean"
    pytest.importorskip("fmu_manipulation_toolbox")
    from controller.fmu.check import run_fmutool_check

    ok, output = run_fmutool_check(fmu3)
    assert ok and "compliant with FMI-3.0" in output, output


def test_fmi3_bit_identical_to_core_and_state(fmu3):
    scenario = conveyor_scenario(T)
    ref = core_run(tracker_params({**DEFAULTS, "planner": PLANNER}), scenario, 1200)
    f = Fmu3(fmu3)
    try:
        reals, ints = f.run(scenario, 0, 400)
        state = f.slave.getFMUState()
        r2, i2 = f.run(scenario, 400, 800)
        assert reals + r2 == ref.reals and ints + i2 == ref.ints
        blob = f.slave.serializeFMUState(state)
        f.slave.freeFMUState(state)
        restored = f.slave.deserializeFMUState(blob)
        f.slave.setFMUState(restored)
        f.slave.freeFMUState(restored)
        r3, i3 = f.run(scenario, 400, 800)
        assert r3 == r2 and i3 == i2
        with pytest.raises(FMICallException) as exc:
            f.slave.doStep(currentCommunicationPoint=1.2, communicationStepSize=1.5 * T)
        assert exc.value.status == 2  # fmi3Discard
        assert "whole multiple" in f.messages[-1][1]
    finally:
        f.close()


def test_fmi3_exception_gives_error_with_traceback(fmu3, monkeypatch, caplog):
    """fmi3Error with the traceback in the importer's logMessage; the Python logger has it too
    but at DEBUG only (pythonfmu3 always forwards errors: no second copy on stderr)."""
    f = Fmu3(fmu3, planner=0)
    try:
        f.run(conveyor_scenario(T), 0, 10)

        def broken(self, master):
            raise RuntimeError("injected failure")

        # (Tracker.advance: the step of Tracker.update, what the FMU's step calls)
        monkeypatch.setattr(bundled_module(fmu3, "tracking.tracker").Tracker, "advance", broken)
        with caplog.at_level(logging.DEBUG, logger="cantrack.fmu"):
            with pytest.raises(FMICallException) as exc:
                f.run(conveyor_scenario(T), 10, 1)
        assert exc.value.status == 3  # fmi3Error
        status, text = f.messages[-1]
        assert status == 3 and "Traceback" in text and "RuntimeError: injected failure" in text
        assert not text.endswith("\n")
        (record,) = [r for r in caplog.records if r.name == "cantrack.fmu"]
        assert record.levelno == logging.DEBUG and record.getMessage() == text
    finally:
        f.close()
