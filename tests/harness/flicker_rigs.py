"""The flicker rows of the rigs (docs/flicker.md, "On the rigs"): ``msflash run --rig R --exposure 2000 --seed S`` with
and without ``--flicker 100:0.3``, seeds 0–7, one rig at a time.

The rigs' image formation is msflash's own (not independent, unlike :mod:`tests.harness.flicker`): these rows say
what a user of the rig sees. Per rig: the mean ratio (spectrum RMSE against the true ambient ÷ the best
non-negative LED fit of it, as the run prints them) of the flickering and the steady runs; in how many runs flicker
was detected (steady: false alarms); in how many the mains fit was decisive, its frequency's largest error against
the lamp's (recorded in the sequence as ``msflash.true_flicker``) and its depths.

Run: ``.venv/bin/python -m tests.harness.flicker_rigs --rig aravis-fake`` (``--seeds N``, default 8; ``--rig sim``).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
from dataclasses import dataclass
from pathlib import Path

from msflash.acquisition.app.cli import main as msflash_main

SEEDS = 8
FLICKER = "100:0.3"
EXPOSURE_US = 2000


@dataclass(frozen=True)
class RigRun:
    """One run's figures."""

    seed: int
    flickering: bool
    ratio: float
    """Spectrum RMSE against the truth ÷ the LED bound."""
    detected: bool
    frequency_error_hz: float | None
    """|fitted − true| where the mains fit was decisive (flickering runs), else None."""
    depth: float | None


def run_once(rig: str, seed: int, flickering: bool, folder: Path) -> RigRun:
    """``msflash run`` on ``rig`` in ``folder`` and its figures (read from what the run wrote)."""
    out = folder / f"{rig}-{seed}-{'flicker' if flickering else 'steady'}"
    argv = ["run", "--rig", rig, "--exposure", str(EXPOSURE_US), "--seed", str(seed), "--out", str(out)]
    with contextlib.redirect_stderr(io.StringIO()) as err, contextlib.redirect_stdout(io.StringIO()):
        status = msflash_main(argv + (["--flicker", FLICKER] if flickering else []))
    if status != 0:
        raise RuntimeError(f"msflash {' '.join(argv)}: exit {status}: {err.getvalue()[-500:]}")
    summary = json.loads((out / "run.json").read_text())
    flicker = json.loads((out / "estimate.json").read_text())["flicker"]
    truth = json.loads((out / "sequence" / "sequence.json").read_text())["msflash"].get("true_flicker")
    fitted = flicker.get("frequency_hz")
    error = abs(fitted - truth["frequency_hz"]) if fitted is not None and truth is not None else None
    return RigRun(
        seed,
        flickering,
        summary["spectrum_rmse_vs_truth"] / summary["spectrum_rmse_led_bound"],
        bool(flicker["detected"]),
        error,
        flicker.get("depth") if fitted is not None else None,
    )


def report(rig: str, runs: list[RigRun], command: str) -> str:
    """The rig's rows in markdown."""
    lines = [f"`{command}`", "", "| rig | lamp | runs | mean ratio | flicker detected | mains fit decisive | "
             "largest frequency error | depths |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for flickering in (True, False):
        these = [r for r in runs if r.flickering == flickering]
        fits = [r for r in these if r.frequency_error_hz is not None]
        depths = [r.depth for r in fits if r.depth is not None]
        lines.append(
            f"| {rig} | {'flickering ' + FLICKER if flickering else 'steady'} | {len(these)} | "
            f"{sum(r.ratio for r in these) / len(these):.2f} | {sum(r.detected for r in these)} of {len(these)} | "
            f"{len(fits)} of {len(these)} | "
            + (f"{max(r.frequency_error_hz for r in fits):.2f} Hz" if fits else "—")  # type: ignore[type-var]
            + " | "
            + (f"{min(depths):.2f}–{max(depths):.2f}" if depths else "—")
            + " |"
        )
    lines += ["", "Per run (seed: ratio flickering / steady): " + ", ".join(
        f"{s}: {next(r.ratio for r in runs if r.seed == s and r.flickering):.2f} / "
        f"{next(r.ratio for r in runs if r.seed == s and not r.flickering):.2f}"
        for s in sorted({r.seed for r in runs})
    )]  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.harness.flicker_rigs", description=__doc__.splitlines()[0])
    parser.add_argument("--rig", default="aravis-fake", choices=("sim", "aravis-fake"))
    parser.add_argument("--seeds", type=int, default=SEEDS)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as folder:
        runs = [
            run_once(args.rig, seed, flickering, Path(folder))
            for seed in range(args.seeds)
            for flickering in (False, True)
        ]
    command = f"python -m tests.harness.flicker_rigs --rig {args.rig}" + (
        f" --seeds {args.seeds}" if args.seeds != SEEDS else ""
    )
    print(report(args.rig, runs, command))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
