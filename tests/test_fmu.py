"""CanTracker.fmu (FMI 2.0 CS, pythonfmu): build, validation, bit-identity with the core,
FMU state, step-size refusal, error logging, several instances, bundling, CLI.

The FMUs are built once per session into a temporary folder.  The FMU's Python code runs in
this process (pythonfmu uses the host's interpreter), so it uses the ``controller`` package
already imported here; ``test_bundled_core_runs_standalone`` checks the bundled copy in a
process where the installed package is hidden.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("pythonfmu")
pytest.importorskip("fmpy")

from fmpy import read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.validation import validate_fmu

from controller.fmu import build_conveyor_fmu, build_tracker_fmu
from controller.fmu.engine import VARIABLES, tracker_params
from controller.fmu.runner import (FmuTracker, bundled_module, circle_scenario,
                                   conveyor_scenario, core_run)
from controller.tracking import MotionState, Tracker, TrackerParams

REPO = Path(__file__).resolve().parents[1]
T = 0.001


def _optimal_available() -> bool:
    try:
        import controller.tracking.optimal  # noqa: F401
    except Exception:
        return False
    return True


#: planner codes to test: 0 softmc always, 1 optimal when it imports (ruckig)
PLANNERS = [0, 1] if _optimal_available() else [0]
DEFAULTS = {row[0]: row[4] for row in VARIABLES if row[2] == "parameter"}


def params_for(**fmu_values) -> TrackerParams:
    """The TrackerParams the FMU uses for these FMU parameter values."""
    return tracker_params({**DEFAULTS, **fmu_values})


def built_fmus(tmp_path_factory) -> Path:
    """CanTracker.fmu and CanConveyor.fmu, built once per session (shared by test_fmu*.py)."""
    d = tmp_path_factory.getbasetemp() / "fmu-build"
    if not (d / "CanConveyor.fmu").is_file():
        build_tracker_fmu(d)
        build_conveyor_fmu(d)
    return d


@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory) -> Path:
    return built_fmus(tmp_path_factory)


@pytest.fixture(scope="session")
def tracker_fmu(fmu_dir) -> Path:
    return fmu_dir / "CanTracker.fmu"


# -- build and model description -----------------------------------------------------------
def test_build_layout(tracker_fmu):
    with zipfile.ZipFile(tracker_fmu) as zf:
        names = set(zf.namelist())
        module = zf.read("resources/slavemodule.txt").decode().strip()
    assert re.fullmatch(r"cantracker_[0-9a-f]{12}", module)
    assert f"resources/{module}.py" in names
    # the core lives in a private package named after the script (no host can shadow it)
    private = f"resources/_{module}/"
    for f in ("__init__.py", "errors.py", "limits.py", "tracking/__init__.py",
              "tracking/tracker.py", "tracking/softmc.py", "fmu/engine.py", "fmu/runtime.py", "pythonfmu/fmi2slave.py"):
        assert private + f in names, f
    assert not any(n.startswith("resources/controller/") for n in names)
    script = zipfile.ZipFile(tracker_fmu).read(f"resources/{module}.py").decode()
    assert not re.search(r"^(from|import) (controller|pythonfmu)\b", script, re.M)
    assert f"from _{module}.pythonfmu import" in script
    assert "documentation/index.html" in names
    # the front library (controller/fmu/front.c) in front of pythonfmu's wrapper on Linux;
    # pythonfmu's wrapper alone on Windows
    binaries = {n for n in names if n.endswith((".so", ".dll", ".dylib", ".pyd"))}
    assert binaries == {"binaries/linux64/CanTracker.so",
                        "binaries/linux64/CanTracker_pythonfmu.so", "binaries/win64/CanTracker.dll"}
    # the FMU does not carry the rest of the package (CLI, simulator, FMU build/check code)
    assert {n for n in names if n.startswith(private + "fmu/")} == {
        private + "fmu/__init__.py", private + "fmu/engine.py", private + "fmu/runtime.py"}
    assert not any(n.startswith((private + "simulate", private + "cli", private + "motion"))
                   for n in names)


def test_model_description_contract(tracker_fmu):
    md = read_model_description(str(tracker_fmu))
    assert md.fmiVersion == "2.0" and md.modelName == "CanTracker"
    cs = md.coSimulation
    assert cs.canGetAndSetFMUstate and cs.canSerializeFMUstate
    assert not cs.canBeInstantiatedOnlyOncePerProcess
    assert float(md.defaultExperiment.stepSize) == 0.001
    assert float(md.defaultExperiment.stopTime) == 1.0
    (mode_type,) = [t for t in md.typeDefinitions if t.name == "Mode"]
    assert [(i.name, int(i.value)) for i in mode_type.items] == [("absolute", 3), ("relative", 5)]
    v = {x.name: x for x in md.modelVariables}
    expect = {
        "sample_time": ("parameter", "fixed", "Real", 0.001, "s"),
        "mode": ("parameter", "fixed", "Enumeration", 3, None),  # items 3, 5 (see below)
        "planner": ("parameter", "fixed", "Integer", 1, None),
        "vel_sync": ("parameter", "tunable", "Real", 2000, "mm/s"),
        "acc_sync": ("parameter", "tunable", "Real", 20000, "mm/s2"),
        "jerk_sync": ("parameter", "tunable", "Real", 400000, "mm/s3"),
        "vel_desync": ("parameter", "tunable", "Real", 2000, "mm/s"),
        "acc_desync": ("parameter", "tunable", "Real", 20000, "mm/s2"),
        "jerk_desync": ("parameter", "tunable", "Real", 400000, "mm/s3"),
        "vel_sync_rot": ("parameter", "tunable", "Real", 360, "deg/s"),
        "acc_sync_rot": ("parameter", "tunable", "Real", 3600, "deg/s2"),
        "jerk_sync_rot": ("parameter", "tunable", "Real", 72000, "deg/s3"),
        "vel_desync_rot": ("parameter", "tunable", "Real", 360, "deg/s"),
        "acc_desync_rot": ("parameter", "tunable", "Real", 3600, "deg/s2"),
        "jerk_desync_rot": ("parameter", "tunable", "Real", 72000, "deg/s3"),
        "filter_factor": ("parameter", "tunable", "Real", 1, "1"),  # dimensionless
        "damping_factor": ("parameter", "tunable", "Real", 1, "1"),
        # the contract says 10: the start value follows the core's default instead
        # (TrackerParams.max_flops, now 6 in a 3 s window)
        "max_flops": ("parameter", "tunable", "Integer", TrackerParams().max_flops, None),
        "vel_max_master": ("parameter", "tunable", "Real", 1000, "mm/s"),
        "acc_max_master": ("parameter", "tunable", "Real", 1000, "mm/s2"),
        "x0": ("parameter", "fixed", "Real", 0, "mm"),
        "c0": ("parameter", "fixed", "Real", 0, "deg"),
        "master_x": ("input", "continuous", "Real", 0, "mm"),
        "master_c": ("input", "continuous", "Real", 0, "deg"),
        "master_vy": ("input", "continuous", "Real", 0, "mm/s"),
        "master_vc": ("input", "continuous", "Real", 0, "deg/s"),
        "master_az": ("input", "continuous", "Real", 0, "mm/s2"),
        "master_ac": ("input", "continuous", "Real", 0, "deg/s2"),
        "engage": ("input", "discrete", "Boolean", "false", None),
        "x": ("output", "continuous", "Real", None, "mm"),
        "vc": ("output", "continuous", "Real", None, "deg/s"),
        "az": ("output", "continuous", "Real", None, "mm/s2"),
        "imfs": ("output", "discrete", "Integer", None, None),
        "state": ("output", "discrete", "Integer", None, None),
        "error": ("output", "discrete", "Integer", None, None),
        "master_input": ("parameter", "fixed", "Enumeration", 0, None),
        "encoder_resolution": ("parameter", "fixed", "Real", 0, "mm"),
        "encoder_resolution_rot": ("parameter", "fixed", "Real", 0, "deg"),
        "encoder_latency": ("parameter", "fixed", "Integer", 0, None),
        "jerk_max_master": ("parameter", "fixed", "Real", 1000, "mm/s3"),
        "encoder_outlier": ("parameter", "fixed", "Real", 0, "mm"),
        "encoder_max_outliers": ("parameter", "fixed", "Integer", 10, None),
        "master_status": ("output", "discrete", "Integer", None, None),
        "master_outliers": ("output", "discrete", "Integer", None, None),
    }
    for name, (causality, variability, typ, start, unit) in expect.items():
        x = v[name]
        assert (x.causality, x.variability, x.type) == (causality, variability, typ), name
        if start is None:
            assert x.start is None, name
        elif typ == "Boolean":
            assert str(x.start).lower() == start, name
        else:
            assert float(x.start) == start, name
        assert x.unit == unit, name
        assert x.description, name
    # every Real has a unit ("1" when dimensionless); enumerations are documented
    assert all(x.unit for x in md.modelVariables if x.type == "Real")
    assert "2 SYNCED" in v["state"].description and "-1 DESYNCING" in v["imfs"].description
    assert "1 MASTER_VELOCITY" in v["error"].description
    (inp_type,) = [t for t in md.typeDefinitions if t.name == "MasterInput"]
    assert [(i.name, int(i.value)) for i in inp_type.items] == [("state", 0), ("encoder", 1)]
    assert "1 OK" in v["master_status"].description
    outputs = [x for x in md.modelVariables if x.causality == "output"]
    assert len(outputs) == 17
    assert {u.variable.name for u in md.initialUnknowns} == {x.name for x in outputs}
    deps = {u.variable.name: [d.name for d in u.dependencies] for u in md.initialUnknowns}
    assert deps["master_status"] == ["master_input"] and deps["x"] == ["x0"]


def test_fmpy_validate(fmu_dir):
    for name in ("CanTracker.fmu", "CanConveyor.fmu"):
        assert validate_fmu(str(fmu_dir / name)) == [], name


def test_fmutool_check(fmu_dir):
    pytest.importorskip("fmu_manipulation_toolbox")
    from controller.fmu.check import run_fmutool_check

    for name in ("CanTracker.fmu", "CanConveyor.fmu"):
        ok, output = run_fmutool_check(fmu_dir / name)
        assert ok, output
        assert "No semantic error" in output and "compliant with FMI-2.0" in output


# -- bit-identity with the core ---------------------------------------------------------------
@pytest.mark.parametrize("planner", PLANNERS)
@pytest.mark.parametrize("scenario_name", ["conveyor", "circle"])
@pytest.mark.parametrize("samples_per_step", [1, 4])
def test_bit_identical_to_core(tracker_fmu, planner, scenario_name, samples_per_step):
    """FMU2Slave loop vs ``Tracker`` fed the same master, extrapolated the same way."""
    base = (conveyor_scenario if scenario_name == "conveyor" else circle_scenario)(T)
    n = samples_per_step

    def scenario(k):  # the master at the step start, step k = [k*n*T, (k+1)*n*T]
        return base(k * n)

    steps = 1400 // n
    with FmuTracker(tracker_fmu, start_values={"planner": planner}) as fmu:
        got = fmu.run(scenario, steps, n * T)
    # the reference, written out here: one Tracker, edges at the step, extrapolate i*T
    tracker = Tracker(params_for(planner=planner), MotionState.at(0, 0, 0, 0))
    engaged = False
    for k in range(steps):
        master, engage = scenario(k)
        if engage != engaged:
            tracker.engage() if engage else tracker.disengage()
            engaged = engage
        for i in range(1, n + 1):
            out = tracker.update(master.extrapolated(i * T))
        sp = out.setpoint
        assert got.reals[k] == [*sp.pos, sp.ang, *sp.vel, sp.ang_vel, *sp.acc, sp.ang_acc], k
        assert got.ints[k] == [int(out.imfs), int(out.state), int(out.error)], k
    states = {row[1] for row in got.ints}
    assert {0, 1, 3} <= states  # engaged, approached and de-synced
    if scenario_name == "conveyor":
        assert 2 in states and {row[2] for row in got.ints} == {0}


@pytest.mark.parametrize("planner", PLANNERS)
def test_simulate_fmu_with_input_table_is_bit_identical(tracker_fmu, planner):
    np = pytest.importorskip("numpy")
    from fmpy import simulate_fmu

    from controller.fmu.runner import MASTER_INPUTS, OUTPUT_INTS, OUTPUT_REALS, master_values

    scenario, n = conveyor_scenario(T), 1200
    rows = []
    for k in range(n + 1):
        m, e = scenario(k)
        rows.append((k * T, *master_values(m), e))
    signals = np.array(rows, dtype=[("time", float)] + [(c, float) for c in MASTER_INPUTS]
                       + [("engage", bool)])
    result = simulate_fmu(str(tracker_fmu), start_values={"planner": planner}, stop_time=n * T,
                          output_interval=T, input=signals)
    ref = core_run(params_for(planner=planner), scenario, n)
    assert len(result) == n + 1
    for k in range(n):
        assert [float(result[c][k + 1]) for c in OUTPUT_REALS] == ref.reals[k], k
        assert [int(result[c][k + 1]) for c in OUTPUT_INTS] == ref.ints[k], k


def test_consistent_with_simulate_run_scenario(tracker_fmu):
    """``cantrack simulate`` (controller.simulate.run_scenario) on examples/linear_absolute.

    The simulator feeds the master at each sample time, the FMU extrapolates the master of
    the step start by T: the same values up to rounding (constant velocity), so the states
    agree exactly and the setpoints to rounding level.
    """
    simulate = pytest.importorskip("controller.simulate")
    example = REPO / "examples" / "linear_absolute.yaml"
    if not example.is_file():
        pytest.skip("examples/linear_absolute.yaml not present")
    res = simulate.run_scenario(example)
    p, robot = res.params, res.scenario.robot
    start = {"sample_time": p.sample_time_s, "mode": int(p.mode), "planner": 0,
             "vel_sync": p.sync_trans.vel, "acc_sync": p.sync_trans.acc,
             "jerk_sync": p.sync_trans.jerk, "vel_desync": p.desync_trans.vel,
             "acc_desync": p.desync_trans.acc, "jerk_desync": p.desync_trans.jerk,
             "vel_sync_rot": p.sync_rot.vel, "acc_sync_rot": p.sync_rot.acc,
             "jerk_sync_rot": p.sync_rot.jerk, "filter_factor": p.filter_factor,
             "damping_factor": p.damping_factor, "x0": robot.pos[0], "y0": robot.pos[1],
             "z0": robot.pos[2], "c0": robot.ang}
    assert p.planner == "softmc"
    Ts, n = p.sample_time_s, res.scenario.n_samples
    (ke,), (kd,) = res.scenario.engage_samples, res.scenario.disengage_samples

    def scenario(k):
        m = MotionState(tuple(res.master_pos[k]), tuple(res.master_vel[k]),
                        tuple(res.master_acc[k]), float(res.master_ang[k]),
                        float(res.master_ang_vel[k]), float(res.master_ang_acc[k]))
        return m, ke <= k < kd

    with FmuTracker(tracker_fmu, start_values=start) as fmu:
        got = fmu.run(scenario, n, Ts)
    assert [row[1] for row in got.ints] == res.state[1:].tolist()
    assert [row[2] for row in got.ints] == res.error[1:].tolist()
    for k in range(n):
        assert got.reals[k][0:3] == pytest.approx(res.setpoint_pos[k + 1].tolist(), abs=1e-6)
        assert got.reals[k][4:7] == pytest.approx(res.setpoint_vel[k + 1].tolist(), abs=1e-5)


# -- tunables --------------------------------------------------------------------------------
def test_tunable_change_takes_effect_at_next_engage(tracker_fmu):
    scenario = circle_scenario(T, windows=((0.05, 0.5), (0.6, 1.2)))
    n_change = 300  # engaged (first window), before the second engage
    with FmuTracker(tracker_fmu, start_values={"planner": 0}) as fmu:
        a = fmu.run(scenario, n_change, T)
        fmu.set({"acc_sync": 5000.0, "vel_sync": 800.0, "acc_desync": 8000.0})
        b = fmu.run(scenario, 1400 - n_change, T, first_step=n_change)
    got = a.reals + b.reals
    # reference: the old parameters until the second engage, then a new Tracker
    old, new = params_for(planner=0), params_for(planner=0, acc_sync=5000.0, vel_sync=800.0,
                                                 acc_desync=8000.0)
    tracker = Tracker(old, MotionState.at())
    engaged = False
    for k in range(1400):
        master, engage = scenario(k)
        if engage != engaged:
            if engage and k > n_change:
                tracker = Tracker(new, tracker.setpoint)
            tracker.engage() if engage else tracker.disengage()
            engaged = engage
        out = tracker.update(master.extrapolated(T))
        sp = out.setpoint
        assert got[k] == [*sp.pos, sp.ang, *sp.vel, sp.ang_vel, *sp.acc, sp.ang_acc], k
    with FmuTracker(tracker_fmu, start_values={"planner": 0}) as fmu:  # without the change
        c = fmu.run(scenario, 1400, T)
    k2 = next(k for k in range(n_change, 1400) if scenario(k)[1])
    assert c.reals[:k2] == got[:k2] and c.reals[k2:] != got[k2:]


# -- FMU state -------------------------------------------------------------------------------
@pytest.mark.parametrize("planner", PLANNERS)
@pytest.mark.parametrize("save_at", [120, 250, 800])  # syncing, synced or de-syncing, off
def test_state_save_restore_serialize_bit_identical(tracker_fmu, planner, save_at):
    scenario = conveyor_scenario(T, engage_s=0.1, release_s=0.7)
    with FmuTracker(tracker_fmu, "a", start_values={"planner": planner}) as fmu:
        fmu.run(scenario, save_at, T)
        state = fmu.slave.getFMUstate()
        t_saved = fmu.time
        first = fmu.run(scenario, 500, T, first_step=save_at)
        replays = []
        for _ in range(2):  # the same saved state restored twice
            fmu.slave.setFMUstate(state)
            fmu.time = t_saved
            replays.append(fmu.run(scenario, 500, T, first_step=save_at))
        blob = fmu.slave.serializeFMUstate(state)
        fmu.slave.freeFMUstate(state)
        restored = fmu.slave.deSerializeFMUstate(blob)
        fmu.slave.setFMUstate(restored)
        fmu.slave.freeFMUstate(restored)
        fmu.time = t_saved
        replays.append(fmu.run(scenario, 500, T, first_step=save_at))
    # a fresh instance continues from the serialized state
    with FmuTracker(tracker_fmu, "b", start_values={"planner": planner}) as other:
        restored = other.slave.deSerializeFMUstate(blob)
        other.slave.setFMUstate(restored)
        other.slave.freeFMUstate(restored)
        other.time = t_saved
        replays.append(other.run(scenario, 500, T, first_step=save_at))
    for r in replays:
        assert r.reals == first.reals and r.ints == first.ints
    ref = core_run(params_for(planner=planner), scenario, save_at + 500)
    assert first.reals == ref.reals[save_at:] and first.ints == ref.ints[save_at:]


# -- refused steps and errors ------------------------------------------------------------------
def test_refused_step_size(tracker_fmu, caplog):
    scenario = conveyor_scenario(T)
    with FmuTracker(tracker_fmu, start_values={"planner": 0}) as fmu:
        fmu.run(scenario, 10, T)
        with caplog.at_level(logging.ERROR, logger="cantrack.fmu"):
            for bad in (1.5 * T, 0.5 * T, 2.0004 * T):
                with pytest.raises(FMICallException) as exc:
                    fmu.slave.doStep(currentCommunicationPoint=fmu.time,
                                     communicationStepSize=bad)
                assert exc.value.status == 2  # fmi2Discard
        msg = fmu.messages[-1]
        assert msg[1] == "logStatusDiscard" and "whole multiples" in msg[2]
        assert "sample_time=0.001 s" in msg[2] and "0.0020004" in msg[2]
        assert any("whole multiples" in r.getMessage() for r in caplog.records)
        # not failed: steps that are multiples (within the tolerance) go on
        m = MotionState((5.0, 1.0, 0.0), (300.0, 20.0, 0.0), (100.0, 0.0, 0.0), 2.0, 3.0, 0.0)
        fmu.step(m, True, T * (1 + 1e-12))  # 1 sample
        fmu.step(m, True, 3 * T * (1 - 1e-13))  # 3 samples
        got = fmu.outputs()
    tracker = Tracker(params_for(planner=0), MotionState.at())
    for k in range(10):
        tracker.update(scenario(k)[0].extrapolated(T))
    tracker.engage()
    tracker.update(m.extrapolated(T))
    for i in (1, 2, 3):
        out = tracker.update(m.extrapolated(i * T))
    sp = out.setpoint
    assert got[0] == [*sp.pos, sp.ang, *sp.vel, sp.ang_vel, *sp.acc, sp.ang_acc]
    assert got[1] == [0, 1, 0]  # syncing


def test_exception_in_step_is_logged_with_traceback(tracker_fmu, monkeypatch, caplog):
    """An exception inside the tracker: error log with the traceback, fmi2Error, and the
    instance refuses steps until a saved state is set."""
    scenario = conveyor_scenario(T)
    with FmuTracker(tracker_fmu, start_values={"planner": 0}) as fmu:
        fmu.run(scenario, 150, T)
        saved = fmu.slave.getFMUstate()
        t_saved = fmu.time
        # the FMU runs its private copy of the core: break that one
        fmu_tracker = bundled_module(tracker_fmu, "tracking.tracker").Tracker
        real_update = fmu_tracker.advance  # (the step of update; the FMU's step calls it)

        def broken(self, master):
            raise RuntimeError("injected failure in Tracker.update")

        monkeypatch.setattr(fmu_tracker, "advance", broken)
        m, e = scenario(150)
        with caplog.at_level(logging.ERROR, logger="cantrack.fmu"):
            with pytest.raises(FMICallException) as exc:
                fmu.step(m, e, T)
        assert exc.value.status == 3  # fmi2Error: the front library returns the logged status
        status, category, text = fmu.messages[-1]
        assert status == 3 and category == "logStatusError"
        assert "Traceback (most recent call last)" in text
        assert "RuntimeError: injected failure in Tracker.update" in text
        assert "unknown error" not in text
        assert any("injected failure" in r.getMessage() for r in caplog.records)
        monkeypatch.setattr(fmu_tracker, "advance", real_update)
        with pytest.raises(FMICallException):
            fmu.step(m, e, T)  # refused: failed earlier
        assert "failed earlier" in fmu.messages[-1][2]
        fmu.slave.setFMUstate(saved)  # recovers
        fmu.slave.freeFMUstate(saved)
        fmu.time = t_saved
        got = fmu.run(scenario, 50, T, first_step=150)
    ref = core_run(params_for(planner=0), scenario, 200)
    assert got.reals == ref.reals[150:]


def test_reset_starts_over(tracker_fmu):
    scenario = conveyor_scenario(T)
    with FmuTracker(tracker_fmu, start_values={"planner": 0}) as fmu:
        first = fmu.run(scenario, 300, T)
        fmu.reset()  # (planner 0 again, time 0)
        again = fmu.run(scenario, 300, T)
    assert again.reals == first.reals and again.ints == first.ints


def test_invalid_tunable_at_engage_is_refused_and_repeatable(tracker_fmu):
    scenario = conveyor_scenario(T, engage_s=0.05)
    with FmuTracker(tracker_fmu, start_values={"planner": 0}) as fmu:
        fmu.run(scenario, 50, T)  # engage rises at step 50
        fmu.set({"vel_sync": -5.0})
        m, e = scenario(50)
        with pytest.raises(FMICallException) as exc:
            fmu.step(m, e, T)
        assert exc.value.status == 2
        status, category, text = fmu.messages[-1]
        assert (status, category) == (2, "logStatusDiscard")
        assert "vel_sync=-5.0 mm/s is outside its declared range [1e-09, inf]" in text
        assert "Traceback" not in text and "\n" not in text
        # the step was not done (fmu.time did not advance): repeat it with a valid value
        fmu.set({"vel_sync": 2000.0})
        got = fmu.run(scenario, 400, T, first_step=50)
    ref = core_run(params_for(planner=0), scenario, 450)
    assert got.reals == ref.reals[50:] and got.ints == ref.ints[50:]


def test_invalid_fixed_parameter_is_logged_and_every_step_refused(tracker_fmu, caplog):
    """fmi2Error (not fmi2Fatal: pythonfmu then crashes on fmi2FreeInstance) from
    exitInitializationMode with one line naming the value and its declared range, no
    traceback; every step refused with the message; the instance can still be freed."""
    with caplog.at_level(logging.ERROR, logger="cantrack.fmu"):
        with FmuTracker(tracker_fmu, start_values={"sample_time": 0.5},
                        init_errors=True) as fmu:
            assert fmu.init_error.status == 3
            status, category, text = fmu.messages[-1]
            assert (status, category) == (3, "logStatusError")
            assert text == ("tracker: exitInitializationMode refused the parameters: "
                            "sample_time=0.5 s is outside its declared range [1e-05, 0.1]")
            for _ in range(2):
                with pytest.raises(FMICallException) as exc:
                    fmu.step(MotionState(), False, 0.5)
                assert exc.value.status == 3
                assert "sample_time=0.5 s" in fmu.messages[-1][2]
                assert "Traceback" not in fmu.messages[-1][2]
    assert any("sample_time=0.5 s" in r.getMessage() for r in caplog.records)


def test_reset_initialises_again_and_clears_the_init_error(tracker_fmu):
    """``FmuTracker.reset`` initialises afresh: a refused initialisation's ``init_error``
    goes with a reset whose parameters are accepted (the instance then steps as the core),
    and a reset whose parameters are refused keeps its own error when ``init_errors``."""
    scenario = conveyor_scenario(T)
    with FmuTracker(tracker_fmu, start_values={"sample_time": 0.5},
                    init_errors=True) as fmu:
        assert fmu.init_error is not None and fmu.init_error.status == 3
        fmu.reset(start_values={"sample_time": T, "planner": 0})
        assert fmu.init_error is None
        got = fmu.run(scenario, 200, T)
        assert got.reals == core_run(params_for(planner=0), scenario, 200).reals
        fmu.reset(start_values={"sample_time": 0.5})
        assert fmu.init_error is not None and fmu.init_error.status == 3
        assert "sample_time=0.5 s" in fmu.messages[-1][2]
    with FmuTracker(tracker_fmu, start_values={"planner": 0}) as fmu:
        with pytest.raises(FMICallException):  # (without init_errors: raised, as at start)
            fmu.reset(start_values={"sample_time": 0.5})


def test_unusable_serialized_state_is_refused_without_crash(tracker_fmu):
    with FmuTracker(tracker_fmu, start_values={"planner": 0}) as fmu:
        state = fmu.slave.deSerializeFMUstate(b"not a pickled state")
        with pytest.raises(FMICallException) as exc:
            fmu.slave.setFMUstate(state)
        assert exc.value.status == 3  # fmi2Error (the front library: the logged status)
        fmu.slave.freeFMUstate(state)
        assert "unusable state" in fmu.messages[-1][2]
        with pytest.raises(FMICallException):
            fmu.step(MotionState(), False, T)


# -- several instances ---------------------------------------------------------------------------
def test_two_instances_are_independent(tracker_fmu):
    sa = conveyor_scenario(T)
    sb = circle_scenario(T)
    pb = PLANNERS[-1]
    a = FmuTracker(tracker_fmu, "a", start_values={"planner": 0, "x0": 10.0})
    b = FmuTracker(tracker_fmu, "b", start_values={"planner": pb, "acc_sync": 9000.0})
    try:
        ra, rb = [], []
        for k in range(0, 1200, 100):  # interleaved in blocks of 100 steps
            ra.append(a.run(sa, 100, T, first_step=k))
            rb.append(b.run(sb, 100, T, first_step=k))
    finally:
        a.close()
        b.close()
    got_a = [r for block in ra for r in block.reals]
    got_b = [r for block in rb for r in block.reals]
    assert got_a == core_run(params_for(planner=0), sa, 1200, initial=MotionState.at(10.0)).reals
    assert got_b == core_run(params_for(planner=pb, acc_sync=9000.0), sb, 1200).reals


# -- bundling ------------------------------------------------------------------------------------
_HIDE_INSTALLED = """
import sys, importlib.abc
class _Hide(importlib.abc.MetaPathFinder):
    # hide the installed/editable 'controller' (and its editable finder) from this process
    def find_spec(self, name, path=None, target=None):
        if name == "controller" and path is None:
            for finder in sys.meta_path:
                if finder is self or "editable" in type(finder).__module__.lower():
                    continue
                spec = finder.find_spec(name, path, target)
                if spec is not None and spec.origin and "/resources/" in spec.origin:
                    return spec
            raise ImportError("installed controller hidden by the test")
        return None
sys.meta_path.insert(0, _Hide())
"""


def test_bundled_core_runs_standalone(tracker_fmu, tmp_path):
    """In a process where the installed ``controller`` cannot be imported, the FMU runs its
    private copy (resources/_cantracker_<hash>/) and gives the same outputs as the core here;
    it leaves no ``controller`` module in the host."""
    scenario = conveyor_scenario(T)
    planner = PLANNERS[-1]
    ref = core_run(params_for(planner=planner), scenario, 600)
    expected = tmp_path / "expected.json"
    expected.write_text(json.dumps({"reals": [[repr(x) for x in row] for row in ref.reals],
                                    "ints": ref.ints}))
    script = _HIDE_INSTALLED + textwrap.dedent(f"""
        import json
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        fmu = {str(tracker_fmu)!r}
        md = read_model_description(fmu)
        vr = {{v.name: v.valueReference for v in md.modelVariables}}
        d = extract(fmu)
        s = FMU2Slave(guid=md.guid, unzipDirectory=d, modelIdentifier="CanTracker",
                      instanceName="standalone")
        s.instantiate()
        s.setupExperiment(startTime=0.0)
        s.enterInitializationMode()
        s.setInteger([vr["planner"]], [{planner}])
        s.exitInitializationMode()
        assert "controller" not in sys.modules
        private = [m for m in sys.modules if m.startswith("_cantracker_")]
        assert private and all(sys.modules[m].__file__.startswith(str(d)) for m in private
                               if getattr(sys.modules[m], "__file__", None)), private
        exp = json.load(open({str(expected)!r}))
        ins = ["master_x", "master_y", "master_z", "master_c", "master_vx", "master_vy",
               "master_vz", "master_vc", "master_ax", "master_ay", "master_az", "master_ac"]
        outs = ["x", "y", "z", "c", "vx", "vy", "vz", "vc", "ax", "ay", "az", "ac"]
        for k in range(600):
            t = k * 0.001
            e = 0.1 <= t < 1.0
            vals = [100.0 + 300.0 * t, 50.0, 0.0, 10.0 + 20.0 * t, 300.0, 0.0, 0.0, 20.0,
                    0.0, 0.0, 0.0, 0.0]
            s.setReal([vr[n] for n in ins], vals)
            s.setBoolean([vr["engage"]], [e])
            s.doStep(currentCommunicationPoint=t, communicationStepSize=0.001)
            got = [repr(x) for x in s.getReal([vr[n] for n in outs])]
            ints = s.getInteger([vr[n] for n in ("imfs", "state", "error")])
            assert got == exp["reals"][k] and ints == exp["ints"][k], (k, got, exp["reals"][k])
        s.terminate()
        s.freeInstance()  # (a host exiting without it: test_fmu_robustness)
        print("OK", sys.modules[private[0]].__file__)
    """)
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=tmp_path, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "OK" in proc.stdout and "/resources/_cantracker_" in proc.stdout


def _build_from_install(wheel: Path, tmp_path: Path,
                        compiled: Path | None = None) -> tuple[Path, dict]:
    """Unpack ``wheel`` into ``tmp_path/site`` (with the compiled modules and manifest of the
    ``compiled`` tracking folder added, as a compiled install has them) and run
    ``python -m controller.fmu build`` from there in a process where the installed package is
    hidden.  -> (CanTracker.fmu, {"native": controller.tracking.NATIVE there, "tracker": the
    file controller.tracking.tracker was loaded from})."""
    import os
    import shutil

    site = tmp_path / "site"
    with zipfile.ZipFile(wheel) as zf:
        zf.extractall(site)
    assert (site / "controller" / "fmu" / "tracker_slave.py").is_file()
    if compiled is not None:
        # (the group's packages: the tracking folder and its siblings, setup.py PACKAGES,
        #  and the folders of the single compiled modules, setup.py MODULES)
        for package in ("tracking", "conveyor", "conveyor/frames", "kinematics",
                        "canopen/apps", "canopen/master", "canopen/slave"):
            for path in (compiled.parent / package).iterdir():
                if path.name.endswith((".so", ".pyd")) or path.name == "_native_manifest.json":
                    shutil.copy2(path, site / "controller" / package / path.name)
    hide = _HIDE_INSTALLED.replace('"/resources/" in spec.origin',
                                   f'spec.origin.startswith({str(site)!r})')
    script = hide + textwrap.dedent(f"""
        import json
        sys.path.insert(0, {str(site)!r})
        import controller.tracking.tracker
        from controller.fmu.cli import main
        rc = main(["build", "-o", {str(tmp_path / "out")!r}])
        import controller
        assert controller.__file__.startswith({str(site)!r}), controller.__file__
        print(json.dumps({{"native": controller.tracking.NATIVE,
                          "tracker": controller.tracking.tracker.__file__}}))
        sys.exit(rc)
    """)
    env = {k: v for k, v in os.environ.items() if k != "CANTRACK_PURE"}
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=tmp_path, env=env, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    probe = json.loads(proc.stdout.splitlines()[-1])
    assert probe["tracker"].startswith(str(site)), probe
    return tmp_path / "out" / "CanTracker.fmu", probe


def _check_bundles_sources_only(fmu: Path) -> None:
    """The FMU is valid, bundles the tracking core's sources, never an install's compiled
    modules (docs/architecture.md "Compiled core": the FMU runs in another Python), and runs
    as the core here."""
    assert validate_fmu(str(fmu)) == []
    with zipfile.ZipFile(fmu) as zf:
        resources = [n for n in zf.namelist() if n.startswith("resources/")]
    assert [n for n in resources if n.endswith("/tracking/tracker.py")], resources
    assert not [n for n in resources
                if n.endswith((".so", ".pyd")) or "mypyc" in n or "_native_manifest" in n]
    with FmuTracker(fmu, start_values={"planner": 0}) as f:
        got = f.run(conveyor_scenario(T), 300, T)
    assert got.reals == core_run(params_for(planner=0), conveyor_scenario(T), 300).reals


def test_build_from_a_regular_install(pure_wheel, tmp_path):
    """``python -m controller.fmu build`` from a (pure) wheel install: no repository on the
    path."""
    fmu, probe = _build_from_install(pure_wheel, tmp_path)
    assert probe["native"] is False and probe["tracker"].endswith("tracker.py"), probe
    _check_bundles_sources_only(fmu)


def test_build_from_a_compiled_install(pure_wheel, compiled_tracking, tmp_path):
    """The same from a compiled install (the session's wheel with this install's compiled
    modules and manifest added, which run there): the FMU still bundles the ``.py`` files
    only."""
    fmu, probe = _build_from_install(pure_wheel, tmp_path, compiled=compiled_tracking)
    assert probe["native"] is True and probe["tracker"].endswith((".so", ".pyd")), (
        f"the install's compiled modules ({compiled_tracking}) do not run beside the wheel's "
        f"sources (a build older than the checkout? pip install -e . again): {probe}")
    _check_bundles_sources_only(fmu)


def test_non_python_host(tracker_fmu, tmp_path):
    """fmu/c_host/fmi2_host.c (a C importer) runs the FMU with no LD_PRELOAD, PYTHONHOME or
    PYTHONPATH: the FMU's front library loads libpython (pythonfmu's wrapper alone fails
    with "undefined symbol: _Py_NoneStruct", pythonfmu #202); it also ends cleanly when it
    exits with the instance alive."""
    import shutil

    gcc = shutil.which("gcc") or shutil.which("cc")
    if not sys.platform.startswith("linux") or gcc is None:
        pytest.skip("needs Linux and a C compiler")
    host = tmp_path / "fmi2_host"
    subprocess.run([gcc, "-O1", "-o", str(host), str(REPO / "fmu" / "c_host" / "fmi2_host.c"),
                    "-ldl"], check=True, capture_output=True, timeout=120)
    unzipped = tmp_path / "CanTracker"
    with zipfile.ZipFile(tracker_fmu) as zf:
        zf.extractall(unzipped)
    md = read_model_description(str(tracker_fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    planner = PLANNERS[-1]
    scenario, n = conveyor_scenario(T), 1200
    from controller.fmu.runner import master_values
    lines = [f"{vr['master_x']} {vr['engage']} {vr['x']}"]
    for k in range(n):
        m, e = scenario(k)
        lines.append(f"{int(e)} " + " ".join(repr(x) for x in master_values(m)))
    (tmp_path / "inputs.txt").write_text("\n".join(lines) + "\n")
    binaries = unzipped / "binaries" / "linux64"
    args = [str(host), str(binaries / "CanTracker.so"), md.guid,
            (unzipped / "resources").as_uri(), str(tmp_path / "inputs.txt"), str(planner)]
    env = {"PATH": "/usr/bin:/bin"}  # nothing about Python
    wrapper_only = [str(host), str(binaries / "CanTracker_pythonfmu.so"), *args[2:]]
    proc = subprocess.run(wrapper_only, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3 and "_Py_NoneStruct" in proc.stderr, proc.stderr
    proc = subprocess.run(args, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = [line.split() for line in proc.stdout.splitlines()]
    ref = core_run(params_for(planner=planner), scenario, n)
    assert [[float(x) for x in r[:12]] for r in rows] == ref.reals
    assert [[int(x) for x in r[12:]] for r in rows] == ref.ints
    # the same host exiting with its instance alive (no fmi2Terminate / fmi2FreeInstance):
    # pythonfmu's wrapper finalises the Python it started as the process ends; the FMU's
    # exit hook has released the trackers first, so nothing is reported leaked or aborts
    proc = subprocess.run([*args, "live"], env=env, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert len(proc.stdout.splitlines()) == n
    for word in ("nanobind", "leaked", "bort", "corrupted", "Segmentation", "Fatal Python"):
        assert word not in proc.stderr, proc.stderr[-2000:]


# -- CLI -----------------------------------------------------------------------------------------
def test_cli_build_and_check(tmp_path, capsys):
    from controller.fmu.cli import add_parser

    parser = argparse.ArgumentParser(prog="cantrack")
    add_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["fmu", "build", "-o", str(tmp_path)])
    assert args.func(args) == 0
    fmu = tmp_path / "CanTracker.fmu"
    assert str(fmu) in capsys.readouterr().out
    argv = ["fmu", "check", str(fmu), "--no-fmutool"]
    if 1 not in PLANNERS:
        argv += ["--planner", "0"]
    args = parser.parse_args(argv)
    assert args.func(args) == 0
    out = capsys.readouterr().out
    for line in ("fmpy validate ", "smoke co-simulation ", "core identity ",
                 "step-size refusal ", "FMU state "):
        assert re.search(re.escape(line) + r"\.* ok", out), out
    assert out.rstrip().endswith("RESULT: PASS")
    bad = tmp_path / "bad.fmu"
    bad.write_bytes(b"not a zip")
    args = parser.parse_args(["fmu", "check", str(bad)])
    assert args.func(args) == 1
    assert "not an FMU" in capsys.readouterr().out
