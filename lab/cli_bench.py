"""``msflash bench``: speed figures as ratios measured in one run."""

from __future__ import annotations

import argparse
import importlib
from typing import Any

from msflash.acquisition.app.cli_common import positive_int, print_json, progress, whole_number
from msflash.acquisition.progress import count

_OPTIONAL_PARTS = {
    "camera": ("msflash.lab.bench.camera", "camera_bench"),
    "booth": ("msflash.lab.bench.booth", "run_bench"),
    "capture": ("msflash.lab.bench.capture", "capture_bench"),
    "decode": ("msflash.lab.bench.decode", "decode_bench"),
    "live": ("msflash.lab.bench.live", "live_bench"),
    "many": ("msflash.lab.bench.many", "many_bench"),
    "flash-energy": ("msflash.lab.bench.flash_energy", "flash_energy_bench"),
}
"""Bench parts contributed by other modules: part name → (module, function returning a dict)."""

_QUICK_PARTS = frozenset({"flash-energy"})
"""Optional parts whose function takes ``quick`` (``--quick``: fewer draws)."""

LARGE_SIZE = (3000, 4096)
"""(height, width) of the second size the processing targets are measured on (issue 21)."""


def _bench(args: argparse.Namespace) -> int:
    from msflash.lab.bench.processing import processing_bench

    report: dict[str, Any] = {}
    parts = args.part or ["processing", "startup", *_OPTIONAL_PARTS]
    if "processing" in parts:
        sizes = [(args.height, args.width)] + ([] if args.quick else [LARGE_SIZE])
        shown = ", ".join(f"{width}×{height}" for height, width in sizes)
        progress(f"bench: processing ({shown}, RGB and raw RGGB, 7 LEDs; {args.pairs} interleaved pairs a ratio)…")
        report["processing"] = processing_bench(
            args.height, args.width, repeats=args.repeats, pairs=args.pairs, sizes=tuple(sizes)
        )
        _part_done(report, parts)
    if "startup" in parts:
        from msflash.lab.bench.startup import startup_bench

        progress(f"bench: start-up (msflash --help, msflash estimate, import numpy; {args.rounds} interleaved rounds)…")
        report["startup"] = startup_bench(args.rounds, args.sequence)
        _part_done(report, parts)
    for part, (module_name, function_name) in _OPTIONAL_PARTS.items():
        if part not in parts:
            continue
        try:
            module = importlib.import_module(module_name)
            function = getattr(module, function_name)
        except (ImportError, AttributeError) as err:
            report[part] = {"skipped": f"{module_name}.{function_name} unavailable ({err})"}
            continue
        progress(f"bench: {part}…")
        report[part] = function(quick=args.quick) if part in _QUICK_PARTS else function()
        _part_done(report, parts)
    if args.json:
        print_json(report)
    else:
        _print_human(report)
    return 0


def _part_done(report: dict[str, Any], parts: list[str]) -> None:
    """The bench's bar (on a terminal): one step per part measured."""
    count("bench", len(report), len(set(parts)), "part")


def _print_human(report: dict[str, Any], indent: str = "") -> None:
    for key, value in report.items():
        if isinstance(value, dict) and "target" in value and "met" in value:
            print(f"{indent}{key}: {_judged(value)}")
        elif isinstance(value, dict):
            print(f"{indent}{key}:")
            _print_human(value, indent + "  ")
        elif isinstance(value, list):
            print(f"{indent}{key}:")
            for item in value:
                if isinstance(item, dict):
                    print(indent + "  - " + ", ".join(f"{k}={_fmt(v)}" for k, v in item.items()))
                else:
                    print(f"{indent}  - {_fmt(item)}")
        else:
            print(f"{indent}{key}: {_fmt(value)}")


def _judged(figure: dict[str, Any]) -> str:
    """One line for a figure with a target: its value, spread, target and verdict."""
    verdict = {True: "met", False: "NOT met", None: "not judged (too few pairs)"}[figure["met"]]
    if "median" in figure:
        spread = f"quartiles {figure['q1']:.3g}–{figure['q3']:.3g}, range {figure['min']:.3g}–{figure['max']:.3g}, {figure['pairs']} pairs"
        return f"{figure['median']:.3g} (median; {spread}) target {figure['target']}: {verdict}"
    return f"{figure['ratio']:.3g} target {figure['target']}: {verdict}"


def _fmt(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


MIN_FRAME_SIDE = 64
"""The smallest ``--height``/``--width``: the estimate's statistics need at least 5 rows of 8 × 8 blocks of each CFA
plane (``--height 0`` was refused naming the scene's label array, ``--width -1`` as a width of 0, 16 or 32 as
"channel statistics: 2×2 blocks of 8×8" — none naming the option)."""


_frame_side = whole_number(MIN_FRAME_SIDE, unit="pixels")
"""argparse type of ``--height`` and ``--width``: a whole number of pixels ≥ :data:`MIN_FRAME_SIDE`."""


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``bench``."""
    bench = subparsers.add_parser("bench", help="measure speed as ratios in one run (processing, camera, booth)")
    bench.add_argument(
        "--part",
        action="append",
        choices=("processing", "startup", *_OPTIONAL_PARTS),
        help="run only this part (repeatable); default all",
    )
    bench.add_argument(
        "--height",
        type=_frame_side,
        default=1024,
        help=f"frame height for the processing part (its first size; at least {MIN_FRAME_SIDE})",
    )
    bench.add_argument(
        "--width",
        type=_frame_side,
        default=1280,
        help=f"frame width for the processing part (its first size; at least {MIN_FRAME_SIDE})",
    )
    bench.add_argument(
        "--repeats",
        type=positive_int,
        default=5,
        help="processing part: repeats of the solver timings (the best is kept)",
    )
    bench.add_argument(
        "--pairs",
        type=positive_int,
        default=15,
        help="processing part: interleaved pairs per ratio (the targets are judged from 15)",
    )
    bench.add_argument(
        "--quick",
        action="store_true",
        help=f"processing part: the targets at --height × --width only, not also at {LARGE_SIZE[1]}×{LARGE_SIZE[0]}; "
        "flash-energy part: 2 draws a case instead of 6",
    )
    bench.add_argument(
        "--rounds",
        type=positive_int,
        default=9,
        help="start-up part: interleaved runs of each command (the medians are compared)",
    )
    bench.add_argument(
        "--sequence",
        metavar="DIR",
        default=None,
        help="start-up part: the sequence 'estimate' reads (default: the demo's, captured on the "
        "simulated rig into a temporary folder)",
    )
    bench.add_argument("--json", action="store_true", help="print one JSON object")
    bench.set_defaults(handler=_bench)
