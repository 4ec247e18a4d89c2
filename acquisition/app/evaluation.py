"""Colour accuracy and noise of a chart sequence (``msflash evaluate``).

``evaluate``: the sequence's ambient estimate, matching and complementary flashes, the
synthesised images (and any re-captured flash frame), rendered the paper's way (camera → XYZ
fitted on a Macbeth chart under D65, no white balance) and compared patch by patch with the ideal
chart under D65 (CIEDE2000, Fig. 9). A von Kries-balanced ambient image is compared with the
complementary image for per-channel SNR and chroma noise (Fig. 3). Output: linear EXR, 16-bit
sRGB TIFF and PNG per image (each with its metadata), ``evaluation.json`` and a self-contained
``report.html``.

The simulated colour study (``msflash colour-study``) applies the same measures to simulated captures:
:mod:`msflash.lab.colour_study`.

Which pixels are which patch
----------------------------
:mod:`msflash.acquisition.session.chart_layout`: the chart is detected unless ``--patch-px`` /
``--border-px`` rebuild the sim rig's layout, and the layout is checked against the ambient image
either way (evaluation stops with a message naming the options when it does not fit).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.app.cli_common import dumps_json, progress
from msflash.acquisition.app.html_report import HtmlReport
from msflash.acquisition.app.plot_style import (
    PALETTE,
    draw_flash_mixes,
    figure_png,
    in_plot_unit,
    peak_of,
    pyplot,
    spectral_axis,
)
from msflash.acquisition.app.srgb_png import enlarged, srgb_png_bytes
from msflash.acquisition.sequence.exr_metadata import LINEAR_UNITS
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.image_files import write_image
from msflash.acquisition.session import analysis, sequence_spectra
from msflash.acquisition.session.both_flashes import solve_both
from msflash.acquisition.session.chart_layout import (
    ChartLayout,
    ChartName,
    check_layout,
    sequence_layout,
)
from msflash.processing import colour_metrics, datasets
from msflash.processing.errors import SpectralDataError
from msflash.processing.flash import FlashBounds, FlashSolution, solve_complementary, solve_matching
from msflash.processing.flicker import applied_offsets
from msflash.processing.raw_colour import rgb_chromaticities
from msflash.processing.render import camera_to_srgb_linear, camera_to_xyz_matrix, demosaic_bilinear, encode_srgb
from msflash.processing.spectra import Spectra, WavelengthGrid
from msflash.processing.synthesis import synthesize

CHANNELS = ("R", "G", "B")


# -- measures on images -----------------------------------------------------------------------
@dataclass(frozen=True)
class ColourContext:
    """What every measure needs besides the images."""

    layout: ChartLayout
    camera_to_xyz: np.ndarray
    reference: colour_metrics.ReferenceChart
    cfa: str | None
    led_names: tuple[str, ...] = ()
    """The LEDs of the images, named in the EXRs written (:func:`write_outputs`)."""


def colour_context(
    camera_photons: Spectra, grid: WavelengthGrid, layout: ChartLayout, cfa: str | None, led_names: tuple[str, ...] = ()
) -> ColourContext:
    """Camera → XYZ fitted on the Macbeth chart under D65, and the ideal chart under D65 (Fig. 9)."""
    chart = datasets.macbeth().resample(grid, outside="edge")
    d65 = datasets.illuminant("D65", grid)
    matrix = camera_to_xyz_matrix(camera_photons, chart, d65.to_unit("photons"))
    return ColourContext(layout, matrix, colour_metrics.reference_chart(chart, d65), cfa, led_names)


def full_rgb(image: np.ndarray, cfa: str | None) -> np.ndarray:
    """(H, W, 3) linear RGB: a mosaic is demosaicked bilinearly (the paper's rendering)."""
    if image.ndim == 2:
        if cfa is None:
            return np.repeat(image[:, :, None].astype(np.float64), 3, axis=2)
        return demosaic_bilinear(image, cfa)
    return image.astype(np.float64)


def delta_e_of(
    image: np.ndarray, context: ColourContext, white_balance: np.ndarray | None = None
) -> colour_metrics.ChartDeltaE:
    """Fig. 9's per-patch ΔE00 of a linear image (patch means from the raw samples)."""
    means = colour_metrics.patch_means(
        image, context.layout.labels, context.layout.n_patches, context.cfa, min_pixels=2
    )
    return colour_metrics.chart_delta_e(means, context.camera_to_xyz, context.reference, white_balance)


def noise_of(image: np.ndarray, context: ColourContext, white_balance: np.ndarray | None = None) -> dict[str, Any]:
    """Per-channel SNR and chroma noise on the neutral patches of a linear image (black removed)."""
    neutrals = list(context.layout.neutrals)
    balanced = image if white_balance is None else colour_metrics.von_kries_balance(image, white_balance, context.cfa)
    snr = colour_metrics.channel_snr(balanced, context.layout.labels, neutrals, context.cfa)
    rgb = full_rgb(np.asarray(balanced, dtype=np.float64), context.cfa)
    labels = context.layout.labels
    if context.cfa is not None:  # interpolated pixels next to an edge mix patches: one more pixel of margin
        labels = colour_metrics.usable_labels(np.where(labels < 0, context.layout.n_patches, labels), 1)
        labels[labels >= context.layout.n_patches] = -1
    chroma = colour_metrics.chroma_noise(
        rgb, labels, neutrals, context.camera_to_xyz, context.reference, context.layout.n_patches
    )
    return {
        "patches": neutrals,
        "snr": {c: snr[:, i] for i, c in enumerate(CHANNELS)},
        "mean_snr": {c: float(np.mean(snr[:, i])) for i, c in enumerate(CHANNELS)},
        "chroma_noise": chroma,
        "mean_chroma_noise": float(np.mean(chroma)),
    }


def preview_png(
    image: np.ndarray,
    context: ColourContext,
    scale: float,
    white_balance: np.ndarray | None = None,
    metadata: dict[str, Any] | None = None,
) -> tuple[bytes, np.ndarray]:
    """PNG bytes (enlarged to ≥ 1024 pixels, sRGB chunk) and the float sRGB image (the image's own size) of a
    linear image at the ΔE exposure normalisation ``scale``.

    Display white is the Y of a perfect white after normalisation, so previews of images with
    different exposures or flash power compare directly.
    """
    rgb = full_rgb(image, context.cfa) * scale
    srgb_linear, _ = camera_to_srgb_linear(rgb, context.camera_to_xyz, white_balance)
    encoded = encode_srgb(srgb_linear, float(context.reference.white_xyz[1]))
    text = {"Software": "msflash", "Description": json.dumps(metadata or {}, default=str)}
    return srgb_png_bytes(enlarged(np.round(encoded * 255).astype(np.uint8)), text), encoded


def write_outputs(
    out: Path,
    name: str,
    image: np.ndarray,
    context: ColourContext,
    scale: float,
    white_balance: np.ndarray | None,
    metadata: dict[str, Any],
) -> bytes:
    """``name.exr`` (linear camera RGB), ``name.tiff`` (16-bit sRGB) and ``name.png`` (8-bit sRGB), all with metadata."""
    attributes = {f"msflash:{key}": value for key, value in metadata.items()}
    linear = full_rgb(image, context.cfa) * (white_balance if white_balance is not None else 1.0)
    # What the RGB means to a viewer: the camera's primaries (balanced by the von Kries gains when given).
    camera_to_xyz = context.camera_to_xyz / (white_balance if white_balance is not None else 1.0)
    try:
        chromaticities: tuple[float, ...] | None = rgb_chromaticities(camera_to_xyz)
    except SpectralDataError:
        chromaticities = None
    write_image(
        out / f"{name}.exr",
        linear.astype(np.float32),
        {
            **attributes,
            "msflash:content": "linear camera RGB per µs·gain",
            "msflash:units": LINEAR_UNITS,
            "msflash:led_names": ", ".join(context.led_names),
        },
        chromaticities,
    )
    png, encoded = preview_png(image, context, scale, white_balance, metadata)
    write_image(
        out / f"{name}.tiff",
        np.round(encoded * 65535).astype(np.uint16),
        {**attributes, "msflash:content": "sRGB, camera→XYZ fitted under D65, exposure-normalised"},
    )
    (out / f"{name}.png").write_bytes(png)
    return png


# -- evaluate a sequence ----------------------------------------------------------------------
@dataclass(frozen=True)
class _SpectraFlashes:
    """The flash solvers on LED spectra and camera responsivities in photons (a :class:`FlashSolver`)."""

    leds: Spectra
    camera: Spectra
    target: Spectra
    bounds: FlashBounds

    def solve(self, mode: str, ambient_weights: np.ndarray) -> FlashSolution:
        if mode == "matching":
            return solve_matching(ambient_weights, self.leds, self.camera, bounds=self.bounds)
        return solve_complementary(ambient_weights, self.leds, self.camera, self.target, bounds=self.bounds)


def _solve_both(
    ambient_weights: np.ndarray, leds: Spectra, camera: Spectra, target: Spectra, bounds: FlashBounds
) -> tuple[dict[str, FlashSolution], list[str]]:
    both = solve_both(_SpectraFlashes(leds, camera, target, bounds), ambient_weights, first="matching")
    return both.solutions, both.notes


def evaluate_sequence(
    sequence: Sequence,
    out: Path,
    chart: ChartName = "macbeth",
    patch_px: int | None = None,
    border_px: int | None = None,
    margin_px: int = 1,
    bounds: FlashBounds = "physical",
    target: str = "D65",
) -> dict[str, Any]:
    """Evaluate a sequence of a chart; writes images, ``evaluation.json`` and ``report.html`` to ``out``.

    Without ``patch_px`` and ``border_px`` the chart is detected (:func:`sequence_layout`).
    """
    out.mkdir(parents=True, exist_ok=True)
    camera = sequence_spectra.camera_responsivities_photons(sequence)
    leds = sequence_spectra.led_spectra_photons(sequence)
    stack = analysis.load_frame_stack(sequence)
    cfa = sequence.camera.cfa
    ambient, saturated = sequence.load_linear_frame(stack.ambient_index)
    # Find and check the layout before any processing, so a wrong --patch-px fails at once.
    found = sequence_layout(sequence, chart, patch_px, border_px, margin_px)
    check_layout(ambient, found.build(ambient.shape[:2], saturated), cfa)
    progress("estimating the ambient and solving the flashes")
    estimate = analysis.estimate_sequence(sequence, stream=analysis.stream_stack(sequence, stack))
    target_spd = sequence_spectra.target_illuminant(target, sequence)
    solutions, notes = _solve_both(estimate.ambient_weights, leds, camera, target_spd, bounds)

    images: dict[str, np.ndarray] = {"ambient": ambient}
    weights: dict[str, np.ndarray] = {}
    for mode, solution in solutions.items():
        image, synth_saturated = synthesize(
            stack.ambient,
            stack.led_frames,
            stack.spec,
            solution.flash_weights,
            ambient_offsets=applied_offsets(estimate.flicker),
        )
        images[mode], weights[mode] = image.astype(np.float64), solution.flash_weights
        saturated |= synth_saturated
    for index in sequence.indices("flash"):
        # A re-captured flash frame: named after the solved mix its LED levels are closest to.
        image, flash_saturated = sequence.load_linear_frame(index)
        levels = np.asarray(sequence.frames[index].led_levels, dtype=float)
        closest = min(
            solutions, key=lambda m: float(np.linalg.norm(np.clip(solutions[m].flash_weights, 0, 1) - levels))
        )
        name = f"{closest}-capture" if f"{closest}-capture" not in images else f"flash-{index}"
        images[name], weights[name] = image, levels
        saturated |= flash_saturated
    layout = found.build(ambient.shape[:2], saturated)
    uniformity = check_layout(ambient, layout, cfa)
    context = colour_context(camera, sequence.grid, layout, cfa, tuple(led.name for led in sequence.leds))
    d65_white = camera.values.T @ datasets.illuminant("D65", sequence.grid).to_unit("photons").values[:, 0]
    gains = colour_metrics.von_kries_gains(camera.values.T @ estimate.spectrum.values[:, 0], d65_white)
    noise_image = "complementary-capture" if "complementary-capture" in images else "complementary"
    result = _measure(out, images, context, gains, images[noise_image], weights)
    result.update(
        {
            "sequence": str(sequence.directory),
            "chart": chart,
            "layout": layout.description,
            "layout_parameters": found.report,
            "layout_uniformity": uniformity,
            "bounds": bounds,
            "target": target,
            "ambient_weights": estimate.ambient_weights,
            "flash_weights": {m: s.flash_weights for m, s in solutions.items()},
            "complementary_target_reached": solutions["complementary"].target_reached,
            "warnings": notes,
            "noise_flash_image": noise_image if noise_image.endswith("capture") else "complementary (synthesised)",
        }
    )
    spectra_png = figure_png(spectra_figure(sequence.grid, leds, estimate.spectrum, solutions, target_spd))
    (out / "spectra.png").write_bytes(spectra_png)
    result["report"] = str(out / "report.html")
    (out / "evaluation.json").write_text(dumps_json(public_result(result)) + "\n")
    _sequence_report(out / "report.html", result, spectra_png)
    return result


def _measure(
    out: Path,
    images: dict[str, np.ndarray],
    context: ColourContext,
    gains: np.ndarray,
    flash_image: np.ndarray,
    weights: dict[str, np.ndarray],
) -> dict[str, Any]:
    """ΔE of every image (plus the von Kries-balanced ambient), noise of von Kries vs the flash image, outputs."""
    delta_e: dict[str, Any] = {}
    previews: dict[str, bytes] = {}
    rendered = [(name, image, None) for name, image in images.items()] + [
        ("ambient-von-kries", images["ambient"], gains)
    ]
    for name, image, balance in rendered:
        result = delta_e_of(image, context, balance)
        delta_e[name] = {"mean": result.mean, "max": result.max, "per_patch": result.delta_e}
        previews[name] = write_outputs(
            out,
            name,
            image,
            context,
            result.scale,
            balance,
            {
                "image": name,
                "flash_weights": weights.get(name, np.zeros(0)).tolist(),
                "white_balance": None if balance is None else balance.tolist(),
                "mean_delta_e00": result.mean,
            },
        )
    noise: dict[str, Any] = {
        "von_kries": noise_of(images["ambient"], context, gains),
        "complementary": noise_of(flash_image, context),
    }
    noise["von_kries_gains"] = gains
    return {
        "delta_e": delta_e,
        "noise": noise,
        "previews": {name: f"{name}.png" for name in previews},
        "_png": previews,
    }


def spectra_figure(
    grid: WavelengthGrid,
    leds: Spectra,
    estimate: Spectra,
    solutions: dict[str, FlashSolution],
    target: Spectra,
    truth: Spectra | None = None,
) -> Any:
    """The ambient estimate, the flash mixes and the target, in :data:`plot_style.PLOT_UNIT`."""
    plt = pyplot()
    wavelengths = grid.wavelengths_nm
    ambient = in_plot_unit(estimate)[:, 0]
    peak = peak_of(ambient)
    figure, axis = plt.subplots(figsize=(8, 4.2))
    if truth is not None:
        true_values = in_plot_unit(truth)[:, 0]
        axis.plot(
            wavelengths,
            true_values * float(ambient @ true_values) / float(true_values @ true_values) / peak,
            color=PALETTE.truth,
            ls="--",
            lw=1.5,
            label="true ambient (scaled)",
        )
    draw_flash_mixes(axis, wavelengths, in_plot_unit(leds), ambient, solutions, in_plot_unit(target)[:, 0], peak)
    spectral_axis(axis, "peak of the estimate")
    axis.legend(loc="upper left")
    figure.tight_layout()
    return figure


def _delta_e_rows(delta_e: dict[str, Any]) -> list[list[object]]:
    return [[name, values["mean"], values["max"]] for name, values in delta_e.items()]


def _noise_rows(noise: dict[str, Any]) -> list[list[object]]:
    return [
        [
            label,
            noise[key]["mean_snr"]["R"],
            noise[key]["mean_snr"]["G"],
            noise[key]["mean_snr"]["B"],
            noise[key]["mean_chroma_noise"],
        ]
        for key, label in (("von_kries", "ambient, von Kries balanced"), ("complementary", "complementary flash"))
    ]


_NOISE_HEADERS = ["image", "SNR R", "SNR G", "SNR B", "chroma noise (ΔE a*b*)"]


def _sequence_report(path: Path, result: dict[str, Any], spectra_png: bytes) -> None:
    report = HtmlReport(f"msflash evaluation — {Path(result['sequence']).name}")
    report.add_paragraph(
        f"Sequence {result['sequence']}; chart {result['chart']} ({result['layout']}); "
        f"flash bounds {result['bounds']}; complementary target {result['target']}."
    )
    report.add_heading("Images (camera → XYZ fitted under D65, no white balance, exposure-normalised)")
    report.add_images(list(result["_png"].items()), columns=3)
    report.add_heading("Spectra")
    report.add_images([("ambient estimate and flash mixes", spectra_png)], plot=True)
    report.add_heading("CIEDE2000 against the ideal chart under D65 (Fig. 9)")
    report.add_table(["image", "mean ΔE00", "max ΔE00"], _delta_e_rows(result["delta_e"]), table_id="delta-e")
    report.add_heading("Noise at equal exposure (Fig. 3), neutral patches")
    report.add_table(_NOISE_HEADERS, _noise_rows(result["noise"]), table_id="noise", digits=1)
    for note in result["warnings"]:
        report.add_paragraph(f"warning: {note}", warning=True)
    report.write(path)


def public_result(result: dict[str, Any]) -> dict[str, Any]:
    return {key: value for key, value in result.items() if not key.startswith("_")}
