"""Ambient illuminant estimation from a flash sequence (paper eq. 4–6).

The ambient image is predicted by a weighted sum of the LED-only images,
``m_a ≈ Σ_k w_a,k m_f,k`` (eq. 4–5); the estimated ambient spectrum is ``I w_a`` with ``I`` the
LED spectra (n_wavelengths × k). Unknown gains and absolute LED powers fold into ``w_a``, so the
method calibrates itself. Every variant works on the sufficient statistics of
:mod:`processing.statistics` and costs microseconds.

Methods (:data:`AMBIENT_METHODS`)
---------------------------------
``lstsq``
    Plain least squares, eq. 5.
``nonneg``
    Least squares with a non-negative spectrum, ``I w ≥ 0``.
``tikhonov``
    Non-negative spectrum plus a squared roughness penalty ``λ ‖∇ I w‖²`` — a quadratic
    programme with a closed form on the k weights. ``alpha="auto"`` chooses it by the discrepancy
    principle (:func:`discrepancy_alpha`). The default.
``roughness``
    The paper's eq. 6 with an unsquared penalty: ``‖m_a − Σ w m_f‖ + α ‖∇ I w‖`` with
    ``I w ≥ 0``, solved by majorise–minimise over Tikhonov problems. The data term is the norm of
    the residual over all samples (the authors' code sums per-pixel 3-channel norms, which needs
    the pixels; the total norm needs only the statistics).

``alpha`` is dimensionless: the penalty weight is ``alpha · tr(G) / tr(LᵀL)`` (and its square
root for ``roughness``), so one value means the same for any image size, exposure or LED set.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from functools import cached_property, lru_cache
from typing import TYPE_CHECKING, Literal

import numpy as np

from msflash.processing.ambient_band import constrained_band, sandwich_band
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.least_squares import FactoredQuadratic
from msflash.processing.noise_floor import NOISE_FLOOR_SHARE, noise_floored
from msflash.processing.scipy_cores import lapack
from msflash.processing.spectra import Spectra, require_unit
from msflash.processing.statistics import SequenceStatistics

if TYPE_CHECKING:
    from msflash.processing.flicker import FlickerCheck

ALPHA_GRID = np.logspace(-9, 1, 41)
"""Dimensionless roughness weights searched by ``alpha="auto"``."""

CONDITION_WARNING = 1e6
"""Condition number of the (diagonally scaled) Gram matrix above which the estimate is flagged."""
RESIDUAL_WARNING = 0.2
"""Model misfit (:attr:`AmbientEstimate.model_misfit`: the relative residual with the pixel noise's share
removed) above which the estimate is flagged. The LEDs explain the ambient image of the lights they
span to within a few per cent and measured lights outside their span up to about a tenth; a scene
that moved leaves far more (docs/ambient-estimate.md)."""
SATURATION_WARNING = 0.5
"""Fraction of saturated samples above which the estimate is flagged."""
LED_SIGNAL_Z = 4.0
"""Below this z-score (one-sided p ≈ 3e-5 for noise) the LED-only image is noise, not light: the LED did not fire (or does not
reach the scene). ``z = Σ f / ‖f‖`` over the N samples: a noise-only difference image has mean 0
and z ~ N(0, 1) whatever the noise level, while light is non-negative and z = √N · mean/RMS —
in the hundreds for real frames even when a highlight dominates the RMS. A fixed mean/RMS bound
would misfire on such scenes (the independent samples' LED images have mean/RMS ≈ 0.15–0.3)."""


@dataclass(frozen=True)
class AmbientEstimate:
    """An estimated ambient illuminant and its reliability signals."""

    spectrum: Spectra
    """The estimated ambient SPD ``I w_a`` (photons, relative to the LEDs at full drive)."""
    ambient_weights: np.ndarray
    """``w_a``, one weight per LED, shape (k,)."""
    method: str
    """The method used (a key of :data:`AMBIENT_METHODS`)."""
    alpha: float
    """The dimensionless roughness weight used (0 when there is none)."""
    relative_residual: float
    """``‖m_a − Σ w m_f‖ / ‖m_a‖`` over the valid samples."""
    residual_rms: float
    """Root-mean-square residual per sample, in linear units (value per µs·gain)."""
    condition_number: float
    """Condition number of the diagonally scaled Gram matrix of the LED-only images."""
    spectrum_std: np.ndarray
    """One-sigma uncertainty of the spectrum per wavelength, shape (n_wavelengths,)."""
    n_samples: int
    """Valid samples used."""
    saturated_fraction: float
    """Fraction of samples excluded as saturated."""
    warnings: tuple[str, ...] = field(default=())
    """Human-readable reliability warnings (empty when all signals are fine)."""
    ambient_z: float = math.inf
    """z-score of the ambient image, ``Σ a / ‖a‖`` (as :data:`LED_SIGNAL_Z` for the LED images; 0 for
    an all-zero image): below :data:`LED_SIGNAL_Z` it holds noise, not light (:attr:`ambient_is_dark`)."""
    noise_correction: str = ""
    """What was done about the LED images' noise (:attr:`SolvedStatistics.description`)."""
    weighted: bool = False
    """Whether the samples carried inverse-variance weights (:mod:`processing.statistics`)."""
    model_misfit: float = 0.0
    """:attr:`relative_residual` with the pixel noise's share removed (on the denoised statistics): what
    the LED images cannot explain of the ambient image."""
    noise_std: np.ndarray | None = None
    """The pixel-noise part of :attr:`spectrum_std` (the solved system's sandwich); equal to it until a model
    error is added (:func:`processing.model_error.with_model_error`)."""
    band_meaning: str = "±1σ of the pixel noise only (the model's own error is not included)"
    """What :attr:`spectrum_std` covers, in words (for the JSON and the plot)."""
    miss_risk: float | None = None
    """Share of reference lights like this one whose estimate misses (:mod:`processing.model_error`), or None."""
    expected_ratio: float | None = None
    """Their median RMSE ÷ LED bound, or None."""
    flicker: FlickerCheck | None = None
    """What was found about a flickering ambient and whether the LED images were corrected for it
    (:mod:`processing.flicker`), or None when it was not looked for."""

    @property
    def ambient_is_dark(self) -> bool:
        """Whether the ambient image holds no light: the weights and spectrum are then noise (or zero)."""
        return not self.ambient_z >= LED_SIGNAL_Z

    @property
    def band(self) -> tuple[np.ndarray, np.ndarray]:
        """The one-sigma band (lower, upper) around the spectrum."""
        centre = self.spectrum.values[:, 0]
        return centre - self.spectrum_std, centre + self.spectrum_std


@dataclass(frozen=True)
class LedTerms:
    """What the estimation problems need of the LED spectra alone, computed once per LED set.

    Every solve used to rebuild these from ``I`` (the roughness operator, its Gram matrix, the
    rows of the non-negativity constraint); at k ≈ 7 that rebuilding cost as much as the solve.
    :class:`AmbientModel` holds one; :data:`AMBIENT_METHODS` builds one per call.
    """

    values: np.ndarray
    """``I``, shape (n_wl, k)."""
    roughness: np.ndarray
    """``L = ∇ I``, shape (n_wl − 1, k)."""
    penalty_gram: np.ndarray
    """``LᵀL``, shape (k, k)."""
    penalty_trace: float
    """``tr(LᵀL)``."""
    emitting: np.ndarray
    """The rows of ``I`` where some LED emits: ``I w ≥ 0`` there (elsewhere it reads 0 ≥ 0)."""
    ridge: np.ndarray
    """``10⁻¹² · Id`` (k × k), added to the scaled normal matrix."""
    nonnegative: FactoredQuadratic
    """The constraint ``I w ≥ 0`` (emitting rows) prepared once; each solve adds only its H."""

    @cached_property
    def unconstrained(self) -> FactoredQuadratic:
        """No constraint, prepared likewise when first used (``lstsq`` only)."""
        return FactoredQuadratic.prepare(np.eye(self.values.shape[1]), where="ambient estimate")

    @classmethod
    def of(cls, led_values: np.ndarray) -> LedTerms:
        """The terms of the LED spectra ``I`` (n_wl × k): prepared once per set of values (the last
        :data:`PREPARED_LED_SETS`), since every estimate of one LED set needs the same ones (a stream's
        :func:`estimate_ambient` made them anew for each sequence: 0.1 ms, docs/speed.md). ``values`` is a
        read-only copy, so a caller's later change to ``led_values`` cannot reach them."""
        values = np.asarray(led_values, dtype=float)
        return _prepared_terms(values.shape, values.tobytes())

    @classmethod
    def _prepare(cls, values: np.ndarray) -> LedTerms:
        roughness = np.diff(values, axis=0)
        penalty_gram = roughness.T @ roughness
        k = values.shape[1]
        emitting = values[np.any(values != 0, axis=1)]
        terms = cls(
            values,
            roughness,
            penalty_gram,
            float(np.trace(penalty_gram)),
            emitting,
            1e-12 * np.eye(k),
            FactoredQuadratic.prepare(np.eye(k), emitting, np.zeros(emitting.shape[0]), "ambient estimate"),
        )
        for array in (terms.roughness, terms.penalty_gram, terms.emitting, terms.ridge):
            array.flags.writeable = False
        return terms

    def penalty_scale(self, statistics: SequenceStatistics) -> float:
        """``tr(G) / tr(LᵀL)``: makes the dimensionless α independent of image size and exposure."""
        return float(_trace(statistics.gram) / max(self.penalty_trace, 1e-300))


def _scaled_condition(gram: np.ndarray) -> float:
    diagonal = np.sqrt(np.clip(np.diag(gram), 1e-300, None))
    scaled = gram / np.outer(diagonal, diagonal)
    # LAPACK's dsyevd as np.linalg.eigvalsh calls it (the same values), without its dispatch.
    eigenvalues, _, info = lapack.dsyevd(scaled, compute_v=0, lower=1)
    if info != 0:
        eigenvalues = np.linalg.eigvalsh(scaled)
    return float(eigenvalues[-1] / eigenvalues[0]) if eigenvalues[0] > 0 else float("inf")


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
    """tr(M), as ``np.trace`` computes it (the same sum) without its ~7 µs of dispatch."""
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
) -> tuple[float, np.ndarray | None]:
    """:func:`discrepancy_alpha`'s α and, when the search solved it on the way, its weights (those of
    :func:`_solve_penalised` at that α, to the bit), else None.

    The least-penalised fit (hence σ² and the bound) and every probe of the bisection where the constraint binds
    are solved as before. The other probes are read from one pass over the grid (:func:`_unconstrained_sweep`):
    where the unconstrained minimiser of ``‖a − F w‖² + λ ‖L w‖²`` already meets ``I w ≥ 0`` it is the
    constrained one, and its residual rise differs from a solve's by rounding only (the bisection's comparisons
    then agree unless a rise lies within rounding of the bound).
    """
    scale = terms.penalty_scale(solved)
    solves: dict[int, np.ndarray] = {}

    def weights(index: int) -> np.ndarray:
        if index not in solves:
            solves[index] = _solve_penalised(solved, terms, float(ALPHA_GRID[index]) * scale, True, "tikhonov estimate")
        return solves[index]

    least = weights(0)
    dof = max(observed.n_samples - observed.n_leds, 1)
    noise_variance = observed.residual_energy(least) / dof
    # The rise r(α) − r(α₀), from the weight-dependent part of the residual alone (the denoised ambient energy
    # cancels): residuals clipped at 0 hid every rise on Bayer frames (docs/raw-frames.md).
    allowed = solved.fit_energy(least) + DISCREPANCY_SIGMAS * observed.n_leds * noise_variance
    sweep = _unconstrained_sweep(solved, terms, scale)

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
    return float(ALPHA_GRID[low]), solves.get(low)


def _unconstrained_sweep(
    solved: SequenceStatistics, terms: LedTerms, scale: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """For every α of :data:`ALPHA_GRID`: the fit energy ``wᵀ G w − 2 cᵀ w`` of the unconstrained minimiser
    ``w(λ) = (G + λ P + ε(λ) Id)⁻¹ c`` (``λ = α · scale``, ``ε(λ) = 10⁻¹² tr(G + λP) / k``: the ridge of
    :func:`_solve_penalised`), and whether it meets ``I w ≥ 0``; None when ``G + ε Id`` has no Cholesky factor.

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
    return fits, np.all(terms.emitting.dot(candidates) >= 0.0, axis=0)


@lru_cache(maxsize=16)
def _identity(k: int) -> np.ndarray:
    identity = np.eye(k)
    identity.flags.writeable = False
    return identity


_ALPHA_COLUMN = ALPHA_GRID[:, None]

PREPARED_LED_SETS = 8
"""How many LED sets' :class:`LedTerms` are kept prepared (:meth:`LedTerms.of`)."""


@lru_cache(maxsize=PREPARED_LED_SETS)
def _prepared_terms(shape: tuple[int, ...], data: bytes) -> LedTerms:
    """:meth:`LedTerms.of` of the float64 values ``data`` of ``shape`` (read-only, not the caller's array)."""
    return LedTerms._prepare(np.frombuffer(data).reshape(shape))


def _weights_lstsq(statistics: SequenceStatistics, terms: LedTerms, alpha: float | str) -> tuple[np.ndarray, float]:
    return _solve_penalised(statistics, terms, 0.0, False, "lstsq estimate"), 0.0


def _weights_nonneg(statistics: SequenceStatistics, terms: LedTerms, alpha: float | str) -> tuple[np.ndarray, float]:
    return _solve_penalised(statistics, terms, 0.0, True, "nonneg estimate"), 0.0


def _weights_tikhonov(statistics: SequenceStatistics, terms: LedTerms, alpha: float | str) -> tuple[np.ndarray, float]:
    alpha_value = discrepancy_alpha(statistics, statistics, terms) if alpha == "auto" else float(alpha)
    weight = alpha_value * terms.penalty_scale(statistics)
    return _solve_penalised(statistics, terms, weight, True, "tikhonov estimate"), alpha_value


def _weights_roughness(
    statistics: SequenceStatistics, terms: LedTerms, alpha: float | str, iterations: int = 100
) -> tuple[np.ndarray, float]:
    """Paper eq. 6 (unsquared norms) by majorise–minimise.

    ``√x ≤ √x₀ + (x − x₀)/(2√x₀)`` bounds both norms by quadratics touching at the current
    iterate, so each step is a Tikhonov problem with weight ``α' · ‖r_t‖ / ‖L w_t‖`` and the
    objective never increases.
    """
    roughness = terms.roughness
    alpha_value = 0.01 if alpha == "auto" else float(alpha)
    alpha_scaled = alpha_value * math.sqrt(terms.penalty_scale(statistics))
    weights = _solve_penalised(statistics, terms, 0.0, True, "roughness estimate")

    def objective(w: np.ndarray) -> float:
        return np.sqrt(statistics.residual_energy(w)) + alpha_scaled * float(np.linalg.norm(roughness @ w))

    previous = objective(weights)
    floor = 1e-12 * np.sqrt(max(statistics.ambient_energy, 1e-300))
    for _ in range(iterations):
        residual_norm = max(np.sqrt(statistics.residual_energy(weights)), floor)
        roughness_norm = max(float(np.linalg.norm(roughness @ weights)), floor)
        weight = alpha_scaled * residual_norm / roughness_norm
        candidate = _solve_penalised(statistics, terms, weight, True, "roughness estimate")
        value = objective(candidate)
        if value > previous * (1 + 1e-12):
            break
        weights, converged = candidate, previous - value <= 1e-10 * max(previous, 1e-300)
        previous = value
        if converged:
            break
    return weights, alpha_value


_METHODS: dict[str, Callable[[SequenceStatistics, LedTerms, float | str], tuple[np.ndarray, float]]] = {
    "lstsq": _weights_lstsq,
    "nonneg": _weights_nonneg,
    "tikhonov": _weights_tikhonov,
    "roughness": _weights_roughness,
}


def _on_values(
    method: Callable[[SequenceStatistics, LedTerms, float | str], tuple[np.ndarray, float]],
) -> Callable[[SequenceStatistics, np.ndarray, float | str], tuple[np.ndarray, float]]:
    def solve(statistics: SequenceStatistics, led_values: np.ndarray, alpha: float | str) -> tuple[np.ndarray, float]:
        return method(statistics, LedTerms.of(led_values), alpha)

    solve.__doc__ = method.__doc__
    return solve


AMBIENT_METHODS: dict[str, Callable[[SequenceStatistics, np.ndarray, float | str], tuple[np.ndarray, float]]] = {
    name: _on_values(method) for name, method in _METHODS.items()
}
"""Ambient estimators by name: ``(statistics, led_values, alpha) -> (ambient_weights, alpha used)``.

Each call prepares the LED terms anew; :class:`AmbientModel` prepares them once."""


@dataclass(frozen=True)
class AmbientModel:
    """Ambient estimation for one LED set, prepared once and solved per sequence (eq. 4–6).

    The LED-only terms (:class:`LedTerms`) are computed at construction. :meth:`weights` is the
    solve alone — what the flash decision needs before the trigger; :meth:`estimate` adds the
    reliability signals (band, conditioning, warnings), which can wait until after it.
    """

    led_spectra: Spectra
    """The k LED spectra at full drive, in photons."""
    terms: LedTerms = field(init=False, repr=False)
    """The LED-only terms of the problems."""

    def __post_init__(self) -> None:
        led_spectra = require_unit(self.led_spectra, "photons")
        # An LED with no emission on the grid contributes nothing to I w: its weight would be solved
        # for, then silently dropped from the spectrum (a calibration on a grid that misses it, say).
        emits = np.any(led_spectra.values > 0, axis=0)
        if not emits.all():
            empty = [name for name, emitting in zip(led_spectra.names, emits) if not emitting]
            raise SpectralDataError(
                f"{led_spectra.source or 'LED spectra'}: the spectrum of LED {', '.join(empty)} has no positive "
                f"value on {led_spectra.grid}; expected each LED's emission at full drive on the sequence's grid"
            )
        object.__setattr__(self, "terms", LedTerms.of(led_spectra.values))

    def weights(
        self,
        statistics: SequenceStatistics,
        method: str = "tikhonov",
        alpha: float | str = "auto",
        denoised: SequenceStatistics | None = None,
    ) -> tuple[np.ndarray, float]:
        """``(w_a, α used)`` for the statistics (see :func:`estimate_ambient`; same errors).

        The problem is solved on :func:`solved_statistics`: the denoised statistics — ``denoised``,
        else :meth:`~processing.statistics.SequenceStatistics.denoised` when the noise was measured —
        which carry no errors-in-variables bias (:mod:`processing.statistics`), with any direction
        whose signal the noise probe exceeds clipped; the statistics as observed when no noise was
        measured.
        """
        weights, alpha_used, _ = self._weights(statistics, method, alpha, denoised)
        return weights, alpha_used

    def _weights(
        self, statistics: SequenceStatistics, method: str, alpha: float | str, denoised: SequenceStatistics | None
    ) -> tuple[np.ndarray, float, SolvedStatistics]:
        """:meth:`weights` and the :func:`solved_statistics` they were solved on."""
        if method not in _METHODS:
            raise ValueError(f"ambient method '{method}' is unknown; expected one of {', '.join(_METHODS)}")
        if alpha != "auto" and (isinstance(alpha, str) or not float(alpha) >= 0 or not math.isfinite(float(alpha))):
            raise SpectralDataError(f"ambient estimate: alpha {alpha!r}; expected a finite number ≥ 0 or 'auto'")
        led_spectra = self.led_spectra
        if led_spectra.count != statistics.n_leds:
            raise SpectralDataError(
                f"{led_spectra.source or 'LED spectra'}: {led_spectra.count} LEDs but the sequence has "
                f"{statistics.n_leds} LED images; expected one spectrum per LED"
            )
        if statistics.n_samples <= statistics.n_leds:
            saturated = statistics.saturated_fraction
            remedy = "lower the exposure" if saturated > 0.5 else "the frames are too small"
            raise SpectralDataError(
                f"frame stack: only {statistics.n_samples} valid samples of {statistics.n_total} ({saturated:.0%} "
                f"saturated); expected many more than the {statistics.n_leds} LEDs — {remedy}"
            )
        diagonal = statistics.gram.diagonal()
        if not np.minimum.reduce(diagonal) > 0:
            dark = [led_spectra.names[i] for i in np.flatnonzero(~(diagonal > 0))]
            raise SolverError(
                f"ambient estimate: the LED-only image of {', '.join(dark)} is empty; expected every LED to add light "
                "(is it connected, and its level above 0?)"
            )
        solution = solved_statistics(statistics, denoised)
        solved = solution.statistics
        if method == "tikhonov" and alpha == "auto":
            alpha, found = _discrepancy_search(solved, statistics, self.terms)
            if found is not None:
                return found, alpha, solution  # what _weights_tikhonov would solve again at this α, to the bit
        return (*_METHODS[method](solved, self.terms, alpha), solution)

    def estimate(
        self, statistics: SequenceStatistics, method: str = "tikhonov", alpha: float | str = "auto"
    ) -> AmbientEstimate:
        """The full estimate of :func:`estimate_ambient`."""
        weights, alpha_used, solution = self._weights(statistics, method, alpha, None)
        return self.reliability(statistics, weights, method, alpha_used, solution)

    def reliability(
        self,
        statistics: SequenceStatistics,
        weights: np.ndarray,
        method: str,
        alpha_used: float,
        solution: SolvedStatistics | None = None,
    ) -> AmbientEstimate:
        """The :class:`AmbientEstimate` of weights found by :meth:`weights`: spectrum and reliability signals.

        ``solution`` is ``solved_statistics(statistics)`` when the caller has it already (:meth:`estimate`)."""
        rss = statistics.residual_energy(weights)
        solution = solved_statistics(statistics) if solution is None else solution
        spectrum_std = self.spectrum_band(statistics, solution.statistics, rss, method, alpha_used)
        condition = _scaled_condition(statistics.gram)
        relative_residual = float(np.sqrt(rss / statistics.ambient_energy)) if statistics.ambient_energy > 0 else 0.0
        ambient_z = (
            statistics.ambient_sum / math.sqrt(statistics.ambient_energy) if statistics.ambient_energy > 0 else 0.0
        )
        solved = solution.statistics
        if solved is statistics:
            misfit = relative_residual
        else:
            misfit = (
                float(np.sqrt(solved.residual_energy(weights) / solved.ambient_energy))
                if solved.ambient_energy > 0
                else 0.0
            )
        spectrum = self.led_spectra.replace(
            values=(self.terms.values @ weights)[:, None],
            names=("ambient",),
            source=f"ambient estimate ({method})",
            metadata={},
        )
        return AmbientEstimate(
            spectrum=spectrum,
            ambient_weights=weights,
            method=method,
            alpha=float(alpha_used),
            relative_residual=relative_residual,
            residual_rms=float(np.sqrt(rss / statistics.n_samples)),
            condition_number=condition,
            spectrum_std=spectrum_std,
            n_samples=statistics.n_samples,
            saturated_fraction=statistics.saturated_fraction,
            warnings=_reliability_warnings(statistics, self.led_spectra.names, condition, float(ambient_z), misfit),
            ambient_z=float(ambient_z),
            noise_correction=solution.description,
            weighted=statistics.weighted,
            model_misfit=misfit,
            noise_std=spectrum_std,
        )

    def spectrum_band(
        self, statistics: SequenceStatistics, solved: SequenceStatistics, rss: float, method: str, alpha_used: float
    ) -> np.ndarray:
        """±1σ of the spectrum: the solved system's (the denoised one when it was used), ``w = (G_s + λP)⁻¹ c`` with
        the observed G in the middle of the sandwich as the products' covariance."""
        terms = self.terms
        noise_variance = rss / max(statistics.n_samples - statistics.n_leds, 1)
        penalty_weight = alpha_used * terms.penalty_scale(solved) if method == "tikhonov" else 0.0
        try:
            system_inverse = np.linalg.pinv(solved.gram + penalty_weight * terms.penalty_gram)
            weights_cov = noise_variance * system_inverse @ statistics.gram @ system_inverse
        except np.linalg.LinAlgError:
            weights_cov = np.full((statistics.n_leds,) * 2, np.inf)
        if method == "lstsq" or not np.all(np.isfinite(weights_cov)):
            return sandwich_band(terms.values, weights_cov)
        return constrained_band(solved, terms, penalty_weight, weights_cov)


def _reliability_warnings(
    statistics: SequenceStatistics, led_names: tuple[str, ...], condition: float, ambient_z: float, misfit: float
) -> tuple[str, ...]:
    """The estimate's warnings: no ambient light, nearly dependent LED images, a misfit beyond the noise,
    saturation, an LED whose image holds no light."""
    warnings = []
    if not ambient_z >= LED_SIGNAL_Z:
        warnings.append(
            f"the ambient image holds noise, not light (z-score {ambient_z:.2g} below {LED_SIGNAL_Z:g}): there is "
            "no ambient light to estimate and the spectrum is noise — was the ambient light off or the lens capped?"
        )
    if condition > CONDITION_WARNING:
        warnings.append(
            f"the LED-only images are nearly dependent (condition number {condition:.3g}); "
            "the weights are poorly determined — more surfaces or more distinct LEDs would help"
        )
    if misfit > RESIDUAL_WARNING and ambient_z >= LED_SIGNAL_Z:
        warnings.append(
            f"the LEDs explain the ambient image poorly (misfit {misfit:.3f} beyond the noise); "
            "the ambient may lie outside the LEDs' span, vary across the scene, or the scene moved"
        )
    if statistics.saturated_fraction > SATURATION_WARNING:
        warnings.append(f"{statistics.saturated_fraction:.0%} of the samples are saturated; lower the exposure")
    signal_z = statistics.led_sums / np.sqrt(np.maximum(np.diag(statistics.gram), 1e-300))
    dark = [name for name, value in zip(led_names, signal_z) if value < LED_SIGNAL_Z]
    if dark:
        warnings.append(
            f"the image of LED {', '.join(dark)} holds noise, not light (z-score below {LED_SIGNAL_Z:g}); "
            "did it fire, and does it reach the scene?"
        )
    return tuple(warnings)


@dataclass(frozen=True)
class SolvedStatistics:
    """The statistics eq. 5 is solved on, and what was done to get them."""

    statistics: SequenceStatistics
    correction: Literal["denoised", "clipped", "observed"]
    """``denoised``: the noise's share removed; ``clipped``: removed, and the directions where the noise
    exceeded the signal clipped (:data:`NOISE_FLOOR_SHARE`); ``observed``: no noise was measured."""
    clipped_directions: int = 0
    """How many of the k directions were clipped."""

    @property
    def description(self) -> str:
        """One line for reports and the JSON."""
        if self.correction == "observed":
            return "none: no noise measured (statistics as observed, biased towards zero weights)"
        if self.correction == "denoised":
            return "denoised: the noise's share of the moments removed"
        return (
            f"denoised and clipped: in {self.clipped_directions} of {self.statistics.n_leds} directions the "
            f"LED images hold less signal than noise; their eigenvalues were raised to {NOISE_FLOOR_SHARE:g} "
            "of the noise's, and the band is wide there"
        )


def solved_statistics(statistics: SequenceStatistics, denoised: SequenceStatistics | None = None) -> SolvedStatistics:
    """The statistics eq. 5 is solved on (:meth:`AmbientModel.weights`) and its band computed from.

    The denoised statistics (``denoised``, else the statistics' own) when their Gram matrix
    ``G − N`` is positive definite. Otherwise the noise probe exceeds the signal in some direction
    (a weak LED, two nearly collinear LEDs): each eigenvalue of ``G − N`` below
    :data:`NOISE_FLOOR_SHARE` of the noise's own along that eigenvector, ``vᵀ N v``, is raised to it,
    so the solve stays defined, the estimate is not thrown back to the biased observed statistics,
    and the band (which inverts that matrix) widens in those directions. Without a noise
    measurement, the statistics as observed.
    """
    clean = statistics.denoised() if denoised is None else denoised
    if clean is None:
        return SolvedStatistics(statistics, "observed")
    floored = noise_floored(clean.gram, statistics.gram - clean.gram)
    if floored is None:
        return SolvedStatistics(clean, "denoised")
    gram, clipped = floored
    return SolvedStatistics(replace(clean, gram=gram), "clipped", clipped)


def estimate_ambient(
    statistics: SequenceStatistics,
    led_spectra: Spectra,
    method: str = "tikhonov",
    alpha: float | str = "auto",
) -> AmbientEstimate:
    """Estimate the ambient illuminant spectrum from a sequence's statistics (eq. 4–6).

    Parameters
    ----------
    statistics
        Sufficient statistics of the sequence (:func:`processing.accumulate.accumulate_statistics`).
    led_spectra
        The k LED spectra at full drive, in photons, in the order of the statistics.
    method
        A key of :data:`AMBIENT_METHODS`.
    alpha
        Dimensionless roughness weight, or ``"auto"`` (``tikhonov``: :func:`discrepancy_alpha`; ``roughness``:
        0.01; the others have none).

    Returns
    -------
    AmbientEstimate
        The spectrum ``I w_a``, the weights and the reliability signals.

    Raises
    ------
    SpectralDataError
        If the LED count differs from the statistics', or no valid sample is left.
    SolverError
        If the LED-only images are linearly dependent.
    """
    if method not in AMBIENT_METHODS:
        raise ValueError(f"ambient method '{method}' is unknown; expected one of {', '.join(AMBIENT_METHODS)}")
    return AmbientModel(led_spectra).estimate(statistics, method, alpha)
