"""The rig's controls from the page: exposure and gain, LED levels, all off, ROI/binning/pixel format, reconnect after
a device error, a snapshot and the pixel readout (``/api/settings``, ``/api/levels``, ``/api/leds-off``,
``/api/camera-format``, ``/api/reconnect``, ``/api/snapshot``, ``/api/pixel``).

Each change runs on the rig thread; a value the camera or the booth refuses is a 400 with its one-line reason
(nothing switched off); the camera's format changes between frames (:meth:`LiveStream.set_image_format`) and the
preview, readout and page follow what it reads back.
"""

from __future__ import annotations

import asyncio
from typing import Any

import numpy as np
from aiohttp import web

from msflash.acquisition.app.live.camera_format import format_request
from msflash.acquisition.app.live.core import LiveCore
from msflash.acquisition.app.live.preview import Preview
from msflash.acquisition.app.live.requests import boolean, finite, json_object, number, refuse
from msflash.acquisition.app.live.snapshots import write_snapshot
from msflash.acquisition.errors import UsageError


class RigControls(LiveCore):
    """The requests that set the camera and the booth."""

    async def _post_settings(self, request: web.Request) -> web.Response:
        body = await json_object(request)
        if "overlay" in body:
            self.state.overlay = boolean(body, "overlay")
        if "sequence_exposure" in body:
            if body["sequence_exposure"] not in ("auto", "live"):
                raise UsageError(f"sequence_exposure {body['sequence_exposure']!r}: expected 'auto' or 'live'")
            self.state.sequence_exposure = body["sequence_exposure"]
        if "mode" in body:
            if body["mode"] not in ("complementary", "matching"):
                raise UsageError(f"mode {body['mode']!r}: expected 'complementary' or 'matching'")
            self.state.mode = body["mode"]
        if "exposure_us" in body or "gain" in body:
            self._busy()
            settings = self.stream.settings
            exposure = number(body, "exposure_us", settings.exposure_us)
            gain = number(body, "gain", settings.gain)
            await self._on_rig(self.stream.set_exposure, exposure, gain)
        self.state.error = None
        await self._push_state()
        return web.json_response(self.state_json())

    async def _post_reconnect(self, request: web.Request) -> web.Response:
        """After a camera or booth error: take one frame now (the stream prepared afresh); its failure is 503 with
        the reason (the error state stays), its success clears the error and the live stream goes on."""
        await json_object(request)
        self._busy()
        try:
            preview = await self._on_rig(self._reconnect)
        except Exception as err:  # noqa: BLE001 - still failing: LEDs off, the reason to the page
            await self._fail(err)
            return refuse(503, f"still failing: {err}")
        self.state.error = self.state.error_source = None
        await self._send_frame(preview, source="live")
        await self._push_state()
        return web.json_response(self.state_json())

    def _reconnect(self) -> Preview:
        self.stream.pause()
        return self._grab()

    async def _post_camera_format(self, request: web.Request) -> web.Response:
        """``{"roi": [x, y, w, h]}``, ``{"binning": [h, v]}``, ``{"pixel_format": name}``: set between frames (the
        stream stops, the camera takes it, the next frame streams at the new size); refused: 400 with the camera's
        one-line reason, nothing else changed."""
        body = await json_object(request)
        self._busy()
        image_request = format_request(body)
        await self._on_rig(self._set_camera_format, image_request)
        self.state.error = None
        await self._push_state()
        return web.json_response(self.state_json())

    def _set_camera_format(self, request: Any) -> None:
        """Set the format on the rig thread; the preview, readout and page follow what the camera reads back."""
        before = self.rig.camera.info
        try:
            self.stream.set_image_format(request)
        finally:
            after = self.rig.camera.info
            if after != before:  # a refusal changed nothing: the last frame still stands
                self._camera_changed(after)

    async def _post_levels(self, request: web.Request) -> web.Response:
        body = await json_object(request)
        self._busy()
        levels = list(self.stream.settings.levels)
        if "levels" in body:
            given = body["levels"]
            if not isinstance(given, list):
                raise UsageError("levels: expected a list of numbers in [0, 1], one per LED")
            levels = [number({"levels": v}, "levels", 0.0) for v in given]
        else:
            channel = body.get("channel")
            if not isinstance(channel, int) or isinstance(channel, bool) or not 0 <= channel < len(levels):
                raise UsageError(f"channel {channel!r}: expected an LED index 0–{len(levels) - 1}")
            if "level" not in body:  # a slider message without its value must not switch the LED off
                raise UsageError(f"level for channel {channel}: missing; expected a number in [0, 1]")
            levels[channel] = number(body, "level", 0.0)
        await self._on_rig(self.stream.set_levels, levels)
        self.state.error = None
        await self._push_state()
        return web.json_response(self.state_json())

    async def _post_leds_off(self, _request: web.Request) -> web.Response:
        self._busy()
        await self._on_rig(self.stream.all_off)
        await self._push_state()
        return web.json_response(self.state_json())

    async def _post_snapshot(self, request: web.Request) -> web.Response:
        """The last live frame as a raw TIFF and an sRGB PNG in the runs folder's ``snapshots/``."""
        await json_object(request)
        frame = self._last_raw
        if frame is None:
            raise UsageError("no live frame yet; expected a page watching the stream")
        rgb = self.renderer.camera_rgb(frame.pixels)
        settings = self.stream.settings
        metadata = {
            "camera": self.camera_model,
            "exposure_us": frame.exposure_us,
            "gain": frame.gain,
            "levels": dict(zip(self.rig.led_spectra.names, settings.levels)),
            "timestamp_ns": frame.timestamp_ns,
        }
        tiff, png = await asyncio.get_running_loop().run_in_executor(
            None, write_snapshot, self.runs / "snapshots", frame.pixels, self.renderer.srgb8(rgb), metadata
        )
        return web.json_response({"tiff": str(tiff.relative_to(self.runs)), "png": str(png.relative_to(self.runs))})

    async def _get_pixel(self, request: web.Request) -> web.Response:
        """``?view=live|mix&x=&y=`` (fractions of the image, 0–1): the raw values per channel there."""
        view = request.query.get("view", "live")
        if view not in ("live", "mix"):
            raise UsageError(f"view {view[:40]!r}: expected 'live' or 'mix'")
        fractions = []
        for key in ("x", "y"):
            try:
                value = float(request.query.get(key, ""))
            except ValueError:
                value = float("nan")
            if not 0.0 <= value <= 1.0:
                raise UsageError(
                    f"{key} {request.query.get(key, '')[:40]!r}: expected a fraction of the image in [0, 1]"
                )
            fractions.append(value)
        values: np.ndarray | None
        if view == "live":
            frame = self._last_raw
            if frame is None:
                raise UsageError("no live frame yet; expected a page watching the stream")
            values, cfa, unit = frame.pixels, self.renderer.cfa, "DN"
        else:
            values = self._last_mix_linear
            if values is None or self.mix is None:
                raise UsageError("no synthesised image yet; expected a fired sequence first")
            cfa, unit = self.mix.cfa, "DN per µs·gain"
        return web.json_response(finite(pixel_readout(values, cfa, fractions[0], fractions[1], unit)))


def pixel_readout(values: np.ndarray, cfa: str | None, x: float, y: float, unit: str) -> dict[str, Any]:
    """The values per channel at fractions ``x``, ``y`` of an image: a mosaic's 2×2 cell (``R``, ``G``, ``G``, ``B``
    as its CFA lays them), an RGB pixel's three channels or a mono pixel's one; with the sample's position."""
    height, width = values.shape[:2]
    if values.ndim == 2 and cfa is not None:
        row = min(int(y * (height // 2)), height // 2 - 1) * 2
        column = min(int(x * (width // 2)), width // 2 - 1) * 2
        cell = values[row : row + 2, column : column + 2].reshape(-1)
        channels = [{"channel": name, "value": float(value)} for name, value in zip(cfa, cell)]
    else:
        row, column = min(int(y * height), height - 1), min(int(x * width), width - 1)
        pixel = np.atleast_1d(values[row, column])
        names = "RGB" if pixel.size == 3 else ["mono"] if pixel.size == 1 else [str(i) for i in range(pixel.size)]
        channels = [{"channel": name, "value": float(value)} for name, value in zip(names, pixel)]
    return {"row": row, "column": column, "unit": unit, "channels": channels}
