"""The live preview (:mod:`acquisition.app.live.preview`) and stream (:mod:`acquisition.session.live`) on a sim rig."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from PIL import Image

from msflash.acquisition.app.live.preview import HISTOGRAM_BINS, OVERLAY_RGB, PREVIEW_WIDTH, PreviewRenderer
from msflash.acquisition.devices.camera import CameraInfo
from msflash.acquisition.errors import UsageError
from msflash.acquisition.session.live import LiveStream
from msflash.acquisition.session.rig import open_rig
from msflash.processing.sensor import cfa_channel_map


def info(cfa: str | None) -> CameraInfo:
    return CameraInfo("test", "test", "1", "BayerRG16" if cfa else "RGB16", cfa, 100.0, 4195.0, 64, 48)


def decoded(jpeg: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(jpeg)).convert("RGB"))


def test_a_mosaic_is_debayered_scaled_to_640_and_its_saturation_painted() -> None:
    renderer = PreviewRenderer(info("RGGB"), None)
    mosaic = np.full((48, 64), 1100, dtype=np.uint16)  # a quarter of full scale above black
    mosaic[:8, :8] = 4195  # a saturated corner: 4×4 superpixels
    preview = renderer.render(mosaic)
    image = decoded(preview.jpeg)
    assert (preview.width, preview.height) == (PREVIEW_WIDTH, 480) == (image.shape[1], image.shape[0])
    assert preview.saturated_fraction == pytest.approx(16 / (24 * 32))
    assert np.allclose(image[10, 10], OVERLAY_RGB, atol=40)  # the corner, magenta
    assert abs(int(image[300, 400, 0]) - int(image[300, 400, 1])) < 12  # grey elsewhere (no colour matrix)
    assert [sum(channel) for channel in preview.histogram] == [24 * 32] * 3
    assert all(len(channel) == HISTOGRAM_BINS for channel in preview.histogram)
    plain = decoded(renderer.render(mosaic, overlay=False).jpeg)
    assert plain[10, 10].min() > 200  # without the overlay the corner is white


def test_the_stream_follows_exposure_and_the_booths_levels() -> None:
    with open_rig("sim") as rig:
        stream = LiveStream(rig)
        renderer = PreviewRenderer(rig.camera.info, rig.camera_responsivities)
        try:
            dark = stream.grab().pixels.astype(float).mean()
            stream.set_exposure(stream.settings.exposure_us * 2, 1.0)
            brighter = stream.grab().pixels.astype(float).mean()
            assert brighter > 1.5 * dark - rig.camera.info.black_level
            reported = stream.set_levels([0, 0, 0, 1.0, 0, 0, 0])
            assert reported == pytest.approx((0, 0, 0, 1.0, 0, 0, 0), abs=1e-4)
            assert rig.emulator is not None and rig.emulator.levels[3] == pytest.approx(1.0, abs=1e-4)
            lit = stream.grab().pixels.astype(float)
            info = rig.camera.info
            assert info.cfa == "RGGB" and lit.shape == (info.height, info.width)  # the sim camera's raw mosaic
            green = cfa_channel_map(info.cfa, lit.shape) == 1
            assert lit[green].mean() > brighter  # led520 lights the green samples
            assert renderer.render(lit.astype(np.uint16)).width == 640
            with pytest.raises(UsageError, match="levels"):
                stream.set_levels([2.0] * 7)
            with pytest.raises(UsageError, match="exposure_us"):
                stream.set_exposure(-1.0, 1.0)
            with pytest.raises(UsageError, match="gain"):
                stream.set_exposure(1000.0, 0.0)
        finally:
            stream.pause()
            stream.all_off()
        assert rig.emulator.levels == (0.0,) * 7


def test_the_live_bench_reports_the_preview_paths_rates(capsys) -> None:
    from msflash.acquisition.app import cli

    assert cli.main(["bench", "--part", "live", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)["live"]
    assert report["preview_size"] == [PREVIEW_WIDTH, 606] and report["frame_shape"] == [106, 112]  # a raw mosaic
    assert report["preview_fps"] > 0 and report["grab_fps"] > 0 and report["target_fps"] == 10
    assert report["preview_fps_over_target"] == pytest.approx(report["preview_fps"] / 10, abs=0.01)
    assert 0 < report["preview_over_grab"]  # a figure, not a verdict: speed is read from the bench
    flash = report["flash_preview"]  # issue 33 item 2: mixes synthesised + rendered per second at 640 px
    assert flash["preview_size"][0] == PREVIEW_WIDTH and flash["sensor"] == [2048, 2448]
    assert flash["mix_preview_fps"] > 0 and flash["synthesis_fps"] > 0 and flash["target_fps"] == 15
    assert flash["mix_preview_fps_over_target"] == pytest.approx(flash["mix_preview_fps"] / 15, abs=0.01)
