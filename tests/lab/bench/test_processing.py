"""Smoke test of the processing bench on a small world: every figure is there (no timed assertion)."""

from __future__ import annotations

import math

from msflash.lab.bench.processing import processing_bench


def test_processing_bench_reports_every_target_with_its_verdict() -> None:
    report = processing_bench(height=48, width=64, repeats=1, pairs=3, sizes=((48, 64), (40, 72)))
    assert set(report["targets"]) == {"64×48", "72×40", "64×48 RGGB", "72×40 RGGB"}  # RGB and raw frames
    for label, figures in report["targets"].items():
        raw = label.endswith("RGGB")
        assert ("raw RGGB, 12-bit" in figures["frames"]) == raw
        for name, target in (
            ("estimate_over_copy", "≤ 1.5" if raw else "≤ 2"),
            ("estimate_all_pixels_over_copy", "≤ 4"),
            ("synthesis_over_copy", "≤ 1.5"),
        ):
            threads = {"1_thread"} if name == "estimate_over_copy" else {"1_thread", "2_threads"}  # one-thread estimate
            assert set(figures[name]) == threads, name
            for figure in figures[name].values():
                assert figure["target"] == target and figure["pairs"] == 3
                assert 0 < figure["min"] <= figure["q1"] <= figure["median"] <= figure["q3"] <= figure["max"]
                assert figure["met"] is None  # 3 pairs: too few to judge
        gains = figures["threads_gain"]  # 2 threads ÷ 1, interleaved: no target
        assert set(gains) == {"synthesis"}
        assert all(gain["pairs"] == 3 and "met" not in gain and gain["median"] > 0 for gain in gains.values())
        for memory in figures["peak_memory_over_frames"].values():
            assert memory["ratio"] > 0 and memory["target"] == "≤ 0.5" and memory["met"] == (memory["ratio"] <= 0.5)
    assert report["targets_met"] is not None  # the memory figures are judged whatever the pairs
    assert math.isfinite(report["prior_estimate_over_copy"]["median"])
    for label in ("64×48", "64×48 RGGB"):  # the family model beside the default, RGB and raw, at the first size
        family = report["targets"][label]["family_estimate_over_copy"]["1_thread"]
        assert math.isfinite(family["median"]) and family["pairs"] == 3 and family["target"] == "≤ 3"
        one_shot = report["targets"][label]["family_estimate_one_shot_over_copy"]  # the numpy fits, reported only
        assert math.isfinite(one_shot["median"]) and "target" not in one_shot
    assert "family_estimate_over_copy" not in report["targets"]["72×40 RGGB"]
    solvers = {entry["solver"]: entry for entry in report["solvers"]}
    assert set(solvers) == {
        "estimate nonneg",
        "estimate tikhonov (alpha 1e-3)",
        "flash matching",
        "flash complementary",
    }
    for entry in solvers.values():
        assert entry["problems"] >= 1 and entry["speedup"] > 0
        assert entry["objective_relative_excess"] <= 1e-6  # the same optimum as cvxpy's
