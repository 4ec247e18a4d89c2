"""The light prior against the LEDs' span: which predicts held-out pixels better (issue 17, build 3).

``--model auto`` chooses among the physics families (:mod:`processing.light_families`), where the prior is one
candidate; this choice is a check of its own (:func:`choose_model`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from msflash.processing.ambient import AmbientModel
from msflash.processing.channel_statistics import ChannelStatistics
from msflash.processing.light_prior import (
    CHOICE_MARGIN,
    PriorModel,
    check_statistics,
    prediction_error,
    solved_moments,
)

ModelName = Literal["led", "prior"]


@dataclass(frozen=True)
class ModelChoice:
    """Which model ``auto`` uses and why: both models' held-out prediction errors of the ambient image."""

    model: ModelName
    """``"led"`` (eq. 4–6, the LEDs' span) or ``"prior"`` (the light prior)."""
    led_error: float
    """Held-out RMS error of the LED model's prediction of the ambient image (pixels as observed), relative to
    the image's RMS."""
    prior_error: float
    """The same for the prior model."""
    margin: float
    """The prior model had to beat the LED model by this fraction."""
    reason: str
    """One sentence with the numbers."""
    errors: HeldOutErrors
    """All held-out errors (noise removed, and as observed)."""


@dataclass(frozen=True)
class HeldOutErrors:
    """Held-out prediction errors of the ambient image, relative to its RMS (:func:`held_out_errors`)."""

    led: float
    """LED model, noise share removed (model error alone)."""
    prior: float
    """Prior model, noise share removed."""
    led_observed: float
    """LED model, on the pixels as observed (noise included)."""
    prior_observed: float
    """Prior model, on the pixels as observed."""


def held_out_errors(statistics: ChannelStatistics, model: PriorModel, led_method: str = "tikhonov") -> HeldOutErrors:
    """Both models' relative held-out errors over the folds of ``statistics``.

    Each fold's ambient pixels are predicted from its LED-only pixels by models trained (on denoised
    moments) on the other folds. The squared errors are summed over folds, on the pixels as observed
    and with the fold's noise share (half-difference probe) removed — the part a better model can
    reduce — and divided by the ambient image's energy.
    """
    check_statistics(statistics, model)
    led_model = AmbientModel(model.led_spectra)
    sums = np.zeros(4)
    k, channels = statistics.n_leds, statistics.n_channels
    for fold in range(statistics.n_folds):
        if statistics.counts[fold] == 0:
            continue
        training = [j for j in range(statistics.n_folds) if j != fold]
        n_train = int(statistics.counts[training].sum()) * channels
        phi, *_ = model.solve(solved_moments(statistics, fold), n_train, observed=statistics.moments.without(fold))
        weights, _ = led_model.weights(statistics.led_statistics(training), led_method)
        direct = np.einsum("cd,i->cdi", np.eye(channels), weights).reshape(1, channels, channels * k)
        held = statistics.moments.fold(fold)
        clean = held if statistics.noise is None else held - statistics.noise.fold(fold)
        sums += [
            prediction_error(direct, np.ones(1), clean),
            prediction_error(model.predictors, phi, clean),
            prediction_error(direct, np.ones(1), held),
            prediction_error(model.predictors, phi, held),
        ]
    energy = float(np.trace(statistics.moments.total().aa[0]))
    relative = np.sqrt(sums / energy) if energy > 0 else np.zeros(4)
    return HeldOutErrors(*(float(v) for v in relative))


def choose_model(statistics: ChannelStatistics, model: PriorModel, margin: float = CHOICE_MARGIN) -> ModelChoice:
    """``auto``: the prior model only where it predicts held-out pixels better than the LED model by ``margin``.

    Both models predict each fold of blocks' ambient pixels from its LED-only pixels, trained on the
    other folds (:func:`held_out_errors`); the errors compared are those on the pixels as observed
    (noise amplified by a model counts against it): on the tuning split they picked the better
    spectrum more often than the noise-corrected ones (docs/light-prior.md, validation). The LED
    model is the simpler (k weights, exact for any surface when the ambient is in the LEDs' span);
    it is kept unless the prior model's relative held-out RMS error is below ``(1 − margin)`` times
    its own.
    """
    errors = held_out_errors(statistics, model)
    led_error, prior_error = errors.led_observed, errors.prior_observed
    if prior_error < (1.0 - margin) * led_error:
        model_name: ModelName = "prior"
        reason = (
            f"the light prior predicts held-out pixels better: relative error {prior_error:.4f} against "
            f"{led_error:.4f} for the LEDs' span (more than {margin:.0%} lower)"
        )
    else:
        model_name = "led"
        reason = (
            f"the LEDs' span predicts held-out pixels as well or better: relative error {led_error:.4f} against "
            f"{prior_error:.4f} for the light prior (which must be more than {margin:.0%} lower)"
        )
    return ModelChoice(model_name, led_error, prior_error, margin, reason, errors)
