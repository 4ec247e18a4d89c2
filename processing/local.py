"""Spatially varying ambient light: tiled statistics, local estimates and model selection (issue 9).

The paper assumes one ambient over the whole scene and names patch-based local estimation as
future work (Blasinski & Farrell 2017, among the limits the authors name). Here the frame is cut
into a grid of tiles and the sufficient statistics of eq. 4–6
(:class:`~processing.statistics.SequenceStatistics`) are accumulated per tile in one pass.
Statistics of disjoint samples add, so

- the global statistics are the sum of the tiles' (:meth:`TiledStatistics.total`),
- a Gaussian-weighted sum of neighbouring tiles' statistics is a *local weighted least squares*
  (:meth:`TiledStatistics.smoothed`): each tile borrows surfaces from its neighbours, in
  proportion to ``exp(−d²/2σ²)`` with ``d`` the distance in tiles,
- and every tile is then solved in microseconds (:func:`estimate_local`).

Model selection (:func:`select_model`, leave-one-tile-out prediction against the global model,
:data:`~processing.local_selection.SELECTION_MARGIN` and :data:`~processing.local_selection.MIN_EXPLAINED_GAIN`) and the noise correction
(:attr:`TiledStatistics.denoised`, errors in variables, the same probe :mod:`processing.block_rows`
measures for the whole frame) are described in ``docs/local-estimation.md`` ("How it works").

Public objects
--------------
- here: :class:`LocalEstimate`, :func:`estimate_local`, :data:`LOCAL_METHODS`, :func:`denoised_global`;
  :func:`coefficient_maps`, :func:`synthesize_local`: the spatially varying computational image;
- :mod:`processing.tile_statistics`: :class:`TiledStatistics`, :class:`TileBlocks`, :func:`tile_statistics`,
  :func:`tile_edges`;
- :mod:`processing.local_selection`: :class:`ModelSelection`, :func:`select_model`, :func:`segment_regions`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np

from msflash.processing.ambient import AMBIENT_METHODS, AmbientEstimate, AmbientModel, gcv_alpha
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.local_selection import (
    ModelSelection,
    RegionSegmentation,
    _held_out_error,
    segment_regions,
    select_model,
)
from msflash.processing.spectra import Spectra, require_unit
from msflash.processing.statistics import FrameStackSpec, SequenceStatistics
from msflash.processing.synthesis import frame_coefficients
from msflash.processing.tile_statistics import TiledStatistics

LOCAL_METHODS = ("auto", "global", "local")
"""``auto`` selects the model from the data; ``global`` is the paper's; ``local`` forces tiles."""
MIN_TILE_SAMPLES_PER_LED = 4
"""A tile with fewer valid samples than this many per LED borrows its estimate from the smoothed fit."""


# -- local estimates --------------------------------------------------------------------------
@dataclass(frozen=True)
class LocalEstimate:
    """The ambient of a scene: global, or one estimate per tile."""

    model: str
    """``global`` or ``local`` (what was used)."""
    method: str
    """What was asked: ``auto``, ``global`` or ``local``."""
    smoothing: float | None
    """Gaussian width in tiles of the local fit (None for global)."""
    global_estimate: AmbientEstimate
    """The single (global) estimate, eq. 4–6 on the whole frame's denoised statistics (always computed: the one
    the caller gave, else solved on the sum of the tiles)."""
    tile_weights: np.ndarray
    """Ambient weights of every tile, (ty, tx, k); all equal to the global weights for the global model."""
    tile_residuals: np.ndarray
    """Relative residual ``‖a_t − F_t w_t‖ / ‖a_t‖`` of every tile under its own weights, (ty, tx)."""
    tile_samples: np.ndarray
    """Valid samples of every tile (own, before smoothing), (ty, tx)."""
    tiles: TiledStatistics
    """The tiled statistics (and geometry)."""
    selection: ModelSelection | None
    """The model selection (None when the method was forced and selection skipped)."""
    led_values: np.ndarray = field(repr=False)
    """The LED spectra (photons, n_wavelengths × k) the weights refer to."""
    warnings: tuple[str, ...] = ()
    """Human-readable warnings."""
    structure: str | None = None
    """For the local model: ``regions`` (two illuminant regions, :func:`segment_regions`) or ``tiles``."""
    regions: RegionSegmentation | None = None
    """The two-region segmentation when ``structure == "regions"``."""

    @property
    def tile_spectra(self) -> np.ndarray:
        """``I w_t`` of every tile, (ty, tx, n_wavelengths), photons."""
        return np.einsum("lk,tsk->tsl", self.led_values, self.tile_weights)

    @property
    def mean_weights(self) -> np.ndarray:
        """Area-weighted mean of the tiles' weights, (k,) — the global weights for the global model."""
        if self.model == "global":
            return self.global_estimate.ambient_weights
        areas = self.tiles.areas
        return np.einsum("ts,tsk->k", areas, self.tile_weights) / areas.sum()

    @property
    def mean_spectrum(self) -> np.ndarray:
        """``I`` times :attr:`mean_weights`, photons (n_wavelengths,)."""
        return self.led_values @ self.mean_weights


def estimate_local(
    tiles: TiledStatistics,
    led_spectra: Spectra,
    method: str = "auto",
    solver: str = "tikhonov",
    alpha: float | str = "auto",
    smoothing: float | None = None,
    regions_allowed: bool = True,
    noise_correction: bool = True,
    global_estimate: AmbientEstimate | None = None,
) -> LocalEstimate:
    """Estimate the ambient globally or per tile, choosing the model from the data for ``auto``.

    Parameters
    ----------
    led_spectra
        The k LED spectra at full drive, photons.
    method
        ``auto`` (:func:`select_model`), ``global`` (the paper) or ``local``.
    solver, alpha
        The estimator of :func:`processing.ambient.estimate_ambient` and its roughness weight. For
        ``alpha="auto"`` with ``tikhonov``, the discrepancy principle chooses it per tile
        (:func:`processing.ambient.discrepancy_alpha`; the model selection's scoring fits use GCV).
    smoothing
        Gaussian width in tiles of the local fit; None takes the best of the selection. Giving it
        forces the tile model.
    regions_allowed
        When the local model is used (and ``smoothing`` is None), try the two-region model
        (:func:`segment_regions`) and keep it when two regions explain the ambient image better
        than a smooth affine field; otherwise (or when False) solve per tile.
    noise_correction
        Solve the local model (tiles and regions) and the global estimate on the denoised statistics
        (:attr:`TiledStatistics.denoised`: the noise bias of the LED-only images' moments removed) when the
        tiles have them (even bin factors), as :func:`processing.ambient.estimate_ambient` does, so the global
        estimate is that of ``msflash estimate --method global`` and ``msflash run``; model selection and
        region labels use the statistics as observed. False: everything on the statistics as observed.
    global_estimate
        The whole-frame estimate (eq. 4–6) when the caller has it (a sequence's, from the whole frame's
        statistics, :func:`processing.accumulate.accumulate_statistics`), used as it is: its α scores the
        selection. None: solved on :meth:`TiledStatistics.total` (why the two can differ on large frames:
        docs/local-estimation.md).
    """
    _check_local_method(method, solver)
    require_unit(led_spectra, "photons")
    total = tiles.total() if noise_correction else replace(tiles.total(), noise=None)
    ambient_model = AmbientModel(led_spectra)
    if global_estimate is None:
        global_estimate = ambient_model.estimate(total, solver, alpha)
    scoring_alpha = _scoring_alpha(solver, global_estimate)
    selection = None
    if method == "auto" or (method == "local" and smoothing is None):
        selection = select_model(tiles, led_spectra, scoring_alpha)
    model = selection.model if method == "auto" and selection is not None else method
    fit = _TileFit(weights=np.broadcast_to(global_estimate.ambient_weights, tiles.shape + (tiles.n_leds,)).copy())
    if model == "local":
        used_sigma = float(smoothing) if smoothing is not None else float(_selected(selection).best_local)
        solve = _LocalSolve(tiles, led_spectra, ambient_model, solver, alpha, noise_correction, global_estimate)
        regions = solve.regions(scoring_alpha, total) if smoothing is None and regions_allowed else None
        fit = solve.fit(used_sigma, regions)
    residual = np.sqrt(_held_out_error(tiles, fit.weights) / np.maximum(tiles.ambient_energy, 1e-300))
    return LocalEstimate(
        model=model,
        method=method,
        smoothing=fit.smoothing,
        global_estimate=global_estimate,
        tile_weights=fit.weights,
        tile_residuals=residual,
        tile_samples=tiles.n_samples.copy(),
        tiles=tiles,
        selection=selection,
        led_values=led_spectra.values,
        warnings=fit.warnings,
        structure=fit.structure,
        regions=fit.regions,
    )


def _check_local_method(method: str, solver: str) -> None:
    """Refuse an unknown local method or ambient solver, naming the choices."""
    if method not in LOCAL_METHODS:
        raise ValueError(f"local method '{method}' is unknown; expected one of {', '.join(LOCAL_METHODS)}")
    if solver not in AMBIENT_METHODS:
        raise ValueError(f"ambient method '{solver}' is unknown; expected one of {', '.join(AMBIENT_METHODS)}")


def _scoring_alpha(solver: str, global_estimate: AmbientEstimate) -> float | None:
    """The selection's scoring fits' roughness weight: the global estimate's (GCV or the given α), for Tikhonov."""
    if solver == "tikhonov" and global_estimate.alpha > 0:
        return global_estimate.alpha
    return None


def _selected(selection: ModelSelection | None) -> ModelSelection:
    """The model selection, which :func:`estimate_local` runs whenever no smoothing is given."""
    assert selection is not None
    return selection


@dataclass(frozen=True)
class _TileFit:
    """Every tile's ambient weights and how they were found (the global model: the global weights)."""

    weights: np.ndarray
    smoothing: float | None = None
    structure: str | None = None
    regions: RegionSegmentation | None = None
    warnings: tuple[str, ...] = ()


@dataclass(frozen=True)
class _LocalSolve:
    """The local model's two structures: two regions, or every tile on its smoothed statistics."""

    tiles: TiledStatistics
    led_spectra: Spectra
    ambient_model: AmbientModel
    solver: str
    alpha: float | str
    noise_correction: bool
    global_estimate: AmbientEstimate

    def regions(self, scoring_alpha: float | None, total: SequenceStatistics) -> RegionSegmentation | None:
        """The two-region model when :func:`segment_regions` chooses it, else None."""
        labelling_alpha = (
            scoring_alpha if scoring_alpha is not None else gcv_alpha(total, self.ambient_model.terms.roughness)
        )
        regions = segment_regions(
            self.tiles,
            self.led_spectra,
            labelling_alpha,
            self.solver,
            self.alpha,
            noise_correction=self.noise_correction,
        )
        return regions if regions is not None and regions.chosen else None

    def fit(self, sigma: float, regions: RegionSegmentation | None) -> _TileFit:
        """The regions' weights mixed per tile, or the solver on every tile smoothed by ``sigma`` tiles."""
        if regions is not None:
            return _TileFit(_region_tile_weights(regions, self.tiles), sigma, "regions", regions)
        clean = self.tiles.denoised if self.noise_correction else None
        weights, warnings = _solve_tiles(
            self.tiles.smoothed(sigma),
            None if clean is None else clean.smoothed(sigma),
            self.tiles,
            self.ambient_model,
            self.solver,
            self.alpha,
            self.global_estimate,
        )
        return _TileFit(weights, sigma, "tiles", None, tuple(warnings))


def _region_tile_weights(regions: RegionSegmentation, tiles: TiledStatistics) -> np.ndarray:
    """Every tile's weights for a two-region estimate: the regions' mixed by their shares of the tile's cells."""
    cells_rows, cells_columns = regions.labels.shape
    centre_rows = (np.arange(cells_rows) + 0.5) * regions.pixel
    centre_columns = (np.arange(cells_columns) + 0.5) * regions.pixel
    tile_rows = np.clip(np.searchsorted(tiles.row_edges, centre_rows, side="right") - 1, 0, tiles.shape[0] - 1)
    tile_columns = np.clip(np.searchsorted(tiles.column_edges, centre_columns, side="right") - 1, 0, tiles.shape[1] - 1)
    index = (tile_rows[:, None] * tiles.shape[1] + tile_columns[None, :]).ravel()
    count = np.bincount(index, minlength=tiles.shape[0] * tiles.shape[1]).astype(float)
    ones = np.bincount(index, weights=regions.labels.ravel().astype(float), minlength=count.size)
    # A tile without a cell centre (tiny tiles) takes its nearest cell's label.
    rows = np.minimum(tiles.centres[0].astype(int) // regions.pixel, cells_rows - 1)
    columns = np.minimum(tiles.centres[1].astype(int) // regions.pixel, cells_columns - 1)
    nearest = regions.labels[rows[:, None], columns[None, :]]
    share = np.where(count > 0, ones / np.maximum(count, 1.0), nearest.ravel().astype(float)).reshape(tiles.shape)
    return (1.0 - share)[..., None] * regions.weights[0] + share[..., None] * regions.weights[1]


def denoised_global(
    tiles: TiledStatistics, led_spectra: Spectra, solver: str = "tikhonov", alpha: float | str = "auto"
) -> np.ndarray:
    """``w_a`` of the global model solved on the denoised statistics (:attr:`TiledStatistics.denoised`).

    The same estimator as the local model's, over the whole frame — the reference that isolates
    what locality adds; the global estimate of :func:`estimate_local` (with ``noise_correction``) is
    this one. Falls back to the observed statistics as :func:`estimate_local` does.
    """
    clean = tiles.denoised
    return AmbientModel(led_spectra).weights(
        tiles.total(), solver, alpha, denoised=None if clean is None else clean.total()
    )[0]


def _solve_tiles(
    smoothed: TiledStatistics,
    denoised: TiledStatistics | None,
    own: TiledStatistics,
    model: AmbientModel,
    solver: str,
    alpha: float | str,
    global_estimate: AmbientEstimate,
) -> tuple[np.ndarray, list[str]]:
    """The chosen solver on every tile's smoothed (denoised when given) statistics; empty tiles take the global weights."""
    weights = np.empty(smoothed.shape + (smoothed.n_leds,))
    fallback = 0
    for i in range(smoothed.shape[0]):
        for j in range(smoothed.shape[1]):
            statistics = smoothed.tile(i, j)
            if statistics.n_samples < MIN_TILE_SAMPLES_PER_LED * statistics.n_leds or not np.all(
                np.diag(statistics.gram) > 0
            ):
                weights[i, j] = global_estimate.ambient_weights
                fallback += 1
                continue
            try:
                weights[i, j] = model.weights(
                    statistics, solver, alpha, denoised=None if denoised is None else denoised.tile(i, j)
                )[0]
            except SolverError:
                weights[i, j] = global_estimate.ambient_weights
                fallback += 1
    warnings = []
    if fallback:
        warnings.append(
            f"{fallback} of {own.shape[0] * own.shape[1]} tiles had too few valid samples and took the global estimate"
        )
    return weights, warnings


# -- the spatially varying computational image ------------------------------------------------
def _interpolation_matrix(centres: np.ndarray, size: int) -> np.ndarray:
    """(size, n) linear interpolation between tile centres, constant beyond the outer ones."""
    n = centres.size
    if n == 1:
        return np.ones((size, 1))
    position = np.clip(np.interp(np.arange(size, dtype=float), centres, np.arange(n, dtype=float)), 0, n - 1)
    lower = np.minimum(np.floor(position).astype(int), n - 2)
    fraction = position - lower
    matrix = np.zeros((size, n))
    matrix[np.arange(size), lower] = 1.0 - fraction
    matrix[np.arange(size), lower + 1] = fraction
    return matrix


def upsample_tiles(values: np.ndarray, tiles: TiledStatistics, shape: tuple[int, int] | None = None) -> np.ndarray:
    """Per-pixel maps (H, W, …) of per-tile values (ty, tx, …), bilinear between tile centres."""
    height, width = shape if shape is not None else tiles.frame_shape
    scale_rows, scale_columns = height / tiles.frame_shape[0], width / tiles.frame_shape[1]
    centre_rows, centre_columns = tiles.centres
    rows = _interpolation_matrix(centre_rows * scale_rows, height)
    columns = _interpolation_matrix(centre_columns * scale_columns, width)
    return np.einsum("hi,ij...,wj->hw...", rows, values, columns, optimize=True)


def coefficient_maps(
    spec: FrameStackSpec,
    tile_flash_weights: np.ndarray,
    tiles: TiledStatistics,
    shape: tuple[int, int],
    ambient_offsets: np.ndarray | None = None,
) -> np.ndarray:
    """Per-pixel coefficients of the linearised frames [ambient, LED frames…], (H, W, 1 + n_frames).

    Each tile's flash weights give frame coefficients (:func:`processing.synthesis.frame_coefficients`);
    they are linear in the weights, so interpolating coefficients = interpolating weights.
    """
    per_tile: np.ndarray = np.empty(tile_flash_weights.shape[:2] + (1 + len(spec.led_scales),))
    for i in range(per_tile.shape[0]):
        for j in range(per_tile.shape[1]):
            ambient_coefficient, coefficients = frame_coefficients(spec, tile_flash_weights[i, j], ambient_offsets)
            per_tile[i, j, 0], per_tile[i, j, 1:] = ambient_coefficient, coefficients
    return upsample_tiles(per_tile, tiles, shape)


def synthesize_local(
    ambient: np.ndarray,
    led_frames: Sequence[np.ndarray],
    spec: FrameStackSpec,
    tile_flash_weights: np.ndarray,
    tiles: TiledStatistics,
    ambient_offsets: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The spatially varying computational flash image ``m_a + Σ_k w_k(x) m_f,k``.

    Per-tile flash weights (e.g. complementary to each tile's ambient) are blended bilinearly
    between tile centres into per-pixel coefficient maps, and the image is the per-pixel weighted
    sum of the raw frames (a Bayer mosaic stays a mosaic: every sample has its own coefficients).
    With equal weights in every tile it equals :func:`processing.synthesis.synthesize`, ``ambient_offsets``
    (a flickering lamp's share in each LED image) included.

    Returns
    -------
    image, saturated
        float32 linear image (value per µs·gain), the frames' shape; (H, W) mask of pixels
        saturated in some input frame.
    """
    frames = [ambient, *led_frames]
    for index, frame in enumerate(frames):
        if frame.shape != ambient.shape:
            raise SpectralDataError(
                f"synthesis: frame {index} has shape {frame.shape} but the ambient frame {ambient.shape}"
            )
    if tile_flash_weights.shape != tiles.shape + (spec.n_leds,):
        raise SpectralDataError(
            f"synthesis: tile flash weights of shape {tile_flash_weights.shape}; expected "
            f"{tiles.shape + (spec.n_leds,)}"
        )
    shape = ambient.shape[:2]
    maps = coefficient_maps(spec, tile_flash_weights, tiles, shape, ambient_offsets)
    scales = np.concatenate([[spec.ambient_scale], np.asarray(spec.led_scales, dtype=float)])
    factors = (maps * scales).astype(np.float32)
    offset = (-spec.black_level * factors.astype(float).sum(axis=-1)).astype(np.float32)
    output = np.empty(ambient.shape, dtype=np.float32)
    saturated = np.zeros(shape, dtype=bool)
    expand = (lambda m: m[:, :, None]) if ambient.ndim == 3 else (lambda m: m)
    output[...] = expand(offset)
    for index, frame in enumerate(frames):
        output += expand(factors[:, :, index]) * frame.astype(np.float32)
        hit = frame >= spec.white_level
        saturated |= hit.any(axis=2) if hit.ndim == 3 else hit
    return output, saturated
