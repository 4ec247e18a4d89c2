"""``python -m tests.harness.family_study``: every candidate of the family model on harness cases, in-process.

For each case (rendered through the cache), the family model's candidates — each form, the LEDs' span and
the light prior — with their held-out evidence and their true ratio to the LED bound, one CSV row per case
and candidate. What the family model's rules (:mod:`processing.light_families`) were chosen on: the
**tuning** rows of the physics and library suites only.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from tests.harness import metrics
from tests.harness.cases import select_cases
from tests.harness.physics_cases import select_physics_cases
from tests.harness.render import HarnessCase
from tests.harness.run import CACHE_ENV, cached_render

BAND_SCALES = (0.5, 1.0, 2.0, 4.0)
TEMPERATURES = (0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.5)


def _paper_rmse(estimate: np.ndarray, truth: np.ndarray) -> float:
    return metrics.rmse(estimate, truth) if np.any(estimate) and np.any(truth) else float("nan")


def evidence_spread(
    chosen: Any, candidates: list[Any], temperature: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """``(spread, average)``: the light families' evidence-weighted spread of ``candidates`` about ``chosen`` and
    their weighted mean, each scaled onto the chosen one, at ``temperature`` (the estimate's own computation)."""
    from msflash.processing.light_families import _scaled_spectra, _weighted_spread

    return _weighted_spread(chosen.fit.spectrum, candidates, _scaled_spectra(chosen, candidates), temperature)


def case_inputs(case: HarnessCase, cache: Path) -> tuple[Any, float, Any, Any, Any, Any]:
    """A case's rendering (cached), its truth's LED bound, its sequence, LED spectra and camera (photons) and frames."""
    from msflash.acquisition.sequence.reader import read_sequence
    from msflash.acquisition.session.analysis import load_frame_stack
    from msflash.acquisition.session.sequence_spectra import camera_responsivities_photons, led_spectra_photons

    truth = cached_render(case, cache)
    sequence = read_sequence(truth.directory)
    bound = metrics.led_bound(truth.led_spd, truth.ambient)
    leds, camera = led_spectra_photons(sequence), camera_responsivities_photons(sequence)
    return truth, bound, sequence, leds, camera, load_frame_stack(sequence)


def study_case(case: HarnessCase, cache: Path) -> tuple[list[dict], dict]:
    """One row per candidate of ``case``, and one row for the case (band coverages, warning features)."""
    from msflash.acquisition.session.analysis import estimate_sequence, stream_stack
    from msflash.acquisition.session.prior_route import sequence_channel_statistics
    from msflash.acquisition.session.sequence_spectra import (
        spectrum_in_sequence_unit,
    )
    from msflash.processing.light_families import family_model
    from msflash.processing.light_prior import prior_model
    from msflash.processing.spectral_data_term import scene_form

    truth, bound, sequence, leds, camera, stack = case_inputs(case, cache)
    clock = time.perf_counter()
    statistics = sequence_channel_statistics(sequence, stack)
    seconds = {"statistics": time.perf_counter() - clock}
    clock = time.perf_counter()
    led_estimate = estimate_sequence(sequence, "tikhonov", "auto", stream=stream_stack(sequence, stack))
    seconds["led"] = time.perf_counter() - clock
    clock = time.perf_counter()
    prior = prior_model(statistics.channels, leds, camera).estimate(statistics)
    seconds["prior"] = time.perf_counter() - clock
    clock = time.perf_counter()
    model = family_model(statistics.channels, leds, camera)
    estimate = model.estimate(statistics, prior.spectrum.values[:, 0])
    seconds["family"] = time.perf_counter() - clock
    rows: list[dict] = []

    def in_unit(values: np.ndarray) -> np.ndarray:
        return np.asarray(
            spectrum_in_sequence_unit(sequence, leds.replace(values=np.asarray(values)[:, None], names=("ambient",))),
            float,
        )

    truth_ambient = truth.ambient
    chosen = estimate.chosen
    scene = scene_form(statistics, model.reduction)
    problem = scene.whitened(list(range(scene.n_folds)))
    own = model.posterior_std(chosen, problem, statistics.n_blocks * statistics.n_channels)
    family_spectrum = in_unit(estimate.spectrum.values[:, 0])  # what msflash reports (the evidence average)
    led_spectrum = np.asarray(
        spectrum_in_sequence_unit(sequence, led_estimate.spectrum), float
    )  # what msflash estimate gives (weighted statistics)
    prior_spectrum = in_unit(prior.spectrum.values[:, 0])
    auto_model = estimate.auto_model
    auto_spectrum = led_spectrum if auto_model == "led" else family_spectrum
    case_row: dict = {
        "case": case.name,
        "split": case.split,
        "family": case.light_type,
        "cfa": case.cfa or "RGB",
        "bound": bound,
        "chosen": chosen.fit.name,
        "auto": auto_model,
        **{f"t:{key}": value for key, value in seconds.items()},
    }
    for name, spectrum in (
        ("led", led_spectrum),
        ("prior", prior_spectrum),
        ("family", family_spectrum),
        ("auto", auto_spectrum),
    ):
        case_row[f"{name}:ratio"] = _paper_rmse(spectrum, truth_ambient) / bound
    for temperature in TEMPERATURES:
        spread, average = evidence_spread(chosen, list(estimate.candidates), temperature)
        spread_unit, average_unit = in_unit(spread), in_unit(average)
        case_row[f"average:ratio:{temperature}"] = _paper_rmse(average_unit, truth_ambient) / bound
        for scale in BAND_SCALES:
            std = np.sqrt((scale * in_unit(own)) ** 2 + spread_unit**2)
            cover = metrics.band_coverage(family_spectrum, std, truth_ambient)
            case_row[f"cov1:{scale}:{temperature}"], case_row[f"cov2:{scale}:{temperature}"] = cover
        # Warning features: each model's distance from the evidence proxies, over the proxy's LED bound.
        peak = float(np.max(np.abs(family_spectrum))) or 1.0
        for proxy_name, proxy in (("chosen", family_spectrum), ("average", average_unit)):
            proxy_bound = metrics.led_bound(truth.led_spd, proxy)
            for name, spectrum in (
                ("led", led_spectrum),
                ("prior", prior_spectrum),
                ("family", family_spectrum),
                ("auto", auto_spectrum),
            ):
                case_row[f"d:{name}:{proxy_name}:{temperature}"] = _paper_rmse(spectrum, proxy) / proxy_bound
            case_row[f"spread:{proxy_name}:{temperature}"] = (
                float(np.sqrt(np.mean((spread_unit / peak) ** 2))) / proxy_bound
            )
        case_row[f"own:{temperature}"] = float(np.sqrt(np.mean((in_unit(own) / peak) ** 2)))
    led_std = np.asarray(
        spectrum_in_sequence_unit(sequence, led_estimate.spectrum.replace(values=led_estimate.spectrum_std[:, None])),
        float,
    )
    gap = led_spectrum - family_spectrum * float(family_spectrum @ led_spectrum) / float(
        family_spectrum @ family_spectrum
    )
    for gamma in (0.0, 0.25, 0.5, 1.0):
        case_row[f"led_cov:{gamma}"] = metrics.band_coverage(
            led_spectrum, np.sqrt(led_std**2 + gamma * gap**2), truth_ambient
        )
    # Evidence features of the family model's own miss risk: its estimate's LED bound and the LEDs' span's noise share.
    case_row["family_bound"] = float(metrics.led_bound(truth.led_spd, family_spectrum))
    case_row["led_held_out"] = estimate.led.held_out_error
    case_row["led_held_out_clean"] = estimate.led.held_out_error_noise_removed
    case_row["chosen_held_out_clean"] = chosen.held_out_error_noise_removed
    case_row["prior_band"] = float(
        np.sqrt(np.mean((in_unit(prior.spectrum_std) / max(float(np.max(prior_spectrum)), 1e-300)) ** 2))
    )
    case_row["prior_cov"] = metrics.band_coverage(prior_spectrum, in_unit(prior.spectrum_std), truth_ambient)
    for candidate in (estimate.led, *estimate.candidates):
        spectrum = np.asarray(
            spectrum_in_sequence_unit(
                sequence, leds.replace(values=candidate.fit.spectrum[:, None], names=("ambient",))
            ),
            float,
        )
        ratio = metrics.rmse(spectrum, truth.ambient) / bound if np.any(spectrum) else float("nan")
        rows.append(
            {
                "case": case.name,
                "split": case.split,
                "family": case.light_type,
                "cfa": case.cfa or "RGB",
                "bound": f"{bound:.4g}",
                "candidate": candidate.fit.name,
                "candidate_family": candidate.fit.family,
                "n_parameters": candidate.fit.n_parameters,
                "held_out": f"{candidate.held_out_error:.6g}",
                "held_out_clean": f"{candidate.held_out_error_noise_removed:.6g}",
                "objective": f"{candidate.fit.objective:.6g}",
                "seconds": f"{candidate.fit.seconds:.5f}",
                "ratio": f"{ratio:.4g}",
                "chosen": int(candidate is estimate.chosen),
                "auto": int(
                    (estimate.auto_model == "led" and candidate is estimate.led)
                    or (estimate.auto_model == candidate.fit.name and candidate is estimate.chosen)
                ),
            }
        )
    return rows, case_row


def _one(arguments: tuple[HarnessCase, Path]) -> tuple[list[dict], dict]:
    try:
        return study_case(*arguments)
    except Exception as error:  # noqa: BLE001 — a failing case is a row, not a crash
        failed = {"case": arguments[0].name, "candidate": "error", "ratio": f"{type(error).__name__}: {error}"}
        return [failed], {"case": arguments[0].name, "error": str(error)}


def study_work(
    prog: str, suite: str, argv: list[str] | None
) -> tuple[argparse.Namespace, list[tuple[HarnessCase, Path]]]:
    """A study's command line (``--suite``, ``--split``, ``--quick``, ``--jobs``, ``--cache``, ``--out``) and its
    cases, each with the cache folder (made, and named to the workers through the environment)."""
    parser = argparse.ArgumentParser(prog=prog)
    parser.add_argument("--suite", choices=("library", "physics"), default=suite)
    parser.add_argument("--split", choices=("tuning", "held_out", "both"), default="tuning")
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--jobs", type=int, default=1)
    parser.add_argument("--cache", type=Path, default=Path(".harness-cache"))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    cases = (select_physics_cases if args.suite == "physics" else select_cases)(args.split, args.quick)
    os.environ[CACHE_ENV] = str(args.cache.resolve())
    args.cache.mkdir(parents=True, exist_ok=True)
    return args, [(case, args.cache.resolve()) for case in cases]


def study_map(one: Callable[[Any], Any], work: list[Any], jobs: int) -> list[Any]:
    """``one`` over the work, in ``jobs`` worker processes when more than one."""
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(jobs) as pool:
            return list(pool.map(one, work, chunksize=1))
    return [one(w) for w in work]


def main(argv: list[str] | None = None) -> int:
    """Run the study; 0 on success."""
    args, work = study_work("python -m tests.harness.family_study", "physics", argv)
    results = study_map(_one, work, args.jobs)
    rows = [row for result in results for row in result[0]]
    fields = list(dict.fromkeys(key for row in rows for key in row))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with args.out.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fields)
        writer.writeheader()
        writer.writerows(rows)
    case_rows = [result[1] for result in results]
    with args.out.with_suffix(".cases.json").open("w") as handle:
        json.dump(case_rows, handle, default=float)
    print(f"{len(work)} cases, {len(rows)} rows → {args.out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
