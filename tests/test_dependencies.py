"""The dependency bounds in pyproject.toml hold for what is installed, and what they protect
is still there (docs/spec/tools.md#3, #4, #5).

A bound that protects a library's private or version-specific API is only as good as the
check that the API is what the code assumes: these tests fail, naming the package and the
version, when the environment leaves the declared range or the assumption breaks.
"""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

import pytest

tomllib = pytest.importorskip("tomllib")  # Python >= 3.11
from packaging.requirements import Requirement  # noqa: E402 (after the skip)

ROOT = Path(__file__).resolve().parents[1]


def _requirements(*extras: str) -> list[Requirement]:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    lines = list(project["dependencies"])
    for extra in extras:
        lines += project["optional-dependencies"][extra]
    return [Requirement(line) for line in lines]


def _installed(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def test_installed_versions_are_inside_the_declared_bounds():
    outside = []
    for req in _requirements("test", "fmu"):
        version = _installed(req.name)
        if version is None:
            if req.name in {r.name for r in _requirements()}:  # core dependencies must be there
                outside.append(f"{req.name}: not installed (pyproject: {req})")
            continue
        if not req.specifier.contains(version, prereleases=True):
            outside.append(f"{req.name} {version} is outside pyproject's {req}")
    assert not outside, "\n".join(outside)


def test_the_bounds_name_the_versions_the_code_needs():
    reqs = {r.name.lower(): r for r in _requirements("fmu")}
    # can.cli (the shared bus flags) appeared in python-can 4.6.0
    assert not reqs["python-can"].specifier.contains("4.5.0")
    assert reqs["python-can"].specifier.contains("4.6.0")
    # the simulated devices use canopen's private LocalNode._write_callbacks
    assert not reqs["canopen"].specifier.contains("2.5.0")
    # the FMI 2 slaves add what pythonfmu 0.7 does not write (InitialUnknowns, units)
    assert not reqs["pythonfmu"].specifier.contains("0.8.0")


def test_python_can_has_the_cli_helpers():
    import can.cli

    assert callable(can.cli.add_bus_arguments)
    assert callable(can.cli.create_bus_from_namespace)


def test_canopen_local_node_registers_its_nmt_write_callback_where_we_remove_it():
    """The simulated devices replace canopen's NMT slave: they remove ``nmt.on_write`` from
    ``LocalNode._write_callbacks`` (private; see pyproject's bound on canopen)."""
    import canopen

    node = canopen.LocalNode(5, canopen.ObjectDictionary())
    callbacks = node._write_callbacks
    assert node.nmt.on_write in callbacks, (
        f"canopen {canopen.__version__}: LocalNode no longer registers NmtSlave.on_write in "
        "_write_callbacks; the simulated devices' NMT replacement must be revisited")
    callbacks.remove(node.nmt.on_write)
    seen = []
    node.add_write_callback(lambda **kw: seen.append((kw["index"], kw["subindex"])))
    var = canopen.objectdictionary.ODVariable("Producer heartbeat time", 0x1017)
    var.data_type = canopen.objectdictionary.UNSIGNED16
    var.access_type = "rw"
    node.object_dictionary.add_object(var)
    node.set_data(0x1017, 0, b"\x64\x00")  # 100 ms: canopen's NMT would start a heartbeat
    assert seen == [(0x1017, 0)]  # our callback ran
    assert getattr(node.nmt, "_send_task", None) is None  # canopen's heartbeat did not start
