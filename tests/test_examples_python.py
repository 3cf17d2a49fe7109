"""Smoke tests of examples/python/: each numbered example runs as a user runs it (a separate
``python examples/python/NN_name.py``) and prints the figures its concept is about; the
figures are checked against what physics or the spec says they must be, not just exit 0."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
from collections import Counter
from itertools import pairwise
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples" / "python"


def _run(name: str, *args: str, timeout_s: float = 120.0) -> str:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env.setdefault("MPLBACKEND", "Agg")
    proc = subprocess.run([sys.executable, str(EXAMPLES / name), *args], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=timeout_s, check=False)
    assert proc.returncode == 0, f"{name} exited {proc.returncode}:\n{proc.stdout}\n{proc.stderr}"
    return proc.stdout


def _figure(out: str, label: str) -> float:
    m = re.search(re.escape(label) + r"\s*(-?[\d.]+(?:e[-+]?\d+)?)", out)
    assert m, f"no {label!r} in the output:\n{out}"
    return float(m.group(1))


def test_every_example_is_numbered_and_tested():
    names = sorted(p.name for p in EXAMPLES.glob("*.py"))
    assert names, "no examples in examples/python"
    for n in names:
        assert re.fullmatch(r"\d\d_[a-z0-9_]+\.py", n), f"{n}: not NN_name.py"
    numbers = [n[:2] for n in names]
    assert len(set(numbers)) == len(numbers), f"two examples share a number: {numbers}"
    tested = set(re.findall(r'_run\("(\d\d_[a-z0-9_]+\.py)"', Path(__file__).read_text()))
    assert set(names) <= tested, f"examples without a smoke test: {sorted(set(names) - tested)}"
    readme = (EXAMPLES / "README.md").read_text()
    assert all(n in readme for n in names), "examples/python/README.md must list every example"


def test_01_track_constant_belt():
    out = _run("01_track_constant_belt.py")
    A, J, V, belt = 20000.0, 400000.0, 2000.0, 300.0  # the default limits [mm/s^2, ^3, /s]
    t_sync = _figure(out, "time to sync:")
    # the 150 mm sideways offset alone needs a rest-to-rest move: >= 2*sqrt(150/A)
    assert 2.0 * math.sqrt(150.0 / A) < t_sync < 1.0
    assert _figure(out, "error after sync:") == 0.0  # the optimal planner copies the master
    assert _figure(out, "peak velocity:") <= V
    assert _figure(out, "peak acceleration:") <= A
    # the sine-acceleration stop from 300 mm/s without a plateau (docs/spec/tracking.md#5.2):
    # peak deceleration a_p = sqrt(2*J*v0/pi), each ramp pi*a_p/(2J), distance v0 * ramp time
    a_p = math.sqrt(2.0 * J * belt / math.pi)
    assert a_p < A
    assert _figure(out, "stop distance after disengage:") == pytest.approx(
        belt * math.pi * a_p / (2.0 * J), abs=0.01)
    assert _figure(out, "final speed") == 0.0


def test_01_with_the_softmc_planner_stays_within_the_limits():
    out = _run("01_track_constant_belt.py", "--planner", "softmc")
    t_sync = _figure(out, "time to sync:")
    assert 2.0 * math.sqrt(150.0 / 20000.0) < t_sync < 2.0
    assert _figure(out, "peak acceleration:") <= 20000.0 * 1.01


def test_02_conveyor_cell():
    out = _run("02_conveyor_cell.py")
    T, belt, down = 0.002, 250.0, 700.0
    triggers = (0.0, 0.8, 1.6, 2.4, 2.45)
    left = {int(i): float(t) for t, i in re.findall(r"t = +([\d.]+) s  item (\d+): item_left", out)}
    missed = {int(i): float(t) for t, i in
              re.findall(r"t = +([\d.]+) s  item (\d+): item_missed", out)}
    # an item leaves the window when the belt has carried it 700 mm past the photo-eye
    assert sorted(left) == [1, 2, 3, 4] and sorted(missed) == [5], out
    for item, t in {**left, **missed}.items():
        assert t == pytest.approx(triggers[item - 1] + down / belt, abs=1.5 * T), item
    assert "caught 4, missed 1" in out
    rows = re.findall(r"^\s+(\d+)  (\w+)\s+([\d.]+|-)\s+(\S+)$", out, re.MULTILINE)
    assert [r[1] for r in rows] == ["caught"] * 4 + ["missed"]
    for _, _status, tts, err in rows[:4]:
        assert 0.0 < float(tts) < 1.0
        assert float(err) == 0.0  # following: the setpoint is the item, exactly


def test_05_fmu_in_fmpy():
    pytest.importorskip("pythonfmu")
    pytest.importorskip("fmpy")
    out = _run("05_fmu_in_fmpy.py", timeout_s=300.0)
    assert "fmpy rows: 751, core rows: 751" in out  # 1.5 s at 2 ms, plus the initial row
    assert _figure(out, "max |FMU - core|:") == 0.0
    t_sync = _figure(out, "time to sync (IMFS 1):")
    assert 2.0 * math.sqrt(150.0 / 20000.0) < t_sync < 1.0
    assert _figure(out, "error at the end:") == 0.0
    assert _figure(out, "velocity") == pytest.approx(300.0, abs=1e-9)


def _frame_bits(n_bytes: int) -> int:
    """Worst-case bits of a CAN 2.0A data frame with stuffing and interframe space."""
    return 8 * n_bytes + 47 + (33 + 8 * n_bytes) // 4


def test_03_bus_demo(tmp_path):
    out = _run("03_bus_demo.py", "--items", "2", "-o", str(tmp_path))
    T = 0.002
    cycles = int(_figure(out, "cycles:"))
    assert "items placed: 2 of 2" in out
    rows = re.findall(r"^\s+(\d+)  (\w+)\s+([\d.]+)\s+([\d.]+)$", out, re.MULTILINE)
    assert [r[1] for r in rows] == ["placed", "placed"], out
    for _, _, sync_s, err_mm in rows:
        assert 0.0 < float(sync_s) < 2.0
        assert float(err_mm) < 0.05  # following an estimated, quantised belt
    # the capture: one SYNC and one encoder TPDO (18Ah) per cycle, 2 ms apart
    lines = (tmp_path / "bus.log").read_text().splitlines()
    ids = Counter(line.split()[2].split("#")[0] for line in lines)
    assert ids["080"] == cycles == ids["18A"]
    sync_t = [float(line.split()[0].strip("()")) for line in lines if " 080#" in line]
    gaps = {round(b - a, 6) for a, b in pairwise(sync_t)}
    assert gaps == {T}
    # the load the controller reports (from the configuration) against the capture's own
    bits = sum(_frame_bits(len(line.split()[2].split("#")[1]) // 2) for line in lines)
    measured_pct = 100.0 * bits / (cycles * T * 1e6)  # demo.yml: 1 Mbit/s
    assert _figure(out, "bus load:") == pytest.approx(measured_pct, abs=2.0)


def test_04_home_and_move_axis():
    out = _run("04_home_and_move_axis.py")
    assert re.search(r"home x: FINISHED", out), out
    assert _figure(out, "move from:") == pytest.approx(0.0, abs=1e-4)  # homing left it at 0
    assert re.search(r"move end: 100\.0000 mm, 6064h = 1000000 counts", out), out
    # demo.yml's x axis: V 200 mm/s, A 2000 mm/s^2, J 50000 mm/s^3, 10000 counts/mm, 2 ms.
    # Rest-to-rest over 100 mm with triangular pulses (docs/spec/axis.md#2.3): half-time
    # T2 = max(sqrt(V/J), V/A) = 0.1 s, each pulse 2*T2 covering V*T2, cruise the rest at V
    V, A, J, d = 200.0, 2000.0, 50000.0, 100.0
    t2 = max(math.sqrt(V / J), V / A)
    expected_s = 4.0 * t2 + (d - 2.0 * V * t2) / V
    assert _figure(out, "move time:") == pytest.approx(expected_s, abs=0.002)
    # one cycle's 607Ah step is at most ceil(counts_per_mm * V * T) (docs/spec/axis.md#6)
    assert _figure(out, "largest 607Ah step per cycle:") <= math.ceil(10000 * V * 0.002)
