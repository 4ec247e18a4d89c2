"""Colour accuracy and noise of a chart sequence (``msflash evaluate``) and the simulated colour study (``msflash colour-study``).

``evaluate``: the sequence's ambient estimate, matching and complementary flashes, the
synthesised images (and any re-captured flash frame), rendered the paper's way (camera → XYZ
fitted on a Macbeth chart under D65, no white balance) and compared patch by patch with the ideal
chart under D65 (CIEDE2000, Fig. 9). A von Kries-balanced ambient image is compared with the
complementary image for per-channel SNR and chroma noise (Fig. 3). Output: linear EXR, 16-bit
sRGB TIFF and PNG per image (each with its metadata), ``evaluation.json`` and a self-contained
``report.html``.

``colour-study``: the same measures on simulated captures (:class:`SimulatedCamera`, in
process, no booth) for the tungsten, fluorescent, green, orange and underwater ambients — the
Fig. 9 chart — and the Fig. 3 noise comparison under water.

Which pixels are which patch
----------------------------
A sequence does not record its chart layout. By default ``evaluate`` detects the chart
(:mod:`calibration.chart_detection`: anywhere in the frames, any scale, a small rotation, either
orientation, RGB or Bayer) and reports where it found it (``layout_parameters``). Given
``--patch-px`` and/or ``--border-px`` it rebuilds the label map with
:func:`processing.image_formation.chart_scene` instead (the sim rig's defaults, 8 and 2), anchored
at the top-left pixel. Pixels outside the chart (the sim rig's highlight strip) and within
``--margin-px`` of a patch edge are ignored. The layout is checked either way: if the patches are
not uniform in the ambient image (within-patch spread larger than a quarter of the spread between
patches) evaluation stops with a message naming the options.

Underwater world of ``colour-study``
------------------------------------
The ambient is :func:`processing.water.underwater_ambient` (D65 at ``--depth-m`` in
``--water``, seen over ``--distance-m``). The same subject → camera path, and the camera →
subject path of the flash, attenuate the LEDs: the world's LEDs are the in-air LEDs ×
:func:`processing.water.flash_path_transmittance`, and the sequence records these (a flash
calibrated in situ; an in-air calibration would give the solvers the wrong red).
"""

from __future__ import annotations

import io
import json
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np

from msflash.acquisition.app.cli_common import UsageError, dumps_json, progress
from msflash.acquisition.app.html_report import HtmlReport
from msflash.acquisition.progress import counted
from msflash.acquisition.sequence.format import Sequence
from msflash.acquisition.sequence.image_files import write_image
from msflash.acquisition.session import analysis
from msflash.calibration import chart_detection
from msflash.processing import colour_metrics, datasets, lights, water
from msflash.processing.ambient import estimate_ambient
from msflash.processing.errors import TargetUnreachableWarning
from msflash.processing.flash import FlashBounds, FlashSolution, solve_complementary, solve_matching
from msflash.processing.image_formation import chart_scene
from msflash.processing.render import camera_to_srgb_linear, camera_to_xyz_matrix, demosaic_bilinear, encode_srgb
from msflash.processing.spectra import DEFAULT_GRID, Spectra, WavelengthGrid
from msflash.processing.statistics import FrameStackSpec, accumulate_statistics
from msflash.processing.synthesis import synthesize

CHARTS = ("macbeth",)
"""Charts ``evaluate`` knows the layout and reference of."""
ChartName = Literal["chart110", "macbeth"]
"""The chart layouts of :func:`processing.image_formation.chart_scene`."""
MACBETH_NEUTRALS = (3, 7, 11, 15, 19, 23)
"""The gray series of the Macbeth chart in ISET order (white … black), 0-based."""
STUDY_AMBIENTS = ("tungsten", "fluorescent", "green", "orange", "underwater")
"""The ambients of Fig. 9 (the paper's booth ambients and its pool dive)."""
LAYOUT_UNIFORMITY_LIMIT = 0.25
"""Largest accepted ratio of within-patch to between-patch spread of the ambient image."""
CHANNELS = ("R", "G", "B")


# -- the chart layout -------------------------------------------------------------------------
@dataclass(frozen=True)
class ChartLayout:
    """Which pixels of an image belong to which chart patch."""

    labels: np.ndarray
    """Patch index of every usable pixel, −1 elsewhere, (H, W)."""
    n_patches: int
    """Number of patches (labels 0 … n − 1)."""
    neutrals: tuple[int, ...]
    """The gray patches (for noise measures)."""
    description: str
    """How the layout was obtained."""


def chart_layout(
    shape: tuple[int, int],
    chart: ChartName = "macbeth",
    patch_px: int = 8,
    border_px: int = 2,
    margin_px: int = 1,
    excluded: np.ndarray | None = None,
) -> ChartLayout:
    """The label map of a simulated chart of ``chart_scene(chart, patch_px, border_px)`` at the top left."""
    if chart not in CHARTS:
        raise UsageError(f"--chart '{chart}': unknown; expected one of {', '.join(CHARTS)}")
    if patch_px < 1 or border_px < 0 or margin_px < 0:
        raise UsageError(
            f"--patch-px {patch_px}, --border-px {border_px}, --margin-px {margin_px}: expected "
            "patch ≥ 1 and the others ≥ 0"
        )
    if 2 * margin_px >= patch_px:
        raise UsageError(
            f"--margin-px {margin_px} leaves nothing of {patch_px}-pixel patches; expected margin < patch/2"
        )
    scene = chart_scene(chart, patch_px=patch_px, border_px=border_px)
    n_patches = scene.reflectances.count - 1  # the last surface is the border
    height, width = scene.shape
    if height > shape[0] or width > shape[1]:
        raise UsageError(
            f"--patch-px {patch_px} --border-px {border_px}: the {chart} chart is {height}×{width} pixels "
            f"but the image is {shape[0]}×{shape[1]}; expected the sim rig's layout"
        )
    labels = np.full(shape, -1, dtype=np.int64)
    chart_labels = np.asarray(scene.labels, dtype=np.int64)
    labels[:height, :width] = np.where(chart_labels == n_patches, -1, chart_labels)
    # The border counts as its own surface for the edge margin, then is dropped.
    with_border = np.full(shape, n_patches + 1, dtype=np.int64)
    with_border[:height, :width] = chart_labels
    usable = colour_metrics.usable_labels(with_border, margin_px, excluded)
    usable[(usable >= n_patches)] = -1
    return ChartLayout(
        usable,
        n_patches,
        MACBETH_NEUTRALS,
        f"{chart} chart rebuilt with chart_scene(patch_px={patch_px}, border_px={border_px}) at the "
        f"top-left pixel, {margin_px}-pixel margin",
    )


@dataclass(frozen=True)
class SequenceLayout:
    """How a sequence's patches are found: a given sim-rig layout or a detected chart."""

    build: Callable[..., ChartLayout]
    """``build(shape, excluded=None)``: the label map for an image shape, dropping excluded pixels."""
    report: dict[str, Any]
    """For JSON output: ``detected`` and the layout's parameters."""


def sequence_layout(
    sequence: Sequence,
    chart: ChartName = "macbeth",
    patch_px: int | None = None,
    border_px: int | None = None,
    margin_px: int = 1,
) -> SequenceLayout:
    """The chart layout of ``sequence``: detected when neither ``patch_px`` nor ``border_px`` is given.

    Detection (:func:`calibration.chart_detection.detect_in_sequence`) finds the chart anywhere in
    the frames, at any scale and a small rotation; given options rebuild the sim rig's chart at the
    top left (:func:`chart_layout`, the other option at its sim-rig default).

    Raises
    ------
    UsageError
        An unknown chart, or no single chart found (naming the sequence and the layout options).
    """
    if chart not in CHARTS:
        raise UsageError(f"--chart '{chart}': unknown; expected one of {', '.join(CHARTS)}")
    if patch_px is not None or border_px is not None:
        patch, border = (8 if patch_px is None else patch_px), (2 if border_px is None else border_px)
        return SequenceLayout(
            lambda shape, excluded=None: chart_layout(shape, chart, patch, border, margin_px, excluded),
            {"detected": False, "patch_px": patch, "border_px": border, "margin_px": margin_px},
        )
    if margin_px < 0:
        raise UsageError(f"--margin-px {margin_px}: expected ≥ 0")
    reflectances = datasets.macbeth().resample(sequence.grid, outside="edge")
    try:
        grid = chart_detection.detect_in_sequence(sequence, reflectances, *chart_detection.MACBETH_GRID)
    except chart_detection.ChartDetectionError as err:
        raise UsageError(str(err)) from err
    patch = min(grid.as_dict()["patch_px"])
    if 2 * margin_px >= patch:
        raise UsageError(
            f"--margin-px {margin_px} leaves nothing of the {patch:.1f}-pixel patches of the chart "
            f"detected in {sequence.path}; expected margin < patch/2"
        )
    description = f"{grid.describe()}, {margin_px}-pixel margin"
    return SequenceLayout(
        lambda shape, excluded=None: ChartLayout(
            grid.labels(shape, margin_px, excluded), grid.rows * grid.columns, MACBETH_NEUTRALS, description
        ),
        {"detected": True, **grid.as_dict(), "margin_px": margin_px},
    )


def check_layout(
    image: np.ndarray, layout: ChartLayout, cfa: str | None, *, worst_patch_limit: float = 1.0, twin_z: float = 4.0
) -> float:
    """Check that ``layout`` fits the chart in ``image``; return the median within/between spread ratio.

    Three tests, each aimed at one way a wrong ``--patch-px/--border-px/--margin-px`` shows:

    - the median patch's within-patch spread (green) must stay below
      :data:`LAYOUT_UNIFORMITY_LIMIT` × the spread between patch means (most patches misplaced);
    - the worst patch's within spread must stay below ``worst_patch_limit`` × the between spread
      (a patch straddling two chart patches or a border);
    - at most a quarter of the patches may read the same colour as another patch, i.e. differ
      from it by less than ``twin_z`` standard errors in every channel (a layout of smaller pitch
      that samples parts of the chart several times while every sampled area is uniform).

    Raises
    ------
    UsageError
        Naming the failed test and the options to check.
    """
    green = 1 if (image.ndim == 3 or cfa is not None) else 0
    within, means, errors = [], [], []
    for patch in range(layout.n_patches):
        channels = colour_metrics.patch_pixels(image, layout.labels, patch, cfa)
        samples = channels[green]
        if samples.size < 2:
            raise UsageError(
                f"chart layout: patch {patch} has {samples.size} usable pixels; expected a layout that "
                "fits the image (--patch-px/--border-px/--margin-px)"
            )
        within.append(samples.std())
        means.append([c.mean() if c.size else np.nan for c in channels])
        errors.append([c.std(ddof=1) / np.sqrt(c.size) if c.size > 1 else np.nan for c in channels])
    patch_means, standard_errors = np.array(means), np.array(errors)
    between = float(np.std(patch_means[:, green]))
    spread = np.array(within) / between if between > 0 else np.full(len(within), np.inf)
    ratio = float(np.median(spread))
    if not ratio <= LAYOUT_UNIFORMITY_LIMIT:
        raise UsageError(
            f"chart layout: patches are not uniform in the ambient image (within/between spread "
            f"{ratio:.2f} > {LAYOUT_UNIFORMITY_LIMIT}); expected the sim rig's chart with these "
            "--patch-px/--border-px (a real photograph needs its own patch map)"
        )
    worst = int(np.argmax(spread))
    if not spread[worst] <= worst_patch_limit:
        raise UsageError(
            f"chart layout: patch {worst} is not uniform in the ambient image (within/between spread "
            f"{spread[worst]:.2f} > {worst_patch_limit}); expected every patch inside one chart patch "
            "(check --patch-px/--border-px/--margin-px)"
        )
    with np.errstate(invalid="ignore", divide="ignore"):
        z = np.abs(patch_means[:, None] - patch_means[None]) / np.hypot(standard_errors[:, None], standard_errors[None])
    z = np.where(np.isfinite(z), z, -np.inf).max(axis=2)  # the most distinct channel with ≥ 2 samples each
    np.fill_diagonal(z, np.inf)
    twins = int(np.sum((z < twin_z).any(axis=1)))
    if twins > layout.n_patches / 4:
        raise UsageError(
            f"chart layout: {twins} of {layout.n_patches} patches read the same colour as another patch "
            f"(< {twin_z:g} standard errors apart); expected {layout.n_patches} distinct chart patches — "
            "the layout samples parts of the chart several times (check --patch-px/--border-px)"
        )
    return ratio


# -- measures on images -----------------------------------------------------------------------
@dataclass(frozen=True)
class ColourContext:
    """What every measure needs besides the images."""

    layout: ChartLayout
    camera_to_xyz: np.ndarray
    reference: colour_metrics.ReferenceChart
    cfa: str | None


def colour_context(
    camera_photons: Spectra, grid: WavelengthGrid, layout: ChartLayout, cfa: str | None
) -> ColourContext:
    """Camera → XYZ fitted on the Macbeth chart under D65, and the ideal chart under D65 (Fig. 9)."""
    chart = datasets.macbeth().resample(grid, outside="edge")
    d65 = datasets.illuminant("D65", grid)
    matrix = camera_to_xyz_matrix(camera_photons, chart, d65.to_unit("photons"))
    return ColourContext(layout, matrix, colour_metrics.reference_chart(chart, d65), cfa)


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
    """PNG bytes and the float sRGB image of a linear image at the ΔE exposure normalisation ``scale``.

    Display white is the Y of a perfect white after normalisation, so previews of images with
    different exposures or flash power compare directly.
    """
    rgb = full_rgb(image, context.cfa) * scale
    srgb_linear, _ = camera_to_srgb_linear(rgb, context.camera_to_xyz, white_balance)
    encoded = encode_srgb(srgb_linear, float(context.reference.white_xyz[1]))
    plt = _pyplot()
    buffer = io.BytesIO()
    text = {"Software": "msflash", "Description": json.dumps(metadata or {}, default=str)}
    plt.imsave(buffer, np.round(encoded * 255).astype(np.uint8), format="png", metadata=text)
    return buffer.getvalue(), encoded


def _pyplot():  # noqa: ANN202 - matplotlib is imported lazily, with the non-interactive backend
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _figure_png(figure: Any) -> bytes:
    plt = _pyplot()
    buffer = io.BytesIO()
    figure.tight_layout()
    figure.savefig(buffer, format="png", dpi=100)
    plt.close(figure)
    return buffer.getvalue()


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
    write_image(
        out / f"{name}.exr",
        linear.astype(np.float32),
        {**attributes, "msflash:content": "linear camera RGB per µs·gain"},
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
def _solve_both(
    ambient_weights: np.ndarray, leds: Spectra, camera: Spectra, target: Spectra, bounds: FlashBounds
) -> tuple[dict[str, FlashSolution], list[str]]:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", TargetUnreachableWarning)
        solutions = {
            "matching": solve_matching(ambient_weights, leds, camera, bounds=bounds),
            "complementary": solve_complementary(ambient_weights, leds, camera, target, bounds=bounds),
        }
    return solutions, [str(w.message) for w in caught]


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
    camera = analysis.camera_responsivities_photons(sequence)
    leds = analysis.led_spectra_photons(sequence)
    stack = analysis.load_frame_stack(sequence)
    cfa = sequence.camera.cfa
    ambient, saturated = sequence.load_linear_frame(stack.ambient_index)
    # Find and check the layout before any processing, so a wrong --patch-px fails at once.
    found = sequence_layout(sequence, chart, patch_px, border_px, margin_px)
    check_layout(ambient, found.build(ambient.shape[:2], saturated), cfa)
    progress("estimating the ambient and solving the flashes")
    estimate = analysis.estimate_sequence(sequence, stack=stack)
    target_spd = analysis.target_illuminant(target, sequence)
    solutions, notes = _solve_both(estimate.ambient_weights, leds, camera, target_spd, bounds)

    images: dict[str, np.ndarray] = {"ambient": ambient}
    weights: dict[str, np.ndarray] = {}
    for mode, solution in solutions.items():
        image, synth_saturated = synthesize(stack.ambient, stack.led_frames, stack.spec, solution.flash_weights)
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
    context = colour_context(camera, sequence.grid, layout, cfa)
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
    spectra_png = _spectra_plot(sequence.grid, leds, estimate.spectrum, solutions, target_spd)
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


def _spectra_plot(
    grid: WavelengthGrid,
    leds: Spectra,
    estimate: Spectra,
    solutions: dict[str, FlashSolution],
    target: Spectra,
    truth: Spectra | None = None,
) -> bytes:
    plt = _pyplot()
    wavelengths = grid.wavelengths_nm
    ambient = estimate.values[:, 0]
    peak = float(np.max(np.abs(ambient))) or 1.0
    figure, axis = plt.subplots(figsize=(7, 3.6))
    axis.plot(wavelengths, ambient / peak, color="tab:blue", lw=2, label="ambient (estimate)")
    if truth is not None:
        true_values = truth.to_unit("photons").values[:, 0]
        axis.plot(
            wavelengths,
            true_values * float(ambient @ true_values) / float(true_values @ true_values) / peak,
            color="black",
            ls="--",
            label="ambient (truth)",
        )
    for mode, solution in solutions.items():
        axis.plot(wavelengths, leds.values @ solution.flash_weights / peak, lw=1.2, label=f"{mode} flash")
    total = leds.values @ (solutions["complementary"].ambient_weights + solutions["complementary"].flash_weights)
    axis.plot(wavelengths, total / peak, color="tab:purple", lw=2, label="ambient + complementary")
    target_values = target.values[:, 0]
    axis.plot(
        wavelengths,
        target_values * float(total @ target_values) / float(target_values @ target_values) / peak,
        color="gray",
        ls=":",
        label="target (scaled)",
    )
    axis.set_xlabel("wavelength (nm)")
    axis.set_ylabel("relative power (photons)")
    axis.legend(fontsize=7)
    return _figure_png(figure)


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
    report.add_images(list(result["_png"].items()), width_px=260)
    report.add_heading("Spectra")
    report.add_images([("ambient estimate and flash mixes", spectra_png)])
    report.add_heading("CIEDE2000 against the ideal chart under D65 (Fig. 9)")
    report.add_table(["image", "mean ΔE00", "max ΔE00"], _delta_e_rows(result["delta_e"]), table_id="delta-e")
    report.add_heading("Noise at equal exposure (Fig. 3), neutral patches")
    report.add_table(_NOISE_HEADERS, _noise_rows(result["noise"]), table_id="noise", digits=1)
    for note in result["warnings"]:
        report.add_paragraph(f"warning: {note}", note=True)
    report.write(path)


# -- the simulated colour study ---------------------------------------------------------------
def _capture(camera: Any, plan: Any) -> list[np.ndarray]:
    camera.prepare(plan)
    camera.start()
    frames = []
    try:
        for _ in plan.steps:
            camera.trigger()
            frames.append(camera.next_frame(5.0).pixels)
    finally:
        camera.stop()
    return frames


def simulated_world(
    ambient: str,
    seed: int = 0,
    patch_px: int = 12,
    cfa: str | None = None,
    depth_m: float = 5.0,
    distance_m: float = 1.0,
    water_type: str = "ocean",
    grid: WavelengthGrid = DEFAULT_GRID,
) -> Any:
    """The sim rig's camera on a Macbeth chart under a named ambient (underwater: :mod:`processing.water`)."""
    from msflash.acquisition.devices.simulated_camera import SimulatedCamera

    scene = chart_scene("macbeth", patch_px=patch_px, border_px=2)
    if ambient == "underwater":
        spd = water.underwater_ambient(depth_m, distance_m, water=water_type, grid=grid)
    else:
        spd = lights.ambient_spectrum(ambient, grid)
    world = SimulatedCamera.default(scene=scene, ambient=spd, cfa=cfa, seed=seed, grid=grid)
    if ambient == "underwater":
        path = water.flash_path_transmittance(distance_m, water_type, grid).values
        suggested = world.suggested_exposure_us
        world = SimulatedCamera(
            world.scene,
            world.ambient,
            world.led_spectra.replace(values=world.led_spectra.values * path),
            world.camera_responsivities,
            world.sensor,
            world.scale,
            seed=seed,
            name="SimulatedCamera (underwater)",
        )
        world.suggested_exposure_us = suggested
    return world


def study_ambient(
    name: str,
    seed: int = 0,
    patch_px: int = 12,
    cfa: str | None = None,
    bounds: FlashBounds = "physical",
    out: Path | None = None,
    **world_options: Any,
) -> dict[str, Any]:
    """One ambient of the study: capture, estimate, flash, synthesise/re-capture, ΔE and noise."""
    from msflash.acquisition.plan import CapturePlan

    world = simulated_world(name, seed, patch_px, cfa, **world_options)
    grid = world.ambient.grid
    exposure = float(world.suggested_exposure_us or 10_000.0)
    k = world.led_spectra.count
    frames = _capture(world, CapturePlan.ambient_then_each_led(k, exposure))
    black, white = world.sensor.black_level, world.sensor.white_level
    spec = FrameStackSpec(black, white, 1.0 / exposure, (1.0 / exposure,) * k, np.eye(k))
    statistics = accumulate_statistics(frames[0], frames[1:], spec, bin_factor=2, cfa_period=2 if cfa else 1)
    leds = world.led_spectra.to_unit("photons")
    camera = world.camera_responsivities.to_unit("photons")
    estimate = estimate_ambient(statistics, leds)
    target = datasets.illuminant("D65", grid).to_unit("photons")
    solutions, notes = _solve_both(estimate.ambient_weights, leds, camera, target, bounds)

    def linear(raw: np.ndarray) -> np.ndarray:
        return (raw.astype(np.float64) - black) / exposure

    images = {"ambient": linear(frames[0])}
    saturated = np.zeros(frames[0].shape[:2], dtype=bool)
    for mode, solution in solutions.items():
        image, synth_saturated = synthesize(frames[0], frames[1:], spec, solution.flash_weights)
        images[mode] = image.astype(np.float64)
        saturated |= synth_saturated
    # The complementary flash re-captured at the same exposure (physical drive levels): the Fig. 3 image.
    recapture_weights = np.clip(solutions["complementary"].flash_weights, 0.0, 1.0)
    recapture = _capture(world, CapturePlan.single(recapture_weights, exposure))[0]
    images["complementary-capture"] = linear(recapture)
    layout = chart_layout(frames[0].shape[:2], "macbeth", patch_px, 2, 2 if cfa else 1, excluded=saturated)
    context = colour_context(camera, grid, layout, cfa)
    gains = colour_metrics.von_kries_gains(
        camera.values.T @ estimate.spectrum.values[:, 0], camera.values.T @ target.values[:, 0]
    )
    weights = {
        "matching": solutions["matching"].flash_weights,
        "complementary": solutions["complementary"].flash_weights,
        "complementary-capture": recapture_weights,
    }
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        measured = _measure(out, images, context, gains, images["complementary-capture"], weights)
    else:
        measured = _measure_only(images, context, gains, images["complementary-capture"])
    truth = world.true_ambient
    measured.update(
        {
            "ambient": name,
            "ambient_source": truth.source,
            "exposure_us": exposure,
            "bounds": bounds,
            "ambient_weights": estimate.ambient_weights,
            "flash_weights": {mode: s.flash_weights for mode, s in solutions.items()},
            "complementary_target_reached": solutions["complementary"].target_reached,
            "warnings": notes,
            "_spectra_png": _spectra_plot(grid, leds, estimate.spectrum, solutions, target, truth)
            if out is not None
            else None,
        }
    )
    return measured


def _measure_only(
    images: dict[str, np.ndarray], context: ColourContext, gains: np.ndarray, flash_image: np.ndarray
) -> dict[str, Any]:
    """ΔE and noise without writing anything (tests, --json without --out)."""
    delta_e = {}
    for name, image, balance in [(n, i, None) for n, i in images.items()] + [
        ("ambient-von-kries", images["ambient"], gains)
    ]:
        result = delta_e_of(image, context, balance)
        delta_e[name] = {"mean": result.mean, "max": result.max, "per_patch": result.delta_e}
    noise = {
        "von_kries": noise_of(images["ambient"], context, gains),
        "complementary": noise_of(flash_image, context),
        "von_kries_gains": gains,
    }
    return {"delta_e": delta_e, "noise": noise, "_png": {}}


def delta_e_summary(results: dict[str, dict[str, Any]]) -> dict[str, dict[str, float]]:
    """Mean ΔE00 per ambient for ambient only / + matching / + complementary, and the relative cut."""
    summary = {}
    for name, result in results.items():
        ambient = result["delta_e"]["ambient"]["mean"]
        matching = result["delta_e"]["matching"]["mean"]
        complementary = result["delta_e"]["complementary"]["mean"]
        summary[name] = {
            "ambient": ambient,
            "matching": matching,
            "complementary": complementary,
            "complementary_capture": result["delta_e"]["complementary-capture"]["mean"],
            "ambient_von_kries": result["delta_e"]["ambient-von-kries"]["mean"],
            "complementary_cut": 1.0 - complementary / ambient,
            "matching_change": matching - ambient,
        }
    return summary


def _fig9_png(summary: dict[str, dict[str, float]]) -> bytes:
    plt = _pyplot()
    names = list(summary)
    positions = np.arange(len(names))
    figure, axis = plt.subplots(figsize=(7.5, 3.6))
    for offset, (key, label, colour) in zip(
        (-0.27, 0.0, 0.27),
        (
            ("ambient", "ambient only", "tab:gray"),
            ("matching", "+ matching flash", "tab:orange"),
            ("complementary", "+ complementary flash", "tab:blue"),
        ),
    ):
        axis.bar(positions + offset, [summary[n][key] for n in names], width=0.26, label=label, color=colour)
    axis.set_xticks(positions, names)
    axis.set_ylabel("mean CIEDE2000 vs chart under D65")
    axis.legend(fontsize=8)
    return _figure_png(figure)


def _snr_png(noise: dict[str, Any]) -> bytes:
    plt = _pyplot()
    figure, axis = plt.subplots(figsize=(5.5, 3.4))
    positions = np.arange(3)
    for offset, (key, label) in zip(
        (-0.2, 0.2), (("von_kries", "ambient + von Kries"), ("complementary", "complementary flash"))
    ):
        axis.bar(positions + offset, [noise[key]["mean_snr"][c] for c in CHANNELS], width=0.38, label=label)
    axis.set_xticks(positions, CHANNELS)
    axis.set_ylabel("SNR on neutral patches (mean/std)")
    axis.legend(fontsize=8)
    return _figure_png(figure)


def colour_study(
    out: Path | None,
    ambients: tuple[str, ...] = STUDY_AMBIENTS,
    seed: int = 0,
    patch_px: int = 12,
    cfa: str | None = None,
    bounds: FlashBounds = "physical",
    **world_options: Any,
) -> dict[str, Any]:
    """Fig. 9 (ΔE per ambient: ambient / + matching / + complementary) and Fig. 3 (noise under water)."""
    results = {}
    with counted("colour study", len(ambients), "ambient") as advance:
        for name in ambients:
            results[name] = study_ambient(
                name, seed, patch_px, cfa, bounds, out / name if out is not None else None, **world_options
            )
            advance(f"colour study: {name} done")
    summary = delta_e_summary(results)
    noise = {
        name: {
            "von_kries": result["noise"]["von_kries"]["mean_snr"],
            "complementary": result["noise"]["complementary"]["mean_snr"],
            "von_kries_chroma_noise": result["noise"]["von_kries"]["mean_chroma_noise"],
            "complementary_chroma_noise": result["noise"]["complementary"]["mean_chroma_noise"],
        }
        for name, result in results.items()
    }
    payload: dict[str, Any] = {
        "ambients": list(ambients),
        "seed": seed,
        "patch_px": patch_px,
        "cfa": cfa,
        "bounds": bounds,
        "world": {k: v for k, v in world_options.items()},
        "delta_e": summary,
        "noise": noise,
        "details": {name: public_result(result) for name, result in results.items()},
    }
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "colour-study.json").write_text(dumps_json(payload) + "\n")
        _study_report(out / "report.html", payload, results, summary)
        payload["report"] = str(out / "report.html")
    return payload


def public_result(result: dict[str, Any]) -> dict[str, Any]:
    return {key: value for key, value in result.items() if not key.startswith("_")}


def _study_report(
    path: Path, payload: dict[str, Any], results: dict[str, dict[str, Any]], summary: dict[str, dict[str, float]]
) -> None:
    report = HtmlReport("msflash colour study (simulation): Fig. 9 and Fig. 3")
    report.add_paragraph(
        f"Simulated Macbeth chart ({payload['patch_px']}-pixel patches, seed {payload['seed']}, CFA {payload['cfa']}), "
        f"the paper's 7 LEDs, flash bounds {payload['bounds']}. Rendering: camera → XYZ fitted on the Macbeth "
        "chart under D65, no white balance, each image scaled by one luminance factor; ΔE00 against the ideal "
        "chart under D65."
    )
    report.add_heading("Mean CIEDE2000 per ambient (Fig. 9)")
    report.add_images([("mean ΔE00", _fig9_png(summary))])
    report.add_table(
        [
            "ambient",
            "ambient only",
            "+ matching",
            "+ complementary",
            "complementary (re-captured)",
            "von Kries ambient",
            "complementary cut",
        ],
        [
            [
                name,
                s["ambient"],
                s["matching"],
                s["complementary"],
                s["complementary_capture"],
                s["ambient_von_kries"],
                f"{100 * s['complementary_cut']:.0f}%",
            ]
            for name, s in summary.items()
        ],
        table_id="delta-e",
    )
    for name, result in results.items():
        report.add_heading(f"{name}: {result['ambient_source']}", level=3)
        images = [
            (label, result["_png"][key])
            for key, label in (
                ("ambient", "ambient only"),
                ("matching", "+ matching"),
                ("complementary", "+ complementary"),
                ("ambient-von-kries", "ambient, von Kries"),
            )
            if key in result["_png"]
        ]
        report.add_images(images, width_px=220)
        if result.get("_spectra_png"):
            report.add_images([("spectra", result["_spectra_png"])])
        for note in result["warnings"]:
            report.add_paragraph(f"warning: {note}", note=True)
    report.add_heading("Noise at equal exposure (Fig. 3): von Kries-balanced ambient vs complementary flash")
    for name, result in results.items():
        report.add_heading(name, level=3)
        report.add_table(_NOISE_HEADERS, _noise_rows(result["noise"]), table_id=f"noise-{name}", digits=1)
    if "underwater" in results:
        report.add_images(
            [
                ("underwater: SNR per channel", _snr_png(results["underwater"]["noise"])),
                ("ambient, von Kries", results["underwater"]["_png"]["ambient-von-kries"]),
                ("complementary flash (re-captured)", results["underwater"]["_png"]["complementary-capture"]),
            ],
            width_px=None,
        )
    report.write(path)
