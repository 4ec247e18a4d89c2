"""The spectra of a run as SVG drawn by matplotlib on the server: the estimate with its band, the flash mixes.

The page's charts are the report's (``spectra.png``, :func:`acquisition.app.report.spectra_figure`) drawn
from the run's own files (``estimate.json``, ``flash-*.json``, ``sequence/sequence.json``), so a run of an
earlier session draws the same way, and the page needs no plotting script or network: matplotlib's axes,
ticks, units (:func:`~acquisition.app.plot_style.spectral_axis`), clipping to the axes and the one palette
(:data:`~acquisition.app.plot_style.PALETTE`, the flash mixes by
:func:`~acquisition.app.plot_style.draw_flash_mixes`, as the report draws them). Left: the estimated ambient
± 1σ (the band ``estimate.json`` describes) and, on a simulated rig, the true ambient scaled onto it (least
squares, the metric's scaling); right: the matching and complementary flashes, ambient + complementary and
the target. Each drawn series carries an SVG id (``band``, ``estimate``, ``truth``, ``mixes``) for the page's tests.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.app.live.runs import read_json
from msflash.processing.flash import FlashSolution
from msflash.processing.spectra import Spectra, WavelengthGrid

FIGSIZE = (5.6, 3.3)
"""Each chart's size in inches (matplotlib's SVG is scalable: the page sizes it)."""
BAND_TOP = 2.5
"""The ambient chart's range reaches at most this many times the estimate's peak (and as far below 0)."""


def _plot_unit(wavelengths: np.ndarray, values: np.ndarray, unit: str) -> np.ndarray:
    """``values`` (n_wavelengths, k) given in ``unit``, in the plots' unit."""
    from msflash.acquisition.app.plot_style import in_plot_unit

    step = float(wavelengths[1] - wavelengths[0]) if wavelengths.size > 1 else 1.0
    grid = WavelengthGrid(float(wavelengths[0]), float(wavelengths[-1]), step)
    names = tuple(f"s{i}" for i in range(values.shape[1]))
    return in_plot_unit(Spectra(grid, values, names, "spd", unit))  # type: ignore[arg-type]


def _svg(figure: Any) -> str:
    from msflash.acquisition.app.plot_style import pyplot

    buffer = io.StringIO()
    try:
        figure.savefig(buffer, format="svg", bbox_inches="tight")
    finally:
        pyplot().close(figure)
    text = buffer.getvalue()
    return text[text.index("<svg") :]  # no XML prologue: the SVG goes inline into the page


def _solution(flash: Any, mode: str, count: int) -> FlashSolution | None:
    if not isinstance(flash, dict):
        return None
    try:
        weights = np.asarray(flash.get("flash_weights", []), dtype=float)
        ambient = np.asarray(flash.get("ambient_weights", []), dtype=float)
    except (TypeError, ValueError):
        return None
    if weights.shape != (count,) or ambient.shape != (count,):
        return None
    return FlashSolution(mode, ambient, weights, None, 0.0, str(flash.get("bounds", "")), True)


_CACHE: dict[tuple[str, int], dict[str, str] | None] = {}
"""Charts drawn, by run folder and ``estimate.json``'s modification time (a run's report is written once)."""


def run_charts(folder: Path) -> dict[str, str] | None:
    """``{"ambient": svg, "mixes": svg}`` for the run in ``folder``, or None before its report exists
    (drawn once per run: matplotlib takes a fraction of a second a chart)."""
    try:
        key = (str(folder), (folder / "estimate.json").stat().st_mtime_ns)
    except OSError:
        return None
    if key not in _CACHE:
        if len(_CACHE) > 64:
            _CACHE.clear()
        _CACHE[key] = _draw_charts(folder)
    return _CACHE[key]


def _draw_charts(folder: Path) -> dict[str, str] | None:
    estimate = read_json(folder / "estimate.json")
    sequence = read_json(folder / "sequence" / "sequence.json")
    if not isinstance(estimate, dict) or not isinstance(sequence, dict):
        return None
    try:
        wavelengths = np.asarray(estimate["wavelengths_nm"], dtype=float)
        spectrum = np.asarray(estimate["spectrum"], dtype=float)
        std = np.asarray(estimate["spectrum_std"], dtype=float)
        leds = np.array([led["spd"] for led in sequence["leds"]], dtype=float).T
        estimate_unit = str(estimate.get("spectral_unit", "energy"))
        sequence_unit = str(sequence.get("spectral_unit", "energy"))
    except (KeyError, TypeError, ValueError):
        return None
    if leds.shape[0] != wavelengths.size or spectrum.shape != wavelengths.shape or std.shape != wavelengths.shape:
        return None
    from msflash.acquisition.app.plot_style import draw_flash_mixes, peak_of, pyplot, spectral_axis

    plt = pyplot()
    try:
        curves = _plot_unit(wavelengths, np.stack([spectrum, std], axis=1), estimate_unit)
        led_values = _plot_unit(wavelengths, leds, sequence_unit)
    except Exception:  # noqa: BLE001 - a unit or grid the plots cannot take: no charts, the files stay listed
        return None
    values, sigma = curves[:, 0], np.abs(curves[:, 1])
    peak = peak_of(values)

    covers = "pixel noise + model error" if estimate.get("miss_risk") is not None else "pixel noise only"
    truth = _scaled_truth(sequence, wavelengths, values, sequence_unit)
    ambient_chart = _ambient_chart(
        wavelengths, values / peak, sigma / peak, None if truth is None else truth / peak, covers
    )

    solutions = {}
    for mode in ("matching", "complementary"):
        solution = _solution(read_json(folder / f"flash-{mode}.json"), mode, leds.shape[1])
        if solution is not None:
            solutions[mode] = solution
    target = None
    flash = read_json(folder / "flash-complementary.json")
    if isinstance(flash, dict) and isinstance(flash.get("target"), str):
        try:
            from msflash.processing import datasets

            grid = WavelengthGrid(float(wavelengths[0]), float(wavelengths[-1]), float(wavelengths[1] - wavelengths[0]))
            from msflash.acquisition.app.plot_style import in_plot_unit

            target = in_plot_unit(datasets.illuminant(flash["target"], grid))[:, 0]
        except Exception:  # noqa: BLE001 - an unknown target: drawn without it
            target = None
    figure, axis = plt.subplots(figsize=FIGSIZE)
    draw_flash_mixes(axis, wavelengths, led_values, values, solutions, target, peak)
    for line in axis.get_lines():
        line.set_gid("mix-" + str(line.get_label()).split(" (")[0].replace(" ", "-"))
    axis.set_xlim(float(wavelengths[0]), float(wavelengths[-1]))
    axis.set_title("Flash mixes")
    spectral_axis(axis, "peak of the estimate")
    axis.legend(loc="upper right", fontsize=7)
    return {"ambient": ambient_chart, "mixes": _svg(figure)}


def _scaled_truth(sequence: dict, wavelengths: np.ndarray, values: np.ndarray, unit: str) -> np.ndarray | None:
    """A simulated rig's true ambient, scaled onto the estimate ``values`` (least squares, the metric's), or None."""
    msflash = sequence.get("msflash")
    truth = msflash.get("true_ambient") if isinstance(msflash, dict) else None
    if not isinstance(truth, dict) or len(truth.get("spd", [])) != wavelengths.size:
        return None
    curve = _plot_unit(wavelengths, np.asarray(truth["spd"], dtype=float)[:, None], unit)[:, 0]
    if float(curve @ curve) <= 0:
        return None
    return curve * float(values @ curve) / float(curve @ curve)


def _ambient_chart(
    wavelengths: np.ndarray, values: np.ndarray, sigma: np.ndarray, truth: np.ndarray | None, covers: str
) -> str:
    """The estimate (in units of its peak) ± 1σ and the scaled truth, as SVG.

    The axes hold every series: the band and the truth set the range, up to :data:`BAND_TOP`; a band wider than
    that is drawn to the axes' edge (its geometry stays inside the plot area, never over the tick labels).
    """
    from msflash.acquisition.app.plot_style import PALETTE, pyplot, spectral_axis

    lower, upper = values - sigma, values + sigma
    drawn = [upper] if truth is None else [upper, truth]
    top = min(max(1.3, *(float(np.max(series)) + 0.05 for series in drawn)), BAND_TOP)
    bottom = max(min(0.0, float(np.min(lower)) - 0.05, float(np.min(values)) - 0.05), -BAND_TOP)
    figure, axis = pyplot().subplots(figsize=FIGSIZE)
    axis.fill_between(
        wavelengths, np.clip(lower, bottom, top), np.clip(upper, bottom, top), color=PALETTE.ambient, alpha=0.2,
        lw=0, label=f"estimate ± 1σ ({covers})", gid="band",
    )  # fmt: skip
    axis.plot(wavelengths, values, color=PALETTE.ambient, lw=2, label="estimate", gid="estimate")
    if truth is not None:
        axis.plot(
            wavelengths, np.clip(truth, bottom, top), color=PALETTE.truth, ls="--", lw=1.5,
            label="true ambient (scaled)", gid="truth",
        )  # fmt: skip
    axis.set_ylim(bottom, top)
    axis.set_xlim(float(wavelengths[0]), float(wavelengths[-1]))
    axis.set_title("Ambient illuminant (estimate)")
    spectral_axis(axis, "peak of the estimate")
    axis.legend(loc="upper left", fontsize=7)
    return _svg(figure)
