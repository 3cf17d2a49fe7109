"""Mutated input files (bus.yml, scenario files, EDS files) and how cantrack answers them.

Bad input must end in a clear error naming what and where (``FILE:LINE, key 'KEY'``, for an
EDS file its section and key) or be accepted *and right*; never a traceback.  This module
makes the mutants and judges the answers, for the property tests (``tests/test_mutants.py``,
a few hundred examples) and the larger run (``benchmarks/mutants.py``, thousands).

Mutations of a YAML file are made on its parsed tree (the project's own loader, so that the
file's floats, hex integers and merge keys read as cantrack reads them), then dumped again:

- a leaf replaced by a value of :data:`YAML_VALUES` (NaN, +-inf, 1e300, a 5000-digit integer,
  null, a string, a list, a mapping, 0, -1, 1e-9, the value negated or times 1e6);
- a key deleted, an unknown key added;
- text mutations: a NUL byte, a 5000-deep nesting, the file cut at a random place.

An EDS file is mutated section by section (CiA 306): an entry's value replaced by a value of
:data:`EDS_VALUES`, an entry deleted, a whole sub-index section deleted, a DefaultValue out of
its DataType's range.

The answer is one of :class:`Verdict`: ``error`` (a :class:`~controller.errors.CantrackError`
whose message names the file and a line, key or section), ``accepted`` (and nothing found
wrong), ``unclear`` (an error message without a place), ``traceback`` (any other exception),
``wrong`` (accepted, but the file's value was ignored -- e.g. ``key: null`` taken as the
default -- or a loaded value is not finite).  Hypothesis is imported only by the strategies.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import random
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import yaml

from ..errors import CantrackError

#: values put in place of a YAML leaf (label, value); callables get the old value
YAML_VALUES: list[tuple[str, Any]] = [
    ("null", None), ("nan", math.nan), ("inf", math.inf), ("-inf", -math.inf),
    ("1e300", 1e300), ("-1e300", -1e300), ("5000-digit int", 10 ** 5000), ("0", 0),
    ("-1", -1), ("1e-9", 1e-9), ("string", "xyz"), ("empty string", ""), ("true", True),
    ("list", [1, 2, 3]), ("empty list", []), ("mapping", {"a": 1}), ("empty mapping", {}),
    ("negated", lambda v: -v if isinstance(v, (int, float)) and not isinstance(v, bool)
     else None),
    ("x1e6", lambda v: v * 1e6 if isinstance(v, (int, float)) and not isinstance(v, bool)
     else None),
    ("2**64", 2 ** 64),
]

#: values put in place of an EDS entry's value
EDS_VALUES: list[str] = ["", "xx", "0x99", "0xFFFF", "7", "-1", "1e300", "nan",
                         "0x100000000", "99999999999999999999", "$NODEID+x", "rw ro",
                         "0x7", "2", "0"]


class Verdict(enum.Enum):
    ERROR = "error"          # a clear error naming the place
    ACCEPTED = "accepted"    # accepted, nothing found wrong
    UNCLEAR = "unclear"      # an error that does not say where
    TRACEBACK = "traceback"  # an exception that is not a CantrackError
    WRONG = "wrong"          # accepted but wrong

    @property
    def ok(self) -> bool:
        return self in (Verdict.ERROR, Verdict.ACCEPTED)


@dataclasses.dataclass(frozen=True)
class Mutant:
    family: str       # "bus", "scenario", "eds"
    what: str         # e.g. "x.node_id <- nan"
    text: str         # the mutated file
    #: the key path changed (None for text mutations)
    path: tuple | None = None
    #: the value put there (for the null / ignored-value check)
    label: str = ""


@dataclasses.dataclass(frozen=True)
class Answer:
    mutant: Mutant
    verdict: Verdict
    detail: str

    def __str__(self) -> str:
        return f"[{self.verdict.value}] {self.mutant.family}: {self.mutant.what}: {self.detail}"


# -- YAML ------------------------------------------------------------------------------------
def plain(tree: Any) -> Any:
    """The project's marked YAML tree as plain dicts and lists (for ``yaml.safe_dump``)."""
    if isinstance(tree, dict):
        return {k: plain(v) for k, v in tree.items()}
    if isinstance(tree, list):
        return [plain(v) for v in tree]
    return tree


def load_tree(text: str, file: str = "<base>") -> Any:
    from ..yamlmarks import load_marked
    return plain(load_marked(text, file))


def dump(tree: Any) -> str:
    import sys
    old = sys.get_int_max_str_digits()
    sys.set_int_max_str_digits(0)  # (the 5000-digit integer mutant)
    try:
        return yaml.safe_dump(tree, sort_keys=False, default_flow_style=None, width=100)
    finally:
        sys.set_int_max_str_digits(old)


def leaf_paths(tree: Any, prefix: tuple = ()) -> Iterator[tuple]:
    """Every path to a value (mappings, lists and scalars), depth first."""
    if isinstance(tree, dict):
        for k, v in tree.items():
            yield prefix + (k,)
            yield from leaf_paths(v, prefix + (k,))
    elif isinstance(tree, list):
        for i, v in enumerate(tree):
            yield prefix + (i,)
            yield from leaf_paths(v, prefix + (i,))


def _get(tree: Any, path: tuple) -> Any:
    for p in path:
        tree = tree[p]
    return tree


def _set(tree: Any, path: tuple, value: Any) -> None:
    _get(tree, path[:-1])[path[-1]] = value


def _delete(tree: Any, path: tuple) -> None:
    parent = _get(tree, path[:-1])
    del parent[path[-1]]


def path_text(path: tuple) -> str:
    return ".".join(str(p) for p in path)


def yaml_mutant(family: str, base: Any, rng: random.Random) -> Mutant:
    """One random mutant of the parsed ``base`` tree (deterministic for ``rng``)."""
    import copy
    tree = copy.deepcopy(base)
    paths = list(leaf_paths(tree))
    op = rng.choices(["value", "delete", "unknown", "nul", "deep", "cut"],
                     weights=[70, 10, 6, 5, 5, 4])[0]
    if op in ("value", "delete", "unknown") and paths:
        path = rng.choice(paths)
        if op == "value":
            label, value = rng.choice(YAML_VALUES)
            old = _get(tree, path)
            if callable(value):
                value = value(old)
                if value is None:
                    label, value = "null", None
            _set(tree, path, value)
            return Mutant(family, f"{path_text(path)} <- {label}", dump(tree), path, label)
        if op == "delete":
            _delete(tree, path)
            return Mutant(family, f"{path_text(path)} deleted", dump(tree), path, "deleted")
        parent_path = path[:-1]
        parent = _get(tree, parent_path)
        if isinstance(parent, dict):
            parent["no_such_key"] = 1
            return Mutant(family, f"{path_text(parent_path + ('no_such_key',))} added",
                          dump(tree), parent_path + ("no_such_key",), "unknown key")
    text = dump(tree)
    if op == "nul":
        i = rng.randrange(len(text))
        return Mutant(family, f"NUL byte at offset {i}", text[:i] + "\0" + text[i:])
    if op == "deep":
        lines = text.splitlines(keepends=True)
        i = rng.randrange(len(lines))
        return Mutant(family, f"5000-deep nesting after line {i + 1}",
                      "".join(lines[:i]) + "deep: " + "[" * 5000 + "]" * 5000 + "\n"
                      + "".join(lines[i:]))
    i = rng.randrange(1, len(text))
    return Mutant(family, f"cut at offset {i}", text[:i])


def placed_error(exc: CantrackError, file: str) -> bool:
    """The message names the file and a line, a key or an EDS section."""
    msg = str(exc)
    name = Path(file).name
    if name not in msg:
        return False
    return bool(re.search(r":\d+|line \d+|key '|\[[0-9A-Fa-f]{4}(sub[0-9A-Fa-f]+)?\]|section",
                          msg))


def _finite_everywhere(obj: Any, where: str = "", seen: set | None = None) -> str | None:
    """The first non-finite float in a loaded configuration object (dataclasses, tuples,
    dicts), as its attribute path, or None."""
    seen = set() if seen is None else seen
    if id(obj) in seen:
        return None
    if isinstance(obj, float):
        return None if math.isfinite(obj) else where
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        seen.add(id(obj))
        for f in dataclasses.fields(obj):
            if f.name in ("ods",):
                continue
            bad = _finite_everywhere(getattr(obj, f.name, None), f"{where}.{f.name}", seen)
            if bad:
                return bad
    elif isinstance(obj, dict):
        seen.add(id(obj))
        for k, v in obj.items():
            bad = _finite_everywhere(v, f"{where}[{k!r}]", seen)
            if bad:
                return bad
    elif isinstance(obj, (list, tuple)):
        seen.add(id(obj))
        for i, v in enumerate(obj):
            bad = _finite_everywhere(v, f"{where}[{i}]", seen)
            if bad:
                return bad
    return None


def judge(mutant: Mutant, load: Callable[[Path], Any], path: Path,
          deleted_twin: Callable[[], Any] | None = None,
          check: Callable[[Any], str | None] | None = None) -> Answer:
    """Write ``mutant`` to ``path``, load it with ``load`` and judge the answer.

    ``deleted_twin()`` loads the same file with the mutated key deleted (for the
    null-taken-as-default check); ``check(loaded)`` returns what is wrong with an accepted
    file, or None.
    """
    import sys
    path.write_text(mutant.text, encoding="utf-8")
    old_limit = sys.getrecursionlimit()
    try:
        loaded = load(path)
    except CantrackError as exc:
        if placed_error(exc, str(path)):
            return Answer(mutant, Verdict.ERROR, str(exc).splitlines()[0][:200])
        return Answer(mutant, Verdict.UNCLEAR, str(exc).splitlines()[0][:200])
    except RecursionError as exc:
        return Answer(mutant, Verdict.TRACEBACK, f"RecursionError: {str(exc)[:120]}")
    except Exception as exc:  # noqa: BLE001 -- that is the finding
        return Answer(mutant, Verdict.TRACEBACK, f"{type(exc).__name__}: {str(exc)[:160]}")
    finally:
        sys.setrecursionlimit(old_limit)
    # (a deleted limit may well mean "none": inf; only a non-finite value put in is judged)
    bad = _finite_everywhere(loaded) if mutant.label in ("nan", "inf", "-inf", "1e300",
                                                         "-1e300", "x1e6") else None
    if bad:
        return Answer(mutant, Verdict.WRONG, f"accepted with a non-finite value at {bad}")
    # (an empty list or mapping is "none of these", "" may be a name's default; null is no
    #  value at all)
    if mutant.label == "null" \
            and deleted_twin is not None:
        try:
            twin = deleted_twin()
        except Exception:  # noqa: BLE001 -- the key is required: then null must fail too
            return Answer(mutant, Verdict.WRONG, f"{mutant.label} accepted for a key that is "
                                                 "required")
        if _same(loaded, twin):
            return Answer(mutant, Verdict.WRONG,
                          f"{mutant.label} silently taken as the default")
    if check is not None:
        try:
            problem = check(loaded)
        except CantrackError as exc:  # a clear error at run time is an answer too
            if placed_error(exc, str(path)):
                return Answer(mutant, Verdict.ERROR, "at run time: " + str(exc)[:200])
            return Answer(mutant, Verdict.UNCLEAR, "at run time: " + str(exc)[:200])
        except Exception as exc:  # noqa: BLE001
            return Answer(mutant, Verdict.TRACEBACK,
                          f"at run time: {type(exc).__name__}: {str(exc)[:160]}")
        if problem:
            return Answer(mutant, Verdict.WRONG, problem)
    return Answer(mutant, Verdict.ACCEPTED, "")


def _same(a: Any, b: Any) -> bool:
    try:
        return repr(_strip(a)) == repr(_strip(b))
    except Exception:  # noqa: BLE001
        return False


def _strip(obj: Any) -> Any:
    """A configuration object without its file name and line numbers (for comparison)."""
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return tuple((f.name, _strip(getattr(obj, f.name, None)))
                     for f in dataclasses.fields(obj)
                     if f.name not in ("file", "line", "lines", "ods", "source"))
    if isinstance(obj, dict):
        return tuple((k, _strip(v)) for k, v in obj.items())
    if isinstance(obj, (list, tuple)):
        return tuple(_strip(v) for v in obj)
    return obj


def deleted_text(mutant: Mutant, base: Any) -> str | None:
    """The base file with the mutated key deleted (the twin of a null mutant)."""
    import copy
    if mutant.path is None:
        return None
    tree = copy.deepcopy(base)
    try:
        parent = _get(tree, mutant.path[:-1])
    except (KeyError, IndexError, TypeError):
        return None
    if not isinstance(parent, dict):
        return None
    parent.pop(mutant.path[-1], None)
    return dump(tree)


# -- EDS -------------------------------------------------------------------------------------
_SECTION = re.compile(r"^\[([^\]]+)\]\s*$")


def eds_sections(text: str) -> list[tuple[str, int, list[int]]]:
    """(section name, header line index, entry line indices) of an EDS text."""
    out: list[tuple[str, int, list[int]]] = []
    for i, line in enumerate(text.splitlines()):
        m = _SECTION.match(line.strip())
        if m:
            out.append((m.group(1), i, []))
        elif out and "=" in line and not line.lstrip().startswith(";"):
            out[-1][2].append(i)
    return out


def eds_mutant(base: str, rng: random.Random) -> Mutant:
    """One random mutant of an EDS text (deterministic for ``rng``)."""
    lines = base.splitlines()
    secs = [s for s in eds_sections(base) if s[2]]
    op = rng.choices(["value", "delete_entry", "delete_section", "default_range"],
                     weights=[60, 15, 10, 15])[0]
    name, head, entries = rng.choice(secs)
    if op == "delete_section":
        # a whole object or sub-index section (an object's subs stay: dangling)
        end = max(entries) + 1
        out = lines[:head] + lines[end:]
        return Mutant("eds", f"[{name}] deleted", "\n".join(out) + "\n", (name,), "deleted")
    if op == "default_range":
        keys = {lines[i].split("=", 1)[0].strip().lower(): i for i in entries}
        if "defaultvalue" in keys and "datatype" in keys:
            i = keys["defaultvalue"]
            lines[i] = "DefaultValue=0x1FFFFFFFFFFFFFFFF"
            return Mutant("eds", f"[{name}] DefaultValue out of range", "\n".join(lines)
                          + "\n", (name, "DefaultValue"), "range")
    i = rng.choice(entries)
    key = lines[i].split("=", 1)[0].strip()
    if op == "delete_entry":
        del lines[i]
        return Mutant("eds", f"[{name}] {key} deleted", "\n".join(lines) + "\n", (name, key),
                      "deleted")
    value = rng.choice(EDS_VALUES)
    lines[i] = f"{key}={value}"
    return Mutant("eds", f"[{name}] {key}={value}", "\n".join(lines) + "\n", (name, key),
                  value)


# -- hypothesis strategies -------------------------------------------------------------------
def strategy(make: Callable[[random.Random], Mutant]):
    """A hypothesis strategy drawing mutants from ``make(rng)`` (seeded by hypothesis)."""
    from hypothesis import strategies as st
    return st.randoms(use_true_random=False).map(make)
