"""Packaging: the wheel carries the EDS files and example configurations, so that an installed
(non-editable) cantrack finds its demo bus configuration and EDS files."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from setuptools import find_packages

from controller.resources import data_path

ROOT = Path(__file__).resolve().parents[1]
DATA_PACKAGES = {"controller.eds", "controller.examples", "controller.examples.bus"}


def _setuptools_table() -> dict:
    tomllib = pytest.importorskip("tomllib")
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_the_package_list_names_every_code_package():
    listed = set(_setuptools_table()["packages"])
    assert listed - DATA_PACKAGES == set(find_packages(str(ROOT), include=["controller*"]))
    assert DATA_PACKAGES <= listed


def test_data_path_in_the_checkout():
    assert data_path("eds", "cantrack-servo.eds") == ROOT / "eds" / "cantrack-servo.eds"
    assert data_path("examples", "bus", "demo.yml").is_file()
    with pytest.raises(FileNotFoundError, match="eds/nope.eds: not found"):
        data_path("eds", "nope.eds")


def test_the_wheel_runs_the_demo_configuration(pure_wheel, tmp_path):
    """The session's wheel (tests/conftest.py ``pure_wheel``) unpacked alone on sys.path
    loads the demo's bus.yml: the EDS paths inside (../../eds/...) resolve within the
    installed package.  (Pure: CANTRACK_NO_EXTENSIONS=1 skips the compile, and the wheel has
    no compiled module; tests/test_fmu.py::test_build_from_a_compiled_install adds an
    install's compiled modules to it.)"""
    wheel = pure_wheel
    names = set(zipfile.ZipFile(wheel).namelist())
    assert not [n for n in names if n.endswith((".so", ".pyd", "_native_manifest.json"))]
    assert "controller/tracking/tracker.py" in names
    for eds in ROOT.glob("eds/*.eds"):
        assert f"controller/eds/{eds.name}" in names
    assert "controller/examples/bus/demo.yml" in names
    assert "controller/py.typed" in names  # PEP 561: users' type checkers read our annotations
    site = tmp_path / "site"
    zipfile.ZipFile(wheel).extractall(site)
    code = ("import controller, sys\n"
            "from controller.cli.demo import DEFAULT_CONFIG\n"
            "from controller.canopen.config import load_config\n"
            "cfg = load_config(DEFAULT_CONFIG)\n"
            "print(controller.__file__); print(DEFAULT_CONFIG); print(sorted(cfg.slaves))\n")
    r = subprocess.run([sys.executable, "-S", "-c", code], capture_output=True, text=True,
                       cwd=tmp_path, env={"PYTHONPATH": f"{site}:{_site_packages()}"},
                       timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    pkg, config, slaves = r.stdout.splitlines()
    assert pkg.startswith(str(site)) and config.startswith(str(site)), r.stdout
    assert slaves == str(sorted(load_bus_config_here().slaves))


def load_bus_config_here():
    from controller.canopen.config import load_config

    return load_config(ROOT / "examples" / "bus" / "demo.yml")


def _site_packages() -> str:
    """The dependencies' folders (numpy, canopen, ...), without cantrack's editable finder."""
    import canopen
    import numpy

    return ":".join(sorted({str(Path(m.__file__).resolve().parents[1])
                            for m in (numpy, canopen)}))


def test_the_hil_options_are_known_before_the_paths(tmp_path):
    """``pytest -m hil --bus-config rig.yml`` (no test path): the plugin comes from the
    installed package's pytest11 entry point, so pytest knows --bus-config and does not take
    rig.yml for a test path."""
    rig = tmp_path / "rig.yml"
    rig.write_text((ROOT / "examples" / "bus" / "vcan.yml").read_text())
    r = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-m", "hil",
                        "-p", "no:cacheprovider", "--can-interface", "virtual",
                        "--can-channel", "hil-options", "--bus-config", str(rig)],
                       cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    assert "test_hil_bus_traffic_is_clean_canopen" in r.stdout
