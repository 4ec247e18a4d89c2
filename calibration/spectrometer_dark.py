"""A spectrometer export's baseline (dark) taken off, its counts per second, its counts made energy.

Public objects
--------------
- :func:`out_of_band_baseline`: the level of an export where the LED emits nothing (its tails).
- :func:`remove_baseline`: the one route from a raw export to an emission: a dark export (scaled
  to the export's integration time if it was taken at another), the dark the program stored in
  the file (AvaSoft), or the out-of-band tail; never silent.
- :func:`counts_per_second`: raw counts divided by each export's integration time.
- :func:`divide_by_response`: counts made energy by the spectrometer's response (irradiance calibration).

The dark model
--------------
A spectrometer's dark reading at integration time ``t`` is ``d(λ, t) = o + r(λ)·t``: a fixed offset
``o`` (the ADC's bias, the electrical dark) and a dark current ``r`` that accumulates with time.
A dark taken at ``t_d`` is brought to the export's ``t`` as ``o + (d − o)·t/t_d``. The offset is
0 when the program subtracted the electrical dark (OceanView ``Electric dark correction enabled:
true``); otherwise it is measured on the export's out-of-band tail, where the export is
``o + r·t`` alone: ``o = median(tail − d·t/t_d) / (1 − t/t_d)``. Without such a tail a dark of
another time is refused (one line, naming both times). Averaging does not enter: the programs
average scans (the level stays, the noise drops).

Without a dark (no ``--dark``, nothing stored in the file) the baseline is the export's level in
its out-of-band tails (the median of each side; a line between the two sides when both exist) and
is subtracted **with a warning**; an export whose tails sit at 0 within their noise was already
dark-corrected (a note says so). A raw-counts export without such a tail is refused unless
``no_dark`` says the export needs no dark. ``no_dark`` takes the values as they are, with a
warning when the tails say otherwise.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from msflash.calibration.errors import CalibrationError
from msflash.calibration.spectrometer import SpectrometerMeasurement, clip_measurement_negatives
from msflash.processing.spectra import Spectra

Report = Callable[[str], None]

TAIL_FRACTION = 0.002
"""The emission is 'nothing' where the smoothed signal above the baseline is below this share of its peak."""
TAIL_MARGIN_FWHM = 0.5
"""Further margin beyond that point, in FWHM of the emission (LED skirts fall slowly)."""
MIN_TAIL_SAMPLES = 8
"""Fewest out-of-band samples a baseline is measured on."""
BASELINE_SIGMAS = 4.0
"""A tail median further from 0 than this many standard errors is a baseline (not noise)."""
BASELINE_PEAK_SHARE = 0.002
"""…and larger than this share of the peak: smaller offsets change no energy that matters."""
SAME_TIME = 0.01
"""Integration times within 1 % are the same."""


@dataclass(frozen=True)
class Baseline:
    """The level of an export's out-of-band tails."""

    values: np.ndarray
    """The baseline at each sample, shape (n,)."""
    level: float
    """Its mean over the tails."""
    sigma: float
    """The noise of one sample in the tails."""
    standard_error: float
    """Of ``level``."""
    tail: np.ndarray
    """Mask of the tail samples."""
    span: str
    """The tails' wavelengths, for messages (``300–420, 640–1000 nm``)."""

    @property
    def significant(self) -> bool:
        """Whether the tails sit above (or below) 0 by more than noise."""
        return abs(self.level) > BASELINE_SIGMAS * self.standard_error


def _smooth(values: np.ndarray, width: int) -> np.ndarray:
    if width <= 1:
        return values
    kernel = np.ones(width) / width
    return np.convolve(np.pad(values, width // 2, mode="edge"), kernel, mode="valid")[: values.size]


def _sigma(values: np.ndarray) -> float:
    differences = np.diff(values)
    if differences.size < 2:
        return 0.0
    return float(1.4826 * np.median(np.abs(differences - np.median(differences))) / math.sqrt(2))


def _span(wavelengths: np.ndarray, mask: np.ndarray) -> str:
    parts, start = [], None
    for i, inside in enumerate(np.append(mask, False)):
        if inside and start is None:
            start = i
        elif not inside and start is not None:
            parts.append(f"{wavelengths[start]:.0f}–{wavelengths[i - 1]:.0f}")
            start = None
    return ", ".join(parts) + " nm"


def out_of_band_baseline(wavelengths_nm: np.ndarray, values: np.ndarray) -> Baseline | None:
    """The export's baseline measured on its tails, where the emission is nothing; None without tails.

    The tails start beyond the points where the smoothed signal above the current baseline falls
    below :data:`TAIL_FRACTION` of its peak, plus :data:`TAIL_MARGIN_FWHM` of the emission's width;
    the baseline starts at the median of the lowest fifth of the samples and is re-measured on the
    tails three times. Each side's baseline is its median (robust to hot pixels); with both sides
    the baseline is the line through them, else that side's level.

    Examples
    --------
    >>> w = np.arange(300.0, 1000.0, 0.5)
    >>> led = 1000 * np.exp(-0.5 * ((w - 520) / 10) ** 2) + 100 + np.random.default_rng(1).normal(0, 2, w.size)
    >>> b = out_of_band_baseline(w, led)
    >>> round(b.level), b.significant
    (100, True)
    """
    wavelengths = np.asarray(wavelengths_nm, dtype=float)
    values = np.asarray(values, dtype=float)
    n = values.size
    if n < 2 * MIN_TAIL_SAMPLES:
        return None
    step = float(np.median(np.diff(wavelengths)))
    smoothing = max(1, int(round(5.0 / step)) | 1)  # ~5 nm box: the noise off, the emission kept
    baseline = np.full(n, float(np.median(np.sort(values)[: max(n // 5, 1)])))
    tail = np.zeros(n, dtype=bool)
    for _ in range(3):
        signal = _smooth(values - baseline, smoothing)
        top = int(np.argmax(signal))
        peak = float(signal[top])
        if not peak > 0:
            return None
        above = signal > 0.5 * peak
        fwhm = float(np.ptp(wavelengths[above])) + step
        low = top
        while low > 0 and signal[low] > TAIL_FRACTION * peak:
            low -= 1
        high = top
        while high < n - 1 and signal[high] > TAIL_FRACTION * peak:
            high += 1
        margin = TAIL_MARGIN_FWHM * fwhm
        left = (wavelengths < wavelengths[low] - margin) & (np.arange(n) < low)
        right = (wavelengths > wavelengths[high] + margin) & (np.arange(n) > high)
        sides = [side for side in (left, right) if np.count_nonzero(side) >= MIN_TAIL_SAMPLES]
        if not sides:
            return None
        tail = np.any(sides, axis=0)
        if len(sides) == 2:
            x = [float(np.median(wavelengths[side])) for side in sides]
            y = [float(np.median(values[side])) for side in sides]
            baseline = np.interp(wavelengths, x, y)  # constant beyond the sides' centres
        else:
            baseline = np.full(n, float(np.median(values[sides[0]])))
    sigma = float(np.median([_sigma(values[side]) for side in sides]))
    count = int(np.count_nonzero(tail))
    # The median of n Gaussian samples spreads √(π/2)·σ/√n; neighbouring samples of a smoothed
    # export are correlated, so count one sample per box-car width at most.
    standard_error = math.sqrt(math.pi / 2) * sigma / math.sqrt(max(count / smoothing, 1.0))
    return Baseline(baseline, float(np.mean(baseline[tail])), sigma, standard_error, tail, _span(wavelengths, tail))


def _dark_at_time(
    measurement: SpectrometerMeasurement, dark: SpectrometerMeasurement
) -> tuple[np.ndarray, dict[str, object]]:
    """The dark brought to the export's integration time (see the module notes), and how."""
    t, t_dark = measurement.settings.integration_time_s, dark.settings.integration_time_s
    assert t is not None and t_dark is not None  # _minus_dark calls it only when both are stated
    ratio = t / t_dark
    if abs(ratio - 1) <= SAME_TIME:
        return dark.values, {"method": "dark export", "dark": dark.source, "dark_integration_time_s": t_dark}
    if measurement.settings.electric_dark and dark.settings.electric_dark:
        offset, offset_from = 0.0, "0: the program subtracted the electrical dark"
    else:
        tail = out_of_band_baseline(measurement.wavelengths_nm, measurement.values)
        if tail is None:
            raise CalibrationError(
                f"{dark.source}: dark taken at {1e3 * t_dark:g} ms but {measurement.source} at {1e3 * t:g} ms, and "
                f"{measurement.source} has no out-of-band tail to measure the dark's fixed offset on; expected a dark "
                f"at {1e3 * t:g} ms (the export's integration time)"
            )
        offset = float(np.median((measurement.values - ratio * dark.values)[tail.tail]) / (1 - ratio))
        offset_from = f"the out-of-band tail {tail.span}"
    scaled = offset + (dark.values - offset) * ratio
    return scaled, {
        "method": "dark export scaled to the integration time",
        "dark": dark.source,
        "dark_integration_time_s": t_dark,
        "time_ratio": ratio,
        "fixed_offset": offset,
        "fixed_offset_from": offset_from,
    }


def _same_grid(measurement: SpectrometerMeasurement, dark: SpectrometerMeasurement) -> None:
    if dark.wavelengths_nm.shape != measurement.wavelengths_nm.shape or not np.allclose(
        dark.wavelengths_nm, measurement.wavelengths_nm, atol=1e-6
    ):
        raise CalibrationError(
            f"{dark.source}: dark export samples {dark.wavelengths_nm.size} wavelengths "
            f"{dark.wavelengths_nm[0]:g}–{dark.wavelengths_nm[-1]:g} nm but {measurement.source} samples "
            f"{measurement.wavelengths_nm.size} ({measurement.wavelengths_nm[0]:g}–{measurement.wavelengths_nm[-1]:g} nm); "
            "expected the same instrument grid"
        )


def _with_values(
    measurement: SpectrometerMeasurement, values: np.ndarray, baseline: dict[str, object], what: str
) -> SpectrometerMeasurement:
    changed = replace(measurement, values=values, metadata={**measurement.metadata, "baseline": baseline})
    return clip_measurement_negatives(changed, what)


def remove_baseline(
    measurement: SpectrometerMeasurement,
    dark: SpectrometerMeasurement | None = None,
    no_dark: bool = False,
    report: Report = lambda line: None,
) -> SpectrometerMeasurement:
    """The export with its baseline removed; ``metadata["baseline"]`` says how (see the module notes).

    Parameters
    ----------
    dark
        A dark export (shutter closed) on the same instrument grid, or None.
    no_dark
        The export needs no dark (it is dark-corrected, or calibrated): take it as it is.
    report
        Receives the warning or note (one line).

    Raises
    ------
    CalibrationError
        One line naming the file(s): another instrument grid; a dark of another integration time
        with no tail to measure the fixed offset on; a raw-counts export without a dark or a tail;
        a dark and an export of which only one states its integration time.
    """
    if dark is not None:
        return _minus_dark(measurement, dark, report)
    where = measurement.source
    stored = measurement.metadata.get("dark_values")
    if stored is not None and not no_dark:
        report(f"{where}: the dark stored in the export (its Dark column) subtracted")
        return _with_values(
            measurement, measurement.values - stored, {"method": "dark column of the export"}, f"{where} minus its Dark"
        )
    return _minus_tail(measurement, no_dark, report)


def _minus_dark(
    measurement: SpectrometerMeasurement, dark: SpectrometerMeasurement, report: Report
) -> SpectrometerMeasurement:
    """The export minus a dark export, scaled to the export's integration time when both state theirs."""
    where = measurement.source
    _same_grid(measurement, dark)
    times = (measurement.settings.integration_time_s, dark.settings.integration_time_s)
    if times[0] is not None and times[1] is not None:
        values, how = _dark_at_time(measurement, dark)
        if how["method"] != "dark export":
            report(
                f"{where}: the dark {dark.source} was taken at {1e3 * times[1]:g} ms, the export at "
                f"{1e3 * times[0]:g} ms: scaled (dark current ∝ time, fixed offset {how['fixed_offset']:.4g} from "
                f"{how['fixed_offset_from']})"
            )
    elif (times[0] is None) != (times[1] is None):
        stated, unstated = (measurement, dark) if times[0] is not None else (dark, measurement)
        raise CalibrationError(
            f"{unstated.source}: states no integration time but {stated.source} does "
            f"({1e3 * (stated.settings.integration_time_s or 0):g} ms); expected both (a header line or "
            "--integration-time-ms), so that a dark of another time is not subtracted as if it were the same"
        )
    else:
        values, how = dark.values, {"method": "dark export (integration times not stated)", "dark": dark.source}
    result = _with_values(measurement, measurement.values - values, how, f"{where} minus the dark {dark.source}")
    after = out_of_band_baseline(result.wavelengths_nm, result.values)
    if (
        after is not None
        and after.significant
        and abs(after.level) > BASELINE_PEAK_SHARE * float(np.max(result.values))
    ):
        report(
            f"warning: {where}: after subtracting the dark {dark.source} the out-of-band tail ({after.span}) "
            f"still sits at {after.level:.4g} ({100 * after.level / float(np.max(result.values)):.2g} % of the "
            "peak): a dark of another integration time or temperature?"
        )
    return result


def _minus_tail(measurement: SpectrometerMeasurement, no_dark: bool, report: Report) -> SpectrometerMeasurement:
    """Without a dark: the out-of-band tail checked (``no_dark``) or subtracted when it holds a baseline."""
    where = measurement.source
    raw_counts = measurement.settings.value_unit == "counts"
    tail = out_of_band_baseline(measurement.wavelengths_nm, measurement.values)
    peak = float(np.max(measurement.values))
    if no_dark:
        if tail is not None and tail.significant and tail.level > BASELINE_PEAK_SHARE * peak:
            report(
                f"warning: {where}: --no-dark, but the out-of-band tail ({tail.span}) sits at {tail.level:.4g} "
                f"({100 * tail.level / peak:.2g} % of the peak); kept as it is"
            )
        return replace(measurement, metadata={**measurement.metadata, "baseline": {"method": "none (--no-dark)"}})
    if tail is None:
        if raw_counts:
            raise CalibrationError(
                f"{where}: raw counts, no dark given and no out-of-band tail to measure the baseline on; expected "
                "--dark FILE (shutter closed, same integration time), or --no-dark if the export is dark-corrected"
            )
        report(f"{where}: no dark given and no out-of-band tail to check for a baseline; values taken as they are")
        return replace(measurement, metadata={**measurement.metadata, "baseline": {"method": "none (no tail)"}})
    if not tail.significant or abs(tail.level) <= BASELINE_PEAK_SHARE * peak:
        report(
            f"{where}: no dark given; the out-of-band tail ({tail.span}) reads {tail.level:.3g} ± "
            f"{tail.standard_error:.2g}: already dark-corrected, nothing subtracted"
        )
        return replace(
            measurement,
            metadata={**measurement.metadata, "baseline": {"method": "none (tail at 0)", "level": tail.level}},
        )
    report(
        f"warning: {where}: no dark given: a baseline of {tail.level:.4g} ({100 * tail.level / peak:.2g} % of the peak, "
        f"from the out-of-band tail {tail.span}) subtracted; give --dark FILE (shutter closed, same integration "
        "time), or --no-dark if the export is dark-corrected"
    )
    return _with_values(
        measurement,
        measurement.values - tail.values,
        {"method": "out-of-band tail", "level": tail.level, "tail": tail.span},
        f"{where} minus its out-of-band baseline",
    )


def counts_per_second(
    measurements: Sequence[SpectrometerMeasurement], report: Report = lambda line: None
) -> tuple[list[SpectrometerMeasurement], bool]:
    """Raw-counts exports divided by their integration times; and whether they were.

    LEDs measured at different integration times (a dim LED integrated longer) keep their true
    ratios only per second. Calibrated exports (energy, photons) are already per unit time and are
    returned unchanged.

    Raises
    ------
    CalibrationError
        Raw-counts exports of which some state their integration time and some do not.
    """
    counts = [m for m in measurements if m.settings.value_unit == "counts"]
    if not counts:
        return list(measurements), False
    stated = [m for m in counts if m.settings.integration_time_s is not None]
    if stated and len(stated) != len(counts):
        missing = next(m for m in counts if m.settings.integration_time_s is None)
        raise CalibrationError(
            f"{missing.source}: states no integration time but {stated[0].source} does "
            f"({1e3 * (stated[0].settings.integration_time_s or 0):g} ms); expected every export's integration time "
            "(a header line, or --integration-time-ms) so the LEDs' ratios hold"
        )
    if not stated:
        if len(counts) > 1:
            report(
                "warning: the exports state no integration time: the LEDs' ratios assume one time for all "
                "(--integration-time-ms, or measure the ratios through the camera with --white SEQ)"
            )
        return list(measurements), False
    result = []
    for m in measurements:
        t = m.settings.integration_time_s
        if m.settings.value_unit == "counts" and t is not None:
            m = replace(m, values=m.values / t, metadata={**m.metadata, "per_second": True})
        result.append(m)
    times = sorted({float(m.settings.integration_time_s or 0.0) for m in stated})
    if len(times) > 1:
        report(
            "exports at integration times "
            + ", ".join(f"{1e3 * t:g}" for t in times)
            + " ms: counts divided by each time (counts per second)"
        )
    return result, True


def divide_by_response(spectra: Spectra, response: Spectra, where: str) -> Spectra:
    """Counts (per second) on a grid made energy: divided by the spectrometer's response on that grid.

    ``response`` is the spectrometer's signal per unit energy (counts per second per W·m⁻²·nm⁻¹,
    any common scale: an irradiance calibration), one column, already on ``spectra``'s grid.

    Raises
    ------
    CalibrationError
        Where an LED emits (above 1 % of its peak) and the response is not positive.
    """
    factor = response.values[:, 0]
    for index, name in enumerate(spectra.names):
        column = spectra.values[:, index]
        emitting = column > 0.01 * float(np.max(column))
        blind = emitting & ~(factor > 0)
        if np.any(blind):
            wavelength = float(spectra.wavelengths_nm[int(np.argmax(blind))])
            raise CalibrationError(
                f"{where}: the response is {factor[int(np.argmax(blind))]:g} at {wavelength:g} nm where LED '{name}' "
                "emits; expected a positive response over every LED's emission"
            )
    with np.errstate(divide="ignore", invalid="ignore"):
        values = np.where(factor[:, None] > 0, spectra.values / factor[:, None], 0.0)
    return spectra.replace(values=values, unit="energy", source=f"{spectra.source} ÷ response {where}")
