"""The code points into docs/spec/, and only there; every such pointer resolves.

Users of cantrack have the repository, not the documents it was written from: a docstring
that cites a source document, a note or a path of a development machine cannot be followed.
These tests walk the tracked files (``git ls-files``) and check

- no tracked file outside ``tests/`` and ``.ci/`` names a development machine's path
  (``/work/...``) or the source folders (``shared/notes``, ``shared/seeds``);
- no tracked text in the shipped folders cites the source documents ("the page",
  ``notes/``, ``seeds/``, "algorithm page", "overview page") except as part of a
  ``docs/spec/`` link;
- every ``docs/spec/FILE.md#ANCHOR`` link anywhere in the tracked files, and every relative
  link inside ``docs/spec/*.md``, names an existing file and an existing anchor: an explicit
  ``<a id="N.M"></a>``, a heading whose text starts with that section number, or a heading's
  GitHub slug.
"""

from __future__ import annotations

import re
import subprocess
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: folders and files shipped to users whose text must not cite the source documents
SHIPPED = ("controller/", "docs/", "examples/", "benchmarks/", "fmu/", "eds/", "README.md",
           "CONTRIBUTING.md", "pyproject.toml")
MACHINE_PATHS = re.compile(r"/work/|shared/notes|shared/seeds")
SOURCE_CITES = re.compile(r"\bthe page\b|\bnotes/|\bseeds/|\balgorithm page\b|\boverview page\b",
                          re.IGNORECASE)
SPEC_LINK = re.compile(r"docs/spec/([\w./-]+?\.md)(?:#([\w.-]*[\w-]))?")
MD_LINK = re.compile(r"\]\(([^)\s]*)\)")
ANCHOR_TAG = re.compile(r'<a\s+(?:id|name)="([^"]+)"\s*>\s*</a>')
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")


#: this file (its examples are deliberately broken)
SELF = Path(__file__).resolve().relative_to(ROOT).as_posix()


def _tracked() -> list[str]:
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True,
                             check=True).stdout
    except (OSError, subprocess.CalledProcessError) as exc:  # pragma: no cover - no git
        pytest.fail(f"git ls-files failed in {ROOT}: {exc}")
    return [p for p in out.decode().split("\0") if p]


def _text(rel: str) -> str | None:
    path = ROOT / rel
    try:
        data = path.read_bytes()
    except OSError:  # tracked but deleted in the work tree
        return None
    if b"\0" in data[:4096]:
        return None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return None


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to dashes."""
    s = re.sub(r"<[^>]+>", "", heading).strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


@cache
def _anchors(rel: str) -> frozenset[str]:
    text = _text(rel) or ""
    found: set[str] = set(ANCHOR_TAG.findall(text))
    fence = False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fence = not fence
            continue
        m = None if fence else HEADING.match(line)
        if m:
            title = m.group(2)
            found.add(_slug(title))
            number = re.match(r"(\d+(?:\.\d+)*)\.?\s", title + " ")
            if number:
                found.add(number.group(1))
    return frozenset(found)


def _lines(rel: str):
    text = _text(rel)
    if text is None:
        return
    yield from enumerate(text.splitlines(), 1)


def test_no_machine_paths_outside_tests_and_ci():
    bad = [f"{rel}:{n}: {line.strip()}" for rel in _tracked()
           if not rel.startswith(("tests/", ".ci/"))
           for n, line in _lines(rel) if MACHINE_PATHS.search(line)]
    assert not bad, "paths of a development machine in tracked files:\n" + "\n".join(bad)


def test_shipped_text_cites_docs_spec_not_the_source_documents():
    bad = []
    for rel in _tracked():
        if not rel.startswith(SHIPPED):
            continue
        for n, line in _lines(rel):
            if SOURCE_CITES.search(SPEC_LINK.sub("", line)):
                bad.append(f"{rel}:{n}: {line.strip()}")
    assert not bad, ("citations of documents that are not in the repository (point to a "
                     "section of docs/spec/ instead):\n" + "\n".join(bad))


def _resolve(target_file: str, anchor: str | None) -> str | None:
    """None if ``target_file`` (relative to the root) and ``anchor`` exist, else why not."""
    if not (ROOT / target_file).is_file():
        return f"no file {target_file}"
    if anchor and anchor not in _anchors(target_file):
        return f"no section #{anchor} in {target_file}"
    return None


def test_every_docs_spec_link_resolves():
    bad = []
    for rel in _tracked():
        if rel == SELF:
            continue
        for n, line in _lines(rel):
            for m in SPEC_LINK.finditer(line):
                why = _resolve("docs/spec/" + m.group(1), m.group(2))
                if why:
                    bad.append(f"{rel}:{n}: {m.group(0)}: {why}")
    assert not bad, "docs/spec links that do not resolve:\n" + "\n".join(bad)


def test_links_inside_docs_spec_resolve():
    spec = [rel for rel in _tracked() if rel.startswith("docs/spec/") and rel.endswith(".md")]
    assert "docs/spec/README.md" in spec
    bad = []
    for rel in spec:
        base = (ROOT / rel).parent
        for n, line in _lines(rel):
            for m in MD_LINK.finditer(line):
                target = m.group(1)
                if re.match(r"[a-z]+:", target):  # http:, mailto: ...
                    continue
                path, _, anchor = target.partition("#")
                file = (base / path).resolve() if path else ROOT / rel
                try:
                    file_rel = file.relative_to(ROOT).as_posix()
                except ValueError:
                    bad.append(f"{rel}:{n}: {target}: outside the repository")
                    continue
                if file.is_dir():
                    continue
                why = _resolve(file_rel, anchor or None)
                if why:
                    bad.append(f"{rel}:{n}: {target}: {why}")
    assert not bad, "links in docs/spec that do not resolve:\n" + "\n".join(bad)


def test_the_checks_see_what_they_look_for(tmp_path):
    """The patterns find a citation, a machine path and a broken anchor (the checks can fail)."""
    assert SOURCE_CITES.search("as the page writes")
    assert SOURCE_CITES.search("see notes/tracking-algorithm-notes.md")
    assert not SOURCE_CITES.search(SPEC_LINK.sub("", "see docs/spec/tracking.md#3.2"))
    assert MACHINE_PATHS.search("see /work/shared/notes/x.md")
    assert _resolve("docs/spec/tracking.md", "3.2") is None
    assert _resolve("docs/spec/tracking.md", "99.9") is not None
    assert _resolve("docs/spec/no-such-file.md", None) is not None
