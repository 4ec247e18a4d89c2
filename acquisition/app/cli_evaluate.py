"""``msflash evaluate SEQ --chart macbeth`` and ``msflash colour-study``: the command line of
:mod:`acquisition.app.evaluation` (what they measure and how: its docstring)."""

from __future__ import annotations

import argparse
from pathlib import Path

from msflash.acquisition.app.cli_common import (
    UsageError,
    claimed_output,
    optional_claimed_output,
    print_json,
    progress,
)
from msflash.acquisition.app.evaluation import STUDY_AMBIENTS, colour_study, evaluate_sequence, public_result
from msflash.acquisition.app.options import layout_options, target_value
from msflash.acquisition.sequence.format import read_sequence
from msflash.acquisition.sequence.locate import ARGUMENT_HELP as SEQUENCE_HELP
from msflash.acquisition.sequence.locate import locate_sequence
from msflash.acquisition.session.chart_layout import CHARTS
from msflash.processing import lights, water


# -- the command line -------------------------------------------------------------------------
def _default_out(sequence_dir: Path) -> Path:
    return sequence_dir.resolve().parent / "evaluation"


def _evaluate(args: argparse.Namespace) -> int:
    directory = locate_sequence(args.sequence)
    sequence = read_sequence(directory)
    with claimed_output(args.out if args.out else _default_out(directory), "msflash evaluate") as out:
        result = evaluate_sequence(
            sequence, out, args.chart, args.patch_px, args.border_px, args.margin_px, args.bounds, args.target
        )
    result = public_result(result)
    if args.json:
        print_json(result)
    else:
        for name, values in result["delta_e"].items():
            progress(f"{name}: mean ΔE00 {values['mean']:.2f}")
        print(out)
    return 0


def _study(args: argparse.Namespace) -> int:
    ambients = tuple(a.strip() for a in args.ambients.split(",") if a.strip())
    unknown = [a for a in ambients if a not in lights.AMBIENTS]
    if unknown or not ambients:
        raise UsageError(
            f"--ambients '{args.ambients}': expected a comma-separated list of {', '.join(lights.AMBIENTS)}"
        )
    where = args.out if args.out else (None if args.json else Path("colour-study"))
    with optional_claimed_output(where, "msflash colour-study") as out:
        payload = colour_study(
            out,
            ambients,
            args.seed,
            args.patch_px,
            args.cfa,
            args.bounds,
            depth_m=args.depth_m,
            distance_m=args.distance_m,
            water_type=args.water,
        )
    if args.json:
        print_json(payload)
    else:
        for name, s in payload["delta_e"].items():
            progress(
                f"{name}: ΔE00 ambient {s['ambient']:.2f}, matching {s['matching']:.2f}, "
                f"complementary {s['complementary']:.2f} ({100 * s['complementary_cut']:.0f}% cut)"
            )
        print(out)
    return 0


def _bounds_option(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--bounds",
        default="physical",
        choices=("physical", "nonnegative"),
        help="flash weights in [0, 1] (physical, default: re-capturable) or ≥ 0 (computational)",
    )


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``evaluate`` and ``colour-study``."""
    evaluate = subparsers.add_parser(
        "evaluate", help="ΔE00 against the chart under D65 and noise, for a chart sequence"
    )
    evaluate.add_argument("sequence", metavar="SEQ", help=SEQUENCE_HELP)
    evaluate.add_argument("--chart", required=True, choices=CHARTS, help="the chart in the scene")
    layout_options(evaluate)
    evaluate.add_argument(
        "--target", default="D65", type=target_value, help="complementary target illuminant (name or CSV file)"
    )
    _bounds_option(evaluate)
    evaluate.add_argument("--out", default=None, help="output directory (default: evaluation/ beside the sequence)")
    evaluate.add_argument("--json", action="store_true", help="print the results as one JSON object")
    evaluate.set_defaults(handler=_evaluate)

    study = subparsers.add_parser("colour-study", help="simulated Fig. 9 (ΔE per ambient) and Fig. 3 (noise) study")
    study.add_argument("--ambients", default=",".join(STUDY_AMBIENTS), help="comma-separated ambients")
    study.add_argument("--seed", type=int, default=0, help="noise seed")
    study.add_argument("--patch-px", type=int, default=12, help="patch side in pixels")
    study.add_argument("--cfa", default=None, choices=("RGGB", "BGGR", "GRBG", "GBRG"), help="raw Bayer frames")
    _bounds_option(study)
    study.add_argument("--depth-m", type=float, default=5.0, help="underwater: depth of the chart")
    study.add_argument("--distance-m", type=float, default=1.0, help="underwater: camera–chart distance")
    study.add_argument("--water", default="ocean", choices=tuple(water.WATER_TYPES), help="underwater: water type")
    study.add_argument("--out", default=None, help="output directory (default colour-study/; none with --json)")
    study.add_argument("--json", action="store_true", help="print the results as one JSON object")
    study.set_defaults(handler=_study)
