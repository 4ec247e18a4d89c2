"""What ``msflash run`` leaves next to the sequence: JSON results, images, a plot and a report.

Matplotlib (Agg) draws the spectra plot and writes the 8-bit PNG previews; linear results go
through :mod:`acquisition.sequence.image_files` as float EXR.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.app.cli_common import dumps_json
from msflash.acquisition.errors import OutputWriteError
from msflash.acquisition.export.exr_metadata import exr_metadata
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.image_files import write_image
from msflash.acquisition.session import analysis
from msflash.processing import datasets
from msflash.processing.ambient import AmbientEstimate
from msflash.processing.flash import FlashSolution
from msflash.processing.metrics import led_fit, led_fit_rmse, spectrum_rmse
from msflash.processing.render import camera_to_xyz_matrix, demosaic_superpixel, srgb_preview
from msflash.processing.spectra import Spectra
from msflash.processing.synthesis import synthesize


def _pyplot():  # noqa: ANN202 - matplotlib is imported lazily, with the non-interactive backend
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_png(path: Path, rgb8: np.ndarray) -> Path:
    """Write an 8-bit RGB preview as PNG."""
    _pyplot().imsave(path, rgb8)
    return path


def linear_rgb(sequence: Sequence, image: np.ndarray) -> np.ndarray:
    """An (H, W, 3) linear camera image from a linear frame (demosaicked 2×2 if it is a mosaic)."""
    if image.ndim == 2:
        if sequence.camera.cfa is None:
            return np.repeat(image[:, :, None], 3, axis=2)
        return demosaic_superpixel(image, sequence.camera.cfa)
    return image


def preview_image(sequence: Sequence, image: np.ndarray) -> np.ndarray:
    """An 8-bit sRGB preview of a linear frame of the sequence, as the run report draws its previews."""
    return srgb_preview(linear_rgb(sequence, image), _camera_to_xyz(sequence))


def _camera_to_xyz(sequence: Sequence) -> np.ndarray | None:
    responsivities = sequence.camera_responsivities()
    if responsivities is None:
        return None
    grid = sequence.grid
    chart = datasets.macbeth().resample(grid, outside="edge")
    return camera_to_xyz_matrix(
        responsivities.to_unit("photons"), chart, datasets.illuminant("D65", grid).to_unit("photons")
    )


def plot_spectra(
    path: Path,
    sequence: Sequence,
    estimate: AmbientEstimate,
    solutions: dict[str, FlashSolution],
    true_ambient: Spectra | None,
    target: Spectra | None,
) -> Path:
    """The spectra plot: estimate ± 1σ, true ambient and the LEDs' best fit of it (simulation), flash mixes,
    ambient + complementary flash."""
    plt = _pyplot()
    wavelengths = sequence.wavelengths_nm
    leds = sequence.led_spectra()
    estimate_values = analysis.spectrum_in_sequence_unit(sequence, estimate.spectrum)
    std = estimate.spectrum.replace(values=estimate.spectrum_std[:, None]).to_unit(sequence.spectral_unit).values[:, 0]
    peak = float(np.max(estimate_values)) or 1.0
    figure, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    left, right = axes
    # The band is the estimate's own uncertainty (AmbientEstimate.spectrum_std), one standard deviation each side;
    # the legend says what it covers (pixel noise, and the model's error when the camera is known).
    covers = "pixel noise + model error" if estimate.miss_risk is not None else "pixel noise only"
    left.fill_between(
        wavelengths,
        (estimate_values - std) / peak,
        (estimate_values + std) / peak,
        color="tab:blue",
        alpha=0.25,
        lw=0,
        label=f"estimate ± 1σ ({covers})",
    )
    left.plot(wavelengths, estimate_values / peak, color="tab:blue", lw=2, label=f"estimate ({estimate.method})")
    if true_ambient is not None:
        # Truth and the LEDs' best fit of it, each least-squares scaled onto the estimate (the metric's scaling).
        truth = true_ambient.resample(sequence.grid).to_unit(sequence.spectral_unit).values[:, 0]
        for curve, style in (
            (truth, dict(color="black", ls="--", lw=1.5, label="true ambient (scaled)")),
            (
                led_fit(leds.values, truth),
                dict(color="gray", ls=":", lw=1.5, label="best non-negative LED fit of the truth"),
            ),
        ):
            if np.any(curve):
                left.plot(wavelengths, curve * float(estimate_values @ curve) / float(curve @ curve) / peak, **style)
    left.set_title("Ambient illuminant")
    left.set_xlabel("wavelength (nm)")
    left.set_ylabel(f"relative spectral power ({sequence.spectral_unit})")
    left.legend()
    for mode, solution in solutions.items():
        flash = leds.values @ solution.flash_weights
        right.plot(wavelengths, flash / peak, lw=1.5, label=f"{mode} flash")
    complementary = solutions.get("complementary")
    if complementary is not None:
        total = leds.values @ (complementary.ambient_weights + complementary.flash_weights)
        right.plot(wavelengths, total / peak, color="tab:purple", lw=2, label="ambient + complementary")
        if target is not None and complementary.scale:
            target_values = target.to_unit(sequence.spectral_unit).values[:, 0]
            target_scale = float(total @ target_values) / float(target_values @ target_values) / peak
            right.plot(wavelengths, target_values * target_scale, color="gray", ls=":", label="target (scaled)")
    right.plot(wavelengths, estimate_values / peak, color="tab:blue", lw=1, alpha=0.6, label="ambient (estimate)")
    right.set_title("Flash mixes")
    right.set_xlabel("wavelength (nm)")
    right.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def write_run_report(
    out: Path,
    sequence: Sequence,
    estimate: AmbientEstimate,
    solutions: dict[str, FlashSolution],
    mode: str,
    true_ambient: Spectra | None,
    stack: analysis.FrameStack,
    target_name: str,
) -> dict[str, Any]:
    """Write everything a run shows a person; return the summary (also written as run.json).

    Raises
    ------
    OutputWriteError
        A file of the report could not be written (disk full, directory gone): names it and says
        that the sequence, written before the report, is complete.
    """
    out = Path(out)
    try:
        return _write_run_report(out, sequence, estimate, solutions, mode, true_ambient, stack, target_name)
    except OSError as err:
        raise OutputWriteError(
            f"{out}: the run report could not be written ({err}); expected a writable disk with room for it. "
            f"The sequence is complete in {sequence.directory} ('msflash estimate', 'flash' and 'synthesize' "
            "read it)"
        ) from err


def _write_run_report(
    out: Path,
    sequence: Sequence,
    estimate: AmbientEstimate,
    solutions: dict[str, FlashSolution],
    mode: str,
    true_ambient: Spectra | None,
    stack: analysis.FrameStack,
    target_name: str,
) -> dict[str, Any]:
    estimate_payload = analysis.estimate_payload(sequence, estimate)
    (out / "estimate.json").write_text(dumps_json(estimate_payload) + "\n")
    for name, solution in solutions.items():
        (out / f"flash-{name}.json").write_text(
            dumps_json(analysis.flash_payload(sequence, solution, target_name)) + "\n"
        )

    matrix = _camera_to_xyz(sequence)
    ambient_linear, _ = sequence.load_linear_frame(stack.ambient_index)
    previews = {"ambient": write_png(out / "ambient.png", srgb_preview(linear_rgb(sequence, ambient_linear), matrix))}
    for name, solution in solutions.items():
        image, _ = synthesize(stack.ambient, stack.led_frames, stack.spec, solution.flash_weights)
        exr = exr_metadata(sequence, 1 if image.ndim == 2 else image.shape[2])
        write_image(
            out / f"{name}.exr",
            image,
            {**exr.attributes, "msflash:flash_weights": solution.flash_weights.tolist()},
            exr.chromaticities,
        )
        previews[name] = write_png(out / f"{name}.png", srgb_preview(linear_rgb(sequence, image), matrix))
    flash_indices = sequence.indices("flash")
    if flash_indices:
        captured, _ = sequence.load_linear_frame(flash_indices[-1])
        previews["flash-capture"] = write_png(
            out / "flash-capture.png", srgb_preview(linear_rgb(sequence, captured), matrix)
        )

    target = None
    if "complementary" in solutions:
        target = analysis.target_illuminant(target_name, sequence).to_unit(sequence.spectral_unit)
    plot = plot_spectra(out / "spectra.png", sequence, estimate, solutions, true_ambient, target)
    summary: dict[str, Any] = {
        "sequence": str(out / "sequence"),
        "frames": len(sequence.frames),
        "ambient_weights": estimate.ambient_weights,
        "relative_residual": estimate.relative_residual,
        "estimate_warnings": list(estimate.warnings),
        "flash": {
            name: {"flash_weights": s.flash_weights, "scale": s.scale, "target_reached": s.target_reached}
            for name, s in solutions.items()
        },
        "recaptured_mode": mode,
        "previews": {name: str(path) for name, path in previews.items()},
        "plot": str(plot),
    }
    if true_ambient is not None:
        summary.update(score_against_truth(sequence, estimate, true_ambient))
    _write_markdown(out / "report.md", summary, sequence)
    return summary


def score_against_truth(sequence: Sequence, estimate: AmbientEstimate, true_ambient: Spectra) -> dict[str, float]:
    """The estimate's spectrum RMSE against the true ambient (a simulation) and what the LEDs allow.

    Returns
    -------
    dict
        ``spectrum_rmse_vs_truth``: the estimate's RMSE (paper's Table 1 metric);
        ``spectrum_rmse_led_bound``: the RMSE of the best non-negative fit of the truth by the
        sequence's LED spectra (:func:`processing.metrics.led_fit_rmse`), both in the sequence's unit.
    """
    truth = true_ambient.resample(sequence.grid).to_unit(sequence.spectral_unit).values[:, 0]
    return {
        "spectrum_rmse_vs_truth": spectrum_rmse(analysis.spectrum_in_sequence_unit(sequence, estimate.spectrum), truth),
        "spectrum_rmse_led_bound": led_fit_rmse(sequence.led_spectra().values, truth),
    }


def _write_markdown(path: Path, summary: dict[str, Any], sequence: Sequence) -> None:
    names = [led.name for led in sequence.leds]
    lines = [
        "# msflash run",
        "",
        f"Sequence: `{summary['sequence']}` ({summary['frames']} frames, camera {sequence.camera.model}).",
        "",
        "![spectra](spectra.png)",
        "",
        "| LED | " + " | ".join(names) + " |",
        "|---|" + "---|" * len(names),
        "| ambient weights | " + " | ".join(f"{w:.3g}" for w in summary["ambient_weights"]) + " |",
    ]
    for mode, flash in summary["flash"].items():
        lines.append(f"| {mode} flash | " + " | ".join(f"{w:.3g}" for w in flash["flash_weights"]) + " |")
    lines += ["", f"Relative residual of the ambient fit: {summary['relative_residual']:.4f}."]
    if "spectrum_rmse_vs_truth" in summary:
        lines.append(
            f"Spectrum RMSE against the true ambient (paper's Table 1 metric): {summary['spectrum_rmse_vs_truth']:.4f}; "
            f"the best non-negative fit of the truth by the LED spectra (what the LEDs allow): "
            f"{summary['spectrum_rmse_led_bound']:.4f}."
        )
    for note in summary["estimate_warnings"]:
        lines.append(f"- warning: {note}")
    lines += [
        "",
        "| ambient | matching (synthesised) | complementary (synthesised) | flash re-capture |",
        "|---|---|---|---|",
        "| ![](ambient.png) | ![](matching.png) | ![](complementary.png) | "
        + ("![](flash-capture.png)" if "flash-capture" in summary["previews"] else "—")
        + " |",
        "",
    ]
    path.write_text("\n".join(lines))
