"""Smoke test of the capture bench on the GigE Vision fake: every figure is there (no timed assertion)."""

from __future__ import annotations

import math
from types import ModuleType

import pytest

from msflash.lab.cli_bench import _OPTIONAL_PARTS

pytestmark = pytest.mark.aravis


def test_capture_bench_returns_every_figure(aravis: ModuleType) -> None:
    from msflash.lab.bench.capture import capture_bench

    report = capture_bench(runs=1, width=64, height=48)
    for key in (
        "wall_ratio",
        "latency_ms_median",
        "latency_ms_max",
        "compute_ms_median",
        "frame_period_ms",
        "exposure_us",
    ):
        assert math.isfinite(report[key]) and report[key] > 0, key
    assert len(report["wall_ratios"]) == len(report["latencies_ms"]) == 1
    parts = report["latency_parts_ms_median"]
    consecutive = ("handoff_ms", "compute_ms", "exposure_ms", "replan_ms", "pset_to_trigger_ms")
    assert set(parts) == {*consecutive, "pset_to_release_ms", "pset_ms"}
    assert all(math.isfinite(value) and value > 0 for value in parts.values())
    # Consecutive intervals from the last LED frame's arrival to the pulse: they add up to each run's latency.
    per_run = report["latency_parts_ms"]
    for run, latency in enumerate(report["latencies_ms"]):
        assert sum(per_run[name][run] for name in consecutive) == pytest.approx(latency, abs=1e-6)
    assert parts["pset_to_trigger_ms"] >= report["booth_settle_ms"]
    # The host's part (compute + serial) ends when the booth sets the flash LEDs: the settle follows.
    for run, latency in enumerate(report["latencies_ms"]):
        host = report["host_latencies_ms"][run]
        assert 0 < host <= latency - report["booth_settle_ms"]
        assert per_run["pset_to_release_ms"][run] < per_run["pset_to_trigger_ms"][run]
    assert report["host_latency_ms_median"] == pytest.approx(report["host_latencies_ms"][0])
    assert isinstance(report["wall_target_met"], bool) and isinstance(report["latency_target_met"], bool)
    assert _OPTIONAL_PARTS["capture"] == ("msflash.lab.bench.capture", "capture_bench")
