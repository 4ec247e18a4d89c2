"""Where the ambient estimate fails, and whether its own reliability signals say so.

Protocol
--------
Noisy raw frames of the 110-surface chart (8-px patches, no border: 80 × 88 px, RGB) are rendered
(:mod:`lab.study.noisy`) and estimated as the app does (4 × 4 block sums, ``tikhonov`` with
GCV by default). From a baseline — 7 LEDs, all 110 surfaces, ambient-to-flash ratio 0.5 (the sim
rig's ``flash_to_ambient = 2``), exposure metered at 80 % of full scale on the brightest frame,
no saturation, all LEDs working, the ambient a named light, no motion — one factor at a time is
varied (:data:`FACTORS`). Each level is repeated over cameras × ambients × noise seeds.

Per estimate: the spectrum RMSE (:func:`processing.metrics.spectrum_rmse`), its excess over the
baseline estimate of the same camera, ambient and seed, and the signals of
:class:`processing.ambient.AmbientEstimate` — relative residual, condition number, the width of
the one-sigma band relative to the peak, the saturated fraction and whether ``warnings`` is
non-empty. An estimate :func:`processing.ambient.estimate_ambient` refuses (too few samples,
an empty LED image) counts as warned, with no error.

One extra signal not in the estimator, reported as a *proposal*: ``led_fill`` =
``min_k Σ f_k / sqrt(n · Σ f_k²)`` — the mean over the RMS of each LED-only image, ≈ 0.6–1 for an
LED that adds light everywhere and ≈ 0 for a frame where the LED did not fire (noise only).

Confusion: an estimate is *bad* when its error exceeds the same world's baseline by more than
``threshold`` (default 0.1, i.e. clearly worse than the noise and LED-span floor), or — second
table — when its error exceeds ``absolute_threshold`` (default 0.3).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from msflash.lab.progress import Progress, report_count
from msflash.lab.study.noisy import (
    World,
    app_estimate,
    make_world,
    refused_record,
    reliability,
    render_stack,
)
from msflash.lab.study.table1 import (
    MapFunction,
    direct_fit,
    flash_norm,
    led_subset_indices,
    select_cameras,
)
from msflash.processing import lights
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid

FACTORS: dict[str, dict[str, Any]] = {
    "n_leds": {"levels": [7, 6, 5, 4, 3], "label": "number of LEDs (paper subsets)"},
    "surfaces": {"levels": [110, 30, 10, 5, 3, 2, 1], "label": "distinct surfaces (drawn, the chart relabelled)"},
    "ambient_to_flash": {
        "levels": [0.5, 0.1, 2.0, 5.0, 10.0, 20.0, 50.0],
        "label": "ambient-to-flash ratio (mean camera signal, all LEDs at full drive)",
    },
    "exposure": {
        "levels": [1.0, 1 / 4, 1 / 16, 1 / 64, 1 / 256, 1 / 1024],
        "label": "exposure relative to the metered one (less light, more noise)",
    },
    "saturation": {
        "levels": [1.0, 1.5, 2.0, 4.0, 8.0, 16.0, 64.0],
        "label": "exposure relative to the metered one (over-exposure)",
    },
    "dead_led": {"levels": [-1, 0, 1, 2, 3, 4, 5, 6], "label": "LED that did not fire (index into the 7; -1: none)"},
    "line_400nm": {
        "levels": [0.0, 0.25, 0.5, 0.75, 0.95],
        "label": "fraction of the ambient's photons in a narrow line at 400 nm (below the LEDs)",
    },
    "line_570nm": {
        "levels": [0.0, 0.25, 0.5, 0.75, 0.95],
        "label": "fraction in a line at 570 nm (the gap between the 520 and 596 nm LEDs)",
    },
    "line_700nm": {"levels": [0.0, 0.25, 0.5, 0.75, 0.95], "label": "fraction in a line at 700 nm (above the LEDs)"},
    "motion": {"levels": [0, 1, 2, 4, 8], "label": "ambient frame shifted by this many pixels (patches are 8 px)"},
}
"""Factors and levels; the first level of each is the baseline."""

DEFAULT_CAMERAS = ("AptinaMT9M031", "Canon 50D", "Nikon D5100")
DEFAULT_AMBIENTS = ("tungsten", "fluorescent", "daylight")
LINE_WIDTH_NM = 5.0
"""Standard deviation of the narrow lines (a Gaussian; on the 10 nm grid it is essentially one sample)."""


def with_line(ambient: Spectra, centre_nm: float, fraction: float, grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """The ambient (photons) with ``fraction`` of its photons moved into a narrow line at ``centre_nm``."""
    photons = ambient.resample(grid).to_unit("photons")
    values = photons.values[:, 0] / photons.values[:, 0].sum()
    line = np.exp(-0.5 * ((grid.wavelengths_nm - centre_nm) / LINE_WIDTH_NM) ** 2)
    line = line / line.sum()
    return photons.replace(
        values=((1 - fraction) * values + fraction * line)[:, None],
        source=f"{photons.source} + {fraction:.0%} line at {centre_nm:g} nm",
    )


def relabelled(world_scene, n_surfaces: int, rng: np.random.Generator):  # noqa: ANN001, ANN201
    """The chart with every patch showing one of ``n_surfaces`` surfaces drawn without repetition."""
    from msflash.processing.scenes import Scene

    n_patches = world_scene.reflectances.count - 1  # the last surface is the (unused) border
    chosen = rng.choice(n_patches, size=n_surfaces, replace=False)
    mapping = np.concatenate([chosen[np.arange(n_patches) % n_surfaces], [n_patches]])
    return Scene(world_scene.reflectances, mapping[world_scene.labels])


def led_fill(statistics) -> float:  # noqa: ANN001
    """``min_k Σ f_k / sqrt(n Σ f_k²)``: ≈ 0 when an LED-only image is noise only (a dead LED)."""
    energy = np.sqrt(np.clip(np.diag(statistics.gram), 1e-300, None) * max(statistics.n_samples, 1))
    return float(np.min(statistics.led_sums / energy))


def _one(
    world: World,
    rng: np.random.Generator,
    truth: np.ndarray,
    method: str,
    alpha: float | str,
    bin_factor: int,
    motion_px: int = 0,
    dead_led: int | None = None,
) -> dict[str, Any]:
    ambient, frames, spec = render_stack(world, rng, motion_px=motion_px, dead_led=dead_led)
    statistics = accumulate_statistics(ambient, frames, spec, bin_factor=bin_factor, weighting=True)
    try:
        estimate = app_estimate(statistics, world, method, alpha)
    except (SolverError, SpectralDataError) as err:
        record = refused_record(str(err), statistics.saturated_fraction)
    else:
        record = reliability(estimate, truth)
    record["led_fill"] = led_fill(statistics) if statistics.n_samples > 0 else float("nan")
    record["bound"] = _bound(truth, world.leds.values)
    return record


def _bound(truth: np.ndarray, leds: np.ndarray) -> float:
    from msflash.processing.metrics import spectrum_rmse

    return spectrum_rmse(direct_fit(truth, leds, "nonneg"), truth)


def run_world(
    camera_name: str,
    camera: Spectra,
    ambient_name: str,
    ambient: Spectra,
    factors: dict[str, list[Any]],
    seeds: Sequence[int],
    method: str,
    alpha: float | str,
    bin_factor: int,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> list[dict[str, Any]]:
    """Every factor level × seed for one camera and ambient: a list of records (the unit of parallel work)."""
    records = []
    base_world = make_world(camera, ambient, grid=grid)
    base_truth = base_world.ambient.values[:, 0]
    baseline_error = {}
    for seed in seeds:
        rng = np.random.default_rng([seed, 0])
        baseline_error[seed] = _one(base_world, rng, base_truth, method, alpha, bin_factor)["error"]
    for factor, levels in factors.items():
        for level_index, level in enumerate(levels):
            for seed in seeds:
                rng = np.random.default_rng([seed, 1 + level_index, 7919 * (1 + list(FACTORS).index(factor))])
                world, truth = base_world, base_truth
                kw: dict[str, Any] = {}
                if factor == "n_leds":
                    world = make_world(camera, ambient, n_leds=int(level), grid=grid)
                elif factor == "surfaces":
                    scene = relabelled(base_world.scene, int(level), np.random.default_rng([seed, 99, int(level)]))
                    world = make_world(camera, ambient, scene=scene, grid=grid)
                elif factor == "ambient_to_flash":
                    world = make_world(camera, ambient, ambient_to_flash=float(level), grid=grid)
                elif factor in ("exposure", "saturation"):
                    world = make_world(camera, ambient, exposure_factor=float(level), grid=grid)
                elif factor == "dead_led":
                    kw = {"dead_led": None if int(level) < 0 else int(level)}
                elif factor.startswith("line_"):
                    centre = float(factor[5:-2])
                    world = make_world(camera, with_line(ambient, centre, float(level), grid), grid=grid)
                    truth = world.ambient.values[:, 0]
                elif factor == "motion":
                    kw = {"motion_px": int(level)}
                else:
                    raise SpectralDataError(
                        f"failure study: unknown factor '{factor}'; expected one of {', '.join(FACTORS)}"
                    )
                record = _one(world, rng, truth, method, alpha, bin_factor, **kw)
                record.update(
                    {
                        "factor": factor,
                        "level": level,
                        "seed": seed,
                        "camera": camera_name,
                        "ambient": ambient_name,
                        "baseline_error": baseline_error[seed],
                    }
                )
                record["excess"] = record["error"] - baseline_error[seed]
                records.append(record)
    return records


def _job(job: tuple) -> list[dict[str, Any]]:
    return run_world(*job)


def summarise(
    records: list[dict[str, Any]], factors: dict[str, list[Any]], threshold: float, absolute_threshold: float
) -> dict[str, Any]:
    """Per factor and level: error mean/std/p90, warning and flag rates, signal medians."""
    out: dict[str, Any] = {}
    for factor, levels in factors.items():
        rows = []
        for level in levels:
            group = [r for r in records if r["factor"] == factor and r["level"] == level]
            errors = np.array([r["error"] for r in group], dtype=float)
            excess = np.array([r["excess"] for r in group], dtype=float)
            finite = errors[np.isfinite(errors)]

            def median(key: str, group: list[dict[str, Any]] = group) -> float:
                values = np.array([r[key] for r in group if not r["refused"]], dtype=float)
                values = values[np.isfinite(values)]
                return float(np.median(values)) if values.size else float("nan")

            rows.append(
                {
                    "level": level,
                    "n": len(group),
                    "error_mean": float(finite.mean()) if finite.size else float("nan"),
                    "error_std": float(finite.std()) if finite.size else float("nan"),
                    "error_p90": float(np.percentile(finite, 90)) if finite.size else float("nan"),
                    "excess_mean": float(np.nanmean(excess)) if np.isfinite(excess).any() else float("nan"),
                    "bound_mean": float(np.mean([r["bound"] for r in group])),
                    "warned_rate": float(np.mean([r["warned"] for r in group])),
                    "refused": int(sum(r["refused"] for r in group)),
                    "flag_rates": {
                        flag: float(np.mean([r["flags"][flag] for r in group]))
                        for flag in ("condition", "residual", "saturation", "risk")
                    },
                    "relative_residual_median": median("relative_residual"),
                    "condition_number_median": median("condition_number"),
                    "band_ratio_median": median("band_ratio"),
                    "band_coverage_2sigma_median": median("band_coverage_2sigma"),
                    "saturated_fraction_median": median("saturated_fraction"),
                    "led_fill_median": median("led_fill"),
                    "led_fill_below_0.2_rate": float(np.mean([r["led_fill"] < 0.2 for r in group])),
                }
            )
        out[factor] = rows
    return out


def confusion(records: list[dict[str, Any]], key: str, threshold: float) -> dict[str, Any]:
    """Bad (``key`` > threshold, or refused) against warned, overall and per factor."""

    def table(group: list[dict[str, Any]]) -> dict[str, int]:
        counts = {"bad_warned": 0, "bad_silent": 0, "good_warned": 0, "good_silent": 0}
        for r in group:
            bad = r["refused"] or (math.isfinite(r[key]) and r[key] > threshold)
            counts[f"{'bad' if bad else 'good'}_{'warned' if r['warned'] else 'silent'}"] += 1
        return counts

    return {
        "threshold": threshold,
        "key": key,
        "all": table(records),
        "per_factor": {
            f: table([r for r in records if r["factor"] == f]) for f in dict.fromkeys(r["factor"] for r in records)
        },
    }


def run_failure(
    factors: Sequence[str] | dict[str, list[Any]] | None = None,
    cameras: Sequence[str] | int | None = DEFAULT_CAMERAS,
    ambients: Sequence[str] = DEFAULT_AMBIENTS,
    seeds: int | Sequence[int] = 2,
    method: str = "tikhonov",
    alpha: float | str = "auto",
    bin_factor: int = 4,
    threshold: float = 0.1,
    absolute_threshold: float = 0.3,
    keep_records: bool = True,
    progress: Progress | None = None,
    map_function: MapFunction | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> dict[str, Any]:
    """The failure study (module notes). Returns a JSON-ready dict: ``summary`` per factor and level,
    ``confusion`` (excess) and ``confusion_absolute``, ``missed`` (bad and silent cases), ``records``,
    ``config``, ``elapsed_s``."""
    started = time.perf_counter()
    if factors is None:
        chosen = {name: spec["levels"] for name, spec in FACTORS.items()}
    elif isinstance(factors, dict):
        chosen = {name: list(levels) for name, levels in factors.items()}
    else:
        chosen = {}
        for name in factors:
            if name not in FACTORS:
                raise SpectralDataError(f"failure study: unknown factor '{name}'; expected one of {', '.join(FACTORS)}")
            chosen[name] = FACTORS[name]["levels"]
    seed_list = list(range(seeds)) if isinstance(seeds, int) else list(seeds)
    camera_set = select_cameras(list(cameras) if isinstance(cameras, (list, tuple)) else cameras)
    jobs = [
        (
            cam,
            camera_set[cam],
            amb,
            lights.ambient_spectrum(amb, grid),
            chosen,
            seed_list,
            method,
            alpha,
            bin_factor,
            grid,
        )
        for cam in camera_set
        for amb in ambients
    ]
    mapper = map_function or (lambda function, items: map(function, items))
    records: list[dict[str, Any]] = []
    for done, result in enumerate(mapper(_job, jobs), start=1):
        records.extend(result)
        report_count(progress, "failure", done, len(jobs), "world", started)
    missed = [
        {
            k: r[k]
            for k in (
                "factor",
                "level",
                "camera",
                "ambient",
                "seed",
                "error",
                "excess",
                "relative_residual",
                "condition_number",
                "band_ratio",
                "led_fill",
            )
        }
        for r in records
        if not r["warned"] and math.isfinite(r["excess"]) and r["excess"] > threshold
    ]
    return {
        "factors": {
            name: {"levels": levels, "label": FACTORS.get(name, {}).get("label", name)}
            for name, levels in chosen.items()
        },
        "summary": summarise(records, chosen, threshold, absolute_threshold),
        "confusion": confusion(records, "excess", threshold),
        "confusion_absolute": confusion(records, "error", absolute_threshold),
        "missed": missed,
        "records": records if keep_records else None,
        "definitions": DEFINITIONS,
        "config": {
            "cameras": list(camera_set),
            "ambients": list(ambients),
            "seeds": seed_list,
            "method": method,
            "alpha": alpha,
            "bin_factor": bin_factor,
            "threshold": threshold,
            "absolute_threshold": absolute_threshold,
            "grid": str(grid),
            "scene": "chart110, 8-px patches, no border (80 x 88 px RGB)",
            "leds": list(flash_norm(grid).names),
            "n_led_subsets": {n: led_subset_indices(n) for n in (3, 4, 5, 6, 7)},
        },
        "elapsed_s": time.perf_counter() - started,
    }


DEFINITIONS = {
    "error": "msflash.processing.metrics.spectrum_rmse of the estimate against the true ambient (photons)",
    "excess": "error minus the baseline error of the same camera, ambient and noise seed",
    "bound": "spectrum_rmse of the best I w >= 0 fit of the true ambient with the LEDs in use",
    "warned": "AmbientEstimate.warnings non-empty, or estimate_ambient refused the input",
    "flags": "which of the estimator's warnings fired: condition > 1e6, relative residual > 0.1, "
    "saturated fraction > 0.5, one-sigma band > half the peak",
    "band_ratio": "max over wavelengths of spectrum_std / peak of the estimate",
    "band_coverage_2sigma": "fraction of wavelengths where |estimate − scaled truth| <= 2 spectrum_std (both / peak)",
    "led_fill": "proposed signal, not in the estimator: min over LEDs of sum(f_k) / sqrt(n sum(f_k^2))",
    "confusion": "bad = excess > threshold (or refused); warned as above",
}
