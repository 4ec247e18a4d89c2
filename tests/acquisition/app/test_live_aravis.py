"""``msflash live`` on the ``aravis-fake`` rig: the real Aravis stream (BayerRG16 over GigE Vision on
127.0.0.1) debayered into the live preview, the booth emulator's levels set from the page's endpoint."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from types import ModuleType

import aiohttp
import pytest

from msflash.acquisition.app.live.in_thread import serve_in_thread
from msflash.acquisition.app.live.requests import bind
from msflash.acquisition.app.live.server import TOKEN_HEADER, LiveServer
from msflash.acquisition.session.rig import open_rig

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
