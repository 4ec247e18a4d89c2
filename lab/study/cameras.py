"""Figs. 6–7 of the paper: camera invariance of the estimates, and the error over the xy grid.

Same noise-free protocol as Table 1 (:mod:`lab.study.table1`): the 110-surface chart, the
34 cameras, the feasible illuminants of the xy grid, the paper's LED subsets; one
:func:`lab.study.table1.evaluate_camera` job per camera.

``run_cameras`` (Fig. 6: "estimates become camera-invariant with ≥ 5 LEDs")
    For each LED count and illuminant, the max-normalised estimates of all cameras; the spread
    between cameras is the RMS over wavelengths of the per-wavelength standard deviation across
    cameras (``camera_spread``), averaged over illuminants. Also the mean spectrum RMSE and the
    worst camera's. The plot shows, for a few illuminants, every camera's estimate per LED count.

``run_xy`` (Fig. 7: error over the xy grid)
    For each feasible chromaticity and LED count: spectrum RMSE and xy error, means over cameras,
    and the direct-LED-fit bound; the plot maps them on the chromaticity diagram.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from msflash.lab.progress import Progress
from msflash.lab.study.illuminants import SmoothIlluminant
from msflash.lab.study.table1 import (
    MapFunction,
    direct_fit,
    evaluate_all_cameras,
    evaluate_camera,
)
from msflash.processing.metrics import spectrum_rmse
from msflash.processing.spectra import DEFAULT_GRID, WavelengthGrid


def _per_camera(
    n_leds_list: Sequence[int],
    method: str,
    alpha: float | str,
    cameras: Sequence[str] | int | None,
    illuminants: Sequence[SmoothIlluminant] | int | None,
    progress: Progress | None,
    map_function: MapFunction | None,
    grid: WavelengthGrid,
    label: str,
) -> dict[str, Any]:
    started = time.perf_counter()
    run = evaluate_all_cameras(
        n_leds_list,
        method,
        [alpha],
        "dimensionless",
        cameras,
        illuminants,
        progress,
        map_function,
        grid,
        label,
        started,
    )
    counts, subsets, names, chosen_illuminants = run.counts, run.subsets, run.names, run.illuminants
    truths, leds, results = run.truths, run.leds, run.results
    return {
        "counts": counts,
        "subsets": subsets,
        "names": names,
        "illuminants": chosen_illuminants,
        "truths": truths,
        "leds": leds,
        "started": started,
        # (n_cam, n_ill, n_sets)
        "spectrum_rmse": np.stack([r["spectrum_rmse"][:, :, 0] for r in results]),
        "xy_error": np.stack([r["xy_error"][:, :, 0] for r in results]),
        "estimates": np.stack([r["estimates"][:, :, 0] for r in results]),  # (n_cam, n_ill, n_sets, n_wl)
        "failed": np.stack([r["failed"][:, :, 0] for r in results]),
    }


def _evaluate_job(job: tuple) -> dict[str, np.ndarray]:
    return evaluate_camera(*job)


def camera_spread(estimates: np.ndarray) -> float:
    """RMS over wavelengths of the std across cameras of max-normalised estimates (n_cam, n_wl); NaN rows skipped."""
    rows = estimates[~np.any(np.isnan(estimates), axis=1)]
    if rows.shape[0] < 2:
        return float("nan")
    return float(np.sqrt(np.mean(rows.std(axis=0) ** 2)))


def run_cameras(
    n_leds_list: Sequence[int] = (3, 4, 5, 6, 7),
    method: str = "tikhonov",
    alpha: float | str = "auto",
    cameras: Sequence[str] | int | None = None,
    illuminants: Sequence[SmoothIlluminant] | int | None = None,
    plot_illuminants: int = 3,
    progress: Progress | None = None,
    map_function: MapFunction | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> dict[str, Any]:
    """Fig. 6: camera spread of the estimates per LED count (module notes). JSON-ready dict."""
    data = _per_camera(n_leds_list, method, alpha, cameras, illuminants, progress, map_function, grid, "cameras")
    estimates, counts, truths = data["estimates"], data["counts"], data["truths"]
    n_ill = truths.shape[1]
    spread = np.array([[camera_spread(estimates[:, i, s]) for s in range(len(counts))] for i in range(n_ill)])
    rmse = data["spectrum_rmse"]
    worst = np.nanmax(rmse, axis=0)  # (n_ill, n_sets)
    picks = np.unique(np.linspace(0, n_ill - 1, min(plot_illuminants, n_ill)).round().astype(int))
    return {
        "n_leds": counts,
        "camera_spread": np.nanmean(spread, axis=0).tolist(),
        "camera_spread_max": np.nanmax(spread, axis=0).tolist(),
        "spectrum_rmse": np.nanmean(rmse, axis=(0, 1)).tolist(),
        "spectrum_rmse_worst_camera": np.nanmean(worst, axis=0).tolist(),
        "per_illuminant_camera_spread": spread.tolist(),
        "examples": [
            {
                "xy": list(data["illuminants"][i].xy),
                "truth": (truths[:, i] / truths[:, i].max()).tolist(),
                "estimates": {str(n): estimates[:, i, s].tolist() for s, n in enumerate(counts)},
            }
            for i in picks
        ],
        "wavelengths_nm": grid.wavelengths_nm.tolist(),
        "failures": int(data["failed"].sum()),
        "definitions": {
            "camera_spread": "RMS over wavelengths of the standard deviation across cameras of the max-normalised "
            "estimates, mean over illuminants (camera_spread_max: worst illuminant)",
            "spectrum_rmse": "msflash.processing.metrics.spectrum_rmse, mean over cameras and illuminants",
            "spectrum_rmse_worst_camera": "the worst camera's spectrum RMSE per illuminant, mean over illuminants",
        },
        "config": {
            "method": method,
            "alpha": alpha,
            "cameras": data["names"],
            "n_cameras": len(data["names"]),
            "illuminants_xy": [list(ill.xy) for ill in data["illuminants"]],
            "grid": str(grid),
        },
        "elapsed_s": time.perf_counter() - data["started"],
    }


def run_xy(
    n_leds_list: Sequence[int] = (3, 4, 5, 6, 7),
    method: str = "tikhonov",
    alpha: float | str = "auto",
    cameras: Sequence[str] | int | None = None,
    illuminants: Sequence[SmoothIlluminant] | int | None = None,
    progress: Progress | None = None,
    map_function: MapFunction | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> dict[str, Any]:
    """Fig. 7: spectrum RMSE, xy error and the LED-fit bound at each feasible xy, per LED count."""
    data = _per_camera(n_leds_list, method, alpha, cameras, illuminants, progress, map_function, grid, "xy")
    truths, leds = data["truths"], data["leds"]
    bound = [
        [
            spectrum_rmse(direct_fit(truths[:, i], leds.values[:, subset], "nonneg"), truths[:, i])
            for subset in data["subsets"]
        ]
        for i in range(truths.shape[1])
    ]
    rmse = np.nanmean(data["spectrum_rmse"], axis=0)  # (n_ill, n_sets)
    return {
        "n_leds": data["counts"],
        "xy": [list(ill.xy) for ill in data["illuminants"]],
        "requested_xy": [list(ill.requested_xy) for ill in data["illuminants"]],
        "spectrum_rmse": rmse.tolist(),
        "spectrum_rmse_camera_std": np.nanstd(data["spectrum_rmse"], axis=0).tolist(),
        "xy_error": (np.nanmean(data["xy_error"], axis=0) * 100).tolist(),
        "bound": bound,
        "worst": [
            {
                "n_leds": n,
                "xy": list(data["illuminants"][int(np.nanargmax(rmse[:, s]))].xy),
                "spectrum_rmse": float(np.nanmax(rmse[:, s])),
            }
            for s, n in enumerate(data["counts"])
        ],
        "failures": int(data["failed"].sum()),
        "definitions": {
            "spectrum_rmse": "[illuminant][LED count]: processing.metrics.spectrum_rmse, mean over cameras",
            "xy_error": "[illuminant][LED count]: 100 x |Δxy|²/2 (Table 1's definition), mean over cameras",
            "bound": "[illuminant][LED count]: spectrum_rmse of the direct I w >= 0 LED fit of the truth",
        },
        "config": {
            "method": method,
            "alpha": alpha,
            "cameras": data["names"],
            "n_cameras": len(data["names"]),
            "grid": str(grid),
        },
        "elapsed_s": time.perf_counter() - data["started"],
    }
