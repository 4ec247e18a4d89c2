"""Light from physics, chosen by evidence: the family model (issue 30, item 2).

The light prior (:mod:`processing.light_prior`) represents the ambient in a basis learnt from a library of
measured lights; on lights unlike that library it does worse than the LEDs' span. The family model fits a few
*generative families* instead (:mod:`processing.light_forms`), each through the scene's data term
(:mod:`processing.spectral_data_term`) by variable projection (:mod:`processing.family_fit`), and chooses among
them here.

**Choice by held-out prediction** (:meth:`FamilyModel.estimate`). Every candidate — each form at each complexity,
the LEDs' span (eq. 5) and the light prior — predicts each fold of block rows' ambient pixels from its
LED-only pixels with its amplitudes refitted on the other folds (its nonlinear parameters stay those of
the fit on all folds). The family model takes the candidate of least held-out error, except that a
candidate with fewer parameters within :data:`SIMPLER_WITHIN` of it is preferred (no more model than the
scene needs). ``auto`` leaves the LEDs' span only when the chosen candidate's held-out error is below
``(1 − AUTO_MARGIN)`` × the LEDs' and the gain exceeds :data:`AUTO_NOISE` of the noise's share
(:func:`choose`): the noise-removed errors are differences of large numbers on raw frames, and held-out
folds share the pixel model's own misfit, which a flexible form can fit instead of the light.

**Band.** The fitted form's parameters have the tempered Gauss–Newton covariance ``κ σ² (DᵀHD)⁻¹``
(D = ∂e/∂(a, θ), σ² the residual per sample, κ as the light prior's), mapped to the spectrum; the spread
of the candidates that predict about as well (evidence weights ``exp(−Δ/τ)`` on their held-out errors)
is added: where the pixels cannot tell two families apart, the band says so.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from msflash.processing import family_kernels
from msflash.processing.channel_statistics import ChannelStatistics
from msflash.processing.family_fit import MAX_DISCHARGE_ATOMS, Fit, fit_discharge, fit_form, fit_mixture, start_costs
from msflash.processing.light_forms import FORMS, Form, seen_forms
from msflash.processing.light_prior import KAPPA, plane_responsivities
from msflash.processing.reference_patch import PATCH_WEIGHT, ReferencePatch
from msflash.processing.spectra import Spectra, WavelengthGrid, require_unit
from msflash.processing.spectral_data_term import (
    Reduction,
    SceneForm,
    Whitened,
    reduce_predictors,
    scene_form,
    unit_predictors,
)

SIMPLER_WITHIN = 0.1
"""A candidate with fewer parameters whose held-out error (noise removed) is within this fraction of the best one's
is preferred (:func:`choose`)."""
AUTO_MARGIN = 0.1
"""``auto`` leaves the LEDs' span only when the chosen candidate predicts held-out pixels (noise removed) this much
better (:func:`choose`)."""
AUTO_NOISE = 0.07
"""…and by more than this multiple of the noise's share, squared (:func:`choose`): flexible forms fit what the
folds share (the pixel model's misfit), not the light."""
AVERAGE_TEMPERATURE = 0.1
"""τ of the evidence weights of the estimate itself: the candidates' evidence-weighted average (Bayesian model
averaging), not the chosen one alone — where the pixels leave two forms equally likely, their mean is the safer
spectrum (the forms that tie are metameric for the camera and differ where it barely sees)."""
EVIDENCE_TEMPERATURE = 0.2
"""τ of the evidence weights ``exp(−(err/err_best − 1)/τ)`` whose candidates' spread enters the band."""
CHECK_TEMPERATURE = 0.5
"""τ of the spread the family's miss check reads (:func:`processing.family_checks.self_check`)."""
SEEN_FRACTION = 0.1
"""An emission band's centre must lie where the camera's most sensitive plane reaches this fraction of its peak
(:func:`processing.light_forms.seen_forms`)."""
POSTERIOR_SCALE = 1.0
"""Multiplies the chosen fit's tempered posterior ±1σ in the band.

Every constant above was chosen on the tuning rows of both harness suites; the sweeps behind each are in
docs/decisions/2026-11-light-families.md."""


@dataclass(frozen=True)
class Candidate:
    """A candidate model and its held-out evidence."""

    fit: Fit
    held_out_error: float
    """Relative held-out RMS error of the ambient image (pixels as observed), amplitudes refitted per fold."""
    held_out_error_noise_removed: float
    """The same with each held-out fold's noise share removed: the evidence the choice uses (on the tuning rows it
    chose better spectra than the observed error, docs/light-families.md)."""
    patch_error: float | None = None
    """With a reference patch: the relative error of the candidate's prediction of the patch (no reflectance
    estimate involved: the patch is known to be spectrally flat)."""

    @property
    def evidence(self) -> float:
        """What the choice ranks by: the held-out error (noise removed), with the patch's error when there is one."""
        if self.patch_error is None:
            return self.held_out_error_noise_removed
        return math.sqrt(self.held_out_error_noise_removed**2 + PATCH_WEIGHT * self.patch_error**2)

    @property
    def noise_share(self) -> float:
        """What removing the noise took off the held-out error, squared: the scale of the noise correction's own
        uncertainty (its probe has a sampling error, and on a mosaic it picks up texture)."""
        return max(self.held_out_error**2 - self.held_out_error_noise_removed**2, 0.0)


@dataclass(frozen=True)
class FamilyEstimate:
    """The family model's estimate of the ambient, its band and the evidence behind it."""

    spectrum: Spectra
    """The chosen candidate's spectrum (photons, relative to the LEDs at full drive)."""
    spectrum_std: np.ndarray
    """±1σ: the fitted form's tempered posterior and the spread of the candidates that predict about as well."""
    chosen: Candidate
    candidates: tuple[Candidate, ...]
    """Every candidate, best held-out error first."""
    led: Candidate
    """The LEDs' span (eq. 5, tikhonov) as a candidate."""
    reason: str
    """Why this candidate, in one sentence with the numbers."""
    auto_model: str
    """What ``auto`` takes: ``led`` or the chosen candidate's name."""
    auto_reason: str
    relative_residual: float
    """``√(J(e)/E)`` on all folds, as observed."""
    n_samples: int
    spread_std: np.ndarray = field(default_factory=lambda: np.zeros(0))
    """The evidence-weighted spread of the candidates about the chosen spectrum (:func:`_weighted_spread`)."""
    reference: ReferencePatch | None = None
    """The reference patches that joined the evidence, if any."""
    warnings: tuple[str, ...] = ()

    @property
    def family(self) -> str:
        """The chosen family."""
        return self.chosen.fit.family

    @property
    def relative_error(self) -> float:
        """The chosen candidate's held-out error over the LEDs' span's (noise removed; 1 where the LEDs' is 0)."""
        led = self.led.held_out_error_noise_removed
        return self.chosen.held_out_error_noise_removed / led if led > 0 else 1.0


def _held_out(
    spectrum_for: Callable[[int, Whitened], np.ndarray], scene: SceneForm, training: dict[int, Whitened]
) -> tuple[float, float]:
    """Relative held-out errors (observed, noise removed) of a model refitted on each fold's complement.

    ``spectrum_for(fold, training[fold])`` is the spectrum fitted without ``fold`` (``training``: each fold's
    complement's denoised data term, :func:`training_terms`).
    """
    sums = np.zeros(2)
    for fold, complement in training.items():
        observed, noise = scene.fold_error(fold, spectrum_for(fold, complement))
        sums += [max(observed, 0.0), max(observed - noise, 0.0)]
    total = float(scene.energy.sum())
    observed_error, clean_error = np.sqrt(sums / max(total, 1e-300))
    return float(observed_error), float(clean_error)


def _held_out_compiled(
    compiled: Any, fits: list[Fit], scene: SceneForm, training: dict[int, Whitened]
) -> list[tuple[float, float]]:
    """:func:`_held_out` of every fit (amplitudes refitted per fold) in one compiled call
    (:mod:`processing.family_kernels`)."""
    widths = [fit.atoms.shape[1] for fit in fits]
    offsets = np.concatenate([[0], np.cumsum(widths)]).astype(np.int64)
    atoms = np.ascontiguousarray(np.hstack([fit.atoms for fit in fits]), float)
    folds = np.array(list(training), np.int64)
    roots = np.ascontiguousarray(np.stack([training[f].root for f in training]), float)
    targets = np.ascontiguousarray(np.stack([training[f].target for f in training]), float)
    arrays = (scene.hessian, scene.linear, scene.energy, scene.noise_hessian, scene.noise_linear, scene.noise_energy)
    sums = compiled.held_out(
        atoms, offsets, roots, targets, folds, *(np.ascontiguousarray(a, float) for a in arrays),
        np.ascontiguousarray(scene.lift, float),
    )  # fmt: skip
    total = float(scene.energy.sum())
    errors = np.sqrt(sums / max(total, 1e-300))
    return [(float(observed), float(clean)) for observed, clean in errors]


def _judged(
    fits: list[Fit], led_fit: Fit, scene: SceneForm, training: dict[int, Whitened]
) -> tuple[Candidate, list[Candidate]]:
    """The LEDs' span and every fit as candidates with their held-out errors (:func:`_held_out`; compiled in one
    call where :mod:`processing.family_kernels` is in use). The prior is learnt elsewhere: judged as it is, not
    refitted."""
    compiled = family_kernels.kernels()
    judged: dict[str, tuple[float, float]] = {}
    each = 0.0
    if compiled is not None:
        start = time.perf_counter()
        refitted = [fit for fit in fits if fit.family != "prior"]
        errors = _held_out_compiled(compiled, [led_fit, *refitted], scene, training)
        each = (time.perf_counter() - start) / (len(refitted) + 1)
        led = Candidate(led_fit, *errors[0])
        judged = dict(zip((fit.name for fit in refitted), errors[1:]))
    else:
        led = Candidate(led_fit, *_held_out(_refit_amplitudes(led_fit), scene, training))
    candidates = []
    for fit in fits:
        if fit.name in judged:
            candidates.append(Candidate(fit.with_seconds(fit.seconds + each), *judged[fit.name]))
            continue
        start = time.perf_counter()
        spectrum_for = _fixed(fit.spectrum) if fit.family == "prior" else _refit_amplitudes(fit)
        held = _held_out(spectrum_for, scene, training)
        candidates.append(Candidate(fit.with_seconds(fit.seconds + time.perf_counter() - start), *held))
    return led, candidates


def training_terms(scene: SceneForm) -> dict[int, Whitened]:
    """Each non-empty fold's complement as a :class:`Whitened` data term (denoised, :meth:`SceneForm.complements`)."""
    return scene.complements()


def _timed(function: Callable[..., Fit], *arguments: object, before: float = 0.0) -> Fit:
    """``function(*arguments)`` with its wall time (and ``before`` seconds spent for it already) as its seconds."""
    start = time.perf_counter()
    fit = function(*arguments)
    return fit.with_seconds(before + time.perf_counter() - start)


def _fixed(spectrum: np.ndarray) -> Callable[[int, Whitened], np.ndarray]:
    def same(fold: int, training: Whitened) -> np.ndarray:
        return spectrum

    return same


def _refit_amplitudes(fit: Fit) -> Callable[[int, Whitened], np.ndarray]:
    def refit(fold: int, training: Whitened) -> np.ndarray:
        amplitudes, _ = training.amplitudes(fit.atoms)
        return fit.atoms @ amplitudes

    return refit


def _band(fit: Fit, grid: WavelengthGrid, problem: Whitened, n_samples: int, kappa: float) -> np.ndarray:
    """±1σ of the fitted spectrum: ``κσ² D (DᵀHD)⁺ Dᵀ`` with D = ∂e/∂(a, θ) by central differences."""
    spectrum = fit.spectrum
    columns = [fit.atoms[:, i] for i in range(fit.atoms.shape[1])]
    if fit.form is not None and fit.theta.size:
        for j in range(fit.theta.size):
            low, high = fit.form.bounds[j]
            step = 1e-3 * max(high - low, 1e-6)
            up, down = fit.theta.copy(), fit.theta.copy()
            up[j], down[j] = min(up[j] + step, high), max(down[j] - step, low)
            if up[j] == down[j]:
                continue
            derivative = (fit.form.atoms(grid, up) - fit.form.atoms(grid, down)) @ fit.amplitudes / (up[j] - down[j])
            columns.append(derivative)
    jacobian = np.column_stack(columns)
    sigma2 = max(problem.error(spectrum), 0.0) / max(n_samples, 1)
    information = problem.information(jacobian)
    covariance = kappa * sigma2 * np.linalg.pinv(information, rcond=1e-10)
    return np.sqrt(np.clip(np.einsum("ij,jk,ik->i", jacobian, covariance, jacobian), 0.0, None))


def choose(candidates: list[Candidate], led: Candidate) -> tuple[Candidate, str, str, str]:
    """The family model's choice and ``auto``'s, with their reasons (module notes).

    The candidate of least evidence E (held-out error, noise removed) unless one with fewer parameters is within
    :data:`SIMPLER_WITHIN` of it (then the simplest such, the better of equals). With ``N`` the LEDs' span's
    :attr:`Candidate.noise_share` (what the noise correction takes off a held-out error: gains well below it are
    not evidence), ``auto`` takes it only when ``E² + AUTO_NOISE · N < (1 − AUTO_MARGIN)² E_led²``, else ``led``.

    Returns
    -------
    Candidate, str, str, str
        The chosen candidate, why, what ``auto`` takes (``led`` or the candidate's name) and why.
    """
    if not candidates:
        return led, "only the LEDs' span was fitted", "led", "only the LEDs' span was fitted"
    noise = led.noise_share
    best = min(candidates, key=lambda c: c.evidence)
    limit = best.evidence * (1 + SIMPLER_WITHIN)
    simpler = [c for c in candidates if c.evidence <= limit and c.fit.n_parameters < best.fit.n_parameters]
    chosen = min(simpler, key=lambda c: (c.fit.n_parameters, c.evidence)) if simpler else best
    error, led_error = chosen.evidence, led.evidence
    reason = (
        f"{chosen.fit.name} ({chosen.fit.n_parameters} parameters) predicts held-out pixels "
        + (
            f"within {SIMPLER_WITHIN:.0%} of the best candidate ({best.fit.name}, {best.fit.n_parameters} parameters, "
            f"{best.evidence:.4f}) with fewer parameters"
            if chosen is not best
            else "best of all candidates"
        )
        + f": relative error {error:.4f} (noise removed) against {led_error:.4f} for the LEDs' span"
    )
    if error**2 + AUTO_NOISE * noise < (1 - AUTO_MARGIN) ** 2 * led_error**2:
        return (
            chosen,
            reason,
            chosen.fit.name,
            f"{chosen.fit.name} predicts held-out pixels better than the LEDs' span: relative error {error:.4f} "
            f"against {led_error:.4f} (noise removed; more than {AUTO_MARGIN:.0%} lower, and by more than "
            f"{AUTO_NOISE:g} of the noise's share {math.sqrt(noise):.4f})",
        )
    return (
        chosen,
        reason,
        "led",
        f"the LEDs' span predicts held-out pixels as well: relative error {led_error:.4f} against {error:.4f} "
        f"for {chosen.fit.name} (noise removed; which must be more than {AUTO_MARGIN:.0%} lower, and by more than "
        f"{AUTO_NOISE:g} of the noise's share {math.sqrt(noise):.4f})",
    )


@dataclass(frozen=True)
class FamilyModel:
    """The family model for one LED set, camera and channel layout, prepared once (module notes)."""

    led_spectra: Spectra
    responsivities: Spectra
    channels: tuple[str, ...]
    kappa: float = KAPPA
    reduction: Reduction = field(init=False, repr=False)
    forms: tuple[Form, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        reduction = reduce_predictors(unit_predictors(self.led_spectra, self.responsivities, self.channels))
        reduction.lift.flags.writeable = False
        object.__setattr__(self, "reduction", reduction)
        object.__setattr__(self, "forms", seen_forms(FORMS, self.seen_nm))

    @property
    def seen_nm(self) -> tuple[float, float]:
        """The wavelengths the camera sees: where its most sensitive plane reaches :data:`SEEN_FRACTION` of the
        camera's peak (photons)."""
        planes = plane_responsivities(self.responsivities, self.channels).max(axis=1)
        seen = np.flatnonzero(planes >= SEEN_FRACTION * max(float(planes.max()), 1e-300))
        nm = self.grid.wavelengths_nm
        return (float(nm[seen[0]]), float(nm[seen[-1]])) if seen.size else (float(nm[0]), float(nm[-1]))

    @property
    def grid(self) -> WavelengthGrid:
        """The LEDs' grid."""
        return self.led_spectra.grid

    def candidates(
        self, statistics: ChannelStatistics, prior_spectrum: np.ndarray | None = None
    ) -> tuple[SceneForm, list[Fit], Fit]:
        """Every family fit on all folds (denoised) and the LEDs' span, with the scene's form."""
        scene = scene_form(statistics, self.reduction)
        fits, led_fit = self._fits(scene.whitened(list(range(scene.n_folds))), prior_spectrum)
        return scene, fits, led_fit

    def _fits(self, problem: Whitened, prior_spectrum: np.ndarray | None) -> tuple[list[Fit], Fit]:
        """:meth:`candidates` on the all-folds data term ``problem``."""
        grid = self.grid
        start = time.perf_counter()
        compiled = family_kernels.kernels()  # asked once for every fit below
        costs = start_costs(self.forms, grid, problem, compiled)  # every form's coarse starts at once
        share = (time.perf_counter() - start) / max(len(self.forms), 1)
        fits = [
            _timed(fit_form, form, grid, problem, True, cost, compiled, before=share)
            for form, cost in zip(self.forms, costs)
        ]
        start = time.perf_counter()
        greedy = fit_discharge(grid, problem, MAX_DISCHARGE_ATOMS, compiled)
        each = (time.perf_counter() - start) / max(len(greedy), 1)
        fits += [fit.with_seconds(each * (i + 1)) for i, fit in enumerate(greedy)]  # size m needs steps 1…m
        best_of: dict[str, Fit] = {}
        for fit in fits:
            if fit.family not in best_of or fit.objective < best_of[fit.family].objective:
                best_of[fit.family] = fit
        families = sorted(best_of)
        for i, a in enumerate(families):
            for b in families[i + 1 :]:
                fits.append(_timed(fit_mixture, best_of[a], best_of[b], grid, problem, compiled))
        # The LEDs' span judged as the families are: non-negative weights on the same (denoised) data term, no
        # roughness penalty (eq. 5's α would bias its held-out error against it).
        leds = self.led_spectra.values
        led_weights, led_objective = problem.amplitudes(leds)
        led_fit = Fit("led", "led", np.zeros(0), leds, led_weights, led_objective, leds.shape[1])
        if prior_spectrum is not None:
            fits.append(
                Fit(
                    "prior",
                    "prior",
                    np.zeros(0),
                    prior_spectrum[:, None],
                    np.ones(1),
                    problem.error(prior_spectrum),
                    16,
                )
            )
        return fits, led_fit

    def estimate(
        self,
        statistics: ChannelStatistics,
        prior_spectrum: np.ndarray | None = None,
        reference: ReferencePatch | None = None,
    ) -> FamilyEstimate:
        """Fit every family, judge each on held-out folds, choose, and give the band and the evidence.

        With a ``reference`` patch its error joins the evidence (:attr:`Candidate.evidence`) and the chosen form's
        amplitudes are refitted to honour it (:data:`PATCH_FIT_WEIGHT`): the estimate is calibrated on it.
        """
        scene = scene_form(statistics, self.reduction)
        folds = list(range(scene.n_folds))
        problem = scene.whitened(folds)
        fits, led_fit = self._fits(problem, prior_spectrum)
        led, candidates = _judged(fits, led_fit, scene, training_terms(scene))
        if reference is not None:
            led = replace(led, patch_error=reference.relative_error(led.fit.spectrum))
            candidates = [replace(c, patch_error=reference.relative_error(c.fit.spectrum)) for c in candidates]
        candidates.sort(key=lambda c: c.evidence)
        chosen, reason, auto_model, auto_reason = choose(candidates, led)
        n_samples = statistics.n_blocks * statistics.n_channels
        if reference is not None and chosen.fit.family not in ("prior", "led"):
            calibrated = reference.calibrate(problem, chosen.fit.atoms)
            chosen = replace(chosen, fit=replace(chosen.fit, amplitudes=calibrated))
            candidates = [chosen if c.fit.name == chosen.fit.name else c for c in candidates]
        scaled = _scaled_spectra(chosen, candidates)
        std = self.band(chosen, candidates, problem, n_samples, scaled)
        spread, _ = _weighted_spread(chosen.fit.spectrum, candidates, scaled, CHECK_TEMPERATURE)
        residual = math.sqrt(max(scene.error(folds, chosen.fit.spectrum, denoised=False), 0.0))
        _, spectrum = _weighted_spread(chosen.fit.spectrum, candidates, scaled, AVERAGE_TEMPERATURE)
        warnings = () if np.max(spectrum) > 0 else ("the estimated spectrum is zero: no ambient light was found",)
        return FamilyEstimate(
            spectrum=self.led_spectra.replace(
                values=spectrum[:, None],
                names=("ambient",),
                source=f"ambient estimate ({chosen.fit.name})",
                metadata={},
            ),
            spectrum_std=std,
            chosen=chosen,
            candidates=tuple(candidates),
            led=led,
            reason=reason,
            auto_model=auto_model,
            auto_reason=auto_reason,
            relative_residual=residual,
            n_samples=n_samples,
            spread_std=spread,
            reference=reference,
            warnings=warnings,
        )

    def band(
        self,
        chosen: Candidate,
        candidates: list[Candidate],
        problem: Whitened,
        n_samples: int,
        scaled: np.ndarray | None = None,
    ) -> np.ndarray:
        """±1σ: the chosen fit's tempered posterior (× :data:`POSTERIOR_SCALE`) and the evidence-weighted spread of
        the candidates (:func:`_weighted_spread`; ``scaled``: their spectra scaled onto the chosen one's, when
        computed already) added in quadrature."""
        own = self.posterior_std(chosen, problem, n_samples)
        scaled = _scaled_spectra(chosen, candidates) if scaled is None else scaled
        spread, _ = _weighted_spread(chosen.fit.spectrum, candidates, scaled)
        return np.sqrt((POSTERIOR_SCALE * own) ** 2 + spread**2)

    def posterior_std(self, chosen: Candidate, problem: Whitened, n_samples: int) -> np.ndarray:
        """The chosen fit's tempered posterior ±1σ alone (zero for the prior, whose band is its own)."""
        if chosen.fit.family in ("prior", "led"):
            return np.zeros(self.grid.size)
        return _band(chosen.fit, self.grid, problem, n_samples, self.kappa)


def _scaled_spectra(chosen: Candidate, candidates: list[Candidate]) -> np.ndarray:
    """(n, candidates): each candidate's spectrum least-squares scaled onto the chosen one's (the spectra's overall
    scales differ by fit)."""
    reference = chosen.fit.spectrum
    if not candidates:
        return np.zeros((reference.size, 0))
    spectra = np.column_stack([c.fit.spectrum for c in candidates])
    energies = np.einsum("ij,ij->j", spectra, spectra)
    with np.errstate(divide="ignore", invalid="ignore"):
        scales = np.where(energies > 0, (reference @ spectra) / energies, 1.0)
    return spectra * scales


def _weighted_spread(
    spectrum: np.ndarray, candidates: list[Candidate], spectra: np.ndarray, temperature: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(spread, average)``: the candidates' RMS distance from ``spectrum`` (the chosen one's) and their mean,
    weighted by their evidence ``exp(−(err/err_best − 1)/τ)`` (τ = :data:`EVIDENCE_TEMPERATURE` by default), from
    their ``spectra`` each scaled onto the chosen one (:func:`_scaled_spectra`). Where the pixels cannot tell two
    families apart, the spread is wide."""
    temperature = EVIDENCE_TEMPERATURE if temperature is None else temperature
    if not candidates:
        return np.zeros_like(spectrum), spectrum
    evidence = [c.evidence for c in candidates]
    best = max(min(evidence), 1e-300)
    excess = np.array([e / best - 1 for e in evidence])
    weights = np.exp(-excess / temperature)
    spread = np.sqrt((weights * (spectra - spectrum[:, None]) ** 2).sum(1) / weights.sum())
    return spread, (spectra * weights).sum(1) / weights.sum()


def family_model(channels: tuple[str, ...], led_spectra: Spectra, responsivities: Spectra) -> FamilyModel:
    """A :class:`FamilyModel` for a sequence's LEDs (photons), camera (photons, the LEDs' grid) and planes."""
    return FamilyModel(require_unit(led_spectra, "photons"), require_unit(responsivities, "photons"), tuple(channels))
