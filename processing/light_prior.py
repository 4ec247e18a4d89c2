"""Past the LEDs' span: the ambient in a basis learned from measured lights (issue 17, build 3).

Eq. 4–6 estimate the ambient as ``I w`` (I: the k LED spectra): whatever the scene, the estimate
lies in the LEDs' span, and its error can never go below the *LED bound* (the best non-negative
fit of the true spectrum by the LEDs). This module's model family represents the ambient in a
basis learned from real light spectra instead, and reads it through the surfaces' colours.

Image formation per block b and channel c (eq. 1–3, gain g folded into the reflectance r_b):

    f_b,(c,i) = Σ_λ C_c(λ) r_b(λ) I_i(λ)          (LED-only responses, LEDs at full drive)
    a_b,c     = Σ_λ C_c(λ) r_b(λ) e(λ)            (ambient response)

The model (:class:`PriorModel`; derivation and validation in docs/light-prior.md): the reflectance of each block
is the Wiener estimate ``r̂_b = W f_b`` from its LED responses (Natural-100's first p components,
:func:`learn_reflectance_basis`); the ambient is ``e = B_e φ`` in a basis learnt from measured lights
(:class:`LightPrior`), whose in-span part lights every surface as the LEDs do and whose remainder goes through r̂:
``â_b = Σ_m φ_m K_m f_b``, ``K_m = E(u_m) + T(b⊥_m) W``. φ is the posterior mode under a Gaussian prior
``φ_rest ~ N(s μ, s² Σ)`` with ``λ = κ σ²/s²`` (empirical Bayes), solved from the channel moments
(:mod:`processing.channel_statistics`, denoised like eq. 5) with ``B_e φ ≥ 0``; the band is the tempered
posterior ``κσ² (H + λ DᵀΣ⁻¹D)⁻¹`` mapped to the spectrum.

Model choice (:func:`choose_model`): both models predict each fold of blocks from the others; ``auto`` uses the
prior model only when its held-out error is below the LED model's by more than :data:`CHOICE_MARGIN` — no more
model than the scene needs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from msflash.processing import datasets
from msflash.processing.channel_statistics import ChannelStatistics, Moments
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.least_squares import FactoredQuadratic
from msflash.processing.light_library import light_library, prior_training_lights, without_near_copies
from msflash.processing.noise_floor import noise_floored
from msflash.processing.spectra import Spectra, WavelengthGrid, require_unit

LIGHT_DIMS = 16
"""Light basis size q (the mean light and 15 principal components; chosen on the tuning split)."""
REFLECTANCE_DIMS = 8
"""Reflectance basis size p (principal components of Natural-100; chosen on the tuning split)."""
RIDGE = 1e-3
"""Dimensionless ridge ρ of the reflectance estimate (chosen on the tuning split)."""
KAPPA = 100.0
"""Prior strength κ: λ = κ σ²/s² (chosen on the tuning split)."""
CHOICE_MARGIN = 0.02
"""``auto`` takes the prior model only when its held-out RMS error is below (1 − margin) × the LED model's."""
EB_ITERATIONS = 30
"""Most empirical-Bayes passes re-estimating σ² and s (they stop once λ changes by less than 10⁻⁴ of itself)."""
DAYLIGHT_CCT_K = tuple(range(4000, 24001, 1000))
"""CIE daylight chromaticities (correlated colour temperatures) added to the light prior's training set."""
BLACKBODY_K = tuple(range(1800, 10001, 400))
"""Blackbody temperatures added to the light prior's training set."""


# -- the light prior --------------------------------------------------------------------------------
@dataclass(frozen=True)
class LightPrior:
    """A basis for light spectra and a Gaussian prior on its coefficients.

    A light is ``e = B φ`` with B's columns orthonormal, column 0 the normalised mean training light.
    For a light of scale ``s = φ_0``: ``φ_rest ~ N(s μ, s² Σ)`` (:attr:`mean`, :attr:`covariance`).
    """

    basis: Spectra
    """B, photons, (n_wl, q), orthonormal columns."""
    mean: np.ndarray
    """μ: mean of the coefficients 1…q−1 of the training lights scaled to φ_0 = 1, shape (q − 1,)."""
    covariance: np.ndarray
    """Σ: their covariance, (q − 1, q − 1)."""
    training: tuple[str, ...]
    """The names of the training spectra (provenance: none is a held-out light or a near copy of one)."""

    @property
    def dims(self) -> int:
        """q."""
        return self.basis.count

    @property
    def grid(self) -> WavelengthGrid:
        """The grid of the basis."""
        return self.basis.grid


def prior_candidate_lights(grid: WavelengthGrid, exclude: tuple[str, ...] = ()) -> Spectra:
    """What the light prior learns from, energy units on ``grid`` (zero outside each table's range).

    The library's :func:`~processing.light_library.prior_training_lights`, CIE daylights at
    :data:`DAYLIGHT_CCT_K` and blackbodies at :data:`BLACKBODY_K`; the added ones pass
    :func:`~processing.light_library.without_near_copies` (no near copy of a held-out light).
    ``exclude`` names further library lights to keep out with their near copies (cross-validation
    within the tuning split).
    """
    import colour

    fine = WavelengthGrid(380.0, 780.0, 5.0)
    extra, names = [], []
    for cct in DAYLIGHT_CCT_K:
        xy = colour.temperature.CCT_to_xy_CIE_D(cct * 1.4388 / 1.4380)
        sd = colour.sd_CIE_illuminant_D_series(xy)
        extra.append(np.interp(fine.wavelengths_nm, sd.wavelengths, sd.values))
        names.append(f"CIE daylight {cct} K")
    for kelvin in BLACKBODY_K:
        extra.append(datasets.illuminant(f"blackbody:{kelvin}", fine).values[:, 0])
        names.append(f"blackbody {kelvin} K")
    added = without_near_copies(
        Spectra(
            fine, np.column_stack(extra), tuple(names), "spd", "energy", source="CIE daylight and blackbody spectra"
        )
    )
    library = prior_training_lights()
    if exclude:
        excluded = light_library().select(list(exclude))
        library, added = without_near_copies(library, excluded), without_near_copies(added, excluded)
    both = library.replace(
        values=np.hstack([library.values, added.resample(library.grid).values]),
        names=library.names + added.names,
        source="light prior training set",
    )
    return both.resample(grid, outside="zero")


@lru_cache(maxsize=64)
def learn_light_prior(grid: WavelengthGrid, dims: int = LIGHT_DIMS, exclude: tuple[str, ...] = ()) -> LightPrior:
    """The light prior on ``grid`` from :func:`prior_candidate_lights` (photons, each light unit-norm).

    Basis: the normalised mean light, then the ``dims − 1`` principal components of the lights'
    parts orthogonal to it; the prior: the mean and covariance of those parts' coefficients for
    lights scaled to unit mean-light coefficient.

    ``exclude``: library labels kept out with their near copies (:func:`prior_candidate_lights`).

    Raises
    ------
    SpectralDataError
        If ``dims`` is not in 2…n_wavelengths, or no training light has light on the grid.
    """
    lights = prior_candidate_lights(grid, exclude).to_unit("photons")
    values = lights.values
    norms = np.linalg.norm(values, axis=0)
    keep = norms > 0
    if not keep.any():
        raise SpectralDataError(f"light prior: no training light emits on {grid}; expected a grid within 380–780 nm")
    if not 2 <= dims <= grid.size:
        raise SpectralDataError(f"light prior: {dims} dimensions on {grid.size} wavelengths; expected 2…{grid.size}")
    unit = values[:, keep] / norms[keep]
    first = unit.mean(axis=1)
    first /= np.linalg.norm(first)
    scale = first @ unit  # every light's coefficient on the mean light (> 0: all lights are non-negative)
    scaled = unit / scale
    rest = scaled - np.outer(first, first @ scaled)
    centred = rest - rest.mean(axis=1, keepdims=True)
    vectors, _, _ = np.linalg.svd(centred, full_matrices=False)
    basis = np.column_stack([first, vectors[:, : dims - 1]])
    coefficients = basis[:, 1:].T @ scaled
    names = tuple(n for n, k in zip(lights.names, keep) if k)
    return LightPrior(
        basis=lights.replace(
            values=basis,
            names=tuple(f"light_basis_{m}" for m in range(dims)),
            source=f"light prior basis ({len(names)} training lights)",
            metadata={},
        ),
        mean=coefficients.mean(axis=1),
        covariance=np.cov(coefficients),
        training=names,
    )


@dataclass(frozen=True)
class ReflectanceBasis:
    """A low-dimensional basis for surface reflectances and the second moments of its coefficients."""

    basis: Spectra
    """B_r, (n_wl, p), orthonormal columns (uncentred principal components)."""
    weights: np.ndarray
    """s²: mean squared coefficient of the training surfaces on each column, shape (p,)."""


@lru_cache(maxsize=16)
def learn_reflectance_basis(grid: WavelengthGrid, dims: int = REFLECTANCE_DIMS) -> ReflectanceBasis:
    """The first ``dims`` uncentred principal components of Natural-100 on ``grid`` (ends held beyond 400–700 nm)."""
    surfaces = datasets.natural100().resample(grid, outside="edge")
    if not 1 <= dims <= min(surfaces.count, grid.size):
        raise SpectralDataError(f"reflectance basis: {dims} dimensions; expected 1…{min(surfaces.count, grid.size)}")
    vectors, singular, _ = np.linalg.svd(surfaces.values, full_matrices=False)
    return ReflectanceBasis(
        basis=surfaces.replace(
            values=vectors[:, :dims],
            names=tuple(f"reflectance_basis_{j}" for j in range(dims)),
            source="Natural-100 principal components",
        ),
        weights=singular[:dims] ** 2 / surfaces.count,
    )


# -- the estimator -----------------------------------------------------------------------------------
@dataclass(frozen=True)
class PriorEstimate:
    """The ambient estimated in the light prior's basis."""

    spectrum: Spectra
    """``B_e φ`` (photons, relative to the LEDs at full drive, like ``I w``)."""
    coefficients: np.ndarray
    """φ, shape (q,)."""
    spectrum_std: np.ndarray
    """One-sigma posterior band per wavelength, shape (n_wl,)."""
    prior_weight: float
    """λ used (the data term's units)."""
    relative_residual: float
    """``‖a − â‖ / ‖a‖`` over the valid blocks (all channels)."""
    n_samples: int
    """Valid block samples (blocks × channels)."""
    warnings: tuple[str, ...] = ()
    """Reliability warnings (empty when none)."""


def plane_responsivities(responsivities: Spectra, channels: tuple[str, ...]) -> np.ndarray:
    """(n_wl, C) responsivity of each plane: the column named by each channel letter (R, G, B)."""
    names = [n.upper() for n in responsivities.names]
    missing = [c for c in channels if c not in names]
    if missing:
        raise SpectralDataError(
            f"camera responsivities: no channel named {', '.join(missing)} among "
            f"{', '.join(responsivities.names)}; expected R, G, B"
        )
    return np.column_stack([responsivities.values[:, names.index(c)] for c in channels])


@dataclass(frozen=True)
class PriorModel:
    """The prior model for one LED set, camera and channel layout, prepared once (module notes, steps 1–2).

    Parameters are the LED spectra and responsivities (photons, one grid), the channel letters of the
    statistics (:attr:`ChannelStatistics.channels`), the light prior and the reflectance basis.
    """

    led_spectra: Spectra
    """The k LED spectra at full drive, photons."""
    responsivities: Spectra
    """The camera's R, G, B responsivities, photons, on the LEDs' grid."""
    channels: tuple[str, ...]
    """The channel letter of each plane of the statistics (``R G B`` or a CFA's four)."""
    prior: LightPrior
    """The light basis and its Gaussian prior."""
    reflectance: ReflectanceBasis
    """The reflectance basis of the Wiener estimate."""
    ridge: float = RIDGE
    """ρ, dimensionless (module notes, step 1)."""
    kappa: float = KAPPA
    """κ, the prior strength and the likelihood's tempering (steps 3–4)."""
    split: bool = True
    """Whether the LED-span part of each basis light bypasses the reflectance estimate (module notes)."""
    predictors: np.ndarray = field(init=False, repr=False)
    """K_m, shape (q, C, C·k)."""
    penalty: np.ndarray = field(init=False, repr=False)
    """``DᵀΣ⁻¹D`` (q × q): the prior's quadratic form per unit λ."""

    def __post_init__(self) -> None:
        led = require_unit(self.led_spectra, "photons")
        camera = require_unit(self.responsivities, "photons")
        for what, spectra in (
            ("camera responsivities", camera),
            ("light prior", self.prior.basis),
            ("reflectance basis", self.reflectance.basis),
        ):
            if not spectra.grid.same_as(led.grid):
                raise SpectralDataError(
                    f"prior model: {what} on {spectra.grid} but the LEDs on {led.grid}; expected one grid"
                )
        if not (self.ridge >= 0 and self.kappa > 0 and math.isfinite(self.ridge) and math.isfinite(self.kappa)):
            raise SpectralDataError(
                f"prior model: ridge {self.ridge}, kappa {self.kappa}; expected ridge ≥ 0, kappa > 0"
            )
        planes = plane_responsivities(camera, self.channels)  # (n, C)
        predictors = light_predictors(
            led.values, planes, self.prior.basis.values, self.reflectance, self.ridge, self.split
        )
        predictors.flags.writeable = False
        object.__setattr__(self, "predictors", predictors)
        difference = np.hstack([-self.prior.mean[:, None], np.eye(self.prior.dims - 1)])  # D φ = φ_rest − φ_0 μ
        penalty = difference.T @ np.linalg.pinv(self.prior.covariance) @ difference
        penalty.flags.writeable = False
        object.__setattr__(self, "penalty", penalty)

    def normal_equations(self, moments: Moments) -> tuple[np.ndarray, np.ndarray, float]:
        """``(H, g, Σ‖a‖²)`` of the data term for moments with one fold (module notes, step 3)."""
        return normal_equations(self.predictors, moments)

    def solve(
        self, moments: Moments, n_samples: int, nonnegative: bool = True, observed: Moments | None = None
    ) -> tuple[np.ndarray, np.ndarray, float, float]:
        """``(φ, posterior covariance of φ, λ, Σ‖a − Σ φ_m K_m f‖²)`` from one fold's moments: the last the residual on
        the observed moments at φ (``n_samples`` σ², what the estimate's relative residual is read from).

        ``moments`` are those φ solves (:func:`solved_moments`: denoised); ``observed`` the same blocks' moments as
        observed, when they differ. Then the normal matrix is floored where the removed noise exceeds the signal
        (:func:`floored_normal_equations`), and σ², which sets λ and the band, is the residual per sample on the
        observed moments: the errors the posterior weighs include the pixel noise the estimate carries, which the
        denoised moments no longer hold (the LEDs' span takes its band's variance from the observed residual too,
        :meth:`processing.ambient.AmbientModel.spectrum_band`).
        """
        if observed is None:
            hessian, linear, energy = self.normal_equations(moments)
            seen = (hessian, linear, energy)
        else:
            seen = self.normal_equations(observed)
            hessian, linear, energy, _ = floored_normal_equations(self.predictors, moments, seen[0])
        q = hessian.shape[0]
        prior, penalty = self.prior, self.penalty
        n = max(n_samples, q + 1)

        def residual(phi: np.ndarray) -> float:
            return float(seen[2] - 2 * seen[1] @ phi + phi @ seen[0] @ phi)

        # Start: the mean light alone (φ = s (1, μ)), its scale fitted — well determined.
        shape = np.concatenate([[1.0], prior.mean])
        s = float(linear @ shape / max(shape @ hessian @ shape, 1e-300))
        phi = s * shape
        weight = previous = 0.0
        for _ in range(EB_ITERATIONS):
            rss = max(residual(phi), 1e-300 * max(seen[2], 1e-300))
            sigma2 = rss / n
            scale2 = max(phi[0] ** 2, 1e-300)
            weight = self.kappa * sigma2 / scale2
            system = hessian + weight * penalty
            try:
                phi = np.linalg.solve(system, linear)
            except np.linalg.LinAlgError as err:
                raise SolverError(
                    f"prior model: the normal equations are singular ({err}); expected LED images with light"
                ) from err
            if abs(weight - previous) <= 1e-4 * weight:
                break
            previous = weight
        system = hessian + weight * penalty
        if nonnegative:
            phi = _nonnegative(system, linear, prior.basis.values)
        rss = max(residual(phi), 0.0)
        # The tempered likelihood whose posterior mode this is: errors of variance κσ² (module notes, step 4).
        covariance = self.kappa * (rss / n) * np.linalg.pinv(system)
        return phi, covariance, weight, rss

    def estimate(self, statistics: ChannelStatistics) -> PriorEstimate:
        """The ambient of a sequence's channel statistics."""
        check_statistics(statistics, self)
        n = statistics.n_blocks * statistics.n_channels
        observed = statistics.moments.total()
        phi, covariance, weight, rss = self.solve(solved_moments(statistics), n, observed=observed)
        basis = self.prior.basis.values
        spectrum = basis @ phi
        std = np.sqrt(np.clip(np.einsum("nm,mj,nj->n", basis, covariance, basis), 0.0, None))
        energy = float(np.trace(observed.aa[0]))
        relative = math.sqrt(rss / energy) if energy > 0 else 0.0
        warnings = []
        # The posterior band says how far the spectrum may be off at each wavelength (docs/light-prior.md);
        # a warning on a wide band flagged mostly good estimates (docs/light-prior.md, validation), so the
        # band is shown, not warned about.
        if not np.max(spectrum) > 0:
            warnings.append("the estimated spectrum is zero: no ambient light was found")
        return PriorEstimate(
            spectrum=self.led_spectra.replace(
                values=spectrum[:, None], names=("ambient",), source="ambient estimate (light prior)", metadata={}
            ),
            coefficients=phi,
            spectrum_std=std,
            prior_weight=float(weight),
            relative_residual=relative,
            n_samples=n,
            warnings=tuple(warnings),
        )


def solved_moments(statistics: ChannelStatistics, left_out: int | None = None) -> Moments:
    """The moments the prior is solved on: all folds' (all but ``left_out``) less *their whole* noise share.

    ``S − N`` summed over the chosen folds (errors in variables, :mod:`processing.channel_statistics`): no noise bias
    in the normal equations. The moments as observed when no noise was measured. :meth:`PriorModel.solve` floors the
    normal matrix where the removed noise exceeds the signal (:func:`floored_normal_equations`).
    """
    moments = statistics.moments
    observed = moments.total() if left_out is None else moments.without(left_out)
    if statistics.noise is None:
        return observed
    return observed - (statistics.noise.total() if left_out is None else statistics.noise.without(left_out))


def wiener_matrix(sensing: np.ndarray, reflectance: ReflectanceBasis, ridge: float) -> np.ndarray:
    """W = R Gᵀ (G R Gᵀ + ρ̄ Id)⁻¹ (n, Ck): the reflectance from a block's LED responses (module notes, step 1)."""
    basis_r = reflectance.basis.values
    second = (basis_r * reflectance.weights) @ basis_r.T  # R (n, n)
    gram = sensing @ second @ sensing.T
    scale = np.trace(gram) / gram.shape[0]
    return np.linalg.solve(gram + (ridge * scale + 1e-12 * np.trace(gram)) * np.eye(gram.shape[0]), sensing @ second).T


def light_predictors(
    leds: np.ndarray,
    planes: np.ndarray,
    lights: np.ndarray,
    reflectance: ReflectanceBasis,
    ridge: float = RIDGE,
    split: bool = True,
) -> np.ndarray:
    """K_m (q, C, C·k) for lights ``lights`` (n, q): how each light's ambient image follows from the LED images.

    ``K_m = E(u_m) + T(b⊥_m) W`` with ``b_m = I u_m + b⊥_m`` (module notes, step 2; ``split=False``: ``T(b_m) W``).
    ``leds`` (n, k) and ``planes`` (n, C, each plane's responsivity) in photons on one grid. Linear in the
    lights: the predictors of the unit spectra δ_λ give any light's as ``Σ_λ e(λ) K_λ``.
    """
    n_wl, channels, k = leds.shape[0], planes.shape[1], leds.shape[1]
    sensing = (planes[:, :, None] * leds[:, None, :]).reshape(n_wl, channels * k).T  # G: (Ck, n)
    wiener = wiener_matrix(sensing, reflectance, ridge)
    if split:
        in_span = np.linalg.lstsq(leds, lights, rcond=None)[0]  # u: (k, q)
        remainder = lights - leds @ in_span
    else:
        in_span, remainder = np.zeros((k, lights.shape[1])), lights
    through_surface = np.einsum("nc,nm,nl->mcl", planes, remainder, wiener)  # T(b⊥_m) W
    direct = np.einsum("cd,im->mcdi", np.eye(channels), in_span).reshape(lights.shape[1], channels, channels * k)
    return direct + through_surface


def normal_equations(predictors: np.ndarray, moments: Moments) -> tuple[np.ndarray, np.ndarray, float]:
    """``(H, g, Σ‖a‖²)`` of ``Σ_b ‖a_b − Σ_m φ_m K_m f_b‖²`` for predictors K (q, C, Ck) and one fold's moments.

    ``H[m, n] = tr(K_mᵀ K_n S_ff)``, ``g[m] = tr(K_m S_fa)``.
    """
    ff, fa, aa = moments.ff[0], moments.fa[0], moments.aa[0]
    q, channels, width = predictors.shape
    flat = predictors.reshape(q, channels * width)
    # As matrix products, not einsum's three-operand loops (slower on these shapes: docs/light-families.md).
    hessian = (predictors.reshape(q * channels, width) @ ff).reshape(q, channels * width) @ flat.T
    linear = flat @ fa.T.reshape(channels * width)
    return 0.5 * (hessian + hessian.T), linear, float(np.trace(aa))


def prediction_error(predictors: np.ndarray, phi: np.ndarray, moments: Moments) -> float:
    """``Σ_b ‖a_b − Σ_m φ_m K_m f_b‖²`` over one fold's moments."""
    hessian, linear, energy = normal_equations(predictors, moments)
    return float(max(energy - 2 * linear @ phi + phi @ hessian @ phi, 0.0))


def floored_normal_equations(
    predictors: np.ndarray, moments: Moments, observed_hessian: np.ndarray
) -> tuple[np.ndarray, np.ndarray, float, int]:
    """``(H, g, Σ‖a‖², floored)``: :func:`normal_equations` of the denoised ``moments``, H kept positive definite.

    The normal matrix of denoised moments, ``H(S − N)``, loses positive definiteness where the noise probe exceeds
    the signal along some combination of the light coefficients (a dim or noisy scene). Its noise share is
    ``H(S) − H(S − N)`` (``observed_hessian`` is ``H(S)``, which the caller has for σ²); each such direction is
    raised to a share of the noise along it (:func:`processing.noise_floor.noise_floored`, the rule the LEDs' span
    applies to its Gram matrix), ``floored`` of them. H as it is when it is positive definite (``floored`` 0).
    """
    hessian, linear, energy = normal_equations(predictors, moments)
    floored = noise_floored(hessian, observed_hessian - hessian)
    if floored is None:
        return hessian, linear, energy, 0
    return floored[0], linear, energy, floored[1]


def _nonnegative(hessian: np.ndarray, linear: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """argmin ½ φᵀHφ − gᵀφ subject to B φ ≥ 0 (scaled like :mod:`processing.ambient`)."""
    scale = max(np.trace(hessian) / hessian.shape[0], 1e-300)
    system = hessian / scale + 1e-12 * np.eye(hessian.shape[0])
    problem = FactoredQuadratic.prepare(system, basis, np.zeros(basis.shape[0]), "prior estimate")
    return problem.minimise(linear / scale).x


def check_statistics(statistics: ChannelStatistics, model: PriorModel) -> None:
    """A one-line error unless ``statistics`` fit ``model`` (LED count, channel layout, enough blocks)."""
    if statistics.n_leds != model.led_spectra.count:
        raise SpectralDataError(
            f"prior estimate: {model.led_spectra.count} LED spectra but the statistics have "
            f"{statistics.n_leds} LED images; expected one spectrum per LED"
        )
    if statistics.channels != model.channels:
        raise SpectralDataError(
            f"prior estimate: statistics of channels {''.join(statistics.channels)} but a model "
            f"for {''.join(model.channels)}; expected the same channel layout"
        )
    if statistics.n_blocks <= model.prior.dims:
        raise SpectralDataError(
            f"prior estimate: {statistics.n_blocks} valid blocks; expected more than the "
            f"{model.prior.dims} light coefficients (lower the exposure, or larger frames)"
        )


def prior_model(
    channels: tuple[str, ...],
    led_spectra: Spectra,
    responsivities: Spectra,
    prior: LightPrior | None = None,
    reflectance: ReflectanceBasis | None = None,
    **options: float | bool,
) -> PriorModel:
    """A :class:`PriorModel` with the default light prior and reflectance basis on the LEDs' grid."""
    grid = led_spectra.grid
    return PriorModel(
        led_spectra,
        responsivities,
        tuple(channels),
        learn_light_prior(grid) if prior is None else prior,
        learn_reflectance_basis(grid) if reflectance is None else reflectance,
        **options,  # type: ignore[arg-type]
    )
