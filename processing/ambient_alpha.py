"""The penalised solve of eq. 5 and the choice of its roughness weight α (:mod:`processing.ambient`'s ``tikhonov``
method): :func:`discrepancy_alpha` (the default, Morozov's discrepancy principle) and :func:`gcv_alpha` (generalised
cross-validation).
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Protocol

import numpy as np

from msflash.processing.ambient_band import LedTerms as BandTerms
from msflash.processing.errors import SpectralDataError
from msflash.processing.least_squares import FactoredQuadratic
from msflash.processing.scipy_cores import lapack
from msflash.processing.statistics import SequenceStatistics


class LedTerms(BandTerms, Protocol):
    """What the solves need of the LED spectra's terms (:class:`processing.ambient.LedTerms` has them)."""

    @property
    def penalty_trace(self) -> float:
        """``tr(LᵀL)``."""

    @property
    def unconstrained(self) -> FactoredQuadratic:
        """No constraint, prepared."""

    def penalty_scale(self, statistics: SequenceStatistics) -> float:
        """``tr(G) / tr(LᵀL)``."""


ALPHA_GRID = np.logspace(-9, 1, 41)
"""Dimensionless roughness weights searched by ``alpha="auto"``."""


def _solve_penalised(
    statistics: SequenceStatistics, terms: LedTerms, weight: float, nonnegative: bool, where: str
) -> np.ndarray:
    """argmin ‖a − F w‖² + weight ‖L w‖² (subject to I w ≥ 0 when ``nonnegative``)."""
    if not math.isfinite(weight):
        raise SpectralDataError(
            f"{where}: the roughness penalty overflows; expected a smaller alpha (auto searches "
            f"{ALPHA_GRID[0]:g}…{ALPHA_GRID[-1]:g})"
        )
    hessian = statistics.gram + weight * terms.penalty_gram if weight else statistics.gram
    scale = max(_trace(hessian) / hessian.shape[0], 1e-300)
    hessian = hessian / scale
    linear = statistics.cross / scale
    # A vanishing ridge keeps H positive definite when two LED images are nearly identical;
    # it is 1e-12 of the mean diagonal, far below any effect on the estimate.
    hessian += terms.ridge
    # Wavelengths where no LED emits give the empty constraint 0 ≥ 0: they are left out (see
    # LedTerms.emitting). The constraint rows are prepared once per LED set; only H is per solve.
    problem = terms.nonnegative if nonnegative else terms.unconstrained
    return problem.with_hessian(hessian, where).minimise(linear).x


def _trace(matrix: np.ndarray) -> float:
    """tr(M), as ``np.trace`` computes it (the same sum) without its dispatch (docs/measurements.md)."""
    return float(np.add.reduce(matrix.diagonal()))


def gcv_alpha(statistics: SequenceStatistics, roughness: np.ndarray) -> float:
    """The dimensionless α minimising generalised cross-validation for the Tikhonov estimate.

    ``GCV(λ) = N · RSS(λ) / (N − tr A(λ))²`` with ``tr A(λ) = tr(G (G + λ LᵀL)⁻¹)``, all from the
    statistics (Golub, Heath & Wahba 1979). Computed without the positivity constraint.
    """
    penalty_gram = roughness.T @ roughness
    return _gcv_alpha(statistics, penalty_gram, float(np.trace(penalty_gram)))


def _gcv_alpha(statistics: SequenceStatistics, penalty_gram: np.ndarray, penalty_trace: float) -> float:
    """:func:`gcv_alpha` for a prepared ``LᵀL`` and its trace.

    LAPACK is called directly where that gives numpy's own results (``dgesv`` for the inverse,
    ``dsyevd`` for the eigenvectors): at k ≈ 7 numpy's linalg wrappers cost several times the
    routines, and this runs on the capture's latency path (the flash decision).
    """
    gram, cross = statistics.gram, statistics.cross
    n = max(statistics.n_samples, statistics.n_leds + 1)
    # Diagonalise G and the penalty together (G = RᵀR, R⁻ᵀ P R⁻¹ = U Λ Uᵀ): with filter factors
    # f = 1/(1 + αλ), b·w = Σ z² f, wᵀGw = Σ z² f², tr A = Σ f — every α of the grid in one pass.
    trace = gram.trace()
    identity = _identity(gram.shape[0])
    try:
        factor = np.linalg.cholesky(gram + (1e-12 * trace) * identity).T
    except np.linalg.LinAlgError:
        return float(ALPHA_GRID[0])
    *_, inverse_factor, info = lapack.dgesv(factor, identity)  # what np.linalg.inv computes
    if info != 0:
        return float(ALPHA_GRID[0])
    # C order as numpy returns it: the products below then take the same BLAS paths (same bits).
    inverse_factor = np.ascontiguousarray(inverse_factor)
    penalty = float(trace / max(penalty_trace, 1e-300)) * penalty_gram
    eigenvalues, vectors, info = lapack.dsyevd(inverse_factor.T.dot(penalty).dot(inverse_factor), compute_v=1, lower=1)
    if info != 0:
        return float(ALPHA_GRID[0])
    z_squared = np.ascontiguousarray(vectors).T.dot(inverse_factor.T.dot(cross)) ** 2
    filters = 1.0 / (1.0 + _ALPHA_COLUMN * np.maximum(eigenvalues, 0.0))  # (n_alpha, k)
    rss = np.maximum(statistics.ambient_energy - filters.dot(z_squared) * 2 + (filters * filters).dot(z_squared), 0.0)
    denominator = (n - filters.sum(axis=1)) ** 2
    positive = denominator > 0
    scores = np.where(positive, n * rss / np.where(positive, denominator, 1.0), np.inf)
    # The first of (numerically) equal minima: the smallest penalty that does as well.
    return float(ALPHA_GRID[np.argmax(scores <= scores.min() * (1 + 1e-12))])


DISCREPANCY_SIGMAS = 0.1
"""How far (× k σ², the expected increase of a fit's residual by k noise-level parameters) the roughness
penalty chosen by :func:`discrepancy_alpha` may raise the residual above the least-penalised fit's.
 Chosen on the ambient harness's tuning split (docs/measurements.md)."""


def discrepancy_alpha(solved: SequenceStatistics, observed: SequenceStatistics, terms: LedTerms) -> float:
    """The largest α of :data:`ALPHA_GRID` whose Tikhonov fit explains the ambient image as well as the
    least-penalised one up to the noise: Morozov's discrepancy principle.

    With ``r(α)`` the residual energy of the fit on the ``solved`` (denoised) statistics — what the
    solve minimises, so it grows with α — and ``σ² = r_obs(α₀) / (n − k)`` the noise per sample left
    by the least-penalised fit on the ``observed`` ones, α is the largest with
    ``r(α) ≤ r(α₀) + DISCREPANCY_SIGMAS · k σ²``: a penalty the data cannot tell from noise. The rise
    ``r(α) − r(α₀)`` is taken from :meth:`~processing.statistics.SequenceStatistics.fit_energy`, never
    from residuals clipped at 0. It
    regularises as much as the pixels allow, where generalised cross-validation (which minimises the
    predicted pixel error, :func:`gcv_alpha`) often takes the smallest α of its grid and lets nearly
    collinear LEDs trade false lobes the camera cannot see. The grid is bisected (about 6 probes); a probe
    whose unconstrained fit already meets ``I w ≥ 0`` is read from one sweep of the grid, the others solved
    (:func:`_discrepancy_search`).

    Measured against GCV on scenes of tuning lights in docs/ambient-harness.md.
    """
    return _discrepancy_search(solved, observed, terms)[0]


def _discrepancy_search(
    solved: SequenceStatistics, observed: SequenceStatistics, terms: LedTerms
) -> tuple[float, np.ndarray]:
    """:func:`discrepancy_alpha`'s α and its weights.

    One pass over the grid (:func:`_unconstrained_sweep`) gives every α's unconstrained minimiser of
    ``‖a − F w‖² + λ ‖L w‖²``; where it meets ``I w ≥ 0`` it is the constrained one, so its residual rise and, for
    the least-penalised fit (hence σ² and the bound) and the chosen α, its weights are read from the sweep: they
    differ from a constrained solve's (:func:`_solve_penalised`) by rounding only (the bisection's comparisons agree
    unless a rise lies within rounding of the bound). Only where the constraint binds is a probe solved.
    """
    scale = terms.penalty_scale(solved)
    solves: dict[int, np.ndarray] = {}

    sweep = _unconstrained_sweep(solved, terms, scale)

    def weights(index: int) -> np.ndarray:
        if index not in solves:
            if sweep is not None and sweep[1][index]:  # the constraint does not bind: the sweep's minimiser
                solves[index] = np.ascontiguousarray(sweep[2][:, index])
            else:
                solves[index] = _solve_penalised(
                    solved, terms, float(ALPHA_GRID[index]) * scale, True, "tikhonov estimate"
                )
        return solves[index]

    least = weights(0)
    dof = max(observed.n_samples - observed.n_leds, 1)
    noise_variance = observed.residual_energy(least) / dof
    # The rise r(α) − r(α₀), from the weight-dependent part of the residual alone (the denoised ambient energy
    # cancels): residuals clipped at 0 hid every rise on Bayer frames (docs/raw-frames.md).
    allowed = solved.fit_energy(least) + DISCREPANCY_SIGMAS * observed.n_leds * noise_variance

    def residual(index: int) -> float:
        if sweep is not None and sweep[1][index]:
            return float(sweep[0][index])
        return solved.fit_energy(weights(index))

    low, high = 0, ALPHA_GRID.size - 1
    if residual(high) <= allowed:
        low = high
    while high - low > 1:
        middle = (low + high) // 2
        if residual(middle) <= allowed:
            low = middle
        else:
            high = middle
    return float(ALPHA_GRID[low]), weights(low)


def _unconstrained_sweep(
    solved: SequenceStatistics, terms: LedTerms, scale: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """For every α of :data:`ALPHA_GRID`: the fit energy ``wᵀ G w − 2 cᵀ w`` of the unconstrained minimiser
    ``w(λ) = (G + λ P + ε(λ) Id)⁻¹ c`` (``λ = α · scale``, ``ε(λ) = 10⁻¹² tr(G + λP) / k``: the ridge of
    :func:`_solve_penalised`), whether it meets ``I w ≥ 0``, and the minimisers (the columns, (k, n_α)); None when ``G + ε Id`` has no Cholesky factor.

    ``G + λ P`` is diagonalised with ``G`` once (``G = Rᵀ R``, ``R⁻ᵀ P R⁻¹ = U Λ Uᵀ``; both with their share of
    the ridge): ``w(λ) = R⁻¹ U (Id + λ Λ)⁻¹ Uᵀ R⁻ᵀ c``, every α in one product (as :func:`_gcv_alpha`).
    """
    gram = solved.gram
    k = gram.shape[0]
    identity = _identity(k)
    factor, info = lapack.dpotrf(gram + (1e-12 * _trace(gram) / k) * identity, lower=0, clean=1)
    if info != 0:
        return None
    inverse_factor, info = lapack.dtrtri(factor, lower=0)
    if info != 0:
        return None
    penalty = terms.penalty_gram + (1e-12 * terms.penalty_trace / k) * identity
    eigenvalues, vectors, info = lapack.dsyevd(inverse_factor.T.dot(penalty).dot(inverse_factor), compute_v=1, lower=1)
    if info != 0:
        return None
    basis = inverse_factor.dot(vectors)
    filters = 1.0 / (1.0 + np.maximum(eigenvalues, 0.0)[:, None] * (ALPHA_GRID * scale))  # (k, n_alpha)
    candidates = basis.dot(basis.T.dot(solved.cross)[:, None] * filters)  # (k, n_alpha)
    fits = np.einsum("ia,ia->a", candidates, gram.dot(candidates)) - 2.0 * solved.cross.dot(candidates)
    if not np.isfinite(fits).all():
        return None
    return fits, np.all(terms.emitting.dot(candidates) >= 0.0, axis=0), candidates


@lru_cache(maxsize=16)
def _identity(k: int) -> np.ndarray:
    identity = np.eye(k)
    identity.flags.writeable = False
    return identity


_ALPHA_COLUMN = ALPHA_GRID[:, None]
