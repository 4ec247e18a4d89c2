"""Accuracy against time: each solver × pixel-subsampling level, and the Pareto front.

Protocol
--------
Noisy raw frames (:mod:`lab.study.noisy`) of the 110-surface chart with 40-px patches and a
4-px dark border (444 × 488 px ≈ 2.2·10⁵ pixels, RGB), 7 LEDs, the baseline of the failure study
(ambient-to-flash 0.5, metered exposure) — or a noisier one with ``ambient_to_flash``. For each
camera × ambient × seed the frames are rendered once; then every *sampling* level builds the
statistics and every *solver* estimates from them:

Sampling (:data:`SAMPLINGS`)
    ``all`` every pixel; ``mask_1e5`` / ``mask_1e4`` / ``mask_1e3`` that many random pixels via
    ``accumulate_statistics(sample_mask=…)`` (which still reads every pixel);
    ``gather_1e4`` / ``gather_1e3`` the same pixels copied out first (what a subsampling reader
    would cost); ``bin2`` / ``bin4`` / ``bin8`` block sums (``bin4`` is the app's
    ``DEFAULT_BIN_FACTOR``); ``patch_means`` per-surface means (needs the labels — a chart only).
Solvers (:data:`SOLVERS`)
    ``lstsq``, ``nonneg``, ``tikhonov`` with GCV (``auto``, the app default) and fixed α = 3e-4
    (best on the noise-free Table-1 protocol), ``roughness`` with α = 0.01.

Time is the wall time of building the statistics (median over repeats) plus the solver's (median),
measured in the worker; it is a study output, sensitive to machine load, not a guarantee.
Accuracy is the mean :func:`processing.metrics.spectrum_rmse` over the worlds.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from msflash.lab.progress import Progress, report_count
from msflash.lab.study.noisy import make_world, patch_mean_frames, render_stack
from msflash.lab.study.table1 import MapFunction, select_cameras
from msflash.processing import lights
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import estimate_ambient
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.metrics import spectrum_rmse
from msflash.processing.scenes import chart_scene
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid

SOLVERS: dict[str, tuple[str, float | str]] = {
    "lstsq": ("lstsq", 0.0),
    "nonneg": ("nonneg", 0.0),
    "tikhonov_auto": ("tikhonov", "auto"),
    "tikhonov_3e-4": ("tikhonov", 3e-4),
    "roughness_0.01": ("roughness", 0.01),
}
"""Solver labels → (method, alpha)."""

SAMPLINGS = (
    "all",
    "mask_1e5",
    "mask_1e4",
    "mask_1e3",
    "gather_1e4",
    "gather_1e3",
    "bin2",
    "bin4",
    "bin8",
    "patch_means",
)
"""Pixel-subsampling levels."""

DEFAULT_CHOICE = ("tikhonov_auto", "bin4")
"""The app's default: tikhonov with GCV on 4 × 4 block sums."""

DEFAULT_CAMERAS = ("AptinaMT9M031", "Canon 50D", "Nikon D5100")
DEFAULT_AMBIENTS = ("tungsten", "fluorescent", "daylight")


def _statistics(sampling: str, ambient: np.ndarray, frames: list[np.ndarray], spec, scene, rng: np.random.Generator):  # noqa: ANN001, ANN202
    """(statistics, seconds) for one sampling level."""
    height, width = ambient.shape[:2]
    if sampling.startswith(("mask_", "gather_")):
        count = int(float(sampling.split("_")[1]))
        if count >= height * width:
            raise SpectralDataError(f"pareto: {count} samples from a {height}x{width} frame; expected fewer")
        chosen = rng.choice(height * width, size=count, replace=False)
        if sampling.startswith("mask_"):
            mask = np.zeros(height * width, dtype=bool)
            mask[chosen] = True
            mask = mask.reshape(height, width)
            started = time.perf_counter()
            statistics = accumulate_statistics(ambient, frames, spec, sample_mask=mask)
            return statistics, time.perf_counter() - started
        started = time.perf_counter()
        rows, columns = np.unravel_index(np.sort(chosen), (height, width))
        gathered = [frame[rows, columns][:, None] for frame in (ambient, *frames)]
        statistics = accumulate_statistics(gathered[0], gathered[1:], spec)
        return statistics, time.perf_counter() - started
    if sampling == "all":
        started = time.perf_counter()
        return accumulate_statistics(ambient, frames, spec), time.perf_counter() - started
    if sampling.startswith("bin"):
        factor = int(sampling[3:])
        started = time.perf_counter()
        return accumulate_statistics(ambient, frames, spec, bin_factor=factor), time.perf_counter() - started
    if sampling == "patch_means":
        started = time.perf_counter()
        mean_ambient, mean_frames = patch_mean_frames(scene, ambient, frames, spec.white_level)
        statistics = accumulate_statistics(mean_ambient, mean_frames, spec)
        return statistics, time.perf_counter() - started
    raise SpectralDataError(f"pareto: sampling '{sampling}'; expected one of {', '.join(SAMPLINGS)}")


def run_pareto_world(
    camera: Spectra,
    ambient: Spectra,
    seeds: Sequence[int],
    samplings: Sequence[str],
    solvers: Sequence[str],
    patch_px: int,
    ambient_to_flash: float,
    repeats: int,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> dict[str, Any]:
    """Errors (n_seeds, n_samplings, n_solvers) and times (statistics, solver) for one camera and ambient."""
    scene = chart_scene("chart110", patch_px=patch_px, border_px=4)
    world = make_world(camera, ambient, scene=scene, ambient_to_flash=ambient_to_flash, grid=grid)
    truth = world.ambient.values[:, 0]
    shape = (len(seeds), len(samplings), len(solvers))
    errors = np.full(shape, np.nan)
    solve_s = np.full(shape, np.nan)
    stats_s = np.full(shape[:2], np.nan)
    for i, seed in enumerate(seeds):
        ambient_frame, frames, spec = render_stack(world, np.random.default_rng([seed, 17]))
        for j, sampling in enumerate(samplings):
            timings = []
            for _ in range(max(repeats, 1)):
                statistics, seconds = _statistics(
                    sampling, ambient_frame, frames, spec, world.scene, np.random.default_rng([seed, 23, j])
                )
                timings.append(seconds)
            stats_s[i, j] = float(np.median(timings))
            for s, label in enumerate(solvers):
                method, alpha = SOLVERS[label]
                timings = []
                try:
                    for _ in range(max(repeats, 1)):
                        started = time.perf_counter()
                        estimate = estimate_ambient(statistics, world.leds, method, alpha)
                        timings.append(time.perf_counter() - started)
                except (SolverError, SpectralDataError):
                    continue
                solve_s[i, j, s] = float(np.median(timings))
                errors[i, j, s] = spectrum_rmse(estimate.spectrum.values[:, 0], truth)
    return {"errors": errors, "solve_s": solve_s, "stats_s": stats_s, "pixels": int(scene.labels.size)}


def _job(job: tuple) -> dict[str, Any]:
    return run_pareto_world(*job)


def pareto_front(errors: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Boolean mask of the points no other point beats in both error and time (NaN points excluded)."""
    shape = np.shape(errors)
    errors, times = np.ravel(errors), np.ravel(times)
    ok = np.isfinite(errors) & np.isfinite(times)
    front = np.zeros(errors.shape, dtype=bool)
    for index in np.flatnonzero(ok):
        dominated = (
            ok
            & (errors <= errors[index])
            & (times <= times[index])
            & ((errors < errors[index]) | (times < times[index]))
        )
        front[index] = not dominated.any()
    return front.reshape(shape)


def run_pareto(
    cameras: Sequence[str] | int | None = DEFAULT_CAMERAS,
    ambients: Sequence[str] = DEFAULT_AMBIENTS,
    seeds: int | Sequence[int] = 2,
    samplings: Sequence[str] = SAMPLINGS,
    solvers: Sequence[str] = tuple(SOLVERS),
    patch_px: int = 40,
    ambient_to_flash: float = 0.5,
    repeats: int = 3,
    progress: Progress | None = None,
    map_function: MapFunction | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> dict[str, Any]:
    """The Pareto study (module notes). JSON-ready: one point per solver × sampling with mean/std error,
    median time, ``on_front``; ``front`` (sorted by time), ``default`` and whether it is on the front."""
    started = time.perf_counter()
    for label in solvers:
        if label not in SOLVERS:
            raise SpectralDataError(f"pareto: solver '{label}'; expected one of {', '.join(SOLVERS)}")
    for label in samplings:
        if label not in SAMPLINGS:
            raise SpectralDataError(f"pareto: sampling '{label}'; expected one of {', '.join(SAMPLINGS)}")
    seed_list = list(range(seeds)) if isinstance(seeds, int) else list(seeds)
    camera_set = select_cameras(list(cameras) if isinstance(cameras, (list, tuple)) else cameras)
    jobs = [
        (
            camera_set[cam],
            lights.ambient_spectrum(amb, grid),
            seed_list,
            list(samplings),
            list(solvers),
            patch_px,
            ambient_to_flash,
            repeats,
            grid,
        )
        for cam in camera_set
        for amb in ambients
    ]
    mapper = map_function or (lambda function, items: map(function, items))
    results = []
    for done, result in enumerate(mapper(_job, jobs), start=1):
        results.append(result)
        report_count(progress, "pareto", done, len(jobs), "world", started)
    errors = np.concatenate([r["errors"] for r in results])  # (worlds·seeds, n_samp, n_solv)
    solve_s = np.concatenate([r["solve_s"] for r in results])
    stats_s = np.concatenate([r["stats_s"] for r in results])
    mean_error = np.nanmean(errors, axis=0)
    total = np.nanmedian(stats_s, axis=0)[:, None] + np.nanmedian(solve_s, axis=0)
    front = pareto_front(mean_error, total)
    points: list[dict[str, Any]] = []
    for j, sampling in enumerate(samplings):
        for s, solver in enumerate(solvers):
            column = errors[:, j, s]
            points.append(
                {
                    "solver": solver,
                    "sampling": sampling,
                    "error_mean": float(mean_error[j, s]),
                    "error_std": float(np.nanstd(column)),
                    "time_s": float(total[j, s]),
                    "statistics_s": float(np.nanmedian(stats_s[:, j])),
                    "solver_s": float(np.nanmedian(solve_s[:, j, s])),
                    "failed": int(np.isnan(column).sum()),
                    "on_front": bool(front[j, s]),
                }
            )
    default = next((p for p in points if (p["solver"], p["sampling"]) == DEFAULT_CHOICE), None)
    on_front = sorted((p for p in points if p["on_front"]), key=lambda p: p["time_s"])
    if default is not None and not default["on_front"]:
        # How far the default is from the front: the best front error at no more time, the fastest at no more error.
        faster = [p for p in on_front if p["time_s"] <= default["time_s"]]
        default["front_error_at_its_time"] = min((p["error_mean"] for p in faster), default=None)
        better = [p for p in on_front if p["error_mean"] <= default["error_mean"]]
        default["front_time_at_its_error"] = min((p["time_s"] for p in better), default=None)
    return {
        "points": points,
        "front": on_front,
        "default": default,
        "definitions": {
            "error_mean": "mean processing.metrics.spectrum_rmse over cameras x ambients x seeds",
            "time_s": "median wall time of accumulate_statistics (or the patch means / pixel gather) plus median "
            "estimate_ambient time, per frame stack, in the worker",
            "on_front": "no other point has both lower-or-equal error and time (one strictly lower)",
        },
        "config": {
            "cameras": list(camera_set),
            "ambients": list(ambients),
            "seeds": seed_list,
            "samplings": list(samplings),
            "solvers": {s: list(SOLVERS[s]) for s in solvers},
            "patch_px": patch_px,
            "pixels": results[0]["pixels"] if results else None,
            "ambient_to_flash": ambient_to_flash,
            "repeats": repeats,
            "grid": str(grid),
            "default": list(DEFAULT_CHOICE),
        },
        "elapsed_s": time.perf_counter() - started,
    }
