"""The camera bench: its timing stages and statistics, and an end-to-end run on a tiny format.

Figures are not asserted against targets (no timed tests); what is asserted is that every stage
is timed on one clock in the right order and that the interval arithmetic is right.
"""

from __future__ import annotations

import math
import time
from types import ModuleType, SimpleNamespace
from typing import Any

import numpy as np
import pytest

from msflash.lab.bench.camera import _plan, excess_ci, stage_ms


def _timing(sent: int, triggered: int, device: int, popped: int, delivered: int) -> Any:
    frame = SimpleNamespace(device_ns=device, received_ns=device, popped_ns=popped, delivered_ns=delivered)
    return SimpleNamespace(sent_ns=sent, triggered_ns=triggered, frame=frame)


def test_stage_ms_splits_each_trigger_into_its_stages() -> None:
    stages = stage_ms([_timing(0, 200_000, 900_000, 20_900_000, 21_800_000)])
    assert {k: float(v[0]) for k, v in stages.items()} == pytest.approx(
        {"issue": 0.2, "wait": 0.9, "transit": 20.0, "handoff": 0.9, "total": 21.8}
    )


def test_excess_ci_sums_stage_differences_and_covers_them() -> None:
    rng = np.random.default_rng(1)
    theirs = {
        "issue": rng.normal(0.1, 0.01, 300),
        "handoff": rng.normal(0.05, 0.005, 300),
        "transit": rng.normal(20.0, 8.0, 300),
    }
    ours = {"issue": theirs["issue"] + 0.03, "handoff": theirs["handoff"] + 0.8, "transit": rng.normal(20.0, 8.0, 300)}
    excess, low, high = excess_ci(ours, theirs)
    assert excess == pytest.approx(0.83, abs=1e-9)
    assert low <= 0.83 <= high and high - low < 0.05  # the noisy transit stage is not counted
    wide = excess_ci(ours, theirs, stages=("transit",))
    assert wide[2] - wide[1] > 1.0
    assert all(math.isnan(x) for x in excess_ci({"issue": np.array([]), "handoff": np.array([])}, theirs))


@pytest.mark.aravis
def test_frame_timing_stages_are_ordered_on_the_host_clock(aravis: ModuleType, gv_fake: Any) -> None:
    """The bench relies on the fake stamping frame starts with the host clock: trigger ≤ start ≤
    leader received ≤ popped ≤ delivered, for AravisCamera and for the bare loop."""
    with aravis.AravisCamera(gv_fake.address, interfaces="gige", pixel_format="Mono8", roi=(0, 0, 64, 48)) as camera:
        assert camera.last_frame_timing is None
        plan = _plan(3, 1000.0, "software")
        camera.prepare(plan)
        camera.start()
        for _ in range(3):
            sent = time.time_ns()
            camera.trigger()
            camera.next_frame(plan.frame_timeout_s)
            t = camera.last_frame_timing
            assert sent <= t.device_ns <= t.received_ns <= t.popped_ns <= t.delivered_ns <= time.time_ns()
        camera.stop()
    from msflash.lab.bench.bare_run import bare_aravis_run  # after the aravis fixture: needs the typelib

    for _ in range(3):  # the bare loop takes no frame again: one lost on loopback under load is run again
        run = bare_aravis_run(
            gv_fake.address,
            width=64,
            height=48,
            pixel_format="Mono8",
            n_frames=3,
            software_trigger=True,
            warm_up_frames=1,
        )
        if run.bad == run.missing == 0:
            break
    assert run.frames == 3 and len(run.timings) == 3 and run.bad == run.missing == 0
    for t in run.timings:
        f = t.frame
        assert (
            t.sent_ns <= t.triggered_ns and t.sent_ns <= f.device_ns <= f.received_ns <= f.popped_ns <= f.delivered_ns
        )


@pytest.mark.aravis
def test_camera_bench_reports_every_figure(aravis: ModuleType) -> None:
    from msflash.lab.bench.camera import camera_bench

    report = camera_bench(
        n_frames=6, n_triggers=8, repeats=1, width=64, height=48, frame_rate_hz=200.0, latency_blocks=2
    )
    assert report["format"] == "64x48 Mono16"
    for key in (
        "fps_msflash",
        "fps_bare",
        "fps_ratio",
        "latency_ms_msflash",
        "latency_ms_bare",
        "latency_excess_ms",
        "latency_issue_excess_ms",
        "latency_handoff_excess_ms",
        "latency_excess_mean_ms",
    ):
        assert math.isfinite(report[key]), key
    low, high = report["latency_excess_ci95_ms"]
    assert low <= report["latency_excess_ms"] <= high
    assert report["latency_excess_ms"] == pytest.approx(
        report["latency_issue_excess_ms"] + report["latency_handoff_excess_ms"]
    )
    for side in ("msflash", "bare"):
        stages = report["latency_stages_ms"][side]
        assert set(stages) == {"issue", "wait", "transit", "handoff", "total"}
        assert all(v >= 0 for v in stages.values()), stages
    assert report["drops_msflash"] == 0 and report["drops_bare"] == 0
    assert report["latency_triggers"] == 8
    assert isinstance(report["fps_target_met"], bool) and isinstance(report["latency_target_met"], bool)
    assert report["latency_target_met"] == (high <= report["latency_excess_target_ms"])
