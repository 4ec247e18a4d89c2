"""``python -m tests.harness.family_answers``: every family-model answer of the quick harness cases, to compare checkouts.

A speed change to the family model (:mod:`processing.light_families`, its fits and kernels, the channel statistics)
must leave its answers as they were. This writes, for the quick rows of both harness suites (physics and library,
tuning and held out: 40 cases) and the bench's RGB and raw 1280×1024 worlds, each on the numpy route
(``MSFLASH_KERNELS=numpy``) and the compiled one (the frame kernels and the compiled fits prepared) — 84 estimates —
digests of the channel statistics, the prior's spectrum, the family spectrum, its band and spread, and every
candidate's held-out errors (``repr``, all digits) and spectrum, with the chosen candidate, ``auto``'s choice and the
reason. ``--compare A B`` says how many differ and where. The harness cases' channel statistics are taken as
``msflash estimate --model family`` takes them (from the LED estimate's block rows, since issue 31), the bench
worlds' by the frames' own pass.

Run it with each checkout's code (``PYTHONPATH=<checkout>``, e.g. a ``git archive`` of the commit before, next to a
``shared`` link to the spectral data), then compare: docs/speed.md, the family model's sections.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np


def _digest(values: Any) -> str:
    return hashlib.sha1(np.ascontiguousarray(np.asarray(values, float)).tobytes()).hexdigest()[:16]


def _answers(statistics: Any, leds: Any, camera: Any) -> dict[str, Any]:
    from msflash.processing.light_families import family_model
    from msflash.processing.light_prior import prior_model

    prior = prior_model(statistics.channels, leds, camera).estimate(statistics)
    estimate = family_model(statistics.channels, leds, camera).estimate(statistics, prior.spectrum.values[:, 0])
    moments = [statistics.moments] + ([] if statistics.noise is None else [statistics.noise])
    return {
        "statistics": _digest(np.concatenate([np.ravel(getattr(m, f)) for m in moments for f in ("ff", "fa", "aa")])),
        "prior": _digest(prior.spectrum.values),
        "spectrum": _digest(estimate.spectrum.values),
        "std": _digest(estimate.spectrum_std),
        "spread": _digest(estimate.spread_std),
        "chosen": estimate.chosen.fit.name,
        "auto": estimate.auto_model,
        "reason": estimate.reason,
        "candidates": [
            [c.fit.name, repr(c.held_out_error), repr(c.held_out_error_noise_removed), _digest(c.fit.spectrum)]
            for c in estimate.candidates
        ],
        "warnings": list(estimate.warnings),
    }


def _both_routes(name: str, statistics_of: Callable[[], Any], leds: Any, camera: Any, out: dict[str, Any]) -> None:
    from msflash.processing import family_kernels, frame_kernels

    for route in ("numpy", "compiled"):
        if route == "numpy":
            os.environ[frame_kernels.KERNELS_VARIABLE] = "numpy"
        else:
            os.environ.pop(frame_kernels.KERNELS_VARIABLE, None)
            family_kernels.prepare()
        try:
            out[f"{name}|{route}"] = _answers(statistics_of(), leds, camera)
        finally:
            os.environ.pop(frame_kernels.KERNELS_VARIABLE, None)


def collect(cache: Path) -> dict[str, Any]:
    """Every answer (module notes), keyed ``case|route``."""
    from msflash.acquisition.session.analysis import DEFAULT_BIN_FACTOR, block_factor, stream_stack
    from msflash.acquisition.session.prior_route import sequence_channel_statistics
    from msflash.lab.bench.processing import benchmark_world
    from msflash.processing.channel_statistics import accumulate_channel_statistics
    from tests.harness.cases import select_cases
    from tests.harness.family_study import case_inputs
    from tests.harness.physics_cases import select_physics_cases
    from tests.harness.run import CACHE_ENV

    cache.mkdir(parents=True, exist_ok=True)
    os.environ[CACHE_ENV] = str(cache.resolve())
    out: dict[str, Any] = {}
    for suite, select in (("physics", select_physics_cases), ("library", select_cases)):
        for split in ("tuning", "held_out"):
            for case in select(split, True):
                _, _, sequence, leds, camera, stack = case_inputs(case, cache.resolve())
                _both_routes(
                    f"{suite}:{case.name}",
                    # As ``msflash estimate --model family`` takes them: from the LED estimate's block rows.
                    lambda sequence=sequence, stack=stack: sequence_channel_statistics(
                        sequence,
                        stack,
                        stream=stream_stack(sequence, stack, DEFAULT_BIN_FACTOR, full_probe=True),
                    ),
                    leds,
                    camera,
                    out,
                )
    for cfa in (None, "RGGB"):
        world = benchmark_world(1024, 1280, cfa=cfa)
        frames, spec = world["frames"], world["spec"]
        factor = block_factor(frames[0].shape, cfa, DEFAULT_BIN_FACTOR)

        def statistics_of(frames: Any = frames, spec: Any = spec, factor: int = factor, cfa: Any = cfa) -> Any:
            return accumulate_channel_statistics(frames[0], frames[1:], spec, bin_factor=factor, cfa=cfa)

        _both_routes(f"bench:{cfa or 'RGB'}", statistics_of, world["leds"], world["camera"], out)
    return out


def compare(before: dict[str, Any], after: dict[str, Any]) -> list[str]:
    """Lines saying how many answers differ, then each difference."""
    keys = sorted(set(before) | set(after))
    differ = [key for key in keys if before.get(key) != after.get(key)]
    lines = [f"{len(keys)} family estimates compared, {len(differ)} differ"]
    for key in differ:
        one, other = before.get(key) or {}, after.get(key) or {}
        fields = sorted(f for f in set(one) | set(other) if one.get(f) != other.get(f))
        lines.append(f"{key}: {', '.join(fields) or 'missing'}")
    return lines


def main(argv: list[str] | None = None) -> int:
    """Write the answers (``OUT``) or compare two files (``--compare A B``); 0, or 1 when answers differ."""
    parser = argparse.ArgumentParser(prog="python -m tests.harness.family_answers", description=__doc__.splitlines()[0])
    parser.add_argument("out", nargs="?", type=Path, help="where to write the answers (JSON)")
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--cache", type=Path, default=Path(".harness-cache"))
    args = parser.parse_args(argv)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if args.compare:
        before, after = (json.loads(path.read_text()) for path in args.compare)
        lines = compare(before, after)
        print("\n".join(lines))
        return 1 if len(lines) > 1 else 0
    if args.out is None:
        parser.error("give OUT or --compare BEFORE AFTER")
    answers = collect(args.cache)
    args.out.write_text(json.dumps(answers, indent=1))
    print(f"{len(answers)} family estimates → {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
