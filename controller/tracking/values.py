"""Frozen value types that are cheap to make: :func:`fast_init`.

A ``@dataclass(frozen=True)`` ``__init__`` sets every field through ``object.__setattr__``
(the frozen class's own ``__setattr__`` refuses), a generic attribute lookup per field: a
``MotionState`` of 8 fields costs about 3x what the same slots cost set directly, and the
cycle makes several value objects per sample (states, estimates, tracker outputs).
:func:`fast_init` gives a frozen *slots* dataclass an ``__init__`` with the same parameters,
defaults and ``__post_init__`` call that sets each slot through its slot descriptor; the class
stays the dataclass it was (fields, ``replace``, equality, hash, pickling, frozen against
assignment).  What dataclasses itself offers does not help here: without ``frozen`` the
values could be changed, and ``__slots__`` alone does not change how ``__init__`` sets them.
"""

from __future__ import annotations

import dataclasses
import inspect
import types
from typing import Any, Callable, TypeVar

from ..errors import ParameterError

T = TypeVar("T")

try:
    from mypy_extensions import mypyc_attr
except ImportError:  # (without mypy: the pure source, e.g. bundled in an FMU; only mypyc reads it)
    def mypyc_attr(*attrs: str, **kwattrs: Any) -> Callable[[T], T]:  # type: ignore[misc]
        return lambda x: x


def as_stored(obj: object) -> Any:
    """``obj`` typed ``Any``: its attributes read as they are stored.  For the validators in
    ``__post_init__``, which see what the caller passed before converting or refusing it (an
    ``int`` for a ``Mode`` field, ``1.5`` for an ``int`` one): compiled code checks a read of
    a typed field against its annotation (and turns an ``int`` read as ``float`` into a
    float), reads through ``Any`` are Python's (docs/architecture.md "Compiled core")."""
    return obj


def attributes(obj: object) -> dict[str, Any]:
    """The instance attributes of ``obj`` by name, for ``__getstate__``: its ``__dict__``
    (a copy) in the pure source; the attributes a compiled class lists in
    ``__mypyc_attrs__`` (it has no ``__dict__``) that are set, and the ``__dict__`` of a
    Python subclass of it.  ``__setstate__`` sets them
    back with ``setattr``, which works for both."""
    names = [n for klass in type(obj).__mro__ for n in getattr(klass, "__mypyc_attrs__", ())]
    state = {n: getattr(obj, n) for n in dict.fromkeys(names)
             if not n.startswith("__") and hasattr(obj, n)}
    # (a Python subclass of a compiled class has both)
    state.update(getattr(obj, "__dict__", {}))
    return state


def python_class(cls: type[T]) -> type[T]:
    """Mark ``cls`` as a plain Python class for the compiled core (docs/architecture.md
    "Compiled core"): mypyc compiles its methods but keeps the class itself a Python class,
    so it behaves exactly as in the pure source: a frozen dataclass copies and pickles as
    usual, and its fields take what ``__post_init__`` converts and validates (an ``int``
    for a ``Mode``, ``6.0`` for an ``int``) without mypyc's type checks on assignment.  For
    the parameter and event values, made rarely.  (mypyc makes any class with a decorator it
    does not know a Python class; this one returns ``cls`` unchanged.)"""
    return cls


def _plain_fields(cls: type[Any], who: str) -> list[dataclasses.Field]:
    """The fields of the frozen slots dataclass ``cls``; a TypeError naming ``who`` (the
    generator) unless each is a plain field (no ``default_factory``, ``init=False``,
    keyword-only or ``InitVar``: the generated code covers plain fields only)."""
    params = getattr(cls, "__dataclass_params__", None)
    if params is None or not params.frozen or "__slots__" not in cls.__dict__:
        raise TypeError(f"{who}: {cls.__name__} is not a frozen slots dataclass")
    fields = list(dataclasses.fields(cls))
    for f in fields:
        if not f.init or f.kw_only or f.default_factory is not dataclasses.MISSING:
            raise TypeError(f"{who}: {cls.__name__}.{f.name} is not a plain field")
    if list(inspect.signature(cls.__init__).parameters)[1:] != [f.name for f in fields]:
        raise TypeError(f"{who}: {cls.__name__}.__init__ takes more than its fields")
    return fields


def _generate(cls: type[Any], fields: list[dataclasses.Field], head: str, tail: list[str],
              ns: dict[str, object]) -> types.FunctionType:
    """A function ``head(<the fields, with their defaults>)`` that sets each slot of
    ``self`` through its slot descriptor, then runs the lines ``tail``."""
    args: list[str] = []
    body: list[str] = []
    for f in fields:
        if f.default is dataclasses.MISSING:
            args.append(f.name)
        else:
            ns[f"_d_{f.name}"] = f.default
            args.append(f"{f.name}=_d_{f.name}")
        ns[f"_s_{f.name}"] = cls.__dict__[f.name].__set__
        body.append(f"    _s_{f.name}(self, {f.name})")
    src = head.format(", ".join(args)) + "\n" + "\n".join(body + tail or ["    pass"])
    exec(src, ns)  # noqa: S102 -- generated from the field names, as dataclasses does
    func = ns["_generated"]
    assert isinstance(func, types.FunctionType)  # (what exec defined)
    return func


def fast_init(cls: type[T]) -> type[T]:
    """Replace the ``__init__`` of the frozen slots dataclass ``cls`` (see the module
    docstring).  Fields with a ``default_factory``, ``init=False``, keyword-only fields and
    ``InitVar`` pseudo-fields are refused (the generated code covers plain fields only)."""
    fields = _plain_fields(cls, "fast_init")
    tail = ["    self.__post_init__()"] if hasattr(cls, "__post_init__") else []
    init = _generate(cls, fields, "def _generated(self, {}) -> None:", tail, {})
    init.__name__ = "__init__"
    init.__qualname__ = f"{cls.__qualname__}.__init__"
    init.__doc__ = cls.__init__.__doc__
    setattr(cls, "__init__", init)  # noqa: B010 -- (mypy: no method assignment)
    return cls


def trusted(cls: type[T], name: str) -> Callable[..., T]:
    """A constructor of the frozen slots dataclass ``cls`` (same parameters and defaults as
    its ``__init__``) that stores the values *as given*: no ``__post_init__``, so no
    conversion and no validation.  For the tracking core's own values, made per sample from
    values it computed (Python floats, or the fields of a value that was validated when it
    was made); never for what a caller passes.  ``name``: the function's name as its module
    exports it (for its repr)."""
    fields = _plain_fields(cls, "trusted")
    make = _generate(cls, fields, "def _generated({}):\n    self = _new(_cls)",
                     ["    return self"], {"_new": object.__new__, "_cls": cls})
    make.__name__ = make.__qualname__ = name
    make.__module__ = cls.__module__
    return make


def integer(obj: object, name: str, low: int, high: int | None = None) -> None:
    """Store the field ``name`` of the frozen ``obj``, read as passed (:func:`as_stored`), as
    the ``int`` it equals (``6.0`` -> ``6``: compiled code reads the field by its ``int``
    annotation, docs/architecture.md "Compiled core"); a ParameterError naming the field
    and its value unless it is an integer in [low...high] (``high`` None: >= low)."""
    value = getattr(obj, name)
    if int(value) != value or value < low or (high is not None and value > high):
        allowed = f"in [{low}...{high}]" if high is not None else f">= {low}"
        raise ParameterError(f"{name} (={value!r}) must be an integer {allowed}")
    object.__setattr__(obj, name, int(value))


def boolean(obj: object, *names: str) -> None:
    """Store the fields ``names`` of the frozen ``obj``, read as passed, as the ``bool`` each
    means in an ``if`` (0 and 1 as False and True: compiled code reads the fields by their
    ``bool`` annotations, docs/architecture.md "Compiled core")."""
    for name in names:
        object.__setattr__(obj, name, bool(getattr(obj, name)))


def restore(obj: object, state: dict[str, Any]) -> None:
    """``__setstate__`` of a class whose ``__getstate__`` is :func:`attributes`: set each
    attribute of ``state`` back with ``setattr`` (compiled and pure, and a Python subclass's
    own attributes)."""
    for name, value in state.items():
        setattr(obj, name, value)


__all__ = ["as_stored", "attributes", "boolean", "fast_init", "integer", "mypyc_attr",
           "python_class", "restore", "trusted"]
