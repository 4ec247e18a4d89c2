"""What the LED model gets wrong on measured lights: the estimate's model error and miss risk.

The pixel-noise band of eq. 5 (:attr:`processing.ambient.AmbientEstimate.spectrum_std`) says how
much the weights scatter, not how far ``I w`` lies from the true ambient: a light outside the LEDs'
span, or one the camera sees only through its few channels, is estimated wrongly even without
noise, and that error is usually the larger. It cannot be read off the scene's pixels (the camera
does not see it), so it is learnt from measured lights instead.

For one LED set and camera, every reference light (the light prior's training lights,
:func:`processing.light_library.prior_training_lights`) is estimated as eq. 5 would estimate it
without noise — a generic scene of Natural-100 surfaces under it, explained by the same surfaces
under each LED (non-negative spectrum) — and its error is kept: the estimate minus the truth least-
squares scaled onto it, both in the paper's normalisation (estimate max 1), and the ratio of its RMSE
to the best non-negative LED fit of the truth. For a scene's estimate, the reference lights whose
noise-free estimates look most like it (:data:`NEIGHBOURS` nearest, in that normalisation) say how
wrong such an estimate tends to be at each wavelength (their RMS error: the model band), and how
often it misses (their share of errors above :data:`MISS_RATIO` × their LED bound, with the pixel
noise added): the miss risk behind the estimate's warning.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from msflash.processing.ambient import AmbientEstimate, AmbientModel
from msflash.processing.datasets import natural100
from msflash.processing.errors import SpectralDataError
from msflash.processing.light_library import prior_training_lights
from msflash.processing.scipy_cores import nnls
from msflash.processing.spectra import Spectra, WavelengthGrid, require_unit
from msflash.processing.statistics import SequenceStatistics

NEIGHBOURS = 12
"""Reference lights whose noise-free estimates are nearest a scene's estimate, that describe its error band."""
RISK_NEIGHBOURS = 8
"""The nearest reference lights whose median error ratio predicts a miss (:attr:`ModelError.expected_ratio`)."""
EXPECTED_RATIO_WARNING = 1.06
"""An estimate whose :attr:`ModelError.expected_ratio` reaches this is flagged as a likely miss. Chosen on
tuning-split scenes only; its recall and false alarms are in docs/ambient-estimate.md."""
MISS_RATIO = 1.3
"""An estimate whose RMSE exceeds this multiple of the best non-negative LED fit's is a miss."""


@dataclass(frozen=True)
class LightReference:
    """The LED model's noise-free behaviour on the reference lights, for one LED set and camera."""

    estimates: np.ndarray
    """(n_wl, T) each reference light's noise-free estimate ``I w``, max-normalised."""
    errors: np.ndarray
    """(n_wl, T) each estimate minus its truth least-squares scaled onto it."""
    bounds: np.ndarray
    """(T,) RMSE of the best non-negative LED fit of each light (the LED bound)."""
    rmse: np.ndarray
    """(T,) RMSE of each noise-free estimate."""


@dataclass(frozen=True)
class ModelError:
    """How wrong an estimate like this one tends to be, from its nearest reference lights."""

    spectrum_std: np.ndarray
    """(n_wl,) the model's error at each wavelength, in the estimate's units (RMS over the neighbours)."""
    miss_risk: float
    """Share of the :data:`NEIGHBOURS` whose error, with this estimate's pixel noise added, exceeds
    :data:`MISS_RATIO` × their LED bound."""
    expected_ratio: float
    """Median over the :data:`RISK_NEIGHBOURS` nearest of that error ÷ their LED bound."""


def _paper_rmse_parts(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(max-normalised estimates, their error against the least-squares scaled truth), column-wise."""
    peak = np.max(np.abs(estimate), axis=0)
    normalised = estimate / np.where(peak > 0, peak, 1.0)
    energy = np.sum(truth * truth, axis=0)
    scale = np.sum(truth * normalised, axis=0) / np.where(energy > 0, energy, 1.0)
    return normalised, normalised - truth * scale


def light_reference(
    led_spectra: Spectra, responsivities: Spectra, lights: Spectra | None = None, surfaces: Spectra | None = None
) -> LightReference:
    """The LED model's noise-free estimates of ``lights`` (default: the light prior's training lights).

    Parameters
    ----------
    led_spectra, responsivities
        The k LED spectra and the camera's channels, in photons, on one grid.
    lights
        Reference light spectra (any unit and grid; resampled, zero outside their range).
    surfaces
        Reflectances of the generic scene (default Natural-100, edge values held outside 400–700 nm).
    """
    leds = require_unit(led_spectra, "photons")
    camera = require_unit(responsivities, "photons")
    grid = leds.grid
    if camera.grid != grid:
        raise SpectralDataError(f"model error: responsivities on {camera.grid} but LEDs on {grid}; expected one grid")
    lights = prior_training_lights() if lights is None else lights
    light_values = lights.to_unit("photons").resample(grid, outside="zero").values
    reflectances = (natural100() if surfaces is None else surfaces).resample(grid, outside="edge").values
    # Camera responses of every surface (× channel) to each LED and each light: eq. 2 on the generic scene.
    channels = camera.values  # (n_wl, C)
    probes = (reflectances[:, :, None] * channels[:, None, :]).reshape(grid.size, -1)  # (n_wl, S·C)
    led_responses = probes.T @ leds.values  # (S·C, k)
    light_responses = probes.T @ light_values  # (S·C, T)
    gram = led_responses.T @ led_responses
    model = AmbientModel(leds)
    n = led_responses.shape[0]
    weights = np.column_stack(
        [
            model.weights(
                SequenceStatistics(
                    gram,
                    led_responses.T @ light_responses[:, t],
                    float(light_responses[:, t] @ light_responses[:, t]),
                    n,
                    n,
                    float(light_responses[:, t].sum()),
                    led_responses.sum(axis=0),
                ),
                "nonneg",
            )[0]
            for t in range(light_values.shape[1])
        ]
    )
    estimates, errors = _paper_rmse_parts(leds.values @ weights, light_values)
    best = np.column_stack(
        [leds.values @ nnls(leds.values, light_values[:, t])[0] for t in range(light_values.shape[1])]
    )
    _, best_errors = _paper_rmse_parts(best, light_values)
    return LightReference(
        estimates=estimates,
        errors=errors,
        bounds=np.sqrt(np.mean(best_errors**2, axis=0)),
        rmse=np.sqrt(np.mean(errors**2, axis=0)),
    )


@lru_cache(maxsize=8)
def _cached_reference(led_key: bytes, camera_key: bytes, grid: WavelengthGrid, k: int, c: int) -> LightReference:
    leds = Spectra(
        grid, np.frombuffer(led_key).reshape(grid.size, k), tuple(f"led{i}" for i in range(k)), unit="photons"
    )
    camera = Spectra(
        grid,
        np.frombuffer(camera_key).reshape(grid.size, c),
        tuple(f"c{i}" for i in range(c)),
        kind="responsivity",
        unit="photons",
    )
    return light_reference(leds, camera)


def reference_for(led_spectra: Spectra, responsivities: Spectra) -> LightReference:
    """:func:`light_reference` on the default lights and surfaces, computed once per LED set and camera."""
    leds = require_unit(led_spectra, "photons")
    camera = require_unit(responsivities, "photons").resample(leds.grid, outside="zero")
    return _cached_reference(
        np.ascontiguousarray(leds.values, dtype=float).tobytes(),
        np.ascontiguousarray(camera.values, dtype=float).tobytes(),
        leds.grid,
        leds.count,
        camera.count,
    )


def model_error(
    reference: LightReference, spectrum: np.ndarray, noise_std: np.ndarray, neighbours: int = NEIGHBOURS
) -> ModelError:
    """The model error of an estimate ``spectrum`` (n_wl, any scale) with pixel-noise band ``noise_std``.

    The neighbours are the reference lights whose noise-free estimates are nearest the estimate (both
    max-normalised, Euclidean). Their RMS error per wavelength, scaled to the estimate, is the model
    band; the miss risk counts those whose RMSE combined with this estimate's noise RMS,
    ``√(rmse² + mean(σ²))`` (normalised), exceeds :data:`MISS_RATIO` × their LED bound.
    """
    values = np.asarray(spectrum, dtype=float)
    peak = float(np.max(np.abs(values)))
    if not peak > 0 or not np.isfinite(peak):
        return ModelError(np.zeros_like(values), 1.0, float("inf"))
    distances = np.linalg.norm(reference.estimates - (values / peak)[:, None], axis=0)
    nearest = np.argsort(distances)[: max(1, min(neighbours, distances.size))]
    band = np.sqrt(np.mean(reference.errors[:, nearest] ** 2, axis=1)) * peak
    noise = float(np.sqrt(np.mean(np.square(np.asarray(noise_std, dtype=float) / peak))))
    ratios = np.sqrt(reference.rmse[nearest] ** 2 + noise**2) / np.maximum(reference.bounds[nearest], 1e-12)
    return ModelError(band, float(np.mean(ratios > MISS_RATIO)), float(np.median(ratios[:RISK_NEIGHBOURS])))


def with_model_error(estimate: AmbientEstimate, reference: LightReference) -> AmbientEstimate:
    """``estimate`` with the model error in its band and its miss risk in its warnings.

    The band becomes ``√(σ_noise² + σ_model²)`` (:func:`model_error`); :attr:`AmbientEstimate.noise_std`
    keeps the pixel-noise part.
    """
    noise = estimate.spectrum_std if estimate.noise_std is None else estimate.noise_std
    error = model_error(reference, estimate.spectrum.values[:, 0], noise)
    warnings = list(estimate.warnings)
    if error.expected_ratio >= EXPECTED_RATIO_WARNING and not estimate.ambient_is_dark:
        warnings.append(
            f"the spectrum may be off by more than {MISS_RATIO:g}× what the LEDs allow: the {RISK_NEIGHBOURS} "
            f"measured lights whose estimates look most like this one came out {error.expected_ratio:.2f}× their "
            f"LED bound (median, with this estimate's noise) — see the band"
        )
    return replace(
        estimate,
        spectrum_std=np.sqrt(noise**2 + error.spectrum_std**2),
        noise_std=noise,
        band_meaning=(
            f"±1σ of the pixel noise and the model's error (RMS error of the {NEIGHBOURS} "
            "measured lights whose noise-free estimates look most like this one)"
        ),
        miss_risk=error.miss_risk,
        expected_ratio=error.expected_ratio,
        warnings=tuple(warnings),
    )
