"""``python -m tests.harness.raw_speed``: the raw-frame figures of issue 30 in one process, as interleaved ratios.

For the bench's 1280×1024 world as RGB and as a raw 12-bit RGGB mosaic: the default estimate as ``msflash estimate``
streams it (weighted block rows, one moment product at the end, the default solve), the light models' channel statistics, and the family
model's estimate (statistics, prior, families), each the median of ``--pairs`` pairs interleaved with a copy of the
frames (:func:`msflash.lab.bench.ratios.interleaved_ratio`, as ``msflash bench`` measures). ``--one-thread`` sets
``OPENBLAS_NUM_THREADS=1`` first. One JSON line; no targets asserted (docs/speed.md, Raw frames).
"""

from __future__ import annotations

import argparse
import json
import os


def main(argv: list[str] | None = None) -> int:
    """Print the figures; 0."""
    parser = argparse.ArgumentParser(prog="python -m tests.harness.raw_speed", description=__doc__.splitlines()[0])
    parser.add_argument("--height", type=int, default=1024)
    parser.add_argument("--width", type=int, default=1280)
    parser.add_argument("--pairs", type=int, default=21)
    parser.add_argument("--one-thread", action="store_true", help="OPENBLAS_NUM_THREADS=1 (BLAS on one thread)")
    args = parser.parse_args(argv)
    if args.one_thread:
        os.environ["OPENBLAS_NUM_THREADS"] = "1"
    from msflash.acquisition.session.analysis import DEFAULT_BIN_FACTOR, block_factor
    from msflash.lab.bench.processing import benchmark_world, family_ratio, frame_copy, streamed_estimate
    from msflash.lab.bench.ratios import interleaved_ratio
    from msflash.processing import frame_kernels
    from msflash.processing.channel_statistics import accumulate_channel_statistics

    frame_kernels.prepare()
    figures: dict[str, float] = {}
    for cfa in ("RGGB", None):
        world = benchmark_world(args.height, args.width, cfa=cfa)
        frames, spec = world["frames"], world["spec"]
        factor = block_factor(frames[0].shape, cfa)

        def streamed(world=world, factor=factor) -> object:  # noqa: ANN001
            return streamed_estimate(world, factor)

        def channels(frames=frames, spec=spec, cfa=cfa) -> object:  # noqa: ANN001
            bin_factor = block_factor(frames[0].shape, cfa, DEFAULT_BIN_FACTOR)
            return accumulate_channel_statistics(frames[0], frames[1:], spec, bin_factor=bin_factor, cfa=cfa)

        label, copy = cfa or "RGB", frame_copy(frames)
        figures[f"{label} estimate"] = interleaved_ratio(streamed, copy, args.pairs)["median"]
        figures[f"{label} channel_statistics"] = interleaved_ratio(channels, copy, args.pairs)["median"]
        figures[f"{label} family"] = family_ratio(world, args.pairs)["median"]
    print(json.dumps({name: round(value, 2) for name, value in figures.items()}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
