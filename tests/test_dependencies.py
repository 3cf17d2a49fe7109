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
    # the slave engine overrides the calls canopen's SDO server makes (checked with 2.3-2.4)
    assert not reqs["canopen"].specifier.contains("2.5.0")
    # the FMI 2 slaves add what pythonfmu 0.7 does not write (InitialUnknowns, units)
    assert not reqs["pythonfmu"].specifier.contains("0.8.0")


def test_python_can_has_the_cli_helpers():
    import can.cli

    assert callable(can.cli.add_bus_arguments)
    assert callable(can.cli.create_bus_from_namespace)


def test_canopen_sdo_server_goes_through_the_methods_the_slave_engine_overrides():
    """The slave engine (controller/canopen/slave/engine.py) overrides ``LocalNode.get_data``/
    ``set_data`` and ``SdoServer.on_request``/``send_response`` (see pyproject's bound on
    canopen): canopen's own SDO server must still reach the object dictionary through
    ``get_data``/``set_data`` and answer through ``send_response`` (docs/spec/tools.md#3)."""
    import canopen

    calls: list[str] = []

    class Node(canopen.LocalNode):
        def get_data(self, index, subindex, check_readable=False):
            calls.append(f"get {index:04X}")
            return super().get_data(index, subindex, check_readable)

        def set_data(self, index, subindex, data, check_writable=False):
            calls.append(f"set {index:04X}")
            super().set_data(index, subindex, data, check_writable)

    var = canopen.objectdictionary.ODVariable("A value", 0x2000)
    var.data_type = canopen.objectdictionary.UNSIGNED16
    var.access_type = "rw"
    od = canopen.ObjectDictionary()
    od.add_object(var)
    node = Node(5, od)
    answers: list[bytes] = []
    node.sdo.send_response = lambda response: answers.append(bytes(response))
    node.sdo.on_request(0x605, b"\x2b\x00\x20\x00\x64\x00\x00\x00", 0.0)  # download
    node.sdo.on_request(0x605, b"\x40\x00\x20\x00\x00\x00\x00\x00", 0.0)  # upload
    assert calls == ["set 2000", "get 2000"], calls
    assert answers[0][0] == 0x60 and answers[1][:1] == b"\x4b" and answers[1][4:6] == b"\x64\x00"
