"""Fig. 5 of the paper: estimation error vs the number of distinct surfaces in the scene.

Protocol (paper Section 5, the authors' ``s_evalNatural100NumPatches.m``): for each count in
1, 3, 5, 7, 9, 20, 30, draw that many surfaces of the 110-patch chart *with repetition*
(``randi(110, [n, 1])``), 10 draws each; estimate the ambient from those surfaces only (7 LEDs)
and report the spectrum RMSE (:func:`processing.metrics.spectrum_rmse`). The bound is the same
metric for the direct non-negative LED fit of the true spectrum. Images are normalised on the
whole chart before the draw, as the authors do.

The authors evaluated one illuminant (xy = (2/9, 2/9)), one camera (their third, a Canon
1D Mark III) and α = 0.06 of their eq. 6; by default we average over every feasible illuminant
and every camera, and the draws are shared by all of them (as the authors share a draw across
their loops). Pass ``illuminants``/``cameras`` to narrow it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from msflash.lab.progress import Progress, report_count
from msflash.lab.study.illuminants import SmoothIlluminant
from msflash.lab.study.table1 import (
    MapFunction,
    direct_fit,
    evaluate_camera,
    flash_norm,
    led_subset_indices,
    select_cameras,
    select_illuminants,
    transfer_matrix,
)
from msflash.processing import datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.metrics import spectrum_rmse
from msflash.processing.spectra import DEFAULT_GRID, WavelengthGrid

PAPER_SURFACE_COUNTS = (1, 3, 5, 7, 9, 20, 30)
"""Numbers of distinct surfaces of the paper's Fig. 5 (``[1:2:10, 20, 30]``)."""

PAPER_DRAWS = 10
"""Random draws per count."""


def draw_surfaces(counts: Sequence[int], draws: int, n_surfaces: int, seed: int) -> list[list[np.ndarray]]:
    """``draws`` index sets per count, drawn uniformly with repetition: ``[count][draw] -> indices``."""
    rng = np.random.default_rng(seed)
    return [[rng.integers(0, n_surfaces, size=count) for _ in range(draws)] for count in counts]


def run_surfaces(
    counts: Sequence[int] = PAPER_SURFACE_COUNTS,
    draws: int = PAPER_DRAWS,
    n_leds: int = 7,
    method: str = "tikhonov",
    alpha: float | str = "auto",
    cameras: Sequence[str] | int | None = None,
    illuminants: Sequence[SmoothIlluminant] | int | None = None,
    alpha_units: str = "dimensionless",
    seed: int = 0,
    progress: Progress | None = None,
    map_function: MapFunction | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> dict[str, Any]:
    """Spectrum RMSE (and pixel RMSE) vs number of distinct surfaces (paper Fig. 5).

    Parameters are those of :func:`lab.study.table1.run_table1` plus ``counts``,
    ``draws`` and ``seed`` (the draws are reproducible).

    Returns
    -------
    dict
        JSON-ready: ``counts``; ``spectrum_rmse`` (mean over draws of the mean over cameras and
        illuminants), ``spectrum_rmse_std`` (standard deviation over draws), ``pixel_rmse``
        (× 100), ``bound`` (the direct LED fit's spectrum RMSE, a horizontal line),
        ``failures`` per count (estimates refused or failed, left out), ``config``,
        ``elapsed_s``.
    """
    started = time.perf_counter()
    counts = [int(c) for c in counts]
    if not counts or min(counts) < 1 or draws < 1:
        raise SpectralDataError(f"surfaces study: counts {counts}, draws {draws}; expected counts ≥ 1 and draws ≥ 1")
    subset = led_subset_indices(n_leds)
    chosen_cameras = select_cameras(cameras)
    chosen_illuminants = select_illuminants(illuminants, grid)
    leds = flash_norm(grid)
    chart = datasets.chart110().resample(grid)
    truths = np.column_stack([ill.spectrum.values[:, 0] for ill in chosen_illuminants])
    drawn = draw_surfaces(counts, draws, chart.count, seed)
    flat = [indices for per_count in drawn for indices in per_count]  # count-major

    names = list(chosen_cameras)
    jobs = [
        (
            transfer_matrix(chart, chosen_cameras[name]),
            leds.values,
            truths,
            [subset],
            method,
            [alpha],
            alpha_units,
            grid,
            flat,
        )
        for name in names
    ]
    mapper = map_function or (lambda function, items: map(function, items))
    results = []
    for done, result in enumerate(mapper(_evaluate_job, jobs), start=1):
        results.append(result)
        report_count(progress, "surfaces", done, len(names), "camera", started)

    # (n_cam, n_ill, 1, 1, n_counts·draws) → (n_counts, draws, n_cam·n_ill)
    def arrange(name: str) -> np.ndarray:
        values = np.stack([r[name][:, 0, 0, :] for r in results])  # (n_cam, n_ill, n_draws_total)
        return values.reshape(-1, len(counts), draws).transpose(1, 2, 0)

    spectrum = arrange("spectrum_rmse")
    pixel = arrange("pixel_rmse")
    failed = arrange("failed")
    per_draw = _nanmean(spectrum, axis=2)  # (n_counts, draws)
    bound = float(
        np.mean(
            [
                spectrum_rmse(direct_fit(truths[:, i], leds.values[:, subset], "nonneg"), truths[:, i])
                for i in range(truths.shape[1])
            ]
        )
    )
    return {
        "counts": counts,
        "spectrum_rmse": _nanmean(per_draw, axis=1).tolist(),
        "spectrum_rmse_std": _nanstd(per_draw, axis=1).tolist(),
        "spectrum_rmse_per_draw": per_draw.tolist(),
        "pixel_rmse": (_nanmean(pixel, axis=(1, 2)) * 100).tolist(),
        "bound": bound,
        "failures": failed.sum(axis=(1, 2)).astype(int).tolist(),
        "estimates_per_count": int(failed.shape[1] * failed.shape[2]),
        "definitions": {
            "spectrum_rmse": "msflash.processing.metrics.spectrum_rmse, mean over cameras × illuminants per draw, "
            "then mean (and std) over draws",
            "pixel_rmse": "100 × RMSE of a − Σ w f over the drawn surfaces (images divided by the stack maximum "
            "of the whole chart)",
            "bound": "spectrum_rmse of the direct I w ≥ 0 LED fit of the true spectrum, mean over illuminants",
            "failures": "estimates refused or failed (e.g. one surface gives 3 values for 7 LEDs, which "
            "estimate_ambient refuses); left out of the means, NaN when all failed",
        },
        "config": {
            "n_leds": n_leds,
            "draws": draws,
            "seed": seed,
            "method": method,
            "alpha": alpha,
            "alpha_units": alpha_units,
            "cameras": names,
            "n_cameras": len(names),
            "illuminants_xy": [list(ill.xy) for ill in chosen_illuminants],
            "grid": str(grid),
        },
        "elapsed_s": time.perf_counter() - started,
    }


def _nanmean(values: np.ndarray, axis: int | tuple[int, ...]) -> np.ndarray:
    """Mean ignoring NaN; NaN (without a warning) where everything is NaN."""
    valid = ~np.isnan(values)
    count = valid.sum(axis=axis)
    total = np.where(valid, values, 0.0).sum(axis=axis)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _nanstd(values: np.ndarray, axis: int) -> np.ndarray:
    mean = _nanmean(values, axis)
    return np.sqrt(_nanmean((values - np.expand_dims(mean, axis)) ** 2, axis))


def _evaluate_job(job: tuple) -> dict[str, np.ndarray]:
    return evaluate_camera(*job)
