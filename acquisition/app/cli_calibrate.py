"""``msflash calibrate leds|camera|dark|linearity``: measure and store a calibration (calibration/files.py).

Every command updates the calibration directory given by ``--out`` (sections it does not measure
are kept; each save gets a new id). Bad input (a malformed spectrometer file, a sequence without
dark frames) exits with status 2 and one ``msflash: error:`` line.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.app.cli_common import UsageError, claimed_output, positive_int, print_json, progress
from msflash.acquisition.app.evaluation import check_layout, sequence_layout  # the layouts of `msflash evaluate`
from msflash.acquisition.app.options import layout_options
from msflash.acquisition.sequence.format import Sequence, read_sequence
from msflash.acquisition.sequence.locate import ARGUMENT_HELP as SEQUENCE_HELP
from msflash.acquisition.sequence.locate import locate_sequence
from msflash.calibration.camera_response import (
    estimate_responsivities,
    learn_prior,
    responsivity_rmse,
)
from msflash.calibration.chart_sequence import (
    estimate_from_measurements,
    resolve_light,
    sequence_measurements,
)
from msflash.calibration.dark import measure_dark, measure_linearity
from msflash.calibration.errors import CalibrationError
from msflash.calibration.files import CalibrationSet, load_or_new, save_calibration
from msflash.calibration.led_spectra import characterise_led, relative_power_through_camera
from msflash.calibration.spectrometer import (
    measurement_to_spectra,
    read_spectrometer_file,
    subtract_dark,
)
from msflash.calibration.validation import calibration_lights, simulate_chart_responses
from msflash.calibration.white_reference import parse_roi, white_led_responses
from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID, Spectra


def _bad_input(handler: Callable[[argparse.Namespace], int]) -> Callable[[argparse.Namespace], int]:
    """Calibration errors are bad input: exit 2 with one line."""

    def run(args: argparse.Namespace) -> int:
        try:
            # One writer per calibration directory at a time (issue 19): a second calibrate gets exit 2.
            with claimed_output(args.out, f"msflash calibrate {args.calibrate_command}"):
                return handler(args)
        except CalibrationError as err:
            raise UsageError(str(err)) from err

    return run


def _existing(directory: str) -> CalibrationSet:
    """The calibration in ``directory`` to update (or a new one); what reading it clipped on stderr."""
    calibration = load_or_new(directory)
    for note in calibration.notes:
        progress(note)
    return calibration


def _plot_leds(path: Path, spectra, characterisations) -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot

    figure, axis = pyplot.subplots(figsize=(7, 4))
    for index, item in enumerate(characterisations):
        axis.plot(
            spectra.wavelengths_nm,
            spectra.values[:, index],
            label=f"{item.name} ({item.peak_nm:.0f} nm, FWHM {item.fwhm_nm:.0f})",
        )
    axis.set_xlabel("wavelength (nm)")
    axis.set_ylabel(f"spectral power ({spectra.unit})")
    axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    pyplot.close(figure)


def _measured_leds(args: argparse.Namespace) -> tuple[Spectra, list, dict]:
    """Spectra, characterisations and the ``leds`` section from the spectrometer exports."""
    dark = read_spectrometer_file(args.dark, args.unit, args.column) if args.dark else None
    measurements, characterisations = [], []
    for file in args.files:
        measurement = read_spectrometer_file(file, args.unit, args.column)
        if dark is not None:
            measurement = subtract_dark(measurement, dark)
        item = characterise_led(measurement)
        for warning in item.warnings:
            progress(f"warning: {warning}")
        measurements.append(measurement)
        characterisations.append(item)
    spectra = measurement_to_spectra(measurements, DEFAULT_GRID).to_unit("energy")
    section = {
        "peaks_nm": [c.peak_nm for c in characterisations],
        "fwhm_nm": [c.fwhm_nm for c in characterisations],
        "centroids_nm": [c.centroid_nm for c in characterisations],
        "models": [
            {"model": "Ohno2005 asymmetric", **c.model, "relative_rms_residual": c.model_residual}
            for c in characterisations
        ],
        "sources": [str(f) for f in args.files],
        "dark": str(args.dark) if args.dark else None,
        "relative_power": None,
        "relative_power_note": "ratios as measured by the spectrometer; measure them through the camera on a white "
        "reference with --white SEQ when the probe moved between LEDs",
        "warnings": [w for c in characterisations for w in c.warnings],
        "clipped_negatives": spectra.metadata.get("clipped_negatives", []),
    }
    for note in spectra.metadata.get("clipped_notes", []):
        progress(note)
    return spectra, characterisations, section


def _white_power(
    args: argparse.Namespace, sequence: Sequence, shapes: Spectra, calibration: CalibrationSet
) -> tuple[Spectra, dict]:
    """``shapes`` scaled to the power ratios the camera sees on the white reference ``sequence`` (``--white``)."""
    if sequence.leds and len(sequence.leds) != shapes.count:
        raise UsageError(
            f"--white {args.white}: the sequence has {len(sequence.leds)} LEDs but {shapes.count} LED "
            "spectra were given; expected one spectrum per LED, in the sequence's order"
        )
    if calibration.camera_responsivities is not None:
        camera, camera_from = calibration.camera_responsivities, f"calibration {args.out}"
    elif (from_sequence := sequence.camera_responsivities()) is not None:
        camera, camera_from = from_sequence, f"sequence {sequence.path}"
    else:
        raise UsageError(
            f"--white {args.white}: no camera responsivities, neither in {args.out} nor in the sequence; "
            "expected 'msflash calibrate camera … --out' first (or a sequence that records them)"
        )
    roi = parse_roi(args.white_roi) if args.white_roi else None
    white = white_led_responses(sequence, roi)
    for warning in white.warnings:
        progress(f"warning: {warning}")
    reflectance = None
    if args.white_reflectance:
        try:
            reflectance = (
                datasets.load_spectra_csv(args.white_reflectance, kind="reflectance", unit="none")
                .select([0])
                .resample(shapes.grid, outside="error")
            )
        except (SpectralDataError, ValueError, OSError) as err:
            raise UsageError(
                f"--white-reflectance {args.white_reflectance}: {err}; expected a CSV "
                "'wavelength_nm, reflectance' covering the LEDs"
            ) from err
    peaks = shapes.values.max(axis=0)
    if not np.all(peaks > 0):
        raise UsageError(
            f"LED spectra {', '.join(n for n, p in zip(shapes.names, peaks, strict=True) if not p > 0)}: "
            "no positive value; expected an emission peak"
        )
    shapes = shapes.replace(values=shapes.values / peaks)  # each LED's peak 1: `power` is then its peak's ratio
    power = relative_power_through_camera(
        shapes, white.responses, camera.resample(shapes.grid, outside="zero"), reflectance
    )
    scaled = shapes.replace(values=shapes.values * power)
    report = {
        "relative_power": power.tolist(),
        "relative_power_note": None,
        "relative_power_source": {
            "white_sequence": str(sequence.path),
            "camera_responsivities": camera_from,
            "white_reflectance": args.white_reflectance,
            **white.report(),
        },
    }
    return scaled, report


def _leds(args: argparse.Namespace) -> int:
    if not args.files and not args.white:
        raise UsageError("calibrate leds: expected spectrometer exports FILES…, --white SEQ, or both")
    calibration = _existing(args.out)
    white = read_sequence(locate_sequence(args.white, "--white ")) if args.white else None
    characterisations: list = []
    if args.files:
        spectra, characterisations, section = _measured_leds(args)
    elif calibration.led_spectra is not None:
        spectra, section = calibration.led_spectra, dict(calibration.leds)
        progress(f"LED shapes from {args.out}")
    else:
        assert white is not None  # FILES or --white was required above
        spectra, section = (
            white.led_spectra().resample(DEFAULT_GRID, outside="zero").to_unit("energy"),
            {"sources": [f"{white.path} (led spectra as recorded)"]},
        )
        progress(f"LED shapes from {white.path} (no spectrometer exports, no LED section in {args.out})")
    if white is not None:
        spectra, power = _white_power(args, white, spectra, calibration)
        section = {**section, **power}
    calibration = calibration.updated(led_spectra=spectra, leds=section)
    path = save_calibration(calibration, args.out)
    if characterisations:
        _plot_leds(Path(args.out) / "leds.png", spectra, characterisations)
    payload: dict[str, Any] = {
        "calibration": str(path),
        "id": calibration.id,
        "leds": [
            {
                "name": c.name,
                "peak_nm": c.peak_nm,
                "fwhm_nm": c.fwhm_nm,
                "model_residual": c.model_residual,
                "saturated": c.saturated,
                "snr": c.snr,
            }
            for c in characterisations
        ],
        "relative_power": dict(zip(spectra.names, section["relative_power"], strict=True))
        if section.get("relative_power")
        else None,
        "clipped_negatives": section.get("clipped_negatives", []),
    }
    if args.json:
        print_json(payload)
    else:
        for c in characterisations:
            print(
                f"{c.name}: peak {c.peak_nm:.1f} nm, FWHM {c.fwhm_nm:.1f} nm, model residual {c.model_residual:.3f}"
                + (" SATURATED" if c.saturated else "")
            )
        if payload["relative_power"]:
            print(
                "relative power through the camera: "
                + ", ".join(f"{name} {value:.3f}" for name, value in payload["relative_power"].items())
            )
        print(f"wrote {path} (id {calibration.id})")
    return 0


def _camera_from_sequences(args: argparse.Namespace) -> int:
    if args.chart != "macbeth":
        raise UsageError(
            f"--chart {args.chart}: recorded sequences support the macbeth layout only; expected --chart macbeth"
        )
    sequences = [read_sequence(locate_sequence(directory, "--sequence ")) for directory in args.sequence]
    if args.light and len(args.light) != len(sequences):
        raise UsageError(
            f"--light given {len(args.light)} times for {len(sequences)} sequences; expected one per "
            "sequence, in order (NAME, CSV file, or 'none' for an unknown ambient)"
        )
    grid = sequences[0].grid
    lights = [
        None if spec is None or spec.lower() == "none" else resolve_light(spec, grid)
        for spec in (args.light or [None] * len(sequences))
    ]
    chart = datasets.macbeth().resample(grid, outside="edge")

    # Each sequence its own layout (detected unless --patch-px/--border-px): the chart may move.
    layouts = [
        sequence_layout(sequence, args.chart, args.patch_px, args.border_px, args.margin_px) for sequence in sequences
    ]
    for sequence, layout in zip(sequences, layouts, strict=True):  # the layout must fit before anything is estimated
        index = sequence.indices("ambient")[0] if sequence.indices("ambient") else 0
        raw = sequence.load_frame(index).astype(np.float64)
        layout_map = layout.build(raw.shape[:2])
        check_layout(raw, layout_map, sequence.camera.cfa)
        if layout.report["detected"]:
            progress(f"{sequence.directory}: {layout_map.description}")
    labels_for = [lambda shape, excluded, layout=layout: layout.build(shape, excluded).labels for layout in layouts]
    measurements = sequence_measurements(sequences, lights, chart, labels_for)
    cameras = {name: s.resample(grid, outside="zero") for name, s in datasets.paper_cameras().items()}
    unknown = [name for name in args.prior_exclude if name not in cameras]
    if unknown:
        raise UsageError(f"--prior-exclude {unknown}: not among the 34 paper cameras; expected names like NikonD100")
    prior = learn_prior(cameras, exclude=args.prior_exclude) if args.method != "smoothness" else None
    progress(
        f"{len(measurements.frames)} chart frames, {measurements.data.shape[0]} patch means; "
        f"prior from {len(prior.cameras) if prior else 0} cameras"
    )
    result = estimate_from_measurements(measurements, args.method, prior)
    estimate = result.estimate
    recorded = sequences[0].camera_responsivities()
    rmse = responsivity_rmse(estimate.responsivities, recorded.to_unit("photons")) if recorded is not None else None
    calibration = _existing(args.out).updated(
        camera_responsivities=estimate.responsivities,
        camera={
            "method": estimate.method,
            "alphas": list(estimate.alphas),
            "shrinkages": list(estimate.shrinkages),
            "relative_residual": list(estimate.relative_residual),
            "chart": args.chart,
            "sequences": [str(s.directory) for s in sequences],
            "lights": args.light or [],
            "light_scales": result.light_scales,
            "frames": list(measurements.frames),
            "prior_excluded": list(args.prior_exclude),
            "layouts": [layout.report for layout in layouts],
            "rmse_vs_sequence_responsivity": rmse,
        },
    )
    path = save_calibration(calibration, args.out)
    payload = {
        "calibration": str(path),
        "id": calibration.id,
        "method": estimate.method,
        "light_scales": result.light_scales,
        "relative_residual": list(estimate.relative_residual),
        "layouts": [
            {"sequence": str(s.directory), **layout.report} for s, layout in zip(sequences, layouts, strict=True)
        ],
        "rmse_vs_sequence_responsivity": rmse,
    }
    if args.json:
        print_json(payload)
    else:
        print(
            f"responsivities recovered ({estimate.method}) from {len(measurements.frames)} chart frames"
            + (f", RMSE vs the sequence's recorded responsivities {rmse:.4f}" if rmse is not None else "")
        )
        print(f"wrote {path} (id {calibration.id})")
    return 0


def _camera(args: argparse.Namespace) -> int:
    if args.sequence and args.simulate:
        raise UsageError("calibrate camera: --sequence and --simulate exclude each other; expected one")
    if args.sequence:
        return _camera_from_sequences(args)
    if not args.simulate:
        raise UsageError("calibrate camera: expected --sequence SEQ… (recorded chart sequences) or --simulate")
    cameras = {name: s.resample(DEFAULT_GRID, outside="zero") for name, s in datasets.paper_cameras().items()}
    if args.camera not in cameras:
        raise UsageError(f"--camera '{args.camera}': not one of the 34 paper cameras; expected e.g. NikonD100")
    chart = datasets.macbeth().resample(DEFAULT_GRID) if args.chart == "macbeth" else datasets.chart110()
    lights = calibration_lights(DEFAULT_GRID)
    progress(f"simulating {args.chart} under {lights.count} lights ({', '.join(lights.names)}) with {args.camera}")
    truth = cameras[args.camera]
    responses, std = simulate_chart_responses(truth, chart, lights, rng=np.random.default_rng(args.seed))
    prior = learn_prior(cameras, exclude=[args.camera])  # never the camera under test
    estimate = estimate_responsivities(
        responses, chart, lights, args.method, prior if args.method != "smoothness" else None, std
    )
    rmse = responsivity_rmse(estimate.responsivities, truth)
    calibration = _existing(args.out).updated(
        camera_responsivities=estimate.responsivities,
        camera={
            "method": estimate.method,
            "alphas": list(estimate.alphas),
            "shrinkages": list(estimate.shrinkages),
            "relative_residual": list(estimate.relative_residual),
            "chart": args.chart,
            "lights": list(lights.names),
            "simulated_camera": args.camera,
            "rmse_vs_truth": rmse,
        },
    )
    path = save_calibration(calibration, args.out)
    payload = {"calibration": str(path), "id": calibration.id, "method": estimate.method, "rmse_vs_truth": rmse}
    if args.json:
        print_json(payload)
    else:
        print(f"{args.camera}: responsivities recovered ({estimate.method}), RMSE vs truth {rmse:.4f}")
        print(f"wrote {path} (id {calibration.id})")
    return 0


def _dark(args: argparse.Namespace) -> int:
    sequence = read_sequence(locate_sequence(args.sequence))
    indices = sequence.indices("dark")
    if not indices:
        raise UsageError(f"{sequence.path}: frames has no 'dark' frame; expected frames with role 'dark'")
    # Dark frames measure the black level, so the declared one is not held against them.
    result = measure_dark([sequence.load_frame(i, check_levels=False) for i in indices], sequence.camera.cfa)
    calibration = _existing(args.out).updated(
        dark={**result.as_dict(), "cfa": sequence.camera.cfa, "sequence": str(sequence.directory)}
    )
    path = save_calibration(calibration, args.out)
    if args.json:
        print_json({"calibration": str(path), "id": calibration.id, **result.as_dict()})
    else:
        print("black level per channel: " + ", ".join(f"{v:.2f}" for v in result.black_level))
        print("read noise (DN): " + ", ".join(f"{v:.2f}" for v in result.read_noise_dn))
        print(f"wrote {path} (id {calibration.id})")
    return 0


def _linearity(args: argparse.Namespace) -> int:
    sequence = read_sequence(locate_sequence(args.sequence))
    indices = [i for i, f in enumerate(sequence.frames) if f.role != "dark"]
    lights = sorted({sequence.frames[i].led_levels for i in indices})
    if len(lights) > 1:  # e.g. a chart sequence: each frame under other LEDs, so no common response curve
        raise UsageError(
            f"{sequence.path}: the lit frames are under {len(lights)} different illuminations (LED levels "
            f"{', '.join(str(list(levels)) for levels in lights[:3])}{', …' if len(lights) > 3 else ''}); "
            "expected one illumination at several exposures of a uniform target"
        )
    if len(indices) < 3:
        raise UsageError(
            f"{sequence.path}: {len(indices)} lit frames; expected at least 3 exposures of a uniform target"
        )
    calibration = _existing(args.out)
    black = calibration.dark["black_level"] if calibration.dark else sequence.camera.black_level
    frames = [sequence.load_frame(i) for i in indices]
    exposures = [sequence.frames[i].exposure_us * sequence.frames[i].gain for i in indices]
    result = measure_linearity(frames, exposures, black, sequence.camera.cfa, sequence.camera.white_level)
    calibration = calibration.updated(linearity={**result.as_dict(), "sequence": str(sequence.directory)})
    path = save_calibration(calibration, args.out)
    if args.json:
        print_json({"calibration": str(path), "id": calibration.id, **result.as_dict()})
    else:
        print(
            f"max deviation from linear {result.max_relative_deviation:.4f}, linear up to "
            f"{result.linear_limit_dn} DN, saturation level {result.saturation_level}"
        )
        print(f"wrote {path} (id {calibration.id})")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``calibrate`` with ``leds``, ``camera``, ``dark`` and ``linearity``."""
    calibrate = subparsers.add_parser(
        "calibrate", help="measure LED spectra, camera responsivities, dark and linearity"
    )
    commands = calibrate.add_subparsers(dest="calibrate_command", metavar="WHAT", parser_class=type(calibrate))
    calibrate.set_defaults(
        handler=lambda args: (_ for _ in ()).throw(
            UsageError("calibrate: expected one of leds, camera, dark, linearity")
        )
    )

    leds = commands.add_parser(
        "leds", help="LED spectra from spectrometer exports; their power ratios through the camera"
    )
    leds.add_argument("files", nargs="*", help="spectrometer exports (CSV or text: wavelength, value), one per LED")
    leds.add_argument("--unit", default="energy", choices=("energy", "photons"), help="what the value column holds")
    leds.add_argument("--column", type=positive_int, default=None, help="value column when there are more than two")
    leds.add_argument("--dark", help="a dark export (shutter closed) to subtract")
    leds.add_argument(
        "--white",
        metavar="SEQ",
        help="a sequence of a white reference (ambient + one frame per LED): the LEDs' power ratios as "
        "the camera sees them (shapes from FILES, else the calibration's, else the sequence's)",
    )
    leds.add_argument("--white-roi", metavar="X,Y,W,H", help="where the white reference is (default: the central half)")
    leds.add_argument(
        "--white-reflectance",
        metavar="CSV",
        help="the reference's reflectance, 'wavelength_nm, reflectance' (default: spectrally flat)",
    )
    leds.add_argument("--out", required=True, help="calibration directory (created or updated)")
    leds.add_argument("--json", action="store_true")
    leds.set_defaults(handler=_bad_input(_leds))

    camera = commands.add_parser(
        "camera", help="camera responsivities from a chart under the LEDs and broadband lights"
    )
    camera.add_argument(
        "--sequence",
        nargs="+",
        default=[],
        metavar="SEQ",
        help="recorded chart sequences (format v1): LED frames and each ambient frame",
    )
    camera.add_argument(
        "--light",
        action="append",
        default=[],
        metavar="NAME_OR_CSV",
        help="the known broadband light of each sequence's ambient frame, in order (a name like "
        "tungsten/daylight/D65, a CSV 'wavelength_nm, value' in energy, or 'none'); its power is "
        "estimated",
    )
    layout_options(camera, patch_type=positive_int)  # with --sequence, as `msflash evaluate`
    camera.add_argument(
        "--prior-exclude",
        action="append",
        default=[],
        metavar="NAME",
        help="leave this paper camera out of the learned prior (e.g. the camera under test)",
    )
    camera.add_argument("--simulate", action="store_true", help="render the chart in the sim world instead")
    camera.add_argument("--camera", default="NikonD100", help="simulated camera (one of the 34 paper cameras)")
    camera.add_argument("--chart", default="macbeth", choices=("macbeth", "chart110"))
    camera.add_argument(
        "--method",
        default="pca_prior",
        choices=("pca_prior", "pca_subspace", "smoothness"),
        help="prior: the learned second moment (default), its best subspace by evidence, or smoothness",
    )
    camera.add_argument("--seed", type=int, default=0)
    camera.add_argument("--out", required=True, help="calibration directory (created or updated)")
    camera.add_argument("--json", action="store_true")
    camera.set_defaults(handler=_bad_input(_camera))

    for name, handler, text in (
        ("dark", _dark, "black level and read noise from a sequence's dark frames"),
        ("linearity", _linearity, "linearity and saturation from frames at several exposures"),
    ):
        sub = commands.add_parser(name, help=text)
        sub.add_argument("sequence", help=SEQUENCE_HELP)
        sub.add_argument("--out", required=True, help="calibration directory (created or updated)")
        sub.add_argument("--json", action="store_true")
        sub.set_defaults(handler=_bad_input(handler))
