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
    programme with a closed form on the k weights. ``alpha="auto"`` chooses it by generalised
    cross-validation (GCV). The default.
``roughness``
    The paper's eq. 6 with an unsquared penalty: ``‖m_a − Σ w m_f‖ + α ‖∇ I w‖`` with
    ``I w ≥ 0``, solved by majorise–minimise over Tikhonov problems. The data term is the norm of
    the residual over all samples (the authors' code sums per-pixel 3-channel norms, which needs
    the pixels; the total norm needs only the statistics).

``alpha`` is dimensionless: the penalty weight is ``alpha · tr(G) / tr(LᵀL)`` (and its square
root for ``roughness``), so one value means the same for any image size, exposure or LED set.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from processing.errors import SolverError, SpectralDataError
from processing.least_squares import minimise_quadratic
from processing.spectra import Spectra, require_unit
from processing.statistics import SequenceStatistics

AmbientMethod = Literal["lstsq", "nonneg", "tikhonov", "roughness"]

ALPHA_GRID = np.logspace(-9, 1, 41)
"""Dimensionless roughness weights searched by ``alpha="auto"``."""

CONDITION_WARNING = 1e6
"""Condition number of the (diagonally scaled) Gram matrix above which the estimate is flagged."""
RESIDUAL_WARNING = 0.1
"""Relative residual ``‖m_a − Σ w m_f‖ / ‖m_a‖`` above which the estimate is flagged."""
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

    @property
    def band(self) -> tuple[np.ndarray, np.ndarray]:
        """The one-sigma band (lower, upper) around the spectrum."""
        centre = self.spectrum.values[:, 0]
        return centre - self.spectrum_std, centre + self.spectrum_std


def roughness_operator(led_spectra: Spectra) -> np.ndarray:
    """``L = ∇ I``: first differences over wavelength of the LED spectra, shape (n_wl − 1, k)."""
    return np.diff(led_spectra.values, axis=0)


def _scaled_condition(gram: np.ndarray) -> float:
    diagonal = np.sqrt(np.clip(np.diag(gram), 1e-300, None))
    scaled = gram / np.outer(diagonal, diagonal)
    eigenvalues = np.linalg.eigvalsh(scaled)
    return float(eigenvalues[-1] / eigenvalues[0]) if eigenvalues[0] > 0 else float("inf")


def _penalty_scale(statistics: SequenceStatistics, roughness: np.ndarray) -> float:
    penalty_gram = roughness.T @ roughness
    return float(np.trace(statistics.gram) / max(np.trace(penalty_gram), 1e-300))


def _solve_penalised(statistics: SequenceStatistics, led_values: np.ndarray, penalty: np.ndarray,
                     weight: float, nonnegative: bool, where: str) -> np.ndarray:
    """argmin ‖a − F w‖² + weight ‖P w‖² (subject to I w ≥ 0 when ``nonnegative``)."""
    hessian = statistics.gram + weight * (penalty.T @ penalty)
    scale = max(np.trace(hessian) / hessian.shape[0], 1e-300)
    hessian = hessian / scale
    linear = statistics.cross / scale
    # A vanishing ridge keeps H positive definite when two LED images are nearly identical;
    # it is 1e-12 of the mean diagonal, far below any effect on the estimate.
    hessian = hessian + 1e-12 * np.eye(hessian.shape[0])
    if nonnegative:
        # Wavelengths where no LED emits give the empty constraint 0 ≥ 0: leave them out.
        emitting = led_values[np.any(led_values != 0, axis=1)]
        return minimise_quadratic(hessian, linear, emitting, np.zeros(emitting.shape[0]), where=where).x
    return minimise_quadratic(hessian, linear, where=where).x


def gcv_alpha(statistics: SequenceStatistics, roughness: np.ndarray) -> float:
    """The dimensionless α minimising generalised cross-validation for the Tikhonov estimate.

    ``GCV(λ) = N · RSS(λ) / (N − tr A(λ))²`` with ``tr A(λ) = tr(G (G + λ LᵀL)⁻¹)``, all from the
    statistics (Golub, Heath & Wahba 1979). Computed without the positivity constraint.
    """
    gram, cross = statistics.gram, statistics.cross
    n = max(statistics.n_samples, statistics.n_leds + 1)
    # Diagonalise G and the penalty together (G = RᵀR, R⁻ᵀ P R⁻¹ = U Λ Uᵀ): with filter factors
    # f = 1/(1 + αλ), b·w = Σ z² f, wᵀGw = Σ z² f², tr A = Σ f — every α of the grid in one pass.
    ridge = 1e-12 * np.trace(gram) * np.eye(gram.shape[0])
    try:
        inverse_factor = np.linalg.inv(np.linalg.cholesky(gram + ridge).T)
    except np.linalg.LinAlgError:
        return float(ALPHA_GRID[0])
    penalty = _penalty_scale(statistics, roughness) * (roughness.T @ roughness)
    eigenvalues, vectors = np.linalg.eigh(inverse_factor.T @ penalty @ inverse_factor)
    z_squared = (vectors.T @ (inverse_factor.T @ cross)) ** 2
    filters = 1.0 / (1.0 + np.outer(ALPHA_GRID, np.clip(eigenvalues, 0.0, None)))  # (n_alpha, k)
    rss = np.clip(statistics.ambient_energy - filters @ z_squared * 2 + (filters**2) @ z_squared, 0.0, None)
    denominator = (n - filters.sum(axis=1)) ** 2
    scores = np.where(denominator > 0, n * rss / np.where(denominator > 0, denominator, 1.0), np.inf)
    # The first of (numerically) equal minima: the smallest penalty that does as well.
    best = int(np.flatnonzero(scores <= scores.min() * (1 + 1e-12))[0])
    return float(ALPHA_GRID[best])


def _weights_lstsq(statistics: SequenceStatistics, led_values: np.ndarray, alpha: float | str) -> tuple[np.ndarray, float]:
    return _solve_penalised(statistics, led_values, np.zeros((1, statistics.n_leds)), 0.0, False, "lstsq estimate"), 0.0


def _weights_nonneg(statistics: SequenceStatistics, led_values: np.ndarray, alpha: float | str) -> tuple[np.ndarray, float]:
    return _solve_penalised(statistics, led_values, np.zeros((1, statistics.n_leds)), 0.0, True, "nonneg estimate"), 0.0


def _weights_tikhonov(statistics: SequenceStatistics, led_values: np.ndarray, alpha: float | str) -> tuple[np.ndarray, float]:
    roughness = np.diff(led_values, axis=0)
    alpha_value = gcv_alpha(statistics, roughness) if alpha == "auto" else float(alpha)
    weight = alpha_value * _penalty_scale(statistics, roughness)
    return _solve_penalised(statistics, led_values, roughness, weight, True, "tikhonov estimate"), alpha_value


def _weights_roughness(statistics: SequenceStatistics, led_values: np.ndarray, alpha: float | str,
                       iterations: int = 100) -> tuple[np.ndarray, float]:
    """Paper eq. 6 (unsquared norms) by majorise–minimise.

    ``√x ≤ √x₀ + (x − x₀)/(2√x₀)`` bounds both norms by quadratics touching at the current
    iterate, so each step is a Tikhonov problem with weight ``α' · ‖r_t‖ / ‖L w_t‖`` and the
    objective never increases.
    """
    roughness = np.diff(led_values, axis=0)
    alpha_value = 0.01 if alpha == "auto" else float(alpha)
    alpha_scaled = alpha_value * np.sqrt(_penalty_scale(statistics, roughness))
    weights = _solve_penalised(statistics, led_values, roughness, 0.0, True, "roughness estimate")

    def objective(w: np.ndarray) -> float:
        return np.sqrt(statistics.residual_energy(w)) + alpha_scaled * float(np.linalg.norm(roughness @ w))

    previous = objective(weights)
    floor = 1e-12 * np.sqrt(max(statistics.ambient_energy, 1e-300))
    for _ in range(iterations):
        residual_norm = max(np.sqrt(statistics.residual_energy(weights)), floor)
        roughness_norm = max(float(np.linalg.norm(roughness @ weights)), floor)
        weight = alpha_scaled * residual_norm / roughness_norm
        candidate = _solve_penalised(statistics, led_values, roughness, weight, True, "roughness estimate")
        value = objective(candidate)
        if value > previous * (1 + 1e-12):
            break
        weights, converged = candidate, previous - value <= 1e-10 * max(previous, 1e-300)
        previous = value
        if converged:
            break
    return weights, alpha_value


AMBIENT_METHODS: dict[str, Callable[[SequenceStatistics, np.ndarray, float | str], tuple[np.ndarray, float]]] = {
    "lstsq": _weights_lstsq,
    "nonneg": _weights_nonneg,
    "tikhonov": _weights_tikhonov,
    "roughness": _weights_roughness,
}
"""Ambient estimators by name; each returns (ambient_weights, alpha used)."""


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
        Sufficient statistics of the sequence (:func:`processing.statistics.accumulate_statistics`).
    led_spectra
        The k LED spectra at full drive, in photons, in the order of the statistics.
    method
        A key of :data:`AMBIENT_METHODS`.
    alpha
        Dimensionless roughness weight, or ``"auto"`` (GCV for ``tikhonov``).

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
    require_unit(led_spectra, "photons")
    if led_spectra.count != statistics.n_leds:
        raise SpectralDataError(
            f"{led_spectra.source or 'LED spectra'}: {led_spectra.count} LEDs but the sequence has "
            f"{statistics.n_leds} LED images; expected one spectrum per LED"
        )
    if statistics.n_samples <= statistics.n_leds:
        raise SpectralDataError(
            f"frame stack: only {statistics.n_samples} valid samples ({statistics.saturated_fraction:.0%} "
            "saturated); expected many more than the number of LEDs — lower the exposure"
        )
    if not np.all(np.diag(statistics.gram) > 0):
        dark = [led_spectra.names[i] for i in np.flatnonzero(~(np.diag(statistics.gram) > 0))]
        raise SolverError(
            f"ambient estimate: the LED-only image of {', '.join(dark)} is empty; expected every LED to add light "
            "(is it connected, and its level above 0?)"
        )
    led_values = led_spectra.values
    weights, alpha_used = AMBIENT_METHODS[method](statistics, led_values, alpha)

    rss = statistics.residual_energy(weights)
    dof = max(statistics.n_samples - statistics.n_leds, 1)
    noise_variance = rss / dof
    roughness = np.diff(led_values, axis=0)
    penalty_weight = alpha_used * _penalty_scale(statistics, roughness) if method == "tikhonov" else 0.0
    try:
        system_inverse = np.linalg.pinv(statistics.gram + penalty_weight * roughness.T @ roughness)
        weights_cov = noise_variance * system_inverse @ statistics.gram @ system_inverse
    except np.linalg.LinAlgError:
        weights_cov = np.full((statistics.n_leds,) * 2, np.inf)
    spectrum_std = np.sqrt(np.clip(np.einsum("ij,jk,ik->i", led_values, weights_cov, led_values), 0, None))

    condition = _scaled_condition(statistics.gram)
    relative_residual = float(np.sqrt(rss / statistics.ambient_energy)) if statistics.ambient_energy > 0 else 0.0
    warnings = []
    if condition > CONDITION_WARNING:
        warnings.append(
            f"the LED-only images are nearly dependent (condition number {condition:.3g}); "
            "the weights are poorly determined — more surfaces or more distinct LEDs would help"
        )
    if relative_residual > RESIDUAL_WARNING:
        warnings.append(
            f"the LEDs explain the ambient image poorly (relative residual {relative_residual:.3f}); "
            "the ambient may lie outside the LEDs' span, vary across the scene, or the scene moved"
        )
    if statistics.saturated_fraction > SATURATION_WARNING:
        warnings.append(f"{statistics.saturated_fraction:.0%} of the samples are saturated; lower the exposure")
    signal_z = statistics.led_sums / np.sqrt(np.maximum(np.diag(statistics.gram), 1e-300))
    dark = [name for name, value in zip(led_spectra.names, signal_z) if value < LED_SIGNAL_Z]
    if dark:
        warnings.append(
            f"the image of LED {', '.join(dark)} holds noise, not light (z-score below {LED_SIGNAL_Z:g}); "
            "did it fire, and does it reach the scene?"
        )
    centre = led_values @ weights
    if np.any(spectrum_std > 0.5 * np.max(np.abs(centre))):
        warnings.append("the uncertainty band is wider than half the spectrum's peak")

    spectrum = led_spectra.replace(
        values=centre[:, None], names=("ambient",), source=f"ambient estimate ({method})", metadata={}
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
        warnings=tuple(warnings),
    )
