"""``python -m tests.harness.cold_stages [--cfa RGGB|RGB] [--pairs 61]``: the default estimate's stages as the bench
takes them — each estimate right after a copy of the frames (caches cold) — on the bench's 1280×1024 world.

Wall milliseconds (``time.perf_counter``, one BLAS thread), medians of ``--pairs``: the copy; the ambient frame's
pass with its noise line and weights; the 7 LED frames' passes; the moments
(:meth:`processing.block_rows.BlockRows.statistics`); the LED terms (an :class:`processing.ambient.AmbientModel`,
as :func:`processing.ambient.estimate_ambient` makes one); the solve (α and weights); the reliability (band,
condition, warnings); then, after another copy, the whole streamed estimate
(:func:`msflash.lab.bench.processing.streamed_estimate`) and its ratio to the copy. One JSON line; nothing
asserted (docs/speed.md).
"""

from __future__ import annotations

import argparse
import json
import os
import time


def main(argv: list[str] | None = None) -> int:
    """Print the figures; 0."""
    parser = argparse.ArgumentParser(prog="python -m tests.harness.cold_stages", description=__doc__.splitlines()[0])
    parser.add_argument("--cfa", choices=("RGGB", "RGB"), default="RGGB")
    parser.add_argument("--pairs", type=int, default=61)
    args = parser.parse_args(argv)
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    import numpy as np

    from msflash.acquisition.session.analysis import block_factor
    from msflash.acquisition.session.estimate_stream import SAMPLE_WEIGHTING
    from msflash.lab.bench.processing import benchmark_world, frame_copy, streamed_estimate
    from msflash.processing import frame_kernels
    from msflash.processing.ambient import AmbientModel
    from msflash.processing.block_rows import BlockRows
    from msflash.processing.block_sums import plane_shape

    frame_kernels.prepare()
    cfa = None if args.cfa == "RGB" else args.cfa
    world = benchmark_world(1024, 1280, cfa=cfa)
    frames, spec, leds = world["frames"], world["spec"], world["leds"]
    period, n = (2 if cfa else 1), len(frames) - 1
    factor = block_factor(frames[0].shape, cfa)
    copy = frame_copy(frames)
    clock = time.perf_counter
    names = ("copy", "ambient pass, noise line, weights", "7 LED passes", "moments", "LED terms", "solve")
    times: dict[str, list[float]] = {name: [] for name in (*names, "reliability", "whole streamed")}
    for _ in range(args.pairs):
        marks = [clock()]
        copy()
        marks.append(clock())
        frame_kernels.wanted(frames[0].nbytes * len(frames))
        rows = BlockRows(
            n,
            plane_shape(frames[0].shape, period),
            factor,
            spec.white_level,
            black_level=spec.black_level,
            weighting=SAMPLE_WEIGHTING,
        )
        rows.add_frame(n, frames[0], period)
        marks.append(clock())
        for row in range(n):
            rows.add_frame(row, frames[row + 1], period)
        marks.append(clock())
        statistics = rows.statistics(spec)
        marks.append(clock())
        model = AmbientModel(leds)
        marks.append(clock())
        weights, alpha, solution = model._weights(statistics, "tikhonov", "auto", None)
        marks.append(clock())
        model.reliability(statistics, weights, "tikhonov", alpha, solution)
        marks.append(clock())
        for name, start, stop in zip((*names, "reliability"), marks[:-1], marks[1:], strict=True):
            times[name].append(stop - start)
        copy()
        start = clock()
        streamed_estimate(world, factor)
        times["whole streamed"].append(clock() - start)
    figures = {name: round(float(np.median(values)) * 1e3, 3) for name, values in times.items()}
    figures["ratio"] = round(figures["whole streamed"] / figures["copy"], 3)
    print(args.cfa, json.dumps(figures, ensure_ascii=False), f"load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
