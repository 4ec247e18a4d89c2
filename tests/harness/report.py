"""The harness's outputs: the markdown table (docs/ambient-harness.md) and the per-case CSV.

Aggregates per split and variant (mean and worst of RMSE ÷ LED bound, misses, band coverage,
warning recall and false alarms), the same per family (RGB/Bayer, wavelength grid, LED count,
light type, bit depth), the warning confusion table, and the worst cases.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from tests.harness import metrics, splits
from tests.harness.cases import CASES_PER_SPLIT, GRIDS, QUICK_EVERY, RATIO_RANGE
from tests.harness.physics_cases import CASES_PER_SPLIT as PHYSICS_CASES
from tests.harness.physics_cases import QUICK_EVERY as PHYSICS_QUICK
from tests.harness.run import CaseResult, case_record
from tests.harness.variants import Variant


def _light_kind(result: CaseResult) -> str:
    from tests.harness.physics_cases import light_of

    light = light_of(result.case)
    return light.kind if not light.second_kind else "+".join(sorted((light.kind, light.second_kind)))


FAMILIES: dict[str, Callable[[CaseResult], object]] = {
    "RGB / Bayer": lambda r: r.case.mosaic,
    "CFA layout": lambda r: r.case.cfa or "RGB",
    "wavelength grid": lambda r: r.case.grid_label,
    "LED count": lambda r: r.case.led_count,
    "light type": lambda r: r.case.light_type,
    "bit depth": lambda r: r.case.bits,
    "spectral unit": lambda r: r.case.unit,
    "light kind": _light_kind,
}
"""Family dimensions the report breaks results down by."""
LIBRARY_FAMILIES = (
    "RGB / Bayer",
    "CFA layout",
    "wavelength grid",
    "LED count",
    "light type",
    "bit depth",
    "spectral unit",
)
PHYSICS_FAMILIES = ("light type", "CFA layout", "light kind", "LED count", "wavelength grid", "bit depth")


def _number(value: float | None, digits: int = 2) -> str:
    return "—" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def _percent(value: float | None) -> str:
    return "—" if value is None or math.isnan(value) else f"{100 * value:.0f} %"


def _ratios(results: Sequence[CaseResult], variant: str) -> list[float]:
    return [m.ratio if (m := r.of(variant)) is not None else math.nan for r in results]


def _coverage(results: Sequence[CaseResult], variant: str) -> tuple[float | None, float | None]:
    pairs = [
        (m.coverage_1, m.coverage_2) for r in results if (m := r.of(variant)) is not None and m.coverage_1 is not None
    ]
    if not pairs:
        return None, None
    values = np.array(pairs, float)
    return float(values[:, 0].mean()), float(values[:, 1].mean())


def _confusion(results: Sequence[CaseResult], variant: str) -> metrics.Confusion | None:
    rows = [
        (m.ratio, bool(m.warnings))
        for r in results
        if (m := r.of(variant)) is not None and m.warnings is not None and math.isfinite(m.ratio)
    ]
    if not rows:
        return None
    ratios, warned = zip(*rows)
    return metrics.confusion(ratios, warned)


def _by_split(results: Sequence[CaseResult]) -> list[tuple[str, list[CaseResult]]]:
    return [
        (split, [r for r in results if r.case.split == split])
        for split in splits.SPLITS
        if any(r.case.split == split for r in results)
    ]


def summary_table(results: Sequence[CaseResult], variants: Sequence[Variant]) -> list[str]:
    """Per split and variant: cases, failures, mean / worst ratio, misses, coverage, warning recall / false alarms."""
    lines = [
        "| split | variant | cases | failed | mean ratio | worst ratio | misses (> 1.3) | ±1σ coverage "
        "| ±2σ coverage | warning recall | false alarms |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for split, subset in _by_split(results):
        for variant in variants:
            summary = metrics.summarise(_ratios(subset, variant.name))
            cover_1, cover_2 = _coverage(subset, variant.name)
            matrix = _confusion(subset, variant.name)
            lines.append(
                f"| {split} | {variant.name} | {summary.count} | {summary.failed} | {_number(summary.mean)} "
                f"| {_number(summary.worst)} | {_percent(summary.miss_rate)} | {_percent(cover_1)} "
                f"| {_percent(cover_2)} | {_percent(matrix.recall if matrix else None)} "
                f"| {_percent(matrix.false_alarm_rate if matrix else None)} |"
            )
    return lines


def family_table(results: Sequence[CaseResult], variants: Sequence[Variant], family: str) -> list[str]:
    """Mean / worst ratio per value of one family dimension, per split, for every variant."""
    key = FAMILIES[family]
    lines = [
        f"| {family} | split | cases | " + " | ".join(f"{v.name} mean / worst" for v in variants) + " |",
        "|---|---|---|" + "---|" * len(variants),
    ]
    values = sorted({key(r) for r in results}, key=str)
    for value in values:
        for split, subset in _by_split(results):
            group = [r for r in subset if key(r) == value]
            if not group:
                continue
            cells = []
            for variant in variants:
                summary = metrics.summarise(_ratios(group, variant.name))
                cells.append(f"{_number(summary.mean)} / {_number(summary.worst)}")
            lines.append(f"| {value} | {split} | {len(group)} | " + " | ".join(cells) + " |")
    return lines


def confusion_table(results: Sequence[CaseResult], variants: Sequence[Variant]) -> list[str]:
    """Warned / silent misses and non-misses per split for every variant that can warn."""
    lines = [
        "| split | variant | warned misses | silent misses | warned non-misses | silent non-misses "
        "| recall | false-alarm rate |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for split, subset in _by_split(results):
        for variant in variants:
            matrix = _confusion(subset, variant.name)
            if matrix is None:
                continue
            lines.append(
                f"| {split} | {variant.name} | {matrix.warned_misses} | {matrix.silent_misses} "
                f"| {matrix.warned_good} | {matrix.silent_good} | {_percent(matrix.recall)} "
                f"| {_percent(matrix.false_alarm_rate)} |"
            )
    return lines


def worst_cases(results: Sequence[CaseResult], variant: str, count: int = 5) -> list[str]:
    """The ``count`` worst cases of one variant per split, with their conditions."""
    lines = ["| split | case | ratio | RMSE | bound | warned | conditions |", "|---|---|---|---|---|---|---|"]
    for split, subset in _by_split(results):
        scored = [(m.ratio, r, m) for r in subset if (m := r.of(variant)) is not None and math.isfinite(m.ratio)]
        for ratio, result, measured in sorted(scored, key=lambda t: -t[0])[:count]:
            c = result.case
            light = c.light
            if light.startswith("physics:"):
                from tests.harness.physics_cases import light_of

                light = light_of(c).label
            conditions = (
                f"{c.mosaic} {c.cfa or ''} {c.bits}-bit, {c.grid_label} {c.unit}, {c.leds}, "
                f"{c.light_type} '{light}', {c.camera}, ratio {c.ratio:.2f}, {c.exposures} exposures"
                + (f", vignetting {c.vignetting:.2f}" if c.vignetting < 1 else "")
                + (", specular" if c.specular else "")
            )
            lines.append(
                f"| {split} | {c.name} | {ratio:.2f} | {measured.rmse:.3f} | {result.bound:.3f} "
                f"| {'yes' if measured.warnings else 'no'} | {conditions} |"
            )
    return lines


def failure_map(results: Sequence[CaseResult], variants: Sequence[Variant], by: str = "light kind") -> list[str]:
    """Where each model fails and whether it warned: per value of ``by`` and split, each variant's misses
    (ratio > 1.3) as ``warned / misses`` of the cases (— when the variant cannot warn)."""
    key = FAMILIES[by]
    lines = [
        f"| {by} | split | cases | " + " | ".join(f"{v.name} warned / misses" for v in variants) + " |",
        "|---|---|---|" + "---|" * len(variants),
    ]
    for value in sorted({key(r) for r in results}, key=str):
        for split, subset in _by_split(results):
            group = [r for r in subset if key(r) == value]
            if not group:
                continue
            cells = []
            for variant in variants:
                measured = [m for r in group if (m := r.of(variant.name)) is not None and math.isfinite(m.ratio)]
                misses = [m for m in measured if m.ratio > metrics.MISS_FACTOR]
                if not misses:
                    cells.append("·")
                elif any(m.warnings is None for m in misses):
                    cells.append(f"— / {len(misses)}")
                else:
                    cells.append(f"{sum(bool(m.warnings) for m in misses)} / {len(misses)}")
            lines.append(f"| {value} | {split} | {len(group)} | " + " | ".join(cells) + " |")
    return lines


def failures(results: Sequence[CaseResult]) -> list[str]:
    """Failed estimates and Python warnings seen, one line each (at most 20)."""
    lines = []
    for result in results:
        for m in result.measured:
            if m.error:
                lines.append(f"- {result.case.name} {m.variant}: failed: {m.error[:200]}")
            for note in m.notes[:2]:
                lines.append(f"- {result.case.name} {m.variant}: {note[:200]}")
    return lines[:20] + ([f"- … and {len(lines) - 20} more"] if len(lines) > 20 else [])


INTRO = """# Ambient-estimation harness (issue 17)

Measured results of every ambient estimator variant on sequences rendered **outside msflash's
simulator**, from measured spectra the simulated rig does not use by default. Generated by
`{command}` ({elapsed:.0f} s, {jobs} jobs, commit `{commit}`); do not edit by hand.

## What it renders
`tests/harness/render.py`, its own renderer (it shares no code with msflash's image formation or
writers; it reuses the independent generator `tests/processing/unseen_sequences.py`'s CSV reader,
interpolation and OpenImageIO writer). Reflectance × light × camera are integrated on a 1-nm grid
(380–780 nm); the sequence carries its LED spectra and camera responsivities *sampled* on the
case's grid ({grids}), in energy or photon units. Per case: 128 × 160 pixels of 20–60 surfaces in
16-pixel patches (plus one white patch) with a ±5 % fixed texture; RGB or raw Bayer (RGGB, BGGR,
GRBG, GBRG); 10/12/14/16-bit data with black levels; photon (Poisson, 5 000–20 000 e⁻ full
well) and read noise (2–10 e⁻); in half of the cases cos⁴ vignetting (corners at 0.50–0.85) and
in half unequal exposures and gains per frame; a clipping specular strip in a quarter; an ambient
/ flash ratio (white surface, ambient over the mean single-LED signal) log-uniform in
{ratio_low:g}–{ratio_high:g}. The sequence is an ambient frame and one frame per LED (ambient + that LED).

Sources: lights — the 401-light library (Houser et al. 2013, `/work/shared/data/lights/`);
LEDs — the paper's 7 Luxeon LEDs and its 3–6 subsets, the ISETCam 4-, 5-, 6- and 8-LED sets;
cameras — the paper's 34, the 7 ISETCam cameras on their own grids, colour-science's Nikon 5100
and Sigma SDMerill; surfaces — Vrhel Munsell and Objects, Macbeth, Gretag SG 140, Esser.

## Splits
- Lights: msflash's library split (`processing.light_library.library_lights`, near-copy groups
  split whole; the light prior trains on the tuning side only).
- Cameras: held out when `zlib.crc32(identity) % 1000 < 300` (`tests/harness/splits.py`; one
  camera in two files is one identity).
- Surfaces: tuning scenes draw from Vrhel Munsell + Objects + Macbeth, held-out scenes from
  Gretag SG 140 + Esser; none is Natural-100.
- A held-out case uses a held-out light, camera and surfaces only. {per_split} cases per split,
  balanced over mosaic, bit depth, grid, LED set and light type (`tests/harness/cases.py`).
  **Never tune on the held-out rows.**

## Variants
{variants}

## Metrics
- ratio = spectrum RMSE ÷ LED bound. RMSE is the paper's (estimate max-normalised, truth
  least-squares scaled onto it); the LED bound is that RMSE for the best non-negative LED fit of
  the truth (nnls). Ratios below 1 happen: the bound minimises squared error before the
  normalisation, not the RMSE itself.
- A *miss* is ratio > {miss:g}. Warning recall = warned misses ÷ misses; false alarms = warned
  non-misses ÷ non-misses (variants that cannot warn show —).
- Band coverage: share of wavelengths where the (scaled) truth lies within ±1σ / ±2σ of the
  estimate, the band scaled like the estimate; mean over cases. Targets 55–80 % and ≥ 90 %.
  Variants without a band show —.

## Limits of the harness
- The ambient is uniform and the flash lights the scene with the same geometry (no shading
  difference between ambient and flash, no motion, no flicker); the LED spectra and
  responsivities written are the ones rendered with (no calibration error beyond the grid's
  sampling).
- The light library stops at 780 nm: cameras with infrared response (NikonD200IR) see nothing
  beyond it.
- Light types are msflash's keyword classification of the labels; a few LED lamps named by their
  CCT ("… LED … 2700K") are classed as incandescent.
- `authors` uses α = 100 as the authors did on full frames (320 × 256 pixels after their 4×
  downsampling); these frames have far fewer pixels, so the roughness term weighs more.
  `authors-alpha-scaled` scales α by the pixel count (the paper's own rationale), untuned.

## Reproduce
```
cd /path/to/msflash && python -m tests.harness.ambient --out docs/ambient-harness.md --jobs 2
```
Options: `--split tuning|held_out|both`, `--variant NAME` (restrict) or `--variant NAME="ARGS"`
(add `msflash estimate SEQ --json ARGS`), `--quick` (every {quick}th case). The per-case
results (one row per case: its conditions, LED bound, and every variant's ratio, band coverage,
warning count) are in `{csv_name}` beside this file.
"""


def markdown(
    results: Sequence[CaseResult],
    variants: Sequence[Variant],
    *,
    command: str,
    elapsed: float,
    jobs: int,
    commit: str,
    csv_name: str,
    suite: str = "library",
) -> str:
    """The whole report (``suite``: ``library`` lights or ``physics`` lights)."""
    variant_lines = "\n".join(f"- `{v.name}`: `{v.command}`" for v in variants)
    intro = INTRO if suite == "library" else PHYSICS_INTRO
    parts = [
        intro.format(
            command=command,
            elapsed=elapsed,
            jobs=jobs,
            commit=commit,
            grids=", ".join(f"{a:g}–{b:g}/{c:g}" for a, b, c in GRIDS),
            ratio_low=RATIO_RANGE[0],
            ratio_high=RATIO_RANGE[1],
            per_split=CASES_PER_SPLIT if suite == "library" else PHYSICS_CASES,
            variants=variant_lines,
            miss=metrics.MISS_FACTOR,
            quick=QUICK_EVERY if suite == "library" else PHYSICS_QUICK,
            csv_name=csv_name,
        ),
        "## Summary",
        "",
        *summary_table(results, variants),
        "",
        "## Warning confusion (miss: ratio > 1.3)",
        "",
        *confusion_table(results, variants),
        "",
    ]
    for family in LIBRARY_FAMILIES if suite == "library" else PHYSICS_FAMILIES:
        title = "light family" if suite == "physics" and family == "light type" else family
        parts += [f"## Per family: {title} (ratio mean / worst)", "", *family_table(results, variants, family), ""]
    if suite == "physics":
        parts += [
            "## Failure map: where each model misses, and whether it warned",
            "",
            "Per light kind: `warned / misses` (· no miss). Every model's warnings: `docs/light-families.md`.",
            "",
            *failure_map(results, variants),
            "",
        ]
    for name in ("default", "auto") if suite == "physics" else ("default",):
        if any(v.name == name for v in variants):
            parts += [f"## Worst cases of `{name}`", "", *worst_cases(results, name), ""]
    problems = failures(results)
    parts += ["## Failures and Python warnings", "", *(problems or ["none"]), ""]
    return "\n".join(parts)


PHYSICS_INTRO = """# Ambient-estimation harness on lights from physics (issue 30)

Measured results of every ambient estimator variant on sequences lit by lights **generated from physics**,
in no library: thermal (Planck, tungsten's emissivity, CIE daylight), discharge (mercury, sodium, metal-halide
and rare-earth phosphor lines at their known wavelengths over continua), solid-state (phosphor-converted
whites with free pump and phosphor bands, violet-pumped whites, RGB/RGBA luminaires), transmitted (daylight at
depth in water of a composition, thermal light through dyed gels) and mixtures of two
(`tests/harness/physics_lights.py`). Generated by `{command}` ({elapsed:.0f} s, {jobs} jobs, commit
`{commit}`); do not edit by hand.

## What it renders
The library harness's renderer (`tests/harness/render.py`, independent of msflash's image formation):
reflectance × light × camera on a 1-nm grid (380–780 nm), the sequence carrying its LED spectra and
responsivities sampled on the case's grid ({grids}); the truth is the light as a spectroradiometer with a
triangular slit as wide as the grid step reports it. RGB or raw Bayer (RGGB, BGGR, GRBG, GBRG, a fifth each),
10–16 bits, photon and read noise, vignetting, unequal exposures, specular strips, ambient / flash ratio
{ratio_low:g}–{ratio_high:g}, as in the library harness.

## Splits
- Lights: every kind's parameters are drawn from **disjoint intervals** per split
  (`physics_lights.RANGES`): other colour temperatures, pump and phosphor wavelengths, phosphor blends, line
  widths, depths and water compositions, gels.
- Cameras: tuning cases use the library harness's tuning cameras or ten cameras made from physics
  (`physics:t00…t09`: silicon QE × dye filters × IR cut, `tests/harness/physics_cameras.py`); held-out cases
  its held-out cameras or ten other physics cameras (`physics:h00…h09`).
- Surfaces: tuning scenes Vrhel Munsell + Objects + Macbeth; held-out scenes the CIE 2017 colour-fidelity
  set (TM-30's 99, used nowhere else), Gretag SG 140 and Esser — none is Natural-100.
- {per_split} cases per split, balanced over family, CFA layout, LED set, grid and bit depth
  (`tests/harness/physics_cases.py`). **Never tune on the held-out rows.**

## Variants
{variants}

## Metrics
As the library harness (`docs/ambient-harness.md`): ratio = spectrum RMSE ÷ LED bound; a *miss* is a ratio
above {miss:g}; recall = warned misses ÷ misses, false alarms = warned non-misses ÷ non-misses; band
coverage = share of wavelengths with the scaled truth within ±1σ / ±2σ (targets 55–80 % and ≥ 90 %).

## Reproduce
```
python -m tests.harness.ambient --suite physics --out docs/physics-harness.md --jobs 2 --cache .harness-cache
```
`--quick` keeps every {quick}th case; the per-case results are in `{csv_name}` beside this file.
"""


def write_csv(results: Sequence[CaseResult], path: Path) -> None:
    """One row per case: its conditions and LED bound, then per variant ``VARIANT:ratio`` (RMSE ÷ bound),
    ``:coverage_1``, ``:coverage_2``, ``:warnings`` (count; empty: cannot warn), ``:error`` and ``:flags``
    (Python warnings seen)."""
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = None
        for result in results:
            row = {**case_record(result), "bound": _round(result.bound)}
            for m in result.measured:
                row.update(
                    {
                        f"{m.variant}:ratio": _round(m.ratio),
                        f"{m.variant}:coverage_1": _round(m.coverage_1),
                        f"{m.variant}:coverage_2": _round(m.coverage_2),
                        f"{m.variant}:warnings": "" if m.warnings is None else len(m.warnings),
                        f"{m.variant}:error": m.error[:80],
                        f"{m.variant}:flags": "; ".join(note[:60] for note in m.notes),
                    }
                )
            if writer is None:
                writer = csv.DictWriter(handle, list(row))
                writer.writeheader()
            writer.writerow(row)


def _round(value: float | None) -> str:
    return "" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.4g}"
