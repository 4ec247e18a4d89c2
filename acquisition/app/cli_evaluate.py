"""``msflash evaluate SEQ --chart macbeth``: the command line of :mod:`acquisition.app.evaluation` (what it
measures and how: its docstring)."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from msflash.acquisition.app.cli_common import (
    UsageError,
    claimed_output,
    print_json,
    progress,
)
from msflash.acquisition.app.evaluation import evaluate_sequence, public_result
from msflash.acquisition.app.options import TARGET_HELP, flash_bounds_option, layout_options, target_value
from msflash.acquisition.sequence.locate import ARGUMENT_HELP as SEQUENCE_HELP
from msflash.acquisition.sequence.locate import locate_sequence
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.chart_layout import CHARTS


# -- the command line -------------------------------------------------------------------------
def _default_out(sequence_dir: Path) -> Path:
    return sequence_dir.resolve().parent / "evaluation"


def _refuse_a_run_or_sequence(out: Path) -> None:
    """``--out`` must not be a run's folder or a sequence's: the evaluation writes ``report.html``,
    ``matching.exr``, ``ambient.png`` … and ``evaluate RUN --out RUN`` replaced the run's own report and images."""
    for marker, what in (("run.json", "run"), ("sequence.json", "sequence")):
        if os.path.isfile(out / marker):  # False on any OSError: a name too long is claimed_output's to refuse
            raise UsageError(
                f"--out {out}: holds a {what} ({marker}); the evaluation's report.html and images would replace or sit "
                "among its own; "
                "expected a new folder or an earlier evaluation's (the default is evaluation/ beside the sequence)"
            )


def _evaluate(args: argparse.Namespace) -> int:
    directory = locate_sequence(args.sequence)
    sequence = read_sequence(directory)
    target = Path(args.out) if args.out else _default_out(directory)
    _refuse_a_run_or_sequence(target)
    with claimed_output(target, "msflash evaluate") as out:
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


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``evaluate``."""
    evaluate = subparsers.add_parser(
        "evaluate", help="ΔE00 against the chart under D65 and noise, for a chart sequence"
    )
    evaluate.add_argument("sequence", metavar="SEQ", help=SEQUENCE_HELP)
    evaluate.add_argument("--chart", required=True, choices=CHARTS, help="the chart in the scene")
    layout_options(evaluate)
    evaluate.add_argument("--target", default="D65", type=target_value, help=TARGET_HELP)
    flash_bounds_option(evaluate)
    evaluate.add_argument("--out", default=None, help="output directory (default: evaluation/ beside the sequence)")
    evaluate.add_argument("--json", action="store_true", help="print the results as one JSON object")
    evaluate.set_defaults(handler=_evaluate)
