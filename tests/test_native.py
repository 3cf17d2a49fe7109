"""The compiled core (docs/architecture.md "Compiled core"): ``controller.tracking``,
``controller.conveyor`` (with ``frames``) and ``controller.kinematics``, and the demo's
setpoint source ``controller.canopen.apps.demo``.

- compiled and pure give byte-identical results: a stepped ``cantrack demo`` (bus.log,
  telemetry, summary) and the simulator's traces of examples, each run in a subprocess with
  ``CANTRACK_PURE=1`` and one without; the value classes have the same dataclass fields;
- ``CANTRACK_PURE=1`` runs every module of the compiled packages from its source;
- the stale build guard: a source edited after the build runs as source (every compiled
  package), with one warning naming the file.

Where the install did not compile the core (no C compiler at ``pip install`` time, or
``CANTRACK_NO_EXTENSIONS=1``) the tests that need the compiled modules are skipped; in CI
(``CANTRACK_VCAN_REQUIRED=1``, which .ci/run sets, or ``CI=true``; .ci/run installs gcc before
the project) they fail instead.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import controller

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = Path(controller.__file__).resolve().parent
EXTENSION_SUFFIXES = (".so", ".pyd")

#: the packages the build compiles (setup.py PACKAGES) and their modules that stay pure
#: (setup.py PURE_ONLY; every package's __init__ too)
COMPILED = ("tracking", "conveyor", "conveyor/frames", "kinematics", "canopen/slave")
PURE_ONLY = {"controller.tracking.batch", "controller.tracking.metrics",
             "controller.conveyor.errors", "controller.canopen.slave.plc",
             "controller.canopen.slave.sdo_server", "controller.canopen.slave.world"}
#: the single compiled modules of other packages (setup.py MODULES)
SINGLE = ("controller.canopen.apps.demo",)
#: the modules of the compiled packages, as the source tree has them, and the single ones
MODULES = sorted([
    "controller." + p.relative_to(PACKAGE).with_suffix("").as_posix().replace("/", ".")
    for package in COMPILED for p in (PACKAGE / package).glob("*.py")
    if p.name != "__init__.py"] + list(SINGLE))

#: prints NATIVE and, per module of the compiled packages, where it was loaded from
PROBE = ("import importlib, json, sys, controller.tracking as t\n"
         f"for name in {MODULES!r}:\n"
         "    importlib.import_module(name)\n"
         "mods = {k: m.__file__ for k, m in sorted(sys.modules.items())\n"
         "        if (k.startswith(('controller.tracking.', 'controller.conveyor.',\n"
         "                          'controller.kinematics.', 'controller.canopen.slave.'))\n"
         "            or k in " f"{SINGLE!r})\n"
         "        and not k.endswith('__mypyc') and not k.endswith('.frames')}\n"
         "print(json.dumps({'native': t.NATIVE, 'modules': mods}))\n")


def _env(pure: bool, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k != "CANTRACK_PURE"}
    if pure:
        env["CANTRACK_PURE"] = "1"
    env.update(extra)
    return env


def _python(args: list[str], pure: bool, cwd: Path | None = None,
            **extra: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=cwd,
                          env=_env(pure, **extra), timeout=300)


def _probe(pure: bool, cwd: Path = ROOT, **extra: str) -> tuple[dict, str]:
    r = _python(["-c", PROBE], pure, cwd=cwd, **extra)
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.splitlines()[-1]), r.stderr


@pytest.fixture(scope="module")
def native(skip_or_fail) -> None:
    """Skip (fail in CI: tests/conftest.py) unless this install runs the compiled core."""
    probe, _ = _probe(pure=False)
    if not probe["native"]:
        skip_or_fail("the tracking core is not compiled in this install (pip install -e . "
                     "needs a C compiler and the Python headers; CANTRACK_NO_EXTENSIONS unset)")


def test_pure_is_honoured(native):
    probe, stderr = _probe(pure=True)
    assert probe["native"] is False
    assert sorted(probe["modules"]) == MODULES
    assert all(f.endswith(".py") for f in probe["modules"].values()), probe["modules"]
    assert stderr == ""


def test_the_compiled_modules_run_by_default(native):
    probe, stderr = _probe(pure=False)
    assert probe["native"] is True
    assert sorted(probe["modules"]) == MODULES
    assert len(MODULES) == 43  # (tracking 14, conveyor 14, frames 4, kinematics 2,
    #                             simulated devices 8, demo)
    assert all(f.endswith(EXTENSION_SUFFIXES) == (name not in PURE_ONLY)
               for name, f in probe["modules"].items()), probe["modules"]
    assert stderr == ""


#: prints the fields of every dataclass of the compiled packages' modules
FIELDS = ("import dataclasses, importlib, json\n"
          "out = {}\n"
          f"for name in {MODULES!r}:\n"
          "    m = importlib.import_module(name)\n"
          "    for k, v in sorted(vars(m).items()):\n"
          "        if isinstance(v, type) and dataclasses.is_dataclass(v) and "
          "v.__module__ == name:\n"
          "            out[name + '.' + k] = [f.name for f in dataclasses.fields(v)]\n"
          "print(json.dumps(out))\n")


def test_compiled_and_pure_value_classes_have_the_same_fields(native):
    """mypyc gives a Python class's class attributes annotations: an attribute without
    ``ClassVar`` (``units = "mm"``, ``x = property(...)``) would become a dataclass field
    compiled (another ``__init__``, repr and equality)."""
    fields = []
    for pure in (False, True):
        r = _python(["-c", FIELDS], pure)
        assert r.returncode == 0, r.stderr
        fields.append(json.loads(r.stdout.splitlines()[-1]))
    assert fields[0] == fields[1]
    assert fields[0]["controller.conveyor.frames.linear.LinearGeometry"] == [
        "origin", "directions", "scales", "local_axis"]
    assert fields[0]["controller.canopen.slave.engine.PdoChannel"][:8] == [
        "kind", "number", "cob_id", "transmission", "inhibit_ns", "event_ns", "sync_start",
        "mapping"]


def _demo(out: Path, pure: bool) -> tuple[bytes, list[dict], list[str]]:
    r = _python(["-m", "controller.cli", "demo", "-q", "--items", "3", "-o", str(out)], pure)
    assert r.returncode == 0, r.stderr
    lines = [json.loads(line) for line in (out / "telemetry.jsonl").read_text().splitlines()]
    assert lines[-1]["type"] == "end"
    del lines[-1]["wall_s"]  # (the one wall-clock figure)
    assert "items placed 3, missed 0, of 3" in r.stdout
    summary = [re.sub(r" in [0-9.]+ s wall \([0-9.]+x real time\)", "", line)
               for line in r.stdout.splitlines() if not line.startswith("files:")]
    return (out / "bus.log").read_bytes(), lines, summary


def test_compiled_and_pure_demo_are_identical(native, tmp_path):
    """The stepped demo: the same frames on the bus, the same telemetry and summary."""
    compiled = _demo(tmp_path / "compiled", pure=False)
    pure = _demo(tmp_path / "pure", pure=True)
    assert compiled[0] == pure[0]
    assert compiled[1] == pure[1]
    assert compiled[2] == pure[2]


@pytest.mark.parametrize("scenario", [
    "linear_absolute.yaml", "relative_mode.yaml", "accelerating_optimal.yaml",
    "encoder_conditioned.yaml", "conveyor_rotary.yaml", "cell_handoff.yaml"])
def test_compiled_and_pure_simulator_traces_are_identical(native, tmp_path, scenario):
    traces = []
    for pure in (False, True):
        out = tmp_path / f"{'pure' if pure else 'compiled'}.csv"
        r = _python(["-m", "controller.cli", "simulate", str(ROOT / "examples" / scenario),
                     "-q", "-o", str(out)], pure)
        assert r.returncode == 0, r.stderr
        traces.append(out.read_bytes())
    assert traces[0] == traces[1]
    assert len(traces[0]) > 1000


@pytest.mark.parametrize("source", ["tracking/vec.py", "conveyor/frames/linear.py",
                                    "canopen/apps/demo.py", "canopen/slave/drive.py"])
def test_a_source_changed_after_the_build_runs_as_source(native, tmp_path, source):
    """The stale build guard: copy the compiled package, edit one source (of the tracking
    core, of a conveyor subpackage): that import runs every compiled package pure and warns
    once, naming the file; the unedited copy runs compiled."""
    copy = tmp_path / "site" / "controller"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    # (and the EDS files beside it, as a checkout has them: the simulated devices' pure
    #  plc.py reads its own at import)
    shutil.copytree(ROOT / "eds", tmp_path / "site" / "eds")
    tracking = copy / "tracking"
    assert (tracking / "_native_manifest.json").is_file()
    site = str(tmp_path / "site")
    probe, stderr = _probe(pure=False, cwd=tmp_path, PYTHONPATH=site)
    assert probe["native"] is True, stderr
    assert all(f.startswith(site) for f in probe["modules"].values())

    edited = copy / source
    edited.write_text(edited.read_text() + "\n# edited after the build\n")
    probe, stderr = _probe(pure=False, cwd=tmp_path, PYTHONPATH=site)
    assert probe["native"] is False
    assert all(f.startswith(site) and f.endswith(".py") for f in probe["modules"].values())
    warnings = [line for line in stderr.splitlines() if "RuntimeWarning" in line]
    assert len(warnings) == 1, stderr
    assert f"{edited}: changed since the tracking core was compiled" in warnings[0]
    assert "rebuild with pip install -e ." in warnings[0]
