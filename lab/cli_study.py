"""``msflash study NAME``: the paper's simulation studies with JSON and a plot.

``table1`` reproduces Table 1 (accuracy vs number of LEDs over 34 cameras and 23 illuminants);
``surfaces`` reproduces Fig. 5 (accuracy vs number of distinct surfaces); ``cameras`` Fig. 6
(camera invariance vs number of LEDs); ``xy`` Fig. 7 (error over the xy grid); ``failure`` maps
where the estimate fails on noisy frames and whether its warnings fire; ``pareto`` charts accuracy
against time per solver × pixel subsampling. The computation lives
in :mod:`lab.study`; this module parses options, runs it (serially, on a local dask
cluster, or on a dask scheduler at an address), prints the result and, with ``--out``, writes
``<name>.json`` and ``<name>.png`` there. Progress goes to stderr.
"""

from __future__ import annotations

import argparse
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from msflash.acquisition.app.cli_common import (
    UsageError,
    dumps_json,
    number_where,
    positive_int,
    print_json,
    progress,
    seed_int,
    whole_number,
)
from msflash.acquisition.app.options import add_scheduler_options
from msflash.acquisition.app.plot_style import PALETTE, pyplot, save_figure
from msflash.acquisition.session.dask_map import dask_mapper
from msflash.lab.cli_support import REPORTER, optional_claimed_output, relative_power
from msflash.processing.ambient import AMBIENT_METHODS
from msflash.processing.names import unknown_name
from msflash.processing.user_numbers import number_or_non_finite, plain_whole_number

STUDIES = ("table1", "surfaces", "cameras", "xy", "failure", "pareto")
"""Study names accepted by ``msflash study``."""


# The option types raise argparse.ArgumentTypeError, whose message argparse prints after the option's
# name; a ValueError (UsageError is one) would print "invalid _counts value: '0'" instead.
def _alpha(text: str) -> float | str | list[float]:
    if text in ("auto", "paper"):
        return text
    try:
        values = [number_or_non_finite(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"'{text}': expected a number ≥ 0, a comma-separated list, 'auto' or 'paper'"
        ) from None
    if not all(value >= 0 and math.isfinite(value) for value in values):
        raise argparse.ArgumentTypeError(f"'{text}': expected finite values ≥ 0")
    return values[0] if len(values) == 1 else values


def _counts(text: str) -> list[int]:
    try:
        values = [plain_whole_number(part) for part in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}': expected comma-separated whole numbers") from None
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"'{text}': expected whole numbers ≥ 1")
    return values


def _names(text: str) -> list[str]:
    values = [part.strip() for part in text.split(",") if part.strip()]
    if not values:
        raise argparse.ArgumentTypeError(f"'{text}': expected comma-separated names")
    return values


def _run(args: argparse.Namespace) -> int:
    if args.name not in STUDIES:
        raise UsageError(unknown_name("study", args.name, STUDIES))
    alpha = args.alpha
    alpha_units = args.alpha_units
    if alpha == "paper":
        if args.solver != "roughness":
            raise UsageError("--alpha paper is the authors' sweep of eq. 6; expected --solver roughness")
        from msflash.lab.study.table1 import PAPER_ALPHAS

        alpha, alpha_units = (list(PAPER_ALPHAS) if args.name == "table1" else 0.06), "paper"
    if args.name in ("failure", "pareto") and (alpha_units == "paper" or isinstance(alpha, list)):
        raise UsageError(f"--alpha for {args.name}: expected one dimensionless value or 'auto'")
    if isinstance(alpha, list) and args.name != "table1":
        raise UsageError("--alpha: a sweep is only for table1; expected one value")
    if alpha_units == "paper" and args.solver != "roughness":
        raise UsageError("--alpha-units paper is the authors' eq. 6; expected --solver roughness")
    with optional_claimed_output(args.out, "msflash study") as out:
        with dask_mapper(args.scheduler, args.workers, verbose=getattr(args, "verbose", 0) > 0) as mapper:
            if args.name == "table1":
                from msflash.lab.study.table1 import run_table1

                result = run_table1(
                    n_leds_list=args.leds,
                    method=args.solver,
                    alpha=alpha,
                    cameras=args.cameras,
                    illuminants=args.illuminants,
                    alpha_units=alpha_units,
                    progress=REPORTER,
                    map_function=mapper,
                )
            elif args.name == "surfaces":
                from msflash.lab.study.surfaces import run_surfaces

                result = run_surfaces(
                    draws=args.draws,
                    method=args.solver,
                    alpha=alpha,
                    cameras=args.cameras,
                    illuminants=args.illuminants,
                    alpha_units=alpha_units,
                    seed=args.seed,
                    progress=REPORTER,
                    map_function=mapper,
                )
            elif args.name in ("cameras", "xy"):
                if alpha_units == "paper":
                    raise UsageError(f"--alpha-units paper: not for {args.name}; expected a dimensionless alpha")
                from msflash.lab.study.cameras import run_cameras, run_xy

                run = run_cameras if args.name == "cameras" else run_xy
                result = run(
                    n_leds_list=args.leds,
                    method=args.solver,
                    alpha=alpha,
                    cameras=args.cameras,
                    illuminants=args.illuminants,
                    progress=REPORTER,
                    map_function=mapper,
                )
            elif args.name == "failure":
                from msflash.lab.study.failure import DEFAULT_CAMERAS, run_failure

                result = run_failure(
                    factors=args.factors,
                    cameras=args.cameras or DEFAULT_CAMERAS,
                    seeds=args.seeds,
                    method=args.solver,
                    alpha=alpha,
                    threshold=args.threshold,
                    keep_records=args.records,
                    progress=REPORTER,
                    map_function=mapper,
                    **({"ambients": args.ambients} if args.ambients else {}),
                )
            else:
                from msflash.lab.study.pareto import DEFAULT_CAMERAS, run_pareto

                result = run_pareto(
                    cameras=args.cameras or DEFAULT_CAMERAS,
                    seeds=args.seeds,
                    ambient_to_flash=args.ambient_to_flash,
                    patch_px=args.patch_px,
                    repeats=args.repeats,
                    progress=REPORTER,
                    map_function=mapper,
                    **({"samplings": args.samplings} if args.samplings else {}),
                    **({"ambients": args.ambients} if args.ambients else {}),
                )
        result = json.loads(dumps_json(result))  # plain JSON types (numpy scalars, tuples) from here on
        if out is not None:
            json_path = out / f"{args.name}.json"
            json_path.write_text(json.dumps(result, indent=1) + "\n", encoding="utf-8")
            png_path = out / f"{args.name}.png"
            PLOTS[args.name](result, png_path)
            result["files"] = {"json": str(json_path), "png": str(png_path)}
            progress(f"wrote {json_path} and {png_path}")
    if args.json:
        print_json(result)
    else:
        print(TEXTS[args.name](result))
    return 0


_ROWS = (
    ("pixel_rmse", "Pixel RMSE (x1e-2)"),
    ("xy_error", "CIE xy error (x1e-2)"),
    ("spectrum_rmse", "Spectrum RMSE"),
    ("multispectral_rmse", "Multispectral (LED fit)"),
)


def _table1_text(result: dict[str, Any]) -> str:
    config = result["config"]
    lines = [
        f"Table 1: {config['method']} alpha={config['alpha']} ({config['alpha_units']}), "
        f"{config['n_cameras']} cameras x {config['n_illuminants']} illuminants, {result['elapsed_s']:.1f} s",
        f"{'# LEDs':26s}" + "".join(f"{n:>15d}" for n in result["n_leds"]),
    ]
    for key, label in _ROWS:
        paper = result["paper"].get(key, [])
        cells = "".join(f"{ours:>8.3f} ({p:<4g})" for ours, p in zip(result[key], paper, strict=False))
        lines.append(f"{label:26s}{cells}")
    lines.append("(ours, paper in brackets)")
    if result.get("failures"):
        lines.append(f"{result['failures']} estimates failed (SolverError) and were left out")
    return "\n".join(lines)


def _surfaces_text(result: dict[str, Any]) -> str:
    config = result["config"]
    lines = [
        f"Fig. 5: {config['n_leds']} LEDs, {config['method']} alpha={config['alpha']}, {config['n_cameras']} "
        f"cameras x {len(config['illuminants_xy'])} illuminants, {config['draws']} draws, "
        f"{result['elapsed_s']:.1f} s",
        f"{'surfaces':>9s} {'spectrum RMSE':>14s} {'std':>7s} {'pixel RMSE x1e-2':>17s}",
    ]
    for count, mean, std, pixel in zip(
        result["counts"], result["spectrum_rmse"], result["spectrum_rmse_std"], result["pixel_rmse"], strict=True
    ):
        if mean is None:
            lines.append(f"{count:>9d} {'failed':>14s}   (estimate_ambient refused or failed for every draw)")
            continue
        lines.append(f"{count:>9d} {mean:>14.4f} {std:>7.4f} {pixel:>17.4f}")
    lines.append(f"bound (direct LED fit of the truth): {result['bound']:.4f}")
    return "\n".join(lines)


def _plot_table1(result: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    figure, axes = plt.subplots(1, 4, figsize=(16, 4))
    counts = result["n_leds"]
    for axis, (key, label) in zip(axes, _ROWS, strict=True):
        axis.plot(counts, result[key], "o-", color=PALETTE.ambient, label="msflash")
        paper = result["paper"].get(key)
        if paper:
            axis.plot(counts[: len(paper)], paper, "s--", color=PALETTE.reference, label="paper")
        axis.set_title(label, fontsize=10)
        axis.set_xlabel("# LEDs")
        axis.set_xticks(counts)
        axis.grid(True, alpha=0.3)
    axes[0].legend()
    config = result["config"]
    figure.suptitle(f"Table 1 — {config['method']}, alpha {config['alpha']} ({config['alpha_units']})", fontsize=10)
    figure.tight_layout()
    save_figure(figure, path)


def _plot_surfaces(result: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(6, 4))

    def numbers(values: list[Any]) -> list[float]:  # JSON null (all estimates failed) → NaN, not drawn
        return [float("nan") if value is None else value for value in values]

    axis.errorbar(
        result["counts"],
        numbers(result["spectrum_rmse"]),
        yerr=numbers(result["spectrum_rmse_std"]),
        fmt="o-",
        capsize=3,
        color=PALETTE.ambient,
        label="estimate (mean ± std over draws)",
    )
    axis.axhline(result["bound"], color=PALETTE.led_fit, linestyle=":", lw=1.8, label="direct LED fit")
    axis.set_xlabel("distinct surfaces")
    axis.set_ylabel("spectrum RMSE")
    axis.grid(True, alpha=0.3)
    axis.legend(fontsize=8)
    figure.tight_layout()
    save_figure(figure, path)


MAX_PARETO_PATCH_PX = 256
"""The largest pareto ``--patch-px``: its chart110 of 10 × 11 patches is then 2.9 k × 3.2 k pixels a frame
(``--patch-px 100000`` asked for a 4 TiB label map and crashed with a MemoryError)."""


_pareto_patch = whole_number(1, MAX_PARETO_PATCH_PX, "pixels")
"""argparse type of ``--patch-px``: a whole number of pixels, 1 … :data:`MAX_PARETO_PATCH_PX`."""


def _finite_at_least(lowest: float, expected: str) -> Callable[[str], float]:
    """argparse type of a finite number ≥ ``lowest`` (``--threshold nan`` counted no estimate as failed, ``-1``
    every one; ``--ambient-to-flash -1`` or ``nan`` reached the simulation)."""
    return number_where(lambda value: math.isfinite(value) and value >= lowest, expected)


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``msflash study``."""
    study = subparsers.add_parser(
        "study",
        help="simulation studies (table1: Table 1; surfaces: Fig. 5; cameras: Fig. 6; "
        "xy: Fig. 7; failure: where estimates fail and whether they warn; "
        "pareto: accuracy vs time)",
    )
    study.add_argument("name", metavar="NAME", help=f"the study: {', '.join(STUDIES)}")
    study.add_argument("--out", metavar="DIR", help="write NAME.json and NAME.png to this folder")
    study.add_argument("--json", action="store_true", help="print the result as one JSON object")
    study.add_argument(
        "--solver",
        default="tikhonov",
        choices=sorted(AMBIENT_METHODS),
        help="ambient estimator (default: tikhonov, the app's default)",
    )
    study.add_argument(
        "--alpha",
        default="auto",
        type=_alpha,
        help="roughness weight: a number, a comma-separated sweep (table1: best per metric), 'auto', "
        "or 'paper' (the authors' logspace(-3,1,10) sweep of eq. 6; --solver roughness)",
    )
    study.add_argument(
        "--alpha-units",
        default="dimensionless",
        choices=("dimensionless", "paper"),
        help="'paper': alpha is the authors' eq.-6 weight (--solver roughness)",
    )
    study.add_argument(
        "--leds", type=_counts, default=[3, 4, 5, 6, 7], help="table1/cameras/xy: LED counts (default 3,4,5,6,7)"
    )
    study.add_argument(
        "--cameras",
        type=positive_int,
        default=None,
        help="use the first N of the 34 cameras (failure/pareto default: 3 chosen cameras)",
    )
    study.add_argument(
        "--ambients",
        type=_names,
        default=None,
        help="failure/pareto: comma-separated ambients (default tungsten,fluorescent,daylight)",
    )
    study.add_argument(
        "--factors",
        type=_names,
        default=None,
        help="failure: comma-separated factors (default all: n_leds, surfaces, ambient_to_flash, "
        "exposure, saturation, dead_led, line_400nm, line_570nm, line_700nm, motion)",
    )
    study.add_argument(
        "--seeds", type=positive_int, default=2, help="failure/pareto: noise seeds per world (default 2)"
    )
    study.add_argument(
        "--threshold",
        type=_finite_at_least(0.0, "a finite RMSE ≥ 0"),
        default=0.1,
        help="failure: excess spectrum RMSE over the baseline counted as a failure (default 0.1)",
    )
    study.add_argument("--records", action="store_true", help="failure: keep every estimate's record in the JSON")
    study.add_argument(
        "--ambient-to-flash",
        type=_finite_at_least(math.ulp(0.0), "a finite ratio > 0"),
        default=0.5,
        help="pareto: the ambient's camera signal over all LEDs' together at full drive (default 0.5: the sim "
        "rig's before --flash-power; its default booth now gives 0.05)",
    )
    study.add_argument(
        "--patch-px",
        type=_pareto_patch,
        default=40,
        help=f"pareto: chart patch size in pixels (default 40; at most {MAX_PARETO_PATCH_PX})",
    )
    study.add_argument(
        "--samplings",
        type=_names,
        default=None,
        help="pareto: comma-separated sampling levels (default all: all, mask_1e5, mask_1e4, mask_1e3, "
        "gather_1e4, gather_1e3, bin2, bin4, bin8, patch_means)",
    )
    study.add_argument("--repeats", type=positive_int, default=3, help="pareto: timing repeats (median; default 3)")
    study.add_argument(
        "--illuminants",
        type=positive_int,
        default=None,
        help="use N of the 23 feasible illuminants, spread over the grid",
    )
    study.add_argument("--draws", type=positive_int, default=10, help="surfaces: draws per count (default 10)")
    study.add_argument("--seed", type=seed_int, default=0, help="surfaces: random seed of the draws")
    add_scheduler_options(study, what="study's cameras and illuminants")
    study.set_defaults(handler=_run)


# -- cameras (Fig. 6), xy (Fig. 7), failure, pareto -------------------------------------------
def _num(value: Any) -> float:
    return float("nan") if value is None else float(value)


def _cameras_text(result: dict[str, Any]) -> str:
    config = result["config"]
    lines = [
        f"Fig. 6: {config['method']} alpha={config['alpha']}, {config['n_cameras']} cameras x "
        f"{len(config['illuminants_xy'])} illuminants, {result['elapsed_s']:.1f} s",
        f"{'# LEDs':>7s} {'camera spread':>14s} {'worst illum.':>13s} {'spectrum RMSE':>14s} {'worst camera':>13s}",
    ]
    for row in zip(
        result["n_leds"],
        result["camera_spread"],
        result["camera_spread_max"],
        result["spectrum_rmse"],
        result["spectrum_rmse_worst_camera"],
        strict=True,
    ):
        lines.append(
            f"{row[0]:>7d} {_num(row[1]):>14.4f} {_num(row[2]):>13.4f} {_num(row[3]):>14.4f} {_num(row[4]):>13.4f}"
        )
    lines.append("camera spread: RMS over wavelengths of the std across cameras of max-normalised estimates")
    return "\n".join(lines)


def _xy_text(result: dict[str, Any]) -> str:
    counts = result["n_leds"]
    lines = [
        f"Fig. 7: spectrum RMSE (mean over {result['config']['n_cameras']} cameras) at each feasible xy, "
        f"{result['elapsed_s']:.1f} s",
        f"{'x':>6s} {'y':>6s}" + "".join(f"{n:>7d}" for n in counts) + "   bound(7)",
    ]
    for xy, values, bound in zip(result["xy"], result["spectrum_rmse"], result["bound"], strict=True):
        lines.append(
            f"{xy[0]:>6.3f} {xy[1]:>6.3f}" + "".join(f"{_num(v):>7.3f}" for v in values) + f"   {bound[-1]:.3f}"
        )
    return "\n".join(lines)


def _failure_text(result: dict[str, Any]) -> str:
    config = result["config"]
    lines = [
        f"Failure map: {config['method']} alpha={config['alpha']}, bin {config['bin_factor']}, "
        f"{len(config['cameras'])} cameras x {len(config['ambients'])} ambients x {len(config['seeds'])} seeds, "
        f"{result['elapsed_s']:.1f} s",
        f"{'factor':>17s} {'level':>9s} {'error':>7s} {'std':>6s} {'excess':>7s} {'warned':>7s} "
        f"{'resid':>6s} {'cond':>8s} {'band':>6s} {'fill':>5s}",
    ]
    for factor, rows in result["summary"].items():
        for row in rows:
            lines.append(
                f"{factor:>17s} {row['level']:>9.4g} {_num(row['error_mean']):>7.3f} {_num(row['error_std']):>6.3f} "
                f"{_num(row['excess_mean']):>7.3f} {row['warned_rate']:>7.0%} "
                f"{_num(row['relative_residual_median']):>6.3f} {_num(row['condition_number_median']):>8.2g} "
                f"{_num(row['band_ratio_median']):>6.2f} {_num(row['led_fill_median']):>5.2f}"
            )
    for key, title in (("confusion", "excess > threshold"), ("confusion_absolute", "error > threshold")):
        table = result[key]["all"]
        lines.append(
            f"{title} ({result[key]['threshold']}): bad & warned {table['bad_warned']}, bad & silent "
            f"{table['bad_silent']}, good & warned {table['good_warned']}, good & silent {table['good_silent']}"
        )
    return "\n".join(lines)


def _pareto_text(result: dict[str, Any]) -> str:
    config = result["config"]
    lines = [
        f"Pareto: {len(config['cameras'])} cameras x {len(config['ambients'])} ambients x {len(config['seeds'])} "
        f"seeds, {config['pixels']} px, ambient/flash {config['ambient_to_flash']}, {result['elapsed_s']:.1f} s",
        f"{'solver':>15s} {'sampling':>12s} {'error':>7s} {'std':>6s} {'time ms':>9s} front",
    ]
    for point in sorted(result["points"], key=lambda p: p["time_s"]):
        lines.append(
            f"{point['solver']:>15s} {point['sampling']:>12s} {_num(point['error_mean']):>7.3f} "
            f"{_num(point['error_std']):>6.3f} {1000 * _num(point['time_s']):>9.2f} {'*' if point['on_front'] else ''}"
        )
    default = result.get("default")
    if default:
        lines.append(
            f"default {default['solver']} {default['sampling']}: error {_num(default['error_mean']):.3f}, "
            f"{1000 * _num(default['time_s']):.2f} ms, {'on' if default['on_front'] else 'off'} the front"
        )
    return "\n".join(lines)


def _plot_cameras(result: dict[str, Any], path: Path) -> None:
    """Fig. 6: every camera's estimate against the truth per example illuminant and LED count, then the spread."""
    plt = pyplot()
    examples = result["examples"]
    counts = result["n_leds"]
    wavelengths = result["wavelengths_nm"]
    figure = plt.figure(figsize=(3.2 * len(counts) + 0.8, 2.6 * len(examples) + 3.6), layout="constrained")
    top, bottom = figure.subfigures(2, 1, height_ratios=[2.6 * len(examples), 3.2])
    axes = top.subplots(len(examples), len(counts), squeeze=False, sharex=True, sharey=True)
    for row, example in enumerate(examples):
        for column, n in enumerate(counts):
            axis = axes[row][column]
            for estimate in example["estimates"][str(n)]:
                axis.plot(
                    wavelengths,
                    relative_power(wavelengths, estimate, "photons"),
                    color=PALETTE.ambient,
                    alpha=0.35,
                    linewidth=0.9,
                )
            axis.plot(
                wavelengths,
                relative_power(wavelengths, example["truth"], "photons"),
                "--",
                color=PALETTE.truth,
                linewidth=1.3,
            )
            axis.set_title(f"{n} LEDs, xy ({example['xy'][0]:.2f}, {example['xy'][1]:.2f})", fontsize=9)
            if row == len(examples) - 1:
                axis.set_xlabel("wavelength (nm)")
        axes[row][0].set_ylabel("relative power\n(energy, peak = 1)")
    top.suptitle("Fig. 6: every camera's estimate (green) against the true ambient (black, dashed)")
    summary, rmse = bottom.subplots(1, 2)
    summary.plot(counts, [_num(v) for v in result["camera_spread"]], "o-", label="camera spread (mean)")
    summary.plot(
        counts, [_num(v) for v in result["camera_spread_max"]], "s--", label="camera spread (worst illuminant)"
    )
    rmse.plot(
        counts, [_num(v) for v in result["spectrum_rmse"]], "o-", color=PALETTE.ambient, label="spectrum RMSE (mean)"
    )
    rmse.plot(
        counts,
        [_num(v) for v in result["spectrum_rmse_worst_camera"]],
        "s--",
        color=PALETTE.warning,
        label="worst camera",
    )
    for axis in (summary, rmse):
        axis.set_xlabel("# LEDs")
        axis.set_xticks(counts)
        axis.legend()
    summary.set_ylabel("spread across cameras")
    rmse.set_ylabel("spectrum RMSE")
    save_figure(figure, path)


def _plot_xy(result: dict[str, Any], path: Path) -> None:
    save_figure(xy_figure(result), path)


def xy_figure(result: dict[str, Any]) -> Any:
    """Fig. 7: one chromaticity panel per LED count (at most 3 a row, shared axes, equal aspect), one colour bar."""
    plt = pyplot()
    import numpy as np

    from msflash.lab.study.illuminants import cmfs_photons

    counts = result["n_leds"]
    columns = min(len(counts), 3)
    rows = math.ceil(len(counts) / columns)
    figure, axes = plt.subplots(
        rows,
        columns,
        figsize=(4.2 * columns + 1.2, 4.4 * rows + 0.6),
        squeeze=False,
        sharex=True,
        sharey=True,
        layout="constrained",
    )
    cmf = cmfs_photons()
    locus = cmf / cmf.sum(axis=1, keepdims=True)
    xy = np.array(result["xy"])
    values = np.array([[_num(v) for v in row] for row in result["spectrum_rmse"]])
    top = float(np.nanmax(values))
    for index, n in enumerate(counts):
        axis = axes[index // columns][index % columns]
        axis.plot(np.append(locus[:, 0], locus[0, 0]), np.append(locus[:, 1], locus[0, 1]), "k-", linewidth=0.8)
        points = axis.scatter(xy[:, 0], xy[:, 1], c=values[:, index], s=110, vmin=0, vmax=top, cmap="viridis")
        for (x, y), value in zip(xy, values[:, index], strict=True):
            axis.annotate(
                f"{value:.2f}", (x, y), fontsize=7, ha="center", va="bottom", xytext=(0, 6), textcoords="offset points"
            )
        axis.set_title(f"{n} LEDs")
        axis.set_xlim(0, 0.8)
        axis.set_ylim(0, 0.9)
        axis.set_aspect("equal")
        if index // columns == rows - 1 or index + columns >= len(counts):
            axis.set_xlabel("CIE 1931 x")
            axis.tick_params(labelbottom=True)
        if index % columns == 0:
            axis.set_ylabel("CIE 1931 y")
    for index in range(len(counts), rows * columns):
        axes[index // columns][index % columns].axis("off")
    figure.colorbar(points, ax=axes.ravel().tolist(), shrink=0.8, label="spectrum RMSE (mean over cameras)")
    figure.suptitle("Fig. 7: spectrum RMSE of the estimate over the feasible xy grid")
    return figure


def _plot_failure(result: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    factors = list(result["summary"])
    columns = min(len(factors), 5)
    rows = (len(factors) + columns - 1) // columns
    figure, axes = plt.subplots(rows, columns, figsize=(3.4 * columns, 3.0 * rows), squeeze=False)
    for index, factor in enumerate(factors):
        axis = axes[index // columns][index % columns]
        table = result["summary"][factor]
        positions = list(range(len(table)))
        axis.errorbar(
            positions,
            [_num(r["error_mean"]) for r in table],
            yerr=[_num(r["error_std"]) for r in table],
            fmt="o-",
            capsize=3,
            color=PALETTE.ambient,
            label="spectrum RMSE",
        )
        axis.plot(
            positions, [_num(r["bound_mean"]) for r in table], ":", color=PALETTE.led_fit, lw=1.8, label="LED-fit bound"
        )
        twin = axis.twinx()
        twin.bar(positions, [r["warned_rate"] for r in table], alpha=0.3, color=PALETTE.warning, label="warned")
        twin.set_ylim(0, 1.05)
        twin.tick_params(labelsize=7)
        axis.set_xticks(positions)
        axis.set_xticklabels([f"{r['level']:g}" for r in table], fontsize=7, rotation=45)
        axis.set_title(factor, fontsize=9)
        axis.tick_params(labelsize=7)
        axis.grid(True, alpha=0.3)
        if index == 0:
            axis.legend(fontsize=6, loc="upper left")
            twin.legend(fontsize=6, loc="upper right")
    for index in range(len(factors), rows * columns):
        axes[index // columns][index % columns].axis("off")
    figure.suptitle(
        "Failure map: error (mean ± std, left axis) and warning rate (red bars, right axis); first level = baseline",
        fontsize=10,
    )
    figure.tight_layout()
    save_figure(figure, path)


def _plot_pareto(result: dict[str, Any], path: Path) -> None:
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(7.5, 5))
    solvers = list(dict.fromkeys(p["solver"] for p in result["points"]))
    markers = "osD^v<>"
    for index, solver in enumerate(solvers):
        points = [p for p in result["points"] if p["solver"] == solver and p["error_mean"] is not None]
        axis.scatter(
            [1000 * p["time_s"] for p in points],
            [p["error_mean"] for p in points],
            marker=markers[index % 7],
            label=solver,
            alpha=0.8,
        )
        for p in points:
            axis.annotate(
                p["sampling"],
                (1000 * p["time_s"], p["error_mean"]),
                fontsize=6.5,
                alpha=0.8,
                xytext=(2, 2),
                textcoords="offset points",
            )
    front = result["front"]
    axis.plot([1000 * p["time_s"] for p in front], [p["error_mean"] for p in front], "k-", linewidth=1, label="front")
    default = result.get("default")
    if default:
        axis.scatter(
            [1000 * default["time_s"]],
            [default["error_mean"]],
            s=200,
            facecolors="none",
            edgecolors=PALETTE.warning,
            linewidths=2,
            label="app default",
        )
    axis.set_xscale("log")
    axis.set_xlabel("time per frame stack (ms, statistics + solver)")
    axis.set_ylabel("spectrum RMSE (mean)")
    axis.grid(True, alpha=0.3, which="both")
    axis.legend(fontsize=7)
    figure.tight_layout()
    save_figure(figure, path)


PLOTS = {
    "table1": _plot_table1,
    "surfaces": _plot_surfaces,
    "cameras": _plot_cameras,
    "xy": _plot_xy,
    "failure": _plot_failure,
    "pareto": _plot_pareto,
}
TEXTS = {
    "table1": _table1_text,
    "surfaces": _surfaces_text,
    "cameras": _cameras_text,
    "xy": _xy_text,
    "failure": _failure_text,
    "pareto": _pareto_text,
}
