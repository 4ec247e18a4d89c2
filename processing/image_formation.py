"""Image formation (eq. 1–3 of the paper) and a simple sensor model, for simulation.

Public objects
--------------
- :func:`total_illumination`: ``i = i_a + I w`` (eq. 2 with the flash as weighted LEDs).
- :func:`expected_response`: the noise-free ``m = g Cᵀ diag(r) i`` for every pixel (eq. 1–3).
- :func:`render_frame`: an integer raw frame with photon and read noise, black level, gain,
  saturation, quantisation and an optional Bayer mosaic.
- :func:`exposure_for_peak`: the exposure putting the brightest pixel at a fraction of full scale.
- :class:`MixedIllumination`, :func:`expected_response_mixed`: a spatially varying illuminant.

Scenes are :mod:`processing.scenes`; the sensor model and Bayer layouts :mod:`processing.sensor`.

Units
-----
Everything inside works in **photons**: illuminants and responsivities given in energy are
converted with ``Spectra.to_unit("photons")`` (the paper's simulations do the same), so a
response counts photo-electrons. The integral of eq. 1 is discretised as a sum times the grid
step, so the response does not depend on the sampling interval. ``scale`` carries everything
the spectra leave out (aperture, pixel area, quantum efficiency): it is the number of electrons
one unit of ``Σ r c i Δλ`` produces per microsecond.

The response is computed once per *surface* (n × 3 numbers) and then indexed by the label image;
no per-pixel spectral products are ever formed.

References
----------
Blasinski H., Farrell J. "Computational multispectral flash", ICCP 2017, eq. 1–3:
``m_j = g ∫ r(λ) c_j(λ) i(λ) dλ``, ``i = i_a + i_f``,
``m = g Cᵀ diag(r) i_a + g Cᵀ diag(r) i_f``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from msflash.processing.errors import SpectralDataError
from msflash.processing.scenes import Scene
from msflash.processing.sensor import SensorModel, mosaic
from msflash.processing.spectra import Spectra, require_same_grid

if TYPE_CHECKING:
    from numpy.random import Generator


# -- image formation (eq. 1–3) ----------------------------------------------------------------
def total_illumination(ambient: Spectra, led_spectra: Spectra, led_levels: Sequence[float] | np.ndarray) -> Spectra:
    """``i = i_a + I w``: the ambient plus the LEDs at their drive levels (eq. 2).

    Parameters
    ----------
    led_levels
        ``w``, k drive levels (0 = off, 1 = full).

    Returns
    -------
    Spectra
        One spectrum, in the ambient's unit, on the common grid.
    """
    grid = require_same_grid(ambient, led_spectra)
    levels = np.asarray(led_levels, dtype=float)
    if levels.shape != (led_spectra.count,) or not np.all(np.isfinite(levels)):
        raise SpectralDataError(
            f"total illumination: {levels.size} LED levels for {led_spectra.count} LEDs ({led_spectra.source}); "
            "expected one finite level per LED"
        )
    if ambient.count != 1 or ambient.kind != "spd" or led_spectra.kind != "spd":
        raise SpectralDataError("total illumination: expected one ambient spectrum and LED spectra of kind 'spd'")
    flash = led_spectra.to_unit(ambient.unit).values @ levels
    return Spectra(
        grid,
        ambient.values[:, 0] + flash,
        ("illumination",),
        kind="spd",
        unit=ambient.unit,
        source=f"{ambient.source or 'ambient'} + LEDs at {tuple(round(float(v), 4) for v in levels)}",
    )


def surface_responses(reflectances: Spectra, illuminant: Spectra, camera_responsivities: Spectra) -> np.ndarray:
    """``Cᵀ diag(r) i Δλ`` for every surface: the per-surface core of eq. 1–3, in photons.

    Returns
    -------
    np.ndarray
        (n_surfaces, n_channels) expected electrons per microsecond at unit ``scale``.
    """
    grid = require_same_grid(reflectances, illuminant, camera_responsivities)
    if illuminant.kind != "spd" or illuminant.count != 1:
        raise SpectralDataError(f"{illuminant.source or 'illuminant'}: expected one spectrum of kind 'spd'")
    if camera_responsivities.kind != "responsivity":
        raise SpectralDataError(
            f"{camera_responsivities.source or 'camera responsivities'}: kind '{camera_responsivities.kind}'; "
            "expected responsivity"
        )
    photons = illuminant.to_unit("photons").values[:, 0]
    responsivities = camera_responsivities.to_unit("photons").values
    return (reflectances.values * photons[:, None]).T @ responsivities * grid.step_nm


def expected_response(
    scene: Scene,
    illuminant: Spectra | MixedIllumination,
    camera_responsivities: Spectra,
    exposure_us: float,
    gain: float = 1.0,
    scale: float = 1.0,
) -> np.ndarray:
    """The noise-free response ``m = g Cᵀ diag(r) i`` of every pixel (eq. 1–3), in electrons × gain.

    Parameters
    ----------
    illuminant
        ``i`` (e.g. from :func:`total_illumination`), one spectrum; energy is converted to photons.
        A :class:`MixedIllumination` gives a spatially varying illuminant
        (:func:`expected_response_mixed`).
    camera_responsivities
        ``C``, (n_wavelengths, n_channels); energy is converted to photons.
    exposure_us, gain, scale
        Together the paper's ``g``: ``g = scale · exposure_us · gain``.

    Returns
    -------
    np.ndarray
        (H, W, n_channels) float: expected photo-electrons times ``gain`` (divide by the sensor's
        ``electrons_per_dn`` for digital numbers above black). Linear in the illuminant and in
        ``g``; not clipped.
    """
    for name, value in (("exposure_us", exposure_us), ("gain", gain), ("scale", scale)):
        if not (math.isfinite(value) and value >= 0):
            raise SpectralDataError(f"expected response: {name} is {value}; expected a finite value ≥ 0")
    if isinstance(illuminant, MixedIllumination):
        return expected_response_mixed(scene, illuminant, camera_responsivities, exposure_us, gain, scale)
    per_surface = surface_responses(scene.reflectances, illuminant, camera_responsivities)
    g = scale * exposure_us * gain
    image = per_surface[scene.labels] * g
    if scene.shading is not None:
        image *= scene.shading[..., None]
    if scene.specular is not None and scene.specular_gain > 0:
        # Dichromatic model: the interface reflection is neutral, i.e. the illuminant as a white
        # diffuser would show it, added on top of the body reflection.
        white = Spectra(illuminant.grid, np.ones(illuminant.grid.size), ("white",), kind="reflectance", unit="none")
        highlight = surface_responses(white, illuminant, camera_responsivities)[0] * g * scene.specular_gain
        image[scene.specular] += highlight
    return image


def render_frame(
    scene: Scene,
    illuminant: Spectra | MixedIllumination,
    camera_responsivities: Spectra,
    sensor: SensorModel,
    exposure_us: float,
    gain: float = 1.0,
    scale: float = 1.0,
    rng: Generator | None = None,
    noise: bool = True,
) -> np.ndarray:
    """A raw frame: eq. 1–3 through a sensor with photon and read noise.

    Steps: expected electrons (:func:`expected_response` at gain 1) → Bayer sampling if
    ``sensor.cfa`` → Poisson photon noise → full-well clip → Gaussian read noise → ×
    ``gain / electrons_per_dn`` → + black level → rounding → clip to ``[0, white_level]``. Pixels
    that hit the full well or the top code read exactly ``white_level``, so "≥ white_level" finds
    every saturated pixel.

    Parameters
    ----------
    gain
        Linear analogue gain, applied after the photo-electrons are collected.
    rng
        Random generator (seed it for reproducible frames); a fresh unseeded one if None.
    noise
        False gives the noise-free frame (still quantised and clipped), as in the paper's simulations.

    Returns
    -------
    np.ndarray
        Unsigned integers of ``sensor.dtype``, (H, W, 3) or (H, W) for a mosaic.
    """
    if not (math.isfinite(gain) and gain > 0):
        raise SpectralDataError(f"render frame: gain is {gain}; expected a finite value > 0")
    electrons = expected_response(scene, illuminant, camera_responsivities, exposure_us, 1.0, scale)
    if sensor.cfa is not None:
        if electrons.shape[2] != 3:
            raise SpectralDataError(
                f"render frame: a {sensor.cfa} mosaic needs 3 channels; the camera has {electrons.shape[2]}"
            )
        electrons = mosaic(electrons, sensor.cfa)
    rng = rng if rng is not None else np.random.default_rng()
    if noise:
        electrons = rng.poisson(electrons).astype(float)
    full_well = electrons >= sensor.full_well_e
    if noise and sensor.read_noise_e > 0:
        electrons = electrons + rng.normal(0.0, sensor.read_noise_e, electrons.shape)
    values = np.rint(sensor.black_level + electrons * (gain / sensor.electrons_per_dn))
    values = np.clip(values, 0, sensor.white_level)
    values[full_well] = sensor.white_level
    return values.astype(sensor.dtype)


def exposure_for_peak(
    scene: Scene,
    illuminant: Spectra | MixedIllumination,
    camera_responsivities: Spectra,
    sensor: SensorModel,
    fraction: float = 0.95,
    gain: float = 1.0,
) -> float:
    """The exposure (µs) putting the brightest expected pixel value at ``fraction`` of full scale.

    Full scale is the saturation point (:meth:`SensorModel.saturation_electrons`); the paper's
    simulations use 95%. Highlights are left out, as a photographer meters the subject.

    Raises
    ------
    SpectralDataError
        If ``fraction`` is not in (0, 1] or the scene gives no signal.
    """
    if not 0 < fraction <= 1:
        raise SpectralDataError(f"exposure for peak: fraction {fraction}; expected 0 < fraction ≤ 1")
    metered = scene
    if scene.specular is not None:
        metered = Scene(scene.reflectances, scene.labels, scene.shading, None)
    response = expected_response(metered, illuminant, camera_responsivities, 1.0)
    if scene.specular is not None:
        response = response[~scene.specular]
    peak = float(np.max(response)) if response.size else 0.0
    if peak <= 0:
        raise SpectralDataError(
            "exposure for peak: the scene gives no signal under this illuminant; "
            "expected some light reaching the camera"
        )
    return fraction * sensor.saturation_electrons(gain) / peak


# -- spatially varying illumination (issue 9) -------------------------------------------------
@dataclass(frozen=True)
class MixedIllumination:
    """A spatially varying illuminant: pixel ``x`` sees ``Σ_n weights[x, n] · spectra[:, n]``.

    Two ambients with a boundary or a gradient, plus the LEDs as a component of weight 1
    everywhere (:meth:`plus`). Light is additive, so the response is the per-pixel weighted sum of
    the responses to each component (:func:`expected_response_mixed`). Arrays are copied and made
    read-only; spectra are kept in photons.
    """

    spectra: Spectra
    """The components, (n_wavelengths, n) SPDs."""
    weights: np.ndarray
    """Per-pixel weight of each component, (H, W, n), finite and ≥ 0."""

    def __post_init__(self) -> None:
        if self.spectra.kind != "spd":
            raise SpectralDataError(f"mixed illumination: spectra of kind '{self.spectra.kind}'; expected spd")
        weights = np.array(self.weights, dtype=float, copy=True)
        if weights.ndim != 3 or weights.shape[2] != self.spectra.count:
            raise SpectralDataError(
                f"mixed illumination: weights have shape {weights.shape}; expected (H, W, "
                f"{self.spectra.count}) (one map per component)"
            )
        if not np.all(np.isfinite(weights)) or np.any(weights < 0):
            raise SpectralDataError("mixed illumination: weights must be finite and ≥ 0")
        weights.flags.writeable = False
        object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "spectra", self.spectra.to_unit("photons"))

    @classmethod
    def two_ambients(cls, first: Spectra, second: Spectra, mixing_map: np.ndarray) -> MixedIllumination:
        """``(1 − m(x)) · first + m(x) · second`` for a mixing map ``m`` (H, W) in [0, 1]."""
        grid = require_same_grid(first, second)
        mixing = np.asarray(mixing_map, dtype=float)
        if mixing.ndim != 2 or np.any(mixing < 0) or np.any(mixing > 1) or not np.all(np.isfinite(mixing)):
            raise SpectralDataError(
                f"mixed illumination: mixing map of shape {mixing.shape}; expected (H, W) values in [0, 1]"
            )
        values = np.column_stack([first.to_unit("photons").values[:, 0], second.to_unit("photons").values[:, 0]])
        spectra = Spectra(
            grid,
            values,
            ("first", "second"),
            kind="spd",
            unit="photons",
            source=f"{first.source or 'first'} | {second.source or 'second'}",
        )
        return cls(spectra, np.stack([1.0 - mixing, mixing], axis=-1))

    def plus(self, uniform: Spectra) -> MixedIllumination:
        """This illumination plus a spatially uniform one (the flash: ``total_illumination`` of a dark ambient)."""
        require_same_grid(self.spectra, uniform)
        extra = uniform.to_unit("photons").values[:, :1]
        spectra = Spectra(
            self.spectra.grid,
            np.hstack([self.spectra.values, extra]),
            self.spectra.names + (f"uniform {self.spectra.count}",),
            kind="spd",
            unit="photons",
            source=self.spectra.source,
        )
        ones = np.ones(self.weights.shape[:2] + (1,))
        return MixedIllumination(spectra, np.concatenate([self.weights, ones], axis=-1))


def expected_response_mixed(
    scene: Scene,
    illumination: MixedIllumination,
    camera_responsivities: Spectra,
    exposure_us: float,
    gain: float = 1.0,
    scale: float = 1.0,
) -> np.ndarray:
    """:func:`expected_response` under a spatially varying illuminant.

    The response to each component is computed per surface (as for a uniform illuminant) and the
    pixels take the weighted sum: exact by the linearity of eq. 1–3. Highlights mirror the local
    illuminant.
    """
    if illumination.weights.shape[:2] != scene.shape:
        raise SpectralDataError(
            f"mixed illumination: weights cover {illumination.weights.shape[:2]} pixels but the "
            f"scene has {scene.shape}; expected one weight map per scene pixel"
        )
    image = np.zeros(scene.shape + (camera_responsivities.count,))
    for index in range(illumination.spectra.count):
        component = illumination.spectra.select([index])
        image += (
            expected_response(scene, component, camera_responsivities, exposure_us, gain, scale)
            * illumination.weights[:, :, index : index + 1]
        )
    return image
