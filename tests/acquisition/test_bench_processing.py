"""Smoke test of the processing bench on a small world: every figure is there (no timed assertion)."""

from __future__ import annotations

import math

from msflash.acquisition.app.bench import processing_bench


def test_processing_bench_reports_every_ratio_and_both_thread_counts() -> None:
    report = processing_bench(height=48, width=64, repeats=1)
    for key in (
        "estimate_over_copy",
        "estimate_over_copy_interleaved",
        "estimate_all_pixels_over_copy",
        "synthesis_over_copy",
        "prior_estimate_over_copy",
        "prior_estimate_over_copy_interleaved",
    ):
        assert math.isfinite(report[key]) and report[key] > 0, key
    for key in ("estimate_over_copy_by_threads", "synthesis_over_copy_by_threads"):
        assert set(report[key]) == {"1", "2"} and all(value > 0 for value in report[key].values()), key
    assert report["threads"] in (1, 2)
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
