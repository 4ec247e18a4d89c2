"""``msflash live`` on the ``aravis-fake`` rig: the real Aravis stream (BayerRG16 over GigE Vision on
127.0.0.1) debayered into the live preview, the booth emulator's levels set from the page's endpoint."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from types import ModuleType

import aiohttp
import pytest

from msflash.acquisition.app.live.requests import bind
from msflash.acquisition.app.live.server import TOKEN_HEADER, LiveServer
from msflash.acquisition.session.rig import open_rig
from tests.acquisition.support.live import serve_in_thread

pytestmark = pytest.mark.aravis


def test_the_fakes_mosaic_streams_as_a_colour_preview_and_the_levels_reach_the_booth(
    aravis: ModuleType, tmp_path: Path
) -> None:
    sock = bind("127.0.0.1", 0)
    with open_rig("aravis-fake") as rig:
        assert rig.camera.info.cfa == "RGGB"
        server = LiveServer(rig, tmp_path / "runs", sock)
        base = f"http://127.0.0.1:{server.port}"
        with serve_in_thread(server):

            async def watch() -> list[dict]:
                headers = []
                async with aiohttp.ClientSession() as session:
                    async with session.ws_connect(f"{base}/ws?token={server.token}") as ws:
                        assert (await ws.receive_json())["state"]["rig"] == "aravis-fake"
                        async with session.post(
                            base + "/api/levels",
                            headers={TOKEN_HEADER: server.token},
                            json={"channel": 6, "level": 1.0},
                        ) as response:
                            assert response.status == 200
                        while len(headers) < 3:
                            message = await ws.receive()
                            if message.type == aiohttp.WSMsgType.BINARY:
                                length = int.from_bytes(message.data[:4], "little")
                                headers.append(json.loads(message.data[4 : 4 + length]))
                return headers

            headers = asyncio.run(watch())
            assert rig.emulator is not None and rig.emulator.levels[6] == pytest.approx(1.0, abs=1e-4)
            assert all(h["width"] == 640 and h["height"] == round(93 * 640 / 100) for h in headers)
            red, green, _blue = (sum(i * n for i, n in enumerate(c)) / sum(c) for c in headers[-1]["histogram"])
            assert red > green  # led660 at full drive lights the red channel most
        assert tuple(rig.emulator.levels) == (0.0,) * 7  # the server stopped: LEDs off before the rig closes
    sock.close()


def test_the_fakes_roi_and_depth_from_the_page_and_what_its_scene_cannot_follow_refused(
    aravis: ModuleType, tmp_path: Path
) -> None:
    """The GigE fake's own limits (Width 1 … its sensor, binning 1 … 16), the rendered scene read out at its ROI and
    depth; binning and a non-RGGB format refused with the reason (the fake keeps its frame size when it bins)."""
    sock = bind("127.0.0.1", 0)
    with open_rig("aravis-fake") as rig:
        server = LiveServer(rig, tmp_path / "runs", sock)
        base = f"http://127.0.0.1:{server.port}"
        with serve_in_thread(server):

            async def go() -> tuple[list[tuple[int, str]], list[dict]]:
                replies, headers = [], []
                async with aiohttp.ClientSession() as session:
                    async with session.ws_connect(f"{base}/ws?token={server.token}") as ws:
                        for body in ({"roi": [8, 4, 48, 40], "pixel_format": "BayerRG8"}, {"binning": [2, 2]}):
                            async with session.post(
                                base + "/api/camera-format", headers={TOKEN_HEADER: server.token}, json=body
                            ) as response:
                                replies.append((response.status, await response.text()))
                        async with session.post(
                            base + "/api/camera-format",
                            headers={TOKEN_HEADER: server.token},
                            json={"pixel_format": "Mono8"},
                        ) as response:
                            replies.append((response.status, await response.text()))
                        while len(headers) < 40 and not (headers and headers[-1].get("raw_size") == [48, 40]):
                            message = await ws.receive()
                            if message.type == aiohttp.WSMsgType.BINARY:
                                length = int.from_bytes(message.data[:4], "little")
                                headers.append(json.loads(message.data[4 : 4 + length]))
                return replies, headers

            replies, headers = asyncio.run(go())
            assert replies[0][0] == 200, replies[0]
            assert json.loads(replies[0][1])["camera_format"]["summary"] == "BayerRG8 · 48 × 40 px"
            assert replies[1][0] == 400 and "keeps its frame size when it bins" in replies[1][1]
            assert replies[2][0] == 400 and "the rendered scene is a RGGB mosaic" in replies[2][1]
            assert headers[-1]["raw_size"] == [48, 40]  # the fake streams the ROI, the scene rendered into it
            assert server._last_raw is not None and server._last_raw.pixels.dtype.name == "uint8"
    sock.close()
