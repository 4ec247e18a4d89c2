"""The page, the per-case CSV and the chart of :mod:`tests.harness.block_size` (block size against accuracy and time)."""

from __future__ import annotations

import csv
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

FAMILY_LABELS = {
    "led": "LED model (eq. 4–6, the default)",
    "prior": "light prior (--model prior)",
    "local": "local tiles (--method auto)",
}
SPLITS = ("tuning", "held_out")
RULE_BLOCKS = (4, 8)
"""The block sizes ``acquisition.session.analysis.block_factor`` picks (ringed on the chart)."""


def _values(rows: Iterable[dict[str, Any]], key: str) -> np.ndarray:
    values = np.asarray([row.get(key, np.nan) for row in rows], float)
    return values[np.isfinite(values)]


def _pick(rows: list[dict[str, Any]], **match: Any) -> list[dict[str, Any]]:
    return [row for row in rows if all(row.get(key) == value for key, value in match.items())]


def _median(values: np.ndarray) -> float:
    return float(np.median(values)) if values.size else float("nan")


def _mean(values: np.ndarray) -> float:
    return float(np.mean(values)) if values.size else float("nan")


def _format(value: float, digits: int = 2) -> str:
    return "—" if not np.isfinite(value) else f"{value:.{digits}f}"


def accuracy(rows: list[dict[str, Any]], split: str, family: str, block: int) -> tuple[float, int]:
    """Mean RMSE ÷ LED bound of one split, family and block size, and the number of cases it failed on."""
    chosen = _pick(rows, split=split, family=family, block=block)
    values = _values(chosen, "ratio")
    return (float(values.mean()) if values.size else float("nan")), len(chosen) - values.size


def time_ratio(raw: dict[str, Any], family: str, block: int) -> float:
    """The estimate's time ÷ the copy's on the bench scene."""
    return next((t["ratio"] for t in raw["times"] if t["family"] == family and t["block"] == block), float("nan"))


def write_csv(path: Path, rows: list[dict[str, Any]]) -> None:
    """One row per case × family × block size."""
    from tests.harness.block_size import FIELDS

    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, FIELDS, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({key: f"{value:.4g}" if isinstance(value, float) else value for key, value in row.items()})


def plot(path: Path, raw: dict[str, Any]) -> None:
    """Mean accuracy against time: columns the two splits, rows the LED-span families (LED model, local
    tiles) and the light prior; one line per family through the even block sizes, odd ones as crosses,
    each point labelled by its block size. A block size that failed on some case is left out."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FixedLocator, NullFormatter, ScalarFormatter

    rows = raw["rows"]
    blocks = sorted({row["block"] for row in rows})
    colours = {"led": "tab:blue", "local": "tab:green", "prior": "tab:orange"}
    panels = (("led", "local"), ("prior",))
    offsets = {"led": (4, 4), "local": (4, -10), "prior": (4, 4)}
    figure, axes = plt.subplots(2, 2, figsize=(13, 9), sharex=True)
    for column, split in enumerate(SPLITS):
        for row_index, families in enumerate(panels):
            axis = axes[row_index, column]
            for family in families:
                colour = colours[family]
                points = []
                for block in blocks:
                    mean, failed = accuracy(rows, split, family, block)
                    elapsed = time_ratio(raw, family, block)
                    if not failed and np.isfinite(mean) and np.isfinite(elapsed):
                        points.append((elapsed, mean, block))
                even = [p for p in points if p[2] % 2 == 0 or p[2] == 1]
                odd = [p for p in points if p[2] % 2 == 1 and p[2] != 1]
                axis.plot([p[0] for p in even], [p[1] for p in even], "-o", color=colour, label=FAMILY_LABELS[family])
                axis.plot([p[0] for p in odd], [p[1] for p in odd], "x", color=colour, alpha=0.6)
                chosen = [p for p in points if p[2] in RULE_BLOCKS]
                axis.scatter(
                    [p[0] for p in chosen],
                    [p[1] for p in chosen],
                    s=140,
                    facecolors="none",
                    edgecolors="black",
                    zorder=3,
                )
                for x, y, block in points:
                    axis.annotate(
                        str(block), (x, y), textcoords="offset points", xytext=offsets[family], fontsize=7, color=colour
                    )
            axis.set_xscale("log")
            axis.xaxis.set_major_locator(FixedLocator([2, 3, 4, 6, 10, 20, 40, 60]))
            axis.xaxis.set_major_formatter(ScalarFormatter())
            axis.xaxis.set_minor_formatter(NullFormatter())
            axis.grid(True, which="both", alpha=0.3)
            axis.set_title(f"{split.replace('_', '-')} split", fontsize=10)
            if column == 0:
                axis.set_ylabel("mean spectrum RMSE ÷ LED bound")
            if row_index == 1:
                axis.set_xlabel("time ÷ a copy of the frames (bench scene 1280×1024, interleaved median)")
    handles, labels = [], []
    for axis in axes[:, 0]:
        more_handles, more_labels = axis.get_legend_handles_labels()
        handles += more_handles
        labels += more_labels
    handles.append(plt.Line2D([], [], marker="x", linestyle="", color="grey"))
    labels.append("odd block size (no noise probe)")
    handles.append(plt.Line2D([], [], marker="o", markersize=11, markerfacecolor="none", color="black", linestyle=""))
    labels.append("the app's rule: 8 × 8 (large frames), 4 × 4 (small ones)")
    figure.legend(handles, labels, loc="lower center", ncol=3, frameon=False)
    figure.suptitle(
        "Block size (numbers at the points) against accuracy on the harness and time on the bench scene",
        fontsize=12,
    )
    figure.tight_layout(rect=(0, 0.07, 1, 0.96))
    figure.savefig(path, dpi=100)
    plt.close(figure)


def _bench_table(raw: dict[str, Any]) -> list[str]:
    bench = raw["bench"]
    seeds = len({row["seed"] for row in bench})
    lines = [
        "| block | noise correction | RMSE vs truth (reference) | worst z, own α | worst z, same α "
        "| within ±2σ, same α | band ratio | worst z in the reported band |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for block in sorted({row["block"] for row in bench}):
        chosen = _pick(bench, block=block)
        lines.append(
            f"| {block} | {chosen[0]['correction']} | {_format(_median(_values(chosen, 'rmse')), 3)} "
            f"({_format(_median(_values(chosen, 'reference_rmse')), 3)}) "
            f"| {_format(_median(_values(chosen, 'worst_z')), 1)} "
            f"| {_format(_median(_values(chosen, 'worst_z_same_alpha')), 1)} "
            f"| {_format(100 * _median(_values(chosen, 'within_2sigma_same_alpha')), 0)} % "
            f"| {_format(_median(_values(chosen, 'band_ratio')))} "
            f"| {_format(_median(_values(chosen, 'worst_z_full')))} |"
        )
    lines.append("")
    lines.append(
        f"Medians over {seeds} noise seeds. z: |block − all-pixel| ÷ the all-pixel estimate's pixel-noise σ, worst "
        "wavelength; *own α*: each solved with its own discrepancy α (what `msflash estimate` gives), *same α*: "
        "the reference re-solved at the block estimate's α; band ratio: the block band ÷ the reference's; the "
        "last column divides by the reference's reported band (pixel noise and the LED model's error)."
    )
    return lines


def _harness_agreement_table(rows: list[dict[str, Any]]) -> list[str]:
    lines = [
        "| block | split | cases | median worst z, own α | median worst z, same α | 90th pct, same α "
        "| cases ≤ 3σ, same α | median band ratio | cases within the reported band | mean RMSE ÷ bound (reference) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for block in sorted({row["block"] for row in rows}):
        for split in SPLITS:
            chosen = _pick(rows, split=split, family="led", block=block)
            z, same, full = (_values(chosen, key) for key in ("worst_z", "worst_z_same_alpha", "worst_z_full"))
            lines.append(
                f"| {block} | {split} | {z.size} | {_format(_median(z), 1)} | {_format(_median(same), 1)} "
                f"| {_format((float(np.percentile(same, 90)) if same.size else float('nan')), 1)} | {_format(100 * _mean((same <= 3).astype(float)), 0)} % "
                f"| {_format(_median(_values(chosen, 'band_ratio')))} "
                f"| {_format(100 * _mean((full <= 1).astype(float)), 0)} % "
                f"| {_format(_mean(_values(chosen, 'ratio')))} ({_format(_mean(_values(chosen, 'reference_ratio')))}) |"
            )
    return lines


def _accuracy_table(raw: dict[str, Any]) -> list[str]:
    rows = raw["rows"]
    families = ("led", "prior", "local")
    header = "| block | " + " | ".join(f"{f} tuning | {f} held-out | {f} time" for f in families) + " |"
    lines = [header, "|---|" + "---|" * (3 * len(families))]
    for block in sorted({row["block"] for row in rows}):
        cells = []
        for family in families:
            for split in SPLITS:
                mean, failed = accuracy(rows, split, family, block)
                cells.append(_format(mean) + (f" ({failed} failed)" if failed else ""))
            cells.append(_format(time_ratio(raw, family, block), 1) + "×")
        lines.append(f"| {block} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append(
        f"All-pixel reference (weighted, its noise removed with the known noise): {time_ratio(raw, 'reference', 1):.1f}× a copy."
    )
    return lines


def write_outputs(out: Path, png: Path, raw: dict[str, Any], csv_path: Path | None = None) -> None:
    """The chart (``png``), the per-case CSV (``csv_path``, when given) and the tables, appended to the page's
    hand-written part (everything in ``out`` above the line ``<!-- generated -->``, kept)."""
    plot(png, raw)
    if csv_path is not None:
        write_csv(csv_path, raw["rows"])
    marker = "<!-- generated -->"
    kept = out.read_text().split(marker)[0] if out.exists() else "# Block size\n\n"
    cases = len({row["case"] for row in raw["rows"]})
    generated = [
        marker,
        "",
        f"Generated by `python -m tests.harness.block_size{' --quick' if raw.get('quick') else ''} --jobs 2` "
        f"({cases} harness cases, {raw.get('rounds', '?')} interleaved timing pairs per point, "
        f"{raw.get('seconds', 0) / 60:.0f} min on the shared 2-CPU machine); the tables below are rewritten by it.",
        "",
        "### Bench scene (1280 × 1024 RGB, 7 LEDs, tungsten): the LED model against the all-pixel reference",
        "",
        *_bench_table(raw),
        "",
        "### Harness sweep: the LED model against the all-pixel reference, per case",
        "",
        *_harness_agreement_table(raw["rows"]),
        "",
        "### Accuracy (mean RMSE ÷ LED bound) and time (÷ a copy of the frames) per family and block size",
        "",
        *_accuracy_table(raw),
        "",
        f"![accuracy against time]({png.name})",
        "",
    ]
    out.write_text(kept + "\n".join(generated))
