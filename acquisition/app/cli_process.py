"""``msflash estimate``, ``msflash flash`` and ``msflash synthesize`` on recorded sequences."""

from __future__ import annotations

import argparse
import json
import warnings
from pathlib import Path

import numpy as np

from msflash.acquisition.app.cli_common import UsageError, positive_int, print_json, progress
from msflash.acquisition.app.options import add_estimation_options
from msflash.acquisition.sequence.format import Sequence, read_sequence
from msflash.acquisition.sequence.image_files import read_image_header, write_image
from msflash.acquisition.sequence.locate import ARGUMENT_HELP as SEQUENCE_HELP
from msflash.acquisition.sequence.locate import locate_sequence
from msflash.acquisition.session import analysis
from msflash.processing.ambient import LED_SIGNAL_Z
from msflash.processing.errors import TargetUnreachableWarning
from msflash.processing.local import DEFAULT_TILES, LOCAL_METHODS
from msflash.processing.synthesis import to_raw_values

DEFAULT_LOCAL_METHOD = "auto"
"""Default of ``--method``: ``auto`` keeps the global estimate unless a local model predicts held-out tiles
clearly better, so a uniform scene costs nothing (its acceptance results: docs/local-estimation.md)."""


def _weights(text: str, n_leds: int) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split(",")], dtype=float)
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


def _read_calibrated(args: argparse.Namespace):
    """The sequence, with a calibration applied (``--calibration`` or the sequence's reference); notes on stderr."""
    sequence, notes = analysis.apply_calibration(
        read_sequence(locate_sequence(args.sequence)), getattr(args, "calibration", None)
    )
    for note in notes:
        progress(note)
    return sequence


_FLASH_GOAL = {"matching": "match", "complementary": "complement"}
"""What each flash mode does to the ambient (for the dark-ambient refusal)."""


def _refuse_dark_ambient(sequence, estimate, what: str) -> None:
    """A UsageError naming the ambient frame when it holds no light: there is no ambient to ``what``.

    The estimate is then noise (or zero): estimate would plot it normalised to full height, matching
    would rescale it to a full-drive mix, and complementary (scale-free, least power) returns a
    flash of ~1e-6 drive that "reaches" the target on the noise.
    """
    if not estimate.ambient_is_dark:
        return
    index = sequence.indices("ambient")[0]
    raise UsageError(
        f"{sequence.path}: frames[{index}].file '{sequence.frames[index].file}': the ambient image holds no light "
        f"(z-score {estimate.ambient_z:.2g} < {LED_SIGNAL_Z:g}: no signal above the black level "
        f"{sequence.camera.black_level:g}); expected an ambient illuminant to {what} — was the light off, the lens "
        "capped or the exposure far too short?"
    )


AMBIENT_MODELS = ("led", "prior", "auto")
DEFAULT_AMBIENT_MODEL = "led"
"""Default of ``--model``: the LED-span estimate (eq. 4–6), the one ``run`` and ``flash`` solve their flash from.
``auto`` beats it on the harness's mean (docs/ambient-harness.md) but not yet on the worst scenes, and ``run``
and ``flash`` do not use it yet."""


def add_model_option(parser: argparse.ArgumentParser) -> None:
    """``--model led|prior|auto`` (docs/light-prior.md)."""
    parser.add_argument(
        "--model",
        default=DEFAULT_AMBIENT_MODEL,
        choices=AMBIENT_MODELS,
        help="ambient model: led (a mix of the LED spectra, eq. 4-6; default), prior (a basis learnt "
        "from measured lights, read through the surfaces' colours; needs the camera's "
        "responsivities), auto (prior only where it predicts held-out pixels better)",
    )


def _estimate(args: argparse.Namespace) -> int:
    sequence = _read_calibrated(args)
    if sequence.partial:
        progress(f"{sequence.path}: the sequence is incomplete (complete: false); estimating from the frames present")
    if args.model != "led":
        return _estimate_with_prior(args, sequence)
    if args.method != "global":
        return _estimate_local(args, sequence)
    estimate = analysis.estimate_sequence(sequence, args.solver, args.alpha, bin_factor=args.bin)
    _refuse_dark_ambient(sequence, estimate, "estimate")
    payload = analysis.estimate_payload(sequence, estimate)
    for warning in estimate.warnings:
        progress(f"warning: {warning}")
    if args.json:
        print_json(payload)
    else:
        names = payload["led_names"]
        print(f"ambient estimate of {sequence.directory} ({estimate.method}, alpha {estimate.alpha:.3g})")
        print("ambient weights: " + ", ".join(f"{n}={w:.4g}" for n, w in zip(names, estimate.ambient_weights)))
        print(
            f"relative residual {estimate.relative_residual:.4f}, condition {estimate.condition_number:.3g}, "
            f"{estimate.n_samples} samples, {estimate.saturated_fraction:.1%} saturated"
        )
        peak = float(np.max(payload["spectrum"])) or 1.0
        for wavelength, value in zip(sequence.wavelengths_nm, payload["spectrum"]):
            print(f"  {wavelength:6.1f} nm  {value / peak:7.4f}  {'#' * int(round(max(value, 0) / peak * 40))}")
    return 0


def _estimate_with_prior(args: argparse.Namespace, sequence: Sequence) -> int:
    """``estimate --model prior|auto``: the light-prior estimate, or ``auto``'s choice between it and eq. 4–6.

    The LED side is what ``--model led`` gives (global, or local when ``--method`` finds the illuminant
    varying across the scene: the light prior is one global spectrum, so a local estimate stays).
    """
    from msflash.acquisition.session.prior_route import led_side, with_model_choice

    stack = analysis.load_frame_stack(sequence)
    led, payload, varies = led_side(sequence, stack, args.method, args.solver, args.alpha, args.tiles, args.bin)
    _refuse_dark_ambient(sequence, led, "estimate")
    payload, chosen, reason = with_model_choice(sequence, stack, payload, args.model, varies)
    for warning in payload["warnings"]:
        progress(f"warning: {warning}")
    if args.json:
        print_json(payload)
    else:
        print(f"ambient estimate of {sequence.directory} ({chosen} model; asked {args.model}): {reason}")
        peak = float(np.max(payload["spectrum"])) or 1.0
        for wavelength, value in zip(sequence.wavelengths_nm, payload["spectrum"]):
            print(f"  {wavelength:6.1f} nm  {value / peak:7.4f}  {'#' * int(round(max(value, 0) / peak * 40))}")
    return 0


def _flash(args: argparse.Namespace) -> int:
    kind = None if args.out is None else _check_output_type(Path(args.out))
    sequence = _read_calibrated(args)
    if args.out is not None:
        _check_raw_output(kind, Path(args.out), sequence)
    if args.method != "global" or args.out is not None:
        return _flash_local(args, sequence)
    estimate = analysis.estimate_sequence(sequence, args.solver, args.alpha, bin_factor=args.bin)
    _refuse_dark_ambient(sequence, estimate, _FLASH_GOAL[args.mode])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        solution = analysis.solve_sequence_flash(
            sequence, args.mode, estimate.ambient_weights, args.target, args.bounds
        )
    for warning in caught:
        progress(f"warning: {warning.message}")
    payload = analysis.flash_payload(sequence, solution, args.target)
    payload["estimate_warnings"] = list(estimate.warnings)
    if args.json:
        print_json(payload)
    else:
        names = payload["led_names"]
        print(f"{solution.mode} flash for {sequence.directory} ({solution.bounds} bounds)")
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
    _check_raw_output(_check_output_type(output), output, sequence)
    image, saturated, stack = analysis.synthesize_sequence(sequence, weights)
    _write_flash_image(output, image, stack, sequence, {"msflash:flash_weights": weights.tolist()})
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
        type=positive_int,
        default=DEFAULT_TILES,
        help=f"tiles per side for local estimation (default {DEFAULT_TILES})",
    )


def _estimate_local(args: argparse.Namespace, sequence: Sequence) -> int:
    local = analysis.estimate_sequence_local(
        sequence, args.method, args.solver, args.alpha, args.tiles, bin_factor=args.bin
    )
    _refuse_dark_ambient(sequence, local.global_estimate, "estimate")
    payload = analysis.local_estimate_payload(sequence, local)
    for warning in payload["warnings"]:
        progress(f"warning: {warning}")
    if args.json:
        print_json(payload)
        return 0
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
    peak = float(np.max(payload["spectrum"])) or 1.0
    for wavelength, value in zip(payload["wavelengths_nm"], payload["spectrum"]):
        print(f"  {wavelength:6.1f} nm  {value / peak:7.4f}  {'#' * int(round(max(value, 0) / peak * 40))}")
    return 0


def _flash_local(args: argparse.Namespace, sequence: Sequence) -> int:
    stack = analysis.load_frame_stack(sequence)
    local = analysis.estimate_sequence_local(
        sequence, args.method, args.solver, args.alpha, args.tiles, stack=stack, bin_factor=args.bin
    )
    _refuse_dark_ambient(sequence, local.global_estimate, _FLASH_GOAL[args.mode])
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        solution, tile_weights, _ = analysis.solve_sequence_flash_local(
            sequence, args.mode, local, args.target, args.bounds
        )
    for message in dict.fromkeys(str(warning.message) for warning in caught):
        progress(f"warning: {message}")
    payload = analysis.local_flash_payload(sequence, solution, local, tile_weights, args.target)
    if args.out is not None:
        output = Path(args.out)
        if local.model == "local":
            image, saturated, _ = analysis.synthesize_sequence_local(sequence, tile_weights, local, stack)
        else:
            image, saturated, _ = analysis.synthesize_sequence(sequence, solution.flash_weights, stack)
        metadata = {
            "msflash:flash_weights": solution.flash_weights.tolist(),
            "msflash:method": local.model,
            "msflash:mode": solution.mode,
        }
        if local.model == "local":
            metadata["msflash:tile_flash_weights"] = json.dumps(np.round(tile_weights, 6).tolist())
        _write_flash_image(output, image, stack, sequence, metadata)
        payload["out"] = str(output)
        payload["saturated_fraction"] = float(saturated.mean())
    if args.json:
        print_json(payload)
    else:
        names = payload["led_names"]
        print(f"{solution.mode} flash for {payload['sequence']} ({solution.bounds} bounds, {local.model} model)")
        label = "area-weighted mean flash weights" if local.model == "local" else "flash weights"
        print(f"{label}: " + ", ".join(f"{n}={w:.4g}" for n, w in zip(names, solution.flash_weights)))
        if args.out is not None:
            print(f"wrote {args.out}")
    return 0


_OUTPUT_TYPES = {".exr": "exr", ".tif": "tiff", ".tiff": "tiff"}
"""``--out`` suffixes: linear float EXR, or 16-bit raw TIFF at the ambient frame's exposure and gain."""


def _check_output_type(output: Path) -> str:
    """``exr`` or ``tiff`` for ``--out``; refused before any work is done."""
    kind = _OUTPUT_TYPES.get(output.suffix.lower())
    if kind is None:
        raise UsageError(f"--out {output}: unsupported image type; expected .exr (linear float) or .tiff (16-bit raw)")
    return kind


def _check_raw_output(kind: str | None, output: Path, sequence: Sequence) -> None:
    """Refuse a raw ``.tiff`` (``kind`` from :func:`_check_output_type`) for a sequence whose frames are float (EXR): raw TIFF values are whole counts
    in the frames' own encoding, and float frames have none (normalised ones, white level 1, would
    all round to 0 or 1)."""
    ambient = sequence.indices("ambient")
    if kind != "tiff" or not ambient:
        return
    header = read_image_header(sequence.frame_path(ambient[0]))
    if np.issubdtype(header.dtype, np.floating):
        raise UsageError(
            f"--out {output}: the frames of {sequence.path} are float ({sequence.frames[ambient[0]].file}, white level "
            f"{sequence.camera.white_level:g}), so a 16-bit raw TIFF cannot hold them in their encoding; expected .exr "
            "(linear float)"
        )


def _write_flash_image(
    output: Path, image: np.ndarray, stack: analysis.FrameStack, sequence: Sequence, metadata: dict
) -> None:
    kind = _check_output_type(output)
    try:
        if kind == "exr":
            write_image(output, image, {**metadata, "msflash:units": "value per us*gain"})
            return
        ambient = sequence.frames[stack.ambient_index]
        white = sequence.camera.white_level
        raw = to_raw_values(image, ambient.exposure_us, ambient.gain, sequence.camera.black_level, white)
        write_image(output, raw, {**metadata, "msflash:exposure_us": ambient.exposure_us, "msflash:gain": ambient.gain})
    except OSError as err:
        blocking = next((parent for parent in output.parents if parent.exists()), None)
        reason = (
            f"{blocking} is not a directory"
            if blocking is not None and not blocking.is_dir()
            else err.strerror or str(err)
        )
        raise UsageError(f"--out {output}: cannot be written ({reason}); expected a writable file path") from None
    clipped = int(np.count_nonzero((raw >= white) | (raw <= 0)))
    if clipped:
        progress(
            f"warning: {clipped} of the {raw.size} samples of {output} ({clipped / raw.size:.2%}) are clipped to the "
            f"raw range 0…{white:g} at the ambient frame's exposure; .exr keeps the linear values"
        )


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``estimate``, ``flash`` and ``synthesize``."""
    estimate = subparsers.add_parser("estimate", help="estimate the ambient illuminant spectrum of a sequence")
    estimate.add_argument("sequence", help=SEQUENCE_HELP)
    add_estimation_options(estimate)
    _add_calibration_option(estimate)
    add_local_options(estimate)
    add_model_option(estimate)
    estimate.add_argument("--json", action="store_true", help="print one JSON object")
    estimate.set_defaults(handler=_estimate)

    flash = subparsers.add_parser("flash", help="solve the matching or complementary flash for a sequence")
    flash.add_argument("sequence", help=SEQUENCE_HELP)
    flash.add_argument("--mode", required=True, choices=("complementary", "matching"))
    flash.add_argument(
        "--target", default="D65", help="complementary target: an illuminant name (D65, A, FL2…) or a CSV file"
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
        "with a local estimate the flash weights vary across the frame",
    )
    flash.add_argument("--json", action="store_true", help="print one JSON object")
    flash.set_defaults(handler=_flash)

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
