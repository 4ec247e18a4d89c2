"""From a recorded sequence to the models beyond the LEDs' span: ``--model prior|family|auto`` (issues 17 and 30).

The thin layer between a :class:`~acquisition.sequence.format.Sequence` and :mod:`processing.light_prior` /
:mod:`processing.light_families`, as :mod:`acquisition.session.analysis` is for eq. 4–6: the channel-resolved
statistics are the LED estimate's stream's (:meth:`EstimateStream.channel_statistics`: its block rows, each frame
passed over once), the LED spectra and responsivities go to photons; a reference patch or chart keeps only its
rectangles' crops, taken as the frames pass through the same stream
(:class:`~acquisition.session.reference_crops.ReferenceCrops`). :data:`MODEL_ROUTES` is the one
table from a ``--model`` name to what it computes. A flickering ambient is read once, by the LED side's estimate
(:func:`acquisition.session.analysis.flicker_check`), and its correction is applied to every statistic the light
models are fitted through (:func:`processing.flicker.corrected_channel_statistics`; docs/flicker.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.session import analysis, local_route
from msflash.acquisition.session.analysis import DEFAULT_BIN_FACTOR, FrameStack
from msflash.acquisition.session.estimate_stream import EstimateStream, stream_sequence
from msflash.acquisition.session.reference_crops import ReferenceCrops
from msflash.acquisition.session.sequence_spectra import (
    camera_responsivities_photons,
    led_spectra_photons,
    spectrum_in_sequence_unit,
)
from msflash.processing.ambient import AmbientEstimate, estimate_ambient
from msflash.processing.channel_statistics import ChannelStatistics
from msflash.processing.family_checks import LED_WARNING, PRIOR_WARNING, MissCheck, predicted_ratio, self_check
from msflash.processing.flicker import FlickerCheck, corrected_channel_statistics
from msflash.processing.light_families import (
    AUTO_MARGIN,
    AUTO_NOISE,
    AVERAGE_TEMPERATURE,
    SIMPLER_WITHIN,
    FamilyEstimate,
    family_model,
)
from msflash.processing.light_prior import PriorEstimate, prior_model
from msflash.processing.prior_choice import ModelChoice, choose_model
from msflash.processing.reference_patch import ReferencePatch
from msflash.processing.spectra import Spectra


@dataclass(frozen=True)
class SequencePriorResult:
    """Both models' estimates of a sequence and which one ``auto`` picks."""

    prior: PriorEstimate
    """The light-prior estimate."""
    led: AmbientEstimate
    """The LED-span estimate (eq. 4–6, tikhonov), from the same channel statistics."""
    choice: ModelChoice
    """``auto``'s choice and its reason."""

    @property
    def chosen_spectrum(self):  # noqa: ANN201 — a Spectra
        """The spectrum of the chosen model (photons, the LEDs' units)."""
        return self.prior.spectrum if self.choice.model == "prior" else self.led.spectrum


def sequence_channel_statistics(
    sequence: Sequence,
    stack: FrameStack | None = None,
    bin_factor: int = DEFAULT_BIN_FACTOR,
    flicker: FlickerCheck | None = None,
    stream: EstimateStream | None = None,
) -> ChannelStatistics:
    """The channel statistics of a sequence, corrected for the ambient gains ``flicker`` applies (the LED estimate's
    check; None: as the frames hold them): :meth:`EstimateStream.channel_statistics` of ``stream``, the LED
    estimate's own (made by :func:`light_model_stream`: the frames are passed over once, issue 31), or of one fed
    ``stack`` (None: the files, one frame at a time) binned by ``bin_factor`` like the LED estimate."""
    stream = stream or light_model_stream(sequence, stack, bin_factor)
    return corrected_channel_statistics(stream.channel_statistics(), flicker)


def light_model_stream(
    sequence: Sequence,
    stack: FrameStack | None,
    bin_factor: int = DEFAULT_BIN_FACTOR,
    tiles: int | None = None,
    references: ReferenceCrops | None = None,
) -> EstimateStream:
    """The LED estimate's stream as the light models need it (every block row's probe kept, ``full_probe``), fed
    ``stack`` or, without one, the files one frame at a time (:func:`~acquisition.session.estimate_stream.stream_sequence`);
    ``references``: a reference patch's or chart's crops, taken from the same frames as they pass."""
    if stack is None:
        return stream_sequence(sequence, bin_factor, tiles, full_probe=True, references=references)
    return analysis.stream_stack(sequence, stack, bin_factor, tiles, full_probe=True, references=references)


def estimate_sequence_prior(
    sequence: Sequence,
    stack: FrameStack | None = None,
    flicker: FlickerCheck | None = None,
    statistics: ChannelStatistics | None = None,
) -> SequencePriorResult:
    """The light-prior estimate of a sequence, the LED-span one and ``auto``'s choice between them; ``flicker``
    and ``statistics`` as in :func:`estimate_sequence_family`.

    Raises
    ------
    RecordingError
        If the sequence has no camera responsivities or unusable frames.
    """
    if statistics is None:
        statistics = sequence_channel_statistics(sequence, stack, flicker=flicker)
    leds = led_spectra_photons(sequence)
    model = prior_model(statistics.channels, leds, camera_responsivities_photons(sequence))
    return SequencePriorResult(
        model.estimate(statistics), estimate_ambient(statistics.led_statistics(), leds), choose_model(statistics, model)
    )


def prior_payload(sequence: Sequence, result: SequencePriorResult) -> dict:
    """The JSON fields for ``msflash estimate --model prior|auto``: the chosen model, why, and both spectra.

    ``spectrum``/``spectrum_std`` are the chosen model's (sequence unit); ``model_choice`` holds the
    held-out errors behind the choice; ``prior`` the light-prior estimate whichever model was chosen.
    """
    prior = result.prior
    chosen = result.choice.model
    std = prior.spectrum_std if chosen == "prior" else result.led.spectrum_std
    spectrum = result.chosen_spectrum
    errors = result.choice.errors
    return {
        "sequence": str(sequence.directory),
        "wavelengths_nm": sequence.wavelengths_nm,
        "spectral_unit": sequence.spectral_unit,
        "model": chosen,
        **spectrum_fields(sequence, spectrum, std),
        "model_choice": {
            "model": chosen,
            "reason": result.choice.reason,
            "margin": result.choice.margin,
            "held_out_relative_error": {"led": errors.led_observed, "prior": errors.prior_observed},
            "held_out_relative_error_noise_removed": {"led": errors.led, "prior": errors.prior},
        },
        "prior": {
            **spectrum_fields(sequence, prior.spectrum, prior.spectrum_std),
            "coefficients": prior.coefficients,
            "prior_weight": prior.prior_weight,
            "relative_residual": prior.relative_residual,
            "warnings": list(prior.warnings),
        },
        "led": {
            "spectrum": spectrum_in_sequence_unit(sequence, result.led.spectrum),
            "ambient_weights": result.led.ambient_weights,
            "relative_residual": result.led.relative_residual,
            "warnings": list(result.led.warnings),
        },
        "n_samples": prior.n_samples,
    }


def spectrum_fields(sequence: Sequence, spectrum: Spectra, std: np.ndarray) -> dict:
    """``spectrum`` and its ±1σ band ``std`` as the payload's ``spectrum`` and ``spectrum_std`` (the sequence's
    unit)."""
    return {
        "spectrum": spectrum_in_sequence_unit(sequence, spectrum),
        "spectrum_std": spectrum_in_sequence_unit(sequence, spectrum.replace(values=np.asarray(std)[:, None])),
    }


def led_side(
    sequence: Sequence,
    stack: FrameStack | None,
    method: str,
    solver: str,
    alpha: float | str,
    tiles: int,
    bin_factor: int = DEFAULT_BIN_FACTOR,
    references: ReferenceCrops | None = None,
) -> tuple[AmbientEstimate, dict, bool, EstimateStream]:
    """The LED-span side of ``estimate --model prior|auto``: what ``--model led`` gives (global, or local when
    ``method`` finds the illuminant varying across the scene), its payload, whether it varies, and the stream of the
    frames (``stack``, or the files one at a time) it was made from: the light models' channel statistics come from
    it (:func:`sequence_channel_statistics`), and a reference's crops (``references``) are taken by it as the frames
    pass."""
    stream = light_model_stream(sequence, stack, bin_factor, None if method == "global" else tiles, references)
    if method != "global":
        local = local_route.estimate_sequence_local(sequence, method, solver, alpha, stream=stream)
        payload = local_route.local_estimate_payload(sequence, local)
        return local.global_estimate, payload, local.model == "local", stream
    led = analysis.estimate_sequence(sequence, solver, alpha, stream=stream)
    return led, analysis.estimate_payload(sequence, led), False, stream


def estimate_sequence_family(
    sequence: Sequence,
    stack: FrameStack | None = None,
    prior: PriorEstimate | None = None,
    reference: ReferencePatch | None = None,
    flicker: FlickerCheck | None = None,
    statistics: ChannelStatistics | None = None,
) -> tuple[PriorEstimate, FamilyEstimate]:
    """The light prior's and the family model's estimates of a sequence (the prior is one of the candidates);
    ``reference``: a reference patch or chart already measured (:meth:`ReferenceCrops.patch
    <acquisition.session.reference_crops.ReferenceCrops.patch>`, its crops taken as the frames passed through the
    stream: no frame is read here); ``flicker``: the LED estimate's check, whose gains correct every statistic;
    ``statistics``: the sequence's channel statistics so corrected, when taken already.

    Raises
    ------
    RecordingError
        If the sequence has no camera responsivities or unusable frames.
    """
    if statistics is None:
        statistics = sequence_channel_statistics(sequence, stack, flicker=flicker)
    leds = led_spectra_photons(sequence)
    camera = camera_responsivities_photons(sequence)
    if prior is None:
        prior = prior_model(statistics.channels, leds, camera).estimate(statistics)
    family = family_model(statistics.channels, leds, camera).estimate(
        statistics, prior.spectrum.values[:, 0], reference
    )
    return prior, family


def family_payload(sequence: Sequence, family: FamilyEstimate) -> dict:
    """The JSON block ``family``: the chosen family and form, its parameters, the evidence and why."""
    fit = family.chosen.fit

    def evidence(candidate) -> dict:  # noqa: ANN001 — a light_families.Candidate
        return {
            "model": candidate.fit.name,
            "family": candidate.fit.family,
            "n_parameters": candidate.fit.n_parameters,
            "held_out_relative_error": candidate.held_out_error,
            "held_out_relative_error_noise_removed": candidate.held_out_error_noise_removed,
            "reference_patch_relative_error": candidate.patch_error,
        }

    return {
        "family": fit.family,
        "form": fit.name,
        "parameters": fit.parameters(),
        "n_parameters": fit.n_parameters,
        "reason": family.reason,
        **spectrum_fields(sequence, family.spectrum, family.spectrum_std),
        "relative_residual": family.relative_residual,
        "reference": None
        if family.reference is None
        else {
            "equations": int(family.reference.target.size),
            "led_misfit": family.reference.led_misfit,
            "chosen_relative_error": family.reference.relative_error(family.spectrum.values[:, 0]),
        },
        "evidence": {
            "criterion": "held-out prediction of the ambient image (folds of block rows, noise removed); the "
            f"simplest candidate within {SIMPLER_WITHIN:.0%} of the best is preferred; the spectrum is the "
            f"candidates' average weighted by exp(-(error/best - 1)/{AVERAGE_TEMPERATURE:g})",
            "led": evidence(family.led),
            "candidates": [evidence(c) for c in family.candidates],
        },
        "warnings": list(family.warnings),
    }


LED_GAP_SHARE = 0.25
"""Where the family evidence is computed, the LEDs' band adds this share of the squared gap between their estimate
and the family's (scaled onto it; its coverage: docs/light-families.md)."""
OLD_LED_MISS_WARNING = "the spectrum may be off by more than"
"""The start of :mod:`processing.model_error`'s warning, which the families' check replaces where it is computed."""


def _checks(
    sequence: Sequence, led_payload: dict, prior: PriorEstimate, family: FamilyEstimate
) -> dict[str, MissCheck]:
    """Every model's miss check against the family evidence, in the sequence's unit (as estimates are scored)."""
    leds = np.column_stack([np.asarray(led.spd, float) for led in sequence.leds])
    family_spectrum = np.asarray(spectrum_in_sequence_unit(sequence, family.spectrum), float)
    spread = np.asarray(
        spectrum_in_sequence_unit(sequence, family.spectrum.replace(values=family.spread_std[:, None])), float
    )
    prior_spectrum = np.asarray(spectrum_in_sequence_unit(sequence, prior.spectrum), float)
    return {
        "led": predicted_ratio(np.asarray(led_payload["spectrum"], float), family_spectrum, leds, LED_WARNING, "LEDs'"),
        "prior": predicted_ratio(prior_spectrum, family_spectrum, leds, PRIOR_WARNING, "light prior's"),
        "family": self_check(family_spectrum, spread, leds, family.relative_error),
    }


def _models_block(
    sequence: Sequence, led_payload: dict, prior: PriorEstimate, family: FamilyEstimate
) -> tuple[dict, dict[str, MissCheck]]:
    """``models``: each model's spectrum, band, warnings and miss check, whichever is chosen."""
    checks = _checks(sequence, led_payload, prior, family)
    led_warnings = [w for w in led_payload.get("warnings", []) if not w.startswith(OLD_LED_MISS_WARNING)]
    led_spectrum = np.asarray(led_payload["spectrum"], float)
    family_spectrum = np.asarray(spectrum_in_sequence_unit(sequence, family.spectrum), float)
    energy = float(family_spectrum @ family_spectrum)
    gap = led_spectrum - family_spectrum * (float(family_spectrum @ led_spectrum) / energy if energy > 0 else 0.0)
    given = led_payload.get("spectrum_std")
    led_std = np.zeros_like(led_spectrum) if given is None else np.asarray(given, float)
    blocks = {
        "led": {
            "spectrum": led_payload["spectrum"],
            "spectrum_std": np.sqrt(led_std**2 + LED_GAP_SHARE * gap**2),
            "band": f"{led_payload.get('band', '±1σ')}, with {LED_GAP_SHARE:g} of the squared gap to the family "
            "estimate added",
            "warnings": led_warnings,
        },
        "prior": {
            **spectrum_fields(sequence, prior.spectrum, prior.spectrum_std),
            "warnings": list(prior.warnings),
        },
        "family": {
            **spectrum_fields(sequence, family.spectrum, family.spectrum_std),
            "warnings": list(family.warnings),
        },
    }
    for name, check in checks.items():
        label = {"led": "LEDs'", "prior": "light prior's", "family": f"family ({family.chosen.fit.name})"}[name]
        blocks[name]["miss_check"] = {
            "predicted_ratio_to_led_bound": check.predicted_ratio,
            "threshold": check.threshold,
            "warned": check.warned,
            "basis": check.basis,
        }
        if check.warned:
            blocks[name]["warnings"].append(check.message(label))
    return blocks, checks


@dataclass(frozen=True)
class _RouteInputs:
    """What a ``--model`` route reads (:data:`MODEL_ROUTES`; the fields as :func:`with_model_choice` takes them)."""

    sequence: Sequence
    stack: FrameStack | None
    requested: str
    varies: bool
    led_payload: dict
    reference: ReferencePatch | None
    """The reference patch or chart, measured from its crops (None: none given)."""
    flicker: FlickerCheck | None
    statistics: ChannelStatistics
    """One set of channel statistics for both models (the same, corrected alike), from the LED side's stream."""


def _prior_route(given: _RouteInputs) -> tuple[dict, str, str, dict]:
    """``--model prior``: the light prior, checked against the family evidence."""
    sequence, stack, flicker, statistics = given.sequence, given.stack, given.flicker, given.statistics
    result = estimate_sequence_prior(sequence, stack, flicker, statistics)
    prior = prior_payload(sequence, result)
    _, family = estimate_sequence_family(sequence, stack, result.prior, given.reference, flicker, statistics)
    models, _ = _models_block(sequence, given.led_payload, result.prior, family)
    replacement = {
        "spectrum": prior["prior"]["spectrum"],
        "spectrum_std": prior["prior"]["spectrum_std"],
        "band": "±1σ posterior of the light prior (pixel noise and the model's misfit)",
        "warnings": models["prior"]["warnings"],
    }
    extra = {"model_choice": prior["model_choice"], "prior": prior["prior"], "models": models}
    return extra, "prior", "asked for the light prior (--model prior)", replacement


def _family_route(given: _RouteInputs) -> tuple[dict, str, str, dict]:
    """``--model family`` and ``--model auto``: the family model's choice (auto: the LEDs' span unless the evidence
    says otherwise; a scene whose illuminant varies keeps the local LED model)."""
    sequence = given.sequence
    prior, family = estimate_sequence_family(
        sequence, given.stack, None, given.reference, given.flicker, given.statistics
    )
    block = family_payload(sequence, family)
    models, _ = _models_block(sequence, given.led_payload, prior, family)
    led_error = family.led.held_out_error_noise_removed
    choice = {
        "held_out_relative_error_noise_removed": {
            "led": led_error,
            family.chosen.fit.name: family.chosen.held_out_error_noise_removed,
        },
        "margin": AUTO_MARGIN,
        "noise_margin": AUTO_NOISE,
        "noise_share": family.led.noise_share,
    }
    if given.requested == "family":
        chosen, reason = family.chosen.fit.name, family.reason
    elif given.varies:
        chosen, reason = (
            "led",
            "the illuminant varies across the scene (the local LED model was chosen); the families are one global "
            "spectrum",
        )
    else:
        chosen, reason = family.auto_model, family.auto_reason
    replacement = {
        "spectrum": block["spectrum"],
        "spectrum_std": block["spectrum_std"],
        "band": "±1σ of the fitted family (tempered posterior) and the spread of the candidates that predict "
        "held-out pixels about as well",
        "warnings": models["family"]["warnings"],
        "led_warnings": models["led"]["warnings"],
    }
    return (
        {"model_choice": choice, "family": block, "prior": models["prior"], "models": models},
        chosen,
        reason,
        replacement,
    )


MODEL_ROUTES = {"prior": _prior_route, "family": _family_route, "auto": _family_route}
"""``--model`` name → its route: ``_RouteInputs → (fields, chosen, reason, replacement)``. ``replacement`` holds the
spectrum, band, band meaning and warnings that replace the LED ones when ``chosen`` is not ``led`` (``led`` itself
needs no route: it is :mod:`acquisition.session.analysis`'s estimate), and ``led_warnings``, the LED payload's
warnings with the families' check in place of the reference lights' when it is."""


def with_model_choice(
    sequence: Sequence,
    stack: FrameStack | None,
    payload: dict,
    requested: str,
    varies: bool,
    reference: ReferenceCrops | None = None,
    flicker: FlickerCheck | None = None,
    stream: EstimateStream | None = None,
) -> tuple[dict, str, str]:
    """The estimate payload of ``--model prior|family|auto``: the model estimated, the model chosen and why.

    ``prior`` takes the light prior; ``family`` the family model's choice (:mod:`processing.light_families`);
    ``auto`` keeps the LEDs' span unless a family predicts held-out pixels clearly better, and keeps a local LED
    estimate (a family is one global spectrum). The chosen model's spectrum, band and warnings replace the LED
    ones, which stay under ``led`` when another model wins. ``models`` holds every model's spectrum, band, warnings
    and miss check (predicted ratio to the LED bound against the family evidence, docs/light-families.md).
    ``reference``: the crops of a spectrally flat patch (``--reference-patch``) or of a chart's patches
    (``--reference-chart``), taken by ``stream`` as the frames passed (:class:`~acquisition.session.reference_crops.
    ReferenceCrops`), whose error joins the evidence and on which the family estimate is calibrated. ``flicker``: the
    LED side's flicker check; its gains correct the light models' statistics and the reference's as they corrected
    the LED estimate's (docs/flicker.md). ``stream``: the LED side's stream of the frames (:func:`led_side`), from
    whose block rows the light models' statistics are taken without a second pass (None: one is made here, fed
    ``stack`` or the files, and ``reference``).

    Returns
    -------
    dict, str, str
        The payload (docs/architecture.md §7), the chosen model and the reason.
    """
    stream = stream or light_model_stream(sequence, stack, references=reference)
    statistics = sequence_channel_statistics(sequence, stack, flicker=flicker, stream=stream)
    patch = None if reference is None else reference.patch(stream.layout().spec, flicker)
    given = _RouteInputs(sequence, stack, requested, varies, payload, patch, flicker, statistics)
    fields, chosen, reason, replacement = MODEL_ROUTES[requested](given)
    payload = dict(payload)
    payload.update({key: value for key, value in fields.items() if key != "model_choice"})
    payload["model"] = chosen
    payload["model_choice"] = {**fields["model_choice"], "model": chosen, "reason": reason, "requested": requested}
    if chosen == "led" and "led_warnings" in replacement:
        payload["warnings"] = replacement["led_warnings"]
        payload["spectrum_std"] = fields["models"]["led"]["spectrum_std"]
        payload["band"] = fields["models"]["led"]["band"]
    if chosen != "led":
        payload["led"] = {key: payload[key] for key in ("spectrum", "spectrum_std", "ambient_weights", "warnings")}
        payload["spectrum"] = replacement["spectrum"]
        payload["spectrum_std"] = payload["spectrum_std_noise"] = replacement["spectrum_std"]
        payload["band"] = replacement["band"]
        payload["miss_risk"] = payload["expected_ratio_to_led_bound"] = None
        payload["warnings"] = replacement["warnings"]
    return payload, chosen, reason
