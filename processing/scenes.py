"""Scenes for simulation: surfaces (reflectances) laid out by a label image (eq. 1's ``r``).

Public objects
--------------
- :class:`Scene`: surfaces laid out by a label image, with optional shading and a specular area.
- :func:`chart_scene`, :func:`mosaic_scene`, :func:`uniform_scene`, :func:`white_reference_scene`
  build common ones (a chart placed anywhere in a frame is the tests': ``tests/calibration/placed_scenes.py``).

A scene is rendered by :mod:`processing.image_formation` (eq. 1–3) once per *surface*, then indexed
by the label image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from msflash.processing.errors import SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID, Spectra


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


def uniform_scene(reflectance: Spectra, height: int, width: int, shading: np.ndarray | None = None) -> Scene:
    """A scene showing the first surface of ``reflectance`` everywhere (for tests and noise studies),
    optionally with a :attr:`Scene.shading` map."""
    return Scene(reflectance.select([0]), np.zeros((height, width), dtype=np.int32), shading=shading)


def chart_grid(n_patches: int) -> tuple[int, int]:
    """Rows and columns of :func:`chart_scene`'s chart of ``n_patches``: 6 columns for 24, else ``ceil(sqrt(n))``.

    >>> chart_grid(24), chart_grid(110)
    ((4, 6), (10, 11))
    """
    columns = 6 if n_patches == 24 else math.ceil(math.sqrt(n_patches))
    return math.ceil(n_patches / columns), columns


def chart_shape(n_patches: int, patch_px: int, border_px: int) -> tuple[int, int]:
    """Height and width in pixels of :func:`chart_scene`'s chart, without building it (a caller checks that a
    layout fits an image before the label map is allocated).

    >>> chart_shape(24, 8, 2)
    (42, 62)
    """
    rows, columns = chart_grid(n_patches)
    return rows * patch_px + (rows + 1) * border_px, columns * patch_px + (columns + 1) * border_px


def chart_scene(
    reflectances: Spectra | Literal["chart110", "macbeth"] = "chart110",
    patch_px: int = 8,
    border_px: int = 2,
    specular_strip_px: int = 0,
) -> Scene:
    """A reflectance chart: square patches on a dark border, filled column by column (ISET order).

    Patches per row: 6 for 24 patches, otherwise ``ceil(sqrt(n))``.

    Parameters
    ----------
    reflectances
        The patches, or ``"chart110"`` (the paper's Natural-100 + gray strip, default: 10 rows ×
        11 columns, the gray strip last) or ``"macbeth"`` (ISETCam's, 4 rows × 6 columns).
    border_px
        Gap between and around patches, filled with a flat dark surface (reflectance 0.03).
    specular_strip_px
        If > 0, a strip of this height below the chart with a neutral highlight (:attr:`Scene.specular`)
        10 times a white diffuser's (a glossy highlight mirrors the light source), which saturates at
        exposures metered on the chart.

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
    rows, _ = chart_grid(n)
    border = n
    height, width = chart_shape(n, patch_px, border_px)
    labels = np.full((height + specular_strip_px, width), border, dtype=np.int32)
    for k in range(n):
        row, column = k % rows, k // rows  # column-major, as ISET lays out its charts
        top = border_px + row * (patch_px + border_px)
        left = border_px + column * (patch_px + border_px)
        labels[top : top + patch_px, left : left + patch_px] = k
    surfaces = reflectances.replace(
        values=np.hstack([reflectances.values, np.full((reflectances.grid.size, 1), 0.03)]),
        names=reflectances.names + ("border",),
    )
    specular = None
    if specular_strip_px:
        specular = np.zeros(labels.shape, dtype=bool)
        specular[height:, :] = True
    return Scene(surfaces, labels, specular=specular, specular_gain=10.0)


def mosaic_scene(reflectances: Spectra, seed: int = 0, patch_px: int = 8, specular_strip_px: int = 0) -> Scene:
    """A chart of any surfaces in random order: every surface at least once, repeated to 24 patches.

    The layout is :func:`chart_scene`'s (square patches on a dark border, a highlight strip if
    asked); which surface each patch shows is drawn with ``seed``. Fewer surfaces than
    24 are repeated (each as often as the others, ±1), so a scene of three surfaces
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
    patches = max(n, 24)
    order = np.random.default_rng(seed).permutation(np.resize(np.arange(n), patches))
    chart = chart_scene(reflectances.select(order.tolist()), patch_px=patch_px, specular_strip_px=specular_strip_px)
    # chart_scene's patch k shows column k of the selection, i.e. surface order[k]; the border follows.
    surface_of = np.append(order, n)
    surfaces = reflectances.replace(
        values=np.hstack([reflectances.values, chart.reflectances.values[:, -1:]]),
        names=reflectances.names + ("border",),
    )
    return Scene(surfaces, surface_of[chart.labels], specular=chart.specular, specular_gain=chart.specular_gain)


def white_reference_scene(height: int = 96, width: int = 128) -> Scene:
    """A uniform, spectrally flat white reference filling the frame, with a smooth radial falloff.

    What a lab puts in the booth to measure the LEDs' power ratios through the camera
    (:mod:`calibration.white_reference`): one surface of constant reflectance 0.95 (a pressed-PTFE
    or matte white card), shaded from 1 at the centre to 0.8 in the corners.

    >>> scene = white_reference_scene(4, 6)
    >>> scene.labels.shape, scene.reflectances.names, round(float(scene.shading.min()), 2)
    ((4, 6), ('white',), 0.8)
    """
    if height < 2 or width < 2:
        raise SpectralDataError(f"white_reference_scene: {height}×{width}; expected a frame of at least 2×2")
    surface = Spectra(
        DEFAULT_GRID,
        np.full((DEFAULT_GRID.size, 1), 0.95),
        ("white",),
        kind="reflectance",
        unit="none",
        source="flat white reference 0.95",
    )
    rows = (np.arange(height) - (height - 1) / 2) / ((height - 1) / 2)
    columns = (np.arange(width) - (width - 1) / 2) / ((width - 1) / 2)
    radius2 = (rows[:, None] ** 2 + columns[None, :] ** 2) / 2
    return uniform_scene(surface, height, width, shading=1.0 - 0.2 * radius2)
