"""What a run records of the camera after the live view changed its format (``POST /api/camera-format``).

Each sequence's camera entry is read afresh from the camera (size, pixel format, levels); the rig's own record
(``camera.extra``: the format set after it opened, the options it was opened with, whether frames are mono) follows
the change too (:meth:`acquisition.session.rigs.rig.Rig.image_format_changed`). A sim rig served by the live view
(its booth emulator on a pty) and the Aravis GigE fake at 127.0.0.1.
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from types import ModuleType
from typing import Any

import aiohttp
import pytest

from msflash.acquisition.app.live.server import TOKEN_HEADER
from msflash.acquisition.devices.image_format import ImageFormatRequest
from msflash.acquisition.errors import UsageError
from msflash.acquisition.session.live import LiveStream
from tests.acquisition.support.live import live_server, wait_until


def post(url: str, token: str, body: dict[str, Any]) -> tuple[int, str]:
    async def go() -> tuple[int, str]:
        async with aiohttp.ClientSession() as session:
            async with session.post(url, headers={TOKEN_HEADER: token}, json=body) as response:
                return response.status, await response.text()

    return asyncio.run(go())


def get(url: str) -> str:
    async def go() -> str:
        async with aiohttp.ClientSession() as session:
            async with session.get(url) as response:
                return await response.text()

    return asyncio.run(go())


def test_a_live_sequence_after_a_format_change_records_the_format_in_force(tmp_path: Path) -> None:
    """ROI and pixel format set from the page, then a sequence: its camera entry and ``camera.extra`` say the
    format in force (before, ``camera.extra`` said nothing of the change); a refused change records nothing new."""
    runs = tmp_path / "runs"
    with live_server(runs) as server:
        base, token = f"http://127.0.0.1:{server.port}", server.token
        status, text = post(base + "/api/camera-format", token, {"roi": [8, 4, 32, 20], "pixel_format": "BayerRG8"})
        assert status == 200, text
        status, text = post(base + "/api/camera-format", token, {"roi": [0, 0, 50, 20]})  # Width in steps of 8
        assert status == 400 and "Width 50 refused" in text
        status, text = post(base + "/api/sequence", token, {"mode": "matching"})
        assert status == 202, text
        run = json.loads(text)["run"]

        def finished() -> dict | None:
            job = json.loads(get(base + "/api/state"))["job"]
            return job if job["status"] in ("done", "failed") else None

        job = wait_until(finished, "the sequence to finish", timeout_s=240)
        assert job["status"] == "done", job
    camera = json.loads((runs / run / "sequence" / "sequence.json").read_text())["camera"]
    assert camera["pixel_format"] == "BayerRG8" and camera["white_level"] == 255
    assert camera["image_format"] == {  # camera.extra, at the camera entry's top level (format v1)
        "roi": [8, 4, 32, 20],
        "binning": [1, 1],
        "pixel_format": "BayerRG8",
        "set": "after the rig opened (live view)",
    }


@pytest.mark.aravis
def test_the_options_the_rig_opened_with_give_way_to_the_format_set_after(aravis: ModuleType) -> None:
    """The GigE fake opened with ``--roi`` and a ``--feature``: after the live view's change the recorded options
    keep the gain and the feature, drop the ROI they no longer hold, and a Mono16 → RGB8 change makes the rig
    record its frames as the colour frames they are (not as mono frames replicated to R, G, B)."""
    from msflash.acquisition.devices.aravis.camera_features import CameraOptions
    from msflash.acquisition.session.rigs.aravis_fake import open_aravis_fake_rig

    options = CameraOptions(roi=(0, 0, 32, 24), features=(("AcquisitionFrameRate", "25"),))
    with open_aravis_fake_rig(rendered=False, camera_options=options) as rig:
        assert rig.mono
        opened = rig.sequence_header()[1].extra
        assert opened["camera_options"]["read_back"]["roi"] == [0, 0, 32, 24]
        assert opened["channels"] == "Mono16 replicated to R, G, B"
        stream = LiveStream(rig)
        with pytest.raises(UsageError, match="Width"):
            stream.set_image_format(ImageFormatRequest(roi=(0, 0, 10_000, 24)))
        assert rig.sequence_header()[1].extra == opened  # refused: nothing changed, nothing recorded
        stream.set_image_format(ImageFormatRequest(roi=(16, 8, 48, 32), pixel_format="RGB8"))
        camera = rig.sequence_header()[1]
        assert (camera.pixel_format, camera.cfa) == ("RGB8", None)
        assert not rig.mono and "channels" not in camera.extra
        assert camera.extra["image_format"]["roi"] == [16, 8, 48, 32]
        assert camera.extra["image_format"]["pixel_format"] == "RGB8"
        recorded = camera.extra["camera_options"]
        assert "roi" not in recorded["requested"] and "roi" not in recorded["read_back"]
        assert recorded["requested"]["features"] == {"AcquisitionFrameRate": "25"}
        assert "AcquisitionFrameRate" in recorded["read_back"]["features"]
        assert camera.extra["gain"] == opened["gain"]
