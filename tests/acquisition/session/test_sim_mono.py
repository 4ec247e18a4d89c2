"""The ``sim`` rig's monochrome sensor (``--cfa mono``): what a mono machine-vision camera sends, and what msflash
does with it.

The twin names its features as GenICam does (``PixelFormat`` ``Mono12``/``Mono8``, frames of one value a pixel).
The estimate takes one-channel frames end to end (the sequence records them as three identical channels, the
statistics take the one plane: ``acquisition.session.estimate_stream``), so ``capture`` and ``estimate`` run; the
flash matches or complements colours, which one channel does not see, so ``run`` and ``flash`` refuse in one line
(exit 2) naming the camera and what is expected, and ``synthesize`` writes its EXR without chromaticities.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.app.report import score_against_truth
from msflash.acquisition.devices.image_format import ImageFormatRequest
from msflash.acquisition.errors import CameraSettingError
from msflash.acquisition.plan import CapturePlan
from msflash.acquisition.sequence.reader import read_sequence
from msflash.acquisition.session import analysis
from msflash.acquisition.session.rig import open_sim_rig


def test_the_mono_sensor_sends_mono12_frames_and_names_its_formats_as_genicam_does() -> None:
    with open_sim_rig(cfa="mono", seed=4) as rig:
        camera = rig.camera
        info = camera.info
        assert (info.pixel_format, info.cfa, info.white_level) == ("Mono12", None, 4095)
        assert camera.image_limits().features["PixelFormat"].entries == ("Mono8", "Mono12")
        assert rig.mono and rig.sequence_header()[1].extra["channels"] == "Mono12 replicated to R, G, B"
        responsivity = rig.camera_responsivities.values
        assert np.array_equal(responsivity[:, 0], responsivity[:, 1]) and np.array_equal(
            responsivity[:, 0], responsivity[:, 2]
        )
        plan = CapturePlan.single((0.0,) * rig.led_spectra.count, 4000.0, role="ambient")
        frames = []
        for request in (None, ImageFormatRequest(pixel_format="Mono8")):
            if request is not None:
                camera.set_image_format(request)
            camera.prepare(plan)
            camera.start()
            camera.trigger()
            frames.append(camera.next_frame(5.0).pixels)
            camera.stop()
        twelve, eight = frames
        assert twelve.shape == eight.shape == (info.height, info.width)
        assert twelve.dtype == np.uint16 and 240 < np.median(twelve) and twelve.max() <= 4095
        assert eight.dtype == np.uint8 and camera.info.white_level == 255
        with pytest.raises(
            CameraSettingError, match="pixel format BayerRG12: not offered by this camera; expected one of Mono8"
        ):
            camera.set_image_format(ImageFormatRequest(pixel_format="BayerRG12"))


def test_run_refuses_a_mono_camera_in_one_line_before_any_capture(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "run"
    assert main(["run", "--rig", "sim", "--cfa", "mono", "--out", str(out)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    error = [line for line in lines if line.startswith("msflash: error:")]
    assert len(error) == 1 and "camera SimulatedCamera (NikonD100 mono) sends Mono12" in error[0]
    assert "expected a colour camera (a Bayer or RGB pixel format)" in error[0]
    assert not any("captured step" in line for line in lines) and not (out / "sequence").exists()


def test_a_mono_sequence_is_captured_and_estimated_and_the_flash_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "capture"
    assert main(["capture", "--rig", "sim", "--cfa", "mono", "--out", str(out)]) == 0
    sequence = read_sequence(out / "sequence")
    frame = sequence.load_frame(0)
    assert frame.shape[2] == 3 and np.array_equal(frame[:, :, 0], frame[:, :, 2])  # format v1: three alike channels
    estimate = analysis.estimate_sequence(sequence)
    with open_sim_rig(cfa="mono") as rig:
        truth = rig.true_ambient
    score = score_against_truth(sequence, estimate, truth)
    # The one channel determines the ambient about as well as the LEDs allow (0.187 against a 0.192 bound; the RGB
    # mosaic's run 0.182).
    assert score["spectrum_rmse_vs_truth"] < 1.1 * score["spectrum_rmse_led_bound"], score
    capsys.readouterr()
    for mode in ("matching", "complementary"):
        assert main(["flash", str(out / "sequence"), "--mode", mode, "--method", "global"]) == 2
        error = capsys.readouterr().err.strip()
        assert error.count("\n") == 0 and "camera SimulatedCamera (NikonD100 mono) is mono" in error
        assert "expected a colour camera's sequence" in error
    image = tmp_path / "flash.exr"
    assert (
        main(["synthesize", str(out / "sequence"), "--weights", "0.5,0.5,0.5,0.5,0.5,0.5,0.5", "--out", str(image)])
        == 0
    )
    import OpenImageIO as oiio

    spec = oiio.ImageInput.open(str(image)).spec()  # an independent reader of the EXR
    source = spec.getattribute("msflash:chromaticities_source")
    assert source.startswith("none (the camera's R, G and B responsivities are not independent")
    assert json.loads(spec.getattribute("ImageDescription"))["msflash:chromaticities_source"] == source
    assert spec.getattribute("chromaticities") is None


def test_the_live_view_refuses_to_fire_a_sequence_on_a_mono_camera(tmp_path: Path) -> None:
    """The page's ``POST /api/sequence`` on a mono camera: 400 with the run's one line, no run folder, nothing lit."""
    import asyncio

    import aiohttp

    from msflash.acquisition.app.live.requests import bind
    from msflash.acquisition.app.live.server import TOKEN_HEADER, LiveServer
    from tests.acquisition.support.live import emulator_levels, serve_in_thread

    async def fire(url: str, token: str) -> tuple[int, str]:
        async with aiohttp.ClientSession() as session:
            async with session.post(url, headers={TOKEN_HEADER: token}, json={"mode": "matching"}) as response:
                return response.status, await response.text()

    sock = bind("127.0.0.1", 0)
    try:
        with open_sim_rig(cfa="mono") as rig:
            server = LiveServer(rig, tmp_path / "runs", sock)
            with serve_in_thread(server):
                status, text = asyncio.run(fire(f"http://127.0.0.1:{server.port}/api/sequence", server.token))
                assert status == 400, text
                assert "camera SimulatedCamera (NikonD100 mono) sends Mono12" in text and "\n" not in text.strip()
                assert server.state.job.status == "idle" and emulator_levels(server) == (0.0,) * 7
    finally:
        sock.close()
    assert not any((tmp_path / "runs").glob("*/sequence"))
