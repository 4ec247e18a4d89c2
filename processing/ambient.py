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

# ALPHA_GRID, DISCREPANCY_SIGMAS, discrepancy_alpha and gcv_alpha are re-exported from the α search's module.
from msflash.processing.ambient_alpha import ALPHA_GRID as ALPHA_GRID
from msflash.processing.ambient_alpha import DISCREPANCY_SIGMAS as DISCREPANCY_SIGMAS
from msflash.processing.ambient_alpha import _discrepancy_search, _solve_penalised, _trace
from msflash.processing.ambient_alpha import discrepancy_alpha as discrepancy_alpha
from msflash.processing.ambient_alpha import gcv_alpha as gcv_alpha
from msflash.processing.ambient_band import constrained_band, sandwich_band, weights_covariance
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.least_squares import FactoredQuadratic
from msflash.processing.noise_floor import NOISE_FLOOR_SHARE, noise_floored
from msflash.processing.scipy_cores import lapack
from msflash.processing.spectra import Spectra, require_unit
from msflash.processing.statistics import SequenceStatistics

if TYPE_CHECKING:
    from msflash.processing.flicker import FlickerCheck


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

    The roughness operator, its Gram matrix and the rows of the non-negativity constraint depend on ``I``
    alone: built here, not in every solve. :class:`AmbientModel` holds one; :data:`AMBIENT_METHODS` builds one
    per call.
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
    silent: tuple[int, ...] = ()
    """The LEDs (columns of ``I``) with no positive value: :class:`AmbientModel` refuses them."""

    @cached_property
    def unconstrained(self) -> FactoredQuadratic:
        """No constraint, prepared likewise when first used (``lstsq`` only)."""
        return FactoredQuadratic.prepare(np.eye(self.values.shape[1]), where="ambient estimate")

    @classmethod
    def of(cls, led_values: np.ndarray) -> LedTerms:
        """The terms of the LED spectra ``I`` (n_wl × k): prepared once per set of values (the last
        :data:`PREPARED_LED_SETS`), since every estimate of one LED set needs the same ones (the cost saved:
        docs/speed.md). ``values`` is a read-only copy, so a caller's later change to ``led_values`` cannot reach them."""
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
            tuple(np.flatnonzero(~np.any(values > 0, axis=0)).tolist()),
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
    if alpha == "auto":
        alpha_value, weights = _discrepancy_search(statistics, statistics, terms)
        return weights, alpha_value
    alpha_value = float(alpha)
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
        terms = LedTerms.of(led_spectra.values)
        # An LED with no emission on the grid contributes nothing to I w: its weight would be solved
        # for, then silently dropped from the spectrum (a calibration on a grid that misses it, say).
        if terms.silent:
            empty = [led_spectra.names[i] for i in terms.silent]
            raise SpectralDataError(
                f"{led_spectra.source or 'LED spectra'}: the spectrum of LED {', '.join(empty)} has no positive "
                f"value on {led_spectra.grid}; expected each LED's emission at full drive on the sequence's grid"
            )
        object.__setattr__(self, "terms", terms)

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
            return found, alpha, solution
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
        spectrum_std = self.spectrum_band(statistics, solution.statistics, rss, method, alpha_used, weights)
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
        self,
        statistics: SequenceStatistics,
        solved: SequenceStatistics,
        rss: float,
        method: str,
        alpha_used: float,
        weights: np.ndarray | None = None,
    ) -> np.ndarray:
        """±1σ of the spectrum: the solved system's (the denoised one when it was used), ``w = (G_s + λP)⁻¹ c`` with
        the observed G in the middle of the sandwich as the products' covariance; for a constrained method, where
        ``I w ≥ 0`` may bind at the estimate ``weights`` (or they are not given), the scatter of the constrained
        estimator (:func:`processing.ambient_band.constrained_band`)."""
        terms = self.terms
        noise_variance = rss / max(statistics.n_samples - statistics.n_leds, 1)
        penalty_weight = alpha_used * terms.penalty_scale(solved) if method == "tikhonov" else 0.0
        try:
            weights_cov = weights_covariance(
                solved.gram + penalty_weight * terms.penalty_gram, statistics.gram, noise_variance
            )
        except np.linalg.LinAlgError:
            weights_cov = np.full((statistics.n_leds,) * 2, np.inf)
        if method == "lstsq" or not np.all(np.isfinite(weights_cov)):
            return sandwich_band(terms.values, weights_cov)
        return constrained_band(solved, terms, penalty_weight, weights_cov, weights)


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
