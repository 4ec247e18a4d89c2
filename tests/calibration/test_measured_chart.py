"""A chart as the lab has it, end to end through the CLI (issue 29 item 5).

- ``msflash calibrate chart PATCH_EXPORTS… --white FILE``: each patch of the paper authors' Macbeth
  chart measured over a white reference under a tungsten lamp with a CCD spectrometer
  (``spectrometer_writers.py``: its own response, an offset and a dark current, shot and read noise,
  averaging), the white at 5 ms and the dark patches longer, a dark per integration time; the
  stored ``chart.csv`` against the chart's data, its noise estimate, and ``calibrate camera``
  taking it when ``--chart`` is not given.
- ``--chart-grid RxC``: the same 24 patches printed on a 3 × 8 card.
- A user's chart file listing the patches row by row (the transposed order is detected).
- ``calibrate camera --simulate`` under the LEDs measured into the calibration (``lights_source``).

The sequences come from the independent render of ``tests/harness/chart_render.py`` (the authors'
chart and LEDs, the held-out Aptina MT9M031 left out of the prior, a 12 % lens falloff). Every
refusal is one line and exit 2.
"""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app import cli
from msflash.calibration.files import load_calibration
from msflash.processing import datasets
from tests.calibration.spectrometer_writers import Instrument, encoded, export_text
from tests.harness import chart_render

CAMERA = "AptinaMT9M031"
WHITE_S = 0.005
WHITE_REFLECTANCE = 0.99
GRID_NM = np.arange(400.0, 701.0, 10.0)


def run(argv: list[str]) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = cli.main([str(a) for a in argv])
    return status, out.getvalue(), err.getvalue()


def refused(argv: list[str]) -> str:
    """The refusal: exit 2, nothing on stdout, the error one line (the last; progress notes may precede it)."""
    status, out, err = run(argv)
    assert (status, out) == (2, ""), err
    lines = err.splitlines()
    assert lines and lines[-1].startswith("msflash: error: ") and err.count("msflash: error: ") == 1, err
    assert "Traceback" not in err
    return lines[-1]


def _authors_chart(wavelengths: np.ndarray) -> np.ndarray:
    w, _, values = chart_render._table(chart_render.AUTHORS_CHART)
    return np.column_stack([np.interp(wavelengths, w, values[:, k]) for k in range(values.shape[1])])


def _tungsten(wavelengths: np.ndarray) -> np.ndarray:
    metres = wavelengths * 1e-9
    lamp = 1.0 / (metres**5 * (np.exp(1.435e-2 / (metres * 2856.0)) - 1.0))
    return lamp / lamp.max()


def write_chart_exports(
    folder: Path, averages: int, *, per_patch_time: bool = True, form: str = "oceanview", seed: int = 3
) -> tuple[list[str], str, list[str]]:
    """Exports of the 24 patches, the white and the darks: (patch files, white file, dark files).

    The lamp puts the white's peak at 40 000 counts in 5 ms; with ``per_patch_time`` each patch is
    measured near that peak (a dark patch up to 100 ms) with a dark at each time used, otherwise
    everything at 20 ms (the lamp dimmed to fit) with one dark.
    """
    folder.mkdir(parents=True, exist_ok=True)
    instrument = Instrument.typical(seed)
    rng = np.random.default_rng(seed + 100)
    reflectance = _authors_chart(instrument.wavelengths_nm)
    white_s = WHITE_S if per_patch_time else 0.020
    scale = 40000.0 / (4000.0 * 1.25 * white_s)
    lamp = _tungsten(instrument.wavelengths_nm) * scale

    def write(name: str, irradiance: np.ndarray | None, time_s: float) -> str:
        counts = instrument.counts(irradiance, time_s, averages, rng)
        path = folder / f"{name}.txt"
        text = export_text(form, instrument.wavelengths_nm, counts, time_s, averages, name=name)
        path.write_bytes(encoded(text))
        return str(path)

    times = []
    for k in range(reflectance.shape[1]):
        time_s = min(WHITE_S / max(float(reflectance[:, k].max()), 1e-3), 0.1) if per_patch_time else 0.020
        times.append(round(time_s, 3))
    patches = [write(f"patch{k + 1:02d}", lamp * reflectance[:, k], t) for k, t in enumerate(times)]
    white = write("white", lamp * WHITE_REFLECTANCE, white_s)
    darks = [write(f"dark-{round(1e3 * t)}ms", None, t) for t in sorted(set(times) | {white_s})]
    return patches, white, darks


def white_reflectance_file(folder: Path) -> str:
    path = folder / "spectralon.csv"
    path.write_text("wavelength_nm,reflectance\n" + "".join(f"{w},{WHITE_REFLECTANCE}\n" for w in range(300, 1101, 10)))
    return str(path)


def dark_options(darks: list[str]) -> list[str]:
    return [option for dark in darks for option in ("--dark", dark)]


@pytest.fixture(scope="module")
def sequences(tmp_path_factory) -> dict[str, list[str]]:
    """Chart sequences (tungsten, D65) of the authors' chart: the Macbeth card (4 × 6) and a 3 × 8 print."""
    folder = tmp_path_factory.mktemp("measured-chart-sequences")
    curves = chart_render.camera(CAMERA)
    scenes = {
        "4x6": chart_render.Scene(falloff=0.12),
        "3x8": chart_render.Scene(shape=(220, 460), origin_yx=(32, 22), falloff=0.12, rows=3, columns=8),
    }
    out: dict[str, list[str]] = {}
    for layout, scene in scenes.items():
        out[layout] = []
        for offset, (light, name) in enumerate(((chart_render.tungsten(), "A"), (chart_render.daylight(), "D65"))):
            path = folder / f"{layout}-{name}"
            chart_render.render_sequence(path, curves, light, name, scene, 40 + offset, CAMERA)
            out[layout].append(str(path))
    return out


def camera_argv(sequences: list[str], out: Path, *extra: str) -> list[str]:
    return [
        "calibrate",
        "camera",
        "--sequence",
        *sequences,
        "--light",
        "A",
        "--light",
        "D65",
        "--prior-exclude",
        CAMERA,
        *extra,
        "--out",
        str(out),
        "--json",
    ]


def fitted_rmse(calibration: Path) -> float:
    return chart_render.truth_rmse(calibration, chart_render.camera(CAMERA))


@pytest.fixture(scope="module")
def measured(tmp_path_factory) -> Path:
    """A calibration holding the chart measured with care (256 scans averaged, a dark per time)."""
    folder = tmp_path_factory.mktemp("measured-chart")
    patches, white, darks = write_chart_exports(folder / "exports", 256)
    out = folder / "cal"
    status, _, err = run(
        [
            "calibrate",
            "chart",
            *patches,
            "--white",
            white,
            *dark_options(darks),
            "--white-reflectance",
            white_reflectance_file(folder),
            "--out",
            out,
        ]
    )
    assert status == 0, err
    assert "warning" not in err, err
    return out


def test_calibrate_chart_stores_the_charts_reflectances(measured: Path) -> None:
    calibration = load_calibration(measured)
    chart = calibration.chart_reflectances
    assert (
        chart is not None and chart.count == 24 and (calibration.chart["rows"], calibration.chart["columns"]) == (4, 6)
    )
    truth = _authors_chart(chart.wavelengths_nm)
    error = chart.values - truth
    assert np.max(np.abs(error)) < 0.01  # reflectance units, 400–700 nm
    assert np.median(np.abs(error / truth)) < 0.003
    # the darks: each export took the one of its own time (nothing scaled), the white at 5 ms
    baselines = calibration.chart["baselines"]
    assert all(b["method"] == "dark export" for b in baselines), baselines[:2]
    noise = calibration.chart["noise"]
    assert 0 < noise["relative_rms"] < 0.005
    # the estimate is the measured scatter (the true error's RMS, within a third)
    assert noise["relative_rms"] == pytest.approx(float(np.sqrt(np.mean((error / truth) ** 2))), rel=0.35)


def test_calibrate_camera_takes_the_measured_chart(measured: Path, sequences, tmp_path) -> None:
    """No ``--chart``: the calibration's measured chart (the shipped ISETCam data is refused on this card)."""
    out = tmp_path / "cal"
    (out).mkdir()
    for name in ("calibration.json", "chart.csv"):
        (out / name).write_bytes((measured / name).read_bytes())
    status, stdout, err = run(camera_argv(sequences["4x6"], out))
    assert status == 0, err
    assert "chart reflectances from calibration" in err
    assert json.loads(stdout)["chart"].startswith("calibration ")
    assert fitted_rmse(out) <= 0.04


def test_a_noisy_chart_measurement_is_warned_about(tmp_path) -> None:
    patches, white, darks = write_chart_exports(tmp_path / "exports", 8, per_patch_time=False)
    status, _, err = run(
        ["calibrate", "chart", *patches, "--white", white, *dark_options(darks), "--out", tmp_path / "c"]
    )
    assert status == 0, err
    warning = [line for line in err.splitlines() if "warning: the measured reflectances carry" in line]
    assert len(warning) == 1 and "average more scans" in warning[0] and "patch24" in warning[0], err
    assert load_calibration(tmp_path / "c").chart["noise"]["relative_rms"] > 0.005


def test_calibrate_chart_refusals_are_one_line(tmp_path) -> None:
    patches, white, darks = write_chart_exports(tmp_path / "exports", 4)
    out = str(tmp_path / "cal")
    short_dark = [d for d in darks if d.endswith("-5ms.txt")]
    # one dark for every time: the lamp's exports have no out-of-band tail to scale it on
    err = refused(["calibrate", "chart", *patches, "--white", white, "--dark", darks[-1], "--out", out])
    assert "has no out-of-band tail to measure the dark's fixed offset on" in err and "expected a dark at" in err
    # no dark at all, raw counts without a tail
    err = refused(["calibrate", "chart", *patches, "--white", white, "--out", out])
    assert "raw counts, no dark given and no out-of-band tail" in err
    # two darks of one time
    twin = Path(tmp_path / "exports" / "dark-copy.txt")
    twin.write_bytes(Path(short_dark[0]).read_bytes())
    err = refused(["calibrate", "chart", *patches, "--white", white, *dark_options([*darks, str(twin)]), "--out", out])
    assert "are both 5 ms; expected one dark per integration time" in err
    # a patch given as the white: the white patch reflects more than "the white"
    err = refused(["calibrate", "chart", *patches, "--white", patches[23], *dark_options(darks), "--out", out])
    assert "× the white" in err and "expected a chart patch darker than the white reference" in err
    # a white lit by an LED, not a lamp: no light where the chart must be measured
    instrument = Instrument.typical(3)
    led = np.exp(-0.5 * ((instrument.wavelengths_nm - 630.0) / 10.0) ** 2) * 1600.0
    counts = instrument.counts(led, WHITE_S, 4, np.random.default_rng(1))
    narrow = tmp_path / "white-led.txt"
    narrow.write_bytes(encoded(export_text("oceanview", instrument.wavelengths_nm, counts, WHITE_S, 4)))
    err = refused(["calibrate", "chart", *patches, "--white", narrow, *dark_options(darks), "--out", out])
    assert "reads below 2 % of its peak" in err and "expected a white reference lit over" in err
    # a grid that does not hold the patches
    err = refused(
        ["calibrate", "chart", *patches, "--white", white, *dark_options(darks), "--chart-grid", "5x5", "--out", out]
    )
    assert "--chart-grid 5x5: 25 patches" in err
    err = refused(
        ["calibrate", "chart", *patches, "--white", white, *dark_options(darks), "--chart-grid", "4by6", "--out", out]
    )
    assert "--chart-grid '4by6': expected ROWSxCOLUMNS" in err
    # the white states no integration time, the patches do: their counts per second are not comparable
    plain = tmp_path / "white-plain.txt"
    rows = [line for line in Path(white).read_text().splitlines() if line[:1].isdigit()]
    plain.write_text("wavelength_nm,counts\n" + "\n".join(r.replace("\t", ",") for r in rows) + "\n")
    err = refused(["calibrate", "chart", *patches, "--white", plain, "--unit", "counts", "--no-dark", "--out", out])
    assert "white-plain.txt: states no integration time but" in err
    assert not (tmp_path / "cal").exists()  # nothing written by a refusal


def test_chart_grid_of_a_card_printed_3_by_8(measured: Path, sequences, tmp_path) -> None:
    """The same 24 patches on a 3 × 8 card: the default 4 × 6 is not found; ``--chart-grid 3x8`` is; a chart
    measured with ``calibrate chart --chart-grid 3x8`` keeps its grid for ``calibrate camera``."""
    chart = str(chart_render.AUTHORS_CHART)
    err = refused(camera_argv(sequences["3x8"], tmp_path / "none", "--chart", chart))
    assert "--patch-px/--border-px" in err  # the refusal names the layout options
    err = refused(camera_argv(sequences["3x8"], tmp_path / "none", "--chart", chart, "--chart-grid", "3x9"))
    assert "--chart-grid 3x9: 27 patches" in err
    status, stdout, err = run(
        camera_argv(sequences["3x8"], tmp_path / "given", "--chart", chart, "--chart-grid", "3x8")
    )
    assert status == 0, err
    layout = json.loads(stdout)["layouts"][0]
    assert layout["detected"] and sorted((layout["rows"], layout["columns"])) == [3, 8]
    assert fitted_rmse(tmp_path / "given") <= 0.04
    # measured as a 3 × 8 chart: calibrate camera needs no --chart-grid
    patches, white, darks = write_chart_exports(tmp_path / "exports", 256, seed=4)
    out = tmp_path / "measured"
    status, _, err = run(
        ["calibrate", "chart", *patches, "--white", white, *dark_options(darks), "--chart-grid", "3x8", "--out", out]
    )
    assert status == 0, err
    status, _, err = run(camera_argv(sequences["3x8"], out))
    assert status == 0, err
    assert "3x8 grid" in err
    assert fitted_rmse(out) <= 0.04


def test_a_chart_file_listing_the_patches_row_by_row_is_found_transposed(sequences, tmp_path) -> None:
    """A vendor's file in reading order (row 1 left to right, then row 2 …), not the Macbeth file's column order."""
    values = _authors_chart(GRID_NM)
    order = [c * 4 + r for r in range(4) for c in range(6)]  # row by row of the 4 × 6 card
    path = tmp_path / "vendor-rows.csv"
    header = "wavelength_nm," + ",".join(f"row{k // 6 + 1}col{k % 6 + 1}" for k in range(24))
    lines = [f"{w:g}," + ",".join(f"{values[i, p]:.6f}" for p in order) for i, w in enumerate(GRID_NM)]
    path.write_text(header + "\n" + "\n".join(lines) + "\n")
    status, stdout, err = run(camera_argv(sequences["4x6"], tmp_path / "rows", "--chart", path))
    assert status == 0, err
    layout = json.loads(stdout)["layouts"][0]
    assert (layout["rows"], layout["columns"]) == (6, 4)  # the file's grid, found transposed on the card
    assert fitted_rmse(tmp_path / "rows") <= 0.04
    # the same patches in no chart order at all: refused, one line
    shuffled = np.random.default_rng(0).permutation(24)
    path.write_text(
        header
        + "\n"
        + "\n".join(f"{w:g}," + ",".join(f"{values[i, p]:.6f}" for p in shuffled) for i, w in enumerate(GRID_NM))
        + "\n"
    )
    refused(camera_argv(sequences["4x6"], tmp_path / "shuffled", "--chart", path))


def _measured_leds(folder: Path) -> Path:
    """``calibrate leds`` from three LED exports (a dark, the instrument's response): energy, true ratios."""
    folder.mkdir(parents=True, exist_ok=True)
    instrument = Instrument.typical(1)
    rng = np.random.default_rng(2)
    leds = datasets.paper_leds()
    files = []
    # The paper's 1st, 4th and 7th LEDs (440, 520, 660 nm), named by the user's export files.
    for index, name, scale in ((0, "led440", 1.0), (3, "led520", 0.6), (6, "led660", 0.8)):
        column = leds.values[:, index]
        irradiance = np.interp(instrument.wavelengths_nm, leds.wavelengths_nm, column / column.max(), left=0, right=0)
        counts = instrument.counts(irradiance * 1500.0 * scale, 0.01, 8, rng)
        files.append(folder / f"{name}.txt")
        files[-1].write_bytes(encoded(export_text("oceanview", instrument.wavelengths_nm, counts, 0.01, 8, name=name)))
    dark = folder / "dark.txt"
    dark.write_bytes(
        encoded(export_text("oceanview", instrument.wavelengths_nm, instrument.counts(None, 0.01, 8, rng), 0.01, 8))
    )
    response = folder / "response.csv"
    response.write_text(
        "wavelength_nm,counts_per_s_per_unit\n"
        + "".join(f"{w:.4f},{r:.6g}\n" for w, r in zip(instrument.wavelengths_nm, instrument.response, strict=True))
    )
    out = folder / "cal"
    status, _, err = run(
        ["calibrate", "leds", *files, "--dark", dark, "--spectrometer-response", response, "--out", out]
    )
    assert status == 0, err
    return out


def test_simulate_renders_under_the_calibrations_measured_leds(tmp_path) -> None:
    with_leds = _measured_leds(tmp_path / "booth")
    status, stdout, err = run(["calibrate", "camera", "--simulate", "--out", with_leds, "--json"])
    assert status == 0, err
    camera = load_calibration(with_leds).camera
    assert camera["lights"][:3] == ["led440", "led520", "led660"] and len(camera["lights"]) == 5
    assert camera["lights_source"].startswith("calibration ") and "leds.csv" in camera["lights_source"]
    assert "simulating macbeth under 5 lights" in err and "LEDs from calibration" in err
    assert json.loads(stdout)["rmse_vs_truth"] == camera["rmse_vs_truth"]
    # a calibration without LEDs: the paper's 7
    status, _, err = run(["calibrate", "camera", "--simulate", "--out", tmp_path / "plain", "--json"])
    assert status == 0, err
    camera = load_calibration(tmp_path / "plain").camera
    assert len(camera["lights"]) == 9 and "ximeaLights" in camera["lights_source"]
    assert "the paper's LEDs" in err


def test_simulate_refusals_are_one_line(tmp_path) -> None:
    out = tmp_path / "cal"
    assert "not one of the 34 paper cameras" in refused(
        ["calibrate", "camera", "--simulate", "--camera", "Foo", "--out", out]
    )
    assert "exclude each other" in refused(["calibrate", "camera", "--simulate", "--sequence", tmp_path, "--out", out])
    assert "unknown; expected macbeth or a CSV file" in refused(
        ["calibrate", "camera", "--simulate", "--chart", "colorchecker", "--out", out]
    )
    missing = tmp_path / "nope.csv"
    assert "nope.csv" in refused(["calibrate", "camera", "--simulate", "--chart", missing, "--out", out])
    percent = tmp_path / "percent.csv"
    percent.write_text(
        "wavelength_nm," + ",".join(f"p{k}" for k in range(6)) + "\n400,5,10,20,40,60,90\n700,5,10,20,40,60,90\n"
    )
    assert "expected reflectance factors 0–1" in refused(
        ["calibrate", "camera", "--simulate", "--chart", percent, "--out", out]
    )
    assert not out.exists()
