"""``msflash export SEQ --to dng|ome-tiff|csv|exr``: a sequence in other tools' formats
(:mod:`acquisition.export.sequence_export`)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

from msflash.acquisition.app.cli_common import print_json, progress
from msflash.acquisition.app.options import TARGET_HELP, add_estimation_options, target_value
from msflash.acquisition.sequence.locate import ARGUMENT_HELP as SEQUENCE_HELP

EXPORT_HELP = "write a sequence as DNG (raw frames), OME-TIFF (all frames), CSV (spectra) or EXR (linear images)"
_FORMATS_HELP = "dng, ome-tiff, csv or exr; several comma-separated (dng,csv)"


def _default_out(sequence: Path) -> Path:
    name = sequence.resolve().parent.name if sequence.name == "sequence" else sequence.name
    return Path(f"{name or 'sequence'}-export")


def _export(args: argparse.Namespace) -> int:
    from msflash.acquisition.export.formats import parse_formats
    from msflash.acquisition.export.sequence_export import check_out, export_sequence
    from msflash.acquisition.sequence.locate import locate_sequence
    from msflash.acquisition.session.one_sequence import read_calibrated

    formats = parse_formats(args.to, "--to")
    directory = locate_sequence(args.sequence)
    out = Path(args.out) if args.out is not None else _default_out(directory)
    check_out(out, "--out")
    # As estimate and flash read it: the calibration given, or the one the sequence references.
    sequence = read_calibrated(str(directory), args.calibration, progress)
    result = export_sequence(
        sequence, formats, out, target=args.target, solver=args.solver, alpha=args.alpha, bin_factor=args.bin
    )
    if (
        directory.name == "sequence"
        and (directory.parent / "run.json").is_file()
        and out.resolve().is_relative_to(directory.parent.resolve())
    ):
        # An export into the run folder, made after the run: its report links it too.
        from msflash.acquisition.app.run_html import link_later_export

        why_not = link_later_export(directory.parent, sequence, formats, result.files, result.notes)
        if why_not is not None:
            result = replace(result, notes=(*result.notes, why_not))
    if args.json:
        print_json(
            {
                "sequence": str(sequence.directory),
                "formats": list(formats),
                "out": str(result.directory),
                "files": [str(path) for path in result.files],
                "notes": list(result.notes),
                **result.details,
            }
        )
    else:
        for note in result.notes:
            sys.stderr.write(f"msflash: note: {note}\n")
        for path in result.files:
            sys.stdout.write(f"{path}\n")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``export``."""
    export = subparsers.add_parser("export", help=EXPORT_HELP)
    export.add_argument("sequence", help=SEQUENCE_HELP)
    export.add_argument("--to", required=True, help=_FORMATS_HELP)
    export.add_argument(
        "--out", default=None, help="new folder for the files (default ./NAME-export; never overwritten)"
    )
    export.add_argument(
        "--target",
        default="D65",
        type=target_value,
        help=f"{TARGET_HELP}; for csv and exr",
    )
    add_estimation_options(export)
    export.add_argument(
        "--calibration",
        metavar="DIR",
        default=None,
        help="LED spectra / responsivities from this calibration (msflash calibrate) override the sequence's",
    )
    export.add_argument("--json", action="store_true", help="print one JSON object")
    export.set_defaults(handler=_export)
