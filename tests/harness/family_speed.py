"""``python -m tests.harness.family_speed``: where the family model's time goes, RGB and raw, in one process.

``msflash bench --part processing`` reports ``family_estimate_over_copy`` on RGB and raw frames (interleaved with the
copy, the issue's figure). This prints, for the bench's 1280×1024 world as RGB and as a raw 12-bit RGGB mosaic, the best of
``--repeats`` timings of each step the family estimate takes — a copy of the frames, the channel statistics, the
light prior, the families (fits and held-out judgement; on the numpy route, as a one-shot ``msflash estimate``
takes it, and compiled, as a process that prepared :mod:`processing.family_kernels` does) — and the estimate over
the copy. One thread (``OPENBLAS_NUM_THREADS=1``); no targets asserted.

``--stages``: instead, the compiled family estimate as the bench runs it (statistics from the block rows the
default estimate filled, prior, families, one after the other, so each stage starts with the caches the frames' pass left), each stage's CPU time
(``time.thread_time``) the median of ``--repeats`` runs, in ms and ÷ the median CPU time of the copy.

``--decile``: the bench's family figure by CPU time, steadier than its medians on a loaded machine: a copy, then the
compiled family estimate (statistics, prior, families), in turn ``--repeats`` times; the lower decile of each, and the
estimate's over the copy's (to compare checkouts, alternate processes).
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
    parser.add_argument("--stages", action="store_true", help="CPU time of each stage of the compiled estimate")
    parser.add_argument("--decile", action="store_true", help="lower decile of the CPU time, estimate ÷ copy")
    args = parser.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if args.stages:
        return _stages(args.height, args.width, max(args.repeats, 21))
    if args.decile:
        return _decile(args.height, args.width, max(args.repeats, 21))
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


def _stages(height: int, width: int, runs: int) -> int:
    """The ``--stages`` table (module notes); 0."""
    import numpy as np

    from msflash.lab.bench.processing import benchmark_world, family_statistics, frame_copy
    from msflash.processing import family_kernels
    from msflash.processing import light_families as lf
    from msflash.processing.light_prior import prior_model

    family_kernels.prepare()
    names = ("channel statistics", "light prior", "scene form, all-folds term", "fits (forms, discharge, mixtures)",
             "fold complements' terms", "held-out judgement", "choice, band, spread", "families (sum)", "whole")  # fmt: skip
    print("| stage | " + " | ".join(f"{cfa} ms (÷ copy)" for cfa in ("RGB", "raw RGGB")) + " |")
    print("|---|---|---|")
    columns = []
    for cfa in (None, "RGGB"):
        world = benchmark_world(height, width, cfa=cfa)
        frames, leds, camera = world["frames"], world["leds"], world["camera"]
        taken = family_statistics(world)  # from the block rows, as the bench's family figure takes them
        channels = taken()
        prior, model = prior_model(channels.channels, leds, camera), lf.family_model(channels.channels, leds, camera)
        copy = frame_copy(frames)
        copies, rows = [], []
        for _ in range(runs):
            start = time.thread_time()
            copy()
            copies.append(time.thread_time() - start)
            marks = [time.thread_time()]
            statistics = taken()
            marks.append(time.thread_time())
            spectrum = prior.estimate(statistics).spectrum.values[:, 0]
            marks.append(time.thread_time())
            scene = lf.scene_form(statistics, model.reduction)
            problem = scene.whitened(list(range(scene.n_folds)))
            marks.append(time.thread_time())
            fits, led_fit = model._fits(problem, spectrum)
            marks.append(time.thread_time())
            training = lf.training_terms(scene)
            marks.append(time.thread_time())
            led, candidates = lf._judged(fits, led_fit, scene, training)
            marks.append(time.thread_time())
            candidates.sort(key=lambda c: c.evidence)
            chosen = lf.choose(candidates, led)[0]
            scaled = lf._scaled_spectra(chosen, candidates)
            model.band(chosen, candidates, problem, statistics.n_blocks * statistics.n_channels, scaled)
            lf._weighted_spread(chosen.fit.spectrum, candidates, scaled, lf.CHECK_TEMPERATURE)
            lf._weighted_spread(chosen.fit.spectrum, candidates, scaled, lf.AVERAGE_TEMPERATURE)
            marks.append(time.thread_time())
            steps = list(np.diff(marks))
            rows.append([*steps, sum(steps[2:]), marks[-1] - marks[0]])
        reference = float(np.median(copies))
        columns.append([f"{1e3 * v:.2f} ({v / reference:.2f})" for v in np.median(np.array(rows), axis=0)])
        columns[-1].insert(0, f"{1e3 * reference:.2f} (1)")
    for i, name in enumerate(("copy of the stack", *names)):
        print(f"| {name} | {columns[0][i]} | {columns[1][i]} |")
    return 0


def _decile(height: int, width: int, runs: int) -> int:
    """The ``--decile`` table (module notes); 0."""
    import numpy as np

    from msflash.lab.bench.processing import benchmark_world, family_statistics, frame_copy
    from msflash.processing import family_kernels
    from msflash.processing.light_families import family_model
    from msflash.processing.light_prior import prior_model

    family_kernels.prepare()
    print("| frames | copy ms | family estimate ms | ÷ copy |")
    print("|---|---|---|---|")
    for cfa in (None, "RGGB"):
        world = benchmark_world(height, width, cfa=cfa)
        frames, leds, camera = world["frames"], world["leds"], world["camera"]
        statistics = family_statistics(world)  # from the block rows, as ``msflash estimate --model family`` takes them
        channels = statistics()
        prior, families = prior_model(channels.channels, leds, camera), family_model(channels.channels, leds, camera)

        def estimate(statistics=statistics, prior=prior, families=families):  # noqa: ANN001, ANN202
            now = statistics()
            return families.estimate(now, prior.estimate(now).spectrum.values[:, 0])

        copy = frame_copy(frames)
        copy(), estimate()
        copies, estimates = [], []
        for _ in range(runs):
            start = time.thread_time()
            copy()
            middle = time.thread_time()
            estimate()
            estimates.append(time.thread_time() - middle)
            copies.append(middle - start)
        low_copy, low_estimate = (float(np.percentile(v, 10)) for v in (copies, estimates))
        label = f"{width}×{height} " + ("RGB" if cfa is None else f"raw {cfa} 12-bit")
        print(f"| {label} | {1e3 * low_copy:.2f} | {1e3 * low_estimate:.2f} | {low_estimate / low_copy:.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
