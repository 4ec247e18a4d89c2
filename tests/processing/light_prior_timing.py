"""Timing of the light prior on 8 synthetic 1280×1024 frames (Bayer and RGB), against the eq. 5 statistics.

Run: ``PYTHONPATH=$PWD .venv/bin/python tests/processing/light_prior_timing.py`` (wall times;
the shared 2-core machine makes them vary by 2× from run to run).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from msflash.processing import datasets  # noqa: E402
from msflash.processing.accumulate import accumulate_statistics  # noqa: E402
from msflash.processing.channel_statistics import accumulate_channel_statistics  # noqa: E402
from msflash.processing.light_prior import prior_model  # noqa: E402
from msflash.processing.prior_choice import choose_model  # noqa: E402
from msflash.processing.spectra import WavelengthGrid  # noqa: E402
from msflash.processing.statistics import FrameStackSpec  # noqa: E402


def best_of(repeats: int, call) -> tuple[float, object]:  # noqa: ANN001
    """Fastest wall time (ms) of ``repeats`` calls, and the last result."""
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = call()
        times.append((time.perf_counter() - start) * 1e3)
    return min(times), result


def main() -> None:
    grid = WavelengthGrid(400, 700, 10)
    leds = datasets.paper_leds().resample(grid, outside="zero").to_unit("photons")
    camera = datasets.camera_responsivities("Canon 5DMarkII").resample(grid, outside="zero")
    rng = np.random.default_rng(0)
    spec = FrameStackSpec(64.0, 4095.0, 1.0, (1.0,) * 7, np.eye(7))
    for cfa in ("RGGB", None):
        shape = (1024, 1280) if cfa else (1024, 1280, 3)
        frames = [rng.integers(100, 3000, size=shape, dtype=np.uint16) for _ in range(8)]
        eq5, _ = best_of(
            3,
            lambda frames=frames, cfa=cfa: accumulate_statistics(
                frames[0], frames[1:], spec, bin_factor=4, cfa_period=2 if cfa else 1
            ),
        )
        channel, statistics = best_of(
            3, lambda frames=frames, cfa=cfa: accumulate_channel_statistics(frames[0], frames[1:], spec, cfa=cfa)
        )
        build, model = best_of(3, lambda statistics=statistics: prior_model(statistics.channels, leds, camera))
        estimate, _ = best_of(5, lambda model=model, statistics=statistics: model.estimate(statistics))
        choice, _ = best_of(3, lambda model=model, statistics=statistics: choose_model(statistics, model))
        print(
            f"{cfa or 'RGB'}: eq. 5 statistics {eq5:.0f} ms, channel statistics {channel:.0f} ms, model "
            f"{build:.1f} ms, prior estimate {estimate:.1f} ms, choose_model (5 folds) {choice:.0f} ms"
        )


if __name__ == "__main__":
    main()
