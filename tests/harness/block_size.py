"""``python -m tests.harness.block_size``: block size against accuracy, agreement and time (issue 21, item 4).

For every harness case (:mod:`tests.harness.cases`, both splits; the held-out rows are reported, never
tuned on) and every block size 1–16, the three model families estimate from the case's frames in
memory, as ``msflash estimate`` does but with the block size forced (no fallback for small frames):

- ``led``: eq. 4–6 on weighted block statistics (``--model led``, the default; tikhonov, discrepancy α);
- ``prior``: the light prior on channel statistics (``--model prior``);
- ``local``: the tiled estimate, ``--method auto`` (accuracy: the mean RMSE over its tiles).

Accuracy is the harness's RMSE ÷ LED bound (:mod:`tests.harness.metrics`). For ``led``, the agreement
with the all-pixel reference (:func:`msflash.lab.study.block_agreement.all_pixel_statistics`:
every pixel, weighted, its noise's share removed with the renderer's known noise) in units of the
reference's pixel-noise band (:func:`~msflash.lab.study.block_agreement.agreement`).
Time is measured on the bench's scene (:func:`msflash.lab.bench.processing.benchmark_world`,
1280 × 1024 RGB, 7 LEDs): each estimate ÷ a copy of the frames into a pre-allocated buffer, run
in turn (ABAB…), the median of the per-pair ratios.

Writes ``--out`` (markdown: its hand-written part above ``<!-- generated -->`` is kept), the chart ``--png``,
the raw results ``--raw`` and, with ``--csv``, one row per case, family and block size.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.analysis import load_frame_stack
from msflash.acquisition.session.sequence_spectra import (
    camera_responsivities_photons,
    led_spectra_photons,
    spectrum_in_sequence_unit,
)
from msflash.lab.study.block_agreement import FrameNoise, agreement, all_pixel_statistics, sensor_noise
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import AmbientEstimate, estimate_ambient
from msflash.processing.channel_statistics import accumulate_channel_statistics
from msflash.processing.light_prior import prior_model
from msflash.processing.local import estimate_local
from msflash.processing.model_error import LightReference, reference_for, with_model_error
from msflash.processing.spectra import Spectra
from msflash.processing.statistics import SequenceStatistics
from msflash.processing.tile_statistics import tile_statistics
from tests.harness import metrics
from tests.harness.cases import select_cases
from tests.harness.render import HarnessCase, render

BLOCK_SIZES = tuple(range(1, 17))
FAMILIES = ("led", "prior", "local")
LOCAL_TILES = 4
"""Tiles per side of the local family (fewer when the blocks do not fill 2 per tile side)."""
FIELDS = (
    "case",
    "split",
    "mosaic",
    "family",
    "block",
    "ratio",
    "worst_z",
    "within_2sigma",
    "band_ratio",
    "worst_z_full",
    "worst_z_same_alpha",
    "within_2sigma_same_alpha",
    "reference_ratio",
    "error",
)


def case_noise(case: HarnessCase, gains: Sequence[float]) -> list[FrameNoise]:
    """The renderer's noise line of each frame (:func:`tests.harness.render.render`), in frame order."""
    span = 2**case.bits - 1 - case.black
    return [sensor_noise(case.full_well_e / span, case.read_noise_e, gain) for gain in gains]


def _tiles(shape: tuple[int, ...], period: int, factor: int) -> tuple[int, int]:
    blocks = (shape[0] // (factor * period), shape[1] // (factor * period))
    return max(1, min(LOCAL_TILES, blocks[0] // 2)), max(1, min(LOCAL_TILES, blocks[1] // 2))


def led_agreement(
    estimate: AmbientEstimate,
    reference: AmbientEstimate,
    reference_statistics: SequenceStatistics,
    leds: Spectra,
    model_reference: LightReference,
) -> dict[str, float]:
    """The agreement columns of an ``led`` row: with the reference at its own (discrepancy) α, and re-solved
    at the block estimate's α (the same regularisation: what the statistics alone change)."""
    agreed = agreement(estimate, reference)
    same = with_model_error(
        estimate_ambient(reference_statistics, leds, "tikhonov", estimate.alpha),
        model_reference,
    )
    shared = agreement(estimate, same)
    return {
        "worst_z": agreed.worst_z,
        "within_2sigma": agreed.within_2sigma,
        "band_ratio": agreed.band_ratio,
        "worst_z_full": agreed.worst_z_full,
        "worst_z_same_alpha": shared.worst_z,
        "within_2sigma_same_alpha": shared.within_2sigma,
    }


def sweep_case(case: HarnessCase) -> list[dict[str, Any]]:
    """Every family × block size on one case: one row each (:data:`FIELDS`)."""
    scratch = Path(tempfile.mkdtemp(prefix="blocks-"))
    try:
        truth = render(case, scratch / case.name)
        sequence = read_sequence(truth.directory)
        stack = load_frame_stack(sequence)
        bound = metrics.led_bound(truth.led_spd, truth.ambient)
        leds = led_spectra_photons(sequence)
        camera = camera_responsivities_photons(sequence)
        period = 2 if sequence.camera.cfa is not None else 1
        gains = [sequence.frames[i].gain for i in (stack.ambient_index, *stack.led_indices)]
        reference_statistics = all_pixel_statistics(
            stack.ambient, stack.led_frames, stack.spec, case_noise(case, gains), cfa_period=period
        )
        model_reference = reference_for(leds, camera)
        reference = with_model_error(estimate_ambient(reference_statistics, leds), model_reference)

        def ratio(spectrum_photons) -> float:  # noqa: ANN001 — a Spectra
            return metrics.rmse(spectrum_in_sequence_unit(sequence, spectrum_photons), truth.ambient) / bound

        reference_ratio = ratio(reference.spectrum)
        prior = None
        rows = []
        for factor in BLOCK_SIZES:
            for family in FAMILIES:
                row: dict[str, Any] = {
                    "case": case.name,
                    "split": case.split,
                    "mosaic": case.mosaic,
                    "family": family,
                    "block": factor,
                    "reference_ratio": reference_ratio,
                }
                try:
                    if family == "led":
                        estimate = estimate_ambient(
                            accumulate_statistics(
                                stack.ambient,
                                stack.led_frames,
                                stack.spec,
                                bin_factor=factor,
                                cfa_period=period,
                                weighting=True,
                            ),
                            leds,
                        )
                        row["ratio"] = ratio(estimate.spectrum)
                        row.update(led_agreement(estimate, reference, reference_statistics, leds, model_reference))
                    elif family == "prior":
                        channels = accumulate_channel_statistics(
                            stack.ambient, stack.led_frames, stack.spec, cfa=sequence.camera.cfa, bin_factor=factor
                        )
                        prior = prior or prior_model(channels.channels, leds, camera)
                        row["ratio"] = ratio(prior.estimate(channels).spectrum)
                    else:
                        tiled = tile_statistics(
                            stack.ambient,
                            stack.led_frames,
                            stack.spec,
                            _tiles(stack.ambient.shape, period, factor),
                            bin_factor=factor,
                            cfa_period=period,
                            weighting=True,
                        )
                        local = estimate_local(tiled, leds)
                        spectra = local.tile_spectra.reshape(-1, local.tile_spectra.shape[-1])
                        unit = spectrum_in_sequence_unit(sequence, local.global_estimate.spectrum)
                        # The tiles' spectra to the sequence's unit by the global spectrum's conversion.
                        factor_unit = unit / np.where(
                            local.global_estimate.spectrum.values[:, 0] == 0,
                            1.0,
                            local.global_estimate.spectrum.values[:, 0],
                        )
                        row["ratio"] = float(
                            np.mean([metrics.rmse(s * factor_unit, truth.ambient) / bound for s in spectra])
                        )
                except Exception as error:  # noqa: BLE001 — a block size a frame cannot take is a result
                    row["error"] = f"{type(error).__name__}: {error}"[:200]
                rows.append(row)
        return rows
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def run_sweep(cases: list[HarnessCase], jobs: int = 1, progress: bool = True) -> list[dict[str, Any]]:
    """:func:`sweep_case` over ``cases`` (``jobs`` worker processes), in case order."""
    rows: list[dict[str, Any]] = []
    executor = ProcessPoolExecutor(jobs) if jobs > 1 else None
    iterator = executor.map(sweep_case, cases, chunksize=1) if executor else map(sweep_case, cases)
    try:
        for index, case_rows in enumerate(iterator, 1):
            rows.extend(case_rows)
            if progress and index % 10 == 0:
                print(f"  {index}/{len(cases)} cases", file=sys.stderr, flush=True)
    finally:
        if executor is not None:
            executor.shutdown()
    return rows


def interleaved_ratio(function: Callable[[], object], reference: Callable[[], object], rounds: int) -> float:
    """Median over ``rounds`` of ``function``'s time ÷ ``reference``'s, the two run in turn in each round."""
    ratios = []
    for _ in range(rounds):
        start = time.perf_counter()
        reference()
        middle = time.perf_counter()
        function()
        ratios.append((time.perf_counter() - middle) / (middle - start))
    return float(np.median(ratios))


def timings(rounds: int = 15, height: int = 1024, width: int = 1280) -> dict[tuple[str, int], float]:
    """``(family, block) → estimate time ÷ copy time`` on the bench's scene (interleaved), plus ``("reference", 1)``."""
    from msflash.lab.bench.processing import benchmark_world
    from msflash.processing.sensor import SensorModel

    world = benchmark_world(height, width)
    frames, spec, leds, camera = world["frames"], world["spec"], world["leds"], world["camera"]
    buffers = [np.empty_like(f) for f in frames]

    def copy() -> None:
        for frame, buffer in zip(frames, buffers):
            np.copyto(buffer, frame)

    channels = accumulate_channel_statistics(frames[0], frames[1:], spec, bin_factor=4).channels
    prior = prior_model(channels, leds, camera)
    sensor = SensorModel()
    lines = [sensor_noise(sensor.electrons_per_dn, sensor.read_noise_e)] * len(frames)

    def job(family: str, factor: int) -> Callable[[], object]:
        if family == "led":
            return lambda: estimate_ambient(
                accumulate_statistics(frames[0], frames[1:], spec, bin_factor=factor, weighting=True), leds
            )
        if family == "prior":
            return lambda: prior.estimate(accumulate_channel_statistics(frames[0], frames[1:], spec, bin_factor=factor))
        if family == "local":
            tiles = _tiles(frames[0].shape, 1, factor)
            return lambda: estimate_local(
                tile_statistics(frames[0], frames[1:], spec, tiles, bin_factor=factor, weighting=True), leds
            )
        return lambda: estimate_ambient(all_pixel_statistics(frames[0], frames[1:], spec, lines), leds)

    out = {("reference", 1): interleaved_ratio(job("reference", 1), copy, rounds)}
    for family in FAMILIES:
        for factor in BLOCK_SIZES:
            out[(family, factor)] = interleaved_ratio(job(family, factor), copy, rounds)
            print(f"  time {family} {factor}: {out[(family, factor)]:.2f}", file=sys.stderr, flush=True)
    return out


def bench_agreement(height: int = 1024, width: int = 1280, seeds: int = 1) -> list[dict[str, Any]]:
    """The ``led`` family's agreement with the all-pixel reference on the bench's scene, per block size and seed."""
    from msflash.lab.bench.processing import benchmark_world
    from msflash.processing import lights
    from msflash.processing.metrics import spectrum_rmse
    from msflash.processing.sensor import SensorModel
    from msflash.processing.spectra import DEFAULT_GRID

    sensor = SensorModel()
    truth = lights.ambient_spectrum("tungsten", DEFAULT_GRID).to_unit("photons").values[:, 0]
    rows = []
    for seed in range(seeds):
        world = benchmark_world(height, width, seed=seed)
        frames, spec, leds = world["frames"], world["spec"], world["leds"]
        lines = [sensor_noise(sensor.electrons_per_dn, sensor.read_noise_e)] * len(frames)
        reference_statistics = all_pixel_statistics(frames[0], frames[1:], spec, lines)
        model_reference = reference_for(leds, world["camera"])
        reference = with_model_error(estimate_ambient(reference_statistics, leds), model_reference)
        for factor in BLOCK_SIZES:
            estimate = estimate_ambient(
                accumulate_statistics(frames[0], frames[1:], spec, bin_factor=factor, weighting=True), leds
            )
            rows.append(
                {
                    "seed": seed,
                    "block": factor,
                    "rmse": spectrum_rmse(estimate.spectrum.values[:, 0], truth),
                    "reference_rmse": spectrum_rmse(reference.spectrum.values[:, 0], truth),
                    **led_agreement(estimate, reference, reference_statistics, leds, model_reference),
                    "correction": estimate.noise_correction.split(":")[0],
                }
            )
    return rows


def build_parser() -> argparse.ArgumentParser:
    """The study's options."""
    parser = argparse.ArgumentParser(prog="python -m tests.harness.block_size", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/block-size.md"), help="markdown page to write")
    parser.add_argument("--png", type=Path, default=Path("docs/block-size.png"), help="chart to write")
    parser.add_argument("--csv", type=Path, help="also write one row per case, family and block size here")
    parser.add_argument("--raw", type=Path, help="raw results (JSON) to write, or to read with --replot")
    parser.add_argument("--quick", action="store_true", help="every 15th case of each split")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes for the sweep")
    parser.add_argument("--rounds", type=int, default=15, help="interleaved timing pairs per point (≥ 15)")
    parser.add_argument("--replot", action="store_true", help="redraw the page and chart from the saved raw results")
    parser.add_argument("--bench-seeds", type=int, default=3, help="noise seeds of the bench scene's agreement")
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run the sweep, the bench agreement and the timings; write the page, the CSV and the chart.

    The raw results go to ``--raw`` (default: block-size.json in the temporary directory) first; ``--replot``
    redraws from them."""
    from tests.harness.block_size_report import write_outputs

    args = build_parser().parse_args(argv)
    raw_path = args.raw or Path(tempfile.gettempdir()) / "block-size.json"
    if args.replot:
        raw = json.loads(raw_path.read_text())
    else:
        started = time.perf_counter()
        cases = select_cases("both", args.quick)
        print(f"sweep: {len(cases)} cases", file=sys.stderr, flush=True)
        rows = run_sweep(cases, args.jobs)
        print("bench scene agreement", file=sys.stderr, flush=True)
        bench = bench_agreement(seeds=args.bench_seeds)
        print("timings", file=sys.stderr, flush=True)
        times = timings(args.rounds)
        raw = {
            "rows": rows,
            "bench": bench,
            "times": [{"family": family, "block": block, "ratio": ratio} for (family, block), ratio in times.items()],
            "seconds": time.perf_counter() - started,
            "quick": args.quick,
            "rounds": args.rounds,
        }
        raw_path.write_text(json.dumps(raw, indent=1))
    write_outputs(args.out, args.png, raw, args.csv)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
