"""Before/after of the one estimation route, interleaved in one process (docs/decisions/one-estimation-route.md).

``python -m tests.harness.estimate_route_bench [--frames N] [--height H] [--width W] [--rounds R]`` writes an
RGB sequence of one ambient and N LED frames to a temporary folder, then alternates, R rounds:

- *stack*: the route before — every frame decoded into a stack (``analysis.load_frame_stack``), the batch
  statistics (``tests.helpers.sequence_statistics``, two threads over the frames) and the estimate;
- *stream*: the route now — ``analysis.estimate_sequence``: one frame decoded at a time into the
  block rows (``EstimateStream``).

It prints, as JSON, each route's best and median wall time, their ratio (stream ÷ stack) per round, and each
route's tracemalloc peak over the bytes of one frame.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
import tracemalloc
from pathlib import Path

from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import analysis
from tests.acquisition.session.test_estimate_stream import write_sequence
from tests.helpers import sequence_statistics


def stack_route(sequence) -> object:  # noqa: ANN001
    stack = analysis.load_frame_stack(sequence)
    statistics_ = sequence_statistics(stack, sequence.camera.cfa)
    return analysis.estimate_from_statistics(sequence, statistics_)


def stream_route(sequence) -> object:  # noqa: ANN001
    return analysis.estimate_sequence(sequence)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--height", type=int, default=768)
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    shape = (args.height, args.width, 3)
    with tempfile.TemporaryDirectory() as folder:
        sequence = read_sequence(write_sequence(Path(folder) / "s", n_led_frames=args.frames, shape=shape))
        routes = {"stack": stack_route, "stream": stream_route}
        for route in routes.values():
            route(sequence)  # warm: imports, caches, kernels
        times: dict[str, list[float]] = {name: [] for name in routes}
        for _ in range(args.rounds):
            for name, route in routes.items():
                started = time.perf_counter()
                route(sequence)
                times[name].append(time.perf_counter() - started)
        peaks = {}
        for name, route in routes.items():
            tracemalloc.start()
            route(sequence)
            peaks[name] = tracemalloc.get_traced_memory()[1]
            tracemalloc.stop()
    frame_bytes = args.height * args.width * 3 * 2
    ratios = [b / a for a, b in zip(times["stack"], times["stream"], strict=True)]
    print(
        json.dumps(
            {
                "frames": f"1 ambient + {args.frames} LED, {args.height}×{args.width} RGB uint16",
                "seconds": {
                    name: {"best": min(values), "median": statistics.median(values)} for name, values in times.items()
                },
                "stream_over_stack": {"median": statistics.median(ratios), "min": min(ratios), "max": max(ratios)},
                "peak_over_one_frame": {name: peak / frame_bytes for name, peak in peaks.items()},
            },
            indent=1,
        )
    )


if __name__ == "__main__":
    main()
