"""Soak (issue 19 item 7): 500 consecutive sequences on the sim rig in one process, through the
command line in-process (``main(["capture", ...])``) and the public API (``msflash.read_sequence``,
``estimate_ambient``, ``solve_flash``, ``synthesize_flash``). After a warm-up, open files, threads
and resident memory must not grow beyond a small bound, and no frame may be lost. Study-marked
(about 5 minutes); ``MSFLASH_SOAK_RUNS`` changes the count. Figures: docs/reliability.md."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import threading
from pathlib import Path

import numpy as np
import pytest

import msflash
from msflash.acquisition.app.cli import main

WARM_UP = 20
LEDS = 3
# Scaled down so 500 runs fit in minutes: the 4-patch-row Macbeth chart, 3 LEDs, a fixed exposure.
CAPTURE = ["capture", "--scene", "macbeth", "--leds", str(LEDS), "--exposure-us", "2000"]
RSS_BOUND_MIB = 40.0
"""Resident memory may grow this much after the warm-up (allocator noise, caches filling)."""


def _resources() -> dict[str, float]:
    status = dict(line.split(":", 1) for line in Path("/proc/self/status").read_text().splitlines())
    return {
        "fds": len(os.listdir("/proc/self/fd")),
        "threads": int(status["Threads"]),
        "python_threads": threading.active_count(),
        "rss_mib": int(status["VmRSS"].split()[0]) / 1024,
    }


@pytest.mark.study
@pytest.mark.timeout(3 * 3600)
def test_500_sequences_leak_nothing_and_lose_no_frame(tmp_path: Path) -> None:
    runs = int(os.environ.get("MSFLASH_SOAK_RUNS", "500"))
    samples, lost = [], []
    for run in range(runs):
        out = tmp_path / f"run{run}"
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
            status = main([*CAPTURE, "--out", str(out), "--seed", str(run)])
        assert status == 0, err.getvalue()
        sequence = msflash.read_sequence(out / "sequence")
        frames = [sequence.load_frame(i) for i in range(len(sequence.frames))]
        if not sequence.complete or len(frames) != 1 + LEDS:
            lost.append((run, sequence.complete, len(frames)))
        estimate = msflash.estimate_ambient(sequence)
        flash = msflash.solve_flash(sequence, estimate, "matching")
        image = msflash.synthesize_flash(sequence, flash)
        assert np.all(np.isfinite(image)) and image.shape == frames[0].shape
        shutil.rmtree(out)
        if run + 1 == WARM_UP or (run + 1) % 50 == 0 or run + 1 == runs:
            samples.append({"run": run + 1, **_resources()})
    print(json.dumps({"runs": runs, "lost": lost, "samples": samples}))
    assert not lost
    start, end = samples[0], samples[-1]
    assert end["fds"] <= start["fds"], samples
    assert end["threads"] <= start["threads"] and end["python_threads"] <= start["python_threads"], samples
    assert end["rss_mib"] - start["rss_mib"] <= RSS_BOUND_MIB, samples
