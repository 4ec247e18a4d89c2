"""``python -m tests.harness.family_speed``: where the family model's time goes, RGB and raw, in one process.

``msflash bench --part processing`` reports ``family_estimate_over_copy`` on RGB and raw frames (interleaved with the
copy, the issue's figure). This prints, for the bench's 1280×1024 world as RGB and as a raw 12-bit RGGB mosaic, the best of
``--repeats`` timings of each step the family estimate takes — a copy of the frames, the channel statistics, the
light prior, the families (fits and held-out judgement; on the numpy route, as a one-shot ``msflash estimate``
takes it, and compiled, as a process that prepared :mod:`processing.family_kernels` does) — and the estimate over
the copy. One thread (``OPENBLAS_NUM_THREADS=1``); no targets asserted.
"""

from __future__ import annotations

import argparse
import os
import time
from collections.abc import Callable


def _best(function: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return min(times)


def main(argv: list[str] | None = None) -> int:
    """Print the table; 0."""
    parser = argparse.ArgumentParser(prog="python -m tests.harness.family_speed", description=__doc__.splitlines()[0])
    parser.add_argument("--height", type=int, default=1024)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--repeats", type=int, default=9)
    args = parser.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from msflash.acquisition.session.analysis import DEFAULT_BIN_FACTOR
    from msflash.lab.bench.processing import benchmark_world, frame_copy
    from msflash.processing import family_kernels, frame_kernels
    from msflash.processing.channel_statistics import accumulate_channel_statistics
    from msflash.processing.light_families import family_model
    from msflash.processing.light_prior import prior_model

    frame_kernels.prepare()
    compiled = family_kernels.prepare()
    print("| frames | copy (ms) | channel statistics | light prior | families (numpy) | families (compiled) "
          "| estimate ÷ copy (numpy) | (compiled) |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    for cfa in (None, "RGGB"):
        world = benchmark_world(args.height, args.width, cfa=cfa)
        frames, spec, leds, camera = world["frames"], world["spec"], world["leds"], world["camera"]

        def statistics(frames=frames, spec=spec, cfa=cfa):  # noqa: ANN001, ANN202 — bound per world
            return accumulate_channel_statistics(frames[0], frames[1:], spec, bin_factor=DEFAULT_BIN_FACTOR, cfa=cfa)

        channels = statistics()
        prior = prior_model(channels.channels, leds, camera)
        families = family_model(channels.channels, leds, camera)
        prior_spectrum = prior.estimate(channels).spectrum.values[:, 0]
        copy = _best(frame_copy(frames), args.repeats)
        stats = _best(statistics, args.repeats)
        prior_s = _best(lambda: prior.estimate(channels), args.repeats)  # noqa: B023 — used at once
        family_s = _best(lambda: families.estimate(channels, prior_spectrum), args.repeats)  # noqa: B023
        os.environ[frame_kernels.KERNELS_VARIABLE] = "numpy"  # the numpy route of the families alone
        try:
            numpy_s = _best(lambda: families.estimate(channels, prior_spectrum), args.repeats)  # noqa: B023
        finally:
            os.environ.pop(frame_kernels.KERNELS_VARIABLE)
        label = f"{args.width}×{args.height} " + ("RGB" if cfa is None else f"raw {cfa} 12-bit")
        print(
            f"| {label} | {1e3 * copy:.1f} | {1e3 * stats:.1f} | {1e3 * prior_s:.1f} | {1e3 * numpy_s:.1f} "
            f"| {1e3 * family_s:.1f}{'' if compiled else ' (numba absent: numpy)'} "
            f"| {(stats + prior_s + numpy_s) / copy:.1f} | {(stats + prior_s + family_s) / copy:.1f} |"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
