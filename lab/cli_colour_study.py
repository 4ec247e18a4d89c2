"""``msflash colour-study``: the command line of :mod:`msflash.lab.colour_study` (what it measures and how:
its docstring)."""

from __future__ import annotations

import argparse
from pathlib import Path

from msflash.acquisition.app.cli_common import UsageError, number, print_json, progress, seed_int, whole_number
from msflash.acquisition.app.options import flash_bounds_option
from msflash.lab.cli_support import optional_claimed_output
from msflash.lab.colour_study import STUDY_AMBIENTS, colour_study
from msflash.processing import lights, water


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


MIN_PATCH_PX, MAX_PATCH_PX = 8, 256
"""``--patch-px``'s range: the smallest that keeps at least 2 usable pixels of each CFA plane inside the study's
edge margin (7 left 1 and the refusal named a ``--margin-px`` the command does not have), the largest a
1 k × 1.6 k-pixel chart rendered under every light of the study (``--patch-px 100000`` asked for a
400 000 × 600 000 label map and crashed with a MemoryError)."""


_patch_side = whole_number(MIN_PATCH_PX, MAX_PATCH_PX, "pixels")
"""argparse type of ``--patch-px``: a whole number in :data:`MIN_PATCH_PX` … :data:`MAX_PATCH_PX`."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``colour-study``."""
    study = subparsers.add_parser("colour-study", help="simulated Fig. 9 (ΔE per ambient) and Fig. 3 (noise) study")
    study.add_argument("--ambients", default=",".join(STUDY_AMBIENTS), help="comma-separated ambients")
    study.add_argument("--seed", type=seed_int, default=0, help="noise seed")
    study.add_argument(
        "--patch-px",
        type=_patch_side,
        default=12,
        help=f"patch side in pixels, {MIN_PATCH_PX}-{MAX_PATCH_PX} (default 12; the simulated chart is 4 × 6 patches)",
    )
    study.add_argument("--cfa", default=None, choices=("RGGB", "BGGR", "GRBG", "GBRG"), help="raw Bayer frames")
    flash_bounds_option(study)
    study.add_argument("--depth-m", type=number, default=5.0, help="underwater: depth of the chart")
    study.add_argument("--distance-m", type=number, default=1.0, help="underwater: camera–chart distance")
    study.add_argument("--water", default="ocean", choices=tuple(water.WATER_TYPES), help="underwater: water type")
    study.add_argument("--out", default=None, help="output directory (default colour-study/; none with --json)")
    study.add_argument("--json", action="store_true", help="print the results as one JSON object")
    study.set_defaults(handler=_study)
