"""YAML with line marks, and a strict section reader that names file, line and key.

Shared by every configuration reader (bus.yml in ``controller.canopen``, scenario files in
``controller.simulate``).

``load_marked(text, file)`` parses YAML (safe loader) into :class:`MarkedMap` /
:class:`MarkedList` that remember the 1-based line of every key, value and item.  A
:class:`Section` wraps one mapping with its dotted path and checks each value's type and range
when read; :meth:`Section.finish` rejects the keys nobody read, suggesting the closest known
key (dcfgen silently ignores unknown keys; we do not); :meth:`Section.check_keys` does so up
front, listing the valid keys.

Two families of getters share the locations, the key bookkeeping and the errors:

- ``int``/``float``/``bool``/``str``/``vector``: the bus.yml getters (dcfgen's types, ranges
  written ``[lo...hi]``);
- ``number``/``boolean``/``string``/``xyz``/``optional_section``: the scenario files'
  getters (``cantrack simulate``): numbers with a unit in the message and open or closed
  bounds, ``[x, y, z]`` vectors of a unit, and a key left empty in a file (``key:``) named
  as such instead of taken as absent.

Type rules are deliberately strict, because dcfgen coerces silently (``bool("false")`` is
True, ``int(2.7)`` is 2): an integer field takes a YAML integer (decimal or ``0x`` hex) and
nothing else; a bool field takes only ``true``/``false``; a float field takes an int or a
float.
"""

from __future__ import annotations

import builtins
import difflib
import math
import re
from collections.abc import Callable, Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any, Literal, overload

import yaml

from .errors import ConfigError

_MISSING: Any = object()
#: the default of a required key (the getters raise "required key is missing" without one)
MISSING: Any = _MISSING
#: the largest |coordinate| of a position or angle a getter with unit mm or deg takes
#: without bounds of its own [mm, deg] (1 km: 1e300 would overflow a planner's arithmetic)
MAX_POSITION = 1e6


def read_text(path: str | Path) -> str:
    """A configuration or data file's text (UTF-8).  Text that is not UTF-8 is a ConfigError
    naming the file, the line and the byte (e.g. a Latin-1 "µ" in a comment); OSError (no such
    file, ...) propagates for the caller to report."""
    data = Path(path).read_bytes()
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise ConfigError(f"not UTF-8 text (byte {data[exc.start]:#04x}); save the file as "
                          "UTF-8", file=str(path), line=line) from None


class MarkedMap(dict):
    """A YAML mapping with ``line`` (its start), ``key_lines`` and ``value_lines``."""

    line: int | None = None

    def __init__(self) -> None:
        super().__init__()
        self.key_lines: dict = {}
        self.value_lines: dict = {}


class MarkedList(list):
    """A YAML sequence with ``line`` and ``item_lines``."""

    line: int | None = None

    def __init__(self, items: Iterable[Any] = ()) -> None:
        super().__init__(items)
        self.item_lines: list[int] = []


class _Loader(yaml.SafeLoader):
    """SafeLoader with line marks; floats also without a dot or exponent sign (``3.0e7``,
    YAML 1.2).  dcfgen (YAML 1.1) would read those as strings, but it never reads a float."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"))


def _construct_mapping(loader: _Loader, node: yaml.MappingNode) -> MarkedMap:
    own = sum(1 for k, _ in node.value if k.tag != "tag:yaml.org,2002:merge")
    loader.flatten_mapping(node)
    merged = len(node.value) - own  # pairs from "<<: *anchor" come first; own keys override
    m = MarkedMap()
    m.line = node.start_mark.line + 1
    for i, (key_node, value_node) in enumerate(node.value):
        if i < merged or (i >= merged and key_node.value in
                          [k.value for k, _ in node.value[:merged]]
                          and not _own_duplicate(node.value[merged:i], key_node)):
            key = loader.construct_object(key_node, deep=True)
            m[key] = loader.construct_object(value_node, deep=True)
            m.key_lines[key] = key_node.start_mark.line + 1
            m.value_lines[key] = value_node.start_mark.line + 1
            continue
        key = loader.construct_object(key_node, deep=True)
        line = key_node.start_mark.line + 1
        try:
            hash(key)
        except TypeError:
            raise ConfigError("a mapping key must be a plain value", file=loader.name,
                              line=line) from None
        if key in m:
            raise ConfigError(f"duplicate key (first given on line {m.key_lines[key]})",
                              file=loader.name, line=line, key=str(key))
        m[key] = loader.construct_object(value_node, deep=True)
        m.key_lines[key] = line
        m.value_lines[key] = value_node.start_mark.line + 1
    return m


def _own_duplicate(earlier: list, key_node: yaml.Node) -> bool:
    return any(k.value == key_node.value for k, _ in earlier)


def _construct_sequence(loader: _Loader, node: yaml.SequenceNode) -> MarkedList:
    s = MarkedList(loader.construct_object(child, deep=True) for child in node.value)
    s.line = node.start_mark.line + 1
    s.item_lines = [child.start_mark.line + 1 for child in node.value]
    return s


_Loader.add_constructor("tag:yaml.org,2002:map", _construct_mapping)
_Loader.add_constructor("tag:yaml.org,2002:seq", _construct_sequence)


_KEY_LINE = re.compile(r"^\s*(?:-\s+)?([A-Za-z_][\w.-]*)\s*:")


def _nearest_key(text: str, line: int) -> str | None:
    """The last ``key:`` written on or before 1-based ``line`` (for YAML syntax errors)."""
    lines = text.splitlines()
    for i in range(min(line, len(lines)) - 1, -1, -1):
        m = _KEY_LINE.match(lines[i])
        if m:
            return m.group(1)
    return None


#: the deepest nesting of mappings and lists a configuration may have (deeper ones would
#: exhaust the recursion of the YAML composer; no cantrack file nests more than 6)
MAX_DEPTH = 50
#: the longest integer literal [digits] (Python refuses > 4300; no value here needs > 20)
MAX_INT_DIGITS = 40


def _construct_int(loader: _Loader, node: yaml.ScalarNode) -> int:
    digits = sum(ch.isdigit() for ch in str(node.value))
    if digits > MAX_INT_DIGITS:
        raise yaml.constructor.ConstructorError(
            None, None, f"an integer of {digits} digits is too long (at most "
                        f"{MAX_INT_DIGITS})", node.start_mark)
    return yaml.SafeLoader.construct_yaml_int(loader, node)


_Loader.add_constructor("tag:yaml.org,2002:int", _construct_int)


def _too_deep(text: str) -> int | None:
    """The 1-based line where flow nesting (``[``/``{``) first goes deeper than
    :data:`MAX_DEPTH`, outside quotes and comments; None if it never does."""
    depth, line, quote = 0, 1, ""
    comment = False
    prev = "\n"
    for ch in text:
        if ch == "\n":
            line += 1
            comment = False
            if quote == "'" or quote == '"':
                pass
        elif comment:
            pass
        elif quote:
            if ch == quote:
                quote = ""
        elif ch in "'\"" and prev in " \t[{,:\n":
            quote = ch
        elif ch == "#" and prev in " \t\n":
            comment = True
        elif ch in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                return line
        elif ch in "]}":
            depth = max(0, depth - 1)
        prev = ch
    return None


def load_marked(text: str, file: str) -> Any:
    """Parse ``text``; a syntax error becomes a ConfigError with the file, line and the
    nearest key written before it.  So do characters YAML does not allow (a NUL byte, other
    control characters), nesting deeper than :data:`MAX_DEPTH` and integers longer than
    :data:`MAX_INT_DIGITS` digits."""
    deep = _too_deep(text)
    if deep is not None:
        raise ConfigError(f"lists/mappings nested more than {MAX_DEPTH} deep", file=file,
                          line=deep, key=_nearest_key(text, deep))
    try:
        loader = _Loader(text)
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, exc.position) + 1
        what = "a NUL byte" if exc.character in (0, "\0") else \
            f"the character #x{exc.character if isinstance(exc.character, int) else ord(exc.character):04x}"
        raise ConfigError(f"{what} is not allowed in a YAML file (is it a text file?)",
                          file=file, line=line, key=_nearest_key(text, line)) from None
    loader.name = file
    try:
        return loader.get_single_data()
    except yaml.reader.ReaderError as exc:
        line = text.count("\n", 0, exc.position) + 1
        raise ConfigError(f"YAML error: {exc.reason}", file=file, line=line,
                          key=_nearest_key(text, line)) from None
    except RecursionError:
        raise ConfigError(f"lists/mappings nested too deep (at most {MAX_DEPTH})",
                          file=file, line=1) from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        at = mark.line + 1 if mark is not None else None
        where = exc.context_mark or exc.problem_mark
        key = _nearest_key(text, where.line + 1) if where is not None else None
        msg = f"YAML syntax error: {exc.problem or exc}"
        if exc.context:
            ctx_line = f" started on line {exc.context_mark.line + 1}" if exc.context_mark else ""
            msg += f" ({exc.context}{ctx_line})"
        raise ConfigError(msg, file=file, line=at, key=key) from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"YAML error: {exc}", file=file) from None
    finally:
        loader.dispose()


def closest(key: Any, known: Iterable[Any]) -> str | None:
    """The known key closest to ``key`` (a likely misspelling of it), or None."""
    close = difflib.get_close_matches(str(key), [str(k) for k in known], n=1, cutoff=0.6)
    return close[0] if close else None


def suggest(key: str, known: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` for the closest known key, or ``""``."""
    close = closest(key, known)
    return f" (did you mean '{close}'?)" if close else ""


# -- the marks of a loaded value (plain values from Python have none: the defaults) ------
def is_marked(value: Any) -> bool:
    """True for a mapping or list read from a file (it has line marks)."""
    return isinstance(value, (MarkedMap, MarkedList))


def key_line(mapping: Any, key: Any, default: int | None = None) -> int | None:
    """The line of ``key`` in a loaded mapping (``default`` without marks)."""
    return getattr(mapping, "key_lines", {}).get(key, default)


def value_line(mapping: Any, key: Any, default: int | None = None) -> int | None:
    """The line of the value of ``key`` in a loaded mapping (``default`` without marks)."""
    return getattr(mapping, "value_lines", {}).get(key, default)


def item_lines(seq: Any, default: int | None = None) -> list[int | None]:
    """The line of each item of a loaded list (``default`` for each without marks)."""
    lines = getattr(seq, "item_lines", None)
    return list(lines) if lines else [default] * len(seq)


def _type_name(value: Any) -> str:
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int):
        return "an integer"
    if isinstance(value, float):
        return "a number"
    if isinstance(value, str):
        return f"the string {value!r}"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    if value is None:
        return "empty"
    return type(value).__name__


class Section:
    """One mapping of a marked YAML file, read key by key with validation.

    ``path`` is the dotted key path of the mapping (``""`` at the top level).  Every getter
    records the key as known; :meth:`finish` raises on keys that were not read.
    ``base_dir``: where the file's relative paths (CSV files, ...) are resolved; ``root``:
    how messages name the top level (``"the scenario"``).  Sections read from a section
    (:meth:`section`, :meth:`child`) share the file, ``base_dir`` and ``root``.
    """

    def __init__(self, data: Any, file: str, path: str = "", line: int | None = None,
                 head: int | None = None, *, base_dir: Path | None = None,
                 root: builtins.str = "the file") -> None:
        if not isinstance(data, dict):
            raise ConfigError(f"must be a mapping, not {_type_name(data)}", file=file,
                              line=line if line is not None or path else 1, key=path or None)
        self.data = data
        self.file = file
        self.path = path
        self.line = getattr(data, "line", line)
        #: the line of the key that introduced this section (for "required key is missing")
        self.head = head if head is not None else self.line
        self.base_dir = base_dir if base_dir is not None else Path.cwd()
        self.root = root
        self._known: list[Any] = []

    def child(self, data: Any, path: builtins.str, line: int | None) -> Section:
        """A section of this file for ``data`` at ``path`` introduced on ``line`` (a list
        item, a mapping built from this one's values)."""
        return Section(data, self.file, path, line, line if line is not None else self.line,
                       base_dir=self.base_dir, root=self.root)

    def fail(self, message: builtins.str, line: int | None,
             path: builtins.str | None) -> ConfigError:
        """An error of this file at ``line`` and key ``path`` (a value inside a list, ...)."""
        return ConfigError(message, file=self.file, line=line, key=path)

    def _where(self) -> builtins.str:
        return f"'{self.path}'" if self.path else self.root

    # -- locations ---------------------------------------------------------------------
    def key_path(self, key: Any) -> str:
        return f"{self.path}.{key}" if self.path else str(key)

    def key_line(self, key: Any) -> int | None:
        return key_line(self.data, key, self.line)

    def value_line(self, key: Any) -> int | None:
        return value_line(self.data, key, self.key_line(key))

    def error(self, key: Any, message: str, *, at_value: bool = True) -> ConfigError:
        line = self.value_line(key) if at_value else self.key_line(key)
        return ConfigError(message, file=self.file, line=line, key=self.key_path(key))

    def missing(self, key: str) -> ConfigError:
        """A missing required key; a misspelt one present is reported instead."""
        for other in self.data:
            if other not in self._known and suggest(str(other), [key]):
                return self.error(other, f"unknown key (did you mean '{key}'?)",
                                  at_value=False)
        return ConfigError("required key is missing", file=self.file, line=self.head,
                           key=self.key_path(key))

    # -- getters -----------------------------------------------------------------------
    def has(self, key: Any) -> bool:
        """``key`` is given: in a file also when left empty (a getter names that), in a
        mapping from Python not when None."""
        return key in self.data and (self.data[key] is not None or is_marked(self.data))

    def raw(self, key: Any, default: Any = _MISSING) -> Any:
        self._known.append(key)
        if key not in self.data:
            if default is _MISSING:
                raise self.missing(key)
            return default
        return self.data[key]

    def int(self, key: Any, default: Any = _MISSING, *, min: int | None = None,
            max: int | None = None, allowed: Iterable[int] | None = None) -> int:
        value = self.raw(key, default)
        if key not in self.data:
            return value
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(key, f"must be an integer, not {_type_name(value)}")
        self._check_range(key, value, min, max)
        if allowed is not None and value not in set(allowed):
            raise self.error(key, f"(={value}) must be one of {', '.join(map(str, allowed))}")
        return value

    def float(self, key: Any, default: Any = _MISSING, *, min: float | None = None,
              max: float | None = None, above: float | None = None) -> float:
        value = self.raw(key, default)
        if key not in self.data:
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise self.error(key, f"must be a finite number, not {_type_name(value)}")
        if above is not None and not value > above:
            raise self.error(key, f"(={value}) must be > {above}")
        self._check_range(key, value, min, max)
        return float(value)

    def bool(self, key: Any, default: Any = _MISSING) -> bool:
        value = self.raw(key, default)
        if key not in self.data:
            return value
        if not isinstance(value, bool):
            hint = " (dcfgen would read any non-empty string as true)" \
                if isinstance(value, str) else ""
            raise self.error(key, f"must be true or false, not {_type_name(value)}{hint}")
        return value

    def str(self, key: Any, default: Any = _MISSING,
            choices: Iterable[str] | None = None) -> str:
        value = self.raw(key, default)
        if key not in self.data:
            return value
        if not isinstance(value, str) or not value:
            raise self.error(key, f"must be a non-empty string, not {_type_name(value)}")
        if choices is not None:
            choices = list(choices)
            if value not in choices:
                raise self.error(key, f"(={value!r}) must be one of {', '.join(choices)}"
                                 + suggest(value, choices))
        return value

    # (below the getters named int/float/bool/str/list, the builtin types are builtins.X)
    @overload
    def vector(self, key: Any, n: Literal[3],
               default: Any = _MISSING) -> tuple[builtins.float, builtins.float, builtins.float]:
        ...
    @overload
    def vector(self, key: Any, n: builtins.int,
               default: Any = _MISSING) -> tuple[builtins.float, ...]: ...

    def vector(self, key: Any, n: builtins.int,
               default: Any = _MISSING) -> tuple[builtins.float, ...]:
        value = self.raw(key, default)
        if key not in self.data:
            return value
        if not isinstance(value, list) or len(value) != n or any(
                isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x)
                for x in value):
            raise self.error(key, f"must be a list of {n} numbers, not {_type_name(value)}"
                             + (f" of {len(value)} items" if isinstance(value, list) else ""))
        return tuple(float(x) for x in value)

    @overload
    def section(self, key: Any) -> Section: ...
    @overload
    def section(self, key: Any, default: None) -> Section | None: ...
    @overload
    def section(self, key: Any, default: Mapping[Any, Any]) -> Section: ...

    def section(self, key: Any, default: Any = _MISSING) -> Section | None:
        """The mapping at ``key`` (required without ``default``; ``None`` -> None when absent,
        ``{}`` -> an empty section)."""
        value = self.raw(key, default)
        if key not in self.data:
            return value if value is None else Section(
                value, self.file, self.key_path(key), self.line, base_dir=self.base_dir,
                root=self.root)
        return Section(value, self.file, self.key_path(key), self.value_line(key),
                       self.key_line(key), base_dir=self.base_dir, root=self.root)

    def list(self, key: Any, default: Any = _MISSING
             ) -> builtins.list[tuple[Any, builtins.int | None, builtins.str]]:
        """The items of a list as (item, line, dotted path)."""
        value = self.raw(key, default)
        if key not in self.data:
            return [] if value is None else [(v, self.line, self.key_path(key)) for v in value]
        if not isinstance(value, list):
            raise self.error(key, f"must be a list, not {_type_name(value)}")
        lines = item_lines(value, self.value_line(key))
        return [(v, line, f"{self.key_path(key)}[{i}]")
                for i, (v, line) in enumerate(zip(value, lines))]

    # -- the scenario files' getters ------------------------------------------------------
    def check_keys(self, allowed: Iterable[Any]) -> None:
        """Reject every key not in ``allowed`` now, naming the closest and all valid keys."""
        allowed = builtins.list(allowed)
        for k in self.data:
            if k in allowed:
                continue
            close = closest(k, allowed)
            hint = f"; did you mean '{close}'?" if close else ""
            raise ConfigError(f"unknown key in {self._where()}{hint} (valid keys: "
                              f"{', '.join(map(builtins.str, allowed))})", file=self.file,
                              line=self.key_line(k), key=self.key_path(k))
        self._known.extend(allowed)

    def given(self, key: Any, default: Any = _MISSING) -> Any:
        """The value at ``key``, ``default`` when absent (required without one); a key left
        empty in a file is an error, not the default."""
        self._known.append(key)
        value = self.data.get(key)
        if value is None and key in self.data and is_marked(self.data):
            raise self.error(key, "has no value (empty or null): give one or delete the key")
        if value is not None:
            return value
        if default is _MISSING:
            raise self.missing(key)
        return default

    def number(self, key: Any, default: Any = _MISSING, *, lo: builtins.float | None = None,
               hi: builtins.float | None = None, lo_open: builtins.bool = False,
               hi_open: builtins.bool = False, unit: builtins.str = "",
               integer: builtins.bool = False) -> Any:
        """A finite number [``unit``] within the bounds (open or closed); with unit mm or
        deg and no bounds, within :data:`MAX_POSITION`; ``default`` returned as it is."""
        value = self.given(key, default)
        if value is default and default is not _MISSING:
            return value
        if unit in ("mm", "deg") and lo is None and hi is None:
            lo, hi = -MAX_POSITION, MAX_POSITION
        return check_number(value, lambda msg: self.error(key, msg), lo=lo, hi=hi,
                            lo_open=lo_open, hi_open=hi_open, unit=unit, integer=integer)

    def boolean(self, key: Any, default: Any = _MISSING) -> Any:
        value = self.given(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, builtins.bool):
            raise self.error(key, f"must be true or false, got {describe(value)}")
        return value

    def string(self, key: Any, default: Any = _MISSING) -> Any:
        value = self.given(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, builtins.str):
            raise self.error(key, f"must be a string, got {describe(value)}")
        return value

    def file_path(self, key: Any) -> Path:
        """The string at ``key`` as a file's path, a relative one resolved against
        :attr:`base_dir` (the directory of the file being read)."""
        path = Path(self.string(key))
        return path if path.is_absolute() else self.base_dir / path

    def xyz(self, key: Any, default: Any = _MISSING, *, unit: builtins.str = "") -> Any:
        """``[x, y, z]`` [``unit``]; a position (mm) within :data:`MAX_POSITION`."""
        value = self.given(key, default)
        if value is default and default is not _MISSING:
            return value
        if not isinstance(value, builtins.list) or len(value) != 3:
            raise self.error(key, f"must be a list of 3 numbers [x, y, z]{_unit(unit)}, "
                                  f"got {describe(value)}")
        bound = MAX_POSITION if unit == "mm" else None
        return tuple(check_number(v, lambda msg, i=i: self.error(key, f"item {i}: {msg}"),
                                  lo=None if bound is None else -bound, hi=bound, unit=unit)
                     for i, v in enumerate(value))

    def optional_section(self, key: Any) -> Section | None:
        """The mapping at ``key`` if given, None when absent (:meth:`section`: required)."""
        if not self.has(key):
            self._known.append(key)
            return None
        self.given(key)
        return self.child(self.data[key], self.key_path(key), self.key_line(key))

    def items(self) -> Iterator[tuple[Any, Any]]:
        """All (key, value) pairs, marking every key as known."""
        for key, value in self.data.items():
            self._known.append(key)
            yield key, value

    def _check_range(self, key: Any, value: builtins.float, lo: builtins.float | None,
                     hi: builtins.float | None) -> None:
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            lo_s = "" if lo is None else _fmt(lo)
            hi_s = "" if hi is None else _fmt(hi)
            raise self.error(key, f"(={_fmt(value)}) must be in [{lo_s}...{hi_s}]")

    def finish(self, extra_known: Iterable[builtins.str] = ()) -> None:
        """Reject the keys that no getter asked for."""
        known = list(self._known) + list(extra_known)
        for key in self.data:
            if key not in known:
                raise self.error(key, "unknown key" + suggest(key, [str(k) for k in known]),
                                 at_value=False)


def describe(value: Any) -> str:
    """A value as the scenario getters name it in a message (``'x' (str)``, ``a list of 2``)."""
    if value is None:
        return "nothing"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    return f"{value!r} ({type(value).__name__})"


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def _range_text(lo: float | None, hi: float | None, lo_open: bool, hi_open: bool) -> str:
    if hi is None:
        return f"> {lo:g}" if lo_open else f">= {lo:g}"
    if lo is None:
        return f"< {hi:g}" if hi_open else f"<= {hi:g}"
    return f"in {'(' if lo_open else '['}{lo:g}...{hi:g}{')' if hi_open else ']'}"


def check_number(value: Any, fail: Callable[..., ConfigError], *, lo: float | None = None,
                 hi: float | None = None, lo_open: bool = False, hi_open: bool = False,
                 unit: str = "", integer: bool = False) -> float | int:
    """``value`` as a finite number (an int with ``integer``) within the bounds (open or
    closed), else ``fail(message)`` raised; ``unit`` is named in the message."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        kind = "an integer" if integer else "a number"
        raise fail(f"must be {kind}{_unit(unit)}, got {describe(value)}")
    if not math.isfinite(value):
        raise fail(f"must be a finite number, got {value!r}")
    if integer and int(value) != value:
        raise fail(f"must be an integer, got {value!r}")
    if (lo is not None and (value < lo or (lo_open and value == lo))) or \
            (hi is not None and (value > hi or (hi_open and value == hi))):
        raise fail(f"value {value!r} is out of range: must be "
                   f"{_range_text(lo, hi, lo_open, hi_open)}{_unit(unit)}")
    return int(value) if integer else float(value)


def _fmt(x: float) -> str:
    if isinstance(x, int) and abs(x) >= 0x10000:
        return f"{x} (0x{x:X})"
    return f"{x:g}" if isinstance(x, float) else str(x)


def item_section(item: Any, file: str, path: str, line: int | None) -> Section:
    """A Section for one list item (a mapping)."""
    return Section(item, file, path, line)


Validator = Callable[[Section], Any]
