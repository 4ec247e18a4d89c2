"""``msflash bench``: speed figures as ratios measured in one run (these machines are noisy).

Processing part (issue: foundation), on a 1280×1024 RGB sequence with 7 LEDs:

- ``estimate_over_copy``: ambient estimation as ``msflash estimate`` does it (4×4 block sums, one-pass
  statistics, the default solver, the image passes on ``DEFAULT_WORKERS`` threads) ÷ the time to
  read those frames once (a numpy copy, one thread) — target ≤ 3: the best of ``repeats`` runs of
  each; ``estimate_over_copy_interleaved`` the median of ``4·repeats + 1`` ratios of an estimate and a
  copy run in turn (steadier when other load comes and goes); ``estimate_over_copy_by_threads``
  the same on 1 and on 2 threads; ``estimate_unweighted_over_copy`` without the inverse-variance sample
  weights (what they cost); ``estimate_all_pixels_over_copy`` without binning;
- ``solver_speedup``: each estimation and flash solver ÷ cvxpy on exactly the same problems
  (recorded from our solver), with the objectives' relative difference — target ≥ 50×, ≤ 1e-6;
  the LED/camera part of each problem is prepared once per sequence (:class:`AmbientModel`,
  :class:`FlashModel`), as cvxpy is handed the finished problem matrices;
- ``synthesis_over_copy``: synthesis ÷ the same memory copy — target ≤ 2 (``DEFAULT_WORKERS``
  threads; ``synthesis_over_copy_by_threads`` on 1 and 2);
- ``prior_estimate_over_copy``: the light prior's estimate (channel-resolved statistics and solve,
  ``msflash estimate --model prior``) ÷ the same copy (``prior_estimate_over_copy_interleaved`` as above); ``auto_choice_s`` the held-out comparison
  ``--model auto`` adds; ``model_reference_s``/``model_band_s`` the default estimate's model band.

Camera and booth parts are added by their modules when present.
"""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np

from msflash.acquisition.session.analysis import DEFAULT_BIN_FACTOR, SAMPLE_WEIGHTING
from msflash.processing import datasets, lights
from msflash.processing.ambient import AmbientModel, estimate_ambient
from msflash.processing.flash import FlashModel
from msflash.processing.image_formation import SensorModel, chart_scene, exposure_for_peak, render_frame
from msflash.processing.least_squares import minimise_quadratic, recording_problems
from msflash.processing.model_error import light_reference, reference_for, with_model_error
from msflash.processing.spectra import DEFAULT_GRID, Spectra
from msflash.processing.statistics import DEFAULT_WORKERS, FrameStackSpec, accumulate_statistics
from msflash.processing.synthesis import synthesize


def _best_time(function: Callable[[], Any], repeats: int) -> float:
    """Minimum wall time of ``repeats`` calls (the least disturbed by other load)."""
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return float(best)


def _interleaved_ratio(function: Callable[[], Any], reference: Callable[[], Any], rounds: int) -> float:
    """Median over ``rounds`` of ``function``'s time ÷ ``reference``'s, the two run in turn in each round.

    Each ratio pairs two runs a few milliseconds apart, so it holds when other load comes and goes; a
    minimum of separate runs (:func:`_best_time`) pairs the luckiest copy with the luckiest estimate,
    which on a busy machine need not be alike."""
    ratios = []
    for _ in range(rounds):
        start = time.perf_counter()
        reference()
        middle = time.perf_counter()
        function()
        ratios.append((time.perf_counter() - middle) / (middle - start))
    return float(np.median(ratios))


def benchmark_world(height: int = 1024, width: int = 1280, seed: int = 0) -> dict[str, Any]:
    """A rendered 7-LED RGB sequence (tungsten ambient, 110-patch chart) for the benchmarks."""
    grid = DEFAULT_GRID
    leds = datasets.paper_leds().resample(grid, outside="zero").to_unit("photons")
    camera = datasets.isetcam_camera("NikonD100").resample(grid, outside="zero").to_unit("photons")
    ambient = lights.ambient_spectrum("tungsten", grid).to_unit("photons")
    reflectances = datasets.chart110().resample(grid)
    patch = max(4, min(height, width) // 12)
    scene = chart_scene(reflectances, patch_px=patch)
    scene_tiles = (int(np.ceil(height / scene.labels.shape[0])), int(np.ceil(width / scene.labels.shape[1])))
    labels = np.tile(scene.labels, scene_tiles)[:height, :width]
    scene = type(scene)(reflectances=scene.reflectances, labels=labels)
    sensor = SensorModel()
    rng = np.random.default_rng(seed)
    # The ambient at 45% of full scale leaves room for each LED frame (LED peak = ambient peak).
    exposure = exposure_for_peak(scene, ambient, camera, sensor, fraction=0.45)
    frames = [render_frame(scene, ambient, camera, sensor, exposure, rng=rng)]
    led_scale = float(np.max(ambient.values) / np.max(leds.values))
    for k in range(leds.count):
        lit = Spectra(grid, ambient.values[:, 0] + led_scale * leds.values[:, k], ("lit",), unit="photons")
        frames.append(render_frame(scene, lit, camera, sensor, exposure, rng=rng))
    spec = FrameStackSpec(
        sensor.black_level, sensor.white_level, 1.0 / exposure, (1.0 / exposure,) * leds.count, np.eye(leds.count)
    )
    return {
        "frames": frames,
        "spec": spec,
        "leds": leds,
        "camera": camera,
        "target": datasets.illuminant("D65", grid).to_unit("photons"),
    }


def _cvxpy_solve(problem: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]) -> tuple[float, float]:
    import cvxpy as cp

    hessian, linear, constraints, bounds = problem
    hessian = 0.5 * (hessian + hessian.T)
    x = cp.Variable(linear.size)
    objective = cp.Minimize(0.5 * cp.quad_form(x, cp.psd_wrap(hessian)) - linear @ x)
    cons = [constraints @ x >= bounds] if constraints.shape[0] else []
    start = time.perf_counter()
    cp.Problem(objective, cons).solve(solver=cp.CLARABEL, tol_gap_abs=1e-12, tol_gap_rel=1e-12, tol_feas=1e-12)
    elapsed = time.perf_counter() - start
    value = x.value
    assert value is not None, "cvxpy (CLARABEL) found no solution"
    return elapsed, float(0.5 * value @ hessian @ value - linear @ value)


def _compare_with_cvxpy(name: str, run: Callable[[], Any], repeats: int) -> dict[str, Any]:
    with recording_problems() as problems:
        run()
    ours = _best_time(run, repeats)
    total_cvxpy, worst_difference = 0.0, 0.0
    for problem in problems:
        elapsed, value = _cvxpy_solve(problem)
        total_cvxpy += elapsed
        ours_value = minimise_quadratic(*problem).objective
        scale = max(abs(value), abs(ours_value), 1e-300)
        # Positive when ours is worse (higher) than cvxpy's.
        worst_difference = max(worst_difference, (ours_value - value) / scale)
    return {
        "solver": name,
        "problems": len(problems),
        "ours_s": ours,
        "cvxpy_s": total_cvxpy,
        "speedup": total_cvxpy / ours if ours > 0 else None,
        "objective_relative_excess": worst_difference,
    }


def processing_bench(height: int = 1024, width: int = 1280, repeats: int = 5) -> dict[str, Any]:
    """The three processing figures (see the module notes)."""
    world = benchmark_world(height, width)
    frames, spec = world["frames"], world["spec"]

    def copy() -> list[np.ndarray]:
        return [f.copy() for f in frames]

    copy_time = _best_time(copy, repeats)
    statistics = accumulate_statistics(frames[0], frames[1:], spec)

    def estimate(
        bin_factor: int, workers: int = DEFAULT_WORKERS, weighting: bool = SAMPLE_WEIGHTING
    ) -> Callable[[], object]:
        # As msflash estimate: the weighted statistics (acquisition.session.analysis.sequence_statistics) and the default solve.
        return lambda: estimate_ambient(
            accumulate_statistics(
                frames[0], frames[1:], spec, bin_factor=bin_factor, workers=workers, weighting=weighting
            ),
            world["leds"],
        )

    weights = estimate_ambient(statistics, world["leds"]).ambient_weights
    flash_weights = np.clip(weights, 0, 1)

    def synthesis(workers: int = DEFAULT_WORKERS) -> Callable[[], object]:
        return lambda: synthesize(frames[0], frames[1:], spec, flash_weights, workers=workers)

    estimate_time = _best_time(estimate(DEFAULT_BIN_FACTOR), repeats)
    estimate_all_pixels_time = _best_time(estimate(1), repeats)
    synthesis_time = _best_time(synthesis(), repeats)
    result: dict[str, Any] = {
        "frames": f"{len(frames)} × {height}×{width}×3 uint16",
        "copy_s": copy_time,
        "threads": DEFAULT_WORKERS,
        "estimate_s": estimate_time,
        "estimate_over_copy": estimate_time / copy_time,
        "estimate_over_copy_interleaved": _interleaved_ratio(estimate(DEFAULT_BIN_FACTOR), copy, 4 * repeats + 1),
        "estimate_over_copy_by_threads": {
            str(n): _best_time(estimate(DEFAULT_BIN_FACTOR, n), repeats) / copy_time for n in (1, 2)
        },
        "estimate_unweighted_over_copy": _best_time(estimate(DEFAULT_BIN_FACTOR, weighting=False), repeats) / copy_time,
        "estimate_bin": DEFAULT_BIN_FACTOR,
        "estimate_all_pixels_over_copy": estimate_all_pixels_time / copy_time,
        "synthesis_s": synthesis_time,
        "synthesis_over_copy": synthesis_time / copy_time,
        "synthesis_over_copy_by_threads": {str(n): _best_time(synthesis(n), repeats) / copy_time for n in (1, 2)},
    }
    try:
        import cvxpy  # noqa: F401
    except ImportError:
        result["solvers"] = "cvxpy not installed (pip install cvxpy) — solver comparison skipped"
        return result
    leds, camera, target = world["leds"], world["camera"], world["target"]
    # The LED/camera part of each problem is prepared once per sequence (AmbientModel, FlashModel),
    # as cvxpy is handed the finished problem matrices.
    ambient_model = AmbientModel(leds)
    flash_model = FlashModel(leds, camera)
    target_response = flash_model.target_response(target)
    # The estimation solvers proper (AmbientModel.weights); the estimate adds the reliability
    # signals (band, conditioning), which are not part of the problem cvxpy solves.
    solvers = {
        "estimate nonneg": lambda: ambient_model.weights(statistics, "nonneg", 0.0),
        "estimate tikhonov (alpha 1e-3)": lambda: ambient_model.weights(statistics, "tikhonov", 1e-3),
        "flash matching": lambda: flash_model.matching(weights),
        "flash complementary": lambda: flash_model.complementary(weights, target_response),
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result["solvers"] = [_compare_with_cvxpy(name, run, 50) for name, run in solvers.items()]
    result["reliability_signals_s"] = _best_time(lambda: estimate_ambient(statistics, leds, "tikhonov", 1e-3), 20)
    # The LED model's error (processing.model_error): its reference lights once per LED set and camera,
    # then the band and miss risk of each estimate.
    result["model_reference_s"] = _best_time(lambda: light_reference(leds, camera), 3)
    reference, estimated = reference_for(leds, camera), estimate_ambient(statistics, leds)
    result["model_band_s"] = _best_time(lambda: with_model_error(estimated, reference), 20)
    result.update(prior_bench(frames, spec, leds, camera, copy_time, repeats, copy))
    return result


def prior_bench(
    frames: list[np.ndarray],
    spec: FrameStackSpec,
    leds: Spectra,
    camera: Spectra,
    copy_time: float,
    repeats: int,
    copy: Callable[[], Any] | None = None,
) -> dict[str, float]:
    """The light prior's figures (``msflash estimate --model prior|auto``): its channel-resolved statistics and
    estimate ÷ the copy, as ``estimate_over_copy`` (and interleaved with ``copy``, when given);
    ``auto``'s held-out comparison; the model's preparation."""
    from msflash.processing.channel_statistics import ChannelStatistics, accumulate_channel_statistics
    from msflash.processing.light_prior import choose_model, prior_model

    def statistics() -> ChannelStatistics:
        return accumulate_channel_statistics(frames[0], frames[1:], spec, bin_factor=DEFAULT_BIN_FACTOR)

    channels = statistics()
    model = prior_model(channels.channels, leds, camera)

    def estimate() -> object:
        return model.estimate(statistics())

    prior_time = _best_time(estimate, repeats)
    interleaved = (
        {}
        if copy is None
        else {"prior_estimate_over_copy_interleaved": _interleaved_ratio(estimate, copy, 4 * repeats + 1)}
    )
    return {
        "prior_estimate_s": prior_time,
        "prior_estimate_over_copy": prior_time / copy_time,
        **interleaved,
        "prior_model_prepare_s": _best_time(lambda: prior_model(channels.channels, leds, camera), repeats),
        "auto_choice_s": _best_time(lambda: choose_model(channels, model), repeats),
    }
