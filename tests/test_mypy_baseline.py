"""The mypy baseline checker (.ci/mypy_baseline.py): line numbers do not matter, a new error and
a fixed-but-listed error both fail, clean packages may hold no baseline line."""

from __future__ import annotations

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
_spec = importlib.util.spec_from_file_location("mypy_baseline", ROOT / ".ci" / "mypy_baseline.py")
mb = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(mb)

OUT = """\
controller/fmu/runner.py:12: error: Item "None" of "X | None" has no attribute "y"  [union-attr]
controller/fmu/runner.py:12: note: see https://mypy.readthedocs.io
controller/fmu/runner.py:40:7: error: Name "f" already defined on line 3  [no-redef]
controller/fmu/runner.py:90: error: Item "None" of "X | None" has no attribute "y"  [union-attr]
Found 3 errors in 1 file (checked 1 source file)
"""


def test_normalise_drops_line_numbers_and_notes():
    assert mb.normalise(OUT) == [
        'controller/fmu/runner.py: [no-redef] Name "f" already defined on line N',
        'controller/fmu/runner.py: [union-attr] Item "None" of "X | None" has no attribute "y"',
        'controller/fmu/runner.py: [union-attr] Item "None" of "X | None" has no attribute "y"',
    ]


def test_moved_lines_pass_a_new_or_a_fixed_error_fails():
    base = mb.normalise(OUT)
    moved = mb.normalise(OUT.replace(":12:", ":15:").replace(":90:", ":99:"))
    assert mb.compare(moved, base) == ([], [], [])
    one_more = mb.normalise(OUT + OUT.splitlines()[0] + "\n")
    new, stale, _ = mb.compare(one_more, base)
    assert new == [base[1]] and stale == []     # the same message once more is a new finding
    new, stale, _ = mb.compare(base[:2], base)
    assert new == [] and stale == [base[2]]     # fixed: the line must leave the baseline


def test_clean_packages_hold_no_baseline_line():
    line = f"{mb.CLEAN[0]}x.py: [arg-type] whatever"
    assert mb.compare([line], [line])[2] == [line]


def test_the_checked_in_baseline_is_sorted_and_has_no_clean_package_line(tmp_path):
    base = mb.read_baseline()
    assert base == sorted(base)
    assert not [ln for ln in base if ln.startswith(mb.CLEAN)]
    mb.write_baseline(base, tmp_path / "b.txt")
    assert mb.read_baseline(tmp_path / "b.txt") == base
