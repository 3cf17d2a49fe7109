#!/usr/bin/env python3
"""mypy with a baseline that only shrinks (CI runs this; CONTRIBUTING.md "Types and lint").

Runs mypy as configured in pyproject.toml (``[tool.mypy]``: the whole ``controller`` package)
and compares its errors with ``.ci/mypy-baseline.txt``: one line per known error, as
``path: [code] message`` -- no line numbers, so edits elsewhere in a file do not change it.
A line occurs as often as the error does.

Exit 1 when
  - an error is not in the baseline (a new finding: fix it), or
  - a baseline line no longer occurs (fixed: delete the line, or run ``--shrink``), or
  - the baseline holds a line of a package that must stay clean (``CLEAN`` below).

``--shrink`` deletes the baseline lines that no longer occur and never adds one.
``--rebuild`` writes the current errors as the baseline; only for the maintainer who sets the
baseline up -- a change that adds lines to it is not accepted.
"""

from __future__ import annotations

import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BASELINE = ROOT / ".ci" / "mypy-baseline.txt"

#: Packages and modules with no error and no baseline line allowed (issue 10).
CLEAN = (
    "controller/tracking/",
    "controller/motion/",
    "controller/kinematics/",
    "controller/conveyor/",
    "controller/canopen/protocol/",
    "controller/canopen/config/",
)

_ERROR = re.compile(r"^(?P<path>[^:\n]+):\d+(?::\d+)?: error: (?P<msg>.*?)\s+\[(?P<code>[a-z0-9-]+)\]$")
_LINE_REF = re.compile(r"\bline \d+\b")


def normalise(output: str) -> list[str]:
    """mypy's output -> the sorted baseline lines of its errors (notes dropped)."""
    out = []
    for raw in output.splitlines():
        m = _ERROR.match(raw.strip())
        if m:
            path = m["path"].replace("\\", "/")
            msg = _LINE_REF.sub("line N", m["msg"])
            out.append(f"{path}: [{m['code']}] {msg}")
    return sorted(out)


def read_baseline(path: Path = BASELINE) -> list[str]:
    if not path.is_file():
        return []
    return sorted(ln for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#"))


def compare(current: list[str], baseline: list[str]) -> tuple[list[str], list[str], list[str]]:
    """(new findings, stale baseline lines, baseline lines in a clean package)."""
    cur, base = Counter(current), Counter(baseline)
    new = sorted((cur - base).elements())
    stale = sorted((base - cur).elements())
    clean = sorted(ln for ln in baseline if ln.startswith(CLEAN))
    return new, stale, clean


def write_baseline(lines: list[str], path: Path = BASELINE) -> None:
    header = ("# mypy errors accepted for now (.ci/mypy_baseline.py; CONTRIBUTING.md).  Only ever\n"
              "# delete lines: a fixed error must leave this file, a new one must not enter it.\n")
    path.write_text(header + "".join(ln + "\n" for ln in sorted(lines)))


def run_mypy() -> str:
    r = subprocess.run([sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True)
    if r.returncode not in (0, 1) or "error: " not in r.stdout and r.returncode == 1:
        sys.stderr.write(r.stdout + r.stderr)
        raise SystemExit(f"mypy failed to run (exit {r.returncode})")
    return r.stdout


def main(argv: list[str]) -> int:
    current = normalise(run_mypy())
    baseline = read_baseline()
    if "--rebuild" in argv:
        write_baseline(current)
        print(f"{BASELINE.relative_to(ROOT)}: {len(current)} lines written")
        return 0
    new, stale, clean = compare(current, baseline)
    if "--shrink" in argv and stale:
        left = list((Counter(baseline) - Counter(stale)).elements())
        write_baseline(left)
        print(f"{BASELINE.relative_to(ROOT)}: {len(stale)} fixed lines deleted, {len(left)} left")
        baseline = sorted(left)
        new, stale, clean = compare(current, baseline)
    for ln in new:
        print(f"new mypy error (fix it; the baseline only shrinks): {ln}")
    for ln in stale:
        print(f"fixed, delete this line from {BASELINE.relative_to(ROOT)} "
              f"(or run .ci/mypy_baseline.py --shrink): {ln}")
    for ln in clean:
        print(f"{BASELINE.relative_to(ROOT)}: no baseline line allowed in a clean package: {ln}")
    if new:
        print("(mypy's own output with line numbers: python -m mypy)")
    print(f"mypy: {len(current)} errors, baseline {len(baseline)} lines; "
          f"{len(new)} new, {len(stale)} fixed but still listed")
    return 1 if new or stale or clean else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
