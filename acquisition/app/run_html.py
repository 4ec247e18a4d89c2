"""The HTML report of ``msflash run``: previews, spectra, tables and warnings, from ``run.json``'s summary.

Written with :class:`acquisition.app.html_report.HtmlReport` (the writer ``evaluate`` uses) once
the summary is complete, into the run folder beside the files it shows: the previews and the
spectra plot are linked by relative path, not copied, and every link is checked to point at a
file of the run (:meth:`HtmlReport.add_linked_images`). ``run.json`` names it (``report``).

Its "Files" list links every export of the run: ``run --export``'s (``export`` in ``run.json``) and
those ``msflash export RUN --out RUN/NAME`` makes later, inside the run folder, which
:func:`link_later_export` adds to ``run.json`` (``exports``) before it writes the report again.
"""

from __future__ import annotations

import contextlib
import json
from collections.abc import Sequence as SequenceOf
from pathlib import Path
from typing import Any

from msflash.acquisition.app.cli_common import dumps_json
from msflash.acquisition.app.html_report import HtmlReport
from msflash.acquisition.app.options import SOLVER_CONSTRAINTS
from msflash.acquisition.errors import FolderInUseError, OutputWriteError
from msflash.acquisition.sequence.folder_claim import claim_folder
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.session.led_snr import snr_or_none
from msflash.calibration.file_modes import replacing, write_whole

PREVIEW_CAPTIONS = {
    "ambient": "ambient only",
    "matching": "ambient + matching flash (synthesised)",
    "complementary": "ambient + complementary flash (synthesised)",
    "flash-capture": "flash re-captured",
}
"""What each preview of the summary shows."""


def _number(value: Any, digits: int = 3) -> str:
    return "—" if value is None else f"{float(value):.{digits}g}"


def _snr(value: Any) -> str:
    """An LED's SNR in the report: its figure, or "no signal" where none was measured (JSON null)."""
    return "no signal" if value is None else f"{float(value):.3g}"


def write_run_html(path: Path, summary: dict[str, Any], sequence: Sequence) -> Path:
    """Write the run's report to ``path`` (in the run folder) from the summary ``run.json`` holds; return it.

    Raises
    ------
    OutputWriteError
        The report could not be written (disk full, folder gone): one line naming it and saying that the
        sequence and ``run.json`` are complete.
    """
    path = Path(path)
    try:
        return _write(path, summary, sequence)
    except OSError as err:
        raise OutputWriteError(
            f"{path}: could not be written ({err}); expected a writable disk with room for it. The sequence is "
            f"complete in {summary['sequence']} and run.json beside it"
        ) from err


def _write(path: Path, summary: dict[str, Any], sequence: Sequence) -> Path:
    """The page, section by section, written atomically to ``path``."""
    base = path.parent
    names = [led.name for led in sequence.leds]
    report = HtmlReport(f"msflash run — {base.name}")
    report.add_paragraph(
        f"Sequence {summary['sequence']}: {summary['frames']} frames, camera {sequence.camera.model} "
        f"({sequence.camera.pixel_format}, CFA {sequence.camera.cfa or 'none'}), {len(names)} LEDs. "
        f"Re-captured with the {summary['recaptured_mode']} flash"
        + (f"; complementary target {summary['target']}." if summary.get("target") else ".")
    )
    exposure = summary.get("exposure") or {}
    warnings = [*summary["estimate_warnings"], *exposure.get("warnings", [])]
    if warnings:
        report.add_heading("Warnings")
        for note in warnings:
            report.add_paragraph(f"warning: {note}", warning=True)
    _add_images(report, summary, base)
    _add_weights(report, summary, sequence, names)
    _add_accuracy(report, summary)
    if exposure:
        _add_exposure(report, exposure, names)
    if "decision_ms" in summary:
        report.add_paragraph(
            f"Flash decided {summary['decision_ms']:.1f} ms after the last LED frame; the run took "
            f"{summary.get('elapsed_s', float('nan')):.1f} s.",
            note=True,
        )
    _add_files(report, summary, base)
    with replacing(path) as temporary:  # a reader never sees half a report
        report.write(temporary)
    return path


def _add_images(report: HtmlReport, summary: dict[str, Any], base: Path) -> None:
    """The previews, each linked to its full-size file, and the spectra plot."""
    report.add_heading("Images")
    report.add_paragraph(
        "Camera → XYZ fitted on a Macbeth chart under D65, sRGB, no white balance (the ambient's cast stays "
        "visible); each image exposed on its own: the median of each pixel's brightest channel at 25 % of white, "
        "unless less than 0.5 % of the pixels would then reach white. Click an image for the full-size file.",
        note=True,
    )
    order = {name: index for index, name in enumerate(PREVIEW_CAPTIONS)}
    shown = sorted(summary["previews"].items(), key=lambda item: order.get(item[0], len(order)))
    captions = dict(PREVIEW_CAPTIONS, **{"flash-capture": f"{summary['recaptured_mode']} flash re-captured"})
    previews = [(captions.get(name, name), _rebased(summary, file, base)) for name, file in shown]
    report.add_linked_images(previews, base, columns=2)

    report.add_heading("Spectra")
    report.add_linked_images(
        [("ambient estimate and flash mixes", _rebased(summary, summary["plot"], base))], base, plot=True
    )


def _add_weights(report: HtmlReport, summary: dict[str, Any], sequence: Sequence, names: list[str]) -> None:
    """Each LED's measured peak, ambient weight and flash weights, and what they mean."""
    report.add_heading("LED weights")
    peaks = summary.get("led_peak_nm") or list(sequence.led_peaks_nm())
    rows: list[list[object]] = [["measured peak (nm)", *[f"{float(p):.1f}" for p in peaks]]]
    rows.append(["ambient (estimate)", *[_number(w) for w in summary["ambient_weights"]]])
    for mode, flash in summary["flash"].items():
        rows.append([f"{mode} flash", *[_number(w) for w in flash["flash_weights"]]])
    report.add_table(["", *names], rows, table_id="weights")
    solver = summary.get("solver")
    report.add_paragraph(
        "The ambient weights are the LED mix whose images explain the ambient image (eq. 4–5)"
        + (f", solved by {solver}: {SOLVER_CONSTRAINTS[solver]}" if solver in SOLVER_CONSTRAINTS else "")
        + ". A weight may be negative where neighbouring LEDs overlap (the paper's eq. 6 keeps only the spectrum "
        "non-negative). The flash weights are drive levels, 0 to 1. LED names are the booth's or made from the "
        "measured peak; the peak is that of each LED's measured spectral power.",
        note=True,
    )


def _add_accuracy(report: HtmlReport, summary: dict[str, Any]) -> None:
    """The ambient fit's residual, the RMSE against the truth where it is known, each flash's target reached."""
    report.add_heading("Fit and accuracy")
    accuracy: list[list[object]] = [["relative residual of the ambient fit", _number(summary["relative_residual"], 4)]]
    if "spectrum_rmse_vs_truth" in summary:
        accuracy += [
            ["spectrum RMSE against the true ambient (Table 1 metric)", f"{summary['spectrum_rmse_vs_truth']:.4f}"],
            [
                "best non-negative LED fit of the truth (what the LEDs allow)",
                f"{summary['spectrum_rmse_led_bound']:.4f}",
            ],
        ]
    for mode, flash in summary["flash"].items():
        reached = "yes" if flash["target_reached"] else "no"
        accuracy.append([f"{mode} flash reaches its target", reached])
    report.add_table(["measure", "value"], accuracy, table_id="accuracy")


def _add_exposure(report: HtmlReport, exposure: dict[str, Any], names: list[str]) -> None:
    """Each LED frame's exposure with its planned and measured SNR, and the ambient and flash exposures."""
    report.add_heading("Exposure")
    snr = exposure.get("led_snr") or [None] * len(names)
    planned = exposure.get("predicted_led_snr") or [None] * len(names)
    exposures = exposure.get("led_exposures_us") or [None] * len(names)
    report.add_table(
        ["LED", "exposure (µs)", "planned SNR", "SNR"],
        [
            [name, _number(us, 5), _snr(p), _snr(s)]
            for name, us, p, s in zip(names, exposures, planned, snr, strict=True)
        ],
        table_id="exposure",
    )
    for note in exposure.get("led_snr_warnings") or ():
        report.add_paragraph(f"Warning: {note}.", warning=True)
    report.add_paragraph(
        f"Ambient {_number(exposure.get('ambient_exposure_us'), 5)} µs ({exposure.get('mode', '?')}); flash "
        f"{_number(exposure.get('flash_exposure_us'), 5)} µs. SNR: {exposure.get('led_snr_method', '')}, median pixel.",
        note=True,
    )


def _add_files(report: HtmlReport, summary: dict[str, Any], base: Path) -> None:
    """Links to the run's files and to what was exported."""
    files = ["run.json", "estimate.json", *[f"flash-{mode}.json" for mode in summary["flash"]]]
    files += [f"{mode}.exr" for mode in summary["flash"]] + ["sequence/sequence.json"]
    report.add_heading("Files")
    report.add_file_links(files, base)
    for export in _exports(summary):
        report.add_heading(f"Exported ({', '.join(export.get('formats', []))})", level=3)
        report.add_file_links(_inside([str(_rebased(summary, f, base)) for f in export.get("files", [])], base), base)
        for note in export.get("notes", []):
            report.add_paragraph(f"note: {note}", note=True)


def _rebased(summary: dict[str, Any], file: str, base: Path) -> Path:
    """A path ``run.json`` recorded, in the run folder ``base`` now holding the report: the same file of a run
    folder that was moved or copied since (``run.json`` names the report where the run wrote it)."""
    written = Path(str(summary.get("report", base / "report.html"))).parent
    path = Path(file)
    with contextlib.suppress(ValueError):
        return base / path.relative_to(written)
    return path


def _exports(summary: dict[str, Any]) -> list[dict[str, Any]]:
    """``run --export``'s export and the later ones (``exports``), oldest first."""
    found = [summary["export"]] if isinstance(summary.get("export"), dict) else []
    found += [item for item in summary.get("exports", []) if isinstance(item, dict)]
    return found


def _inside(files: SequenceOf[str], base: Path) -> list[str]:
    """The files under ``base`` (the run folder), as paths relative to it; others are not linked (a report travels
    with its folder)."""
    inside = []
    root = base.resolve()
    for file in files:
        with contextlib.suppress(ValueError, OSError):
            inside.append(Path(file).resolve().relative_to(root).as_posix())
    return inside


def link_later_export(
    run_folder: Path, sequence: Sequence, formats: SequenceOf[str], files: SequenceOf[Path], notes: SequenceOf[str]
) -> str | None:
    """Add an export made after the run to ``run.json`` (``exports``) and write ``report.html`` again to link it.

    For ``msflash export RUN --out RUN/NAME``: only a folder holding ``run.json`` and ``report.html``, and only
    files inside it (a report links by relative path). Returns why nothing was changed, or None when the report
    now links the files.
    """
    run_folder = Path(run_folder)
    summary_path = run_folder / "run.json"
    if not (summary_path.is_file() and (run_folder / "report.html").is_file()):
        return f"{run_folder} holds no run.json and report.html: no run report to link the export from"
    if not _inside([str(f) for f in files], run_folder):
        return f"the export is outside {run_folder}: its report.html links only files inside the run folder"
    try:
        claim = claim_folder(run_folder, "msflash export (linking the export from the run report)")
    except (FolderInUseError, OSError) as err:
        return f"{run_folder}: report.html not updated ({err})"
    with claim:
        try:
            summary = json.loads(summary_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as err:
            return f"{summary_path}: unreadable ({err}); report.html not updated"
        if not isinstance(summary, dict) or "report" not in summary:
            return f"{summary_path}: not a run summary; report.html not updated"
        summary["exports"] = [
            *summary.get("exports", []),
            {"formats": list(formats), "files": [str(f) for f in files], "notes": list(notes)},
        ]
        write_whole(summary_path, dumps_json(summary) + "\n")
        write_run_html(run_folder / "report.html", summary, sequence)
    return None


def write_run_summary(out: Path, summary: dict[str, Any], sequence: Sequence) -> None:
    """``run.json`` then the ``report.html`` it links: the last files of every run (``msflash run`` and ``live``).

    Raises
    ------
    OutputWriteError
        Either could not be written; the message says the sequence (and the report's pictures) are complete.
    """
    out = Path(out)
    try:
        (out / "run.json").write_text(dumps_json(summary) + "\n")
    except OSError as err:
        raise OutputWriteError(
            f"{out / 'run.json'}: could not be written ({err}); expected a writable disk with room "
            f"for it. The sequence is complete in {out / 'sequence'}, the report's images and EXRs beside it "
            "(report.html was not written)"
        ) from err
    write_run_html(Path(summary["report"]), summary, sequence)


def exposure_summary(exposure: Any, flash_exposure_us: float | None, captured: Any) -> dict[str, Any]:
    """``run.json``'s ``exposure``: the planned exposures (``ExposurePlan.to_dict``), the flash frame's, and the
    LED frames' SNR as the capture measured it (``run`` and ``live`` alike)."""
    return {
        **exposure.to_dict(),
        "flash_exposure_us": flash_exposure_us,
        "led_snr": [snr_or_none(v) for v in captured.snr],
        "led_snr_method": captured.snr_method,
        "led_snr_warnings": list(captured.snr_warnings),
    }
