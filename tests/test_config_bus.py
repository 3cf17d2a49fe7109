"""bus.yml: Lely dcfgen format + cantrack's dot sections, strict validation, dcfgen parity.

- the demo's and the test template's files load; the example file is accepted by dcfgen;
- every SDO write cantrack's boot derives from the dcfgen keys is exactly what ``dcfgen -v``
  prints for the same file (same order, objects and values);
- a set of bad files: each error is a ConfigError naming the file, the line and the key.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from controller.canopen.config import load_config
from controller.canopen.config.concise import concise_configuration
from controller.canopen.testing import bus_yml, bus_yml_text
from controller.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
DEMO = ROOT / "examples" / "bus" / "demo.yml"
DCFGEN = shutil.which("dcfgen")
needs_dcfgen = pytest.mark.skipif(DCFGEN is None, reason="dcfgen (dcf-tools) not installed")


def test_demo_config_loads():
    cfg = load_config(DEMO)
    assert list(cfg.slaves) == ["encoder", "x", "y", "z", "c"]
    assert cfg.master.sync_period_us == 2000 and cfg.master.sync_overflow == 16
    assert [a.name for a in cfg.tracking.axes] == ["x", "y", "z", "c"]
    assert cfg.tracking.conveyor.modulus == 16777216  # 6002h default of the encoder EDS
    assert cfg.tracking.tracker.sample_time_s == pytest.approx(0.002)
    assert cfg.slaves["y"].node_id == 12  # the YAML merge key (<<: *drive) is honoured
    assert cfg.demo.items == 5
    assert cfg.simulation.devices["x"].initial_counts == 5_500_000


def test_the_loaded_config_is_immutable():
    """load_config returns a ControllerConfig nothing can change: frozen dataclasses all the
    way down, read-only mappings (a changed copy is made with dataclasses.replace)."""
    import dataclasses

    from controller.canopen.config import ControllerConfig
    cfg = load_config(DEMO)
    assert isinstance(cfg, ControllerConfig)
    for obj, name in ((cfg, "tracking"), (cfg.master, "node_id"), (cfg.slaves["x"], "node_id"),
                      (cfg.tracking, "axes"), (cfg.tracking.axes[0].motion, "limits"),
                      (cfg.tracking.axes[0].motion.limits, "vel"), (cfg.simulation, "devices"),
                      (cfg.demo, "items")):
        with pytest.raises(dataclasses.FrozenInstanceError):
            setattr(obj, name, None)
    for mapping, key in ((cfg.slaves, "x"), (cfg.ods, "x"), (cfg.slaves["x"].rpdo, 1),
                         (cfg.slaves["x"].tpdo, 1), (cfg.slaves["x"].other, "k"),
                         (cfg.simulation.devices, "x"), (cfg.tracking.reactions.table, "k")):
        with pytest.raises(TypeError):
            mapping[key] = None  # type: ignore[index]
    changed = dataclasses.replace(cfg, demo=None)
    assert changed.demo is None and cfg.demo is not None and changed.slaves is cfg.slaves


def test_no_config_module_sets_attributes_behind_frozen():
    """No ``object.__setattr__`` in the configuration layer (issue 10: the config was frozen
    but mutated that way)."""
    for path in (ROOT / "controller" / "canopen" / "config").glob("*.py"):
        assert "object.__setattr__" not in path.read_text(encoding="utf-8"), path


def _dcfgen(yml: Path, out: Path) -> subprocess.CompletedProcess:
    out.mkdir(exist_ok=True)
    return subprocess.run([DCFGEN, "-r", "-v", "-d", str(out), yml.name], cwd=yml.parent,
                          capture_output=True, text=True, timeout=60)


_SDO_LINE = re.compile(r"^(\w+): writing (\d+) bytes to 0x([0-9A-F]{4})/(\d+): ([0-9A-F ]+)$")


def _parse_dcfgen(stdout: str) -> dict[str, list[tuple[int, int, bytes]]]:
    out: dict[str, list] = {}
    for line in stdout.splitlines():
        m = _SDO_LINE.match(line.strip())
        assert m, line
        name, n, index, sub, data = m.groups()
        out.setdefault(name, []).append((int(index, 16), int(sub), bytes.fromhex(data)))
        assert len(out[name][-1][2]) == int(n)
    return out


@needs_dcfgen
@pytest.mark.parametrize("which", ["demo", "template"])
def test_dcfgen_accepts_and_our_sdo_list_matches(tmp_path, which):
    if which == "demo":
        src = tmp_path / "bus"
        shutil.copytree(DEMO.parent, src)
        shutil.copytree(ROOT / "eds", tmp_path / "eds")
        yml = src / "demo.yml"
        yml.write_text(yml.read_text().replace("../../eds/", "../eds/"))
    else:
        yml = bus_yml(tmp_path, axes=("x", "y", "z", "c"))
    r = _dcfgen(yml, tmp_path / "out")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    files = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert "master.dcf" in files
    cfg = load_config(yml)
    ours = {name: [(w.index, w.sub_index, w.data()) for w in c.sdos]
            for name, c in concise_configuration(cfg).items()}
    theirs = _parse_dcfgen(r.stdout)
    assert ours == theirs


@needs_dcfgen
def test_dcfgen_fails_on_a_plain_tracking_key(tmp_path):
    """Why our section is '.tracking': dcfgen takes any other top-level key for a slave."""
    text = bus_yml_text().replace(".tracking:", "tracking:")
    yml = bus_yml(tmp_path, text=text)
    assert _dcfgen(yml, tmp_path / "out").returncode != 0
    with pytest.raises(ConfigError, match="dcf"):
        load_config(yml)


# -- bad files -----------------------------------------------------------------------------
GOOD = bus_yml_text()
LINES = GOOD.splitlines()


def _line_of(fragment: str, nth: int = 0) -> int:
    hits = [i + 1 for i, line in enumerate(LINES) if fragment in line]
    return hits[nth]


# name: (old, new, count (occurrence to replace: 1 = first), expected line, key, message regex)
BAD = {
    "unknown_slave_key": ("  heartbeat_producer: 50\n  heartbeat_consumer: true",
                          "  hearbeat_producer: 50\n  heartbeat_consumer: true", 1,
                          _line_of("heartbeat_consumer: true") - 1, "x.hearbeat_producer",
                          r"unknown key \(did you mean 'heartbeat_producer'\?\)"),
    "unknown_master_key": ("  sync_overflow: 16", "  sync_overlow: 16", 1,
                           _line_of("sync_overflow"), "master.sync_overlow",
                           r"did you mean 'sync_overflow'"),
    "wrong_type": ("  sync_period: 2000", "  sync_period: 2ms", 1, _line_of("sync_period"),
                   "master.sync_period", "must be an integer, not the string '2ms'"),
    "float_for_int": ("  sync_period: 2000", "  sync_period: 2000.5", 1,
                      _line_of("sync_period"), "master.sync_period", "must be an integer"),
    "string_bool": ("      enabled: true\n      transmission: 1\n      mapping:\n"
                    "        - {index: 0x6040",
                    "      enabled: \"false\"\n      transmission: 1\n      mapping:\n"
                    "        - {index: 0x6040", 1,
                    _line_of("index: 0x6040") - 3, "x.rpdo.1.enabled",
                    "dcfgen would read any non-empty string as true"),
    "baudrate": ("  baudrate: 1000", "  baudrate: 1001", 1, _line_of("baudrate"),
                 "master.baudrate", "must be one of 10, 20, 50, 125, 250, 500, 800, 1000"),
    "missing_node_id": ("  node_id: 11\n", "", 1, LINES.index("x:") + 1, "x.node_id",
                        "required key is missing"),
    "dcf_not_found": ("cantrack-encoder.eds", "cantrack-encoderr.eds", 1,
                      _line_of("cantrack-encoder.eds"), "encoder.dcf", "not found"),
    "object_missing": ("{index: 0x6004, sub_index: 0}", "{index: 0x6005, sub_index: 0}", 1,
                       _line_of("index: 0x6004"), "encoder.tpdo.1.mapping[0].index",
                       r"object 6005h:00 does not exist in cantrack-encoder.eds"),
    "sub_index_missing": ("{index: 0x6004, sub_index: 0}", "{index: 0x6004, sub_index: 7}", 1,
                          _line_of("index: 0x6004"), "encoder.tpdo.1.mapping[0].sub_index",
                          r"object 6004h:07 does not exist in cantrack-encoder.eds"),
    "not_mappable": ("        - {index: 0x6064, sub_index: 0}",
                     "        - {index: 0x6065, sub_index: 0}", 1, _line_of("index: 0x6064"),
                     "x.tpdo.1.mapping[1].index", r"cannot be mapped into a PDO"),
    "read_only_in_rpdo": ("        - {index: 0x607A, sub_index: 0}",
                          "        - {index: 0x6041, sub_index: 0}", 1,
                          _line_of("index: 0x607A"), "x.rpdo.1.mapping[1].index",
                          "read-only: it cannot be mapped into an RPDO"),
    "too_many_bits": ("        - {index: 0x6064, sub_index: 0}",
                      "        - {index: 0x6064, sub_index: 0}\n"
                      "        - {index: 0x6064, sub_index: 0}", 1,
                      _line_of("index: 0x6041") - 1, "x.tpdo.1.mapping",
                      "maps 80 bits, a CAN frame holds at most 64"),
    "pdo_not_available": ("  rpdo:\n    1:", "  rpdo:\n    5:", 1, _line_of("rpdo:") + 1,
                          "x.rpdo.5", r"RPDO 5 not available in cantrack-servo.eds \(it has "
                                      r"1, 2, 3, 4\)"),
    "pdo_disabled_in_eds": ("  tpdo:\n    1:\n      enabled: true\n      transmission: 1\n"
                            "      mapping:\n        - {index: 0x6041",
                            "  tpdo:\n    4:\n      enabled: true\n      transmission: 1\n"
                            "      mapping:\n        - {index: 0x6041", 1,
                            _line_of("index: 0x6041") - 4, "x.tpdo.4",
                            "TPDO 4 is disabled in cantrack-servo.eds"),
    "transmission_range": ("      transmission: 1\n      mapping:\n        - {index: 0x6040",
                           "      transmission: 245\n      mapping:\n        - {index: 0x6040",
                           1, _line_of("index: 0x6040") - 2, "x.rpdo.1.transmission",
                           r"must be in \[0...240\], 254 or 255"),
    "duplicate_node_id": ("  node_id: 12", "  node_id: 11", 1, _line_of("node_id: 12"),
                          "y.node_id", "also the node_id of 'x'"),
    "master_node_id": ("  node_id: 11", "  node_id: 1", 1, _line_of("node_id: 11"),
                       "x.node_id", "is the master's node_id"),
    "duplicate_cob_id": ("      enabled: true\n      transmission: 1\n      mapping:\n"
                         "        - {index: 0x6040",
                         "      enabled: true\n      cob_id: 0x18A\n      transmission: 1\n"
                         "      mapping:\n        - {index: 0x6040", 1,
                         _line_of("index: 0x6040") - 2, "x.rpdo.1.cob_id",
                         "COB-ID 0x18A of x RPDO 1 is also used by encoder TPDO 1"),
    "sdo_read_only": ("    - {index: 0x605A, sub_index: 0, value: 2}",
                      "    - {index: 0x6041, sub_index: 0, value: 2}", 1,
                      _line_of("index: 0x605A"), "x.sdo[2].index", "is read-only"),
    "sdo_range": ("    - {index: 0x605A, sub_index: 0, value: 2}",
                  "    - {index: 0x605A, sub_index: 0, value: 40000}", 1,
                  _line_of("index: 0x605A"), "x.sdo[2].value",
                  r"must be in \[-32768...32767\]"),
    "unsupported_dcfgen_key": ("  heartbeat_consumer: true", "  heartbeat_consumer: true\n"
                               "  guard_time: 100", 1, _line_of("heartbeat_consumer") + 1,
                               "x.guard_time", "cantrack's boot does not apply"),
    "unknown_dot_section": (".tracking:", ".trackin:", 1, _line_of(".tracking:"), ".trackin",
                            r"unknown section \(did you mean '.tracking'\?\)"),
    "tracking_typo": ("    counts_per_mm: 40.96", "    counts_per_mn: 40.96", 1,
                      _line_of("counts_per_mm: 40.96"), ".tracking.conveyor.counts_per_mn",
                      r"did you mean 'counts_per_mm'"),
    "tracking_unknown_node": ("    node: encoder", "    node: encodr", 1,
                              _line_of("node: encoder"), ".tracking.conveyor.node",
                              r"is not a slave of this bus \(did you mean 'encoder'\?\)"),
    "axis_not_a_drive": ("      y: {node: y,", "      y: {node: encoder,", 1,
                         _line_of("y: {node: y"), ".tracking.kinematics.axes.y.node",
                         "must be a CiA 402 drive"),
    "axis_wrong_unit": ("      y: {node: y, counts_per_mm", "      y: {node: y, counts_per_deg",
                        1, _line_of("y: {node: y"),
                        ".tracking.kinematics.axes.y.counts_per_deg",
                        r"unknown key \(did you mean 'counts_per_mm'\?\)"),
    "axis_twice": ("      y: {node: y,", "      y: {node: x,", 1, _line_of("y: {node: y"),
                   ".tracking.kinematics.axes.y.node", "already drives axis x"),
    "planner": ("    planner: softmc", "    planner: fast", 1, _line_of("planner:"),
                ".tracking.tracker.planner", "must be one of optimal, softmc"),
    "tracker_limit_type": ("    mode: absolute", "    mode: absolute\n    sync_trans: {vel: -1}",
                           1, _line_of("mode: absolute") + 1,
                           ".tracking.tracker.sync_trans.vel", "must be > 0"),
    "sample_time_given": ("    mode: absolute", "    mode: absolute\n    sample_time_s: 0.001",
                          1, _line_of("mode: absolute") + 1,
                          ".tracking.tracker.sample_time_s", "is the SYNC period"),
    "conveyor_not_cyclic": ("      transmission: 1\n      mapping:\n        - {index: 0x6004",
                            "      transmission: 255\n      mapping:\n        - {index: 0x6004",
                            1, _line_of("    index: 0x6004"),
                            ".tracking.conveyor.index", "transmission 1"),
    "window": ("  window: {start: 250, end: 900}", "  window: {start: 950, end: 900}", 1,
               _line_of("  window: {"), ".tracking.window.end", "must be > start"),
    "simulation_unknown_slave": ("  x: {initial_counts", "  xx: {initial_counts", 1,
                                 _line_of("x: {initial_counts"), ".simulation.xx",
                                 r"is not a slave of this bus \(did you mean 'x'\?\)"),
    "simulation_type": ("  x: {initial_counts: 4000000", "  x: {initial_counts: 4.5", 1,
                        _line_of("x: {initial_counts"), ".simulation.x.initial_counts",
                        "must be an integer"),
    "duplicate_key": ("  sync_overflow: 16", "  sync_overflow: 16\n  sync_overflow: 8", 1,
                      _line_of("sync_overflow") + 1, "sync_overflow",
                      "duplicate key"),
    "yaml_syntax": ("  window: {start: 250, end: 900}", "  window: {start: 250, end: 900",
                    1, None, None, "YAML syntax error"),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_bus_yml(tmp_path, name):
    old, new, count, line, key, message = BAD[name]
    assert old in GOOD, f"{name}: {old!r} not in the template"
    text = GOOD.replace(old, new, count)
    path = bus_yml(tmp_path, text=text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    err = info.value
    assert err.file == str(path)
    assert re.search(message, str(err)), str(err)
    if line is not None:
        assert err.line == line, str(err)
    else:
        assert err.line is not None
    if key is not None:
        assert err.key == key, str(err)


def test_error_message_names_file_line_and_key(tmp_path):
    path = bus_yml(tmp_path, text=GOOD.replace("  sync_overflow: 16", "  sync_overlow: 16"))
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == (f"{path}:{_line_of('sync_overflow')}, key 'master.sync_overlow':"
                               " unknown key (did you mean 'sync_overflow'?)")


def test_a_file_that_is_not_utf8_names_file_and_line(tmp_path):
    text = GOOD.replace("  sync_overflow: 16", "  sync_overflow: 16   # 16 \u00b5s").encode(
        "utf-8").replace("\u00b5".encode("utf-8"), b"\xb5")
    path = tmp_path / "latin1.yml"
    path.write_bytes(text)
    with pytest.raises(ConfigError, match=r"not UTF-8 text \(byte 0xb5\)") as info:
        load_config(path)
    assert (info.value.file, info.value.line) == (str(path), _line_of("sync_overflow"))
