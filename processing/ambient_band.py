"""The pixel-noise band of an ambient estimate (:meth:`processing.ambient.AmbientModel.spectrum_band`): the linear
sandwich of the weights' covariance, and for an estimate solved with ``I w ≥ 0`` where the constraint may bind the
scatter of seeded draws projected onto the constraint.
"""

from __future__ import annotations

from functools import lru_cache
from typing import Protocol

import numpy as np

from msflash.processing.errors import SolverError
from msflash.processing.least_squares import FactoredQuadratic
from msflash.processing.scipy_cores import lapack
from msflash.processing.statistics import SequenceStatistics


class LedTerms(Protocol):
    """What the band needs of the LED spectra's terms (:class:`processing.ambient.LedTerms` has them)."""

    @property
    def values(self) -> np.ndarray:
        """``I``, (n_wl, k)."""

    @property
    def penalty_gram(self) -> np.ndarray:
        """``LᵀL``, (k, k)."""

    @property
    def emitting(self) -> np.ndarray:
        """The rows of ``I`` where some LED emits."""

    @property
    def ridge(self) -> np.ndarray:
        """``10⁻¹² · Id``."""

    @property
    def nonnegative(self) -> FactoredQuadratic:
        """The constraint ``I w ≥ 0`` prepared."""


def sandwich_band(led_values: np.ndarray, weights_cov: np.ndarray) -> np.ndarray:
    """``√diag(I Cov(w) Iᵀ)``: the spectrum's standard deviation for weights of covariance ``weights_cov``."""
    return np.sqrt(np.clip(np.einsum("ij,jk,ik->i", led_values, weights_cov, led_values), 0, None))


def weights_covariance(system: np.ndarray, gram: np.ndarray, noise_variance: float) -> np.ndarray:
    """``σ² S⁻¹ G S⁻¹``: the covariance of weights ``S⁻¹ c`` whose products ``c`` have the covariance ``σ² G``.

    ``S⁻¹ = R⁻¹ R⁻ᵀ`` from the Cholesky factor ``S = Rᵀ R`` (LAPACK's ``dpotrf`` and ``dtrtri``, as
    :mod:`processing.least_squares` takes them), where the pseudo-inverse's SVD and its checks cost several times as
    much at k ≈ 7; ``np.linalg.pinv`` where ``S`` has no factor (not positive definite). The two agree to rounding
    where both apply. (Not ``dpotri``: OpenBLAS runs its ``dlauum`` on its threads whatever the size, and on a busy
    machine their wake-ups cost milliseconds.) Raises ``np.linalg.LinAlgError`` as ``pinv`` does.
    """
    factor, info = lapack.dpotrf(system, lower=0, clean=1)
    if info == 0:
        inverse_factor, info = lapack.dtrtri(factor, lower=0)
    inverse = inverse_factor.dot(inverse_factor.T) if info == 0 else np.linalg.pinv(system)
    return noise_variance * inverse @ gram @ inverse


BAND_DRAWS = 64
"""Draws of the unconstrained weights behind the band of a constrained estimate (:func:`constrained_band`)."""

BAND_MARGIN_Z = 4.0
"""Where the estimated spectrum lies at least this many of its sandwich standard deviations above 0 at every
wavelength some LED emits, ``I w ≥ 0`` cannot bind within the band's draws (:func:`constrained_band`): the band is the
sandwich itself."""


def constrained_band(
    solved: SequenceStatistics,
    terms: LedTerms,
    penalty_weight: float,
    weights_cov: np.ndarray,
    weights: np.ndarray | None = None,
) -> np.ndarray:
    """The pixel-noise band of an estimate solved with ``I w ≥ 0``: the spectrum's standard deviation
    over :data:`BAND_DRAWS` draws of the unconstrained estimate ``(G_s + λP)⁻¹ c`` from its sandwich
    covariance, each projected onto the constraint in the problem's metric.

    A constrained quadratic minimiser is the projection of the unconstrained one in that metric, so the
    draws follow the constrained estimator's scatter; the linear sandwich alone ignores the constraint
    and, where it binds (a dark or poorly conditioned scene), says the spectrum could swing several
    times its peak. Draws are seeded: the band is reproducible.

    Where the estimate's spectrum ``I w`` (``weights`` given) lies :data:`BAND_MARGIN_Z` sandwich deviations or more
    above 0 wherever an LED emits, the constraint does not bind at ``w`` (so ``w`` is the unconstrained estimate) nor,
    but for a draw beyond 4σ, at any draw: the draws' scatter would be the sandwich's up to their sampling error
    (≈ 9 % at 64 draws), and the band is the sandwich, exactly (docs/speed.md, rawspeed30d).
    """
    sandwich = sandwich_band(terms.values, weights_cov)
    if weights is not None and np.all(terms.values.dot(weights) >= BAND_MARGIN_Z * sandwich):
        return sandwich
    hessian = solved.gram + penalty_weight * terms.penalty_gram
    scale = max(float(np.add.reduce(hessian.diagonal())) / hessian.shape[0], 1e-300)  # tr H / k, as the solve's
    try:
        problem = terms.nonnegative.with_hessian(hessian / scale + terms.ridge, "ambient band")
        centre = np.linalg.solve(hessian, solved.cross)
        factor = np.linalg.cholesky(
            weights_cov + 1e-12 * max(float(np.trace(weights_cov)), 1e-300) * np.eye(len(centre))
        )
    except (np.linalg.LinAlgError, SolverError):
        return sandwich
    draws = centre[:, None] + factor @ _band_normals(len(centre))
    # A draw that already meets I w ≥ 0 is its own projection: only the others are solved.
    spectra = terms.values @ draws
    outside = np.flatnonzero(np.any(terms.emitting @ draws < 0, axis=0))
    if outside.size:
        spectra[:, outside] = terms.values @ problem.minimise_each(hessian @ draws[:, outside] / scale)
    return row_std(spectra)


def row_std(values: np.ndarray) -> np.ndarray:
    """``np.std(values, axis=1, ddof=1)``, in its own steps (the same sums in the same order: the same bits)
    without its dispatch."""
    mean = np.add.reduce(values, axis=1, keepdims=True)
    mean /= values.shape[1]
    deviations = values - mean
    np.multiply(deviations, deviations, out=deviations)
    variance = np.add.reduce(deviations, axis=1)
    variance /= max(values.shape[1] - 1, 0)
    return np.sqrt(variance, out=variance)


@lru_cache(maxsize=16)
def _band_normals(k: int) -> np.ndarray:
    """The band's standard normal draws for k weights, (k, :data:`BAND_DRAWS`), seeded (0): drawn once, read-only."""
    normals = np.random.default_rng(0).standard_normal((k, BAND_DRAWS))
    normals.flags.writeable = False
    return normals
