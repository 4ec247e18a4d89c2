"""The live page's sequence: what ``msflash run`` does, into a new run folder, with each frame reported.

The route is ``msflash run``'s (:mod:`acquisition.session.run`): the exposures planned for the rig
(:func:`~acquisition.session.run.plan_exposure`), ambient + each LED + the flash decided from the frames in
memory and re-captured in one stream (:func:`~acquisition.session.run.run_one_stream`), then the report of
:func:`acquisition.app.report.write_run_report`, ``run.json`` and ``report.html``. The folder therefore holds the same files
``msflash run --out`` leaves. Called on the live server's rig thread, which owns the camera and the booth.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from msflash.acquisition.app.cli_common import claimed_output
from msflash.acquisition.errors import CaptureCancelled, CaptureError
from msflash.acquisition.sequence.async_writer import AsyncSequenceWriter
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.engine import Cancellation, FrameHandler
from msflash.acquisition.session.exposure import ExposurePolicy
from msflash.acquisition.session.rig import Rig
from msflash.acquisition.session.run import RunOptions, degenerate, plan_exposure, run_one_stream, sequence_writer


@dataclass(frozen=True)
class SequenceRequest:
    """What the page's *fire* button asks for."""

    exposure: str | float = "auto"
    """``auto`` (metered, as ``msflash run``'s default) or one exposure in µs for every frame."""
    options: RunOptions = RunOptions()


def new_run_folder(runs: Path) -> Path:
    """A new folder under ``runs`` named by the UTC time (``-2``, ``-3``… when the second is taken)."""
    stem = datetime.now(UTC).strftime("%Y%m%d-%H%M%S")
    folder, n = runs / stem, 1
    while folder.exists():
        n += 1
        folder = runs / f"{stem}-{n}"
    return folder


def run_sequence(
    rig: Rig,
    out: Path,
    request: SequenceRequest,
    handlers: Sequence[FrameHandler] = (),
    on_phase: Callable[[str], None] | None = None,
    cancel: Cancellation | None = None,
) -> dict[str, Any]:
    """Capture, estimate, flash, re-capture and report into ``out``, as ``msflash run --out out`` does.

    Each frame goes to ``handlers`` as it lands (the page's view of the sequence). ``cancel`` stops
    the metering or the capture between frames (:class:`CaptureCancelled`: the frames written stay,
    the sequence ``complete: false``, the LEDs off) and skips the report. Returns the run's summary (``run.json``).

    Raises
    ------
    CaptureError
        A degenerate estimate (the sequence is kept, no report), or any capture failure.
    CaptureCancelled
        ``cancel`` was cancelled before the report.
    OutputWriteError
        The report or ``run.json`` could not be written.
    """
    phase = on_phase or (lambda _text: None)
    started = time.perf_counter()
    options = request.options
    with claimed_output(out, "msflash live"):
        phase("metering the exposure" if request.exposure == "auto" else "exposure fixed")
        exposure = plan_exposure(rig, request.exposure, ExposurePolicy(), cancel=cancel)
        phase("capturing ambient, each LED and the flash")
        with sequence_writer(rig, out, exposure) as sync_writer, AsyncSequenceWriter(sync_writer) as writer:
            result = run_one_stream(rig, writer, exposure, options, handlers, cancel)
            why_degenerate = degenerate(result.estimate)
            writer.finish()
        if why_degenerate is not None:
            raise CaptureError(
                f"rig '{rig.name}': the ambient estimate is degenerate ({why_degenerate}); no report written. "
                f"The sequence is complete in {out / 'sequence'}"
            )
        if cancel is not None and cancel.cancelled:
            raise CaptureCancelled(
                f"before the report: {cancel.reason}; the sequence is complete in {out / 'sequence'}"
            )
        from msflash.acquisition.app import report, run_html  # matplotlib: imported when a report is drawn

        phase("writing the report")
        sequence = read_sequence(out / "sequence")
        summary = report.write_run_report(
            out,
            sequence,
            result.estimate,
            result.solutions,
            options.mode,
            rig.true_ambient,
            result.stack,
            options.target,
            result.flash_frame,
        )
        summary["exposure"] = run_html.exposure_summary(exposure, result.flash_exposure_us, result.captured)
        summary["decision_ms"] = round(result.decision_ms, 3)
        summary["elapsed_s"] = round(time.perf_counter() - started, 3)
        run_html.write_run_summary(out, summary, sequence)
    return summary
