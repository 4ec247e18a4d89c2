"""The flash before it fires (issue 33 item 2): the last sequence's frames synthesised under the page's mix, presets,
and Fire with exactly the mix shown (``POST /api/mix``, ``POST /api/mix-fire``).

Synthesis runs off the rig thread (:mod:`acquisition.app.live.mix_preview`: ``msflash synthesize``'s numbers on the
preview's samples); a newer mix replaces one not yet rendered. Firing a mix takes one frame on the rig thread at
the run's ambient exposure and gain and compares it with the synthesis, refused when the camera's format is no
longer the run's.
"""

from __future__ import annotations

import asyncio
import logging

import numpy as np
from aiohttp import web

from msflash.acquisition.app.live.core import LiveCore
from msflash.acquisition.app.live.mix_preview import MixPreview, preview_samples
from msflash.acquisition.app.live.requests import finite, json_object
from msflash.acquisition.app.live.runs import list_runs, run_folder
from msflash.acquisition.app.live.snapshots import write_snapshot
from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.errors import UsageError
from msflash.acquisition.session.exposure import whole_pwm_periods
from msflash.processing.synthesis import linearise

log = logging.getLogger(__name__)


class FlashPreviewRoutes(LiveCore):
    """The flash preview's requests and its rendering loop."""

    async def _load_mix(self, run: str) -> None:
        folder = run_folder(self.runs, run)
        if folder is None:
            raise UsageError(f"run {run[:80]!r}: no such run in {self.runs}")
        renderer = self.renderer
        mix = await asyncio.get_running_loop().run_in_executor(None, MixPreview.from_run, folder, renderer)
        self.mix, self.mix_capture = mix, None
        self._view_frames.pop("mix-capture", None)
        self.mix_levels = mix.solved.get(self.state.mode, (0.0,) * len(mix.led_names))
        ambient = await asyncio.get_running_loop().run_in_executor(None, mix.image, (0.0,) * len(mix.led_names))
        await self._send_frame(ambient.preview, source=f"ambient of {mix.run}", view="mix-ambient")
        self._want_mix(self.mix_levels)
        await self._push_state()

    async def _load_newest_mix(self) -> None:
        """At start: the newest run with a readable sequence, so the preview works after a restart."""
        for run in list_runs(self.runs)[:5]:
            try:
                await self._load_mix(run["name"])
                return
            except Exception as err:  # noqa: BLE001 - an unreadable run: try the one before
                log.info("live: no flash preview from %s: %s", run["name"], err)
                continue

    def _want_mix(self, levels: tuple[float, ...]) -> None:
        """Render the mix ``levels`` for the pages; a newer mix replaces one not yet rendered (never a queue)."""
        self._mix_wanted = levels
        if not self._mix_rendering:
            self._mix_rendering = True
            self._spawn(self._render_mixes())

    async def _render_mixes(self) -> None:
        try:
            while self._mix_wanted is not None and self.mix is not None:
                levels, self._mix_wanted = self._mix_wanted, None
                mix = self.mix
                image = await asyncio.get_running_loop().run_in_executor(None, mix.image, levels, self.state.overlay)
                self._last_mix_linear = image.linear
                await self._send_frame(image.preview, source=f"synthesised from {mix.run}", view="mix")
        except Exception as err:  # noqa: BLE001 - logged; the devices are not involved, the next mix tries again
            log.error("live: synthesising the mix failed: %s", err)
        finally:
            self._mix_rendering = False

    async def _post_mix(self, request: web.Request) -> web.Response:
        """``{"run": name}`` loads a run's frames; ``{"levels": [...]}`` or ``{"preset": mode}`` sets the mix."""
        body = await json_object(request)
        if "run" in body:
            if not isinstance(body["run"], str):
                raise UsageError("run: expected a run folder's name")
            await self._load_mix(body["run"])
        mix = self.mix
        if mix is None:
            raise UsageError("no sequence to synthesise from yet; expected a fired sequence first")
        if "preset" in body:
            preset = body["preset"]
            if preset == "ambient":
                self.mix_levels = (0.0,) * len(mix.led_names)
            elif preset in mix.solved:
                self.mix_levels = mix.solved[preset]
            else:
                choices = ", ".join(["ambient", *mix.solved])
                raise UsageError(f"preset {str(preset)[:40]!r}: expected one of {choices}")
        elif "levels" in body:
            self.mix_levels = mix.levels(body["levels"])
        self._want_mix(self.mix_levels)
        return web.json_response({"mix": finite(self._mix_json())})

    async def _post_mix_fire(self, request: web.Request) -> web.Response:
        """Capture one frame with exactly the mix shown, at the run's ambient exposure and gain; its raw TIFF and
        sRGB PNG go to the run's ``mix-captures/``, with how far it is from the synthesised image."""
        body = await json_object(request)
        self._busy()
        mix = self.mix
        if mix is None:
            raise UsageError("no sequence to synthesise from yet; expected a fired sequence first")
        levels = mix.levels(body["levels"]) if "levels" in body else self.mix_levels
        if levels != self.mix_levels:
            raise UsageError("levels: not the mix shown; expected the page's current mix (reload the page)")
        folder = run_folder(self.runs, mix.run)
        if folder is None:
            raise UsageError(f"run '{mix.run}': its folder is gone")
        renderer = self.renderer
        if (renderer.cfa, renderer.black, renderer.white) != (mix.cfa, mix.spec.black_level, mix.spec.white_level):
            raise UsageError(
                f"run '{mix.run}': taken in another pixel format than the camera's now ({self.camera_format['summary']});"
                " expected the run's — set it back, or fire a new sequence"
            )
        exposure_us, gain = mix.ambient_exposure
        # A booth that dims by PWM delivers a fractional level's energy only over whole periods (as the
        # sequence's flash frame is timed): the ambient exposure rounded to them, or the error named.
        pwm_hz = getattr(getattr(self.rig.booth, "info", None), "pwm_hz", None)
        pwm_note = None
        if pwm_hz:
            exposure_us, pwm_note = whole_pwm_periods(exposure_us, levels, pwm_hz, self.stream.exposure_range_us)
        frame = await self._on_rig(self._grab_with, levels, exposure_us, gain)
        linear, saturated = linearise(
            preview_samples(frame.pixels, mix.cfa, self.renderer.width),
            mix.spec.black_level,
            mix.spec.white_level,
            frame.exposure_us,
            frame.gain,
        )
        synthesised, synth_saturated = mix.synthesize(levels)
        if linear.shape != synthesised.shape:
            raise UsageError(
                f"camera frame {frame.pixels.shape}: not run '{mix.run}''s frame size; expected the run's ROI and "
                "binning — set them back, or fire a new sequence"
            )
        keep = ~(saturated | synth_saturated)
        difference = float(np.sqrt(np.mean((linear - synthesised)[keep] ** 2)))
        scale = float(np.sqrt(np.mean(synthesised[keep] ** 2))) or 1.0
        names = dict(zip(mix.led_names, levels))
        metadata = {"run": mix.run, "levels": names, "exposure_us": frame.exposure_us, "gain": frame.gain}
        rgb = self.renderer.camera_rgb(frame.pixels)
        tiff, png = await asyncio.get_running_loop().run_in_executor(
            None, write_snapshot, folder / "mix-captures", frame.pixels, self.renderer.srgb8(rgb), metadata
        )
        self.mix_capture = {
            "levels": list(levels),
            "tiff": str(tiff.relative_to(folder)),
            "png": str(png.relative_to(folder)),
            "relative_rms_difference": difference / scale,
            "exposure_us": frame.exposure_us,
            "gain": frame.gain,
            "warning": pwm_note,
        }
        captured = self.renderer.render_rgb(mix.rgb(linear), scale=1.0 / mix.white, histogram=False)  # the mix's scale
        await self._send_frame(captured, source=f"captured with the mix ({mix.run})", view="mix-capture")
        await self._push_state()
        return web.json_response({"mix": finite(self._mix_json())})

    def _grab_with(self, levels: tuple[float, ...], exposure_us: float, gain: float) -> RawFrame:
        """One frame at ``levels``, ``exposure_us`` and ``gain``; the live settings back after it (rig thread)."""
        before = self.stream.settings
        try:
            self.stream.pause()
            self.stream.set_exposure(exposure_us, gain)
            self.stream.set_levels(levels)
            return self.stream.grab()
        except BaseException:
            self.stream.all_off()
            raise
        finally:
            self.stream.pause()
            self.stream.set_exposure(before.exposure_us, before.gain)
            if self.clients and any(before.levels):  # the live levels again, as after a sequence
                self.stream.set_levels(before.levels)
            else:
                self.stream.all_off()
