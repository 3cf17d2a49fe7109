"""controller.tracking.values: fast_init (the same value objects as the dataclass' own
__init__), trusted (the same without __post_init__), integer / boolean (the int and bool
fields as passed), restore."""

from __future__ import annotations

import dataclasses
import inspect
import pickle

import pytest

from controller.errors import ParameterError
from controller.tracking import MasterEstimate, MotionState, TrackerOutput
from controller.tracking.types import motion_state
from controller.tracking.values import boolean, fast_init, integer, restore, trusted


@dataclasses.dataclass(frozen=True, slots=True)
class Plain:
    a: float
    b: tuple[float, ...] = (1.0, 2.0)
    c: int = 3


Fast = fast_init(dataclasses.make_dataclass(
    "Fast", [("a", float), ("b", tuple, dataclasses.field(default=(1.0, 2.0))),
             ("c", int, dataclasses.field(default=3))], frozen=True, slots=True))


def test_same_signature_values_and_defaults():
    assert list(inspect.signature(Fast.__init__).parameters) == ["self", "a", "b", "c"]
    for args, kw in [((0.5,), {}), ((0.5, (3.0,)), {}), ((0.5,), {"c": 7}),
                     ((), {"a": -1.0, "b": (), "c": 0})]:
        p, f = Plain(*args, **kw), Fast(*args, **kw)
        assert dataclasses.astuple(p) == dataclasses.astuple(f)
    with pytest.raises(TypeError):
        Fast()  # a required field stays required
    with pytest.raises(TypeError):
        Fast(1.0, d=2)


def test_still_frozen_equal_hashable_replaceable_picklable():
    m = MotionState((1.0, 2.0, 3.0), ang=4.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        m.ang = 5.0  # type: ignore[misc]
    assert m == MotionState((1.0, 2.0, 3.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 4.0)
    assert hash(m) == hash(MotionState((1.0, 2.0, 3.0), ang=4.0))
    assert dataclasses.replace(m, ang=6.0).ang == 6.0
    assert pickle.loads(pickle.dumps(m)) == m
    assert MasterEstimate(1.0, 2.0, 3.0).jerk == 0.0
    assert TrackerOutput(m, *[None] * 4).synchronized_now is False  # type: ignore[arg-type]


def test_post_init_runs():
    seen = []

    @fast_init
    @dataclasses.dataclass(frozen=True, slots=True)
    class Checked:
        x: float

        def __post_init__(self) -> None:
            seen.append(self.x)
            if self.x < 0:
                raise ValueError("negative")

    Checked(2.0)
    with pytest.raises(ValueError, match="negative"):
        Checked(-1.0)
    assert seen == [2.0, -1.0]


@pytest.mark.parametrize("make", [
    lambda: dataclasses.dataclass(slots=True)(type("NotFrozen", (), {"__annotations__": {"x": int}})),
    lambda: dataclasses.dataclass(frozen=True)(type("NoSlots", (), {"__annotations__": {"x": int}})),
    lambda: dataclasses.make_dataclass("Factory", [("x", list, dataclasses.field(
        default_factory=list))], frozen=True, slots=True),
    lambda: dataclasses.make_dataclass("KwOnly", [("x", int, dataclasses.field(kw_only=True))],
                                       frozen=True, slots=True),
])
def test_refused_where_it_would_differ(make):
    with pytest.raises(TypeError, match="fast_init"):
        fast_init(make())
    with pytest.raises(TypeError, match="trusted"):
        trusted(make(), "make")


def test_trusted_same_values_without_post_init():
    seen = []

    @dataclasses.dataclass(frozen=True, slots=True)
    class Checked:
        x: float
        y: tuple[float, ...] = (1.0,)

        def __post_init__(self) -> None:
            seen.append(self.x)
            if self.x < 0:
                raise ValueError("negative")

    make = trusted(Checked, "make")
    assert make(2.0) == Checked(2.0) and make(2.0, (3.0,)) == Checked(2.0, (3.0,))
    assert make(y=(), x=1.0) == Checked(1.0, ())
    seen.clear()
    assert make(-1.0).x == -1.0 and seen == []  # not validated
    with pytest.raises(dataclasses.FrozenInstanceError):
        make(1.0).x = 2.0  # type: ignore[misc]
    with pytest.raises(TypeError):
        make()  # a required field stays required


def test_motion_state_as_given():
    args = ((1.0, 2.0, 3.0), (4.0, 5.0, 6.0), (0.5, 0.0, -0.5), 7.0, 8.0, 9.0)
    m = motion_state(*args)
    assert type(m) is MotionState and m == MotionState(*args)
    assert dataclasses.astuple(m) == dataclasses.astuple(MotionState(*args))
    assert m.jerk == (0.0, 0.0, 0.0) and m.ang_jerk == 0.0
    assert pickle.loads(pickle.dumps(m)) == m
    assert pickle.loads(pickle.dumps(motion_state)) is motion_state
    pos = [1.0, 2.0, 3.0]  # (MotionState would convert it: the trusted one does not)
    assert motion_state(pos, *args[1:]).pos is pos
    assert type(MotionState(pos).pos) is tuple


@dataclasses.dataclass(frozen=True)
class _Fields:
    n: object = 0
    flag: object = 0
    other: object = 1


@pytest.mark.parametrize("value, low, high, want", [
    (6, 1, None, 6), (6.0, 1, None, 6), (1.0, 1, None, 1), (0, 0, 100, 0), (100.0, 0, 100, 100),
    (6.5, 1, None, "must be an integer >= 1"), (0, 1, None, "must be an integer >= 1"),
    (-1, 0, 100, r"must be an integer in \[0...100\]"),
    (100.5, 0, 100, r"must be an integer in \[0...100\]"),
    (101, 0, 100, r"must be an integer in \[0...100\]")])
def test_integer(value, low, high, want):
    f = _Fields(n=value)
    if isinstance(want, str):
        with pytest.raises(ParameterError, match=f"n \\(={value!r}\\) {want}"):
            integer(f, "n", low, high)
    else:
        integer(f, "n", low, high)
        assert f.n == want and type(f.n) is int


def test_boolean():
    f = _Fields(flag=1, other=0)
    boolean(f, "flag", "other")
    assert f.flag is True and f.other is False


def test_restore():
    class Box:
        pass

    b = Box()
    restore(b, {"a": 1, "b": [2]})
    assert (b.a, b.b) == (1, [2])  # type: ignore[attr-defined]
