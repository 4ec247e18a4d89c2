"""Camera spectral responsivities from a chart under known lights, by regularised least squares.

Public objects
--------------
- :func:`measurement_matrix`: the rows ``diag(r_p) i_l Δλ`` of the linear model (eq. 1).
- :class:`ResponsivityPrior`, :func:`learn_prior`: a Gaussian prior per channel (second moments) learned
  from a set of cameras (the 34 of the paper, minus the one under test).
- :data:`RESPONSIVITY_METHODS`, :func:`estimate_responsivities`: ``"smoothness"`` (second
  differences) or ``"pca_prior"`` (the learned prior), both non-negative, weights by evidence.
- :func:`responsivity_rmse`: the error measure of the acceptance study.

The model
---------
Channel j of patch p under light l: ``m_plj = Σ_λ r_p(λ) i_l(λ) c_j(λ) Δλ`` (photons), i.e.
``m_j = A c_j`` with one row of ``A`` per (light, patch). The lights are the booth's LEDs (with
their true power ratios, from ``calibrate leds``) and broadband lights whose spectra are known
(measured with the same spectrometer). Narrowband LEDs probe the camera near their peaks, the
broadband lights over the chart's reflectance space; neither determines all 31 samples, so the
estimate is regularised by a Gaussian prior, per channel:

- smoothness: ``c ~ N(0, (D₂ᵀD₂ + δI)⁻¹ / α)`` (second differences);
- pca_prior: ``c ~ N(0, (M + ε·smooth) / α)`` with ``M`` the uncentred second moment of the
  training cameras' channel shapes (each curve scaled to unit norm; their principal directions
  and variances; uncentred so the unknown gain of the camera under test costs nothing) and a
  small smooth share ε.

α and ε maximise the evidence of the camera's own data with the noise level profiled out
(MacKay 1992); the MAP estimate with ``c ≥ 0`` is then found exactly by
:func:`processing.least_squares.minimise_quadratic`. Nothing is tuned on the camera under test:
the prior of camera i is learned without camera i, and α, ε come from camera i's own data.

References
----------
Jiang J., Liu D., Gu J., Süsstrunk S. (2013) "What is the space of spectral sensitivity functions
for digital color cameras?", WACV — the 28-camera database and the finding that two or three
principal components per channel describe them well.
MacKay D. J. C. (1992) "Bayesian interpolation", Neural Computation 4(3) — evidence for α.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from msflash.calibration.errors import CalibrationError
from msflash.processing.errors import SolverError
from msflash.processing.least_squares import minimise_quadratic
from msflash.processing.spectra import Spectra, WavelengthGrid, require_same_grid

CHANNELS = ("R", "G", "B")
ALPHAS = np.logspace(-10, 4, 57)
"""Candidate prior precisions relative to the whitened noise (chosen by the evidence)."""


def second_differences(n: int) -> np.ndarray:
    """The (n − 2) × n second-difference matrix D₂."""
    matrix = np.zeros((n - 2, n))
    for i in range(n - 2):
        matrix[i, i : i + 3] = (1.0, -2.0, 1.0)
    return matrix


def measurement_matrix(reflectances: Spectra, illuminants: Spectra) -> np.ndarray:
    """``A``: one row ``r_p ∘ i_l Δλ`` per light ``l`` (outer) and patch ``p`` (inner), photons.

    Returns
    -------
    np.ndarray
        (n_lights · n_patches, n_wavelengths); ``A @ c`` is the camera's response, in the order of
        ``responses.reshape(-1, n_channels)`` for responses shaped (n_lights, n_patches, n_channels).
    """
    grid = require_same_grid(reflectances, illuminants)
    lights = illuminants.to_unit("photons").values
    return np.vstack([(reflectances.values * lights[:, [l]]).T for l in range(lights.shape[1])]) * grid.step_nm


@dataclass(frozen=True)
class ResponsivityPrior:
    """Second moments of each channel over a set of cameras: a Gaussian prior on the curve shape."""

    grid: WavelengthGrid
    moments: dict[str, np.ndarray]
    """Channel → (n_wavelengths, n_wavelengths) uncentred second moment ``E[u uᵀ]`` of the
    training curves, each channel scaled to unit Euclidean norm ``u = c / ‖c‖`` (rank ≤ number of
    cameras)."""
    cameras: tuple[str, ...]

    def covariance(self, channel: str, shrinkage: float) -> np.ndarray:
        """Prior covariance: the learned moment plus ``shrinkage`` × a smooth covariance of equal trace.

        The learned part has rank ≤ 33; the smooth part (``(D₂ᵀD₂ + δI)⁻¹``) lets the estimate
        leave the training cameras' span where the data insist, preferring smooth departures.
        """
        moment = self.moments[channel]
        smooth = _smooth_covariance(moment.shape[0])
        return moment + shrinkage * np.trace(moment) * smooth


def _smooth_covariance(n: int) -> np.ndarray:
    """``(D₂ᵀD₂ + δI)⁻¹`` scaled to unit trace: a prior of smooth curves."""
    smooth = second_differences(n)
    covariance = np.linalg.inv(smooth.T @ smooth + 1e-3 * np.eye(n))
    return covariance / np.trace(covariance)


def learn_prior(cameras: Mapping[str, Spectra], exclude: Sequence[str] = ()) -> ResponsivityPrior:
    """The per-channel second moment of the curve *shapes* over a set of cameras (photons).

    Each training channel is scaled to unit norm before the moment is taken: a channel's gain is
    a nuisance the fit estimates from the data anyway (α is chosen per channel), so every camera
    weighs the same in the shape prior instead of in proportion to its channel's share of the
    peak. ``cameras``: name → R, G, B on one grid; ``exclude``: the camera under test.

    Raises
    ------
    CalibrationError
        With fewer than 3 training cameras, or a training channel that is zero everywhere.
    """
    training = {name: spectra for name, spectra in cameras.items() if name not in set(exclude)}
    if len(training) < 3:
        raise CalibrationError(f"responsivity prior: {len(training)} training cameras; expected at least 3")
    first = next(iter(training.values()))
    shapes = []
    for name, spectra in training.items():
        require_same_grid(first, spectra)
        values = spectra.to_unit("photons").values
        norms = np.linalg.norm(values, axis=0)
        if not np.all(norms > 0):
            empty = [CHANNELS[c] for c in np.flatnonzero(~(norms > 0))]
            raise CalibrationError(
                f"responsivity prior: camera '{name}' channel {', '.join(empty)} is zero everywhere; "
                "expected a responsivity curve per channel"
            )
        shapes.append(values / norms)
    moments = {}
    for c, channel in enumerate(CHANNELS):
        stack = np.column_stack([shape[:, c] for shape in shapes])
        moments[channel] = stack @ stack.T / stack.shape[1]
    return ResponsivityPrior(first.grid, moments, tuple(training))


RESPONSIVITY_METHODS = ("smoothness", "pca_prior", "pca_subspace")
"""Priors of :func:`estimate_responsivities`."""
SHRINKAGES = (0.003, 0.01, 0.03, 0.1, 0.3)
"""Candidate weights of the smooth part of the learned prior (chosen by the evidence)."""


@dataclass(frozen=True)
class ResponsivityEstimate:
    """Recovered responsivities and how they were found."""

    responsivities: Spectra
    """R, G, B in photons, max-normalised over the three channels."""
    method: str
    """One of :data:`RESPONSIVITY_METHODS`."""
    alphas: tuple[float, ...]
    """The chosen prior precision per channel (relative)."""
    shrinkages: tuple[float, ...]
    """The chosen smooth share of the learned prior per channel (0 for smoothness)."""
    relative_residual: tuple[float, ...]
    """‖A c − m‖ / ‖m‖ per channel at the solution (unweighted)."""
    noise_scale: tuple[float, ...]
    """Estimated noise relative to the given ``response_std`` per channel (≈ 1 when the std is right)."""


def _log_evidence(
    normal: np.ndarray, rhs: np.ndarray, data_norm2: float, n: int, precision: np.ndarray
) -> tuple[float, float]:
    """Profile log evidence of ``m = A c + e``, ``c ~ N(0, τ² P)``, ``e ~ N(0, τ² I)`` (whitened), over τ.

    With ``P⁻¹ = precision``: ``mᵀ C⁻¹ m = mᵀm − bᵀ (P⁻¹ + AᵀA)⁻¹ b`` and
    ``log det C = log det(P⁻¹ + AᵀA) − log det P⁻¹`` (Woodbury and the determinant lemma), so
    every term is a 31 × 31 computation. Returns (log evidence, τ̂²).
    """
    system = precision + normal
    try:
        factor = np.linalg.cholesky(system)
        prior_factor = np.linalg.cholesky(precision)
    except np.linalg.LinAlgError:
        return -np.inf, np.nan
    projected = np.linalg.solve(factor, rhs)
    quadratic = data_norm2 - float(projected @ projected)
    tau2 = max(quadratic / n, 1e-300)
    log_det = 2 * (np.sum(np.log(np.diag(factor))) - np.sum(np.log(np.diag(prior_factor))))
    return -0.5 * n * np.log(tau2) - 0.5 * log_det, tau2


def estimate_responsivities(
    responses: np.ndarray,
    reflectances: Spectra,
    illuminants: Spectra,
    method: str = "pca_prior",
    prior: ResponsivityPrior | None = None,
    response_std: np.ndarray | None = None,
) -> ResponsivityEstimate:
    """Responsivities from linear camera responses of a chart under known lights.

    The model and the choice of α are the module notes'.

    Parameters
    ----------
    responses
        Linear camera values (black-subtracted, per unit exposure and drive), shape
        (n_lights, n_patches, 3), in the order of ``illuminants`` and ``reflectances``.
    illuminants
        The lights with their true relative powers.
    prior
        Required for ``pca_prior`` (learned without the camera under test).
    response_std
        Standard error of each response, same shape (any common scale: the noise level is
        estimated). Default: photon-like, ``sqrt(|m| + 1e-3 max|m|)`` per channel.

    Raises
    ------
    CalibrationError
        On shape mismatches, non-finite responses, an unknown method or a missing prior.
    """
    if method not in RESPONSIVITY_METHODS:
        raise CalibrationError(
            f"responsivity method '{method}' is unknown; expected one of {', '.join(RESPONSIVITY_METHODS)}"
        )
    grid = require_same_grid(reflectances, illuminants)
    responses = np.asarray(responses, dtype=float)
    expected = (illuminants.count, reflectances.count, 3)
    if responses.shape != expected:
        raise CalibrationError(
            f"camera responses have shape {responses.shape}; expected {expected} (lights, patches, channels)"
        )
    if not np.all(np.isfinite(responses)):
        raise CalibrationError("camera responses are not finite; expected linear patch means")
    if method == "pca_prior":
        if prior is None:
            raise CalibrationError("responsivity method 'pca_prior' needs a prior (learn_prior on other cameras)")
        if not prior.grid.same_as(grid):
            raise CalibrationError(f"responsivity prior is on {prior.grid} but the chart on {grid}; expected one grid")
    data = responses.reshape(-1, 3)
    if response_std is None:
        std = np.sqrt(np.abs(data) + 1e-3 * np.max(np.abs(data), axis=0))
    else:
        std = np.asarray(response_std, dtype=float).reshape(-1, 3)
        if std.shape != data.shape or not np.all(np.isfinite(std)) or np.any(std <= 0):
            raise CalibrationError(
                f"response_std has shape {np.shape(response_std)}; expected {expected} positive values"
            )
    design = measurement_matrix(reflectances, illuminants)
    fit = fit_channels(design, data, std, method, prior)
    return fit.normalised(grid, f"estimated from {reflectances.count} patches × {illuminants.count} lights ({method})")


@dataclass(frozen=True)
class ChannelFit:
    """Raw (un-normalised) per-channel MAP curves of :func:`fit_channels` and how they were chosen."""

    curves: np.ndarray
    """(n_wavelengths, 3), in the units that make ``design @ curves`` predict the data."""
    method: str
    alphas: tuple[float, ...]
    shrinkages: tuple[float, ...]
    relative_residual: tuple[float, ...]
    noise_scale: tuple[float, ...]

    def normalised(self, grid: WavelengthGrid, source: str) -> ResponsivityEstimate:
        """The estimate, max-normalised over the three channels."""
        peak = float(self.curves.max())
        if not peak > 0:
            raise CalibrationError("recovered responsivities are all zero; expected a camera that sees the chart")
        spectra = Spectra(grid, self.curves / peak, CHANNELS, kind="responsivity", unit="photons", source=source)
        return ResponsivityEstimate(
            spectra, self.method, self.alphas, self.shrinkages, self.relative_residual, self.noise_scale
        )


SUBSPACE_DIMENSIONS = (1, 2, 3, 4, 6, 8, 12)
"""Candidate dimensions of the learned subspace of ``pca_subspace`` (chosen by the evidence with the
smooth share; the full second moment is a candidate too)."""


def _prior_options(
    method: str, prior: ResponsivityPrior | None, channel: str, smooth: np.ndarray
) -> list[tuple[float, np.ndarray]]:
    """(smooth share, prior covariance) candidates of a method, compared by the evidence."""
    if method == "smoothness":
        return [(0.0, smooth)]
    assert prior is not None
    options = [(s, prior.covariance(channel, s)) for s in SHRINKAGES]
    if method == "pca_subspace":
        values, vectors = np.linalg.eigh(prior.moments[channel])
        order = np.argsort(values)[::-1]
        values, vectors = np.clip(values[order], 0, None), vectors[:, order]
        for k in SUBSPACE_DIMENSIONS:
            moment = (vectors[:, :k] * values[:k]) @ vectors[:, :k].T
            options += [(s, moment + s * np.trace(moment) * smooth) for s in SHRINKAGES]
    return options


def fit_channels(
    design: np.ndarray, data: np.ndarray, std: np.ndarray, method: str, prior: ResponsivityPrior | None
) -> ChannelFit:
    """Per-channel evidence-weighted MAP with ``c ≥ 0`` for rows ``design`` (photons · Δλ), data and std (rows, 3)."""
    n_wl = design.shape[1]
    # Work with curves of peak ~1: scale the design so a max-normalised curve predicts the data.
    smooth = _smooth_covariance(n_wl)
    curves: list[np.ndarray] = []
    alphas: list[float] = []
    shrinks: list[float] = []
    residuals: list[float] = []
    noise: list[float] = []
    for c, channel in enumerate(CHANNELS):
        weights = 1.0 / std[:, c]
        weighted = design * weights[:, None]
        target = data[:, c] * weights
        scale = float(np.linalg.norm(target)) / max(float(np.linalg.norm(weighted.sum(axis=1))), 1e-300) * n_wl
        if not scale > 0:
            raise CalibrationError(
                f"responsivity {channel}: the chart gives no signal in this channel; expected responses above zero"
            )
        weighted = weighted * scale  # now c ≈ O(1) when its samples are O(1)
        normal = weighted.T @ weighted
        rhs = weighted.T @ target
        data_norm2 = float(target @ target)
        options = _prior_options(method, prior, channel, smooth)
        best: tuple[float, float, float, tuple[np.ndarray, float] | None] = (-np.inf, 1.0, 0.0, None)
        for shrinkage, covariance in options:
            covariance = covariance / np.trace(covariance) * n_wl
            base_precision = np.linalg.inv(covariance + 1e-9 * np.eye(n_wl))
            base_precision = (base_precision + base_precision.T) / 2
            for alpha in ALPHAS:
                evidence, tau2 = _log_evidence(normal, rhs, data_norm2, target.size, alpha * base_precision)
                if evidence > best[0]:
                    best = (evidence, float(alpha), shrinkage, (alpha * base_precision, tau2))
        _, alpha, shrinkage, chosen = best
        if chosen is None:
            raise CalibrationError(
                f"responsivity {channel}: no regularisation weight gives a valid model; "
                "expected responses that depend on the lights"
            )
        precision, tau2 = chosen
        hessian = normal + precision
        try:
            solution = minimise_quadratic(hessian, rhs, np.eye(n_wl), np.zeros(n_wl), where=f"responsivity {channel}").x
        except SolverError as err:
            raise CalibrationError(f"responsivity {channel}: {err}") from err
        solution = np.clip(solution, 0.0, None) * scale
        residuals.append(
            float(np.linalg.norm(design @ solution - data[:, c]) / max(float(np.linalg.norm(data[:, c])), 1e-300))
        )
        curves.append(solution)
        alphas.append(alpha)
        shrinks.append(shrinkage)
        noise.append(float(np.sqrt(tau2)))
    return ChannelFit(np.column_stack(curves), method, tuple(alphas), tuple(shrinks), tuple(residuals), tuple(noise))


def responsivity_rmse(estimate: Spectra, truth: Spectra) -> float:
    """RMSE between max-normalised responsivities (each set divided by its largest value), per channel then averaged."""
    require_same_grid(estimate, truth)
    a = estimate.to_unit("photons").values
    b = truth.to_unit("photons").values
    a, b = a / a.max(), b / b.max()
    return float(np.mean(np.sqrt(np.mean((a - b) ** 2, axis=0))))
