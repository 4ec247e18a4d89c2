"""What ``msflash run`` leaves next to the sequence: JSON results, images, a plot and a report.

Previews hold every camera pixel (a mosaic: every 2×2 CFA cell, :func:`linear_rgb`), exposed by
:func:`processing.render.display_white` and written as sRGB PNGs enlarged to at least 1024 pixels
on the long side (:mod:`acquisition.app.srgb_png`); the spectra plot takes its colours and unit
from :mod:`acquisition.app.plot_style`; linear results go through
:mod:`acquisition.sequence.image_files` as float EXR. The HTML report is
:mod:`acquisition.app.run_html`'s, written once ``run.json``'s summary is complete.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.app.cli_common import dumps_json
from msflash.acquisition.app.plot_style import (
    PALETTE,
    draw_flash_mixes,
    in_plot_unit,
    peak_of,
    pyplot,
    save_figure,
    spectral_axis,
)
from msflash.acquisition.app.srgb_png import enlarged, write_srgb_png
from msflash.acquisition.errors import OutputWriteError
from msflash.acquisition.sequence.exr_metadata import exr_image
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.image_files import write_image
from msflash.acquisition.session import analysis, sequence_spectra
from msflash.processing import datasets
from msflash.processing.ambient import AmbientEstimate
from msflash.processing.flash import FlashSolution
from msflash.processing.flicker import applied_offsets
from msflash.processing.metrics import led_fit, led_fit_rmse, spectrum_rmse
from msflash.processing.render import camera_to_xyz_matrix, demosaic_superpixel, srgb_preview
from msflash.processing.spectra import Spectra
from msflash.processing.synthesis import linearise, synthesize

REPORT_NAME = "report.html"
"""The run's HTML report, beside ``run.json`` (written by :func:`acquisition.app.run_html.write_run_html`)."""


def write_preview(path: Path, rgb8: np.ndarray) -> Path:
    """Write an 8-bit sRGB preview as PNG (sRGB chunk), enlarged to at least 1024 pixels on the long side."""
    return write_srgb_png(path, enlarged(rgb8), {"Software": "msflash"})


def linear_rgb(sequence: Sequence, image: np.ndarray) -> np.ndarray:
    """An (H, W, 3) linear camera image from a linear frame; a mosaic is demosaicked 2×2 (one RGB pixel per CFA cell).

    The superpixel keeps only measured colours: bilinear demosaicking of the sim rig's 8-pixel
    patches drew red/blue fringes on every patch edge, which the enlarged preview made plain.
    """
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


def spectra_figure(
    sequence: Sequence,
    estimate: AmbientEstimate,
    solutions: dict[str, FlashSolution],
    true_ambient: Spectra | None,
    target: Spectra | None,
) -> Any:
    """The spectra plot: estimate ± 1σ, true ambient and the LEDs' best fit of it (simulation), flash mixes,
    ambient + complementary flash; every curve in :data:`plot_style.PLOT_UNIT`, scaled by the estimate's peak."""
    plt = pyplot()
    wavelengths = sequence.wavelengths_nm
    leds = in_plot_unit(sequence.led_spectra())
    estimate_values = in_plot_unit(estimate.spectrum)[:, 0]
    std = in_plot_unit(estimate.spectrum.replace(values=estimate.spectrum_std[:, None]))[:, 0]
    peak = peak_of(estimate_values)
    figure, axes = plt.subplots(1, 2, figsize=(12, 4.8))
    left, right = axes
    # The band is the estimate's own uncertainty (AmbientEstimate.spectrum_std), one standard deviation each side;
    # the legend says what it covers (pixel noise, and the model's error when the camera is known).
    covers = "pixel noise + model error" if estimate.miss_risk is not None else "pixel noise only"
    left.fill_between(
        wavelengths,
        (estimate_values - std) / peak,
        (estimate_values + std) / peak,
        color=PALETTE.ambient,
        alpha=0.2,
        lw=0,
        label=f"estimate ± 1σ ({covers})",
    )
    left.plot(wavelengths, estimate_values / peak, color=PALETTE.ambient, lw=2, label=f"estimate ({estimate.method})")
    if true_ambient is not None:
        # Truth and the LEDs' best fit of it, each least-squares scaled onto the estimate (the metric's scaling).
        truth = in_plot_unit(true_ambient.resample(sequence.grid))[:, 0]
        for curve, style in (
            (truth, dict(color=PALETTE.truth, ls="--", lw=1.5, label="true ambient (scaled)")),
            (
                led_fit(leds, truth),
                dict(color=PALETTE.led_fit, ls=":", lw=1.8, label="best non-negative LED fit of the truth"),
            ),
        ):
            if np.any(curve):
                left.plot(wavelengths, curve * float(estimate_values @ curve) / float(curve @ curve) / peak, **style)
    left.set_title("Ambient illuminant")
    spectral_axis(left, "peak of the estimate")
    left.legend()
    target_values = None if target is None else in_plot_unit(target)[:, 0]
    draw_flash_mixes(right, wavelengths, leds, estimate_values, solutions, target_values, peak)
    right.set_title("Flash mixes")
    spectral_axis(right, "peak of the estimate")
    right.legend()
    figure.tight_layout()
    return figure


def write_run_report(
    out: Path,
    sequence: Sequence,
    estimate: AmbientEstimate,
    solutions: dict[str, FlashSolution],
    mode: str,
    true_ambient: Spectra | None,
    stack: analysis.FrameStack,
    target_name: str,
    flash_frame: np.ndarray | None = None,
) -> dict[str, Any]:
    """Write everything a run shows a person; return the summary (also written as run.json).

    Every image comes from frames in memory: the ambient and LED frames of ``stack`` and the re-captured
    ``flash_frame`` (as recorded; None when the flash was synthesised only). No frame is read back from
    disk.

    Raises
    ------
    OutputWriteError
        A file of the report could not be written (disk full, directory gone): names it and says
        that the sequence, written before the report, is complete.
    """
    out = Path(out)
    try:
        (out / "estimate.json").write_text(dumps_json(analysis.estimate_payload(sequence, estimate)) + "\n")
        for name, solution in solutions.items():
            (out / f"flash-{name}.json").write_text(
                dumps_json(analysis.flash_payload(sequence, solution, target_name)) + "\n"
            )
        previews = _write_previews(out, sequence, solutions, stack, flash_frame, applied_offsets(estimate.flicker))
        target = None
        if "complementary" in solutions:
            target = sequence_spectra.target_illuminant(target_name, sequence).to_unit(sequence.spectral_unit)
        plot = save_figure(spectra_figure(sequence, estimate, solutions, true_ambient, target), out / "spectra.png")
    except OSError as err:
        raise OutputWriteError(
            f"{out}: the run report could not be written ({err}); expected a writable disk with room for it. "
            f"The sequence is complete in {sequence.directory} ('msflash estimate', 'flash' and 'synthesize' "
            "read it)"
        ) from err
    summary: dict[str, Any] = {
        "sequence": str(out / "sequence"),
        "frames": len(sequence.frames),
        "ambient_weights": estimate.ambient_weights,
        "solver": estimate.method,
        "led_peak_nm": list(sequence.led_peaks_nm()),
        "relative_residual": estimate.relative_residual,
        "estimate_warnings": list(estimate.warnings),
        "flash": {
            name: {"flash_weights": s.flash_weights, "scale": s.scale, "target_reached": s.target_reached}
            for name, s in solutions.items()
        },
        "recaptured_mode": mode,
        "target": target_name,
        "previews": {name: str(path) for name, path in previews.items()},
        "plot": str(plot),
        "report": str(out / REPORT_NAME),
    }
    if true_ambient is not None:
        summary.update(score_against_truth(sequence, estimate, true_ambient))
    return summary


def _write_previews(
    out: Path,
    sequence: Sequence,
    solutions: dict[str, FlashSolution],
    stack: analysis.FrameStack,
    flash_frame: np.ndarray | None,
    flicker_offsets: np.ndarray | None,
) -> dict[str, Path]:
    """The ambient's, each flash's synthesised (with its EXR; a flickering lamp's shares taken out) and the
    captured flash's previews."""
    matrix = _camera_to_xyz(sequence)
    ambient_linear, _ = _linear(sequence, stack.ambient_index, stack.ambient)
    previews = {
        "ambient": write_preview(out / "ambient.png", srgb_preview(linear_rgb(sequence, ambient_linear), matrix))
    }
    for name, solution in solutions.items():
        image, _ = synthesize(
            stack.ambient,
            stack.led_frames,
            stack.spec,
            solution.flash_weights,
            ambient_offsets=flicker_offsets,
        )
        rgb, exr = exr_image(sequence, image)
        write_image(
            out / f"{name}.exr",
            rgb,
            {
                **exr.attributes,
                "msflash:content": f"the {name} computational flash image",
                "msflash:flash_weights": solution.flash_weights.tolist(),
            },
            exr.chromaticities,
        )
        previews[name] = write_preview(out / f"{name}.png", srgb_preview(linear_rgb(sequence, image), matrix))
    flash_indices = sequence.indices("flash")
    if flash_indices and flash_frame is not None:
        captured, _ = _linear(sequence, flash_indices[-1], flash_frame)
        previews["flash-capture"] = write_preview(
            out / "flash-capture.png", srgb_preview(linear_rgb(sequence, captured), matrix)
        )
    return previews


def _linear(sequence: Sequence, index: int, pixels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Frame ``index``'s pixels in memory, as :meth:`Sequence.load_linear_frame` gives them from the file."""
    entry, camera = sequence.frames[index], sequence.camera
    return linearise(pixels, camera.black_level, camera.white_level, entry.exposure_us, entry.gain)


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
        "spectrum_rmse_vs_truth": spectrum_rmse(
            sequence_spectra.spectrum_in_sequence_unit(sequence, estimate.spectrum), truth
        ),
        "spectrum_rmse_led_bound": led_fit_rmse(sequence.led_spectra().values, truth),
    }
