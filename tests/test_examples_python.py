"""Smoke tests of examples/python/: each numbered example runs as a user runs it (a separate
``python examples/python/NN_name.py``) and prints the figures its concept is about; the
figures are checked against what physics or the spec says they must be, not just exit 0."""

from __future__ import annotations

import math
import os
import re
import subprocess
import sys
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
    for _, status, tts, err in rows[:4]:
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
