"""A chart's reflectances measured with a spectrometer: each patch's export over a white reference's.

``msflash calibrate chart`` parses options and prints; this module does the work with explicit
arguments (:func:`chart_from_exports`); the export reader and the noise estimate are
:mod:`msflash.calibration`'s. Bad input raises :class:`msflash.acquisition.errors.UsageError` naming
the file and what was expected.
"""

from __future__ import annotations

from collections.abc import Sequence as SequenceOf
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.errors import UsageError
from msflash.acquisition.progress import progress
from msflash.acquisition.session.calibration_inputs import Report, read_white_reflectance
from msflash.acquisition.session.chart_layout import chart_reference_grid
from msflash.calibration.chart_noise import NOISE_WARNING, chart_noise, noise_summary
from msflash.calibration.led_exports import ExportOptions, LedExports, read_led_exports
from msflash.processing.spectra import DEFAULT_GRID, Spectra

MIN_WHITE_SHARE = 0.02
"""A chart's reflectance is measured where the white reference reads at least this share of its peak."""


def chart_from_exports(
    files: SequenceOf[str | Path],
    white: str | Path,
    white_reflectance: str | None = None,
    options: ExportOptions | None = None,
    grid_spec: str | None = None,
    report: Report = progress,
) -> tuple[Spectra, dict[str, Any]]:
    """A chart's reflectances from spectrometer exports: each patch over a white reference.

    ``ρ_p(λ) = (s_p(λ) − dark) / (s_white(λ) − dark) · ρ_white(λ)``, each export's baseline removed
    and its counts per second taken as for LEDs (:func:`msflash.calibration.led_exports.read_led_exports`:
    each export takes the dark of its integration time, a dark of another time is scaled where an
    out-of-band tail allows, none without ``--no-dark`` refused), so the spectrometer's response
    cancels. Exports in chart order (column by column, as the Macbeth file).

    The camera fit takes the chart as exact: the reflectances' noise is estimated
    (:mod:`msflash.calibration.chart_noise`), recorded as ``noise`` and warned about above
    ``NOISE_WARNING``.

    Returns
    -------
    The reflectances on :data:`DEFAULT_GRID` (one column per patch, named after the files) and the
    calibration's ``chart`` section.

    Raises
    ------
    UsageError, CalibrationError
        One line naming the file: what the export reader refuses, a white that does not cover the
        grid, reflectances far outside 0–1.5 (a patch brighter than the white: the wrong file?).
    """
    options = options or ExportOptions()
    patches = read_led_exports(files, DEFAULT_GRID, options, report, relative=True)
    reference = read_led_exports([white], DEFAULT_GRID, options, report, relative=True)
    _check_same_instrument(patches, reference, files[0], white)
    white_values = _lit_white(reference, white)
    factor = (
        read_white_reflectance(white_reflectance, DEFAULT_GRID).values[:, 0]
        if white_reflectance
        else np.ones(DEFAULT_GRID.size)
    )
    reflectances = patches.spectra.values / white_values[:, None] * factor[:, None]
    worst = float(reflectances.max())
    if worst > 1.5:
        p = int(np.argmax(reflectances.max(axis=0)))
        raise UsageError(
            f"{files[p]}: reflects {worst:.3g} × the white {white}; expected a chart patch darker than the white "
            "reference (same light, same geometry)"
        )
    names = tuple(Path(f).stem for f in files)
    spectra = Spectra(
        DEFAULT_GRID,
        np.clip(reflectances, 0.0, None),
        names,
        kind="reflectance",
        unit="none",
        source=f"measured: {len(files)} exports over the white {white}",
    )
    rows, columns = chart_reference_grid(len(files), grid_spec)
    noise = noise_summary(
        chart_noise(patches.measurements, reference.measurements[0], DEFAULT_GRID), names, DEFAULT_GRID
    )
    _warn_noise(noise, report)
    section = {
        "sources": [str(f) for f in files],
        "white": str(white),
        "white_reflectance": white_reflectance,
        "rows": rows,
        "columns": columns,
        "acquisition": patches.section["acquisition"],
        "baselines": patches.section["baselines"],
        "noise": noise,
    }
    return spectra, section


def _check_same_instrument(patches: LedExports, reference: LedExports, first: str | Path, white: str | Path) -> None:
    """Refuse patches and a white in different units, or one with an integration time and one without."""
    if patches.unit != reference.unit:
        raise UsageError(
            f"--white {white}: {reference.unit} but the patches are {patches.unit}; expected one instrument and unit"
        )
    if patches.section["counts_per_second"] != reference.section["counts_per_second"]:
        stated, unstated = (first, white) if patches.section["counts_per_second"] else (white, first)
        raise UsageError(
            f"{unstated}: states no integration time but {stated} does; expected both (a header line or "
            "--integration-time-ms), so that the patches and the white are compared per second"
        )


def _lit_white(reference: LedExports, white: str | Path) -> np.ndarray:
    """The white reference's values, refused where it reads below ``MIN_WHITE_SHARE`` of its peak."""
    white_values = reference.spectra.values[:, 0]
    usable = white_values > MIN_WHITE_SHARE * float(white_values.max())
    if not np.all(usable):
        missing = DEFAULT_GRID.wavelengths_nm[~usable]
        raise UsageError(
            f"--white {white}: reads below {100 * MIN_WHITE_SHARE:g} % of its peak at {missing[0]:g}–{missing[-1]:g} nm; "
            f"expected a white reference lit over {DEFAULT_GRID} (a broadband lamp)"
        )
    return white_values


def _warn_noise(noise: dict | None, report: Report) -> None:
    """A warning when the measured reflectances' noise is above ``NOISE_WARNING``."""
    if noise is not None and noise["relative_rms"] > NOISE_WARNING:
        report(
            f"warning: the measured reflectances carry {100 * noise['relative_rms']:.2g} % noise (RMS; worst "
            f"{noise['worst_patch']}, {100 * noise['worst_value']:.2g} % at {noise['worst_nm']:g} nm); the camera fit "
            f"takes them as exact (above {100 * NOISE_WARNING:g} % it cost accuracy in tests): average more scans, or "
            "lengthen the integration time of the dark patches (a dark export per time, --dark)"
        )
