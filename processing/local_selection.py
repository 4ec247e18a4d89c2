"""Which ambient model a scene needs: global or local by leave-one-tile-out prediction, and two illuminant
regions (:func:`select_model`, :func:`segment_regions`; how: ``docs/local-estimation.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msflash.processing.ambient import AmbientModel, gcv_alpha
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.region_cells import Cells
from msflash.processing.spectra import Spectra
from msflash.processing.tile_statistics import TiledStatistics

SMOOTHING_GRID = (0.5, 1.0, 2.0)
"""Gaussian widths (in tiles) of the local candidates: 0.5 is "local" (a tile and a little of its
four neighbours), 1 and 2 "local-smoothed"."""
SELECTION_MARGIN = 0.10
"""A local model must cut the leave-one-tile-out prediction error by more than this fraction of the
global model's; otherwise the global model is kept (calibrated on uniform scenes, see the docs)."""
MIN_EXPLAINED_GAIN = 1e-3
"""A local model must also cut the held-out squared error by more than this fraction of the ambient
image's energy ``Σ_t ‖a_t‖²`` (a global model that predicts the ambient image within √0.001 ≈ 3 %
RMS stays). It lies between the largest cut simulated uniform scenes gave and the smallest of the
gradients, whose two ambients can look alike to the camera (docs/local-estimation.md, how it works)."""
REGION_RADIUS = 2
"""Half-width in blocks of the box over which block residuals are pooled before labelling (5 × 5 blocks)."""
REGION_ITERATIONS = 20
"""At most this many alternations of labelling blocks and re-pooling the regions' statistics (they stop
when no label changes; a few suffice on most scenes)."""


# -- model selection --------------------------------------------------------------------------
@dataclass(frozen=True)
class ModelSelection:
    """The outcome of leave-one-tile-out model selection."""

    model: str
    """``global`` or ``local``."""
    smoothing: float | None
    """Gaussian width in tiles of the chosen local model (None for global)."""
    scores: dict[str, float]
    """Held-out prediction error of every candidate relative to the global model's (global = 1)."""
    best_local: float
    """The smoothing width of the best local candidate (used when ``local`` is forced)."""
    margin: float
    """The margin a local model had to beat."""
    explained_gain: float = 0.0
    """The best local model's held-out error cut as a fraction of the ambient image's energy."""
    min_explained_gain: float = MIN_EXPLAINED_GAIN
    """The fraction it had to exceed."""


def _batched_ridge(gram: np.ndarray, cross: np.ndarray, penalty: np.ndarray, alpha: float) -> np.ndarray:
    """Tikhonov weights ``(G + λ LᵀL)⁻¹ c`` of every tile, λ = α tr(G)/tr(LᵀL) (unconstrained, batched)."""
    k = gram.shape[-1]
    trace = np.trace(gram, axis1=-2, axis2=-1)
    weight = alpha * trace / max(float(np.trace(penalty)), 1e-300)
    system = (
        gram + weight[..., None, None] * penalty + (1e-12 * np.maximum(trace, 1e-300) / k)[..., None, None] * np.eye(k)
    )
    return np.linalg.solve(system, cross[..., None])[..., 0]


def _held_out_error(tiles: TiledStatistics, weights: np.ndarray) -> np.ndarray:
    """``‖a_t − F_t w_t‖²`` of every tile for per-tile weights (ty, tx, k)."""
    quadratic = np.einsum("tsi,tsij,tsj->ts", weights, tiles.gram, weights)
    return np.clip(tiles.ambient_energy - 2.0 * np.einsum("tsi,tsi->ts", tiles.cross, weights) + quadratic, 0.0, None)


def select_model(
    tiles: TiledStatistics,
    led_spectra: Spectra,
    alpha: float | None = None,
) -> ModelSelection:
    """Choose between the global and local models (:data:`SMOOTHING_GRID`) by leave-one-tile-out prediction error:
    a local one must beat the global by :data:`SELECTION_MARGIN` and :data:`MIN_EXPLAINED_GAIN`.

    Parameters
    ----------
    led_spectra
        The LED spectra (photons): the fits are Tikhonov-regularised with their roughness.
    alpha
        Dimensionless roughness weight of the scoring fits; None chooses it by GCV on the global
        statistics.
    """
    roughness = np.diff(led_spectra.values, axis=0)
    penalty = roughness.T @ roughness
    total = tiles.total()
    if alpha is None:
        alpha = gcv_alpha(total, roughness)
    # Global model without tile t: all statistics minus tile t's.
    global_gram = total.gram[None, None] - tiles.gram
    global_cross = total.cross[None, None] - tiles.cross
    global_error = float(_held_out_error(tiles, _batched_ridge(global_gram, global_cross, penalty, alpha)).sum())
    scores = {"global": 1.0}
    reference = max(global_error, 1e-300)
    best_sigma, best_score = float(SMOOTHING_GRID[0]), np.inf
    for sigma in SMOOTHING_GRID:
        neighbours = tiles.smoothed(float(sigma), leave_out=True)
        usable = neighbours.n_samples > tiles.n_leds
        weights = _batched_ridge(neighbours.gram, neighbours.cross, penalty, alpha)
        error = _held_out_error(tiles, weights)
        # A tile whose neighbourhood is empty (tiny grids) is predicted by the global model.
        if not usable.all():
            fallback = _held_out_error(tiles, _batched_ridge(global_gram, global_cross, penalty, alpha))
            error = np.where(usable, error, fallback)
        score = float(error.sum()) / reference
        scores[f"local(sigma={sigma:g})"] = score
        if score < best_score:
            best_sigma, best_score = float(sigma), score
    explained_gain = (1.0 - best_score) * global_error / max(float(tiles.ambient_energy.sum()), 1e-300)
    chosen = "local" if best_score < 1.0 - SELECTION_MARGIN and explained_gain > MIN_EXPLAINED_GAIN else "global"
    return ModelSelection(
        model=chosen,
        smoothing=best_sigma if chosen == "local" else None,
        scores=scores,
        best_local=best_sigma,
        margin=SELECTION_MARGIN,
        explained_gain=float(explained_gain),
    )


# -- two illuminant regions ---------------------------------------------------------------------
@dataclass(frozen=True)
class RegionSegmentation:
    """Two ambient regions: block labels and one estimate per region pooled over all its blocks."""

    labels: np.ndarray
    """(h, w) bool block labels: True = region 1."""
    weights: np.ndarray
    """(2, k) ambient weights of regions 0 and 1 (the chosen solver on each region's pooled statistics)."""
    residual: float
    """In-sample ``Σ_b ‖a_b − F_b w_label(b)‖²`` over the valid blocks."""
    affine_residual: float
    """In-sample residual of the smooth alternative: weights affine in the position, ``w(x) = w₀ + u wᵤ + v wᵥ``."""
    pixel: int
    """Block side in pixels."""

    @property
    def chosen(self) -> bool:
        """Whether two regions explain the ambient image better than a smooth (affine) field."""
        return bool(self.labels.any() and not self.labels.all() and self.residual < self.affine_residual)

    def label_map(self, shape: tuple[int, int]) -> np.ndarray:
        """(H, W) per-pixel region labels (blocks repeated, the uncovered margin takes the nearest block)."""
        rows = np.minimum(np.arange(shape[0]) // self.pixel, self.labels.shape[0] - 1)
        columns = np.minimum(np.arange(shape[1]) // self.pixel, self.labels.shape[1] - 1)
        return self.labels[rows[:, None], columns[None, :]]


def _box(values: np.ndarray, radius: int) -> np.ndarray:
    """Sums over (2r + 1)² windows of an (h, w) map, truncated at the border (cumulative sums)."""

    def along(x: np.ndarray, axis: int) -> np.ndarray:
        n = x.shape[axis]
        padded = np.concatenate([np.zeros_like(np.take(x, [0], axis=axis)), np.cumsum(x, axis=axis)], axis=axis)
        upper = np.minimum(np.arange(n) + radius + 1, n)
        lower = np.maximum(np.arange(n) - radius, 0)
        return np.take(padded, upper, axis=axis) - np.take(padded, lower, axis=axis)

    return along(along(values, 0), 1)


def _interior(region: np.ndarray) -> np.ndarray:
    """(h, w) cells of a boolean map whose 3 × 3 neighbourhood (truncated at the frame's border) is all in it.

    Examples
    --------
    >>> _interior(np.array([[1, 1, 1, 0], [1, 1, 1, 0], [1, 1, 1, 0]], dtype=bool)).astype(int).tolist()
    [[1, 1, 0, 0], [1, 1, 0, 0], [1, 1, 0, 0]]
    """
    inside = region.astype(float)
    return region & (_box(inside, 1) == _box(np.ones_like(inside), 1))


def _affine_residual(tiles: TiledStatistics, penalty: np.ndarray, alpha: float) -> float:
    """In-sample residual of weights affine in the tile-centre position (Tikhonov, from the tile statistics)."""
    rows, columns = tiles.centres
    height, width = tiles.frame_shape
    u = np.broadcast_to((columns / width - 0.5)[None, :], tiles.shape)
    v = np.broadcast_to((rows / height - 0.5)[:, None], tiles.shape)
    basis = np.stack([np.ones(tiles.shape), u, v], axis=-1)  # (ty, tx, 3)
    k = tiles.n_leds
    gram = np.einsum("tsb,tsc,tsij->bicj", basis, basis, tiles.gram, optimize=True).reshape(3 * k, 3 * k)
    cross = np.einsum("tsb,tsi->bi", basis, tiles.cross).reshape(3 * k)
    theta = _batched_ridge(gram, cross, np.kron(np.eye(3), penalty), alpha)
    return float(max(tiles.ambient_energy.sum() - 2.0 * cross @ theta + theta @ gram @ theta, 0.0))


def segment_regions(
    tiles: TiledStatistics,
    led_spectra: Spectra,
    alpha: float,
    solver: str = "tikhonov",
    solver_alpha: float | str = "auto",
    noise_correction: bool = True,
) -> RegionSegmentation | None:
    """Split the frame into two ambient regions and estimate each from all of its blocks.

    1. Tile estimates (ridge on the σ = 0.5 smoothed statistics) seed two clusters: the two tiles
       whose normalised spectra differ most, every tile to the nearer; each cluster's tiles are
       pooled into a first estimate.
    2. Every block is labelled with the region whose weights predict its ambient image better,
       the residual differences summed over a (2r + 1)² box of cells first (r = :data:`REGION_RADIUS`) (a vote: the label
       follows the data, not the tile grid; a bright neighbour can pull a boundary by ≤ r cells). Each region's statistics are then
       pooled from its blocks and re-solved; repeated until no label changes (at most :data:`REGION_ITERATIONS` times).
    3. The chosen solver runs on each region's pooled statistics: a region sees as many surfaces
       as it covers, not a tile's worth. With ``noise_correction`` (and cells that carry a noise
       probe) these are the denoised statistics (:attr:`TiledStatistics.denoised`); labelling uses
       the statistics as observed.

    Returns None when the tiles hold no block data (statistics built from moments only).
    """
    blocks = tiles.blocks
    if blocks is None or not blocks.valid.any():
        return None
    cells = Cells.of(blocks)
    if not cells.valid.any():
        return None
    roughness = np.diff(led_spectra.values, axis=0)
    penalty = roughness.T @ roughness
    seeds = _seed_regions(tiles, led_spectra.values, penalty, alpha)
    labels, weights = _label_cells(cells, seeds, penalty, alpha)
    member = labels[cells.valid]
    final = weights.copy()
    if member.any() and not member.all():
        final = _solve_regions(
            cells, labels, weights, AmbientModel(led_spectra), solver, solver_alpha, noise_correction
        )
    errors = cells.errors(final)
    residual = float(np.where(member, errors[1], errors[0]).sum())
    return RegionSegmentation(
        labels=labels,
        weights=final,
        residual=residual,
        affine_residual=_affine_residual(tiles, penalty, alpha),
        pixel=cells.size,
    )


def _seed_regions(tiles: TiledStatistics, led_values: np.ndarray, penalty: np.ndarray, alpha: float) -> np.ndarray:
    """Two regions' first weights: the tiles split by the two most different normalised σ = 0.5 tile spectra."""
    smoothed = tiles.smoothed(0.5)
    tile_weights = _batched_ridge(smoothed.gram, smoothed.cross, penalty, alpha).reshape(-1, tiles.n_leds)
    spectra = tile_weights @ led_values.T
    spectra /= np.maximum(np.linalg.norm(spectra, axis=1, keepdims=True), 1e-300)
    distances = ((spectra[:, None] - spectra[None]) ** 2).sum(axis=-1)
    first, second = np.unravel_index(int(distances.argmax()), distances.shape)
    in_second = distances[second] < distances[first]
    gram = tiles.gram.reshape(-1, tiles.n_leds, tiles.n_leds)
    cross = tiles.cross.reshape(-1, tiles.n_leds)
    return np.stack(
        [
            _batched_ridge(gram[~in_second].sum(axis=0), cross[~in_second].sum(axis=0), penalty, alpha),
            _batched_ridge(gram[in_second].sum(axis=0), cross[in_second].sum(axis=0), penalty, alpha),
        ]
    )


def _label_cells(cells: Cells, weights: np.ndarray, penalty: np.ndarray, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Label every cell by the region predicting its ambient image better, re-pool, repeat until stable.

    Returns the labels (True: the second region) and the regions' last ridge weights.
    """
    valid = cells.valid
    difference = np.zeros(valid.shape)
    labels = np.zeros(valid.shape, dtype=bool)
    for iteration in range(REGION_ITERATIONS):
        errors = cells.errors(weights)
        # Residual differences summed over a (2r + 1)² box of cells: a vote weighted by the cells'
        # brightness (docs/decisions/docstring-history.md).
        difference[valid] = errors[1] - errors[0]
        previous, labels = labels, _box(difference, REGION_RADIUS) < 0.0
        member = labels[valid]
        if member.all() or not member.any() or (iteration > 0 and np.array_equal(labels, previous)):
            break
        pooled = [cells.statistics(mask) for mask in (~member, member)]
        weights = np.stack([_batched_ridge(p.gram, p.cross, penalty, alpha) for p in pooled])
    return labels, weights


def _solve_regions(
    cells: Cells,
    labels: np.ndarray,
    weights: np.ndarray,
    model: AmbientModel,
    solver: str,
    solver_alpha: float | str,
    noise_correction: bool,
) -> np.ndarray:
    """The chosen solver on each region's pooled interior cells; a region whose solve fails, or that holds no more
    samples than LEDs, keeps ``weights``."""
    valid = cells.valid
    final = weights.copy()
    for index, region in enumerate((~labels, labels)):
        # The cells next to the label edge may straddle the true boundary (light of both sides) or
        # be mislabelled: each region is solved on its interior (cells whose 3 × 3 neighbourhood
        # shares the label), or on all its cells when it has no interior.
        interior = _interior(region)[valid]
        mask = interior if interior.any() else region[valid]
        try:
            final[index] = model.weights(
                cells.statistics(mask),
                solver,
                solver_alpha,
                denoised=cells.denoised_statistics(mask) if noise_correction else None,
            )[0]
        except (SolverError, SpectralDataError):  # a region too small to solve (no more samples than LEDs)
            pass
    return final
