"""``msflash calibrate leds|camera|dark|linearity``: measure and store a calibration (calibration/files.py).

Every command updates the calibration directory given by ``--out`` (sections it does not measure
are kept; each save gets a new id). Bad input (a malformed spectrometer file, a sequence without
dark frames) exits with status 2 and one ``msflash: error:`` line.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from msflash.acquisition.app.cli_common import UsageError, claimed_output, positive_int, print_json, progress, seed_int
from msflash.acquisition.app.options import layout_options
from msflash.acquisition.sequence.locate import ARGUMENT_HELP as SEQUENCE_HELP
from msflash.acquisition.sequence.locate import locate_sequence
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.calibration_inputs import (
    camera_from_chart_sequences,
    dark_of_sequence,
    led_power_through_camera,
    linearity_of_sequence,
    measured_leds,
    simulated_camera_calibration,
)
from msflash.acquisition.session.chart_exports import chart_from_exports
from msflash.acquisition.session.chart_layout import chart_reference
from msflash.calibration.errors import CalibrationError
from msflash.calibration.files import CalibrationSet, load_or_new, save_calibration
from msflash.calibration.led_exports import ExportOptions
from msflash.processing.spectra import DEFAULT_GRID
from msflash.processing.user_numbers import plain_number


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (argparse names the option and exits 2).

    >>> positive_float("2.5")
    2.5
    """
    try:
        value = plain_number(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}': expected a number > 0") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"'{text}': expected a finite number > 0")
    return value


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


def _chart(spec: str | None, calibration: CalibrationSet, grid: str | None = None) -> Any:
    """``--chart``: a built-in name, a CSV of the chart's reflectances, else the calibration's measured chart.

    The measured chart keeps the grid ``calibrate chart --chart-grid`` gave it unless ``--chart-grid`` says otherwise.
    """
    if spec == "chart110":
        return "chart110"
    if spec is None and calibration.chart_reflectances is not None:
        rows, columns = calibration.chart.get("rows"), calibration.chart.get("columns")
        if grid is None and isinstance(rows, int) and isinstance(columns, int):
            grid = f"{rows}x{columns}"
        progress(f"chart reflectances from calibration {calibration.id} (calibrate chart), {grid or 'default'} grid")
    return chart_reference(spec, calibration.chart_reflectances, f"calibration {calibration.id}", grid)


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
            label=f"{item.name} (measured peak {item.peak_nm:.1f} nm, FWHM {item.fwhm_nm:.0f})",
        )
    axis.set_xlabel("wavelength (nm)")
    axis.set_ylabel(f"spectral power ({spectra.unit})")
    axis.legend(fontsize=7)
    figure.tight_layout()
    figure.savefig(path, dpi=100)
    pyplot.close(figure)


def _leds(args: argparse.Namespace) -> int:
    if not args.files and not args.white:
        raise UsageError("calibrate leds: expected spectrometer exports FILES…, --white SEQ, or both")
    calibration = _existing(args.out)
    white = read_sequence(locate_sequence(args.white, "--white ")) if args.white else None
    characterisations: list = []
    if args.files:
        measured = measured_leds(
            args.files,
            args.unit,
            args.column,
            args.dark,
            no_dark=args.no_dark,
            integration_time_ms=args.integration_time_ms,
            spectrometer_response=args.spectrometer_response,
        )
        spectra, characterisations, section = measured.spectra, list(measured.characterisations), measured.section
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
        spectra, power = led_power_through_camera(
            white, spectra, calibration, args.out, args.white_roi, args.white_reflectance
        )
        section = {**section, **power}
    calibration = calibration.updated(led_spectra=spectra, leds=section)
    path = save_calibration(calibration, args.out)
    if characterisations:
        _plot_leds(Path(args.out) / "leds.png", spectra, characterisations)
    relative_power = (
        dict(zip(spectra.names, section["relative_power"], strict=True)) if section.get("relative_power") else None
    )
    payload: dict[str, Any] = {
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
        "relative_power": relative_power,
        "clipped_negatives": section.get("clipped_negatives", []),
    }
    lines = [
        f"{c.name}: peak {c.peak_nm:.1f} nm, FWHM {c.fwhm_nm:.1f} nm, model residual {c.model_residual:.3f}"
        + (" SATURATED" if c.saturated else "")
        for c in characterisations
    ]
    if relative_power:
        lines.append(
            "relative power through the camera: "
            + ", ".join(f"{name} {value:.3f}" for name, value in relative_power.items())
        )
    return _report_saved(args, calibration, path, payload, lines)


def _camera_from_sequences(args: argparse.Namespace) -> int:
    sequences = [read_sequence(locate_sequence(directory, "--sequence ")) for directory in args.sequence]
    existing = _existing(args.out)
    if args.chart == "chart110":
        raise UsageError("--chart chart110: recorded sequences need a chart on a grid; expected macbeth or a CSV")
    result = camera_from_chart_sequences(
        sequences,
        args.light,
        args.method,
        args.prior_exclude,
        _chart(args.chart, existing, args.chart_grid),
        args.patch_px,
        args.border_px,
        args.margin_px,
        light_field="flat" if args.flat_light else "quadratic",
    )
    estimate, rmse = result.estimate, result.rmse_vs_recorded
    calibration = existing.updated(camera_responsivities=estimate.responsivities, camera=result.section())
    path = save_calibration(calibration, args.out)
    payload = {
        "method": estimate.method,
        "light_scales": result.light_scales,
        "relative_residual": list(estimate.relative_residual),
        "layouts": [
            {"sequence": str(s.directory), **layout.report} for s, layout in zip(sequences, result.layouts, strict=True)
        ],
        "rmse_vs_sequence_responsivity": rmse,
        "chart": result.chart,
        "light_field": result.light_field,
    }
    line = f"responsivities recovered ({estimate.method}) from {len(result.measurements.frames)} chart frames" + (
        f", RMSE vs the sequence's recorded responsivities {rmse:.4f}" if rmse is not None else ""
    )
    return _report_saved(args, calibration, path, payload, [line])


def _camera(args: argparse.Namespace) -> int:
    if args.sequence and args.simulate:
        raise UsageError("calibrate camera: --sequence and --simulate exclude each other; expected one")
    if args.sequence:
        return _camera_from_sequences(args)
    if not args.simulate:
        raise UsageError("calibrate camera: expected --sequence SEQ… (recorded chart sequences) or --simulate")
    existing = _existing(args.out)
    # The booth's measured LEDs, when the calibration has them, are the lights the chart is rendered under.
    simulated = simulated_camera_calibration(
        args.camera, _chart(args.chart, existing, args.chart_grid), args.method, args.seed, leds=existing.led_spectra
    )
    estimate, rmse = simulated.estimate, simulated.rmse_vs_truth
    calibration = existing.updated(camera_responsivities=estimate.responsivities, camera=simulated.section())
    path = save_calibration(calibration, args.out)
    payload = {"method": estimate.method, "rmse_vs_truth": rmse}
    line = f"{args.camera}: responsivities recovered ({estimate.method}), RMSE vs truth {rmse:.4f}"
    return _report_saved(args, calibration, path, payload, [line])


def _chart_command(args: argparse.Namespace) -> int:
    options = ExportOptions(
        unit=args.unit,
        column=args.column,
        integration_time_s=None if args.integration_time_ms is None else args.integration_time_ms / 1e3,
        dark=None if args.dark is None else tuple(args.dark),
        no_dark=args.no_dark,
    )
    reflectances, section = chart_from_exports(args.files, args.white, args.white_reflectance, options, args.chart_grid)
    calibration = _existing(args.out).updated(chart_reflectances=reflectances, chart=section)
    path = save_calibration(calibration, args.out)
    payload = {"patches": list(reflectances.names), "rows": section["rows"], "columns": section["columns"]}
    line = (
        f"{reflectances.count} patch reflectances ({section['rows']}×{section['columns']} chart) measured over "
        f"the white {args.white}"
    )
    return _report_saved(args, calibration, path, payload, [line])


def _dark(args: argparse.Namespace) -> int:
    sequence = read_sequence(locate_sequence(args.sequence))
    result = dark_of_sequence(sequence)
    calibration = _existing(args.out).updated(
        dark={**result.as_dict(), "cfa": sequence.camera.cfa, "sequence": str(sequence.directory)}
    )
    path = save_calibration(calibration, args.out)
    lines = [
        "black level per channel: " + ", ".join(f"{v:.2f}" for v in result.black_level),
        "read noise (DN): " + ", ".join(f"{v:.2f}" for v in result.read_noise_dn),
    ]
    return _report_saved(args, calibration, path, result.as_dict(), lines)


def _linearity(args: argparse.Namespace) -> int:
    sequence = read_sequence(locate_sequence(args.sequence))
    calibration = _existing(args.out)
    black = calibration.dark["black_level"] if calibration.dark else sequence.camera.black_level
    result = linearity_of_sequence(sequence, black)
    calibration = calibration.updated(linearity={**result.as_dict(), "sequence": str(sequence.directory)})
    path = save_calibration(calibration, args.out)
    line = (
        f"max deviation from linear {result.max_relative_deviation:.4f}, linear up to "
        f"{result.linear_limit_dn} DN, saturation level {result.saturation_level}"
    )
    return _report_saved(args, calibration, path, result.as_dict(), [line])


def _report_saved(
    args: argparse.Namespace, calibration: CalibrationSet, path: Path, payload: dict, lines: list[str]
) -> int:
    """Say what was saved at ``path``: with ``--json`` the file, the calibration's id and ``payload``; else
    ``lines`` and the file."""
    if args.json:
        print_json({"calibration": str(path), "id": calibration.id, **payload})
    else:
        for line in lines:
            print(line)
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
            UsageError("calibrate: expected one of leds, camera, chart, dark, linearity")
        )
    )

    _register_leds(commands)
    _register_camera(commands)
    _register_chart(commands)
    for name, handler, text in (
        ("dark", _dark, "black level and read noise from a sequence's dark frames"),
        ("linearity", _linearity, "linearity and saturation from frames at several exposures"),
    ):
        sub = commands.add_parser(name, help=text)
        sub.add_argument("sequence", help=SEQUENCE_HELP)
        sub.add_argument("--out", required=True, help="calibration directory (created or updated)")
        sub.add_argument("--json", action="store_true")
        sub.set_defaults(handler=_bad_input(handler))


def _register_leds(commands: argparse._SubParsersAction) -> None:
    """``calibrate leds``: LED spectra from spectrometer exports, their power ratios through the camera."""
    leds = commands.add_parser(
        "leds", help="LED spectra from spectrometer exports; their power ratios through the camera"
    )
    leds.add_argument("files", nargs="*", help="spectrometer exports (CSV or text: wavelength, value), one per LED")
    leds.add_argument(
        "--unit",
        default=None,
        choices=("energy", "photons", "counts"),
        help="what the value column holds (default: as the export's header says; raw counts for Ocean exports, "
        "energy for a plain file)",
    )
    leds.add_argument("--column", type=positive_int, default=None, help="value column when there are more than two")
    leds.add_argument(
        "--dark",
        action="append",
        help="a dark export (shutter closed) to subtract; one of another integration time is scaled to each export's; "
        "once per integration time for darks of several (each export takes the dark of its own time)",
    )
    leds.add_argument(
        "--no-dark",
        action="store_true",
        help="the exports need no dark (dark-corrected or calibrated); without --dark or this, the baseline is "
        "measured on each export's out-of-band tail and subtracted with a warning",
    )
    leds.add_argument(
        "--integration-time-ms",
        type=positive_float,
        default=None,
        metavar="MS",
        help="integration time of exports whose header states none",
    )
    leds.add_argument(
        "--spectrometer-response",
        metavar="FILE",
        help="the spectrometer's response (its irradiance calibration: counts per unit energy, or energy per count "
        "when the column header says '/count'): raw counts become energy",
    )
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


def _register_camera(commands: argparse._SubParsersAction) -> None:
    """``calibrate camera``: responsivities from a chart under the LEDs and broadband lights."""
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
    camera.add_argument(
        "--chart",
        default=None,
        metavar="NAME_OR_CSV",
        help="the chart's reflectances: macbeth (ISETCam's measurement, shipped), chart110 (--simulate), or a CSV "
        "'wavelength_nm, one reflectance per patch' (0–1, patches column by column) — the vendor's data or your "
        "own measurement; default: the calibration's measured chart (calibrate chart), else macbeth",
    )
    camera.add_argument(
        "--chart-grid",
        metavar="ROWSxCOLUMNS",
        help="the chart's grid (default 4x6 for 24 patches, else the grid nearest 2:3)",
    )
    camera.add_argument(
        "--flat-light",
        action="store_true",
        help="assume every patch equally lit (default: the light across the chart — lens falloff, an LED's "
        "spot — is fitted, a smooth gain per frame)",
    )
    camera.add_argument(
        "--method",
        default="pca_prior",
        choices=("pca_prior", "pca_subspace", "smoothness"),
        help="prior: the learned second moment (default), its best subspace by evidence, or smoothness",
    )
    camera.add_argument("--seed", type=seed_int, default=0)
    camera.add_argument("--out", required=True, help="calibration directory (created or updated)")
    camera.add_argument("--json", action="store_true")
    camera.set_defaults(handler=_bad_input(_camera))


def _register_chart(commands: argparse._SubParsersAction) -> None:
    """``calibrate chart``: a chart's reflectances measured with the spectrometer."""
    chart = commands.add_parser(
        "chart",
        help="a chart's reflectances measured with the spectrometer (each patch over a white reference)",
    )
    chart.add_argument("files", nargs="+", help="one spectrometer export per patch, in chart order (column by column)")
    chart.add_argument("--white", required=True, metavar="FILE", help="the export of the white reference, same light")
    chart.add_argument(
        "--white-reflectance",
        metavar="CSV",
        help="the white reference's reflectance, 'wavelength_nm, reflectance' (default: 1)",
    )
    chart.add_argument("--unit", default=None, choices=("energy", "photons", "counts"), help="as for calibrate leds")
    chart.add_argument("--column", type=positive_int, default=None, help="value column when there are more than two")
    chart.add_argument(
        "--dark",
        action="append",
        help="a dark export (shutter closed), once per integration time used (the white is usually measured shorter "
        "than the dark patches: a lamp's export has no out-of-band tail to scale a dark of another time on)",
    )
    chart.add_argument("--no-dark", action="store_true", help="the exports need no dark (dark-corrected)")
    chart.add_argument("--integration-time-ms", type=positive_float, default=None, metavar="MS")
    chart.add_argument("--chart-grid", metavar="ROWSxCOLUMNS", help="the chart's grid (default 4x6 for 24 patches)")
    chart.add_argument("--out", required=True, help="calibration directory (created or updated)")
    chart.add_argument("--json", action="store_true")
    chart.set_defaults(handler=_bad_input(_chart_command))
