"""The HTML report of ``msflash run``: previews, spectra, tables and warnings, from ``run.json``'s summary.

Written with :class:`acquisition.app.html_report.HtmlReport` (the writer ``evaluate`` uses) once
the summary is complete, into the run folder beside the files it shows: the previews and the
spectra plot are linked by relative path, not copied, and every link is checked to point at a
file of the run (:meth:`HtmlReport.add_linked_images`). ``run.json`` names it (``report``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from msflash.acquisition.app.cli_common import dumps_json
from msflash.acquisition.app.html_report import HtmlReport
from msflash.acquisition.errors import OutputWriteError
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.session.exposure import snr_or_none

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
    previews = [(captions.get(name, name), Path(file)) for name, file in shown]
    report.add_linked_images(previews, base, columns=2)

    report.add_heading("Spectra")
    report.add_linked_images([("ambient estimate and flash mixes", Path(summary["plot"]))], base, plot=True)

    report.add_heading("LED weights")
    rows: list[list[object]] = [["ambient (estimate)", *[_number(w) for w in summary["ambient_weights"]]]]
    for mode, flash in summary["flash"].items():
        rows.append([f"{mode} flash", *[_number(w) for w in flash["flash_weights"]]])
    report.add_table(["", *names], rows, table_id="weights")

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

    if exposure:
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
    if "decision_ms" in summary:
        report.add_paragraph(
            f"Flash decided {summary['decision_ms']:.1f} ms after the last LED frame; the run took "
            f"{summary.get('elapsed_s', float('nan')):.1f} s.",
            note=True,
        )

    files = ["run.json", "estimate.json", *[f"flash-{mode}.json" for mode in summary["flash"]]]
    files += [f"{mode}.exr" for mode in summary["flash"]] + ["sequence/sequence.json"]
    report.add_heading("Files")
    report.add_file_links(files, base)
    return report.write(path)


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
            f"for it. The sequence is complete in {out / 'sequence'} and the report beside it"
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
