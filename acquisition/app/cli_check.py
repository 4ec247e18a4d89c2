"""``msflash check SEQ``: is every frame file the one written? (:mod:`acquisition.sequence.check`)."""

from __future__ import annotations

import argparse
import sys

from msflash.acquisition.app.cli_common import dumps_json, print_json
from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.locate import ARGUMENT_HELP as SEQUENCE_HELP
from msflash.processing.user_files import shown_path

CHECK_HELP = "check every frame file of a sequence against the SHA-256 recorded when it was written"


def _check(args: argparse.Namespace) -> int:
    from msflash.acquisition.sequence.check import check_sequence
    from msflash.acquisition.sequence.locate import locate_sequence

    result = check_sequence(locate_sequence(args.sequence))
    if args.json:
        print_json({**result.summary(), "files": [check.to_dict() for check in result.files]})
    else:
        width = max(len("undeclared"), *(len(check.state) for check in result.files)) if result.files else 0
        for check in result.files:
            position = f"frames[{check.index}]" if check.index is not None else "-"
            sys.stdout.write(f"{check.state:<{width}}  {position:<10} {shown_path(check.file)}\n")
        sys.stdout.write(dumps_json(result.summary()) + "\n")
        sys.stdout.flush()
    problem = result.first_problem
    if problem is not None:
        raise RecordingError(problem)  # exit 2, this one line on stderr (docs/architecture.md §7)
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add ``check``."""
    check = subparsers.add_parser("check", help=CHECK_HELP)
    check.add_argument("sequence", help=SEQUENCE_HELP)
    check.add_argument(
        "--json",
        action="store_true",
        help="print one JSON object (the summary and every file's state) instead of the lines",
    )
    check.set_defaults(handler=_check)
