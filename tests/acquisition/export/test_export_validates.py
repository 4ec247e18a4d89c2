"""Issue 33, item 3: exports that validate, read back by independent readers.

DNG: ``exiftool -validate`` (no warning), LibRaw through rawpy (counts, CFA, levels, shutter, date) and
tifffile (IFD0 and the EXIF sub-IFD). OME-TIFF: ome-types against the XSD and tifffile (AcquisitionDate,
DeltaT, no path of the user's). EXR: OpenImageIO and the OpenEXR bindings (R, G, B; the mosaic recoverable).
One number for each LED's wavelength across all of them. The run report links every export.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np
import ome_types
import OpenEXR
import OpenImageIO as oiio
import pytest
import rawpy
import tifffile

from msflash.acquisition.app.cli import main
from msflash.acquisition.export.dng import write_dng
from msflash.acquisition.sequence.format import utc_now_text
from msflash.acquisition.sequence.reader import read_sequence
from msflash.processing.led_wavelength import led_name
from msflash.processing.sensor import cfa_channel_map
from tests.helpers import SAMPLES_DIR, forget_digests, write_test_sequence

BAYER_SAMPLE = SAMPLES_DIR / "sample-bayer-fluorescent-12bit"
EXIFTOOL = shutil.which("exiftool")


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def exiftool(*paths: Path) -> list[dict]:
    """exiftool's JSON of each file: every tag with its group (``-G1``), validated, warnings kept."""
    assert EXIFTOOL, "exiftool is missing: setup.sh installs the Debian package libimage-exiftool-perl"
    done = subprocess.run(
        [EXIFTOOL, "-j", "-G1", "-a", "-n", "-all", "-validate", "-warning", *map(str, paths)],
        capture_output=True,
        text=True,
        check=False,
        timeout=120,
    )
    return json.loads(done.stdout)


def assert_valid(tags: dict) -> None:
    warnings = {key: value for key, value in tags.items() if "Warning" in key}
    assert tags["ExifTool:Validate"] == "0 0 0", warnings  # with -n: errors, warnings, minor warnings
    assert not warnings, warnings


@pytest.fixture(scope="module")
def sim_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A Bayer sim run with every export, made once: ``run --cfa RGGB --export dng,ome-tiff,exr,csv``."""
    out = tmp_path_factory.mktemp("run") / "run"
    status = main(["run", "--rig", "sim", "--cfa", "RGGB", "--out", str(out), "--export", "dng,ome-tiff,exr,csv"])
    assert status == 0
    return out


# -- DNG -----------------------------------------------------------------------------------------
def test_every_dng_of_a_run_validates_and_carries_its_frames_time(sim_run: Path) -> None:
    sequence = read_sequence(sim_run / "sequence")
    paths = [sim_run / "export" / f"{Path(frame.file).stem}.dng" for frame in sequence.frames]
    for path, frame, tags in zip(paths, sequence.frames, exiftool(*paths), strict=True):
        assert_valid(tags)
        assert "IFD0:ExposureTime" not in tags
        assert tags["ExifIFD:ExposureTime"] == pytest.approx(frame.exposure_us / 1e6, rel=1e-6)
        moment = frame.captured_utc
        assert moment is not None
        assert tags["ExifIFD:DateTimeOriginal"] == moment.strftime("%Y:%m:%d %H:%M:%S")
        # exiftool -j -n prints 542803 as a number but keeps "042803" a string (a leading zero)
        assert str(tags["ExifIFD:SubSecTimeOriginal"]).zfill(6) == f"{moment.microsecond:06d}"
        assert tags["ExifIFD:OffsetTimeOriginal"] == "+00:00"
        assert tags["IFD0:Orientation"] == 1
        assert "ExifIFD:ISO" not in tags  # the sim camera states no ISO equivalence
        with rawpy.imread(str(path)) as raw:
            np.testing.assert_array_equal(raw.raw_image, sequence.load_frame(sequence.frames.index(frame)))
            assert "".join("RGBG"[c] for c in raw.raw_pattern.ravel()) == "RGGB"
            assert raw.white_level == round(sequence.camera.white_level)
            assert raw.black_level_per_channel == [round(sequence.camera.black_level)] * 4
            assert raw.other.shutter_speed == pytest.approx(frame.exposure_us / 1e6, rel=1e-6)
            assert raw.other.iso_speed == 0  # none written: LibRaw's "unknown"
            # LibRaw reads the date as local time and rawpy turns it back the same way: the written fields.
            assert raw.other.timestamp == moment.replace(microsecond=0, tzinfo=None)
        with tifffile.TiffFile(path) as tiff:
            page = tiff.pages[0]
            exif = page.tags["ExifTag"].value
            assert exif["SubsecTimeOriginal"] == f"{moment.microsecond:06d}"
            assert page.tags["DateTime"].value == exif["DateTimeOriginal"]
            assert json.loads(page.tags["ImageDescription"].value)["msflash:led_peak_nm"] == [
                led.peak_nm for led in sequence.leds
            ]


def test_dngs_of_the_independent_sample_validate_without_a_date_and_say_so(capsys, tmp_path: Path) -> None:
    out = tmp_path / "dng"
    status, stdout, err = run(capsys, "export", str(BAYER_SAMPLE), "--to", "dng", "--out", str(out), "--json")
    assert status == 0, err
    result = json.loads(stdout)
    assert any("time_utc" in note and "DateTimeOriginal" in note for note in result["notes"])
    assert any("ISOSpeedRatings" in note for note in result["notes"])
    for tags in exiftool(*sorted(out.glob("*.dng"))):
        assert_valid(tags)
        assert "ExifIFD:DateTimeOriginal" not in tags and "ExifIFD:ExposureTime" in tags


def test_iso_is_written_only_where_the_camera_states_its_iso_equivalence(capsys, tmp_path: Path) -> None:
    """``camera.iso_speed_at_unit_gain`` × the frame's linear gain; none when the gain is only relative."""
    sequence_dir = write_test_sequence(tmp_path / "seq", cfa="GRBG", gains=[1.0, 2.0, 1.0, 1.0, 1.0, 1.0, 1.0, 4.0])
    document = json.loads((sequence_dir / "sequence.json").read_text())
    document["camera"]["iso_speed_at_unit_gain"] = 100
    (sequence_dir / "sequence.json").write_text(json.dumps(document))
    out = tmp_path / "iso"
    status, _, err = run(capsys, "export", str(sequence_dir), "--to", "dng", "--out", str(out))
    assert status == 0, err
    sequence = read_sequence(sequence_dir)
    paths = [out / f"{Path(frame.file).stem}.dng" for frame in sequence.frames]
    for frame, tags, path in zip(sequence.frames, exiftool(*paths), paths, strict=True):
        assert_valid(tags)
        assert tags["ExifIFD:ISO"] == round(100 * frame.gain)
        assert tags["ExifIFD:SensitivityType"] == 3  # ISO speed
        with rawpy.imread(str(path)) as raw:
            assert raw.other.iso_speed == round(100 * frame.gain)
    document["camera"]["gain"] = {"linear": "relative: the camera's gain has no known dB scale"}
    (sequence_dir / "sequence.json").write_text(json.dumps(document))
    status, _, err = run(capsys, "export", str(sequence_dir), "--to", "dng", "--out", str(tmp_path / "relative"))
    assert status == 0 and "linear gain is unknown" in err
    assert all("ExifIFD:ISO" not in tags for tags in exiftool(*sorted((tmp_path / "relative").glob("*.dng"))))
    document["camera"]["iso_speed_at_unit_gain"] = -5
    (sequence_dir / "sequence.json").write_text(json.dumps(document))
    status, _, err = run(capsys, "export", str(sequence_dir), "--to", "dng", "--out", str(tmp_path / "bad"))
    assert status == 2 and "camera.iso_speed_at_unit_gain is -5" in err.strip().splitlines()[-1]


@pytest.mark.parametrize("moment", [datetime(2026, 12, 31, 23, 59, 59, 999999, tzinfo=UTC), None])
def test_the_writer_alone_validates_with_and_without_a_time(tmp_path: Path, moment: datetime | None) -> None:
    mosaic = (np.arange(300 * 500).reshape(300, 500) % 4000 + 100).astype(np.uint16)  # several strips
    path = write_dng(
        tmp_path / "f.dng", mosaic, "BGGR", 100, 4095, (0.6, 1.0, 0.7), np.eye(3), "unit · µ", "{}", 33.3, moment
    )
    (tags,) = exiftool(path)
    assert_valid(tags)
    assert tags["IFD0:Model"] == "unit ? ?"  # 7-bit ASCII: what it cannot hold is '?'
    with rawpy.imread(str(path)) as raw:
        np.testing.assert_array_equal(raw.raw_image, mosaic)
    if moment is not None:
        local = datetime(2026, 12, 31, 23, 59, 59)
        assert tags["ExifIFD:DateTimeOriginal"] == local.strftime("%Y:%m:%d %H:%M:%S")
    with pytest.raises(ValueError, match="no time zone"):
        write_dng(tmp_path / "g.dng", mosaic, "BGGR", 100, 4095, (1, 1, 1), np.eye(3), "u", "", 1.0, datetime.now())


# -- the frame's wall-clock time -----------------------------------------------------------------
def test_time_utc_is_stamped_when_the_frame_is_handed_over_and_read_back(sim_run: Path) -> None:
    sequence = read_sequence(sim_run / "sequence")
    times = [frame.captured_utc for frame in sequence.frames]
    assert all(t is not None and t.tzinfo is not None for t in times)
    assert times == sorted(times)  # handed over in capture order
    document = json.loads((sim_run / "sequence" / "sequence.json").read_text())
    assert all(f["time_utc"].endswith("Z") and len(f["time_utc"]) == 27 for f in document["frames"])
    assert datetime.now(UTC) - times[0] < timedelta(hours=1)


def test_a_malformed_time_utc_is_refused_naming_the_field(capsys, tmp_path: Path) -> None:
    sequence_dir = write_test_sequence(tmp_path / "seq")
    document = json.loads((sequence_dir / "sequence.json").read_text())
    assert document["frames"][0]["time_utc"]  # the writer stamped it
    document["frames"][2]["time_utc"] = "yesterday"
    (sequence_dir / "sequence.json").write_text(json.dumps(document))
    forget_digests(sequence_dir)
    status, _, err = run(capsys, "estimate", str(sequence_dir))
    assert status == 2
    assert "frames[2].time_utc is 'yesterday'; expected an ISO 8601 time with its zone" in err


# -- OME-TIFF ------------------------------------------------------------------------------------
def test_ome_tiff_has_the_acquisition_date_per_plane_delta_t_and_no_path(sim_run: Path) -> None:
    path = sim_run / "export" / "sequence.ome.tif"
    sequence = read_sequence(sim_run / "sequence")
    document = ome_types.from_tiff(path, validate=True)
    image = document.images[0]
    first = sequence.frames[0].captured_utc
    assert first is not None
    assert abs(image.acquisition_date - first) < timedelta(milliseconds=1)  # OME keeps milliseconds
    ticks = [frame.extra["timestamp_ns"] for frame in sequence.frames]
    expected = [(tick - ticks[0]) / 1e9 for tick in ticks]
    planes = image.pixels.planes
    assert [plane.delta_t for plane in planes] == pytest.approx(expected, abs=1e-9)
    assert all(plane.delta_t_unit.value == "s" for plane in planes)
    xml = document.to_xml()
    assert str(sim_run) not in xml and "/tmp" not in xml
    with tifffile.TiffFile(path) as tiff:
        assert tiff.is_ome
        assert ome_types.from_xml(tiff.ome_metadata) == document
        assert str(sim_run) not in tiff.ome_metadata
        np.testing.assert_array_equal(tiff.series[0].asarray()[0], sequence.load_frame(0))
    about = json.loads((sim_run / "export" / "spectra.json").read_text())
    assert about["sequence"] == "sequence" and str(sim_run) not in json.dumps(about)


def test_ome_delta_t_falls_back_to_the_wall_clock_without_camera_timestamps(capsys, tmp_path: Path) -> None:
    sequence_dir = write_test_sequence(tmp_path / "seq")  # written without timestamp_ns: time_utc only
    out = tmp_path / "ome"
    status, _, err = run(capsys, "export", str(sequence_dir), "--to", "ome-tiff", "--out", str(out))
    assert status == 0, err
    sequence = read_sequence(sequence_dir)
    image = ome_types.from_tiff(out / "sequence.ome.tif", validate=True).images[0]
    times = [frame.captured_utc for frame in sequence.frames]
    assert [p.delta_t for p in image.pixels.planes] == pytest.approx(
        [(t - times[0]).total_seconds() for t in times], abs=1e-6
    )
    notes = {
        m.k: m.value
        for m in ome_types.from_tiff(out / "sequence.ome.tif").structured_annotations.map_annotations[0].value.ms
    }
    assert "time_utc" in notes["delta_t_source"]


# -- EXR of a Bayer run --------------------------------------------------------------------------
def exr_readers(path: Path) -> tuple[oiio.ImageSpec, np.ndarray, dict]:
    """OpenImageIO's spec and pixels, and the OpenEXR bindings' header (channels checked to agree)."""
    image = oiio.ImageInput.open(str(path))
    assert image is not None, oiio.geterror()
    try:
        spec, pixels = image.spec(), np.asarray(image.read_image(0, 0, 0, 3, "float"))
    finally:
        image.close()
    with OpenEXR.File(str(path), separate_channels=True) as exr:
        channels = exr.channels()
        header = dict(exr.header())
        assert sorted(channels) == ["B", "G", "R"]
        np.testing.assert_array_equal(np.stack([channels[c].pixels for c in "RGB"], axis=-1), pixels)
    return spec, pixels, header


def test_every_exr_of_a_bayer_run_is_rgb_and_says_it_was_demosaicked(capsys, sim_run: Path, tmp_path: Path) -> None:
    sequence = read_sequence(sim_run / "sequence")
    weights = json.loads((sim_run / "flash-matching.json").read_text())["flash_weights"]
    flash_out, synth_out = tmp_path / "flash.exr", tmp_path / "synth.exr"
    status, _, err = run(
        capsys, "flash", str(sim_run), "--mode", "matching", "--method", "global", "--out", str(flash_out)
    )
    assert status == 0, err
    status, _, err = run(
        capsys, "synthesize", str(sim_run), "--weights", ",".join(map(str, weights)), "--out", str(synth_out)
    )
    assert status == 0, err
    files = [
        sim_run / "matching.exr",
        sim_run / "complementary.exr",
        sim_run / "export" / "matching.exr",
        sim_run / "export" / "ambient.exr",
        flash_out,
        synth_out,
    ]
    for path in files:
        spec, pixels, header = exr_readers(path)
        assert spec.channelnames == ("R", "G", "B"), path
        assert spec.getattribute("msflash:cfa") == "RGGB" and header["msflash:cfa"] == "RGGB"
        assert "bilinear" in header["msflash:demosaic"]
        assert "chromaticities" in header  # the camera's primaries, for the RGB it now is
        # The mosaic is every pixel's CFA channel of the file, exactly.
        channel = cfa_channel_map("RGGB", pixels.shape[:2])
        mosaic = np.take_along_axis(pixels, channel[..., None], axis=2)[..., 0]
        if path.name == "ambient.exr":
            expected, _ = sequence.load_linear_frame(sequence.indices("ambient")[0])
            np.testing.assert_allclose(mosaic, expected.astype(np.float32), rtol=1e-6)
    run_rgb = exr_readers(sim_run / "matching.exr")[1]
    export_rgb = exr_readers(sim_run / "export" / "matching.exr")[1]
    np.testing.assert_allclose(run_rgb, export_rgb, rtol=1e-5, atol=1e-6 * float(np.abs(run_rgb).max()))


# -- one number for each LED's wavelength ---------------------------------------------------------
def test_led_wavelengths_are_one_number_everywhere_and_the_names_derive_from_it(sim_run: Path) -> None:
    document = json.loads((sim_run / "sequence" / "sequence.json").read_text())
    names = [led["name"] for led in document["leds"]]
    peaks = [led["peak_nm"] for led in document["leds"]]
    assert names == [led_name(p) for p in peaks]  # the paper's LEDs, named by msflash from their peaks
    assert read_sequence(sim_run / "sequence").led_peaks_nm() == tuple(peaks)
    ome = ome_types.from_tiff(sim_run / "export" / "sequence.ome.tif")
    channels = {c.name.split(" ", 1)[1]: c.excitation_wavelength for c in ome.images[0].pixels.channels}
    assert [channels[name] for name in names] == peaks
    assert [
        c.light_source_settings.wavelength for c in ome.images[0].pixels.channels if c.light_source_settings
    ] == peaks
    for exr in (sim_run / "matching.exr", sim_run / "export" / "complementary.exr"):
        attribute = exr_readers(exr)[0].getattribute("msflash:led_peak_nm")
        assert list(attribute) == pytest.approx(peaks, abs=1e-4)  # float32 in the file
    dng = tifffile.TiffFile(sim_run / "export" / "001-led.dng")
    with dng:
        notes = json.loads(dng.pages[0].tags["ImageDescription"].value)
    assert notes["msflash:led_names"] == names and notes["msflash:led_peak_nm"] == peaks
    assert json.loads((sim_run / "export" / "spectra.json").read_text())["led_peak_nm"] == peaks
    assert json.loads((sim_run / "run.json").read_text())["led_peak_nm"] == peaks
    report = (sim_run / "report.html").read_text()
    assert all(f"<td>{p:.1f}</td>" in report for p in peaks)


def test_an_old_sequence_without_peaks_gets_them_from_its_spectra() -> None:
    sequence = read_sequence(BAYER_SAMPLE)
    assert all(led.peak_nm is None for led in sequence.leds)
    peaks = sequence.led_peaks_nm()
    grid = sequence.wavelengths_nm
    for led, peak in zip(sequence.leds, peaks, strict=True):
        top = grid[int(np.argmax(led.spd))]
        assert abs(peak - top) <= grid[1] - grid[0]  # within a sample of the largest, to 0.1 nm
        assert round(peak, 1) == peak


# -- the report links every export -----------------------------------------------------------------
def linked(report: Path) -> set[str]:
    import re

    return set(re.findall(r'href="([^"]+)"', report.read_text()))


def test_the_run_report_links_every_export_and_one_made_later(capsys, sim_run: Path, tmp_path: Path) -> None:
    run_copy = tmp_path / "run"
    shutil.copytree(sim_run, run_copy, symlinks=True)
    summary = json.loads((run_copy / "run.json").read_text())  # a copy: its run.json names the first folder
    exported = {f"export/{Path(f).name}" for f in summary["export"]["files"]}
    assert exported <= linked(sim_run / "report.html")
    assert {
        "export/000-ambient.dng",
        "export/sequence.ome.tif",
        "export/spectra.csv",
        "export/matching.exr",
    } <= exported
    status, _, err = run(capsys, "export", str(run_copy), "--to", "csv", "--out", str(run_copy / "later"))
    assert status == 0, err
    links = linked(run_copy / "report.html")
    assert {"later/spectra.csv", "later/spectra.json"} <= links and exported <= links
    assert all((run_copy / link).is_file() for link in links)
    assert json.loads((run_copy / "run.json").read_text())["exports"][0]["formats"] == ["csv"]
    # Elsewhere, the report is left as it was (it links only what lives in the run folder).
    status, _, err = run(capsys, "export", str(run_copy), "--to", "csv", "--out", str(tmp_path / "away"))
    assert status == 0 and "outside" not in err
    assert links == linked(run_copy / "report.html")


def test_utc_now_text_is_what_the_reader_accepts() -> None:
    text = utc_now_text()
    assert datetime.fromisoformat(text).tzinfo is not None
