"""Every FMU in independent importers: the Modelica Association's fmusim (FMI 2 and FMI 3) and
the FMU Compliance Checker (FMI 2), built from their sources by the test harness
(:mod:`controller.testing.fmi_tools`: ``$CANTRACK_VENDOR_DIR``, default ``../shared/vendor``;
cached).  Where the sources are absent the tests are skipped with that message; in CI
(``CI=true`` or ``CANTRACK_VCAN_REQUIRED=1``) they fail instead.

The importers run with no Python environment at all (no LD_PRELOAD, PYTHONHOME or
PYTHONPATH): the FMUs' front library loads libpython.  Their results are compared with the
core (CanTracker: the cross-check scenario's reference from ``controller.tracking``;
CanConveyor: ``conveyor_slave.master_state``) to 1e-9, and the Compliance Checker must report
0 warnings and 0 errors.
"""

from __future__ import annotations

import csv
import os
import re
import subprocess
from pathlib import Path

import pytest

pytest.importorskip("pythonfmu")

from controller.fmu.conveyor_slave import VARIABLES as CONVEYOR_VARIABLES
from controller.fmu.conveyor_slave import master_state
from controller.fmu.crosscheck import STEP_SIZE_S, STOP_TIME_S, crosscheck_tables
from controller.fmu.runner import MASTER_INPUTS, OUTPUT_INTS, OUTPUT_REALS

TOL = 1e-9
ROOT = Path(__file__).resolve().parents[1]
CROSSCHECK_INPUT = ROOT / "fmu" / "crosscheck" / "CanTracker_in.csv"


def _bare_env() -> dict[str, str]:
    """An importer's environment: nothing about Python (the front library loads it)."""
    return {"PATH": "/usr/bin:/bin", "HOME": os.environ.get("HOME", "/tmp")}


def _read(path: Path) -> tuple[list[str], list[list[float]]]:
    with path.open(newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], [[float(x) for x in r] for r in rows[1:] if r]


def _close(a: float, b: float) -> bool:
    return abs(a - b) <= TOL * max(1.0, abs(b))


def _compare(header, rows, expected: dict[str, list[float]], times: list[float]) -> list[str]:
    """Differences beyond TOL between columns of ``rows`` and ``expected`` (name -> values)."""
    col = {name: i for i, name in enumerate(header)}
    problems = []
    assert [r[0] for r in rows] == pytest.approx(times, abs=1e-12)
    for name, values in expected.items():
        got = [r[col[name]] for r in rows]
        bad = [(k, g, e) for k, (g, e) in enumerate(zip(got, values)) if not _close(g, e)]
        if bad:
            problems.append(f"{name}: {len(bad)} rows differ, first at t={times[bad[0][0]]}: "
                            f"{bad[0][1]!r} != {bad[0][2]!r}")
    return problems


def _tracker_reference() -> dict[str, list[float]]:
    _inputs, ref = crosscheck_tables()
    names = ["time", *OUTPUT_REALS, *OUTPUT_INTS]
    return {n: [float(r[i]) for r in ref] for i, n in enumerate(names) if n != "time"}


def _times(stop: float) -> list[float]:
    return [k * STEP_SIZE_S for k in range(round(stop / STEP_SIZE_S) + 1)]


def _fmusim(tools, fmu: Path, out: Path, stop: float, inputs: Path | None = None):
    args = [str(tools.fmusim), "--interface-type", "cs", "--start-time", "0",
            "--stop-time", repr(stop), "--output-interval", repr(STEP_SIZE_S),
            "--output-file", str(out)]
    if inputs is not None:
        args += ["--input-file", str(inputs)]
    return subprocess.run([*args, str(fmu)], capture_output=True, text=True, timeout=600,
                          env=_bare_env())


@pytest.mark.parametrize("name", ["CanTracker", "CanTracker3"])
def test_fmusim_tracker_equals_core(fmi_tools, fmu2_path, fmu3_path, tmp_path, name):
    fmu = fmu2_path if name == "CanTracker" else fmu3_path
    out = tmp_path / "out.csv"
    res = _fmusim(fmi_tools, fmu, out, STOP_TIME_S, CROSSCHECK_INPUT)
    assert res.returncode == 0, res.stdout + res.stderr
    header, rows = _read(out)
    assert header == ["time", *OUTPUT_REALS, *OUTPUT_INTS, "master_status", "master_outliers"]
    ref = _tracker_reference()
    assert _compare(header, rows, ref, _times(STOP_TIME_S)) == []
    assert {int(r[header.index("state")]) for r in rows} >= {1, 2, 3}  # synced, de-synced


@pytest.mark.parametrize("name", ["CanTracker", "CanTracker3"])
def test_fmusim_raw_encoder_input_equals_the_simulator(fmi_tools, fmu2_path, fmu3_path,
                                                      tmp_path, name):
    """fmusim with master_input=1 and the encoder parameters as start values, the raw
    (quantised, 2-sample-old) encoder positions of an S-curve belt as its input file: the
    setpoints of the simulator's ``conditioning:`` run (tests/test_conditioning_shells.py)."""
    pytest.importorskip("ruckig")
    from test_conditioning_shells import RES_DEG, Q, _encoder_start, _sim_warm, fmu_scenario
    from test_conditioning_shells import T as T_ENC

    from controller.simulate import load_scenario
    from controller.simulate.master import _quantise, build_profile
    from controller.simulate.runner import simulate

    sc = load_scenario(fmu_scenario())
    res = simulate(sc)
    warm, prof = _sim_warm(sc), build_profile(sc.master)
    L, ke = sc.conditioning.latency_samples, sc.engage_samples[0]
    n = warm + sc.n_samples
    inputs = tmp_path / "encoder_in.csv"
    with inputs.open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", "master_x", "master_c", "engage"])
        for j in range(n + 1):
            st = prof.state((j - warm - L) * T_ENC)
            w.writerow([repr(j * T_ENC), repr(_quantise(st.pos[0], Q)),
                        repr(_quantise(st.ang, RES_DEG)), int(j - warm > ke)])
    fmu = fmu2_path if name == "CanTracker" else fmu3_path
    out = tmp_path / "out.csv"
    starts = []
    for key, value in _encoder_start(L).items():
        starts += ["--start-value", key, repr(value)]
    res_sim = subprocess.run(
        [str(fmi_tools.fmusim), "--interface-type", "cs", "--start-time", "0", "--stop-time",
         repr(n * T_ENC), "--output-interval", repr(T_ENC), "--output-file", str(out),
         "--input-file", str(inputs), *starts, str(fmu)],
        capture_output=True, text=True, timeout=600, env=_bare_env())
    assert res_sim.returncode == 0, res_sim.stdout + res_sim.stderr
    header, rows = _read(out)
    col = {c: i for i, c in enumerate(header)}
    assert len(rows) == n + 1
    for k in range(1, sc.n_samples):
        r = rows[warm + k + 1]  # row i: time i*T, after the step from (i-1)*T
        for i, axis in enumerate("xyz"):
            assert _close(r[col[axis]], float(res.setpoint_pos[k][i])), (k, axis)
            assert _close(r[col["v" + axis]], float(res.setpoint_vel[k][i])), (k, axis)
        assert _close(r[col["c"]], float(res.setpoint_ang[k])), k
        assert int(r[col["state"]]) == res.state[k], k
    assert {int(s) for s in res.state} >= {1, 2}
    assert int(rows[-1][col["master_status"]]) == 1 and int(rows[-1][col["master_outliers"]]) == 0


def _conveyor_reference(stop: float) -> dict[str, list[float]]:
    p = {row[0]: row[4] for row in CONVEYOR_VARIABLES if row[2] == "parameter"}
    cols: dict[str, list[float]] = {n: [] for n in
                                    ("x", "y", "z", "vx", "vy", "vz", "ax", "ay", "az", "engage")}
    for t in _times(stop):
        pos, vel, acc, engage = master_state(t, p)
        for n, v in zip(cols, (*pos, *vel, *acc, float(engage))):
            cols[n].append(v)
    return cols


def test_fmusim_conveyor_equals_core(fmi_tools, fmu2_path, tmp_path):
    out = tmp_path / "out.csv"
    res = _fmusim(fmi_tools, fmu2_path.with_name("CanConveyor.fmu"), out, 3.0)
    assert res.returncode == 0, res.stdout + res.stderr
    header, rows = _read(out)
    assert _compare(header, rows, _conveyor_reference(3.0), _times(3.0)) == []


def test_fmusim_refuses_invalid_parameters(fmi_tools, fmu2_path, fmu3_path, tmp_path):
    """An invalid parameter: fmusim stops at exitInitializationMode with the FMU's one-line
    error and a non-zero exit code (not a crash, not a run of refused steps)."""
    for fmu in (fmu2_path, fmu3_path):
        res = subprocess.run([str(fmi_tools.fmusim), "--start-value", "sample_time", "0.5",
                              "--stop-time", "0.01", str(fmu)], capture_output=True, text=True,
                             timeout=120, env=_bare_env())
        assert res.returncode not in (0, -11), res.stdout + res.stderr
        assert "sample_time=0.5 s is outside its declared range [1e-05, 0.1]" in (
            res.stdout + res.stderr)


def _fmu_check(tools, fmu: Path, out: Path, stop: float, inputs: Path | None = None):
    args = [str(tools.fmu_check), "-h", repr(STEP_SIZE_S), "-s", repr(stop), "-n", "0",
            "-l", "3", "-o", str(out)]
    if inputs is not None:
        args += ["-i", str(inputs)]
    return subprocess.run([*args, str(fmu)], capture_output=True, text=True, timeout=600,
                          env=_bare_env())


def _clean_summary(text: str) -> None:
    assert re.search(r"FMU reported:\s+0 warning\(s\) and error\(s\)", text), text[-2000:]
    assert re.search(r"Checker reported:\s+0 Warning\(s\)\s+0 Error\(s\)", text), text[-2000:]


def test_compliance_checker_tracker(fmi_tools, fmu2_path, tmp_path):
    out = tmp_path / "out.csv"
    res = _fmu_check(fmi_tools, fmu2_path, out, STOP_TIME_S, CROSSCHECK_INPUT)
    assert res.returncode == 0, res.stdout + res.stderr
    _clean_summary(res.stdout + res.stderr)
    header, rows = _read(out)
    assert _compare(header, rows, _tracker_reference(), _times(STOP_TIME_S)) == []


def test_compliance_checker_conveyor(fmi_tools, fmu2_path, tmp_path):
    out = tmp_path / "out.csv"
    res = _fmu_check(fmi_tools, fmu2_path.with_name("CanConveyor.fmu"), out, 3.0)
    assert res.returncode == 0, res.stdout + res.stderr
    _clean_summary(res.stdout + res.stderr)
    header, rows = _read(out)
    assert _compare(header, rows, _conveyor_reference(3.0), _times(3.0)) == []


def test_crosscheck_input_names_match_the_fmu():
    with CROSSCHECK_INPUT.open() as f:
        header = next(csv.reader(f))
    assert header == ["time", *MASTER_INPUTS, "engage"]
