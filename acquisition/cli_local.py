"""``msflash local-study``: the acceptance study of local ambient estimation (issue 9, docs/local-estimation.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from acquisition.cli_common import output_directory, positive_int, print_json, progress
from processing.local import DEFAULT_TILES


def _local_study(args: argparse.Namespace) -> int:
    from processing.study.local import run_study  # matplotlib and scipy only when asked

    progress(f"local study: {args.uniform} uniform scenes, {args.mixed} boundary + {args.mixed} gradient scenes, "
             f"{args.tiles}x{args.tiles} tiles, seeds from {args.seed0}")
    out = output_directory(args.out)
    summary = run_study(n_uniform=args.uniform, n_mixed=args.mixed, tiles=args.tiles, seed0=args.seed0,
                        out=out, timing=not args.no_timing, sweep=not args.no_timing)
    scenarios = summary.pop("scenarios")
    if args.json:
        print_json(summary)
        return 0
    for kind in ("uniform", "boundary", "gradient"):
        entry = summary.get(kind)
        if entry:
            print(f"{kind:9s} n={entry['n']:4d}  auto→global {entry['global_rate']:6.1%}  spectrum RMSE global "
                  f"{entry['rmse_global']:.4f} auto {entry['rmse_auto']:.4f} (cut {entry['auto_cut']:+.1%}, of the excess "
                  f"over the LED bound {entry['excess_cut']:+.1%}), each ambient alone {entry['rmse_alone']:.4f} "
                  f"(cut {entry['alone_cut']:+.1%}), LED bound {entry['rmse_bound']:.4f}, two regions {entry['regions_rate']:.0%}; "
                  f"global on denoised statistics {entry['rmse_global_denoised']:.4f} (cut {entry['locality_cut']:+.1%}), "
                  f"auto without the noise correction {entry['rmse_auto_observed']:.4f}")
    both = summary.get("two_illuminant")
    if both:
        print(f"two-illuminant (boundary + gradient) n={both['n']}: global {both['rmse_global']:.4f} auto "
              f"{both['rmse_auto']:.4f} (cut {both['auto_cut']:+.1%}), each ambient alone {both['rmse_alone']:.4f} "
              f"(cut {both['alone_cut']:+.1%}); against the global model on denoised statistics "
              f"{both['rmse_global_denoised']:.4f}: cut {both['locality_cut']:+.1%}")
    timing = summary.get("timing")
    if timing:
        print(f"cost on {timing['shape'][0]}x{timing['shape'][1]}: global {timing['global_s'] * 1e3:.1f} ms, auto "
              f"{timing['auto_s'] * 1e3:.1f} ms ({timing['auto_ratio']:.2f}x), local {timing['local_s'] * 1e3:.1f} ms "
              f"({timing['local_ratio']:.2f}x)")
    if args.out:
        print(f"wrote {Path(args.out) / 'local-study.json'} ({len(scenarios)} scenarios) and plots")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``local-study``."""
    study = subparsers.add_parser("local-study", help="study local vs global ambient estimation on simulated scenes")
    study.add_argument("--uniform", type=positive_int, default=100, help="uniform-ambient scenes (default 100)")
    study.add_argument("--mixed", type=positive_int, default=30,
                       help="two-illuminant scenes of each kind, boundary and gradient (default 30)")
    study.add_argument("--tiles", type=positive_int, default=DEFAULT_TILES, help=f"tiles per side (default {DEFAULT_TILES})")
    study.add_argument("--seed0", type=positive_int, default=1000,
                       help="first seed: uniform scenes seed0+i, mixed seed0+10000+i, tiles sweep seed0+20000+i (default 1000)")
    study.add_argument("--no-timing", action="store_true", help="skip the full-size timing and the tiles sweep")
    study.add_argument("--out", default=None, help="directory for local-study.json and local-study.png")
    study.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    study.set_defaults(handler=_local_study)
