"""The camera bench runs end to end on a tiny format (figures are not asserted: no timed tests)."""

from __future__ import annotations

import math
from types import ModuleType

import pytest

pytestmark = pytest.mark.aravis


def test_camera_bench_reports_every_figure(aravis: ModuleType) -> None:
    from acquisition.bench_camera import camera_bench

    report = camera_bench(n_frames=6, n_triggers=4, repeats=1, width=64, height=48, frame_rate_hz=200.0)
    assert report["format"] == "64x48 Mono16"
    for key in ("fps_msflash", "fps_bare", "fps_ratio", "latency_ms_msflash", "latency_ms_bare",
                "latency_excess_ms"):
        assert math.isfinite(report[key]), key
    assert report["drops_msflash"] == 0 and report["drops_bare"] == 0
    assert report["latency_triggers"] == 4
    assert isinstance(report["fps_target_met"], bool) and isinstance(report["latency_target_met"], bool)
