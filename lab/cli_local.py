"""``msflash local-study``: the acceptance study of local ambient estimation (issue 9, docs/local-estimation.md)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from msflash.acquisition.app.cli_common import positive_int, print_json, progress
from msflash.lab.cli_support import REPORTER, optional_claimed_output
from msflash.processing.tile_statistics import DEFAULT_TILES


def _local_study(args: argparse.Namespace) -> int:
    from msflash.lab.study.local import run_study  # matplotlib and scipy only when asked

    progress(
        f"local study: {args.uniform} uniform scenes, {args.mixed} boundary + {args.mixed} gradient scenes, "
        f"{args.tiles}x{args.tiles} tiles, seeds from {args.seed0}"
    )
    with optional_claimed_output(args.out, "msflash local-study") as out:
        summary = run_study(
            n_uniform=args.uniform,
            n_mixed=args.mixed,
            tiles=args.tiles,
            seed0=args.seed0,
            timing=not args.no_timing,
            sweep=not args.no_timing,
            progress=REPORTER,
        )
        if out is not None:
            _write(summary, out)
    scenarios = summary.pop("scenarios")
    if args.json:
        print_json(summary)
        return 0
    for kind in ("uniform", "boundary", "gradient"):
        entry = summary.get(kind)
        if entry:
            print(
                f"{kind:9s} n={entry['n']:4d}  auto→global {entry['global_rate']:6.1%}  spectrum RMSE global "
                f"{entry['rmse_global']:.4f} auto {entry['rmse_auto']:.4f} (cut {entry['auto_cut']:+.1%}, of the excess "
                f"over the LED bound {entry['excess_cut']:+.1%}), each ambient alone {entry['rmse_alone']:.4f} "
                f"(cut {entry['alone_cut']:+.1%}), LED bound {entry['rmse_bound']:.4f}, two regions {entry['regions_rate']:.0%}; "
                f"global on denoised statistics {entry['rmse_global_denoised']:.4f} (cut {entry['locality_cut']:+.1%}), "
                f"auto without the noise correction {entry['rmse_auto_observed']:.4f}"
            )
    both = summary.get("two_illuminant")
    if both:
        print(
            f"two-illuminant (boundary + gradient) n={both['n']}: global {both['rmse_global']:.4f} auto "
            f"{both['rmse_auto']:.4f} (cut {both['auto_cut']:+.1%}), each ambient alone {both['rmse_alone']:.4f} "
            f"(cut {both['alone_cut']:+.1%}); against the global model on denoised statistics "
            f"{both['rmse_global_denoised']:.4f}: cut {both['locality_cut']:+.1%}"
        )
    timing = summary.get("timing")
    if timing:
        print(
            f"cost on {timing['shape'][0]}x{timing['shape'][1]}: global {timing['global_s'] * 1e3:.1f} ms, auto "
            f"{timing['auto_s'] * 1e3:.1f} ms ({timing['auto_ratio']:.2f}x), local {timing['local_s'] * 1e3:.1f} ms "
            f"({timing['local_ratio']:.2f}x)"
        )
    if args.out:
        print(f"wrote {Path(args.out) / 'local-study.json'} ({len(scenarios)} scenarios) and plots")
    return 0


def _write(summary: dict, out: Path) -> None:
    """``local-study.json`` (the summary, every scenario included) and the plots, in ``out``."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "local-study.json").write_text(json.dumps(summary, indent=1, default=float) + "\n")
    summary["plots"] = _plots(summary, summary["scenarios"], out)


def _plots(summary: dict, results: list[dict], out: Path) -> list[str]:
    """Per-scenario auto vs global RMSE, the selection scores, where the error stays, and accuracy vs tiles/time."""
    from msflash.acquisition.app.plot_style import PALETTE, SERIES, pyplot, save_figure
    from msflash.lab.study.local import KINDS
    from msflash.processing.local_selection import SELECTION_MARGIN

    plt = pyplot()
    paths = []
    figure, axes = plt.subplots(1, 4, figsize=(20, 4.5))
    colours = dict(zip(KINDS, SERIES, strict=False))
    for kind in KINDS:
        rows = [r for r in results if r["kind"] == kind]
        axes[0].scatter(
            [r["rmse_global"] for r in rows], [r["rmse_auto"] for r in rows], s=10, c=colours[kind], label=kind
        )
        best = [min(v for key, v in r["scores"].items() if key != "global") for r in rows]
        axes[1].hist(best, bins=30, alpha=0.6, color=colours[kind], label=kind)
    top = max(max(r["rmse_global"] for r in results), max(r["rmse_auto"] for r in results))
    axes[0].plot([0, top], [0, top], ":", color=PALETTE.led_fit, lw=1)
    axes[0].plot([0, top], [0, 0.7 * top], "k--", lw=1, label="30 % cut")
    axes[0].set(
        xlabel="global spectrum RMSE (per pixel)", ylabel="auto spectrum RMSE (per pixel)", title="per scenario"
    )
    axes[0].legend()
    axes[1].axvline(1.0, color="k", lw=1)
    axes[1].axvline(1.0 - SELECTION_MARGIN, color="k", ls="--", lw=1, label="decision threshold")
    axes[1].set(xlabel="best local held-out error / global's", ylabel="scenarios", title="model selection")
    axes[1].legend()
    # Where the error stays: mean RMSE of every estimate and of the two references, per scene kind.
    names = (
        ("rmse_global", "global"),
        ("rmse_tiles", "tiles"),
        ("rmse_auto", "auto"),
        ("rmse_alone", "each ambient alone"),
        ("rmse_bound", "LED bound"),
    )
    kinds = [kind for kind in KINDS if kind in summary]
    width = 0.8 / len(names)
    for index, (key, label) in enumerate(names):
        axes[2].bar(
            np.arange(len(kinds)) + (index - (len(names) - 1) / 2) * width,
            [summary[k][key] for k in kinds],
            width,
            label=label,
            color=PALETTE.led_fit if key == "rmse_bound" else SERIES[index],
        )
    axes[2].set_xticks(np.arange(len(kinds)), kinds)
    axes[2].set(ylabel="mean spectrum RMSE (per pixel)", title="estimates and references")
    axes[2].set_ylim(0.12, None)
    axes[2].legend(fontsize=8)
    sweep = summary.get("tiles_sweep")
    if sweep:
        times = [r["time_s"] * 1e3 for r in sweep]
        axes[3].plot(times, [r["rmse_local"] for r in sweep], "o-", label="local (regions)")
        axes[3].plot(times, [r["rmse_tiles"] for r in sweep], "s--", label="tiles only")
        for r, elapsed in zip(sweep, times):
            axes[3].annotate(f"{r['tiles']}²", (elapsed, r["rmse_local"]))
        axes[3].axhline(float(np.mean([r["rmse_global"] for r in sweep])), color="k", ls=":", label="global")
        axes[3].set(
            xlabel="time per estimate, 240×320 frame (ms)",
            ylabel="spectrum RMSE (boundary scenes)",
            title="accuracy vs time (tiles per side)",
        )
        axes[3].legend(loc="upper center", bbox_to_anchor=(0.5, -0.16), ncols=3)  # below: no data covered
    figure.tight_layout()
    paths.append(str(save_figure(figure, out / "local-study.png")))
    return paths


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``local-study``."""
    study = subparsers.add_parser("local-study", help="study local vs global ambient estimation on simulated scenes")
    study.add_argument("--uniform", type=positive_int, default=100, help="uniform-ambient scenes (default 100)")
    study.add_argument(
        "--mixed",
        type=positive_int,
        default=30,
        help="two-illuminant scenes of each kind, boundary and gradient (default 30)",
    )
    study.add_argument(
        "--tiles", type=positive_int, default=DEFAULT_TILES, help=f"tiles per side (default {DEFAULT_TILES})"
    )
    study.add_argument(
        "--seed0",
        type=positive_int,
        default=1000,
        help="first seed: uniform scenes seed0+i, mixed seed0+10000+i, tiles sweep seed0+20000+i (default 1000)",
    )
    study.add_argument("--no-timing", action="store_true", help="skip the full-size timing and the tiles sweep")
    study.add_argument("--out", default=None, help="directory for local-study.json and local-study.png")
    study.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    study.set_defaults(handler=_local_study)
