"""From a user's measurements to calibration sections: spectrometer exports, white-reference, chart and dark sequences.

``msflash calibrate`` parses options and prints; this module does the work with explicit
arguments, so a notebook can calibrate the same way. It sits in the acquisition layer because it
reads sequences (:mod:`msflash.acquisition.sequence.format`) and finds chart patches the way
``msflash evaluate`` does (:mod:`msflash.acquisition.session.chart_layout`); the maths is in
:mod:`msflash.calibration`. What each section holds: ``docs/calibration.md``.

Bad input raises :class:`msflash.acquisition.errors.UsageError` (or
:class:`msflash.calibration.errors.CalibrationError`) naming the option or file and what was
expected; progress and warnings go to ``report`` (one line each).
"""

from __future__ import annotations

from collections.abc import Callable
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from msflash.acquisition.errors import UsageError
from msflash.acquisition.progress import progress
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.session.chart_layout import (
    ChartName,
    ChartReference,
    SequenceLayout,
    chart_reference,
    check_layout,
    sequence_layout,
)
from msflash.calibration.camera_response import (
    ResponsivityEstimate,
    estimate_responsivities,
    learn_prior,
    responsivity_rmse,
)
from msflash.calibration.chart_sequence import (
    ChartMeasurements,
    estimate_from_measurements,
    resolve_light,
    sequence_measurements,
)
from msflash.calibration.dark import DarkResult, LinearityResult, measure_dark, measure_linearity
from msflash.calibration.files import CalibrationSet
from msflash.calibration.led_exports import ExportOptions, read_led_exports
from msflash.calibration.led_spectra import LedCharacterisation, characterise_led, relative_power_through_camera
from msflash.calibration.validation import calibration_lights, simulate_chart_responses
from msflash.calibration.white_reference import parse_roi, white_led_responses
from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID, Spectra

Report = Callable[[str], None]
"""Where progress and warning lines go (default: stderr through :func:`msflash.acquisition.progress.progress`)."""


# -- LED spectra ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class MeasuredLeds:
    """LED spectra from spectrometer exports, with what the calibration's ``leds`` section records."""

    spectra: Spectra
    """One emission spectrum per export on :data:`DEFAULT_GRID`: energy, or spectrometer counts (per second)
    when ``section["unit"]`` is ``counts`` (the math then treats them as energy)."""
    characterisations: tuple[LedCharacterisation, ...]
    """Peak, FWHM, centroid and the asymmetric-Gaussian model of each LED."""
    section: dict[str, Any]
    """The ``leds`` section of the calibration file."""


def measured_leds(
    files: SequenceOf[str | Path],
    unit: Literal["energy", "photons", "counts"] | None = None,
    column: int | None = None,
    dark: str | Path | SequenceOf[str | Path] | None = None,
    report: Report = progress,
    *,
    no_dark: bool = False,
    integration_time_ms: float | None = None,
    spectrometer_response: str | Path | None = None,
) -> MeasuredLeds:
    """Read, dark-subtract and characterise one spectrometer export per LED.

    The exports are read as their instruments write them (:mod:`msflash.calibration.led_exports`):
    unit and integration time from the header, the baseline removed (a dark export, scaled to each
    export's integration time; the dark stored in the file; or the out-of-band tail, with a
    warning), counts per second, energy when the spectrometer's response is given.

    Parameters
    ----------
    files
        One export per LED (CSV or text: wavelength, value), in the booth's LED order.
    unit
        What the value column holds (``energy``, ``photons`` or raw ``counts``); None: as the header says.
    dark
        An export with the shutter closed, subtracted from each; or one per integration time (each
        export takes the dark of its own time).
    report
        Receives warnings (saturation, a low SNR, the baseline) and the notes of clipped negatives.
    no_dark
        The exports need no dark (dark-corrected or calibrated): taken as they are.
    """
    options = ExportOptions(
        unit=unit,
        column=column,
        integration_time_s=None if integration_time_ms is None else integration_time_ms / 1e3,
        dark=dark if dark is None or isinstance(dark, str | Path) else tuple(dark),
        no_dark=no_dark,
        response=spectrometer_response,
    )
    exports = read_led_exports(files, DEFAULT_GRID, options, report)
    characterisations = []
    for measurement in exports.measurements:
        item = characterise_led(measurement)
        for warning in item.warnings:
            report(f"warning: {warning}")
        characterisations.append(item)
    spectra = exports.spectra.to_unit("energy")
    section = {
        "peaks_nm": [c.peak_nm for c in characterisations],
        "fwhm_nm": [c.fwhm_nm for c in characterisations],
        "centroids_nm": [c.centroid_nm for c in characterisations],
        "models": [
            {"model": "Ohno2005 asymmetric", **c.model, "relative_rms_residual": c.model_residual}
            for c in characterisations
        ],
        "sources": [str(f) for f in files],
        **exports.section,
        "relative_power": None,
        "relative_power_note": "ratios as measured by the spectrometer; measure them through the camera on a white "
        "reference with --white SEQ when the probe moved between LEDs",
        "warnings": [w for c in characterisations for w in c.warnings],
        "clipped_negatives": spectra.metadata.get("clipped_negatives", []),
    }
    for note in spectra.metadata.get("clipped_notes", []):
        report(note)
    return MeasuredLeds(spectra, tuple(characterisations), section)


def read_white_reflectance(path: str, grid: Any) -> Spectra:
    """``--white-reflectance``: one reflectance (factors 0–1.5, as ``--chart``'s), covering the grid.

    A file of several columns is refused (its first was taken, silently), and so is a table in percent.
    """
    try:
        table = datasets.load_spectra_csv(path, kind="reflectance", unit="none")
        reflectance = table.resample(grid, outside="error")
    except (SpectralDataError, ValueError, OSError) as err:
        raise UsageError(
            f"--white-reflectance {path}: {err}; expected a CSV 'wavelength_nm, reflectance' covering the LEDs"
        ) from err
    if table.count != 1:
        raise UsageError(
            f"--white-reflectance {path}: {table.count} columns of values; expected one, 'wavelength_nm, reflectance'"
        )
    low, high = float(table.values.min()), float(table.values.max())
    if low < 0 or high > 1.5 or not high > 0:
        raise UsageError(
            f"--white-reflectance {path}: reflectances span {low:g}–{high:g}; expected reflectance factors 0–1 "
            "(divide percentages by 100)"
        )
    return reflectance


def led_power_through_camera(
    white: Sequence,
    shapes: Spectra,
    calibration: CalibrationSet,
    calibration_directory: str | Path,
    white_roi: str | None = None,
    white_reflectance: str | None = None,
    report: Report = progress,
) -> tuple[Spectra, dict[str, Any]]:
    """``shapes`` scaled to the power ratios the camera sees on a white reference (``calibrate leds --white``).

    Each LED's spectrum is normalised to peak 1 and scaled by its power relative to the others as
    the camera measures it on the white reference (:func:`msflash.calibration.led_spectra.relative_power_through_camera`),
    with the camera's responsivities from ``calibration`` or, failing that, those the sequence records.

    ``white`` is a sequence of the white reference (ambient + one frame per LED, in ``shapes``' order),
    ``white_roi`` where it is (default: the central half), ``white_reflectance`` its reflectance (default
    flat). Returns the scaled spectra and the keys added to the ``leds`` section (``relative_power``, its source).
    """
    if white.leds and len(white.leds) != shapes.count:
        raise UsageError(
            f"--white {white.path}: the sequence has {len(white.leds)} LEDs but {shapes.count} LED "
            "spectra were given; expected one spectrum per LED, in the sequence's order"
        )
    if calibration.camera_responsivities is not None:
        camera, camera_from = calibration.camera_responsivities, f"calibration {calibration_directory}"
    elif (from_sequence := white.camera_responsivities()) is not None:
        camera, camera_from = from_sequence, f"sequence {white.path}"
    else:
        raise UsageError(
            f"--white {white.path}: no camera responsivities, neither in {calibration_directory} nor in the "
            "sequence; expected 'msflash calibrate camera … --out' first (or a sequence that records them)"
        )
    roi = parse_roi(white_roi) if white_roi else None
    responses = white_led_responses(white, roi)
    for warning in responses.warnings:
        report(f"warning: {warning}")
    reflectance = read_white_reflectance(white_reflectance, shapes.grid) if white_reflectance else None
    peaks = shapes.values.max(axis=0)
    if not np.all(peaks > 0):
        raise UsageError(
            f"LED spectra {', '.join(n for n, p in zip(shapes.names, peaks, strict=True) if not p > 0)}: "
            "no positive value; expected an emission peak"
        )
    shapes = shapes.replace(values=shapes.values / peaks)  # each LED's peak 1: `power` is then its peak's ratio
    power = relative_power_through_camera(
        shapes, responses.responses, camera.resample(shapes.grid, outside="zero"), reflectance
    )
    scaled = shapes.replace(values=shapes.values * power)
    keys = {
        "relative_power": power.tolist(),
        "relative_power_note": None,
        "relative_power_source": {
            "white_sequence": str(white.path),
            "camera_responsivities": camera_from,
            "white_reflectance": white_reflectance,
            **responses.report(),
        },
    }
    return scaled, keys


# -- camera responsivities -----------------------------------------------------------------------
@dataclass(frozen=True)
class ChartCameraCalibration:
    """Camera responsivities recovered from recorded chart sequences, and how."""

    estimate: ResponsivityEstimate
    """The responsivities and the fit's parameters."""
    measurements: ChartMeasurements
    """The patch means the fit used (frames, data)."""
    layouts: tuple[SequenceLayout, ...]
    """Each sequence's chart layout (detected or given)."""
    light_scales: dict[str, float]
    """The estimated power of each known broadband light (relative to its given spectrum)."""
    rmse_vs_recorded: float | None
    """RMSE against the responsivities the first sequence records, when it does."""
    sequences: tuple[str, ...]
    """The sequences' folders."""
    light_specs: tuple[str | None, ...]
    """The known lights as given."""
    prior_excluded: tuple[str, ...]
    """Paper cameras left out of the prior."""
    chart: str = "macbeth"
    """The chart's reference data: ``macbeth`` (shipped) or the file / calibration it came from."""
    light_field: dict[str, Any] = field(default_factory=dict)
    """The fitted light across the chart (:class:`msflash.calibration.chart_sequence.SequenceCalibration`)."""

    def section(self) -> dict[str, Any]:
        """The calibration file's ``camera`` section."""
        return {
            **_fit_report(self.estimate),
            "chart": self.chart,
            "light_field": self.light_field,
            "sequences": list(self.sequences),
            "lights": list(self.light_specs),
            "light_scales": self.light_scales,
            "frames": list(self.measurements.frames),
            "prior_excluded": list(self.prior_excluded),
            "layouts": [layout.report for layout in self.layouts],
            "rmse_vs_sequence_responsivity": self.rmse_vs_recorded,
        }


def _fit_report(estimate: ResponsivityEstimate) -> dict[str, Any]:
    return {
        "method": estimate.method,
        "alphas": list(estimate.alphas),
        "shrinkages": list(estimate.shrinkages),
        "relative_residual": list(estimate.relative_residual),
    }


def camera_from_chart_sequences(
    sequences: SequenceOf[Sequence],
    light_specs: SequenceOf[str | None],
    method: str = "pca_prior",
    prior_exclude: SequenceOf[str] = (),
    chart: ChartName | ChartReference = "macbeth",
    patch_px: int | None = None,
    border_px: int | None = None,
    margin_px: int = 1,
    report: Report = progress,
    light_field: str = "quadratic",
) -> ChartCameraCalibration:
    """Camera responsivities from Macbeth chart sequences under the LEDs and known broadband lights.

    Each sequence's chart is found (detected unless ``patch_px``/``border_px`` are given) and
    checked against its ambient frame before anything is estimated; the patch means of every LED
    and ambient frame then feed :func:`msflash.calibration.chart_sequence.estimate_from_measurements`
    with a prior learned from the 34 paper cameras (minus ``prior_exclude``) unless ``method`` is
    ``smoothness``.

    Parameters
    ----------
    light_specs
        The known broadband light of each sequence's ambient, in order: a name, a CSV in energy
        units, or ``None``/``"none"`` for an unknown ambient; empty for all unknown.
    chart
        The chart's reference data: the shipped Macbeth, or a :class:`ChartReference` (a user's
        ``--chart FILE.csv``, a calibration's measured chart).
    light_field
        ``quadratic`` (default): the light across the chart is fitted, a smooth gain per frame
        (lens falloff, an LED's spot); ``flat``: every patch equally lit.
    """
    chart = _recorded_chart(chart)
    lights = _chart_lights(sequences, light_specs)
    grid = sequences[0].grid
    reflectances = chart.on(grid)
    cameras = {name: s.resample(grid, outside="zero") for name, s in datasets.paper_cameras().items()}
    unknown = [name for name in prior_exclude if name not in cameras]
    if unknown:
        raise UsageError(f"--prior-exclude {unknown}: not among the 34 paper cameras; expected names like NikonD100")
    # Each sequence its own layout: the chart may move between them.
    layouts = [sequence_layout(s, chart, patch_px, border_px, margin_px) for s in sequences]
    for sequence, layout in zip(sequences, layouts, strict=True):
        _check_layout_fits(sequence, layout, report)
    labels_for = [lambda shape, excluded, layout=layout: layout.build(shape, excluded).labels for layout in layouts]
    positions = [layout.patch_positions(chart.reflectances.count, chart.rows) for layout in layouts]
    measurements = sequence_measurements(list(sequences), lights, reflectances, labels_for, positions)
    prior = learn_prior(cameras, exclude=list(prior_exclude)) if method != "smoothness" else None
    report(
        f"{len(measurements.frames)} chart frames, {measurements.data.shape[0]} patch means of the {chart.name} "
        f"chart; prior from {len(prior.cameras) if prior else 0} cameras"
    )
    names = [chart.patch_name(p) for p in range(chart.reflectances.count)]
    result = estimate_from_measurements(measurements, method, prior, light_field, names)
    if result.light_field.get("gain_range_per_frame"):
        ranges = [r for r in result.light_field["gain_range_per_frame"] if r]
        report(
            f"light across the chart (fitted, {light_field}): {min(r[0] for r in ranges):.3f}–"
            f"{max(r[1] for r in ranges):.3f} of each frame's mean"
        )
    recorded = sequences[0].camera_responsivities()
    rmse = (
        responsivity_rmse(result.estimate.responsivities, recorded.to_unit("photons")) if recorded is not None else None
    )
    return ChartCameraCalibration(
        result.estimate,
        measurements,
        tuple(layouts),
        result.light_scales,
        rmse,
        tuple(str(s.directory) for s in sequences),
        tuple(light_specs),
        tuple(prior_exclude),
        chart.name,
        result.light_field,
    )


def _recorded_chart(chart: ChartName | ChartReference) -> ChartReference:
    """The chart's reference data for recorded sequences: a :class:`ChartReference`, or the shipped Macbeth."""
    if isinstance(chart, ChartReference):
        return chart
    if chart != "macbeth":
        raise UsageError(
            f"--chart {chart}: recorded sequences need the chart's reflectances; expected --chart macbeth or a CSV"
        )
    return chart_reference("macbeth")


def _chart_lights(sequences: SequenceOf[Sequence], light_specs: SequenceOf[str | None]) -> list[Spectra | None]:
    """Each sequence's known broadband light on the first sequence's grid (None: unknown), checked one per sequence."""
    if not sequences:
        raise UsageError("calibrate camera: expected at least one chart sequence (--sequence SEQ…)")
    if light_specs and len(light_specs) != len(sequences):
        raise UsageError(
            f"--light given {len(light_specs)} times for {len(sequences)} sequences; expected one per "
            "sequence, in order (NAME, CSV file, or 'none' for an unknown ambient)"
        )
    grid = sequences[0].grid
    return [
        None if spec is None or spec.lower() == "none" else resolve_light(spec, grid)
        for spec in (light_specs or [None] * len(sequences))
    ]


def _check_layout_fits(sequence: Sequence, layout: SequenceLayout, report: Report) -> None:
    """Refuse a layout that does not fit the sequence's ambient frame, before anything is estimated."""
    index = sequence.indices("ambient")[0] if sequence.indices("ambient") else 0
    raw = sequence.load_frame(index).astype(np.float64)
    layout_map = layout.build(raw.shape[:2])
    check_layout(raw, layout_map, sequence.camera.cfa)
    if layout.report["detected"]:
        report(f"{sequence.directory}: {layout_map.description}")


@dataclass(frozen=True)
class SimulatedCameraCalibration:
    """Responsivities recovered from a chart rendered in the simulated world, against the truth."""

    estimate: ResponsivityEstimate
    lights: Spectra
    """The broadband lights the chart was rendered under."""
    rmse_vs_truth: float
    camera_name: str
    chart: str

    def section(self) -> dict[str, Any]:
        """The calibration file's ``camera`` section."""
        return {
            **_fit_report(self.estimate),
            "chart": self.chart,
            "lights": list(self.lights.names),
            "simulated_camera": self.camera_name,
            "lights_source": self.lights.source,
            "rmse_vs_truth": self.rmse_vs_truth,
        }


def simulated_camera_calibration(
    camera_name: str,
    chart: ChartName | ChartReference = "macbeth",
    method: str = "pca_prior",
    seed: int = 0,
    report: Report = progress,
    leds: Spectra | None = None,
) -> SimulatedCameraCalibration:
    """Render a chart under the calibration lights with paper camera ``camera_name`` and recover its responsivities.

    The lights are ``leds`` — the booth's measured LEDs, from the calibration being updated — or
    the paper's 7, plus the broadband lights. ``chart`` is a built-in chart's name or its
    reflectances (a user's ``--chart FILE.csv``). The prior is learned from the other 33 cameras
    (never the camera under test).
    """
    cameras = {name: s.resample(DEFAULT_GRID, outside="zero") for name, s in datasets.paper_cameras().items()}
    if camera_name not in cameras:
        raise UsageError(f"--camera '{camera_name}': not one of the 34 paper cameras; expected e.g. NikonD100")
    if isinstance(chart, ChartReference):
        reflectances, chart_name = chart.on(DEFAULT_GRID), chart.name
    else:
        reflectances = datasets.macbeth().resample(DEFAULT_GRID) if chart == "macbeth" else datasets.chart110()
        chart_name = chart
    lights = calibration_lights(DEFAULT_GRID, leds=leds)
    report(
        f"simulating {chart_name} under {lights.count} lights ({', '.join(lights.names)}"
        + (f"; LEDs from {leds.source}" if leds is not None else "; the paper's LEDs")
        + f") with {camera_name}"
    )
    truth = cameras[camera_name]
    responses, std = simulate_chart_responses(truth, reflectances, lights, rng=np.random.default_rng(seed))
    prior = learn_prior(cameras, exclude=[camera_name]) if method != "smoothness" else None
    estimate = estimate_responsivities(responses, reflectances, lights, method, prior, std)
    return SimulatedCameraCalibration(
        estimate, lights, responsivity_rmse(estimate.responsivities, truth), camera_name, chart_name
    )


# -- dark and linearity --------------------------------------------------------------------------
def dark_of_sequence(sequence: Sequence) -> DarkResult:
    """Black level and read noise from the sequence's frames of role ``dark``."""
    indices = sequence.indices("dark")
    if not indices:
        raise UsageError(f"{sequence.path}: frames has no 'dark' frame; expected frames with role 'dark'")
    # Dark frames measure the black level, so the declared one is not held against them.
    return measure_dark([sequence.load_frame(i, check_levels=False) for i in indices], sequence.camera.cfa)


def linearity_of_sequence(sequence: Sequence, black_level: Any) -> LinearityResult:
    """Linearity and saturation from the sequence's lit frames: one illumination at several exposures.

    ``black_level`` is the calibration's measured one when there is one, else the sequence's.
    """
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
    frames = [sequence.load_frame(i) for i in indices]
    exposures = [sequence.frames[i].exposure_us * sequence.frames[i].gain for i in indices]
    return measure_linearity(frames, exposures, black_level, sequence.camera.cfa, sequence.camera.white_level)
