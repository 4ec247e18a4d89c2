"""A test-pattern camera switched to a Bayer pixel format is recorded as the raw mosaic it sends.

The Aravis fakes offer BayerBG8/GB8/GR8/RG8 beside Mono and RGB. Before, the ``aravis-fake`` rig's test-pattern
form (``rendered=False``) recorded a Bayer format with ``cfa`` null and not as mono, so the writer refused its
(H, W) frames ("pixels have 1 channel but camera.cfa is null") and nothing was captured. What a pixel format
means (mosaic layout, bit depth, mono / mosaic / RGB) is now read from one table
(:data:`acquisition.devices.aravis.pixel_layouts.PIXEL_FORMATS`) on every path that sets it: at open, from the
command line's ``--pixel-format``, and a live change. The real fakes only: the GigE fake at 127.0.0.1 and the
in-process ``Fake_1`` on the Fake interface (nothing is broadcast).
"""

from __future__ import annotations

import re
from pathlib import Path
from types import ModuleType

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.devices.image_format import ImageFormatRequest
from msflash.acquisition.plan import CapturePlan, CaptureStep
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session.capture import run_capture
from msflash.acquisition.session.live import LiveStream
from msflash.acquisition.session.rigs.rig import Rig
from tests.acquisition.support.hw_rig import fake_camera_capture

pytestmark = pytest.mark.aravis

LEVELS = [(0.0,) * 7] + [tuple(1.0 if j == i else 0.0 for j in range(7)) for i in range(7)]


def _record(rig: Rig, directory: Path) -> None:
    """An ambient frame and one frame per LED, host paced, written as the rig records them."""
    plan = CapturePlan(
        tuple(CaptureStep(i, "led" if any(lv) else "ambient", lv, 1_000.0) for i, lv in enumerate(LEVELS)),
        trigger="software",
    )
    with rig.sequence_writer(directory) as writer:
        run_capture(rig.camera, rig.booth, plan, writer)


def _assert_raw_mosaic(directory: Path, pixel_format: str, cfa: str, shape: tuple[int, int]) -> None:
    sequence = read_sequence(directory)
    camera = sequence.camera
    assert sequence.complete and len(sequence.frames) == 8
    assert (camera.pixel_format, camera.cfa, camera.white_level) == (pixel_format, cfa, 255.0)
    assert "channels" not in camera.extra  # not recorded as mono frames replicated to R, G, B
    frame = sequence.load_frame(0)
    assert frame.shape == shape and 0 < frame.max() <= 255  # 8-bit samples, one per pixel


@pytest.mark.parametrize(("pixel_format", "cfa"), [("BayerGR8", "GRBG"), ("BayerBG8", "BGGR")])
def test_the_gige_fakes_pattern_in_bayer_is_recorded_as_a_mosaic(
    aravis: ModuleType, tmp_path: Path, pixel_format: str, cfa: str
) -> None:
    """Set at open: the camera, the rig and the sequence say mosaic, with the format's own layout."""
    from msflash.acquisition.session.rigs.aravis_fake import open_aravis_fake_rig

    with open_aravis_fake_rig(rendered=False, pixel_format=pixel_format) as rig:
        info = rig.camera.info
        assert (info.pixel_format, info.cfa, info.white_level) == (pixel_format, cfa, 255.0)
        assert not rig.mono
        _record(rig, tmp_path / "s")
    _assert_raw_mosaic(tmp_path / "s", pixel_format, cfa, (48, 64))


def test_a_live_change_to_bayer_is_recorded_as_a_mosaic(aravis: ModuleType, tmp_path: Path) -> None:
    """Mono16 at open, BayerGB8 from the live page, then back to Mono8: each sequence records what is in force."""
    from msflash.acquisition.session.rigs.aravis_fake import open_aravis_fake_rig

    with open_aravis_fake_rig(rendered=False) as rig:
        assert rig.mono
        stream = LiveStream(rig)
        stream.set_image_format(ImageFormatRequest(pixel_format="BayerGB8"))
        assert not rig.mono and rig.sequence_header()[1].cfa == "GBRG"
        _record(rig, tmp_path / "bayer")
        stream.set_image_format(ImageFormatRequest(pixel_format="Mono8"))
        camera = rig.sequence_header()[1]
        assert rig.mono and camera.cfa is None and camera.extra["channels"] == "Mono8 replicated to R, G, B"
    _assert_raw_mosaic(tmp_path / "bayer", "BayerGB8", "GBRG", (48, 64))


def test_the_fake_interfaces_camera_in_bayer_from_the_command_line(
    aravis: ModuleType, hw_calibration: Path, hw_booth_port: str, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """``--pixel-format BayerRG8`` on the hardware rig (``Fake_1``): a raw RGGB sequence that ``read_sequence``
    and ``msflash estimate`` take as a mosaic. The fake's Bayer test pattern saturates a sample of nearly every
    2 × 2 cell at any exposure and ignores the LEDs, so the estimate refuses its data (one line, exit 2) — the
    mosaic got as far as the estimator's saturation check, not refused for its format."""
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    out = tmp_path / "c"
    options = ("--calibration", str(hw_calibration), "--exposure", "10000", "--pixel-format", "BayerRG8")
    assert main([*fake_camera_capture(hw_booth_port, *options, "--roi", "0,0,64,48"), "--out", str(out)]) == 0
    _assert_raw_mosaic(out / "sequence", "BayerRG8", "RGGB", (48, 64))
    capsys.readouterr()
    assert main(["estimate", str(out / "sequence"), "--json"]) == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert error.startswith("msflash: error: frame stack: only ") and "saturated" in error


@pytest.mark.parametrize(
    ("pixel_format", "expected"),
    [
        ("YUV422_8", r"camera Aravis Fake \(serial MSFRIG01\): pixel format 'YUV422_8' is not one msflash decodes"),
        ("BayerGR8", r"aravis-fake: pixel format BayerGR8 has CFA GRBG; expected RGGB, the rendered mosaic's"),
    ],
)
def test_a_format_set_by_feature_is_checked_at_open(
    aravis: ModuleType, tmp_path: Path, capsys: pytest.CaptureFixture, pixel_format: str, expected: str
) -> None:
    """``--feature PixelFormat=…`` is applied after the rig's own format: a format msflash does not decode (the
    GigE fake offers YUV422_8, as colour cameras do) and, on the rendered scene, another mosaic's layout are each
    refused in one line naming the camera and the format (exit 2), before any frame — not recorded as what they
    are not."""
    out = tmp_path / "c"
    status = main(["capture", "--rig", "aravis-fake", "--feature", f"PixelFormat={pixel_format}", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and re.match(f"msflash: error: {expected}", err[-1]), err[-3:]
    assert not (out / "sequence" / "sequence.json").exists()


@pytest.mark.parametrize(
    ("pixel_format", "expected"),
    [
        (
            "YUV422_8",
            r"camera Fake \(serial 1\): pixel format 'YUV422_8' is not one msflash decodes; expected one of Mono8, .*BayerBG12Packed$",
        ),
        ("BayerRG16", r"camera Fake \(serial 1\): PixelFormat 'BayerRG16' is not offered by this camera; expected "),
    ],
)
def test_the_command_lines_pixel_format_is_checked_against_the_one_table(
    aravis: ModuleType,
    hw_calibration: Path,
    hw_booth_port: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture,
    pixel_format: str,
    expected: str,
) -> None:
    """``--pixel-format`` on the hardware rig: a name msflash does not decode, or one the camera does not offer,
    is one line naming the camera and the format (exit 2), before the booth is opened."""
    from tests.acquisition.support.fake_genicam import use_fake_genicam

    use_fake_genicam(None)
    options = ("--calibration", str(hw_calibration), "--pixel-format", pixel_format, "--out", str(tmp_path / "c"))
    status = main(fake_camera_capture(hw_booth_port, *options))
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and re.match(f"msflash: error: {expected}", err[-1]), err[-3:]
