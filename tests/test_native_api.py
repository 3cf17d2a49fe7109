"""The public API of the tracking core takes the same values compiled and pure
(docs/architecture.md "Compiled core").

These tests run in whichever mode is installed (CI: compiled; ``PYTHONPATH=$PWD`` or
``CANTRACK_PURE=1``: the Python source) and assert what the Python source does: integral floats
for the int fields, 0/1 for the bool fields, ints for the enum arguments, lists and numpy
arrays for the vectors, numpy scalars for the encoder position.  Compiled code checks each
read of a typed field or argument against its annotation, so these values must be converted
where they enter (``__post_init__``, the method), not where they are used.
"""

from __future__ import annotations

import numpy as np
import pytest

from controller.limits import Limits
from controller.tracking import (MotionState, SoftMcOptions, TrackError, Tracker, TrackerParams,
                                 TrackState)
from controller.tracking.conditioning import (ConditioningParams, EncoderModel,
                                              MasterConditioner)
from controller.tracking.types import _SOFTMC_SWITCHES

T = 0.002


def _belt(k: int) -> MotionState:
    """The master at sample k: 300 mm/s along x."""
    return MotionState((300.0 * k * T, 0.0, 0.0), (300.0, 0.0, 0.0))


def _run(params: TrackerParams, n: int = 50, master=_belt, mode=None,
         init: MotionState | None = None) -> tuple[tuple[float, float, float], TrackState]:
    t = Tracker(params, init or MotionState.at(100.0, -50.0, 0.0))
    t.engage(mode)
    out = None
    for k in range(1, n):
        out = t.update(master(k))
    assert out is not None
    return out.setpoint.pos, out.state


@pytest.mark.parametrize("planner", ["optimal", "softmc"])
def test_max_flops_as_an_integral_float(planner: str) -> None:
    params = TrackerParams(sample_time_s=T, planner=planner)
    for p in (TrackerParams(sample_time_s=T, planner=planner, max_flops=6.0),
              params.with_(max_flops=6.0)):
        assert p.max_flops == 6 and type(p.max_flops) is int
        assert _run(p) == _run(params)


def test_conditioner_int_fields_as_integral_floats() -> None:
    enc = EncoderModel(latency_samples=1.0)
    assert type(enc.latency_samples) is int and enc.latency_samples == 1
    p = ConditioningParams(sample_time_s=T, encoder=enc, warmup_samples=20.0,
                           max_outliers=10.0)
    assert type(p.warmup_samples) is int and p.warmup_samples == 20
    assert type(p.max_outliers) is int and p.max_outliers == 10
    ref = ConditioningParams(sample_time_s=T, warmup_samples=20)
    a, b = MasterConditioner(p), MasterConditioner(ref)
    for k in range(60):
        assert a.update(300.0 * k * T) == b.update(300.0 * k * T)


@pytest.mark.parametrize("bad", [{"max_flops": 6.5}, {"max_flops": 0}])
def test_max_flops_still_refused(bad: dict) -> None:
    with pytest.raises(ValueError, match="max_flops"):
        TrackerParams(sample_time_s=T, **bad)


def test_desync_flag_as_0() -> None:
    """0 for the bool field: the de-sync from zero acceleration, as with False (the field is
    read at the first update after disengage)."""
    p0 = TrackerParams(sample_time_s=T, desync_from_current_acceleration=0)
    assert p0.desync_from_current_acceleration is False
    pf = TrackerParams(sample_time_s=T, desync_from_current_acceleration=False)
    results = []
    for p in (p0, pf):
        t = Tracker(p, MotionState.at(100.0, -50.0, 0.0))
        t.engage()
        trace = [t.update(_belt(k)) for k in range(1, 300)]
        t.disengage()
        trace += [t.update(_belt(k)) for k in range(300, 600)]
        results.append([(o.setpoint, o.state) for o in trace])
    assert results[0] == results[1]
    assert results[0][-1][1] == TrackState.OFF


@pytest.mark.parametrize("name", _SOFTMC_SWITCHES)
def test_softmc_switch_as_int(name: str) -> None:
    default = getattr(SoftMcOptions(), name)
    opts = SoftMcOptions(**{name: int(default)})
    assert getattr(opts, name) is default
    flipped = SoftMcOptions(**{name: int(not default)})
    assert getattr(flipped, name) is (not default)
    for o in (opts, flipped):
        ref = SoftMcOptions(**{name: bool(getattr(o, name))})
        p = TrackerParams(sample_time_s=T, planner="softmc", softmc=o)
        pr = TrackerParams(sample_time_s=T, planner="softmc", softmc=ref)
        assert _run(p, n=200) == _run(pr, n=200)


def test_disengage_with_an_int_error() -> None:
    t = Tracker(TrackerParams(sample_time_s=T))
    t.engage()
    for k in range(1, 30):
        t.update(_belt(k))
    t.disengage(6)
    out = t.update(_belt(30))
    assert out.error is TrackError.MASTER_LOST


@pytest.mark.parametrize("mode", [np.int64(3), np.int64(5), 5])
def test_engage_with_a_numpy_int(mode) -> None:
    p = TrackerParams(sample_time_s=T)
    assert _run(p, mode=mode) == _run(p, mode=int(mode))


@pytest.mark.parametrize("planner", ["optimal", "softmc"])
@pytest.mark.parametrize("kind", ["list", "array", "numpy-tuple", "float32-tuple"])
def test_vectors_as_lists_and_arrays(planner: str, kind: str) -> None:
    conv = {"list": list, "array": np.array,
            "numpy-tuple": lambda v: tuple(np.array(v)),
            "float32-tuple": lambda v: tuple(np.array(v, dtype=np.float32))}[kind]
    p = TrackerParams(sample_time_s=T, planner=planner)

    def master(k: int) -> MotionState:
        s = _belt(k)
        return MotionState(conv(s.pos), conv(s.vel), conv(s.acc), jerk=conv(s.jerk))

    def plain(k: int) -> MotionState:  # the same numbers as Python floats
        s = _belt(k)
        f = lambda v: tuple(float(x) for x in conv(v))  # noqa: E731
        return MotionState(f(s.pos), f(s.vel), f(s.acc), jerk=f(s.jerk))

    m = master(3)
    for v in (m.pos, m.vel, m.acc, m.jerk):
        assert type(v) is tuple and all(type(x) is float for x in v)
    assert m == plain(3)
    init = MotionState(conv([100.0, -50.0, 0.0]))
    assert _run(p, master=master, init=init) == _run(p, master=plain)


@pytest.mark.parametrize("planner, options", [("optimal", SoftMcOptions()),
                                              ("softmc", SoftMcOptions()),
                                              ("softmc", SoftMcOptions.literal())])
@pytest.mark.parametrize("follow", [0, 1])
def test_setpoint_vectors_are_floats_with_numpy_limits(planner, options, follow) -> None:
    """Limits given as numpy floats (numbers, accepted): the setpoints' vectors are Python
    floats in every phase, compiled and pure.  The softmc planner's clamps carry the numpy
    scalars into its vectors, which the tracker converts (``MotionState``); the optimal
    planner's and the SYNCED follower's are Python floats, stored as given
    (``types.motion_state``)."""
    f = np.float64
    p = TrackerParams(sample_time_s=T, planner=planner, synced_follow=follow, softmc=options,
                      sync_trans=Limits(f(500.0), f(2000.0), f(40000.0)))
    t = Tracker(p, MotionState((100.0, -50.0, 0.0), (-200.0, 0.0, 0.0)))
    t.engage()
    seen = set()
    for k in range(1, 900):
        if k == 600:
            t.disengage()
        out = t.update(_belt(k))
        seen.add(out.state)
        sp = out.setpoint
        assert all(type(x) is float for x in sp.pos + sp.vel + sp.acc), (k, out)
    assert {TrackState.SYNCING, TrackState.SYNCED, TrackState.DESYNCING} <= seen


@pytest.mark.parametrize("bad", [[1.0, 2.0], (1.0, 2.0, 3.0, 4.0), "abc", 5.0])
def test_vectors_of_the_wrong_shape_refused(bad) -> None:
    with pytest.raises(ValueError, match="MotionState pos"):
        MotionState(bad)


def test_vectors_of_python_numbers_kept_as_given() -> None:
    p = (1, 2.0, 3)
    assert MotionState(p).pos is p


@pytest.mark.parametrize("scalar", [np.float64, np.float32, np.int64])
def test_conditioner_numpy_positions(scalar) -> None:
    p = ConditioningParams(sample_time_s=T, warmup_samples=20)
    a, b = MasterConditioner(p), MasterConditioner(p)
    for k in range(60):
        x = scalar(round(300.0 * k * T)) if scalar is np.int64 else scalar(300.0 * k * T)
        got, want = a.update(x), b.update(float(x))
        assert got == want
        assert type(got.pos) is float


def test_limits_still_accepted_as_ints() -> None:
    p = TrackerParams(sample_time_s=T, sync_trans=Limits(2000, 20000, 200000))
    assert _run(p)[1] in (TrackState.SYNCING, TrackState.SYNCED)


# -- the stale build guard (controller/tracking/__init__.py: pure Python in both modes) --------

@pytest.mark.parametrize("value, on", [("", False), ("0", False), ("false", False),
                                       ("No", False), (" OFF ", False), ("FALSE", False),
                                       ("1", True), ("yes", True), ("true", True)])
def test_env_flags_are_booleans(monkeypatch, value: str, on: bool) -> None:
    import controller.tracking as ct
    monkeypatch.setenv("CANTRACK_PURE", value)
    assert ct._flag("CANTRACK_PURE") is on


def _fake_build(tmp_path, sources: dict[str, bytes], compiled: list[str]) -> None:
    import hashlib
    import importlib.machinery
    import json
    suffix = importlib.machinery.EXTENSION_SUFFIXES[0]
    for name, text in sources.items():
        (tmp_path / name).write_bytes(text)
    for stem in compiled:
        (tmp_path / (stem + suffix)).write_bytes(b"not loaded")
    (tmp_path / "_native_manifest.json").write_text(json.dumps({"sources": {
        n: hashlib.sha256(t).hexdigest() for n, t in sources.items()}}))


def test_stale_when_the_group_library_is_missing(tmp_path) -> None:
    import controller.tracking as ct
    _fake_build(tmp_path, {"a.py": b"x = 1\n"}, ["a"])
    assert "_core__mypyc" in ct._stale_source(str(tmp_path))


def test_stale_when_a_compiled_module_is_missing(tmp_path) -> None:
    import controller.tracking as ct
    _fake_build(tmp_path, {"a.py": b"x = 1\n", "b.py": b"y = 2\n"}, ["_core__mypyc", "a"])
    stale = ct._stale_source(str(tmp_path))
    assert stale.startswith(str(tmp_path / "b")) and "missing" in stale


def test_not_stale_when_complete(tmp_path) -> None:
    import controller.tracking as ct
    _fake_build(tmp_path, {"a.py": b"x = 1\n"}, ["_core__mypyc", "a"])
    assert ct._stale_source(str(tmp_path)) is None
    (tmp_path / "a.py").unlink()
    assert "missing" in ct._stale_source(str(tmp_path))


def test_pure_finder_refuses_a_compiled_module_without_its_source(tmp_path) -> None:
    import controller.tracking as ct
    _fake_build(tmp_path, {"a.py": b"x = 1\n"}, ["_core__mypyc", "a", "gone"])
    finder = ct._PureFinder("pkg", str(tmp_path))
    assert finder.find_spec("pkg.a").origin == str(tmp_path / "a.py")
    with pytest.raises(ImportError, match="gone"):
        finder.find_spec("pkg.gone")
    assert finder.find_spec("pkg.absent") is None
