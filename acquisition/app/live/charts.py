"""The spectra of a run as SVG drawn on the server: the estimate with its band, the flash mixes.

The page's plots are plain SVG written here from the run's own files (``estimate.json``,
``flash-*.json``, ``sequence/sequence.json``), so a run of an earlier session draws the same way and the
page needs no plotting script or network. Left: the estimated ambient ± 1σ (the band ``estimate.json``
describes) and, on a simulated rig, the true ambient scaled onto it (least squares, the metric's scaling);
right: the matching and complementary flashes and ambient + complementary, as ``spectra.png`` shows them.
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from msflash.acquisition.app.live.runs import read_json

WIDTH, HEIGHT = 520, 260
LEFT, RIGHT, TOP, BOTTOM = 44, 12, 24, 34
COLOURS = {
    "estimate": "#1f77b4",
    "truth": "#222222",
    "matching": "#ff7f0e",
    "complementary": "#2ca02c",
    "total": "#9467bd",
}


def _xy(wavelengths: np.ndarray, values: np.ndarray, peak: float) -> list[tuple[float, float]]:
    span = float(wavelengths[-1] - wavelengths[0]) or 1.0
    x = LEFT + (wavelengths - wavelengths[0]) / span * (WIDTH - LEFT - RIGHT)
    y = TOP + (1.0 - np.clip(values / peak, -0.05, 1.1) / 1.1) * (HEIGHT - TOP - BOTTOM)
    return list(zip(x.tolist(), y.tolist()))


def _points(points: Sequence[tuple[float, float]]) -> str:
    return " ".join(f"{x:.1f},{y:.1f}" for x, y in points)


def _frame(title: str, wavelengths: np.ndarray, body: list[str], legend: list[tuple[str, str, str]]) -> str:
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" class="chart" viewBox="0 0 {WIDTH} {HEIGHT}" '
        f'width="{WIDTH}" height="{HEIGHT}" role="img" aria-label="{html.escape(title)}">',
        f'<text x="{LEFT}" y="15" class="title">{html.escape(title)}</text>',
        f'<rect x="{LEFT}" y="{TOP}" width="{WIDTH - LEFT - RIGHT}" height="{HEIGHT - TOP - BOTTOM}" class="axes"/>',
    ]
    first, last = float(wavelengths[0]), float(wavelengths[-1])
    for tick in range(int(np.ceil(first / 50) * 50), int(last) + 1, 50):
        x = LEFT + (tick - first) / ((last - first) or 1.0) * (WIDTH - LEFT - RIGHT)
        parts.append(f'<text x="{x:.1f}" y="{HEIGHT - BOTTOM + 14}" class="tick">{tick}</text>')
    parts.append(f'<text x="{WIDTH - RIGHT}" y="{HEIGHT - 4}" class="label" text-anchor="end">wavelength (nm)</text>')
    parts += body
    for i, (css, colour, text) in enumerate(legend):
        y = TOP + 14 + 14 * i
        parts.append(
            f'<line x1="{LEFT + 8}" x2="{LEFT + 26}" y1="{y - 4}" y2="{y - 4}" stroke="{colour}" class="{css}"/>'
        )
        parts.append(f'<text x="{LEFT + 30}" y="{y}" class="legend">{html.escape(text)}</text>')
    parts.append("</svg>")
    return "\n".join(parts)


def _polyline(css: str, colour: str, points: list[tuple[float, float]], dash: str = "") -> str:
    dashed = f' stroke-dasharray="{dash}"' if dash else ""
    return (
        f'<polyline class="{css}" fill="none" stroke="{colour}" stroke-width="2"{dashed} points="{_points(points)}"/>'
    )


def run_charts(folder: Path) -> dict[str, str] | None:
    """``{"ambient": svg, "mixes": svg}`` for the run in ``folder``, or None before its report exists."""
    estimate = read_json(folder / "estimate.json")
    sequence = read_json(folder / "sequence" / "sequence.json")
    if not isinstance(estimate, dict) or not isinstance(sequence, dict):
        return None
    try:
        wavelengths = np.asarray(estimate["wavelengths_nm"], dtype=float)
        spectrum = np.asarray(estimate["spectrum"], dtype=float)
        std = np.asarray(estimate["spectrum_std"], dtype=float)
        leds = np.array([led["spd"] for led in sequence["leds"]], dtype=float).T
    except (KeyError, TypeError, ValueError):
        return None
    if leds.shape[0] != wavelengths.size or spectrum.shape != wavelengths.shape or std.shape != wavelengths.shape:
        return None
    peak = float(np.max(spectrum)) or 1.0
    band = _xy(wavelengths, spectrum + std, peak) + _xy(wavelengths, spectrum - std, peak)[::-1]
    body = [
        f'<polygon class="band" fill="{COLOURS["estimate"]}" fill-opacity="0.25" points="{_points(band)}"/>',
        _polyline("estimate", COLOURS["estimate"], _xy(wavelengths, spectrum, peak)),
    ]
    legend = [("estimate", COLOURS["estimate"], "estimate ± 1σ")]
    band_meaning = str(estimate.get("band") or "")
    truth = (sequence.get("msflash") or {}).get("true_ambient") if isinstance(sequence.get("msflash"), dict) else None
    if isinstance(truth, dict) and len(truth.get("spd", [])) == wavelengths.size:
        curve = np.asarray(truth["spd"], dtype=float)
        if float(curve @ curve) > 0:
            scaled = curve * float(spectrum @ curve) / float(curve @ curve)
            body.append(_polyline("truth", COLOURS["truth"], _xy(wavelengths, scaled, peak), "6 4"))
            legend.append(("truth", COLOURS["truth"], "true ambient (scaled)"))
    if band_meaning:
        body[0] = body[0].replace("/>", f"><title>{html.escape(band_meaning)}</title></polygon>")
    ambient_chart = _frame("Ambient illuminant (estimate)", wavelengths, body, legend)

    curves: list[tuple[str, str, np.ndarray, str, str]] = []
    for mode in ("matching", "complementary"):
        flash = read_json(folder / f"flash-{mode}.json")
        if not isinstance(flash, dict):
            continue
        weights = np.asarray(flash.get("flash_weights", []), dtype=float)
        if weights.size != leds.shape[1]:
            continue
        curves.append((f"mix-{mode}", COLOURS[mode], leds @ weights, "", f"{mode} flash"))
        ambient_weights = np.asarray(flash.get("ambient_weights", []), dtype=float)
        if mode == "complementary" and ambient_weights.size == weights.size:
            total = leds @ (ambient_weights + weights)
            curves.append(("mix-total", COLOURS["total"], total, "", "ambient + complementary"))
    curves.append(("ambient", COLOURS["estimate"], spectrum, "2 3", "ambient (estimate)"))
    mix_peak = max(float(np.max(curve)) for _, _, curve, _, _ in curves) or 1.0
    mixes = [_polyline(css, colour, _xy(wavelengths, curve, mix_peak), dash) for css, colour, curve, dash, _ in curves]
    mix_legend = [(css, colour, text) for css, colour, _, _, text in curves]
    return {"ambient": ambient_chart, "mixes": _frame("Flash mixes", wavelengths, mixes, mix_legend)}
