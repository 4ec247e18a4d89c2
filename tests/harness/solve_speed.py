"""``python -m tests.harness.solve_speed``: the fixed costs of issue 30's estimate that do not scale with the pixels —
the ambient's noise line and the solve — on the bench's 1280×1024 worlds (raw 12-bit RGGB and RGB16).

Each stage's CPU time (``time.thread_time``, one BLAS thread: ``OPENBLAS_NUM_THREADS=1`` is set first), the median of
``--runs`` runs, ÷ the median CPU time of a copy of the frames (:func:`msflash.lab.bench.processing.frame_copy`):
``block pass`` (every frame into fresh unweighted :class:`processing.block_rows.BlockRows`), ``moments``
(:meth:`processing.block_rows.BlockRows.statistics` of the weighted rows, in cache), ``noise line``
(:func:`processing.noise_level.detail_noise_line` of the ambient frame, on the route the block rows take) with its
``haar details`` and ``fit``, the ``numpy noise line`` (the route of a process without the kernels), ``block weights`` (the
inverse-variance weights of every row column from that line, on the rows' route), ``LED terms`` (an
:class:`processing.ambient.AmbientModel` of the world's LEDs, as :func:`processing.ambient.estimate_ambient` makes
one per estimate), ``solve``
(:func:`processing.ambient.estimate_ambient` on the streamed statistics: α, weights, band) with its ``weights`` and
``reliability``, and the whole ``estimate`` as the bench streams it on one thread
(:func:`msflash.lab.bench.processing.streamed_estimate`). One JSON line; nothing asserted (docs/speed.md).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable


def _median_time(function: Callable[[], object], runs: int) -> float:
    times = []
    for _ in range(runs):
        start = time.thread_time()
        function()
        times.append(time.thread_time() - start)
    times.sort()
    return times[len(times) // 2]


def _figures(cfa: str | None, runs: int) -> dict[str, float]:
    """The stages of one world, each ÷ the copy (and the copy in ms)."""
    from msflash.acquisition.session.analysis import block_factor
    from msflash.acquisition.session.estimate_stream import SAMPLE_WEIGHTING
    from msflash.lab.bench.processing import benchmark_world, frame_copy, streamed_estimate
    from msflash.processing import noise_level
    from msflash.processing.ambient import AmbientModel, estimate_ambient
    from msflash.processing.block_rows import BlockRows
    from msflash.processing.block_sums import plane_shape

    world = benchmark_world(1024, 1280, cfa=cfa)
    frames, spec, leds = world["frames"], world["spec"], world["leds"]
    period, n = (2 if cfa else 1), len(frames) - 1
    rows = BlockRows(
        n,
        plane_shape(frames[0].shape, period),
        block_factor(frames[0].shape, cfa),
        spec.white_level,
        black_level=spec.black_level,
        weighting=SAMPLE_WEIGHTING,
    )
    for row, frame in zip([n, *range(n)], frames, strict=True):
        rows.add_frame(row, frame, period)
    statistics = rows.statistics(spec)
    model = AmbientModel(leds)
    weights, alpha = model.weights(statistics)
    ambient, black, white = frames[0], spec.black_level, spec.white_level
    compiled = rows.compiled  # the noise line's route is the moments' (decided once per stack)
    details = noise_level.haar_details(ambient, period, black, white)
    factor = block_factor(frames[0].shape, cfa)

    def block_pass() -> object:  # every frame's block sums and probe, unweighted: no noise line
        unweighted = BlockRows(n, plane_shape(frames[0].shape, period), factor, white, black_level=black)
        for row, frame in zip([n, *range(n)], frames, strict=True):
            unweighted.add_frame(row, frame, period)
        return unweighted

    layout, black_sums = rows.block_shape, black * factor * factor
    ambient_row, ambient_noise = rows.rows[n], rows.ambient_noise

    def block_weights() -> object:  # the weights of every row column from the noise line (main's code: numpy's steps)
        if hasattr(noise_level, "ambient_block_weights"):
            return noise_level.ambient_block_weights(
                ambient_noise, factor, ambient_row, layout, black_sums, None, compiled=compiled
            )
        blocks = ambient_row.reshape(layout).transpose(0, 2, 1)
        return noise_level.ambient_block_noise(ambient_noise, factor, blocks, black_sums, None).weights(
            ambient_row, black_sums
        )

    stages: dict[str, Callable[[], object]] = {
        "estimate": lambda: streamed_estimate(world, factor),
        "block pass": block_pass,
        "moments": lambda: rows.statistics(spec),
        "noise line": lambda: noise_level.detail_noise_line(ambient, period, black, white, compiled=compiled),
        "haar details": lambda: noise_level.haar_details(ambient, period, black, white, compiled=compiled),
        "fit": lambda: noise_level.fit_detail_line(*details, compiled=compiled),
        "numpy noise line": lambda: noise_level.detail_noise_line(ambient, period, black, white),
        "block weights": block_weights,
        "LED terms": lambda: AmbientModel(leds),
        "solve": lambda: estimate_ambient(statistics, leds),
        "weights": lambda: model.weights(statistics),
        "reliability": lambda: model.reliability(statistics, weights, "tikhonov", alpha),
    }
    copy = _median_time(frame_copy(frames), runs)
    label = cfa or "RGB"
    figures = {f"{label} copy ms": copy * 1e3}
    for name, stage in stages.items():
        figures[f"{label} {name}"] = _median_time(stage, runs) / copy
    return figures


def main(argv: list[str] | None = None) -> int:
    """Print the figures; 0."""
    parser = argparse.ArgumentParser(prog="python -m tests.harness.solve_speed", description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=41)
    args = parser.parse_args(argv)
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    from msflash.processing import frame_kernels

    frame_kernels.prepare()
    figures = {**_figures("RGGB", args.runs), **_figures(None, args.runs)}
    print(json.dumps({name: round(value, 3) for name, value in figures.items()}, ensure_ascii=False))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
