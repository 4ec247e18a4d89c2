"""The configurable sim rig: other cameras, LED sets, lights and surfaces, by name or CSV file.

Real parts throughout: ``msflash run``/``capture`` on the sim rig (SimulatedCamera + the booth
emulator on a pty + the LedBooth driver), the files written to a temporary directory.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.devices import simulated_camera
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.rig import open_sim_rig
from msflash.lab.study.local import led_bound
from msflash.processing import datasets, lights
from msflash.processing.metrics import spectrum_rmse
from msflash.processing.spectra import DEFAULT_GRID

GAUSSIAN_PEAKS_NM = (410, 450, 490, 530, 570, 610, 650, 690)
"""An 8-channel booth of Gaussian LEDs (σ 18 nm) spanning the grid: its best non-negative fit of
CIE D50 has a spectrum RMSE of 0.044."""
CAMERA = "AptinaMT9M131"

NOISY_MARGIN = 0.05
"""How far above the NNLS LED bound a noisy run may land. Measured 0.046–0.062 over seeds 0–4 (bound
0.044), LED-only SNR 2.9–10 per pixel, since the sim's LEDs are as bright as a flash (every LED at
least the ambient's signal). With all LEDs together 2× the ambient (LED-only SNR 1–2.5) it was
0.15–0.21 and this margin 0.25: 8 LEDs through 3 channels (condition number ~8·10⁴) amplify the
photon noise. The estimate must also be closer to D50 than to CIE A."""
NOISE_FREE_MARGIN = 0.01
"""Without sensor noise the run reaches the bound (measured 0.0441 against 0.0438)."""


def _write_csv(path: Path, wavelengths_nm: np.ndarray, columns: dict[str, np.ndarray]) -> Path:
    rows = [",".join(["wavelength_nm", *columns])]
    rows += [",".join([f"{w:g}", *(f"{c[i]:.7g}" for c in columns.values())]) for i, w in enumerate(wavelengths_nm)]
    path.write_text("\n".join(rows) + "\n")
    return path


def _gaussian_leds(path: Path, peaks_nm=GAUSSIAN_PEAKS_NM, low_nm: float = 380.0) -> Path:
    wavelengths = np.arange(low_nm, 781.0, 5.0)
    return _write_csv(path, wavelengths, {f"g{p}": np.exp(-0.5 * ((wavelengths - p) / 18.0) ** 2) for p in peaks_nm})


def _error_line(capsys: pytest.CaptureFixture) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    errors = [line for line in lines if line.startswith("msflash: error:")]
    assert len(errors) == 1 and lines[-1] == errors[0], lines
    return errors[0]


def _d50_run(out: Path, leds: Path, *extra: str) -> tuple[dict, float]:
    """``msflash run`` of the 8-LED booth, the ISETCam camera and CIE D50; (run.json, NNLS bound)."""
    status = main(
        ["run", "--out", str(out), "--led-spectra", str(leds), "--sim-camera", CAMERA, "--ambient", "D50", *extra]
    )
    assert status == 0
    sequence = read_sequence(out / "sequence")
    truth = np.asarray(sequence.extra["msflash"]["true_ambient"]["spd"])
    led_values = sequence.led_spectra().to_unit("energy").values
    bound = spectrum_rmse(led_bound(led_values, truth[None, None])[0, 0], truth)
    return json.loads((out / "run.json").read_text()), bound


@pytest.fixture(scope="module")
def d50_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict, float]:
    directory = tmp_path_factory.mktemp("d50")
    summary, bound = _d50_run(directory / "run", _gaussian_leds(directory / "gauss8.csv"))
    return directory / "run", summary, bound


def test_eight_gaussian_leds_and_an_isetcam_camera_estimate_d50_near_the_led_bound(d50_run) -> None:
    out, summary, bound = d50_run
    assert bound == pytest.approx(0.044, abs=0.002)
    assert summary["spectrum_rmse_vs_truth"] <= bound + NOISY_MARGIN
    estimate = np.asarray(json.loads((out / "estimate.json").read_text())["spectrum"])
    tungsten = lights.light_spectrum("A").values[:, 0]
    assert summary["spectrum_rmse_vs_truth"] < spectrum_rmse(estimate, tungsten)


def test_the_sequence_records_the_rig_that_was_simulated(d50_run) -> None:
    out, _, _ = d50_run
    sequence = read_sequence(out / "sequence")
    assert [led.name for led in sequence.leds] == [f"g{p}" for p in GAUSSIAN_PEAKS_NM]
    assert [f.role for f in sequence.frames] == ["ambient"] + ["led"] * 8 + ["flash"]
    assert sequence.camera.model == f"SimulatedCamera ({CAMERA})"
    expected_camera = datasets.isetcam_camera(CAMERA).resample(DEFAULT_GRID).to_unit("energy").values
    np.testing.assert_allclose(sequence.camera_responsivities().to_unit("energy").values, expected_camera, rtol=1e-9)
    truth = sequence.extra["msflash"]["true_ambient"]
    assert truth["name"] == "D50"
    np.testing.assert_allclose(truth["spd"], lights.light_spectrum("D50").values[:, 0], rtol=1e-9)


def test_without_noise_the_run_reaches_the_led_bound(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    default = simulated_camera.SimulatedCamera.default.__func__

    def noise_free(cls, *args, **options):
        return default(cls, *args, **{**options, "noise": False})

    monkeypatch.setattr(simulated_camera.SimulatedCamera, "default", classmethod(noise_free))
    summary, bound = _d50_run(tmp_path / "run", _gaussian_leds(tmp_path / "gauss8.csv"), "--seed", "1")
    assert summary["spectrum_rmse_vs_truth"] <= bound + NOISE_FREE_MARGIN


def test_the_emulated_booth_takes_the_csv_channels(tmp_path: Path) -> None:
    with open_sim_rig(led_spectra=_gaussian_leds(tmp_path / "gauss8.csv")) as rig:
        info = rig.booth.info
        assert info.channels == 8
        assert info.names == tuple(f"g{p}" for p in GAUSSIAN_PEAKS_NM)
        assert info.peaks_nm == tuple(float(p) for p in GAUSSIAN_PEAKS_NM)
        # The camera renders what the booth drives: full drive of one channel lights only that LED.
        assert rig.camera.led_spectra.names == info.names


def test_a_camera_file_is_read_as_the_hardware_rigs_responsivity(tmp_path: Path) -> None:
    camera = datasets.camera_responsivities("Canon 5DMarkII").to_unit("energy")
    path = _write_csv(tmp_path / "canon.csv", camera.wavelengths_nm, dict(zip("RGB", camera.values.T)))
    assert (
        main(["capture", "--out", str(tmp_path / "c"), "--sim-camera", str(path), "--leds", "4", "--exposure", "10000"])
        == 0
    )
    sequence = read_sequence(tmp_path / "c" / "sequence")
    assert [led.name for led in sequence.leds] == ["led440", "led500", "led522", "led661"]  # named from their peaks
    assert sequence.camera.model == "SimulatedCamera (canon)"
    np.testing.assert_allclose(
        sequence.camera_responsivities().to_unit("energy").values, camera.resample(DEFAULT_GRID).values, rtol=1e-6
    )


def test_an_ambient_file_and_a_reflectance_mosaic(tmp_path: Path) -> None:
    light = lights.light_spectrum("FL11", DEFAULT_GRID)
    ambient = _write_csv(tmp_path / "lamp.csv", light.wavelengths_nm, {"lamp": light.values[:, 0]})
    surfaces = datasets.vrhel("food").select([0, 5, 9]).resample(DEFAULT_GRID)
    scene = _write_csv(tmp_path / "three.csv", surfaces.wavelengths_nm, dict(zip(("a", "b", "c"), surfaces.values.T)))
    with open_sim_rig(ambient=str(ambient), scene=str(scene), seed=4) as rig:
        world = rig.camera
        np.testing.assert_allclose(rig.true_ambient.values, light.values, rtol=1e-6)
        assert rig.true_ambient.names == ("lamp",)
        assert world.scene.reflectances.names == ("a", "b", "c", "border")
        patches = [np.count_nonzero(world.scene.labels == k) // 64 for k in range(3)]  # 8 × 8 px patches
        assert sorted(patches) == [8, 8, 8]  # three surfaces repeated to 24 patches
    assert (
        main(
            [
                "capture",
                "--out",
                str(tmp_path / "c"),
                "--ambient",
                str(ambient),
                "--scene",
                str(scene),
                "--exposure",
                "10000",
            ]
        )
        == 0
    )
    assert read_sequence(tmp_path / "c" / "sequence").extra["msflash"]["true_ambient"]["name"] == "lamp"


def _bad_files(tmp_path: Path) -> dict[str, Path]:
    grid = np.arange(450.0, 701.0, 10.0)
    wide = np.arange(400.0, 701.0, 10.0)
    return {
        "narrow": _write_csv(tmp_path / "narrow.csv", grid, {c: np.ones(grid.size) for c in "RGB"}),
        "two": _write_csv(tmp_path / "two.csv", wide, {c: np.ones(wide.size) for c in "RG"}),
        "percent": _write_csv(tmp_path / "percent.csv", wide, {"s1": np.full(wide.size, 40.0)}),
        "dark": _write_csv(tmp_path / "dark.csv", wide, {"on": np.ones(wide.size), "off": np.zeros(wide.size)}),
        "many": _gaussian_leds(tmp_path / "many.csv", peaks_nm=tuple(np.linspace(400, 700, 65).round(1))),
        "star": _write_csv(tmp_path / "star.csv", wide, {"a*b": np.ones(wide.size)}),
    }


@pytest.mark.parametrize(
    ("options", "expected"),
    [
        (["--sim-camera", "Foo"], "--sim-camera: camera 'Foo': unknown; expected one of AptinaMT9M031, "),
        (["--sim-camera", "{narrow}"], "--sim-camera {narrow}: covers 450–700 nm; expected at least 400–700 nm"),
        (["--sim-camera", "{two}"], "{two}: 2 responsivity columns (R, G); expected 3 (R, G, B)"),
        (["--ambient", "moonlight"], "--ambient: light 'moonlight': unknown; expected one of tungsten, "),
        (["--ambient", "{narrow}"], "--ambient {narrow}: covers 450–700 nm; expected at least 400–700 nm"),
        (["--ambient", "{two}"], "--ambient {two}: 2 spectra (R, G); expected one ambient"),
        (
            ["--scene", "forest"],
            "--scene 'forest': unknown; expected one of chart110, macbeth, white or a reflectance CSV",
        ),
        (["--scene", "{percent}"], "--scene {percent}: reflectances span 40–40 (a table in percent? divide by 100)"),
        (["--led-spectra", "{narrow}"], "--led-spectra {narrow}: covers 450–700 nm; expected at least 400–700 nm"),
        (["--led-spectra", "{dark}"], "--led-spectra {dark}: LED 'off' has no light on 400–700 nm"),
        (
            ["--led-spectra", "{many}"],
            "--led-spectra {many}: 65 LED channel(s) (g400.0, g404.7, g409.4, …, g700.0): "
            "the booth emulator cannot serve them (BoothEmulator: 65 names",
        ),
        (["--led-spectra", "{star}"], "--led-spectra {star}: 1 LED channel(s) (a*b): the booth emulator cannot serve"),
        (["--leds", "3", "--led-spectra", "{dark}"], "--leds 3 and --led-spectra {dark}: two LED sets; expected one"),
        (["--leds", "8"], "--leds '8': unknown; expected one of 3, 4, 5, 6, 7"),
        (
            ["--rig", "replay:{percent}", "--sim-camera", "NikonD70"],
            "--sim-camera: describes the simulated world, but the "
            "rig is 'replay:{percent}'; expected --rig sim or "
            "aravis-fake",
        ),
        # aravis-fake renders the same world: its options are checked the same way, before the fake opens.
        (["--rig", "aravis-fake", "--ambient", "moonlight"], "--ambient: light 'moonlight': unknown; expected one of "),
        (["--rig", "aravis-fake", "--scene", "{percent}"], "--scene {percent}: reflectances span 40–40"),
        (
            ["--rig", "aravis-fake", "--cfa", "RGGB"],
            "--cfa: describes the simulated rig's camera, but the rig is "
            "'aravis-fake' (its frames are BayerRG16, an RGGB mosaic)",
        ),
        # Hardware options the simulated rig used to ignore without a word (it read no --responsivity file at all).
        (
            ["--responsivity", "{percent}"],
            "--responsivity: describes a hardware rig's camera or booth, but the rig is "
            "'sim' and would ignore it (the simulated camera is --sim-camera",
        ),
        (
            ["--calibration", "{percent}"],
            "--calibration: describes a hardware rig's camera or booth, but the rig is 'sim'",
        ),
        (
            ["--rig", "aravis-fake", "--pixel-format", "Mono8"],
            "--pixel-format: describes a hardware rig's camera or booth, but the rig is 'aravis-fake'",
        ),
    ],
)
def test_bad_sim_options_give_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture, options: list[str], expected: str
) -> None:
    files = {name: str(path) for name, path in _bad_files(tmp_path).items()}
    status = main(["capture", "--out", str(tmp_path / "out"), *(o.format(**files) for o in options)])
    line = _error_line(capsys)
    assert status == 2
    assert line.startswith("msflash: error: " + expected.format(**files)), line
    assert not (tmp_path / "out" / "sequence").exists()


def test_an_unknown_camera_lists_every_shipped_one(capsys: pytest.CaptureFixture, tmp_path: Path) -> None:
    assert main(["capture", "--out", str(tmp_path / "out"), "--sim-camera", "Nikon D9000"]) == 2
    line = _error_line(capsys)
    for name in datasets.camera_names():
        assert name in line


@pytest.mark.parametrize(
    ("name", "key"), [("F2", "FL2"), ("d65", "D65"), ("tungsten", "tungsten"), ("blackbody:3200", "blackbody 3200 K")]
)
def test_ambient_names(name: str, key: str) -> None:
    with open_sim_rig(ambient=name, n_leds=3) as rig:
        assert rig.true_ambient.names == (key,)
        assert rig.booth.info.channels == 3
