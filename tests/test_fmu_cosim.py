"""CanTracker.fmu in co-simulation (libcosimpy, with the CanConveyor FMU) and the FMI
cross-check files (fmu/crosscheck/CanTracker_{in,ref}.csv, _ref.opt)."""

from __future__ import annotations

from pathlib import Path

import pytest

pytest.importorskip("pythonfmu")
pytest.importorskip("fmpy")

from controller.fmu.build import build_conveyor_fmu, build_tracker_fmu
from controller.fmu.crosscheck import compare_fmu, crosscheck_tables, read_csv, write_crosscheck
from controller.fmu.osp import (
    DEMO_CONVEYOR,
    compare_with_offline,
    system_structure_xml,
    write_system_structure,
)

REPO = Path(__file__).resolve().parents[1]


def _optimal_available() -> bool:
    try:
        import controller.tracking.optimal  # noqa: F401
    except Exception:
        return False
    return True


@pytest.fixture(scope="session")
def fmu_dir(tmp_path_factory) -> Path:
    """The session's FMUs (the same folder test_fmu.py uses: built once)."""
    d = tmp_path_factory.getbasetemp() / "fmu-build"
    if not (d / "CanConveyor.fmu").is_file():
        build_tracker_fmu(d)
        build_conveyor_fmu(d)
    return d


# -- libcosim --------------------------------------------------------------------------------
@pytest.mark.parametrize("planner", [None, 0])  # None: the FMU's default (1, optimal)
def test_libcosim_matches_offline_run(fmu_dir, tmp_path, planner):
    """Conveyor -> tracker in libcosim equals the core run offline with the master sampled at
    each step start (libcosim's connection delay: the tracker's step [t_k, t_k+1] gets the
    conveyor's outputs of t_k)."""
    pytest.importorskip("libcosimpy")
    if planner is None and not _optimal_available():
        pytest.skip("the optimal planner (ruckig) is not available")
    system = tmp_path / "system"
    system.mkdir()
    for name in ("CanTracker.fmu", "CanConveyor.fmu"):
        (system / name).symlink_to(fmu_dir / name)
    path = write_system_structure(system, tracker={} if planner is None else {"planner": 0})
    problems, summary = compare_with_offline(path)
    assert problems == [], summary
    if planner is None:  # the optimal planner settles onto the accelerating conveyor
        assert "synchronised at t=0.4" in summary and "errors none" in summary


def test_committed_system_structure_is_current():
    assert (REPO / "fmu" / "OspSystemStructure.xml").read_text() == system_structure_xml()
    assert DEMO_CONVEYOR["t_engage"] < DEMO_CONVEYOR["t_release"]


# -- FMI cross-check files --------------------------------------------------------------------
def test_crosscheck_files_reproduce_bit_identically(fmu_dir, tmp_path):
    paths = write_crosscheck(tmp_path)
    assert [p.name for p in paths] == ["CanTracker_in.csv", "CanTracker_ref.csv",
                                       "CanTracker_ref.opt"]
    header, rows = read_csv(paths[0])
    assert header[0] == "time" and header[-1] == "engage" and len(rows) == 1501
    assert paths[0].read_text().splitlines()[0].startswith('"time","master_x"')
    assert {row[-1] for row in rows} == {0.0, 1.0}  # booleans as 0/1
    if not _optimal_available():
        pytest.skip("the reference uses the default planner (optimal, needs ruckig)")
    assert compare_fmu(fmu_dir / "CanTracker.fmu", tmp_path) == []


def test_committed_crosscheck_files_are_current(tmp_path):
    """fmu/crosscheck holds the files of the current core; after a deliberate change of the
    core's behaviour regenerate them: cantrack fmu crosscheck -o fmu/crosscheck."""
    if not _optimal_available():
        pytest.skip("the reference uses the default planner (optimal, needs ruckig)")
    committed = REPO / "fmu" / "crosscheck"
    fresh = write_crosscheck(tmp_path)
    for p in fresh:
        assert (committed / p.name).read_text() == p.read_text(), (
            f"fmu/crosscheck/{p.name} is stale: cantrack fmu crosscheck -o fmu/crosscheck")
    inputs, refs = crosscheck_tables()
    assert len(inputs) == len(refs) == 1501
