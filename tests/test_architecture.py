"""The layering of ``controller/`` stays what docs/architecture.md says.

The layer table is read from docs/architecture.md (between ``<!-- layers -->`` and
``<!-- /layers -->``), so the document and the tree cannot drift apart.  Every import of every
module is walked with :mod:`ast` — top level, inside functions and under ``TYPE_CHECKING``
(a type-only import is a dependency of the design too) — and checked:

(a) a module imports only modules of its own layer or of the layers the table allows;
(b) no import cycle between modules of different layers;
(c) no folder under ``controller/canopen`` holds more than :data:`MAX_MODULES` modules;
(d) no module imports a private name (``_x``) from another module;

and every module belongs to a layer (a new package must be placed in the table).
The checker runs on a small synthetic tree too, with one planted violation of each rule.
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOC = ROOT / "docs" / "architecture.md"
MAX_MODULES = 12


@dataclass(frozen=True)
class Layer:
    name: str
    prefixes: tuple[str, ...]
    may_import: frozenset[str]


@dataclass(frozen=True)
class Import:
    source: str  # importing module
    target: str  # imported module (the module a name comes from)
    name: str | None  # the name imported from ``target`` (None: the module itself)
    line: int


def parse_layers(markdown: str) -> list[Layer]:
    """The layer table: ``| layer | modules | may import |`` rows between the markers.

    ``modules`` are backticked module names, each standing for the module or package and all
    below it; ``pkg.__init__`` stands for the package's own ``__init__`` only.  ``may
    import`` lists the layers directly below (``-`` for none); a layer may import every layer
    it reaches through them (:func:`allowed`)."""
    m = re.search(r"<!-- layers -->(.*?)<!-- /layers -->", markdown, re.S)
    if m is None:
        raise ValueError("no <!-- layers --> table")
    layers = []
    for row in m.group(1).strip().splitlines():
        cells = [c.strip() for c in row.strip().strip("|").split("|")]
        if len(cells) != 3 or cells[0] in ("layer", "") or set(cells[0]) <= set("-: "):
            continue
        prefixes = tuple(re.findall(r"`([\w.]+)`", cells[1]))
        allowed = frozenset(n.strip() for n in cells[2].split(",") if n.strip() not in ("-", ""))
        layers.append(Layer(cells[0], prefixes, allowed))
    names = {layer.name for layer in layers}
    for layer in layers:
        unknown = layer.may_import - names
        if unknown:
            raise ValueError(f"layer {layer.name}: unknown layers {sorted(unknown)}")
    return layers


def module_name(path: Path, src_root: Path) -> str:
    parts = list(path.relative_to(src_root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def collect(src_root: Path, package: str) -> tuple[dict[str, Path], list[Import]]:
    """All modules of ``package`` under ``src_root`` and all their imports of each other."""
    modules = {module_name(p, src_root): p for p in sorted((src_root / package).rglob("*.py"))}
    imports = []
    for mod, path in modules.items():
        is_pkg = path.name == "__init__.py"
        pkg = mod if is_pkg else mod.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.split(".")[0] == package:
                        imports.append(Import(mod, a.name, None, node.lineno))
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")
                    base = base[:len(base) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                if target.split(".")[0] != package:
                    continue
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    if sub in modules:  # `from package import module`
                        imports.append(Import(mod, sub, None, node.lineno))
                    else:
                        imports.append(Import(mod, target, a.name, node.lineno))
    return modules, imports


def allowed(layer: Layer, layers: list[Layer]) -> set[str]:
    """The layers ``layer`` may import: those below it in the table, transitively."""
    by_name = {x.name: x for x in layers}
    out: set[str] = set()
    todo = list(layer.may_import)
    while todo:
        name = todo.pop()
        if name not in out:
            out.add(name)
            todo.extend(by_name[name].may_import)
    return out


def layer_of(module: str, layers: list[Layer]) -> Layer | None:
    best, length = None, -1
    for layer in layers:
        for p in layer.prefixes:
            if p.endswith(".__init__"):
                hit = module == p[:-len(".__init__")]
            else:
                hit = module == p or module.startswith(p + ".")
            if hit and len(p) > length:
                best, length = layer, len(p)
    return best


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    counter = 0
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, it = work[-1]
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = []
                    while True:
                        w = stack.pop()
                        on_stack.discard(w)
                        comp.append(w)
                        if w == v:
                            break
                    if len(comp) > 1:
                        out.append(sorted(comp))
    return out


def check_tree(src_root: Path, package: str, layers: list[Layer],
               folders_under: str | None = None) -> list[str]:
    """Every violation of rules (a)-(d) in ``package`` under ``src_root``, one line each
    (``file:line: what``).  Rule (c) applies to the folders under ``folders_under``."""
    modules, imports = collect(src_root, package)
    problems = []

    def where(imp: Import) -> str:
        return f"{modules[imp.source].relative_to(src_root)}:{imp.line}"

    for mod in modules:
        if layer_of(mod, layers) is None:
            problems.append(f"{modules[mod].relative_to(src_root)}: module {mod} is in no layer")
    graph: dict[str, set[str]] = {m: set() for m in modules}
    for imp in imports:
        if imp.target not in modules:
            continue  # a name of a module outside the tree walked (or a typo mypy finds)
        if imp.target != imp.source:
            graph[imp.source].add(imp.target)
        src, dst = layer_of(imp.source, layers), layer_of(imp.target, layers)
        if src is not None and dst is not None and src is not dst \
                and dst.name not in allowed(src, layers):
            problems.append(f"{where(imp)}: layer {src.name} ({imp.source}) imports layer "
                            f"{dst.name} ({imp.target})")
        if imp.name is not None and imp.name.startswith("_") \
                and not (imp.name.startswith("__") and imp.name.endswith("__")) \
                and imp.target != imp.source:
            problems.append(f"{where(imp)}: private name {imp.name} imported from "
                            f"{imp.target}")
    for comp in _cycles(graph):
        names = {layer_of(m, layers).name for m in comp if layer_of(m, layers)}
        if len(names) > 1:
            problems.append(f"import cycle across layers {sorted(names)}: {' -> '.join(comp)}")
    if folders_under is not None:
        base = src_root / folders_under
        for folder in sorted([base, *(p for p in base.rglob("*") if p.is_dir())]):
            mods = [p for p in folder.glob("*.py") if p.name != "__init__.py"]
            if len(mods) > MAX_MODULES:
                problems.append(f"{folder.relative_to(src_root)}: {len(mods)} modules "
                                f"(at most {MAX_MODULES})")
    return problems


# -- the real tree ------------------------------------------------------------------------
#: violations not fixed yet (without line numbers); this list only shrinks: an entry that is
#: no longer found fails test_known_violations_are_still_there (remove it then).
KNOWN: set[str] = set()


def _real_tree_problems() -> list[str]:
    layers = parse_layers(DOC.read_text(encoding="utf-8"))
    found = check_tree(ROOT, "controller", layers, folders_under="controller/canopen")
    return [re.sub(r"^([^:]+):\d+:", r"\1:", p) for p in found]


def test_controller_follows_the_layers_of_docs_architecture():
    assert [p for p in _real_tree_problems() if p not in KNOWN] == []


def test_known_violations_are_still_there():
    assert KNOWN - set(_real_tree_problems()) == set()


def test_every_documented_module_prefix_exists():
    """The table names nothing that is not there (a rename updates docs/architecture.md)."""
    modules, _ = collect(ROOT, "controller")
    for layer in parse_layers(DOC.read_text(encoding="utf-8")):
        for p in layer.prefixes:
            p = p.removesuffix(".__init__")
            assert any(m == p or m.startswith(p + ".") for m in modules), (layer.name, p)


def test_the_documented_layers_form_no_cycle():
    layers = parse_layers(DOC.read_text(encoding="utf-8"))
    graph = {layer.name: set(layer.may_import) for layer in layers}
    assert _cycles(graph) == []


# -- planted violations -------------------------------------------------------------------
TABLE = """
<!-- layers -->
| layer | modules | may import |
|---|---|---|
| base | `pkg.__init__`, `pkg.errors` | - |
| low | `pkg.low` | base |
| high | `pkg.high` | low |
<!-- /layers -->
"""


def _tree(tmp_path: Path, files: dict[str, str]) -> Path:
    for name, text in {"pkg/__init__.py": "", "pkg/errors.py": "class E(Exception): ...\n",
                       "pkg/low/__init__.py": "", "pkg/high/__init__.py": "",
                       "pkg/low/a.py": "from ..errors import E\n",
                       "pkg/high/b.py": "from ..low.a import E\n", **files}.items():
        p = tmp_path / name
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return tmp_path


def _check(tmp_path: Path, files: dict[str, str]) -> list[str]:
    return check_tree(_tree(tmp_path, files), "pkg", parse_layers(TABLE), folders_under="pkg")


def test_a_clean_synthetic_tree_passes(tmp_path):
    assert _check(tmp_path, {}) == []


def test_an_upward_import_in_a_function_is_found(tmp_path):
    problems = _check(tmp_path, {"pkg/low/c.py": "def f():\n    from ..high import b\n"})
    assert problems == ["pkg/low/c.py:2: layer low (pkg.low.c) imports layer high (pkg.high.b)"]


def test_an_upward_type_only_import_is_found(tmp_path):
    problems = _check(tmp_path, {"pkg/low/c.py": "from typing import TYPE_CHECKING\n"
                                                 "if TYPE_CHECKING:\n"
                                                 "    from pkg.high.b import E\n"})
    assert problems == ["pkg/low/c.py:3: layer low (pkg.low.c) imports layer high (pkg.high.b)"]


def test_a_cycle_across_layers_is_found_even_if_the_table_allowed_it(tmp_path):
    table = TABLE.replace("| low | `pkg.low` | base |", "| low | `pkg.low` | base, high |")
    # (the table itself now has a cycle low <-> high: test_the_documented_layers_form_no_cycle)
    root = _tree(tmp_path, {"pkg/low/c.py": "from ..high import b\n",
                            "pkg/high/b.py": "from ..low import c\n"})
    problems = check_tree(root, "pkg", parse_layers(table))
    assert problems == ["import cycle across layers ['high', 'low']: pkg.high.b -> pkg.low.c"]


def test_a_cycle_inside_a_layer_is_allowed(tmp_path):
    assert _check(tmp_path, {"pkg/low/c.py": "from . import d\n",
                             "pkg/low/d.py": "from . import c\n"}) == []


def test_a_folder_with_too_many_modules_is_found(tmp_path):
    files = {f"pkg/low/m{i}.py": "" for i in range(MAX_MODULES)}  # + a.py = 13
    assert _check(tmp_path, files) == [f"pkg/low: {MAX_MODULES + 1} modules (at most "
                                       f"{MAX_MODULES})"]


def test_a_private_import_is_found_but_not_a_dunder(tmp_path):
    problems = _check(tmp_path, {"pkg/low/c.py": "from .a import _helper\n"
                                                 "from pkg import __version__\n"})
    assert problems == ["pkg/low/c.py:1: private name _helper imported from pkg.low.a"]


def test_an_import_two_layers_down_is_allowed_but_not_one_up(tmp_path):
    assert _check(tmp_path, {"pkg/high/c.py": "from pkg.errors import E\n"}) == []
    assert _check(tmp_path, {"pkg/__init__.py": "from pkg.low import a\n"}) == [
        "pkg/__init__.py:1: layer base (pkg) imports layer low (pkg.low.a)"]


def test_a_module_in_no_layer_is_found(tmp_path):
    assert _check(tmp_path, {"pkg/other.py": ""}) == ["pkg/other.py: module pkg.other is in no "
                                                      "layer"]


def test_a_table_naming_an_unknown_layer_is_refused():
    with pytest.raises(ValueError, match="unknown layers"):
        parse_layers(TABLE.replace("| high | `pkg.high` | low |", "| high | `pkg.high` | lwo |"))
