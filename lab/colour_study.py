"""The simulated colour study (``msflash colour-study``): Fig. 9 and Fig. 3 of the paper on simulated captures.

The measures of ``msflash evaluate`` (:mod:`msflash.acquisition.app.evaluation`: camera → XYZ fitted on a
Macbeth chart under D65, no white balance, CIEDE2000 patch by patch against the ideal chart under D65;
per-channel SNR and chroma noise of a von Kries-balanced ambient image against the complementary image)
on captures of :class:`~msflash.acquisition.devices.simulated_camera.SimulatedCamera` (in process, no booth)
for the tungsten, fluorescent, green, orange and underwater ambients — the Fig. 9 chart — and the
Fig. 3 noise comparison under water.

Underwater world
----------------
The ambient is :func:`processing.water.underwater_ambient` (D65 at ``--depth-m`` in
``--water``, seen over ``--distance-m``). The same subject → camera path, and the camera →
subject path of the flash, attenuate the LEDs: the world's LEDs are the in-air LEDs ×
:func:`processing.water.flash_path_transmittance`, and the sequence records these (a flash
calibrated in situ; an in-air calibration would give the solvers the wrong red).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from msflash.acquisition.app.cli_common import dumps_json
from msflash.acquisition.app.evaluation import (
    _NOISE_HEADERS,
    CHANNELS,
    ColourContext,
    _measure,
    _noise_rows,
    _solve_both,
    colour_context,
    delta_e_of,
    noise_of,
    public_result,
    spectra_figure,
)
from msflash.acquisition.app.html_report import HtmlReport
from msflash.acquisition.app.plot_style import PALETTE, figure_png, pyplot
from msflash.acquisition.progress import counted
from msflash.acquisition.session.chart_layout import chart_layout
from msflash.processing import colour_metrics, datasets, lights, water
from msflash.processing.accumulate import accumulate_statistics
from msflash.processing.ambient import estimate_ambient
from msflash.processing.flash import FlashBounds
from msflash.processing.scenes import chart_scene
from msflash.processing.spectra import DEFAULT_GRID, WavelengthGrid
from msflash.processing.statistics import FrameStackSpec
from msflash.processing.synthesis import synthesize

STUDY_AMBIENTS = ("tungsten", "fluorescent", "green", "orange", "underwater")


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
    context = colour_context(camera, grid, layout, cfa, world.led_spectra.names)
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
            "_spectra_png": figure_png(spectra_figure(grid, leds, estimate.spectrum, solutions, target, truth))
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
    return figure_png(fig9_figure(summary))


def fig9_figure(summary: dict[str, dict[str, float]]) -> Any:
    """Fig. 9: mean ΔE00 per ambient for the ambient-only, + matching and + complementary images."""
    plt = pyplot()
    names = list(summary)
    positions = np.arange(len(names))
    figure, axis = plt.subplots(figsize=(8, 4.2))
    for offset, (key, label) in zip(
        (-0.27, 0.0, 0.27),
        (("ambient", "ambient only"), ("matching", "+ matching flash"), ("complementary", "+ complementary flash")),
        strict=True,
    ):
        axis.bar(positions + offset, [summary[n][key] for n in names], width=0.26, label=label, color=PALETTE.of(key))
    axis.set_xticks(positions, names)
    axis.grid(False, axis="x")
    axis.set_ylabel("mean CIEDE2000 vs the chart under D65")
    axis.set_title("Fig. 9: colour error per ambient (simulation)")
    axis.legend()
    figure.tight_layout()
    return figure


def _snr_png(noise: dict[str, Any]) -> bytes:
    """Fig. 3: SNR per channel of the von Kries-balanced ambient and the complementary flash image."""
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(6, 4))
    positions = np.arange(3)
    for offset, (key, label, colour) in zip(
        (-0.2, 0.2),
        (
            ("von_kries", "ambient, von Kries balanced", PALETTE.ambient),
            ("complementary", "complementary flash", PALETTE.complementary),
        ),
        strict=True,
    ):
        axis.bar(
            positions + offset, [noise[key]["mean_snr"][c] for c in CHANNELS], width=0.38, label=label, color=colour
        )
    axis.set_xticks(positions, CHANNELS)
    axis.grid(False, axis="x")
    axis.set_xlabel("camera channel")
    axis.set_ylabel("SNR on neutral patches (mean / std)")
    axis.legend()
    figure.tight_layout()
    return figure_png(figure)


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
        figures = _study_figures(out, results, summary)
        payload["figures"] = {name: str(out / name) for name in figures}
        payload["report"] = str(out / "report.html")
        (out / "colour-study.json").write_text(dumps_json(payload) + "\n")
        _study_report(out / "report.html", payload, results, summary, figures)
    return payload


def _study_figures(
    out: Path, results: dict[str, dict[str, Any]], summary: dict[str, dict[str, float]]
) -> dict[str, bytes]:
    """The study's figures as PNG files beside its report (``fig9.png``, ``fig3-snr.png``, each ambient's
    ``spectra.png``), by path relative to ``out``; the report embeds the same bytes."""
    figures = {"fig9.png": _fig9_png(summary)}
    if "underwater" in results:
        figures["fig3-snr.png"] = _snr_png(results["underwater"]["noise"])
    for name, result in results.items():
        if result.get("_spectra_png"):
            figures[f"{name}/spectra.png"] = result["_spectra_png"]
    for relative, data in figures.items():
        (out / relative).write_bytes(data)
    return figures


def _study_report(
    path: Path,
    payload: dict[str, Any],
    results: dict[str, dict[str, Any]],
    summary: dict[str, dict[str, float]],
    figures: dict[str, bytes],
) -> None:
    report = HtmlReport("msflash colour study (simulation): Fig. 9 and Fig. 3")
    report.add_paragraph(
        f"Simulated Macbeth chart ({payload['patch_px']}-pixel patches, seed {payload['seed']}, CFA {payload['cfa']}), "
        f"the paper's 7 LEDs, flash bounds {payload['bounds']}. Rendering: camera → XYZ fitted on the Macbeth "
        "chart under D65, no white balance, each image scaled by one luminance factor; ΔE00 against the ideal "
        "chart under D65."
    )
    report.add_heading("Mean CIEDE2000 per ambient (Fig. 9)")
    report.add_images([("mean ΔE00 (fig9.png)", figures["fig9.png"])], plot=True)
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
        report.add_images(images, columns=4)
        if f"{name}/spectra.png" in figures:
            report.add_images([(f"spectra ({name}/spectra.png)", figures[f"{name}/spectra.png"])], plot=True)
        for note in result["warnings"]:
            report.add_paragraph(f"warning: {note}", warning=True)
    report.add_heading("Noise at equal exposure (Fig. 3): von Kries-balanced ambient vs complementary flash")
    for name, result in results.items():
        report.add_heading(name, level=3)
        report.add_table(_NOISE_HEADERS, _noise_rows(result["noise"]), table_id=f"noise-{name}", digits=1)
    if "fig3-snr.png" in figures:
        report.add_images([("underwater: SNR per channel (fig3-snr.png)", figures["fig3-snr.png"])], plot=True)
        report.add_images(
            [
                ("underwater: ambient, von Kries", results["underwater"]["_png"]["ambient-von-kries"]),
                (
                    "underwater: complementary flash (re-captured)",
                    results["underwater"]["_png"]["complementary-capture"],
                ),
            ],
            columns=2,
        )
    report.write(path)
