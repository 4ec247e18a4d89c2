"""``python -m tests.harness.warning_study``: the evidence behind each model's miss warning, cached per case.

For each harness case (rendered through the cache) one JSON record: the truth's LED bound and every model's true
ratio to it, the spectra each check can read (the LEDs', the prior's, the family's estimate and bands, every
candidate with its held-out evidence, the reduction's lift — what the camera and the LEDs can see of a spectrum),
and the same estimates from two disjoint halves of the folds of block rows (split-half consistency). Warning rules
are then evaluated offline on the records (:mod:`tests.harness.warning_rules`): choose on the **tuning** rows only.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from tests.harness import metrics
from tests.harness.family_study import case_inputs, evidence_spread, study_map, study_work
from tests.harness.render import HarnessCase

HALVES = ((0, 2, 4), (1, 3))
"""Two disjoint sets of the five folds of block rows: a light the pixels pin reads the same from either."""


def _fold_subset(statistics, folds: tuple[int, ...]):  # noqa: ANN001, ANN202 — ChannelStatistics in, same out
    from msflash.processing.channel_statistics import Moments

    keep = [f for f in folds if f < statistics.n_folds]

    def cut(moments: Moments | None) -> Moments | None:
        return None if moments is None else Moments(moments.ff[keep], moments.fa[keep], moments.aa[keep])

    return replace(
        statistics,
        moments=cut(statistics.moments),
        noise=cut(statistics.noise),
        counts=statistics.counts[keep],
        led_sums=statistics.led_sums[keep],
        ambient_sums=statistics.ambient_sums[keep],
    )


def _block_splits(stack, cfa: str | None) -> dict[str, tuple[np.ndarray, np.ndarray]]:  # noqa: ANN001
    """Pixel masks of two disjoint halves of the statistics' blocks, split by what the surfaces are: by the ambient
    block's colour (log R/B) and by its brightness, each at the median. A light the pixels pin reads the same from
    reddish and bluish surfaces, from dark and bright ones; folds of block rows share one mix of surfaces."""
    from msflash.acquisition.session import analysis
    from msflash.processing.block_sums import cfa_planes
    from msflash.processing.channel_statistics import plane_channels

    period = 2 if cfa else 1
    factor = analysis.block_factor(stack.ambient.shape, cfa)
    planes = cfa_planes(np.asarray(stack.ambient, float), period) - stack.spec.black_level
    names = plane_channels(cfa, planes.shape[2])
    bh, bw = planes.shape[0] // factor, planes.shape[1] // factor
    means = planes[: bh * factor, : bw * factor].reshape(bh, factor, bw, factor, -1).mean(axis=(1, 3))
    by = {c: means[..., [i for i, n in enumerate(names) if n == c]].mean(-1) for c in ("R", "G", "B")}
    floor = 1e-3 * max(float(means.max()), 1e-9)
    scores = {
        "colour": np.log(np.maximum(by["R"], floor) / np.maximum(by["B"], floor)),
        "brightness": by["R"] + by["G"] + by["B"],
    }
    side = factor * period
    out = {}
    for name, score in scores.items():
        upper = score >= np.median(score)
        pixels = np.zeros(stack.ambient.shape[:2], bool)
        pixels[: bh * side, : bw * side] = np.kron(upper, np.ones((side, side), bool))
        covered = np.zeros_like(pixels)
        covered[: bh * side, : bw * side] = True
        out[name] = (pixels, covered & ~pixels)
    return out


def _masked(stack, keep: np.ndarray):  # noqa: ANN001, ANN202 — a FrameStack with the other blocks saturated
    white = stack.spec.white_level

    def cut(frame: np.ndarray) -> np.ndarray:
        mask = keep if frame.ndim == 2 else keep[:, :, None]
        return np.where(mask, frame, np.asarray(white, dtype=frame.dtype))

    return replace(stack, ambient=cut(stack.ambient), led_frames=tuple(cut(f) for f in stack.led_frames))


def _list(values: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(values, float).ravel()]


def study_case(case: HarnessCase, cache: Path) -> dict:
    """The case's record (module notes); photons for the model's own spectra, ``unit`` converts to the sequence's."""
    from msflash.acquisition.session.analysis import estimate_sequence, stream_stack
    from msflash.acquisition.session.prior_route import sequence_channel_statistics
    from msflash.acquisition.session.sequence_spectra import (
        spectrum_in_sequence_unit,
    )
    from msflash.processing.light_families import (
        AVERAGE_TEMPERATURE,
        CHECK_TEMPERATURE,
        family_model,
        training_terms,
    )
    from msflash.processing.light_prior import plane_responsivities, prior_model
    from msflash.processing.spectral_data_term import scene_form

    truth, bound, sequence, leds, camera, stack = case_inputs(case, cache)
    statistics = sequence_channel_statistics(sequence, stack)
    led_estimate = estimate_sequence(sequence, "tikhonov", "auto", stream=stream_stack(sequence, stack))
    priors = prior_model(statistics.channels, leds, camera)
    prior = priors.estimate(statistics)
    model = family_model(statistics.channels, leds, camera)
    estimate = model.estimate(statistics, prior.spectrum.values[:, 0])
    unit = np.asarray(
        spectrum_in_sequence_unit(sequence, leds.replace(values=np.ones((leds.grid.size, 1)), names=("u",))), float
    )
    led_seq = np.asarray(spectrum_in_sequence_unit(sequence, led_estimate.spectrum), float)
    led_std = np.asarray(
        spectrum_in_sequence_unit(sequence, led_estimate.spectrum.replace(values=led_estimate.spectrum_std[:, None])),
        float,
    )
    family = estimate.spectrum.values[:, 0]
    auto_seq = led_seq if estimate.auto_model == "led" else family * unit
    spread, _ = evidence_spread(estimate.chosen, list(estimate.candidates), CHECK_TEMPERATURE)

    def ratio(spectrum_seq: np.ndarray) -> float:
        return float(metrics.rmse(spectrum_seq, truth.ambient) / bound) if np.any(spectrum_seq) else float("nan")

    record: dict = {
        "case": case.name,
        "split": case.split,
        "family": case.light_type,
        "cfa": case.cfa or "RGB",
        "bound": float(bound),
        "truth": _list(truth.ambient),
        "led_spd": np.asarray(truth.led_spd, float).tolist(),
        "unit": _list(unit),
        "wavelengths": _list(leds.grid.wavelengths_nm),
        "camera_planes": plane_responsivities(camera, statistics.channels).tolist(),
        "lift": model.reduction.lift.tolist(),
        "ratio": {
            "led": ratio(led_seq),
            "prior": ratio(prior.spectrum.values[:, 0] * unit),
            "family": ratio(family * unit),
            "auto": ratio(auto_seq),
        },
        "auto_model": estimate.auto_model,
        "led_seq": _list(led_seq),
        "led_std_seq": _list(led_std),
        "prior": _list(prior.spectrum.values[:, 0]),
        "prior_std": _list(prior.spectrum_std),
        "family_spectrum": _list(family),
        "family_std": _list(estimate.spectrum_std),
        "spread": _list(spread),
        "chosen": estimate.chosen.fit.name,
        "chosen_spectrum": _list(estimate.chosen.fit.spectrum),
        "relative_error": float(estimate.relative_error),
        "led_candidate": {
            "spectrum": _list(estimate.led.fit.spectrum),
            "evidence": estimate.led.evidence,
            "held_out": estimate.led.held_out_error,
            "noise_share": estimate.led.noise_share,
        },
        "candidates": [
            {
                "name": c.fit.name,
                "family": c.fit.family,
                "n_parameters": c.fit.n_parameters,
                "evidence": c.evidence,
                "held_out": c.held_out_error,
                "noise_share": c.noise_share,
                "spectrum": _list(c.fit.spectrum),
            }
            for c in estimate.candidates
        ],
        "halves": [],
    }
    # The cheap jackknife: every candidate's form kept, its amplitudes refitted without one fold (what the held-out
    # judgement computes anyway), averaged by the full evidence as the estimate is.
    scene = scene_form(statistics, model.reduction)
    record["amplitude_jackknife"] = []
    for complement in training_terms(scene).values():
        replicas = [
            c
            if c.fit.family == "prior"
            else replace(c, fit=replace(c.fit, amplitudes=complement.amplitudes(c.fit.atoms)[0]))
            for c in estimate.candidates
        ]
        chosen_replica = next(r for r, c in zip(replicas, estimate.candidates) if c is estimate.chosen)
        _, average = evidence_spread(chosen_replica, replicas, AVERAGE_TEMPERATURE)
        record["amplitude_jackknife"].append(_list(average))

    def reading(part: Callable[[], Any]) -> dict:
        """The prior's, the family model's and the LEDs' estimates from part of the statistics (an error recorded)."""
        try:
            statistics_part = part()
            part_prior = priors.estimate(statistics_part)
            part_estimate = model.estimate(statistics_part, part_prior.spectrum.values[:, 0])
        except Exception as error:  # noqa: BLE001 — a part that cannot be fitted is recorded, not a crash
            return {"error": str(error)}
        return {
            "prior": _list(part_prior.spectrum.values[:, 0]),
            "family": _list(part_estimate.spectrum.values[:, 0]),
            "chosen": part_estimate.chosen.fit.name,
            "auto_model": part_estimate.auto_model,
            "led": _list(part_estimate.led.fit.spectrum),
        }

    folds = range(statistics.n_folds)
    record["jackknife"] = [
        reading(lambda left_out=left_out: _fold_subset(statistics, tuple(f for f in folds if f != left_out)))
        for left_out in folds
    ]
    record["surface_halves"] = {
        split: [
            reading(lambda keep=keep: sequence_channel_statistics(sequence, _masked(stack, keep))) for keep in masks
        ]
        for split, masks in _block_splits(stack, sequence.camera.cfa).items()
    }
    record["halves"] = [reading(lambda half=half: _fold_subset(statistics, half)) for half in HALVES]
    return record


def _one(arguments: tuple[HarnessCase, Path]) -> dict:
    try:
        return study_case(*arguments)
    except Exception as error:  # noqa: BLE001 — a failing case is a record, not a crash
        return {"case": arguments[0].name, "error": f"{type(error).__name__}: {error}"}


def main(argv: list[str] | None = None) -> int:
    """Run the study; 0 on success."""
    args, work = study_work("python -m tests.harness.warning_study", "library", argv)
    records = study_map(_one, work, args.jobs)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(records))
    failed = [r for r in records if "error" in r]
    print(f"{len(records)} cases ({len(failed)} failed) → {args.out}", file=sys.stderr)
    for record in failed[:5]:
        print(f"  {record['case']}: {record['error']}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
