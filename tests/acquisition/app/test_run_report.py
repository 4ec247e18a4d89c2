"""What ``msflash run`` leaves for a person: full-size sRGB previews, one HTML report linked from run.json, and
plots that give the matching and complementary flashes the same colours and spectra the same unit everywhere."""

from __future__ import annotations

import json
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest
from matplotlib.colors import to_hex

from msflash.acquisition.app import evaluation, report
from msflash.acquisition.app.cli import main
from msflash.acquisition.app.plot_style import PALETTE, SPECTRAL_AXIS_LABEL, WAVELENGTH_AXIS_LABEL, pyplot
from msflash.acquisition.app.srgb_png import enlargement
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import analysis, sequence_spectra
from msflash.lab import colour_study
from tests.acquisition.support.png_files import png_chunks
from tests.acquisition.support.report_pages import disk_full_for, parse_report


def png_size(path: Path) -> tuple[int, int]:
    """(width, height) from the IHDR chunk."""
    return struct.unpack(">2I", png_chunks(path.read_bytes())["IHDR"][:8])


@pytest.fixture(scope="module", params=[None, "RGGB"], ids=["rgb", "bayer"])
def run_folder(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("run") / "demo"
    cfa = ["--cfa", request.param] if request.param else []
    assert main(["run", "--rig", "sim", "--ambient", "tungsten", "--out", str(out), *cfa]) == 0
    return out


def test_previews_are_full_resolution_srgb_and_at_least_1024_pixels(run_folder: Path) -> None:
    summary = json.loads((run_folder / "run.json").read_text())
    sequence = read_sequence(run_folder / "sequence")
    height, width = sequence.load_frame(0).shape[:2]
    if sequence.camera.cfa is not None:  # one RGB pixel per 2×2 CFA cell: only measured colours
        height, width = height // 2, width // 2
    factor = enlargement((height, width))
    assert set(summary["previews"]) == {"ambient", "matching", "complementary", "flash-capture"}
    for name, file in summary["previews"].items():
        path = Path(file)
        assert png_size(path) == (width * factor, height * factor), name
        assert max(png_size(path)) >= 1024
        assert png_chunks(path.read_bytes())["sRGB"] == b"\x00", name
    assert png_chunks((run_folder / "spectra.png").read_bytes())["sRGB"] == b"\x00"


def test_the_ambient_preview_is_exposed_for_the_chart_not_the_highlight(run_folder: Path) -> None:
    """The sim scene has a highlight strip below the chart (3.8 % of the pixels, 12× the chart's white): it
    used to set display white and left the chart at a median sRGB level near 20 of 255."""
    from PIL import Image

    pixels = np.asarray(Image.open(run_folder / "ambient.png")).astype(float)
    luma = pixels @ [0.2126, 0.7152, 0.0722]
    assert np.median(luma) > 70  # measured 83 (rgb) and 80 (bayer); 20 before
    clipped = np.mean(np.any(pixels >= 255, axis=2))
    assert clipped < 0.1  # the highlight strip (3.8 %) and little else (measured 7 % and 5 %)


def test_one_html_report_linked_from_run_json_points_at_files_of_the_run(run_folder: Path) -> None:
    summary = json.loads((run_folder / "run.json").read_text())
    page_path = Path(summary["report"])
    assert page_path == run_folder / "report.html" and page_path.is_file()
    assert not (run_folder / "report.md").exists()  # one report, HTML
    page = parse_report(page_path)
    shown = {(run_folder / src).resolve() for src in page.images}
    expected = {Path(p).resolve() for p in summary["previews"].values()} | {(run_folder / "spectra.png").resolve()}
    assert shown == expected
    for target in page.images + page.links:
        path = (run_folder / target).resolve()
        assert path.is_file() and path.is_relative_to(run_folder.resolve()), target
    assert {"run.json", "estimate.json", "sequence/sequence.json"} <= set(page.links)
    names = [led.name for led in read_sequence(run_folder / "sequence").leds]
    weights = page.tables["weights"]
    assert weights[0][1:] == names
    rows = {row[0]: row[1:] for row in weights[1:]}
    np.testing.assert_allclose(
        [float(v) for v in rows["ambient (estimate)"]], summary["ambient_weights"], rtol=5e-3
    )  # 3 digits
    for mode, flash in summary["flash"].items():
        np.testing.assert_allclose([float(v) for v in rows[f"{mode} flash"]], flash["flash_weights"], rtol=5e-3)
    accuracy = dict(row for row in page.tables["accuracy"][1:])
    assert (
        accuracy["spectrum RMSE against the true ambient (Table 1 metric)"]
        == f"{summary['spectrum_rmse_vs_truth']:.4f}"
    )
    assert [row[0] for row in page.tables["exposure"][1:]] == names


def legend_colours(figure: object) -> dict[str, str]:
    """Each legend entry's colour, by label, over every axis of the figure."""
    colours = {}
    for axis in figure.axes:  # type: ignore[attr-defined]
        for handle, label in zip(*axis.get_legend_handles_labels(), strict=True):
            if hasattr(handle, "get_color"):
                colour = handle.get_color()
            elif hasattr(handle, "patches"):
                colour = handle.patches[0].get_facecolor()
            else:
                colour = handle.get_facecolor()[0]
            colours[label] = to_hex(colour, keep_alpha=False)
    return colours


def test_every_plot_gives_each_flash_and_the_ambient_its_palette_colour(run_folder: Path) -> None:
    """The run's spectra, evaluate's spectra and the Fig. 9 chart draw matching, complementary and the ambient
    in PALETTE's colours (they used to swap: matplotlib's cycle order followed the solutions' order), and label
    spectra in the one unit."""
    sequence = read_sequence(run_folder / "sequence")
    estimate = analysis.estimate_sequence(sequence)
    solutions = {
        mode: analysis.solve_sequence_flash(sequence, mode, estimate.ambient_weights)
        for mode in ("complementary", "matching")  # the run's order, opposite to evaluate's
    }
    target = sequence_spectra.target_illuminant("D65", sequence)
    figures = {
        "run spectra": report.spectra_figure(sequence, estimate, solutions, None, target),
        "evaluate spectra": evaluation.spectra_figure(
            sequence.grid, sequence_spectra.led_spectra_photons(sequence), estimate.spectrum, solutions, target
        ),
        "fig9": colour_study.fig9_figure({"tungsten": {"ambient": 18.0, "matching": 18.2, "complementary": 4.0}}),
    }
    plt = pyplot()
    try:
        for name, figure in figures.items():
            colours = legend_colours(figure)
            matching = [label for label in colours if "matching" in label]
            complementary = [label for label in colours if "complementary flash" in label and "ambient +" not in label]
            ambient = [label for label in colours if "estimate" in label.split("(")[-1] or label == "ambient only"]
            assert matching and complementary and ambient, (name, colours)
            assert {colours[label] for label in matching} == {PALETTE.matching.lower()}, name
            assert {colours[label] for label in complementary} == {PALETTE.complementary.lower()}, name
            assert {colours[label] for label in ambient} == {PALETTE.ambient.lower()}, name
            if "spectra" in name:
                for axis in figure.axes:
                    assert axis.get_xlabel() == WAVELENGTH_AXIS_LABEL
                    assert axis.get_ylabel().startswith(SPECTRAL_AXIS_LABEL)
    finally:
        for figure in figures.values():
            plt.close(figure)


def test_the_report_renders_in_headless_chromium_with_every_image_loaded(
    run_folder: Path, tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    """The real browser: every <img> decoded (naturalWidth > 0), the page screenshot is not blank."""
    if "bayer" in request.node.callspec.id:
        pytest.skip("one browser run is enough: the rgb run's report")
    chromium, driver_path = shutil.which("chromium") or "/usr/bin/chromium", shutil.which("chromedriver")
    if not Path(chromium).exists() or driver_path is None:
        pytest.skip("chromium and chromedriver are not installed (setup.sh installs them)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = chromium
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu", "--window-size=1280,2400"):
        options.add_argument(argument)
    driver = webdriver.Chrome(service=Service(executable_path=driver_path), options=options)
    try:
        driver.get((run_folder / "report.html").resolve().as_uri())
        state = driver.execute_script(
            "return {ready: document.readyState, images: Array.from(document.images).map("
            "i => ({src: i.getAttribute('src'), complete: i.complete, width: i.naturalWidth, shown: i.width}))};"
        )
        shot = tmp_path / "report.png"
        driver.save_screenshot(str(shot))
    finally:
        driver.quit()
    assert state["ready"] == "complete"
    assert len(state["images"]) == 5
    for image in state["images"]:
        assert image["complete"] and image["width"] >= 1024 and image["shown"] > 300, image
    from PIL import Image

    pixels = np.asarray(Image.open(shot).convert("RGB")).astype(float)
    assert pixels.shape[1] == 1280 and pixels.std() > 20  # the page drew text and pictures, not a blank


def test_a_report_that_cannot_be_written_is_one_line_and_run_json_stays(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Disk full when the HTML is written (injected, as test_run_outputs does for run.json)."""
    # written beside, then renamed
    disk_full_for(monkeypatch, lambda path: path.name == "report.html" or path.name.startswith(".report.html."))
    out = tmp_path / "run"
    assert main(["run", "--rig", "sim", "--out", str(out)]) == 1
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"msflash: error: {out / 'report.html'}: could not be written ([Errno 28] No space left")
    assert f"The sequence is complete in {out / 'sequence'} and run.json beside it" in last
    assert json.loads((out / "run.json").read_text())["report"] == str(out / "report.html")
    assert read_sequence(out / "sequence").complete


def test_the_run_and_evaluate_draw_the_same_flash_mix_curves(run_folder: Path) -> None:
    """Both figures draw the flash mixes through plot_style.draw_flash_mixes: the same labels in the same order
    and the same curves (the run's right panel; evaluate's one axis, beside its truth)."""
    sequence = read_sequence(run_folder / "sequence")
    estimate = analysis.estimate_sequence(sequence)
    solutions = {
        mode: analysis.solve_sequence_flash(sequence, mode, estimate.ambient_weights)
        for mode in ("complementary", "matching")
    }
    target = sequence_spectra.target_illuminant("D65", sequence)
    truth = sequence_spectra.target_illuminant("A", sequence)
    run = report.spectra_figure(sequence, estimate, solutions, truth, target)
    evaluated = evaluation.spectra_figure(
        sequence.grid, sequence_spectra.led_spectra_photons(sequence), estimate.spectrum, solutions, target, truth
    )
    plt = pyplot()
    try:
        drawn = [
            {line.get_label(): line.get_ydata() for line in axis.get_lines()}
            for axis in (run.axes[1], evaluated.axes[0])
        ]
    finally:
        plt.close(run)
        plt.close(evaluated)
    assert list(drawn[1]) == ["true ambient (scaled)", *drawn[0]]
    assert list(drawn[0]) == [
        "ambient (estimate)",
        "matching flash",
        "complementary flash",
        "ambient + complementary flash",
        "target (scaled to ambient + complementary)",
    ]
    for label, values in drawn[0].items():
        # evaluate is given the LED spectra in photons, the run its sequence's energy: a round trip's rounding
        np.testing.assert_allclose(drawn[1][label], values, rtol=1e-12, err_msg=label)
