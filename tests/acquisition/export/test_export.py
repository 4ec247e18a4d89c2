"""``msflash export``: each format opened by an independent reader (rawpy/LibRaw for DNG, ome-types and
tifffile for OME-TIFF, the csv module for CSV, OpenImageIO for EXR), on the independent samples and on
rendered sequences; and its refusals (one line, exit 2, nothing created)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import ome_types
import OpenImageIO as oiio
import pytest
import rawpy
import tifffile

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.reader import read_sequence
from msflash.processing.raw_colour import XYZ_TO_LINEAR_SRGB, camera_matrix
from tests.helpers import SAMPLES_DIR, write_test_sequence

BAYER_SAMPLE = SAMPLES_DIR / "sample-bayer-fluorescent-12bit"
RGB_SAMPLE = SAMPLES_DIR / "sample-rgb-tungsten"
SRGB_TO_XYZ = np.linalg.inv(XYZ_TO_LINEAR_SRGB)
LIBRAW_COLOURS = "RGBG"
"""rawpy's colour_desc for a Bayer DNG: raw_pattern's 0, 1, 2, 3."""


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def export(capsys: pytest.CaptureFixture[str], sequence: Path, to: str, out: Path) -> dict:
    status, stdout, err = run(capsys, "export", str(sequence), "--to", to, "--out", str(out), "--json")
    assert status == 0, err
    return json.loads(stdout)


def estimate_json(capsys: pytest.CaptureFixture[str], sequence: Path) -> dict:
    # The global LED-model estimate, the one run and flash solve from (estimate's default --method auto
    # may choose local tiles).
    status, stdout, err = run(capsys, "estimate", str(sequence), "--method", "global", "--json")
    assert status == 0, err
    return json.loads(stdout)


def independent_neutral(sequence: Path, light_energy: np.ndarray) -> np.ndarray:
    """Σλ R(λ) e(λ) per channel, straight from sequence.json (energy units: the product is unit-free)."""
    document = json.loads((sequence / "sequence.json").read_text())
    assert document["spectral_unit"] == "energy"
    curves = np.array([document["camera"]["responsivity"][c] for c in "RGB"])
    response = curves @ light_energy
    return response / response.max()


def assert_bad_input(status: int, out: str, err: str, *names: str) -> None:
    assert status == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("msflash: error: ")
    for name in names:
        assert name in lines[0], f"{name!r} not named in {lines[0]!r}"
    assert out == ""


@pytest.fixture(scope="module")
def grbg_sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(
        tmp_path_factory.mktemp("seq") / "grbg", cfa="GRBG", gains=[1.0, 2.0, 1.0, 1.0, 1.5, 1.0, 1.0, 3.0]
    )


@pytest.fixture(scope="module")
def bayer_without_responsivity(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(tmp_path_factory.mktemp("seq") / "bare", cfa="RGGB", responsivity=False)


# -- DNG ---------------------------------------------------------------------------------------
def test_dng_of_the_bayer_sample_opens_in_libraw_with_its_counts_levels_cfa_and_the_estimated_neutral(
    capsys, tmp_path: Path
) -> None:
    out = tmp_path / "dng"
    result = export(capsys, BAYER_SAMPLE, "dng", out)
    sequence = read_sequence(BAYER_SAMPLE)
    assert [Path(f).name for f in result["files"]] == [Path(f.file).stem + ".dng" for f in sequence.frames]
    estimate = estimate_json(capsys, BAYER_SAMPLE)
    spectrum = np.asarray(estimate["spectrum"])
    leds = np.column_stack([led.spd for led in sequence.leds])
    for index, frame in enumerate(sequence.frames):
        with rawpy.imread(str(out / Path(result["files"][index]).name)) as raw:
            np.testing.assert_array_equal(raw.raw_image, sequence.load_frame(index))
            assert raw.black_level_per_channel == [256] * 4
            assert raw.white_level == 4095
            assert "".join(LIBRAW_COLOURS[c] for c in raw.raw_pattern.ravel()) == "RGGB"
            # LibRaw's multipliers are 1 / AsShotNeutral: the camera's response to this frame's light,
            # the estimated ambient plus the LEDs at the frame's levels.
            neutral = independent_neutral(BAYER_SAMPLE, spectrum + leds @ np.asarray(frame.led_levels))
            multipliers = np.asarray(raw.camera_whitebalance[:3])
            np.testing.assert_allclose(multipliers / multipliers[1], neutral[1] / neutral, rtol=1e-5)
    assert result["ambient_neutral"] == pytest.approx(list(independent_neutral(BAYER_SAMPLE, spectrum)), rel=1e-5)


def test_the_dng_neutral_is_within_a_few_percent_of_the_true_ambients(capsys, tmp_path: Path) -> None:
    """What a raw developer white-balances to: the sample's true FL2 seen by its camera."""
    out = tmp_path / "dng"
    export(capsys, BAYER_SAMPLE, "dng", out)
    truth = json.loads(BAYER_SAMPLE.with_name(BAYER_SAMPLE.name + ".truth.json").read_text())
    true_neutral = independent_neutral(BAYER_SAMPLE, np.asarray(truth["ambient_spd_energy"]))
    with rawpy.imread(str(out / "000-ambient.dng")) as raw:
        multipliers = np.asarray(raw.camera_whitebalance[:3])
    np.testing.assert_allclose(multipliers[1] / multipliers, true_neutral, rtol=0.03)


def libraw_camera_to_srgb(xyz_to_camera: np.ndarray) -> np.ndarray:
    """What LibRaw makes of a DNG's ColorMatrix1: camera → sRGB, rows of sRGB → camera summing to 1, inverted."""
    camera_from_srgb = xyz_to_camera @ SRGB_TO_XYZ
    camera_from_srgb /= camera_from_srgb.sum(axis=1, keepdims=True)
    return np.linalg.inv(camera_from_srgb)


def test_dng_colour_matrix_is_the_camera_fit_and_libraw_reads_it(capsys, grbg_sequence: Path, tmp_path: Path) -> None:
    out = tmp_path / "dng"
    export(capsys, grbg_sequence, "dng", out)
    sequence = read_sequence(grbg_sequence)
    matrix = camera_matrix(sequence.camera_responsivities())
    with tifffile.TiffFile(out / "000-ambient.dng") as dng:
        tags = dng.pages[0].tags
        assert tuple(tags["DNGVersion"].value) == (1, 4, 0, 0)
        assert tags["UniqueCameraModel"].value == "test-render"
        assert tags["CalibrationIlluminant1"].value == 21  # D65
        exif = tags["ExifTag"].value  # the EXIF sub-IFD, where ExposureTime belongs
        numerator, denominator = exif["ExposureTime"]
        assert numerator / denominator == pytest.approx(sequence.frames[0].exposure_us / 1e6, rel=1e-9)  # seconds
        pairs = np.asarray(tags["ColorMatrix1"].value, dtype=float).reshape(9, 2)
        np.testing.assert_allclose(pairs[:, 0] / pairs[:, 1], matrix.xyz_to_camera.ravel(), atol=1e-6)
    with rawpy.imread(str(out / "000-ambient.dng")) as raw:
        assert "".join(LIBRAW_COLOURS[c] for c in raw.raw_pattern.ravel()) == "GRBG"
        np.testing.assert_allclose(raw.color_matrix[:, :3], libraw_camera_to_srgb(matrix.xyz_to_camera), atol=1e-3)
        np.testing.assert_array_equal(raw.raw_image, sequence.load_frame(0))


def test_dng_without_responsivities_assumes_srgb_and_says_so(
    capsys, bayer_without_responsivity: Path, tmp_path: Path
) -> None:
    out = tmp_path / "dng"
    result = export(capsys, bayer_without_responsivity, "dng", out)
    assert any("linear sRGB" in note for note in result["notes"])
    assert result["color_matrix_source"] == "assumed linear sRGB"
    with rawpy.imread(str(out / "000-ambient.dng")) as raw:
        np.testing.assert_allclose(raw.color_matrix[:, :3], np.eye(3), atol=1e-3)  # camera RGB is sRGB
        multipliers = np.asarray(raw.camera_whitebalance[:3])
    neutral = multipliers[1] / multipliers
    assert neutral[0] > neutral[1] > neutral[2]  # tungsten ambient: reddish


def test_dng_of_rgb_frames_is_refused_and_nothing_is_created(capsys, tmp_path: Path) -> None:
    out = tmp_path / "dng"
    status, stdout, err = run(capsys, "export", str(RGB_SAMPLE), "--to", "dng", "--out", str(out))
    assert_bad_input(status, stdout, err, "camera.cfa", "--to dng")
    assert list(tmp_path.iterdir()) == []


# -- OME-TIFF ----------------------------------------------------------------------------------
@pytest.mark.parametrize("sample", [RGB_SAMPLE, BAYER_SAMPLE], ids=["rgb", "bayer"])
def test_ome_tiff_holds_every_frame_with_led_wavelengths_exposures_and_gains(
    capsys, sample: Path, tmp_path: Path
) -> None:
    out = tmp_path / "ome"
    result = export(capsys, sample, "ome-tiff", out)
    path = Path(result["files"][0])
    assert path.name == "sequence.ome.tif"
    sequence = read_sequence(sample)
    peaks = list(sequence.led_peaks_nm())  # the one number (processing/led_wavelength.py)
    document = ome_types.from_tiff(path, validate=True)  # against the OME 2016-06 XSD (lxml)
    with tifffile.TiffFile(path) as tiff:
        assert ome_types.from_xml(tiff.ome_metadata) == document
    pixels = document.images[0].pixels
    samples = 1 if sequence.camera.cfa else 3
    assert len(pixels.channels) == len(pixels.planes) == len(sequence.frames)
    assert pixels.size_c == len(sequence.frames) * samples
    assert [led.model for led in document.instruments[0].light_emitting_diodes] == [led.name for led in sequence.leds]
    for index, (frame, channel, plane) in enumerate(zip(sequence.frames, pixels.channels, pixels.planes, strict=True)):
        assert channel.samples_per_pixel == samples
        assert plane.the_c == index
        assert plane.exposure_time == frame.exposure_us
        assert plane.exposure_time_unit.value == "µs"
        assert channel.detector_settings.gain == frame.gain
        lit = [k for k, level in enumerate(frame.led_levels) if level > 0]
        if frame.role == "led" and len(lit) == 1:
            assert channel.name == f"{index:03d} {sequence.leds[lit[0]].name}"
            assert channel.excitation_wavelength == peaks[lit[0]]
            assert channel.light_source_settings.id == f"LightSource:{lit[0]}"
        else:
            assert channel.name == f"{index:03d} {frame.role}"
            assert channel.excitation_wavelength is None
    with tifffile.TiffFile(path) as tiff:
        assert tiff.is_ome
        planes = tiff.series[0].asarray()
    assert planes.shape[0] == len(sequence.frames)
    for index in range(len(sequence.frames)):
        np.testing.assert_array_equal(planes[index], sequence.load_frame(index))


# -- CSV ---------------------------------------------------------------------------------------
def read_table(path: Path) -> tuple[list[str], np.ndarray]:
    with open(path, newline="", encoding="utf-8") as handle:
        rows = list(csv.reader(handle))
    return rows[0], np.array(rows[1:], dtype=float)


def test_csv_holds_the_estimate_its_band_the_leds_and_the_flash_mixes_with_units(capsys, tmp_path: Path) -> None:
    out = tmp_path / "csv"
    result = export(capsys, RGB_SAMPLE, "csv", out)
    header, table = read_table(out / "spectra.csv")
    sequence = read_sequence(RGB_SAMPLE)
    column = {name: table[:, i] for i, name in enumerate(header)}
    assert header[0] == "wavelength [nm]"
    assert all(name.endswith("[relative energy]") for name in header[1:])
    np.testing.assert_array_equal(column["wavelength [nm]"], sequence.wavelengths_nm)
    estimate = estimate_json(capsys, RGB_SAMPLE)
    spectrum, std = np.asarray(estimate["spectrum"]), np.asarray(estimate["spectrum_std"])
    np.testing.assert_allclose(column["ambient estimate [relative energy]"], spectrum, rtol=1e-9)
    np.testing.assert_allclose(column["ambient estimate - 1 sigma [relative energy]"], spectrum - std, rtol=1e-9)
    np.testing.assert_allclose(column["ambient estimate + 1 sigma [relative energy]"], spectrum + std, rtol=1e-9)
    leds = np.column_stack([led.spd for led in sequence.leds])
    for k, led in enumerate(sequence.leds):
        np.testing.assert_array_equal(column[f"LED {led.name} at full drive [relative energy]"], leds[:, k])
    for mode in ("matching", "complementary"):
        status, stdout, err = run(capsys, "flash", str(RGB_SAMPLE), "--mode", mode, "--method", "global", "--json")
        assert status == 0, err
        weights = np.asarray(json.loads(stdout)["flash_weights"])
        mix = column[f"{mode} flash mix [relative energy]"]
        np.testing.assert_allclose(mix, leds @ weights, rtol=1e-6)  # two solves agree to the solver's tolerance
    about = json.loads((out / "spectra.json").read_text())
    assert about["band"] == estimate["band"]
    assert [Path(f).name for f in result["files"]] == ["spectra.csv", "spectra.json"]


# -- EXR ---------------------------------------------------------------------------------------
def exr_header(path: Path) -> tuple[oiio.ImageSpec, np.ndarray]:
    image = oiio.ImageInput.open(str(path))
    assert image is not None, oiio.geterror()
    try:
        return image.spec(), np.asarray(image.read_image(0, 0, 0, 3, "float"))
    finally:
        image.close()


def test_exr_export_carries_chromaticities_units_and_led_names(capsys, tmp_path: Path) -> None:
    out = tmp_path / "exr"
    result = export(capsys, RGB_SAMPLE, "exr", out)
    assert [Path(f).name for f in result["files"]] == ["ambient.exr", "matching.exr", "complementary.exr"]
    sequence = read_sequence(RGB_SAMPLE)
    matrix = camera_matrix(sequence.camera_responsivities()).camera_to_xyz
    for name in ("ambient", "matching", "complementary"):
        spec, pixels = exr_header(out / f"{name}.exr")
        assert spec.nchannels == 3
        xy = np.asarray(spec.getattribute("chromaticities"))
        red = matrix[:, 0] / matrix[:, 0].sum()
        np.testing.assert_allclose(xy[:2], red[:2], atol=1e-6)
        white = matrix.sum(axis=1) / matrix.sum()
        np.testing.assert_allclose(xy[6:], white[:2], atol=1e-6)
        assert "per µs" in spec.getattribute("msflash:units")
        assert spec.getattribute("msflash:led_names") == ", ".join(led.name for led in sequence.leds)
        assert "camera responsivities" in spec.getattribute("msflash:chromaticities_source")
    _, ambient = exr_header(out / "ambient.exr")
    expected, _ = sequence.load_linear_frame(sequence.indices("ambient")[0])
    np.testing.assert_allclose(ambient, expected.astype(np.float32), rtol=1e-6)


def test_exr_of_a_mosaic_is_demosaicked_and_without_responsivities_says_srgb(
    capsys, bayer_without_responsivity: Path, tmp_path: Path
) -> None:
    out = tmp_path / "exr"
    result = export(capsys, bayer_without_responsivity, "exr", out)
    assert [Path(f).name for f in result["files"]] == ["ambient.exr"]  # no flash without responsivities
    spec, _ = exr_header(out / "ambient.exr")
    assert spec.nchannels == 3
    np.testing.assert_allclose(
        spec.getattribute("chromaticities"), (0.64, 0.33, 0.3, 0.6, 0.15, 0.06, 0.3127, 0.329), atol=2e-4
    )
    assert "assumed linear sRGB" in spec.getattribute("msflash:chromaticities_source")


# -- the command -------------------------------------------------------------------------------
def test_several_formats_into_one_folder_from_a_run_folder(capsys, grbg_sequence: Path, tmp_path: Path) -> None:
    run_folder = tmp_path / "run"
    run_folder.mkdir()
    (run_folder / "sequence").symlink_to(grbg_sequence)
    out = tmp_path / "both"
    result = export(capsys, run_folder, "dng,csv", out)
    names = sorted(path.name for path in out.iterdir())
    assert names == sorted(Path(f).name for f in result["files"])
    assert "spectra.csv" in names and "000-ambient.dng" in names
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no staging folder left


@pytest.mark.parametrize(
    ("argv", "names"),
    [
        (["--to", "png"], ["--to png", "dng, ome-tiff, csv, exr"]),
        (["--to", "dng,tiff"], ["--to dng,tiff", "'tiff'"]),
    ],
)
def test_unknown_format_is_refused(capsys, tmp_path: Path, argv: list[str], names: list[str]) -> None:
    status, stdout, err = run(capsys, "export", str(BAYER_SAMPLE), *argv, "--out", str(tmp_path / "out"))
    assert_bad_input(status, stdout, err, *names)
    assert list(tmp_path.iterdir()) == []


def test_not_a_sequence_is_refused(capsys, tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    status, stdout, err = run(capsys, "export", str(tmp_path / "empty"), "--to", "csv", "--out", str(tmp_path / "o"))
    assert_bad_input(status, stdout, err, "empty", "no sequence.json in it")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty"]


def test_an_existing_out_is_refused_and_left_alone(capsys, tmp_path: Path) -> None:
    out = tmp_path / "out"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    status, stdout, err = run(capsys, "export", str(BAYER_SAMPLE), "--to", "csv", "--out", str(out))
    assert_bad_input(status, stdout, err, "--out", "already exists")
    assert [p.name for p in out.iterdir()] == ["mine.txt"]


def test_a_frame_failing_midway_leaves_nothing(capsys, grbg_sequence: Path, tmp_path: Path) -> None:
    """A frame file changed after it was written is refused when the export reaches it; the
    frames already exported go with the staging folder."""
    import shutil

    copy = tmp_path / "seq"
    shutil.copytree(grbg_sequence, copy)
    last = read_sequence(copy).frames[-1].file
    (copy / last).write_bytes((copy / last).read_bytes()[:-10])
    out = tmp_path / "out"
    status, stdout, err = run(capsys, "export", str(copy), "--to", "ome-tiff", "--out", str(out))
    assert status == 2, err
    assert last in err.strip().splitlines()[-1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]


# -- the EXRs other commands write, and run --export ---------------------------------------------
def test_flash_out_exr_carries_chromaticities_units_and_led_names(capsys, tmp_path: Path) -> None:
    out = tmp_path / "flash.exr"
    status, _, err = run(capsys, "flash", str(RGB_SAMPLE), "--mode", "complementary", "--out", str(out))
    assert status == 0, err
    spec, _ = exr_header(out)
    sequence = read_sequence(RGB_SAMPLE)
    matrix = camera_matrix(sequence.camera_responsivities()).camera_to_xyz
    white = matrix.sum(axis=1) / matrix.sum()
    np.testing.assert_allclose(np.asarray(spec.getattribute("chromaticities"))[6:], white[:2], atol=1e-6)
    assert "per µs" in spec.getattribute("msflash:units")
    assert spec.getattribute("msflash:led_names") == ", ".join(led.name for led in sequence.leds)


def test_run_export_writes_dngs_whose_neutrals_follow_each_frames_light(capsys, tmp_path: Path) -> None:
    """A sim run with a Bayer camera: the ambient DNG's neutral is near the true ambient's, and the flash
    frame's is the estimate plus the re-captured flash levels."""
    out = tmp_path / "run"
    status, _, err = run(capsys, "run", "--rig", "sim", "--cfa", "RGGB", "--out", str(out), "--export", "dng,csv")
    assert status == 0, err
    summary = json.loads((out / "run.json").read_text())
    assert summary["export"]["formats"] == ["dng", "csv"]
    assert sorted(Path(f).name for f in summary["export"]["files"]) == sorted(
        p.name for p in (out / "export").iterdir()
    )
    sequence_dir = out / "sequence"
    sequence = read_sequence(sequence_dir)
    document = json.loads((sequence_dir / "sequence.json").read_text())
    truth = np.asarray(document["msflash"]["true_ambient"]["spd"])  # energy, the sequence's grid
    estimate = json.loads((out / "estimate.json").read_text())
    spectrum = np.asarray(estimate["spectrum"])
    leds = np.column_stack([led.spd for led in sequence.leds])
    with rawpy.imread(str(out / "export" / "000-ambient.dng")) as raw:
        multipliers = np.asarray(raw.camera_whitebalance[:3])
        np.testing.assert_array_equal(raw.raw_image, sequence.load_frame(0))
    np.testing.assert_allclose(multipliers[1] / multipliers, independent_neutral(sequence_dir, truth), rtol=0.03)
    flash = sequence.indices("flash")[-1]
    with rawpy.imread(str(out / "export" / f"{Path(sequence.frames[flash].file).stem}.dng")) as raw:
        multipliers = np.asarray(raw.camera_whitebalance[:3])
    light = spectrum + leds @ np.asarray(sequence.frames[flash].led_levels)
    np.testing.assert_allclose(multipliers[1] / multipliers, independent_neutral(sequence_dir, light), rtol=1e-5)
    spec, _ = exr_header(out / "complementary.exr")  # run's own EXR: the mosaic demosaicked, and said so
    assert spec.nchannels == 3 and spec.getattribute("msflash:cfa") == "RGGB"
    assert spec.getattribute("msflash:led_names") == ", ".join(led.name for led in sequence.leds)


def test_run_export_dng_of_an_rgb_rig_is_refused_before_capture(capsys, tmp_path: Path) -> None:
    out = tmp_path / "run"
    status, stdout, err = run(capsys, "run", "--rig", "sim", "--cfa", "none", "--out", str(out), "--export", "dng")
    assert status == 2
    assert err.strip().splitlines()[-1].startswith("msflash: error: --export dng")
    assert not (out / "sequence").exists()


def test_dng_of_float_frames_is_refused(capsys, tmp_path: Path) -> None:
    from msflash.acquisition.sequence.format import SequenceCamera, SequenceLed
    from msflash.acquisition.sequence.writer import SequenceWriter
    from tests.helpers import GRID

    directory = tmp_path / "float"
    camera = SequenceCamera(
        model="float", serial=None, pixel_format="BayerRG32f", cfa="RGGB", black_level=0.0, white_level=1.0
    )
    led = SequenceLed("led", np.exp(-(((GRID.wavelengths_nm - 550.0) / 20.0) ** 2)))
    with SequenceWriter(
        directory, wavelengths_nm=GRID.wavelengths_nm, spectral_unit="energy", camera=camera, leds=[led]
    ) as writer:
        writer.add_frame(np.full((16, 16), 0.1, np.float32), "ambient", [0.0], exposure_us=1000.0, gain=1.0)
        writer.add_frame(np.full((16, 16), 0.3, np.float32), "led", [1.0], exposure_us=1000.0, gain=1.0)
    out = tmp_path / "out"
    status, stdout, err = run(capsys, "export", str(directory), "--to", "dng", "--out", str(out))
    assert_bad_input(status, stdout, err, "float32", "integer counts")
    assert not out.exists()


def test_a_dark_ambient_is_refused_for_what_needs_an_estimate_and_leaves_nothing(
    capsys, grbg_sequence: Path, tmp_path: Path
) -> None:
    import shutil

    from msflash.acquisition.sequence.image_files import write_image
    from tests.helpers import forget_digests

    copy = tmp_path / "seq"
    shutil.copytree(grbg_sequence, copy)
    sequence = read_sequence(copy)
    ambient = sequence.frame_path(0)
    write_image(ambient, np.full(sequence.load_frame(0).shape, sequence.camera.black_level, np.uint16))
    forget_digests(copy)
    out = tmp_path / "out"
    status, stdout, err = run(capsys, "export", str(copy), "--to", "csv", "--out", str(out))
    assert status == 2 and stdout == ""
    last = err.strip().splitlines()[-1]  # after the progress lines: "exporting csv", "estimating"
    assert last.startswith("msflash: error: ") and "frames[0].file" in last and "holds no light" in last
    assert sorted(p.name for p in tmp_path.iterdir()) == ["seq"]


def test_the_estimation_options_are_those_of_estimate(capsys, tmp_path: Path) -> None:
    out = tmp_path / "csv"
    status, _, err = run(capsys, "export", str(BAYER_SAMPLE), "--to", "csv", "--out", str(out), "--solver", "nonneg")
    assert status == 0, err
    header, table = read_table(out / "spectra.csv")
    status, stdout, err = run(
        capsys, "estimate", str(BAYER_SAMPLE), "--method", "global", "--solver", "nonneg", "--json"
    )
    assert status == 0, err
    estimate = json.loads(stdout)
    assert estimate["solver"] == "nonneg"
    np.testing.assert_allclose(
        table[:, header.index("ambient estimate [relative energy]")], estimate["spectrum"], rtol=1e-9
    )
    _, default = read_table(Path(export(capsys, BAYER_SAMPLE, "csv", tmp_path / "default")["files"][0]))
    assert not np.allclose(default[:, 1], table[:, 1])  # the option changed the estimate


def test_a_full_disk_midway_is_one_runtime_error_and_leaves_nothing(
    capsys, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno

    from msflash.acquisition.export import sequence_export

    def full(path, wavelengths, columns):  # noqa: ANN001 - write_spectra_csv's signature
        Path(path).write_text("partial")
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(sequence_export, "write_spectra_csv", full)
    out = tmp_path / "out"
    status, stdout, err = run(capsys, "export", str(BAYER_SAMPLE), "--to", "ome-tiff,csv", "--out", str(out))
    assert status == 1 and stdout == ""
    last = err.strip().splitlines()[-1]
    assert last.startswith(f"msflash: error: --out {out}: could not be written (No space left on device)")
    assert list(tmp_path.iterdir()) == []
