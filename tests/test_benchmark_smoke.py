"""Smoke test of benchmarks/tracking.py: a few cases through main(); sane figures, no timing."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from controller.tracking.planner import PLANNERS  # noqa: E402

bench = pytest.importorskip("benchmarks.tracking")


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    # main() registers the reference planner; undo that afterwards so the registry other
    # tests see is unchanged
    mp = pytest.MonkeyPatch()
    mp.setitem(PLANNERS, "reference", bench.REFERENCE_TARGET)
    out = tmp_path_factory.mktemp("bench")
    try:
        res = bench.main(["--quick", "--cases", "6", "--jobs", "1", "--seed", "3",
                          "--json", str(out / "b.json"), "--markdown", str(out / "b.md")])
    finally:
        mp.undo()
    res["_dir"] = out
    return res


def test_writes_table_and_json(result):
    md = (result["_dir"] / "b.md").read_text(encoding="utf-8")
    assert md.startswith("### Tracking benchmark")
    assert "| figure | softmc | optimal | reference | target | result |" in md
    assert "synchronised within 2 s" in md
    assert "Regression scenarios" in md
    data = json.loads((result["_dir"] / "b.json").read_text(encoding="utf-8"))
    assert data["meta"]["random_cases"] == 6
    assert data["meta"]["regression_cases"] == len(bench.regression_cases())
    n_cases = 6 + len(bench.regression_cases())
    assert len(data["runs"]) == n_cases * len(data["meta"]["planners"])
    if "optimal" not in data["meta"]["planners"]:
        assert "not available" in md


def test_reference_is_its_own_yardstick(result):
    ref = result["figures"]["reference"]
    assert ref["success_rate"] == 1.0
    for key in ("ratio_1d_median", "ratio_1d_p90", "ratio_1d_max",
                "ratio_3d_median", "ratio_3d_p90"):
        assert ref[key] == 1.0, key
    assert ref["ruckig_failures"] == 0
    # per-axis limits: the vector norm may reach sqrt(3) in 3-D, not more
    assert ref["norm_worst_ratio_3d"] <= math.sqrt(3.0) * (1 + 1e-6)
    assert ref["axis_worst_ratio_3d"] <= 1.05
    assert ref["norm_worst_ratio_1d"] <= 1.05


def test_figures_are_sane(result):
    figs = result["figures"]
    assert "softmc" in figs and "reference" in figs
    for name, f in figs.items():
        assert 0.0 <= f["success_rate"] <= 1.0, name
        assert f["runs"] == 6 + len(bench.regression_cases())
        for key in ("ratio_1d_median", "ratio_3d_median"):
            assert f[key] is not None and f[key] > 0.0, (name, key)
        assert 0 <= f["oscillating_runs"] <= f["runs"]
        for tol in bench.TOLS:
            for ph in bench.CHECK_PHASES:
                assert 0 <= f[f"viol_{tol:g}_{ph}_runs"] <= f["runs"]
    # the softmc switch spike is there (take-the-middle, docs/spec/tracking.md#3.8)
    assert figs["softmc"]["switch_jerk_max"] > 1.0
    for target in result["targets"]:
        assert target["result"] in (None, True, False)


def test_cases_are_deterministic():
    a, ra = bench.random_cases(5, 8)
    b, rb = bench.random_cases(5, 8)
    assert a == b and ra == rb
    assert [c.dim for c in a] == [1, 3] * 4


def test_encoder_timing_against_a_baseline_checkout(tmp_path):
    """benchmarks/encoder.py --baseline: another checkout's update is timed in a child
    process on the same cases (here this tree as its own baseline: the child must import
    the checkout's controller, the cases' digest must match), on the ideal master and on the
    same encoder stream through its MasterEstimator, interleaved with this tree's; both
    ratios are targets; a directory that is not a checkout is refused by name."""
    enc = pytest.importorskip("benchmarks.encoder")
    res = enc.timing(bench.timing_cases, 1, 1, baseline=ROOT, rounds=1)
    assert [m for m, _ in res["rounds"]] == ["ideal", "conditioned", "baseline",
                                             "baseline_encoder"]
    assert res["baseline"] > 0.0 and res["ratio_baseline"] == pytest.approx(
        res["conditioned"] / res["baseline"])
    assert res["baseline_encoder"] > 0.0 and res["ratio_baseline_encoder"] == pytest.approx(
        res["conditioned"] / res["baseline_encoder"])
    assert res["baseline_path"] == str(ROOT)
    rows = enc.cost_target({"timing": res})
    assert [r[0].rsplit("(", 1)[1] for r in rows] == [
        "the baseline's update on the same encoder stream through its MasterEstimator)",
        "the baseline's update on the ideal master)"]
    assert [r[1] for r in rows] == [f"{res['ratio_baseline_encoder']:.2f}",
                                    f"{res['ratio_baseline']:.2f}"]
    with pytest.raises(SystemExit, match="not a cantrack checkout"):
        enc.timing(bench.timing_cases, 1, 1, baseline=tmp_path, rounds=1)


def test_encoder_seeds_matches_the_encoder_benchmark(capsys):
    """benchmarks/encoder_seeds.py: per seed the kept design's figures of
    benchmarks/encoder.py for the same belts (one cell, two seeds, one belt per cell), the
    table with the count of seeds over the bounds; bad --seeds / --cells are refused by
    name."""
    enc = pytest.importorskip("benchmarks.encoder")
    seeds_mod = pytest.importorskip("benchmarks.encoder_seeds")
    fig = seeds_mod.main(["--seeds", "1-2", "--cells", "50um:2ms", "--belts", "1"])
    for i, seed in enumerate((1, 2)):
        cases = [c for c in enc.belt_cases(seed, 1) if (c.count_mm, c.T) == (0.05, 0.002)]
        f = enc.summarize([enc.run_belt(c, enc.KEPT) for c in cases])[(0.05, 0.002, enc.KEPT)]
        assert fig[(0.05, 0.002)]["jmax"][i] == f["err_change_jmax_p99"]
        assert fig[(0.05, 0.002)]["const"][i] == f["err_const"][1]
    out = capsys.readouterr().out
    jm = fig[(0.05, 0.002)]["jmax"]
    assert f"| {sum(x > 0.1 for x in jm)} of 2 |" in out
    assert seeds_mod._seeds("1-3,7") == [1, 2, 3, 7]
    with pytest.raises(SystemExit, match="--seeds: 'x' is not a seed"):
        seeds_mod._seeds("x")
    with pytest.raises(SystemExit, match="--cells: '5um:2ms' is not a cell"):
        seeds_mod._cells("5um:2ms")
