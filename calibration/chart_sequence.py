"""Camera responsivities from recorded sequences of a chart (``msflash calibrate camera --sequence``).

Public objects
--------------
- :func:`resolve_light`: a known broadband light by name or CSV file, on a sequence's grid.
- :class:`ChartMeasurements`, :func:`sequence_measurements`: linear patch means and standard errors
  of every usable frame of one or more format-v1 sequences, with the light each was taken under.
- :func:`estimate_from_measurements`: the responsivities, with the unknown power of each broadband
  light estimated jointly (alternating: curves given powers, powers given curves).

What is measured
----------------
Per sequence, frames are linearised as ``(raw − black) / (exposure_us · gain)``. Each ``led``
frame minus the ambient frame is the chart under ``Σ_k level_k · LED_k`` alone (the sequence's LED
spectra, true ratios). The ambient frame itself is the chart under the sequence's known broadband
light (``--light``), if one is given; its *power* relative to the LEDs is not known (a booth lamp
is rarely measured at the chart's position with the LEDs' geometry), so each broadband light gets
one unknown scale, common to all patches and channels. Likewise the LED spectra of a sequence have
true ratios among themselves, but two sequences (another day, another gain, a re-measured booth)
need not share a scale: the LEDs of every sequence after the first get one unknown scale too. ``flash`` and ``dark`` frames are not used.

Patches come from a label map per sequence (the CLI detects the chart in each sequence,
:mod:`calibration.chart_detection`, or rebuilds a given layout as ``msflash evaluate`` does);
pixels saturated in either frame of a difference are excluded before the edge margin is applied,
and a Bayer mosaic is read through :func:`processing.colour_metrics.patch_pixels` (each channel its
own sites, no demosaicking). A patch with too few usable pixels in a frame is dropped from that
frame only; a frame that loses more than half of the chart is an error.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from msflash.calibration.camera_response import (
    CHANNELS,
    ChannelFit,
    ResponsivityEstimate,
    ResponsivityPrior,
    fit_channels,
    measurement_matrix,
)
from msflash.calibration.errors import CalibrationError
from msflash.calibration.light_field import field_basis, field_terms, fit_frame_fields, frame_gains
from msflash.processing import datasets, lights
from msflash.processing.colour_metrics import patch_pixels
from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import Spectra, WavelengthGrid

LabelBuilder = Callable[[tuple[int, int], np.ndarray], np.ndarray]
"""``(image shape, excluded mask) → label map`` (patch index, −1 for unusable pixels)."""
MIN_PIXELS = 4
"""Fewest usable samples per channel for a patch mean."""
SCALE_ITERATIONS = 60
"""Most alternations between curves and unknown powers."""
MISFIT_NOISE, MISFIT_RESIDUAL = 4.0, 0.05
"""A fit whose residual is both > 4× the measured noise and > 5 % of the signal is refused: a wrong
layout or a wrong --light (measured: docs/calibration.md)."""
FIELD_EXPLAINS = 4.0
"""A light field explains a flat fit's misfit only if it takes the residual down this many times (a wrong
chart reference does not; docs/calibration.md)."""
SCALE_TOLERANCE = 1e-3
"""Largest relative change of any unknown power at convergence."""


def resolve_light(spec: str, grid: WavelengthGrid) -> Spectra:
    """A broadband light (energy, one column) on ``grid``: a CSV ``wavelength_nm, value`` (energy) or a name.

    Names: the sim rig's ambients (:data:`processing.lights.AMBIENTS`: tungsten, daylight, …)
    or CIE illuminants (:func:`processing.datasets.illuminant`: A, D65, FL2, …).
    """
    path = Path(spec)
    if path.suffix.lower() in (".csv", ".txt") or path.exists():
        if not path.exists():
            raise CalibrationError(
                f"{spec}: light file not found; expected a CSV file 'wavelength_nm, value' or a "
                "name like tungsten or D65"
            )
        try:
            spectra = datasets.load_spectra_csv(path, kind="spd", unit="energy")
            if spectra.count != 1:  # its first column was taken, silently
                raise CalibrationError(
                    f"{spec}: {spectra.count} spectra; expected one light, a CSV file 'wavelength_nm, value'"
                )
            light = spectra.resample(grid, outside="error")
        except (SpectralDataError, ValueError) as err:
            # The table's errors start with its path already ("x.csv:3: …"); only others get it prefixed.
            text = str(err)
            raise CalibrationError(text if text.startswith(str(path)) else f"{spec}: {text}") from err
    else:
        try:
            light = lights.ambient_spectrum(spec, grid) if spec in lights.AMBIENTS else datasets.illuminant(spec, grid)
        except (SpectralDataError, ValueError, KeyError) as err:
            raise CalibrationError(
                f"--light '{spec}': not a known light ({err}); expected a CSV file or one of "
                f"{', '.join(lights.AMBIENTS)}, A, D65, …"
            ) from err
    if not np.all(np.isfinite(light.values)) or np.any(light.values < 0) or not light.values.max() > 0:
        raise CalibrationError(
            f"{spec}: light spectrum is not finite, non-negative and non-zero on "
            f"{grid}; expected a measured broadband light"
        )
    return light.replace(names=(Path(spec).stem if path.suffix else spec,))


@dataclass(frozen=True)
class ChartMeasurements:
    """Rows of the linear model ``m = (diag(r_p) i_l Δλ) c`` gathered from sequences."""

    grid: WavelengthGrid
    design: np.ndarray
    """(rows, n_wavelengths), photons · Δλ, at unit power of the light."""
    data: np.ndarray
    """(rows, 3) linear patch means per µs · gain."""
    std: np.ndarray
    """(rows, 3) their standard errors."""
    group: np.ndarray
    """(rows,) −1 for rows of known power (the first sequence with LED frames: its LEDs), g ≥ 0 for
    rows of unknown power g (a broadband light, or the LEDs of a later sequence)."""
    group_names: tuple[str, ...]
    """Name of each unknown-power group (``sequence index: light`` or ``sequence index: LEDs``)."""
    frames: tuple[dict[str, Any], ...]
    """Per used frame: sequence, file, light, patches used."""
    frame: np.ndarray
    """(rows,) index into ``frames`` of each row."""
    patch: np.ndarray
    """(rows,) chart patch of each row."""
    positions: np.ndarray
    """(rows, 2) the row's patch in the chart (column, row), in patch pitches: where the light field is evaluated."""
    sequence: np.ndarray
    """(rows,) the sequence of each row."""


def patch_statistics(
    image: np.ndarray, labels: np.ndarray, n_patches: int, cfa: str | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Means and standard errors per patch and channel, and each patch's smallest channel sample count.

    Means and errors are NaN where a patch has < MIN_PIXELS samples in some channel; labels outside
    ``0 … n_patches − 1`` (e.g. −1) belong to no patch.
    """
    means = np.full((n_patches, 3), np.nan)
    errors = np.full((n_patches, 3), np.nan)
    counts = np.zeros(n_patches, dtype=int)
    for patch in range(n_patches):
        samples = patch_pixels(image, labels, patch, cfa)
        counts[patch] = min(s.size for s in samples)
        if len(samples) != 3 or counts[patch] < MIN_PIXELS:
            continue
        means[patch] = [s.mean() for s in samples]
        errors[patch] = [s.std(ddof=1) / np.sqrt(s.size) for s in samples]
    return means, errors, counts


def sequence_measurements(
    sequences: Sequence[Any],
    lights: Sequence[Spectra | None],
    reflectances: Spectra,
    labels_for: LabelBuilder | Sequence[LabelBuilder],
    positions_for: Sequence[np.ndarray] | None = None,
) -> ChartMeasurements:
    """Patch means of every LED frame (minus the ambient) and of each ambient with a known light.

    Parameters
    ----------
    sequences
        Format-v1 sequences (:class:`acquisition.sequence.format.Sequence`) of the same chart.
    lights
        Per sequence, its ambient's known broadband light (energy, on the sequence's grid), or None
        when the ambient is not a known light (then only its LED frames are used).
    reflectances
        The chart's patches on the sequences' grid, in label order.
    labels_for
        Builds the label map of an image shape, excluding a mask (saturated pixels): one for all
        sequences, or one per sequence (a chart detected in each, :mod:`calibration.chart_detection`).

    Raises
    ------
    CalibrationError
        Mismatched grids, a sequence without ambient frame or LED frames, colour-less frames, a
        frame where most patches are unusable, or no signal at all.
    """
    builders = _check_sequences(sequences, lights, reflectances, labels_for)
    if positions_for is None:
        k = np.arange(reflectances.count)
        positions_for = [np.column_stack([k // 4, k % 4]).astype(float)] * len(sequences)
    rows = _Rows(reflectances)
    for s, (sequence, light) in enumerate(zip(sequences, lights, strict=True)):
        rows.add_sequence(s, sequence, light, builders[s], np.asarray(positions_for[s], dtype=float))
    return rows.measurements(sequences[0].grid)


def _check_sequences(
    sequences: Sequence[Any],
    lights: Sequence[Spectra | None],
    reflectances: Spectra,
    labels_for: LabelBuilder | Sequence[LabelBuilder],
) -> list[LabelBuilder]:
    """One light and one label builder per sequence, all on the chart's grid; the builders."""
    if len(lights) != len(sequences):
        raise CalibrationError(f"{len(lights)} lights for {len(sequences)} sequences; expected one per sequence")
    if not sequences:
        raise CalibrationError("no sequence given; expected at least one chart sequence")
    builders = list(labels_for) if isinstance(labels_for, Sequence) else [labels_for] * len(sequences)
    if len(builders) != len(sequences):
        raise CalibrationError(f"{len(builders)} label maps for {len(sequences)} sequences; expected one per sequence")
    grid = sequences[0].grid
    if not reflectances.grid.same_as(grid):
        raise CalibrationError(
            f"chart reflectances on {reflectances.grid} but the sequence on {grid}; expected one grid"
        )
    for sequence in sequences[1:]:
        if not sequence.grid.same_as(grid):
            raise CalibrationError(
                f"{sequence.path}: wavelengths_nm {sequence.grid} differ from {grid} of the first sequence; "
                "expected one grid"
            )
    return builders


def _ambient_index(sequence: Any, where: str, light: Spectra | None) -> int:
    """The sequence's first ambient frame (all LEDs off), refusing a sequence that gives nothing to measure."""
    ambient_indices = sequence.indices("ambient")
    if not ambient_indices:
        raise CalibrationError(
            f"{where}: frames has no 'ambient' frame; expected one (the LED frames are measured against it)"
        )
    if not sequence.indices("led") and light is None:
        raise CalibrationError(
            f"{where}: no 'led' frame and no --light for its ambient; expected LED frames or a known broadband light"
        )
    a = ambient_indices[0]
    if any(level > 0 for level in sequence.frames[a].led_levels):
        raise CalibrationError(
            f"{where}: frames[{a}] has role 'ambient' but LED levels "
            f"{list(sequence.frames[a].led_levels)}; expected all zero"
        )
    return int(a)


class _Rows:
    """The rows of :class:`ChartMeasurements` as frames are measured, one usable patch a row."""

    def __init__(self, reflectances: Spectra) -> None:
        self.reflectances = reflectances
        self.n_patches = reflectances.count
        # Per frame, the rows' design, data, std, group, frame, patch, position and sequence.
        self.parts: list[tuple[np.ndarray, ...]] = []
        self.names: list[str] = []
        self.used: list[dict[str, Any]] = []

    def add_sequence(
        self, s: int, sequence: Any, light: Spectra | None, labels_of: LabelBuilder, positions: np.ndarray
    ) -> None:
        """Every LED frame minus the ambient (under its LEDs), then the ambient under a known ``light``."""
        where = str(sequence.path)
        cfa = sequence.camera.cfa
        a = _ambient_index(sequence, where, light)
        led_indices = sequence.indices("led")
        ambient, ambient_saturated = sequence.load_linear_frame(a)
        if ambient.ndim != 3 and cfa is None:
            raise CalibrationError(f"{where}: frames are one-channel without a cfa; expected RGB or a Bayer mosaic")
        leds = sequence.led_spectra()
        led_group = -1
        if led_indices and any(np.any(part[3] < 0) for part in self.parts):
            # LED spectra hold true ratios within a sequence; between sequences (another day, gain or
            # LED calibration) only the first sequence's LEDs fix the scale.
            self.names.append(f"{s}: LEDs")
            led_group = len(self.names) - 1
        frame_of = _Frame(s, cfa, labels_of, positions)
        for i in led_indices:
            frame = sequence.frames[i]
            levels = np.asarray(frame.led_levels, dtype=float)
            if not levels.any():
                raise CalibrationError(
                    f"{where}: frames[{i}] ('{frame.file}') has role 'led' but all LED levels are "
                    "0; expected at least one LED on"
                )
            image, saturated = sequence.load_linear_frame(i)
            spectrum = leds.replace(
                values=leds.values @ levels[:, None], names=("+".join(n for n, v in zip(leds.names, levels) if v > 0),)
            )
            self.add(
                frame_of, image - ambient, saturated | ambient_saturated, spectrum, led_group, f"{where}: {frame.file}"
            )
        if light is not None:
            self.names.append(f"{s}: {light.names[0]}")
            where_ambient = f"{where}: {sequence.frames[a].file}"
            self.add(frame_of, ambient, ambient_saturated, light, len(self.names) - 1, where_ambient)

    def add(
        self, frame: _Frame, image: np.ndarray, excluded: np.ndarray, light: Spectra, group: int, where: str
    ) -> None:
        """One frame's usable patch means as rows under ``light`` (``group`` −1: known power)."""
        labels = frame.labels_of(image.shape[:2], excluded)
        means, errors, _ = patch_statistics(image, labels, self.n_patches, frame.cfa)
        valid = np.all(np.isfinite(means), axis=1)
        used = int(valid.sum())
        if used < max(3, self.n_patches // 2):
            raise CalibrationError(
                f"{where}: only {used} of {self.n_patches} chart patches have {MIN_PIXELS} "
                "unsaturated pixels; expected most of the chart usable (check exposure and "
                "--patch-px/--border-px)"
            )
        design = measurement_matrix(self.reflectances, light.to_unit("photons"))[valid]
        index = (np.full(used, group), np.full(used, len(self.used)), np.flatnonzero(valid))
        self.parts.append(
            (design, means[valid], errors[valid], *index, frame.positions[valid], np.full(used, frame.sequence))
        )
        self.used.append({"frame": where, "light": light.names[0], "patches": used})

    def measurements(self, grid: WavelengthGrid) -> ChartMeasurements:
        """The rows gathered; refused without an LED frame (they fix the broadband lights' scale)."""
        design, data, std, group, frame, patch, positions, sequence = (
            np.concatenate(part) for part in zip(*self.parts)
        )
        if not np.any(group < 0):
            raise CalibrationError(
                "no LED frame in any sequence; expected LED frames (they fix the scale of the broadband lights)"
            )
        # A floor on the standard error: flat (noise-free or quantised) patches must not get infinite weight.
        std = np.maximum(std, 1e-4 * np.nanmax(np.abs(data), axis=0) + 1e-300)
        used = tuple(self.used)
        return ChartMeasurements(
            grid, design, data, std, group, tuple(self.names), used, frame, patch, positions, sequence
        )


@dataclass(frozen=True)
class _Frame:
    """What a measured frame shares with its sequence: the index, mosaic, label builder, patch positions."""

    sequence: int
    cfa: str | None
    labels_of: LabelBuilder
    positions: np.ndarray


@dataclass(frozen=True)
class SequenceCalibration:
    """The result of :func:`estimate_from_measurements`."""

    estimate: ResponsivityEstimate
    light_scales: dict[str, float]
    """Estimated power of each unknown-power group relative to its given spectrum (units of the
    first sequence's LEDs)."""
    iterations: int
    light_field: dict[str, Any] = field(default_factory=dict)
    """The fitted light across the chart: ``model`` and, per frame, the gain's range (min, max)."""


LIGHT_FIELDS = ("quadratic", "flat")
"""``quadratic``: a smooth gain field per frame (:mod:`calibration.light_field`); ``flat``: every patch equally lit."""
FIELD_TOLERANCE = 1e-5
"""Largest change of any field coefficient (log gain) or log power at convergence."""
ANDERSON_MEMORY = 6
"""Past alternations the Anderson acceleration of :func:`estimate_from_measurements` mixes."""
MISFIT_PATCHES = 3
"""How many of the worst-fitting patches a refusal names."""


def _worst_patches(
    m: ChartMeasurements, model: np.ndarray, patch_names: Sequence[str] | None, count: int = MISFIT_PATCHES
) -> str:
    """The patches whose means the model misses most, relative to their signal: ``'Red' 14 %, …``."""
    misses = []
    for patch in np.unique(m.patch):
        rows = m.patch == patch
        signal = float(np.linalg.norm(m.data[rows]))
        if signal > 0:
            misses.append((float(np.linalg.norm(m.data[rows] - model[rows])) / signal, int(patch)))
    misses.sort(reverse=True)
    return ", ".join(
        f"{patch_names[p] if patch_names is not None else f'patch {p + 1}'} {100 * miss:.0f} %"
        for miss, p in misses[:count]
    )


def estimate_from_measurements(
    measurements: ChartMeasurements,
    method: str = "pca_prior",
    prior: ResponsivityPrior | None = None,
    light_field: str = "quadratic",
    patch_names: Sequence[str] | None = None,
) -> SequenceCalibration:
    """Responsivities from :class:`ChartMeasurements`, the lights' powers and the light across the chart fitted jointly.

    Starts from the LED rows alone, then alternates: each broadband power by weighted least
    squares over all its patches and channels given the curves, each frame's light field
    (:func:`calibration.light_field.fit_frame_fields`, when ``light_field`` is ``quadratic``), the
    curves given both, until the powers change by less than :data:`SCALE_TOLERANCE` (relative)
    and the fields by less than :data:`FIELD_TOLERANCE`.

    Parameters
    ----------
    light_field
        One of :data:`LIGHT_FIELDS`.
    patch_names
        How a refusal names the chart's patches (default ``patch N``).

    Raises
    ------
    CalibrationError
        If the model does not fit (see :data:`MISFIT_NOISE`): the message names the channel and
        the patches that disagree most, and suggests measuring the chart.
    """
    if light_field not in LIGHT_FIELDS:
        raise CalibrationError(f"light field '{light_field}' is unknown; expected one of {', '.join(LIGHT_FIELDS)}")
    flat_misfit: tuple[float, ...] | None = None
    if light_field != "flat":
        try:
            flat = estimate_from_measurements(measurements, method, prior, "flat", patch_names)
            flat_misfit = flat.estimate.relative_residual
        except CalibrationError as err:
            flat_misfit = tuple(float(v) for v in getattr(err, "residuals", ())) or None
    m = measurements
    joint = _JointFit(m, method, prior, light_field == "quadratic")
    fit, state, iterations = joint.solve()
    scales, theta = joint.unpack(state)
    gains = joint.gains_of(theta)
    _check_fit(m, fit, joint.row_scales(scales) * gains, flat_misfit if joint.basis is not None else None, patch_names)
    report: dict[str, Any] = {"model": light_field if joint.basis is not None else "flat"}
    if joint.basis is not None:
        report["gain_range_per_frame"] = [
            [float(gains[joint.frame == f].min()), float(gains[joint.frame == f].max())]
            if np.any(joint.frame == f)
            else None
            for f in range(len(m.frames))
        ]
        report["terms"] = [f"u^{i} v^{j}" for i, j in field_terms(m.positions)]
    estimate = fit.normalised(m.grid, f"estimated from {len(m.frames)} chart frames ({method})")
    return SequenceCalibration(estimate, dict(zip(m.group_names, map(float, scales), strict=True)), iterations, report)


class _JointFit:
    """The curves, the unknown powers (log) and the light fields (one per sequence), fitted by alternation.

    The state is ``[log powers…, field coefficients…]``; one alternation (:meth:`step`) solves the powers
    and the fields given the curves, then the curves are refitted given both.
    """

    def __init__(self, m: ChartMeasurements, method: str, prior: ResponsivityPrior | None, fielded: bool) -> None:
        self.m, self.method, self.prior = m, method, prior
        self.known = m.group < 0
        self.n_groups = len(m.group_names)
        # One field per sequence: a lens's falloff and the booth's geometry light every frame of it alike.
        self.frame = m.frame
        self.field_of = m.sequence
        self.basis = field_basis(m.positions, self.field_of) if fielded else None
        self.theta_shape = (int(self.field_of.max()) + 1, self.basis.shape[1] if self.basis is not None else 0)

    def unpack(self, state: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The powers and the field coefficients of a state."""
        return np.exp(state[: self.n_groups]), state[self.n_groups :].reshape(self.theta_shape)

    def row_scales(self, scales: np.ndarray) -> np.ndarray:
        """Each row's light power: 1 for the known LEDs, its group's otherwise."""
        if not self.n_groups:
            return np.ones(len(self.m.group))
        return np.where(self.known, 1.0, scales[np.maximum(self.m.group, 0)])

    def gains_of(self, theta: np.ndarray) -> np.ndarray:
        """Each row's light-field gain (1 without a field)."""
        return frame_gains(self.basis, self.field_of, theta) if self.basis is not None else np.ones(len(self.m.group))

    def refit(self, state: np.ndarray) -> ChannelFit:
        """The curves given the powers and fields of ``state``."""
        scales, theta = self.unpack(state)
        m = self.m
        scaled = m.design * (self.row_scales(scales) * self.gains_of(theta))[:, None]
        return fit_channels(scaled, m.data, m.std, self.method, self.prior)

    def step(self, state: np.ndarray, fit: ChannelFit) -> np.ndarray:
        """One alternation: each light's power and each field given the curves (then the caller refits the curves)."""
        m = self.m
        scales, theta = self.unpack(state)
        gains = self.gains_of(theta)
        new = scales.copy()
        for g in range(self.n_groups):
            rows = m.group == g
            predicted = (m.design[rows] @ fit.curves) * gains[rows, None] / m.std[rows]
            observed = m.data[rows] / m.std[rows]
            denominator = float(np.sum(predicted * predicted))
            if not denominator > 0:
                raise CalibrationError(
                    f"broadband light {m.group_names[g]}: the LED-only curves predict no signal; "
                    "expected LEDs that cover the camera's channels"
                )
            new[g] = max(float(np.sum(predicted * observed)) / denominator, 1e-12)
        if self.basis is not None:
            predicted = (m.design @ fit.curves) * self.row_scales(new)[:, None]
            theta = fit_frame_fields(predicted, m.data, m.std, self.basis, self.field_of, theta)
        return np.concatenate([np.log(new), theta.ravel()])

    def solve(self) -> tuple[ChannelFit, np.ndarray, int]:
        """The fit from the LED rows alone, then Anderson-accelerated alternations; the fit, state, iterations.

        Anderson acceleration (memory :data:`ANDERSON_MEMORY`) mixes the past alternations: plain
        alternation crawls along the valley where the light field and the curves trade off.
        """
        m, known = self.m, self.known
        fit = fit_channels(m.design[known], m.data[known], m.std[known], self.method, self.prior)
        state = np.zeros(self.n_groups + int(np.prod(self.theta_shape)))
        history_x: list[np.ndarray] = []
        history_f: list[np.ndarray] = []
        iterations = 0
        for iterations in range(1, SCALE_ITERATIONS + 1):  # noqa: B007 - read after the loop (how many it took)
            if not self.n_groups and self.basis is None:
                break
            mapped = self.step(state, fit)
            residual = mapped - state
            history_x.append(state)
            history_f.append(residual)
            del history_x[: -ANDERSON_MEMORY - 1], history_f[: -ANDERSON_MEMORY - 1]
            proposal = mapped
            if len(history_f) > 1:
                d_f = np.column_stack([b - a for a, b in zip(history_f[:-1], history_f[1:], strict=True)])
                d_x = np.column_stack([b - a for a, b in zip(history_x[:-1], history_x[1:], strict=True)])
                gamma, *_ = np.linalg.lstsq(d_f, residual, rcond=None)
                proposal = mapped - (d_x + d_f) @ gamma
            change = float(np.max(np.abs(residual))) if residual.size else 0.0
            state = proposal
            fit = self.refit(state)
            if change < min(SCALE_TOLERANCE, FIELD_TOLERANCE):
                break
        return fit, state, iterations


def _check_fit(
    m: ChartMeasurements,
    fit: ChannelFit,
    row_gain: np.ndarray,
    flat_misfit: tuple[float, ...] | None,
    patch_names: Sequence[str] | None,
) -> None:
    """Refuse a fit that misses the patch means (:data:`MISFIT_NOISE`), or whose field hides a flat misfit.

    ``flat_misfit``: the flat model's relative residual per channel when a light field was fitted.
    """
    for c, channel in enumerate(CHANNELS):
        unexplained = (
            flat_misfit is not None
            and flat_misfit[c] > MISFIT_RESIDUAL
            and fit.relative_residual[c] * FIELD_EXPLAINS > flat_misfit[c]
        )
        if fit.noise_scale[c] > MISFIT_NOISE and (fit.relative_residual[c] > MISFIT_RESIDUAL or unexplained):
            model = (m.design @ fit.curves) * row_gain[:, None]
            error = CalibrationError(
                f"chart frames: the model does not fit the patch means (channel {channel}: residual "
                f"{100 * fit.relative_residual[c]:.0f} % of the signal, {fit.noise_scale[c]:.1f}× the measurement noise; "
                f"patches that disagree most: {_worst_patches(m, model, patch_names)}); expected the right --light for "
                "each sequence's ambient, the chart layout of the frames (--patch-px/--border-px) and the chart's own "
                "reflectances — a chart differs from its published data: measure it (msflash calibrate chart) and give "
                "--chart FILE.csv"
            )
            error.residuals = fit.relative_residual  # type: ignore[attr-defined]
            raise error
