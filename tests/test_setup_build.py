"""setup.py's up-to-date check of an editable install's in-place build (docs/architecture.md
"Compiled core"): ``pip install -e .`` again compiles only when the build differs from what
the manifest records.  Pure functions on a fake build folder: nothing is compiled here."""

from __future__ import annotations

import copy
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SUFFIX = ".cpython-3xx-test.so"


@pytest.fixture(scope="module")
def setup_py():
    """setup.py as a module (not run as __main__: ``setup()`` is not called)."""
    spec = importlib.util.spec_from_file_location("cantrack_setup", ROOT / "setup.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture
def record(setup_py) -> dict:
    """The checkout's build record with a fixed mypy version and a test extension suffix."""
    r = setup_py._build_record(mypy_version="2.4.1")
    r["build"]["ext_suffix"] = SUFFIX
    return r


@pytest.fixture
def build(setup_py, record, tmp_path) -> Path:
    """A fake in-place build of ``record`` in ``controller/tracking``: its manifest, an
    (empty) file per extension (the sources' names are relative to ``controller/``)."""
    tracking = tmp_path / "controller" / "tracking"
    setup_py._write_manifest(tracking, record)
    for stem in ["tracking/_core__mypyc"] + [name[:-3] for name in record["sources"]]:
        path = tmp_path / "controller" / (stem + SUFFIX)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"")
    return tracking


def test_the_record_names_what_the_compile_depends_on(setup_py, record):
    assert set(record["sources"]) == {setup_py._name(p) for p in setup_py._sources()}
    assert "tracking/tracker.py" in record["sources"]
    assert "conveyor/frames/linear.py" in record["sources"]
    assert not {"tracking/batch.py", "conveyor/errors.py"} & set(record["sources"])
    # the single modules of the CANopen shell (setup.py MODULES) and the simulated devices'
    # per-SYNC modules, and nothing else of it
    assert {name for name in record["sources"] if name.startswith("canopen/")} == {
        "canopen/apps/demo.py", "canopen/master/masterio.py", "canopen/master/axisio.py",
        "canopen/slave/drive.py", "canopen/slave/encoder.py", "canopen/slave/engine.py",
        "canopen/slave/node.py", "canopen/slave/rack.py"}
    build = record["build"]
    assert build["python"] and build["mypy"] == "2.4.1"
    assert build["flags"]["mypycify"] == {"opt_level": "3", "debug_level": "0",
                                          "group_name": "controller.tracking._core"}
    assert build["flags"]["mypy_ini"] == setup_py.MYPYC_INI
    # the modules mypy reads for their types: the package's pure ones and the base layer
    assert {"controller/limits.py", "controller/errors.py", "controller/tracking/__init__.py",
            "controller/tracking/batch.py"} <= set(build["read"])
    assert not {f"controller/{name}" for name in record["sources"]} & set(build["read"])
    # (mypy reads nothing of the CANopen shell for them: MYPYC_INI skips it)
    assert not [name for name in build["read"] if name.startswith("controller/canopen/")]
    assert "[mypy-controller.canopen,controller.canopen.*]\nfollow_imports = skip" \
        in setup_py.MYPYC_INI
    # what the import-time stale guard reads is unchanged: compiled source -> SHA-256
    assert all(len(digest) == 64 for digest in record["sources"].values())


def test_an_unchanged_build_is_up_to_date(setup_py, record, build):
    assert setup_py._in_place_build_stale(build, record) is None
    # (as written to and read back from the manifest's JSON)
    assert json.loads((build / setup_py.MANIFEST).read_text()) == record


def test_a_changed_source_is_stale(setup_py, record, build):
    now = copy.deepcopy(record)
    now["sources"]["tracking/tracker.py"] = "0" * 64
    assert setup_py._in_place_build_stale(build, now) == (
        "tracking/tracker.py: changed since the last build")


def test_a_module_added_to_the_compiled_list_is_stale(setup_py, record, build):
    now = copy.deepcopy(record)
    now["sources"]["tracking/newmodule.py"] = "1" * 64
    assert setup_py._in_place_build_stale(build, now) == (
        "tracking/newmodule.py: not compiled in the last build")
    del now["sources"]["tracking/newmodule.py"], now["sources"]["tracking/vec.py"]
    assert "tracking/vec.py: compiled in the last build" in \
        setup_py._in_place_build_stale(build, now)


def test_another_mypy_version_is_stale(setup_py, record, build):
    now = setup_py._build_record(mypy_version="2.4.2")
    now["build"]["ext_suffix"] = SUFFIX
    assert setup_py._in_place_build_stale(build, now) == (
        "the mypy version changed (last build '2.4.1', now '2.4.2')")


def test_another_python_or_flags_is_stale(setup_py, record, build, monkeypatch):
    now = copy.deepcopy(record)
    now["build"]["python"] = "3.11.99 (another build)"
    assert setup_py._in_place_build_stale(build, now).startswith("the Python changed")
    monkeypatch.setenv("CFLAGS", "-O0")
    now = setup_py._build_record(mypy_version="2.4.1")
    now["build"]["ext_suffix"] = SUFFIX
    assert setup_py._in_place_build_stale(build, now).startswith("the compile flags changed")


def test_a_changed_module_that_mypy_reads_is_stale(setup_py, record, build):
    now = copy.deepcopy(record)
    now["build"]["read"]["controller/limits.py"] = "2" * 64
    assert setup_py._in_place_build_stale(build, now) == (
        "controller/limits.py: changed since the last build (mypy reads its types)")


@pytest.mark.parametrize("stem", ["tracking/tracker", "tracking/_core__mypyc",
                                  "conveyor/frames/linear", "canopen/master/axisio"])
def test_a_missing_extension_file_is_stale(setup_py, record, build, stem):
    (build.parent / (stem + SUFFIX)).unlink()
    assert setup_py._in_place_build_stale(build, record) == f"{stem}{SUFFIX}: missing"


def test_no_manifest_or_an_older_one_is_stale(setup_py, record, build):
    older = {"group": record["group"], "sources": record["sources"]}  # (before the record)
    (build / setup_py.MANIFEST).write_text(json.dumps(older))
    assert setup_py._in_place_build_stale(build, record) == (
        f"{setup_py.MANIFEST} records no build (written by an older setup.py)")
    (build / setup_py.MANIFEST).unlink()
    assert setup_py._in_place_build_stale(build, record) == (
        f"no usable {setup_py.MANIFEST} (FileNotFoundError)")


def test_removing_a_build_takes_the_single_modules_own_files_only(setup_py, tmp_path):
    """CANTRACK_NO_EXTENSIONS=1 (or a failed compile) removes an earlier in-place build: the
    compiled packages' extension files and manifest, and of a single compiled module's
    package (setup.py MODULES) that module's file only."""
    root = tmp_path / "controller"
    files = ["tracking/_core__mypyc", "tracking/tracker", "conveyor/frames/linear",
             "canopen/apps/demo", "canopen/master/axisio", "canopen/apps/other"]
    for stem in files:
        path = root / (stem + ".cpython-311-x86_64-linux-gnu.so")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"")
    setup_py._write_manifest(root / "tracking", {"sources": {}})
    (root / "canopen" / "apps" / "demo.py").write_text("")
    setup_py._remove_build(root)
    left = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    assert left == ["canopen/apps/demo.py",
                    "canopen/apps/other.cpython-311-x86_64-linux-gnu.so"]


def test_no_compiled_file_is_tracked_by_git():
    """The in-place build's files (every compiled module's extension, setup.py PACKAGES and
    MODULES) are ignored by git, never committed: a clean checkout has no shim whose group
    library is missing."""
    import shutil
    import subprocess

    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    tracked = subprocess.run(["git", "ls-files", "*.so", "*.pyd", "*_native_manifest.json"],
                             cwd=ROOT, capture_output=True, text=True, check=True).stdout
    assert tracked == ""
    built = [p.relative_to(ROOT).as_posix() for p in (ROOT / "controller").rglob("*.so")]
    if built:  # (an in-place build: git ignores every one of its files)
        ignored = subprocess.run(["git", "check-ignore", *built], cwd=ROOT,
                                 capture_output=True, text=True).stdout.split()
        assert sorted(ignored) == sorted(built)
