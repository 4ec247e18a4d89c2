"""Image formation (eq. 1–3 of the paper) and a simple sensor model, for simulation.

Public objects
--------------
- :class:`Scene`: surfaces (reflectances) laid out by a label image, with optional shading and
  a specular area; :func:`chart_scene`, :func:`mosaic_scene` and :func:`uniform_scene` build
  common ones, and :func:`placed_scene` puts a scene anywhere in a larger frame (scaled, rotated).
- :class:`SensorModel`: black and white level, bit depth, conversion gain, read noise, full well,
  colour filter array.
- :func:`total_illumination`: ``i = i_a + I w`` (eq. 2 with the flash as weighted LEDs).
- :func:`expected_response`: the noise-free ``m = g Cᵀ diag(r) i`` for every pixel (eq. 1–3).
- :func:`render_frame`: an integer raw frame with photon and read noise, black level, gain,
  saturation, quantisation and an optional Bayer mosaic.
- :func:`mosaic`, :data:`CFA_PATTERNS`, :func:`cfa_channel_map`: the Bayer layouts.
- :func:`exposure_for_peak`: the exposure putting the brightest pixel at a fraction of full scale.

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
from typing import TYPE_CHECKING, Literal

import numpy as np

from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID, Spectra, require_same_grid

if TYPE_CHECKING:
    from numpy.random import Generator

CFA_PATTERNS: dict[str, tuple[tuple[int, int], tuple[int, int]]] = {
    "RGGB": ((0, 1), (1, 2)),
    "BGGR": ((2, 1), (1, 0)),
    "GRBG": ((1, 0), (2, 1)),
    "GBRG": ((1, 2), (0, 1)),
}
"""Channel index (0 = R, 1 = G, 2 = B) at ``(row % 2, column % 2)`` for each Bayer layout."""


# -- scenes -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class Scene:
    """A flat scene: each pixel shows one surface, optionally shaded, optionally specular.

    Arrays are copied and made read-only on construction.
    """

    reflectances: Spectra
    """Surface reflectances, shape (n_wavelengths, n_surfaces)."""
    labels: np.ndarray
    """Surface index of every pixel, integer array (H, W), values in ``[0, n_surfaces)``."""
    shading: np.ndarray | None = None
    """Per-pixel factor on the diffuse reflection (geometry, vignetting), (H, W), ≥ 0; None = 1."""
    specular: np.ndarray | None = None
    """Pixels that also show a neutral highlight (dichromatic model), bool (H, W); None = none."""
    specular_gain: float = 4.0
    """Strength of the highlight relative to a perfect white diffuser; > 1 saturates at metered exposures."""

    def __post_init__(self) -> None:
        where = f"scene ({self.reflectances.source or 'reflectances'})"
        if self.reflectances.kind != "reflectance":
            raise SpectralDataError(f"{where}: reflectances have kind '{self.reflectances.kind}'; expected reflectance")
        labels = np.array(self.labels, copy=True)
        if labels.ndim != 2 or labels.size == 0 or not np.issubdtype(labels.dtype, np.integer):
            raise SpectralDataError(
                f"{where}: labels have shape {labels.shape} and type {labels.dtype}; "
                "expected a non-empty integer array (H, W)"
            )
        if labels.min() < 0 or labels.max() >= self.reflectances.count:
            raise SpectralDataError(
                f"{where}: labels span {labels.min()}…{labels.max()}; expected "
                f"0…{self.reflectances.count - 1} (one per surface)"
            )
        labels.flags.writeable = False
        object.__setattr__(self, "labels", labels)
        if self.shading is not None:
            shading = np.array(self.shading, dtype=float, copy=True)
            if shading.shape != labels.shape or not np.all(np.isfinite(shading)) or np.any(shading < 0):
                raise SpectralDataError(
                    f"{where}: shading has shape {shading.shape}; expected finite values ≥ 0 of shape {labels.shape}"
                )
            shading.flags.writeable = False
            object.__setattr__(self, "shading", shading)
        if self.specular is not None:
            specular = np.array(self.specular, dtype=bool, copy=True)
            if specular.shape != labels.shape:
                raise SpectralDataError(f"{where}: specular mask has shape {specular.shape}; expected {labels.shape}")
            specular.flags.writeable = False
            object.__setattr__(self, "specular", specular)
        if not (math.isfinite(self.specular_gain) and self.specular_gain >= 0):
            raise SpectralDataError(f"{where}: specular_gain is {self.specular_gain}; expected a finite value ≥ 0")

    @property
    def shape(self) -> tuple[int, int]:
        """Image size (H, W)."""
        return (int(self.labels.shape[0]), int(self.labels.shape[1]))

    def surface_mask(self, surface: int | str) -> np.ndarray:
        """Pixels showing one surface (by index or name) without a highlight, bool (H, W)."""
        index = self.reflectances.names.index(surface) if isinstance(surface, str) else int(surface)
        mask = self.labels == index
        return mask & ~self.specular if self.specular is not None else mask


def uniform_scene(reflectance: Spectra, height: int, width: int, shading: np.ndarray | None = None) -> Scene:
    """A scene showing the first surface of ``reflectance`` everywhere (for tests and noise studies),
    optionally with a :attr:`Scene.shading` map."""
    return Scene(reflectance.select([0]), np.zeros((height, width), dtype=np.int32), shading=shading)


def chart_scene(
    reflectances: Spectra | Literal["chart110", "macbeth"] = "chart110",
    patch_px: int = 8,
    columns: int | None = None,
    border_px: int = 2,
    border_reflectance: float = 0.03,
    specular_strip_px: int = 0,
    specular_gain: float = 10.0,
) -> Scene:
    """A reflectance chart: square patches on a dark border, filled column by column (ISET order).

    Parameters
    ----------
    reflectances
        The patches, or ``"chart110"`` (the paper's Natural-100 + gray strip, default: 10 rows ×
        11 columns, the gray strip last) or ``"macbeth"`` (ISETCam's, 4 rows × 6 columns).
    patch_px
        Side of a patch in pixels.
    columns
        Patches per row; by default 6 for 24 patches, otherwise ``ceil(sqrt(n))``.
    border_px
        Gap between and around patches, filled with a flat dark surface.
    border_reflectance
        Reflectance of that surface (real charts are printed on near-black board).
    specular_strip_px
        If > 0, a strip of this height below the chart with a neutral highlight
        (:attr:`Scene.specular`), which saturates at exposures metered on the chart.
    specular_gain
        Strength of that highlight relative to a white diffuser (glossy highlights mirror the
        light source, so they are many times brighter than any diffuse patch).

    Returns
    -------
    Scene
        Surfaces are the patches followed by one named ``"border"``; patch ``k`` has label ``k``.
    """
    if isinstance(reflectances, str):
        # Resolved here so callers can name a chart; the data loaders are the only file readers.
        from msflash.processing import datasets

        loaders = {"chart110": datasets.chart110, "macbeth": datasets.macbeth}
        if reflectances not in loaders:
            raise SpectralDataError(f"chart_scene: unknown chart '{reflectances}'; expected chart110 or macbeth")
        reflectances = loaders[reflectances]()
    n = reflectances.count
    if patch_px < 1 or border_px < 0 or specular_strip_px < 0:
        raise SpectralDataError(
            f"chart_scene: patch_px {patch_px}, border_px {border_px}, specular_strip_px "
            f"{specular_strip_px}; expected patch_px ≥ 1 and the others ≥ 0"
        )
    if columns is None:
        columns = 6 if n == 24 else math.ceil(math.sqrt(n))
    rows = math.ceil(n / columns)
    border = n
    height = rows * patch_px + (rows + 1) * border_px
    width = columns * patch_px + (columns + 1) * border_px
    labels = np.full((height + specular_strip_px, width), border, dtype=np.int32)
    for k in range(n):
        row, column = k % rows, k // rows  # column-major, as ISET lays out its charts
        top = border_px + row * (patch_px + border_px)
        left = border_px + column * (patch_px + border_px)
        labels[top : top + patch_px, left : left + patch_px] = k
    surfaces = reflectances.replace(
        values=np.hstack([reflectances.values, np.full((reflectances.grid.size, 1), float(border_reflectance))]),
        names=reflectances.names + ("border",),
    )
    specular = None
    if specular_strip_px:
        specular = np.zeros(labels.shape, dtype=bool)
        specular[height:, :] = True
    return Scene(surfaces, labels, specular=specular, specular_gain=specular_gain)


def mosaic_scene(
    reflectances: Spectra, seed: int = 0, min_patches: int = 24, patch_px: int = 8, specular_strip_px: int = 0
) -> Scene:
    """A chart of any surfaces in random order: every surface at least once, repeated to ``min_patches``.

    The layout is :func:`chart_scene`'s (square patches on a dark border, a highlight strip if
    asked); which surface each patch shows is drawn with ``seed``. Fewer surfaces than
    ``min_patches`` are repeated (each as often as the others, ±1), so a scene of three surfaces
    still has a chart's area. The estimator's accuracy depends on the number of *distinct* surfaces
    (the paper's Fig. 5), not on the repeats.

    Returns
    -------
    Scene
        Surfaces are ``reflectances`` (once each, in their order) then ``"border"``.

    Examples
    --------
    >>> from msflash.processing.spectra import Spectra, WavelengthGrid
    >>> two = Spectra(WavelengthGrid(400, 700, 300), [[0.2, 0.8], [0.3, 0.7]], ("a", "b"), kind="reflectance", unit="none")
    >>> scene = mosaic_scene(two, patch_px=2)
    >>> sorted(np.unique(scene.labels).tolist()), scene.reflectances.names
    ([0, 1, 2], ('a', 'b', 'border'))
    """
    n = reflectances.count
    if min_patches < 1:
        raise SpectralDataError(f"mosaic_scene: min_patches {min_patches}; expected ≥ 1")
    patches = max(n, min_patches)
    order = np.random.default_rng(seed).permutation(np.resize(np.arange(n), patches))
    chart = chart_scene(reflectances.select(order.tolist()), patch_px=patch_px, specular_strip_px=specular_strip_px)
    # chart_scene's patch k shows column k of the selection, i.e. surface order[k]; the border follows.
    surface_of = np.append(order, n)
    surfaces = reflectances.replace(
        values=np.hstack([reflectances.values, chart.reflectances.values[:, -1:]]),
        names=reflectances.names + ("border",),
    )
    return Scene(surfaces, surface_of[chart.labels], specular=chart.specular, specular_gain=chart.specular_gain)


def white_reference_scene(
    height: int = 96, width: int = 128, reflectance: float = 0.95, corner_shading: float = 0.8
) -> Scene:
    """A uniform, spectrally flat white reference filling the frame, with a smooth radial falloff.

    What a lab puts in the booth to measure the LEDs' power ratios through the camera
    (:mod:`calibration.white_reference`): one surface of constant ``reflectance`` (a pressed-PTFE
    or matte white card), shaded from 1 at the centre to ``corner_shading`` in the corners.

    >>> scene = white_reference_scene(4, 6)
    >>> scene.labels.shape, scene.reflectances.names, round(float(scene.shading.min()), 2)
    ((4, 6), ('white',), 0.8)
    """
    if height < 2 or width < 2 or not 0 < reflectance <= 1 or not 0 < corner_shading <= 1:
        raise SpectralDataError(
            f"white_reference_scene: {height}×{width}, reflectance {reflectance}, corner shading "
            f"{corner_shading}; expected a frame of at least 2×2 and both in (0, 1]"
        )
    surface = Spectra(
        DEFAULT_GRID,
        np.full((DEFAULT_GRID.size, 1), float(reflectance)),
        ("white",),
        kind="reflectance",
        unit="none",
        source=f"flat white reference {reflectance:g}",
    )
    rows = (np.arange(height) - (height - 1) / 2) / ((height - 1) / 2)
    columns = (np.arange(width) - (width - 1) / 2) / ((width - 1) / 2)
    radius2 = (rows[:, None] ** 2 + columns[None, :] ** 2) / 2
    return uniform_scene(surface, height, width, shading=1.0 - (1.0 - corner_shading) * radius2)


def placed_scene(
    scene: Scene,
    shape: tuple[int, int],
    centre_yx: tuple[float, float] | None = None,
    angle_deg: float = 0.0,
    scale: float = 1.0,
    background_reflectance: float = 0.2,
) -> Scene:
    """``scene`` photographed on a flat background: scaled, rotated and placed anywhere in a frame.

    Each pixel of the new frame shows the surface under its centre (nearest neighbour), so a rotated
    chart has the jagged edges of a real sampled one; shading and the specular mask move with it.

    Parameters
    ----------
    scene
        The scene to place (typically :func:`chart_scene`).
    shape
        Size (H, W) of the new frame.
    centre_yx
        Where the scene's centre lands (row, column; pixel centres are integers); default the
        frame's centre.
    angle_deg
        Rotation, counter-clockwise as displayed (rows grow downwards).
    scale
        Pixels of the new frame per pixel of ``scene``.
    background_reflectance
        The flat surface, appended last and named ``"background"``, shown outside the scene.

    Returns
    -------
    Scene
        Surfaces of ``scene`` then ``"background"``.

    Examples
    --------
    >>> chart = chart_scene("macbeth", patch_px=8)  # 42 × 62 pixels, centre (20.5, 30.5)
    >>> placed = placed_scene(chart, (60, 80), centre_yx=(29.5, 39.5))
    >>> bool(np.array_equal(placed.labels[9:51, 9:71], chart.labels)), placed.reflectances.names[-1]
    (True, 'background')
    """
    height, width = int(shape[0]), int(shape[1])
    if height < 1 or width < 1 or not (math.isfinite(scale) and scale > 0) or not math.isfinite(angle_deg):
        raise SpectralDataError(
            f"placed_scene: shape {shape}, scale {scale}, angle {angle_deg}; expected a positive "
            "shape and scale and a finite angle"
        )
    centre = ((height - 1) / 2, (width - 1) / 2) if centre_yx is None else centre_yx
    source_centre = ((scene.shape[0] - 1) / 2, (scene.shape[1] - 1) / 2)
    rows, columns = np.mgrid[0:height, 0:width].astype(float)
    dy, dx = rows - centre[0], columns - centre[1]
    angle = math.radians(angle_deg)
    cos, sin = math.cos(angle), math.sin(angle)
    # Inverse map: undo the rotation (counter-clockwise as displayed: y points down) and the scale.
    source_x = (cos * dx - sin * dy) / scale + source_centre[1]
    source_y = (sin * dx + cos * dy) / scale + source_centre[0]
    row_index, column_index = np.rint(source_y).astype(np.int64), np.rint(source_x).astype(np.int64)
    inside = (row_index >= 0) & (row_index < scene.shape[0]) & (column_index >= 0) & (column_index < scene.shape[1])
    row_index, column_index = np.where(inside, row_index, 0), np.where(inside, column_index, 0)
    background = scene.reflectances.count
    labels = np.where(inside, scene.labels[row_index, column_index], background).astype(np.int32)
    shading = None if scene.shading is None else np.where(inside, scene.shading[row_index, column_index], 1.0)
    specular = None if scene.specular is None else inside & scene.specular[row_index, column_index]
    grid_size = scene.reflectances.grid.size
    surfaces = scene.reflectances.replace(
        values=np.hstack([scene.reflectances.values, np.full((grid_size, 1), float(background_reflectance))]),
        names=scene.reflectances.names + ("background",),
    )
    return Scene(surfaces, labels, shading=shading, specular=specular, specular_gain=scene.specular_gain)


# -- the sensor -------------------------------------------------------------------------------
@dataclass(frozen=True)
class SensorModel:
    """A linear sensor: electrons → (gain, conversion gain) → digital numbers above a black level."""

    black_level: float = 256.0
    """Digital value of no light."""
    white_level: float = 65535.0
    """Digital value at and above which a pixel is saturated; clipped pixels read exactly this."""
    bit_depth: int = 16
    """Bits per sample; ``white_level`` must fit."""
    electrons_per_dn: float = 0.5
    """Conversion gain at gain 1: electrons per digital number."""
    read_noise_e: float = 2.0
    """Standard deviation of the read noise, in electrons (referred to the input)."""
    full_well_e: float = 40000.0
    """Electrons a pixel holds; a fuller pixel is clipped and reads ``white_level``."""
    cfa: str | None = None
    """Bayer layout of a raw mosaic (RGGB, BGGR, GRBG, GBRG) or None for full RGB frames."""

    def __post_init__(self) -> None:
        if not 1 <= self.bit_depth <= 32:
            raise SpectralDataError(f"sensor model: bit_depth {self.bit_depth}; expected 1–32")
        if not 0 <= self.black_level < self.white_level <= 2**self.bit_depth - 1:
            raise SpectralDataError(
                f"sensor model: black_level {self.black_level}, white_level {self.white_level}; expected "
                f"0 ≤ black < white ≤ {2**self.bit_depth - 1} ({self.bit_depth} bits)"
            )
        for name in ("electrons_per_dn", "full_well_e"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise SpectralDataError(f"sensor model: {name} is {value}; expected a finite value > 0")
        if not (math.isfinite(self.read_noise_e) and self.read_noise_e >= 0):
            raise SpectralDataError(f"sensor model: read_noise_e is {self.read_noise_e}; expected ≥ 0")
        if self.cfa is not None and self.cfa not in CFA_PATTERNS:
            raise SpectralDataError(
                f"sensor model: cfa '{self.cfa}'; expected None or one of {', '.join(CFA_PATTERNS)}"
            )

    @property
    def dtype(self) -> np.dtype:
        """The smallest unsigned integer type holding ``bit_depth`` bits."""
        return np.dtype(np.uint8 if self.bit_depth <= 8 else np.uint16 if self.bit_depth <= 16 else np.uint32)

    def saturation_electrons(self, gain: float) -> float:
        """Electrons at which a pixel saturates at ``gain``: the full well or the top code, whichever first."""
        return min(self.full_well_e, (self.white_level - self.black_level) * self.electrons_per_dn / gain)


def machine_vision_sensor(cfa: str | None = "RGGB") -> SensorModel:
    """A colour machine-vision camera's sensor: a 12-bit raw Bayer mosaic (``cfa``; None for RGB frames).

    The figures of a large-pixel global-shutter CMOS sensor of the class industrial colour cameras carry
    (Sony IMX174-class, EMVA 1288 data sheets: about 32 ke⁻ saturation, 7 e⁻ temporal dark noise):
    30.8 ke⁻ at the white level (8 e⁻ a digital number over 3855 codes), 7 e⁻ read noise, 12 bits with the
    black pedestal at 240 — what the ``sim`` rig's camera delivers by default
    (:meth:`acquisition.devices.simulated_camera.SimulatedCamera.default`). Small-pixel sensors hold a
    third of that (IMX264-class, 10.5 ke⁻): docs/raw-frames.md has the demo with one.

    >>> sensor = machine_vision_sensor()
    >>> sensor.cfa, sensor.bit_depth, sensor.dtype.name, round(sensor.saturation_electrons(1.0))
    ('RGGB', 12, 'uint16', 30840)
    """
    return SensorModel(
        black_level=240.0,
        white_level=4095.0,
        bit_depth=12,
        electrons_per_dn=8.0,
        read_noise_e=7.0,
        full_well_e=32000.0,
        cfa=cfa,
    )


# -- Bayer mosaics ----------------------------------------------------------------------------
def cfa_channel_map(cfa: str, shape: tuple[int, int]) -> np.ndarray:
    """Channel index (0 R, 1 G, 2 B) of every pixel of a ``cfa`` mosaic, int array ``shape``.

    Examples
    --------
    >>> cfa_channel_map("BGGR", (2, 2)).tolist()
    [[2, 1], [1, 0]]
    """
    if cfa not in CFA_PATTERNS:
        raise SpectralDataError(f"cfa '{cfa}': unknown layout; expected one of {', '.join(CFA_PATTERNS)}")
    tile = np.asarray(CFA_PATTERNS[cfa], dtype=np.int8)
    height, width = shape
    return np.tile(tile, ((height + 1) // 2, (width + 1) // 2))[:height, :width]


def mosaic(rgb: np.ndarray, cfa: str) -> np.ndarray:
    """Sample an (H, W, 3) image through a Bayer filter: (H, W), one channel per pixel.

    Examples
    --------
    >>> rgb = np.zeros((2, 2, 3)); rgb[..., 0], rgb[..., 1], rgb[..., 2] = 1, 2, 3
    >>> mosaic(rgb, "RGGB").tolist()
    [[1.0, 2.0], [2.0, 3.0]]
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise SpectralDataError(f"mosaic: image has shape {rgb.shape}; expected (H, W, 3)")
    channels = cfa_channel_map(cfa, rgb.shape[:2])
    return np.take_along_axis(rgb, channels[..., None].astype(np.intp), axis=2)[..., 0]


# -- image formation (eq. 1–3) ----------------------------------------------------------------
def total_illumination(ambient: Spectra, led_spectra: Spectra, led_levels: Sequence[float] | np.ndarray) -> Spectra:
    """``i = i_a + I w``: the ambient plus the LEDs at their drive levels (eq. 2).

    Parameters
    ----------
    ambient
        ``i_a``, one spectrum.
    led_spectra
        ``I``, (n_wavelengths, k): each LED at full drive, true ratios between LEDs.
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
    scene
        Surfaces and their layout.
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
    scene, illuminant, camera_responsivities, exposure_us, scale
        As for :func:`expected_response`.
    sensor
        The sensor model.
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
    scale: float = 1.0,
    include_specular: bool = False,
) -> float:
    """The exposure (µs) putting the brightest expected pixel value at ``fraction`` of full scale.

    Full scale is the saturation point (:meth:`SensorModel.saturation_electrons`); the paper's
    simulations use 95%. Highlights are left out unless ``include_specular``, as a photographer
    meters the subject.

    Raises
    ------
    SpectralDataError
        If ``fraction`` is not in (0, 1] or the scene gives no signal.
    """
    if not 0 < fraction <= 1:
        raise SpectralDataError(f"exposure for peak: fraction {fraction}; expected 0 < fraction ≤ 1")
    metered = scene
    if scene.specular is not None and not include_specular:
        metered = Scene(scene.reflectances, scene.labels, scene.shading, None)
    response = expected_response(metered, illuminant, camera_responsivities, 1.0, 1.0, scale)
    if scene.specular is not None and not include_specular:
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

    def mean_spectrum(self, mask: np.ndarray | None = None) -> np.ndarray:
        """The illumination averaged over the pixels of ``mask`` (all by default), photons, (n_wavelengths,)."""
        weights = self.weights if mask is None else self.weights[np.asarray(mask, dtype=bool)]
        return self.spectra.values @ weights.reshape(-1, self.spectra.count).mean(axis=0)


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
