"""``msflash estimate``, ``msflash flash`` and ``msflash synthesize`` on recorded sequences."""

from __future__ import annotations

import argparse
import contextlib
from collections.abc import Callable
from pathlib import Path

import numpy as np

from msflash.acquisition.app.cli_common import UsageError, print_json, progress
from msflash.acquisition.app.options import (
    TARGET_HELP,
    add_estimation_options,
    add_scheduler_options,
    target_value,
    tiles_value,
)
from msflash.acquisition.sequence.locate import ARGUMENT_HELP as SEQUENCE_HELP
from msflash.acquisition.sequence.locate import locate_sequence
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import analysis, many, one_sequence
from msflash.processing.local import LOCAL_METHODS
from msflash.processing.tile_statistics import DEFAULT_TILES
from msflash.processing.user_numbers import plain_number, plain_whole_number

DEFAULT_LOCAL_METHOD = "auto"
"""Default of ``--method``: ``auto`` keeps the global estimate unless a local model predicts held-out tiles
clearly better, so a uniform scene costs nothing (its acceptance results: docs/local-estimation.md)."""


def _weights(text: str, n_leds: int) -> np.ndarray:
    try:
        values = np.array([plain_number(v) for v in text.split(",")], dtype=float)
    except ValueError:
        raise UsageError(f"--weights '{text}': expected comma-separated numbers, one per LED") from None
    if values.size != n_leds:
        raise UsageError(f"--weights has {values.size} values; expected {n_leds} (one per LED)")
    if not np.all(np.isfinite(values)):
        raise UsageError("--weights: expected finite numbers")
    return values


def _add_calibration_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--calibration",
        metavar="DIR",
        default=None,
        help="LED spectra / responsivities from this calibration (msflash calibrate) override the sequence's",
    )


DEFAULT_AMBIENT_MODEL = "led"
"""Default of ``--model``: the LED-span estimate (eq. 4–6), the one ``run`` and ``flash`` solve their flash from.
``auto`` beats it on the harness's mean (docs/ambient-harness.md) but not yet on the worst scenes, and ``run``
and ``flash`` do not use it yet."""


def add_model_option(parser: argparse.ArgumentParser) -> None:
    """``--model led|prior|family|auto`` (docs/light-prior.md, docs/light-families.md)."""
    parser.add_argument(
        "--model",
        default=DEFAULT_AMBIENT_MODEL,
        choices=one_sequence.AMBIENT_MODELS,
        help="ambient model: led (a mix of the LED spectra, eq. 4-6; default), prior (a basis learnt "
        "from measured lights, read through the surfaces' colours; needs the camera's "
        "responsivities), family (light from physics: thermal, discharge, solid-state, transmitted or a "
        "mixture, the family and its complexity chosen by held-out prediction; needs the responsivities), "
        "auto (the LEDs' span unless a family predicts held-out pixels clearly better)",
    )


def _rectangle(text: str) -> tuple[int, int, int, int]:
    """``X,Y,W,H`` (pixels) for ``--reference-patch``."""
    try:
        values = tuple(plain_whole_number(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}': expected X,Y,WIDTH,HEIGHT in whole pixels") from None
    if len(values) != 4 or min(values) < 0:
        raise argparse.ArgumentTypeError(f"'{text}': expected four whole numbers ≥ 0, X,Y,WIDTH,HEIGHT")
    return values


def _file_for_workers(args: argparse.Namespace, path: str | None) -> str | None:
    """A file option as the workers see it (absolute for a scheduler at an address; see many.for_scheduler)."""
    if path is None or getattr(args, "sequence", None) is not None:  # one sequence: as given
        return path
    return many.for_scheduler(args.scheduler or "local", [path])[0]


def _estimate_settings(args: argparse.Namespace) -> one_sequence.EstimateSettings:
    return one_sequence.EstimateSettings(
        solver=args.solver,
        alpha=args.alpha,
        bin_factor=args.bin,
        method=args.method,
        tiles=args.tiles,
        model=getattr(args, "model", DEFAULT_AMBIENT_MODEL),
        calibration=_file_for_workers(args, args.calibration),
        reference_patch=getattr(args, "reference_patch", None),
        reference_chart=_file_for_workers(args, getattr(args, "reference_chart", None)),
    )


def _flash_settings(args: argparse.Namespace, out: str | None) -> one_sequence.FlashSettings:
    target = args.target
    if Path(target).is_file():  # a CSV file rather than an illuminant's name
        target = _file_for_workers(args, target) or target
    return one_sequence.FlashSettings(_estimate_settings(args), args.mode, target, args.bounds, out)


def _many(args: argparse.Namespace) -> list[str] | None:
    """The sequences when the command runs over many (several, a folder of them, or ``--scheduler``), else None
    (``args.sequence`` then names the one)."""
    args.sequence = None
    sequences, expanded = many.sequence_inputs(args.sequences)
    if len(sequences) == 1 and not expanded and args.scheduler is None and args.workers is None:
        args.sequence = sequences[0]
        return None
    return many.for_scheduler(args.scheduler or "local", sequences)


def _run_many(args: argparse.Namespace, record, jobs: list) -> int:
    """Print each sequence's JSON line in input order, its notes and error on stderr; the worst status at the end."""
    done = []
    records = many.run_many(
        record, jobs, args.scheduler or "local", args.workers, verbose=getattr(args, "verbose", 0) > 0
    )
    with contextlib.closing(records):  # the cluster is closed even when printing fails (a closed pipe)
        for result in records:
            for note in result.notes:
                progress(f"{result.sequence}: {note}")
            if result.error is not None:
                progress(f"error: {result.error}")
            print_json(result.json_object())
            done.append(result)
    failed = [result for result in done if result.status]
    if failed:
        progress(f"{len(failed)} of {len(done)} sequences failed")
    return many.exit_status(done)


def _estimate(args: argparse.Namespace) -> int:
    sequences = _many(args)
    settings = _estimate_settings(args)
    if sequences is not None:
        return _run_many(args, many.estimate_record, [(sequence, settings) for sequence in sequences])
    result = one_sequence.estimate_one(args.sequence, settings, progress)
    sequence, payload = result.sequence, result.payload
    if args.json:
        print_json(payload)
    elif result.choice is not None:
        chosen, reason = result.choice
        print(f"ambient estimate of {sequence.directory} ({chosen} model; asked {args.model}): {reason}")
        _print_spectrum(payload["spectrum"], sequence.wavelengths_nm)
    elif result.local is not None:
        _print_local(payload, result.local)
    else:
        estimate = result.estimate
        assert estimate is not None  # the global route
        names = payload["led_names"]
        print(f"ambient estimate of {sequence.directory} ({estimate.method}, alpha {estimate.alpha:.3g})")
        print("ambient weights: " + ", ".join(f"{n}={w:.4g}" for n, w in zip(names, estimate.ambient_weights)))
        print(
            f"relative residual {estimate.relative_residual:.4f}, condition {estimate.condition_number:.3g}, "
            f"{estimate.n_samples} samples, {estimate.saturated_fraction:.1%} saturated"
        )
        _print_spectrum(payload["spectrum"], sequence.wavelengths_nm)
    return 0


def _print_spectrum(spectrum, wavelengths_nm) -> None:
    peak = float(np.max(spectrum)) or 1.0
    for wavelength, value in zip(wavelengths_nm, spectrum):
        print(f"  {wavelength:6.1f} nm  {value / peak:7.4f}  {'#' * int(round(max(value, 0) / peak * 40))}")


def _flash(args: argparse.Namespace) -> int:
    sequences = _many(args)
    if sequences is not None:
        if args.out is not None:
            one_sequence.check_output_type(Path(args.out))
        outputs = many.output_paths(_file_for_workers(args, args.out), sequences)
        jobs = [(sequence, _flash_settings(args, out)) for sequence, out in zip(sequences, outputs, strict=True)]
        return _run_many(args, many.flash_record, jobs)
    result = one_sequence.flash_one(args.sequence, _flash_settings(args, args.out), progress)
    solution, payload = result.solution, result.payload
    if args.json:
        print_json(payload)
    elif result.local is not None:
        names = payload["led_names"]
        print(f"{solution.mode} flash for {payload['sequence']} ({solution.bounds} bounds, {result.local.model} model)")
        label = "area-weighted mean flash weights" if result.local.model == "local" else "flash weights"
        print(f"{label}: " + ", ".join(f"{n}={w:.4g}" for n, w in zip(names, solution.flash_weights)))
        if args.out is not None:
            print(f"wrote {args.out}")
    else:
        names = payload["led_names"]
        print(f"{solution.mode} flash for {result.sequence.directory} ({solution.bounds} bounds)")
        print("flash weights: " + ", ".join(f"{n}={w:.4g}" for n, w in zip(names, solution.flash_weights)))
        if solution.scale is not None:
            print(f"scale s = {solution.scale:.4g} (target {args.target})")
        print(
            f"camera-space chromatic error {solution.relative_error:.4f}"
            + ("" if solution.target_reached else " (target NOT reached)")
        )
    return 0


def _synthesize(args: argparse.Namespace) -> int:
    sequence = read_sequence(locate_sequence(args.sequence))
    weights = _weights(args.weights, len(sequence.leds))
    output = Path(args.out)
    one_sequence.check_raw_output(one_sequence.check_output_type(output), output, sequence)
    image, saturated, layout, flicker = analysis.synthesize_checked(sequence, weights)  # each frame read once
    if flicker is not None and flicker.summary() is not None:  # docs/flicker.md
        progress(str(flicker.summary()))
    one_sequence.write_flash_image(
        output, image, layout.ambient_index, sequence, {"msflash:flash_weights": weights.tolist()}, progress
    )
    clipped = float(saturated.mean())
    if clipped > 0:
        progress(f"warning: {clipped:.1%} of the pixels were saturated in some input frame")
    if args.json:
        print_json({"out": str(output), "flash_weights": weights, "saturated_fraction": clipped})
    else:
        print(f"wrote {output}")
    return 0


# -- spatially varying ambient (issue 9) -------------------------------------------------------
def add_local_options(parser: argparse.ArgumentParser) -> None:
    """``--method auto|global|local`` and ``--tiles N`` (docs/local-estimation.md)."""
    parser.add_argument(
        "--method",
        default=DEFAULT_LOCAL_METHOD,
        choices=LOCAL_METHODS,
        help="ambient model: global (one spectrum, the paper), local (per tile, smoothed across "
        "neighbours) or auto (chosen by leave-one-tile-out prediction error; uniform scenes "
        f"stay global) (default: {DEFAULT_LOCAL_METHOD})",
    )
    parser.add_argument(
        "--tiles",
        type=tiles_value,
        default=DEFAULT_TILES,
        help=f"tiles per side for local estimation (default {DEFAULT_TILES})",
    )


def _print_local(payload: dict, local) -> None:
    names = payload["led_names"]
    chosen = f"{local.model} model" + (
        f", {local.tiles.shape[0]}x{local.tiles.shape[1]} tiles, smoothing {local.smoothing:g} tiles"
        if local.model == "local"
        else ""
    )
    print(
        f"ambient estimate of {payload['sequence']} ({chosen}; asked {local.method}; solver {local.global_estimate.method})"
    )
    if local.selection is not None:
        print(
            "held-out error relative to global: " + ", ".join(f"{k} {v:.3f}" for k, v in local.selection.scores.items())
        )
    label = "area-weighted mean ambient weights" if local.model == "local" else "ambient weights"
    print(f"{label}: " + ", ".join(f"{n}={w:.4g}" for n, w in zip(names, payload["ambient_weights"])))
    if local.model == "local":
        print(
            f"tile relative residuals: median {np.median(local.tile_residuals):.4f}, max {local.tile_residuals.max():.4f}"
        )
    _print_spectrum(payload["spectrum"], payload["wavelengths_nm"])


_SEQUENCES_HELP = (
    f"{SEQUENCE_HELP}; or a folder of those (its sub-folders, in name order); several are run on dask (--scheduler) and give one JSON line each, in input order, a failed "
    "sequence its own error line while the others go on"
)


def _json_and_scheduler(parser: argparse.ArgumentParser, handler: Callable[[argparse.Namespace], int]) -> None:
    """``--json``, the scheduler of several sequences, and the command's handler."""
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object (several sequences: one JSON line each, always)"
    )
    add_scheduler_options(parser, None, "sequences (with several)")
    parser.set_defaults(handler=handler)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``estimate``, ``flash`` and ``synthesize``."""
    estimate = subparsers.add_parser("estimate", help="estimate the ambient illuminant spectrum of a sequence")
    estimate.add_argument("sequences", nargs="+", metavar="SEQUENCE", help=_SEQUENCES_HELP)
    add_estimation_options(estimate)
    _add_calibration_option(estimate)
    add_local_options(estimate)
    add_model_option(estimate)
    estimate.add_argument(
        "--reference-patch",
        type=_rectangle,
        default=None,
        metavar="X,Y,W,H",
        help="a grey or white card in the scene (pixels of the full frame): its colour, free of any reflectance "
        "estimate, joins the evidence that chooses the family and calibrates the estimate (--model prior|family|auto)",
    )
    estimate.add_argument(
        "--reference-chart",
        default=None,
        metavar="FILE",
        help="a colour chart in the scene: a JSON file of patches (rect in pixels, reflectance per wavelength); "
        "their colours, free of any reflectance estimate, join the evidence and calibrate the estimate "
        "(--model prior|family|auto; docs/light-families.md)",
    )
    _json_and_scheduler(estimate, _estimate)

    flash = subparsers.add_parser("flash", help="solve the matching or complementary flash for a sequence")
    flash.add_argument("sequences", nargs="+", metavar="SEQUENCE", help=_SEQUENCES_HELP)
    flash.add_argument("--mode", required=True, choices=("complementary", "matching"))
    flash.add_argument(
        "--target",
        default="D65",
        type=target_value,
        help=TARGET_HELP,
    )
    flash.add_argument(
        "--bounds",
        default="physical",
        choices=("physical", "nonnegative", "free"),
        help="physical: 0..1 (re-capture); nonnegative/free: computational synthesis",
    )
    add_estimation_options(flash)
    _add_calibration_option(flash)
    add_local_options(flash)
    flash.add_argument(
        "--out",
        default=None,
        help="also write the computational flash image (.exr linear float, .tiff 16-bit raw); "
        "with a local estimate the flash weights vary across the frame; with several sequences a path "
        "holding {name}, each sequence folder's name (out/{name}.exr)",
    )
    _json_and_scheduler(flash, _flash)

    synth = subparsers.add_parser("synthesize", help="synthesise the computational flash image from a sequence")
    synth.add_argument("sequence", help=SEQUENCE_HELP)
    synth.add_argument(
        "--weights",
        required=True,
        help="flash weights W1,W2,… (one per LED, full-drive units; a negative first weight needs "
        "the = form, --weights=-0.5,…, or argparse reads it as an option)",
    )
    synth.add_argument(
        "--out", required=True, help="output image: .exr (linear float) or .tiff (16-bit raw at the ambient exposure)"
    )
    synth.add_argument("--json", action="store_true", help="print one JSON object")
    synth.set_defaults(handler=_synthesize)
