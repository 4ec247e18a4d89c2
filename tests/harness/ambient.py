"""``python -m tests.harness.ambient --out docs/ambient-harness.md``: run the ambient harness.

Renders the cases of the chosen split(s) (:mod:`tests.harness.cases`), runs every selected
variant (:mod:`tests.harness.variants`) on each and writes the markdown report to ``--out`` and
the per-case CSV beside it (same name, ``.csv``).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from tests.harness import report
from tests.harness.cases import select_cases
from tests.harness.physics_cases import select_physics_cases
from tests.harness.run import CACHE_ENV, run_cases
from tests.harness.variants import VARIANTS, select

PHYSICS_VARIANTS = (
    "default",
    "led-checked",
    "prior",
    "family",
    "auto",
    "family-patch",
    "auto-patch",
    "family-chart",
    "auto-chart",
)
"""The variants the physics suite runs unless ``--variant`` names others (the baselines are the library's)."""


def build_parser() -> argparse.ArgumentParser:
    """The harness's options."""
    parser = argparse.ArgumentParser(prog="python -m tests.harness.ambient", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/ambient-harness.md"), help="markdown report to write")
    parser.add_argument("--split", choices=("tuning", "held_out", "both"), default="both")
    parser.add_argument(
        "--suite",
        choices=("library", "physics"),
        default="library",
        help="library: lights of the 401-light library; physics: lights generated from physics (issue 30)",
    )
    parser.add_argument(
        "--cache", type=Path, default=None, help="keep rendered cases in this directory and reuse them (gitignored)"
    )
    parser.add_argument(
        "--variant",
        action="append",
        metavar="NAME[=ARGS]",
        help='NAME restricts the run to registered variants; NAME="ARGS" adds `msflash estimate '
        "SEQ --json ARGS` (repeatable; default: every registered variant)",
    )
    parser.add_argument("--quick", action="store_true", help="a small subset of the cases")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes")
    return parser


def _commit() -> str:
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).parent,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
            cwd=Path(__file__).parent,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+changes" if dirty else "")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the harness; 0 on success."""
    args = build_parser().parse_args(argv)
    try:
        variants = select(args.variant)
    except ValueError as error:
        print(f"harness: error: {error}", file=sys.stderr)
        return 2
    if args.cache is not None:
        os.environ[CACHE_ENV] = str(args.cache.resolve())
    if args.suite == "physics":
        if not any("=" not in text for text in args.variant or []):
            variants = [v for v in variants if v.name in PHYSICS_VARIANTS] + [
                v for v in variants if v.name not in VARIANTS
            ]
        cases = select_physics_cases(args.split, args.quick)
    else:
        cases = select_cases(args.split, args.quick)
    print(
        f"{len(cases)} cases × {len(variants)} variants ({', '.join(v.name for v in variants)}), {args.jobs} jobs",
        flush=True,
    )
    start = time.monotonic()
    results = run_cases(cases, variants, args.jobs, progress=True)
    elapsed = time.monotonic() - start
    args.out.parent.mkdir(parents=True, exist_ok=True)
    csv_path = args.out.with_suffix(".csv")
    command = "python -m tests.harness.ambient " + " ".join(argv if argv is not None else sys.argv[1:])
    args.out.write_text(
        report.markdown(
            results,
            variants,
            command=command.strip(),
            elapsed=elapsed,
            jobs=args.jobs,
            commit=_commit(),
            csv_name=csv_path.name,
            suite=args.suite,
        ),
        encoding="utf-8",
    )
    report.write_csv(results, csv_path)
    print(f"wrote {args.out} and {csv_path} ({elapsed:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
