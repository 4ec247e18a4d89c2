"""Table 1 of the paper: ambient-estimation accuracy vs the number of flash LEDs.

Protocol (paper Section 5 and the authors' ``s_simNatural100.m`` / ``s_evalNatural100NumLeds.m``)
-------------------------------------------------------------------------------------------------
- Chart: the 110 surfaces of :func:`processing.datasets.chart110`, one response per surface
  (the chart has no noise, so an image is a 110 × 3 matrix).
- Cameras: the 34 of :func:`processing.datasets.paper_cameras`.
- LEDs: the 7 paper LEDs resampled to the 400–700/10 nm grid, converted to photons and divided
  by one global maximum (``flashNorm`` of the authors); subsets by :data:`PAPER_LED_SUBSETS`.
- Illuminants: the smoothest non-negative spectra of the 23 feasible points of the
  ``linspace(0,1,10)²`` xy grid (:func:`lab.study.illuminants.feasible_grid`), photons,
  peak 1.
- Images: ambient image ``a`` and LED-only images ``f_k`` (all 7 LEDs), noise-free. The stack
  ``[a, f_1 … f_7]`` is divided by its largest value (the authors' ``rawLin / max(rawLin(:))``):
  "exposure at 95 % of full scale" has no other effect without noise, because the frames are
  linearised by their exposure before this normalisation.
- Estimation: :func:`processing.ambient.estimate_ambient` on statistics built from the
  per-surface responses (gram = Σ f fᵀ, cross = Σ f a over the 330 values).

Metrics (each a mean over illuminants × cameras)
------------------------------------------------
``pixel_rmse``
    ``sqrt(mean((a − Σ_k w_k f_k)²))`` over the 110 × 3 values of the normalised images, × 100.
``pixel_rmse_ambient095``
    The same with the images scaled so the brightest ambient value is 0.95 (the other reading of
    "exposure set to 95 %"), × 100.
``xy_error``
    ``mean over the two coordinates of (xy_est − xy_true)²`` = ``|Δxy|² / 2``, × 100 — exactly
    the authors' ``mean((spdEstxy − spdxy).^2, 1)``; CIE 1931 2° observer on the photon spectra.
``xy_squared_distance``
    ``|Δxy|²`` (squared Euclidean distance), × 100 — twice ``xy_error``.
``spectrum_rmse``
    :func:`processing.metrics.spectrum_rmse` per camera (estimate max-normalised, truth
    least-squares scaled onto it), averaged.
``spectrum_rmse_shared_scale``
    The authors' code: one scale for the truth, fitted to the camera-averaged normalised estimate.
``multispectral_rmse``
    :func:`processing.metrics.spectrum_rmse` of the best direct LED fit of the true spectrum,
    ``argmin ‖t − I w‖`` subject to ``I w ≥ 0`` (the authors' constraint); camera independent.
``multispectral_rmse_lstsq``
    The same with plain least squares.
``multispectral_rmse_authors``
    The authors' code: the truth (peak 1) times the scale ``gf`` that fits it to the camera-mean
    normalised estimate, and the RMSE of its ``I w ≥ 0`` fit without renormalising the fit.

When ``alpha`` is a sequence, every metric is computed for every value and, as the authors did
(``min(mean(...))`` over ``alphaVec``), the table reports for each metric and LED count the
best mean over the values, with the chosen value in ``alpha_selected``.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from msflash.lab.progress import Progress, report_count
from msflash.lab.study.illuminants import SmoothIlluminant, cmfs_photons, feasible_grid
from msflash.processing import datasets
from msflash.processing.ambient import AMBIENT_METHODS, estimate_ambient
from msflash.processing.errors import SolverError, SpectralDataError
from msflash.processing.least_squares import minimise_quadratic
from msflash.processing.metrics import spectrum_rmse
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid
from msflash.processing.statistics import SequenceStatistics

PAPER_TABLE1: dict[str, list[float]] = {
    "n_leds": [3, 4, 5, 6, 7],
    "pixel_rmse": [1.5, 1.0, 0.4, 0.3, 0.2],
    "xy_error": [0.3, 0.1, 0.05, 0.03, 0.03],
    "spectrum_rmse": [0.22, 0.18, 0.16, 0.13, 0.13],
    "multispectral_rmse": [0.14, 0.12, 0.14, 0.13, 0.13],
}
"""The paper's Table 1 (pixel RMSE and CIE xy error × 10⁻²)."""

PAPER_ALPHAS = tuple(float(a) for a in np.logspace(-3, 1, 10))
"""The authors' ``alphaVec = logspace(-3, 1, 10)`` for eq. 6 (in their units, see ``alpha_units``)."""

PAPER_GRID_STEP_NM = 5.0
"""The authors simulate on 400:5:700 nm; their roughness norm is taken on that grid."""

METRICS = ("pixel_rmse", "pixel_rmse_ambient095", "xy_error", "xy_squared_distance", "spectrum_rmse")
"""Per-camera metrics, averaged over cameras and illuminants."""

MapFunction = Callable[[Callable[..., Any], Sequence[Any]], Iterable[Any]]


# -- inputs -----------------------------------------------------------------------------------
def flash_norm(grid: WavelengthGrid = DEFAULT_GRID) -> Spectra:
    """The paper's 7 LEDs on ``grid`` in photons divided by one global maximum (``flashNorm``)."""
    leds = datasets.paper_leds().resample(grid).to_unit("photons")
    return leds.replace(values=leds.values / float(np.max(leds.values)))


def led_subset_indices(n_leds: int) -> list[int]:
    """0-based indices of the paper's subset of ``n_leds`` LEDs."""
    if n_leds not in datasets.PAPER_LED_SUBSETS:
        raise SpectralDataError(
            f"table 1: {n_leds} LEDs; expected one of {', '.join(map(str, datasets.PAPER_LED_SUBSETS))}"
        )
    return [index - 1 for index in datasets.PAPER_LED_SUBSETS[n_leds]]


def select_cameras(cameras: Sequence[str] | int | None) -> dict[str, Spectra]:
    """The paper's cameras: all 34 (None), the first ``n`` (an int), or by name."""
    available = datasets.paper_cameras()
    if cameras is None:
        return available
    if isinstance(cameras, int):
        if not 1 <= cameras <= len(available):
            raise SpectralDataError(f"table 1: {cameras} cameras; expected 1–{len(available)}")
        return dict(list(available.items())[:cameras])
    chosen = {}
    for name in cameras:
        if name not in available:
            raise SpectralDataError(f"table 1: unknown camera '{name}'; expected one of {', '.join(available)}")
        chosen[name] = available[name]
    return chosen


def select_illuminants(
    illuminants: Sequence[SmoothIlluminant] | int | None, grid: WavelengthGrid = DEFAULT_GRID
) -> tuple[SmoothIlluminant, ...]:
    """The feasible-grid illuminants: all (None), ``n`` spread evenly over them (an int), or given."""
    if illuminants is None or isinstance(illuminants, int):
        everything = feasible_grid(grid=grid)
        if illuminants is None:
            return everything
        if not 1 <= illuminants <= len(everything):
            raise SpectralDataError(f"table 1: {illuminants} illuminants; expected 1–{len(everything)}")
        picks = np.unique(np.linspace(0, len(everything) - 1, illuminants).round().astype(int))
        return tuple(everything[i] for i in picks)
    return tuple(illuminants)


def transfer_matrix(chart: Spectra, camera: Spectra) -> np.ndarray:
    """``T`` with ``T @ s`` = the (110·3,) image of the chart under photon spectrum ``s`` (rows surface-major).

    Same numbers as :func:`processing.image_formation.surface_responses` (``Cᵀ diag(r) i Δλ``),
    kept linear in the illuminant so each camera is set up once.
    """
    responsivities = camera.to_unit("photons").values
    n_wl = chart.grid.size
    return (chart.values[:, :, None] * responsivities[:, None, :]).transpose(1, 2, 0).reshape(
        -1, n_wl
    ) * chart.grid.step_nm


def direct_fit(truth: np.ndarray, led_values: np.ndarray, how: str = "nonneg") -> np.ndarray:
    """Best LED approximation ``I w`` of a spectrum: ``argmin ‖t − I w‖`` (``"nonneg"``: with ``I w ≥ 0``)."""
    if how == "lstsq":
        weights = np.linalg.lstsq(led_values, truth, rcond=None)[0]
    elif how == "nonneg":
        hessian = led_values.T @ led_values
        scale = float(np.trace(hessian) / hessian.shape[0])
        emitting = led_values[np.any(led_values != 0, axis=1)]
        weights = minimise_quadratic(
            hessian / scale, led_values.T @ truth / scale, emitting, np.zeros(emitting.shape[0]), where="direct LED fit"
        ).x
    else:
        raise SpectralDataError(f"direct fit: '{how}'; expected nonneg or lstsq")
    return led_values @ weights


def statistics_from_images(ambient: np.ndarray, led_images: np.ndarray) -> SequenceStatistics:
    """Sufficient statistics of noise-free flattened images: ``a`` (n,), LED-only ``F`` (n, k)."""
    return SequenceStatistics(
        gram=led_images.T @ led_images,
        cross=led_images.T @ ambient,
        ambient_energy=float(ambient @ ambient),
        n_samples=int(ambient.size),
        n_total=int(ambient.size),
        ambient_sum=float(ambient.sum()),
        led_sums=led_images.sum(axis=0),
    )


def dimensionless_alpha(alpha: float, statistics: SequenceStatistics, led_values: np.ndarray, step_nm: float) -> float:
    """Convert the authors' eq.-6 weight to :mod:`processing.ambient`'s dimensionless ``alpha`` (``roughness``).

    The authors minimise ``‖a − F w‖ + α ‖R I w‖`` with images divided by the stack maximum, ``I``
    = flashNorm and ``R`` first differences on a 5 nm grid. ``roughness`` uses
    ``α' · sqrt(tr G / tr LᵀL) · ‖L w‖`` with ``L`` the differences on our grid; differences of a
    smooth spectrum scale as ``sqrt(step)`` in norm, so ``‖R I w‖₅ ≈ sqrt(5/step) ‖L w‖``.
    """
    roughness = np.diff(led_values, axis=0)
    penalty_scale = float(np.trace(statistics.gram) / max(np.trace(roughness.T @ roughness), 1e-300))
    return float(alpha * math.sqrt(PAPER_GRID_STEP_NM / step_nm) / math.sqrt(penalty_scale))


# -- one camera -------------------------------------------------------------------------------
def evaluate_camera(
    transfer: np.ndarray,
    led_values: np.ndarray,
    truths: np.ndarray,
    subsets: Sequence[Sequence[int]],
    method: str,
    alphas: Sequence[float | str],
    alpha_units: str,
    grid: WavelengthGrid,
    surfaces: Sequence[Sequence[int]] | None = None,
) -> dict[str, np.ndarray]:
    """All metrics of one camera: arrays (n_illuminants, n_subsets, n_alphas[, n_surface_draws]).

    A pure function of arrays (picklable), the unit of parallel work.

    Parameters
    ----------
    transfer
        :func:`transfer_matrix` of the camera, (n_surfaces·3, n_wl).
    led_values
        flashNorm, (n_wl, 7).
    truths
        True photon spectra, (n_wl, n_illuminants), peak 1.
    subsets
        0-based LED indices per LED count.
    method, alphas, alpha_units
        Estimator, its weights, and ``"dimensionless"`` or ``"paper"`` (roughness only).
    grid
        The wavelength grid.
    surfaces
        Optional surface draws (indices into the chart, repetition allowed): metrics are then
        computed on each draw's images, adding a last axis. None: the whole chart.

    Returns
    -------
    dict
        ``pixel_rmse`` … ``spectrum_rmse`` (see the module notes, unscaled), ``estimates`` (…,
        n_wl) max-normalised estimated spectra, ``alpha_used`` and ``failed`` (SolverError).
    """
    cmf = cmfs_photons(grid)
    n_ill, n_sets, n_alpha = truths.shape[1], len(subsets), len(alphas)
    draws = [None] if surfaces is None else list(surfaces)
    shape = (n_ill, n_sets, n_alpha, len(draws))
    out = {name: np.full(shape, np.nan) for name in METRICS}
    out["alpha_used"] = np.full(shape, np.nan)
    out["failed"] = np.zeros(shape, dtype=bool)
    out["estimates"] = np.full(shape + (grid.size,), np.nan)
    led_images_all = transfer @ led_values  # (n·3, 7), independent of the illuminant
    for i in range(n_ill):
        truth = truths[:, i]
        ambient_all = transfer @ truth
        stack_max = max(float(ambient_all.max()), float(led_images_all.max()))
        ambient_all = ambient_all / stack_max
        led_all = led_images_all / stack_max
        to_095 = 0.95 / float(ambient_all.max())
        truth_xy = _xy(cmf, truth)
        for d, draw in enumerate(draws):
            if draw is None:
                ambient, led_images = ambient_all, led_all
            else:
                rows = (np.asarray(draw)[:, None] * 3 + np.arange(3)[None, :]).ravel()
                ambient, led_images = ambient_all[rows], led_all[rows]
            for s, subset in enumerate(subsets):
                images = led_images[:, list(subset)]
                statistics = statistics_from_images(ambient, images)
                spectra = Spectra(
                    grid,
                    led_values[:, list(subset)],
                    tuple(f"led{k}" for k in subset),
                    kind="spd",
                    unit="photons",
                    source="flashNorm",
                )
                for a, alpha in enumerate(alphas):
                    value: float | str = alpha
                    if alpha_units == "paper" and alpha != "auto":
                        value = dimensionless_alpha(float(alpha), statistics, spectra.values, grid.step_nm)
                    try:
                        estimate = estimate_ambient(statistics, spectra, method, value)
                    except (SolverError, SpectralDataError):
                        # e.g. fewer values than LEDs (one surface, 7 LEDs): estimate_ambient refuses.
                        out["failed"][i, s, a, d] = True
                        continue
                    weights = estimate.ambient_weights
                    residual = ambient - images @ weights
                    rmse = float(np.sqrt(np.mean(residual**2)))
                    spectrum = estimate.spectrum.values[:, 0]
                    peak = float(np.max(np.abs(spectrum)))
                    if peak == 0:
                        out["failed"][i, s, a, d] = True
                        continue
                    delta = _xy(cmf, spectrum) - truth_xy
                    out["pixel_rmse"][i, s, a, d] = rmse
                    out["pixel_rmse_ambient095"][i, s, a, d] = rmse * to_095
                    out["xy_error"][i, s, a, d] = float(np.mean(delta**2))
                    out["xy_squared_distance"][i, s, a, d] = float(np.sum(delta**2))
                    out["spectrum_rmse"][i, s, a, d] = spectrum_rmse(spectrum, truth)
                    out["alpha_used"][i, s, a, d] = estimate.alpha
                    out["estimates"][i, s, a, d] = spectrum / peak
    if surfaces is None:
        out = {name: values[:, :, :, 0] for name, values in out.items()}
    return out


def _xy(cmf: np.ndarray, spectrum: np.ndarray) -> np.ndarray:
    xyz = cmf.T @ spectrum
    total = float(xyz.sum())
    return xyz[:2] / total if total != 0 else np.full(2, np.nan)


def shared_scale_rmse(estimates: np.ndarray, truth: np.ndarray) -> float:
    """The authors' spectrum RMSE: one truth scale fitted to the camera-mean estimate, RMSE per camera, mean.

    ``estimates`` (n_cameras, n_wl), each max-normalised; NaN rows (failures) are left out.
    """
    rows = estimates[~np.any(np.isnan(estimates), axis=1)]
    if rows.size == 0:
        return float("nan")
    reference = truth / truth.max()
    mean_estimate = rows.mean(axis=0)
    gain = float(reference @ mean_estimate) / float(reference @ reference)
    return float(np.mean(np.sqrt(np.mean((rows - gain * reference) ** 2, axis=1))))


# -- the table --------------------------------------------------------------------------------
@dataclass(frozen=True)
class CameraRuns:
    """The noise-free protocol evaluated for every camera: what Table 1 and the camera study share."""

    counts: list[int]
    """LED counts."""
    subsets: list[list[int]]
    """The paper's LED subsets (0-based indices) for each count."""
    names: list[str]
    """Camera names, in the order of ``results``."""
    illuminants: tuple[SmoothIlluminant, ...]
    """The illuminants (smoothest spectra of the feasible xy grid)."""
    truths: np.ndarray
    """True spectra, (n_wavelengths, n_illuminants)."""
    leds: Any
    """The flash LED spectra (photons, one global maximum)."""
    results: list[dict[str, Any]]
    """One :func:`_evaluate_job` result per camera."""


def evaluate_all_cameras(
    n_leds_list: Sequence[int],
    method: str,
    alphas: Sequence[float | str],
    alpha_units: str,
    cameras: Sequence[str] | int | None,
    illuminants: Sequence[Any] | int | None,
    progress: Progress | None,
    map_function: MapFunction | None,
    grid: WavelengthGrid,
    label: str,
    started: float,
) -> CameraRuns:
    """Evaluate every camera × illuminant × LED subset (in parallel through ``map_function``)."""
    counts = [int(n) for n in n_leds_list]
    if not counts:
        raise SpectralDataError(f"{label} study: no LED counts; expected some of 3–7")
    subsets = [led_subset_indices(n) for n in counts]
    chosen_cameras = select_cameras(cameras)
    chosen_illuminants = select_illuminants(illuminants, grid)
    leds = flash_norm(grid)
    chart = datasets.chart110().resample(grid)
    truths = np.column_stack([ill.spectrum.values[:, 0] for ill in chosen_illuminants])
    names = list(chosen_cameras)
    jobs = [
        (
            transfer_matrix(chart, chosen_cameras[name]),
            leds.values,
            truths,
            subsets,
            method,
            list(alphas),
            alpha_units,
            grid,
        )
        for name in names
    ]
    mapper = map_function or (lambda function, items: map(function, items))
    results = []
    for done, result in enumerate(mapper(_evaluate_job, jobs), start=1):
        results.append(result)
        report_count(progress, label, done, len(names), "camera", started)
    return CameraRuns(counts, subsets, names, chosen_illuminants, truths, leds, results)


def run_table1(
    n_leds_list: Sequence[int] = (3, 4, 5, 6, 7),
    method: str = "tikhonov",
    alpha: float | str | Sequence[float] = "auto",
    cameras: Sequence[str] | int | None = None,
    illuminants: Sequence[SmoothIlluminant] | int | None = None,
    alpha_units: str = "dimensionless",
    progress: Progress | None = None,
    map_function: MapFunction | None = None,
    grid: WavelengthGrid = DEFAULT_GRID,
) -> dict[str, Any]:
    """Reproduce the paper's Table 1.

    Parameters
    ----------
    n_leds_list
        LED counts (paper subsets).
    method
        A key of :data:`processing.ambient.AMBIENT_METHODS`.
    alpha
        The estimator's roughness weight, ``"auto"``, or a sequence of weights (a sweep: each
        metric reports its best mean over the sweep, as the authors did).
    cameras
        Camera names, a count (the first n), or None for all 34.
    illuminants
        Illuminants, a count (spread over the feasible grid), or None for all 23.
    alpha_units
        ``"dimensionless"`` (:mod:`processing.ambient`'s) or ``"paper"`` (the authors' eq.-6
        weight, ``method="roughness"`` only; see :func:`dimensionless_alpha`).
    progress
        Called with a short message after each camera.
    map_function
        ``map``-like ``f(function, items) -> results`` for parallel execution over cameras
        (e.g. a dask client's map-and-gather); the builtin ``map`` by default.
    grid
        The wavelength grid.

    Returns
    -------
    dict
        JSON-ready: ``n_leds`` and the paper-unit lists ``pixel_rmse``, ``xy_error``,
        ``spectrum_rmse``, ``multispectral_rmse`` aligned with it, the variants (see the module
        notes), ``paper`` (the published table), ``definitions``, ``config`` and ``elapsed_s``.
    """
    started = time.perf_counter()
    if method not in AMBIENT_METHODS:
        raise SpectralDataError(f"table 1: method '{method}'; expected one of {', '.join(AMBIENT_METHODS)}")
    if alpha_units not in ("dimensionless", "paper"):
        raise SpectralDataError(f"table 1: alpha_units '{alpha_units}'; expected dimensionless or paper")
    if alpha_units == "paper" and method != "roughness":
        raise SpectralDataError("table 1: alpha_units='paper' is the authors' eq. 6; expected method='roughness'")
    alphas: list[float | str] = [alpha] if isinstance(alpha, (str, int, float)) else list(alpha)
    if not alphas:
        raise SpectralDataError("table 1: an empty alpha sweep; expected at least one value")
    run = evaluate_all_cameras(
        n_leds_list, method, alphas, alpha_units, cameras, illuminants, progress, map_function, grid, "table1", started
    )
    counts, subsets, names, chosen_illuminants = run.counts, run.subsets, run.names, run.illuminants
    truths, leds, results = run.truths, run.leds, run.results

    # (n_cameras, n_ill, n_sets, n_alpha)
    stacked = {name: np.stack([r[name] for r in results]) for name in (*METRICS, "alpha_used", "failed")}
    estimates = np.stack([r["estimates"] for r in results])  # (n_cam, n_ill, n_sets, n_alpha, n_wl)
    n_ill, n_sets, n_alpha = truths.shape[1], len(subsets), len(alphas)
    shared = np.array(
        [
            [[shared_scale_rmse(estimates[:, i, s, a], truths[:, i]) for a in range(n_alpha)] for s in range(n_sets)]
            for i in range(n_ill)
        ]
    )

    per_alpha = {name: np.nanmean(stacked[name], axis=(0, 1)) for name in METRICS}  # (n_sets, n_alpha)
    per_alpha["spectrum_rmse_shared_scale"] = np.nanmean(shared, axis=0)
    scale = {
        "pixel_rmse": 100.0,
        "pixel_rmse_ambient095": 100.0,
        "xy_error": 100.0,
        "xy_squared_distance": 100.0,
        "spectrum_rmse": 1.0,
        "spectrum_rmse_shared_scale": 1.0,
    }
    table: dict[str, Any] = {"n_leds": counts}
    alpha_selected: dict[str, list[Any]] = {}
    for name, values in per_alpha.items():
        best = np.nanargmin(np.where(np.isnan(values), np.inf, values), axis=1)
        table[name] = [float(values[s, best[s]] * scale[name]) for s in range(n_sets)]
        alpha_selected[name] = [alphas[best[s]] for s in range(n_sets)]

    for how in ("nonneg", "lstsq"):
        key = "multispectral_rmse" if how == "nonneg" else "multispectral_rmse_lstsq"
        table[key] = [
            float(
                np.mean(
                    [
                        spectrum_rmse(direct_fit(truths[:, i], leds.values[:, subset], how), truths[:, i])
                        for i in range(n_ill)
                    ]
                )
            )
            for subset in subsets
        ]

    # The authors' Table-1 bound: the truth scaled onto the camera-mean estimate (gf), then the
    # RMSE of its direct fit, not renormalised — at the alpha chosen for spectrum_rmse.
    authors_bound = []
    for s, subset in enumerate(subsets):
        a = alphas.index(alpha_selected["spectrum_rmse"][s])
        values = []
        for i in range(n_ill):
            rows = estimates[:, i, s, a]
            rows = rows[~np.any(np.isnan(rows), axis=1)]
            reference = truths[:, i] / truths[:, i].max()
            if rows.size == 0:
                continue
            gain = float(reference @ rows.mean(axis=0)) / float(reference @ reference)
            fit = direct_fit(reference * gain, leds.values[:, subset], "nonneg")
            values.append(float(np.sqrt(np.mean((reference * gain - fit) ** 2))))
        authors_bound.append(float(np.mean(values)) if values else float("nan"))
    table["multispectral_rmse_authors"] = authors_bound

    failures = int(stacked["failed"].sum())
    paper = {
        key: [value for n, value in zip(PAPER_TABLE1["n_leds"], values, strict=True) if n in counts]
        for key, values in PAPER_TABLE1.items()
    }
    table.update(
        {
            "alpha_selected": alpha_selected if len(alphas) > 1 else None,
            "alpha_used_mean": [float(np.nanmean(stacked["alpha_used"][:, :, s, :])) for s in range(n_sets)]
            if len(alphas) == 1
            else None,
            "per_alpha": {
                "alphas": alphas,
                **{name: (values * scale[name]).tolist() for name, values in per_alpha.items()},
            }
            if len(alphas) > 1
            else None,
            "per_illuminant_spectrum_rmse": {
                "xy": [list(ill.xy) for ill in chosen_illuminants],
                "values": np.nanmean(stacked["spectrum_rmse"], axis=0).min(axis=-1).tolist(),
            },
            "paper": paper,
            "failures": failures,
            "definitions": DEFINITIONS,
            "config": {
                "method": method,
                "alpha": alphas if len(alphas) > 1 else alphas[0],
                "alpha_units": alpha_units,
                "cameras": names,
                "n_cameras": len(names),
                "illuminants_xy": [list(ill.xy) for ill in chosen_illuminants],
                "n_illuminants": n_ill,
                "grid": str(grid),
                "units": "photons; LEDs divided by one global maximum",
            },
            "elapsed_s": time.perf_counter() - started,
        }
    )
    return table


def _evaluate_job(job: tuple) -> dict[str, np.ndarray]:
    return evaluate_camera(*job)


DEFINITIONS = {
    "pixel_rmse": "100 × sqrt(mean over 110 surfaces × 3 channels of (a − Σ w f)²), images divided by the "
    "maximum of the ambient and all 7 LED-only images (authors' rawLin/max)",
    "pixel_rmse_ambient095": "as pixel_rmse with the ambient image's maximum at 0.95",
    "xy_error": "100 × mean over x and y of (xy_est − xy_true)² = 100 × |Δxy|²/2 (authors' code), CIE 1931 2°",
    "xy_squared_distance": "100 × |Δxy|² (squared Euclidean distance in CIE 1931 xy)",
    "spectrum_rmse": "msflash.processing.metrics.spectrum_rmse per camera (estimate max-normalised, truth "
    "least-squares scaled onto it), averaged",
    "spectrum_rmse_shared_scale": "authors' code: truth scaled onto the camera-mean estimate, RMSE per camera, averaged",
    "multispectral_rmse": "spectrum_rmse of argmin ‖t − I w‖ s.t. I w ≥ 0 (direct LED fit of the truth)",
    "multispectral_rmse_lstsq": "spectrum_rmse of the plain least-squares LED fit of the truth",
    "multispectral_rmse_authors": "authors' code: truth (peak 1) × gf, gf fitted onto the camera-mean normalised "
    "estimate; RMSE of its I w ≥ 0 LED fit, not renormalised",
    "averaging": "mean over illuminants × cameras; with an alpha sweep each metric takes its best mean over "
    "the sweep per LED count (authors' min(mean(...)))",
}
"""What each reported number is."""
