"""Fire: the sequence ``msflash run`` captures, into a new folder of the runs directory (``POST /api/sequence``).

It runs on the rig thread with the live stream paused; each frame's preview goes to the pages as it lands
(:class:`_PageView`, a frame handler of the capture engine); once done, its frames become the flash preview. The
live LED levels come back after it while a page watches (it ends with the LEDs off).
"""

from __future__ import annotations

import asyncio
import logging
from pathlib import Path
from typing import Any

from aiohttp import web

from msflash.acquisition.app.live.flash_preview import FlashPreviewRoutes
from msflash.acquisition.app.live.preview import Preview
from msflash.acquisition.app.live.requests import json_object
from msflash.acquisition.app.live.run_job import SequenceRequest, new_run_folder, run_sequence
from msflash.acquisition.app.live.state import SequenceJob
from msflash.acquisition.errors import CaptureCancelled, UsageError
from msflash.acquisition.session.engine import Cancellation, CaptureResult, FrameEvent
from msflash.acquisition.session.run import RunOptions, check_colour_camera

log = logging.getLogger(__name__)


class SequenceRoutes(FlashPreviewRoutes):
    """Firing a sequence and following it."""

    async def _post_sequence(self, request: web.Request) -> web.Response:
        body = await json_object(request)
        self._busy()
        if self.rig.camera_responsivities is None:
            raise UsageError(
                f"rig '{self.rig.name}': the flash solvers need the camera's responsivities; expected "
                "--responsivity FILE.csv or --calibration DIR with a camera section"
            )
        check_colour_camera(self.rig, self.rig.name)
        mode = body.get("mode", self.state.mode)
        if mode not in ("complementary", "matching"):
            raise UsageError(f"mode {mode!r}: expected 'complementary' or 'matching'")
        exposure: str | float = "auto" if self.state.sequence_exposure == "auto" else self.stream.settings.exposure_us
        folder = new_run_folder(self.runs)
        n_leds = self.rig.led_spectra.count
        labels = ["ambient", *self.rig.led_spectra.names[:n_leds], "flash"]
        self.state.job = SequenceJob("running", folder.name, "starting", [{"label": label} for label in labels])
        request_ = SequenceRequest(exposure, RunOptions(mode=mode, target=self.target))
        self._spawn(self._sequence(folder, request_))
        await self._push_state()
        return web.json_response({"run": folder.name}, status=202)

    async def _sequence(self, folder: Path, request: SequenceRequest) -> None:
        loop = asyncio.get_running_loop()
        job = self.state.job
        cancel = self._cancel = Cancellation()

        def on_phase(text: str) -> None:
            loop.call_soon_threadsafe(self._phase, job, text)

        def work() -> dict[str, Any]:
            self.stream.pause()
            try:
                summary = run_sequence(self.rig, folder, request, (_PageView(self, job, loop),), on_phase, cancel)
            except BaseException:
                self.stream.all_off()  # the capture switched them off; the live levels say so too
                raise
            self._restore_levels()
            return summary

        try:
            summary = await self._on_rig(work)
        except CaptureCancelled as err:
            log.info("live: the sequence into %s stopped: %s", folder, err)
            job.status, job.message = "stopped", f"stopped: {err}; the frames taken are in {folder.name}"
        except Exception as err:  # noqa: BLE001 - shown on the page; the capture switched the LEDs off
            log.error("live: the sequence into %s failed: %s", folder, err)
            job.status, job.message = "failed", str(err)
            self.state.error = f"sequence: {err}"
        else:
            job.status = "done"
            try:
                await self._load_mix(folder.name)
            except Exception as err:  # noqa: BLE001 - the run stands; only its flash preview is missing
                log.error("live: the flash preview of %s could not be loaded: %s", folder.name, err)
            rmse = summary.get("spectrum_rmse_vs_truth")
            job.message = f"done in {summary['elapsed_s']:.1f} s" + (
                f"; spectrum RMSE against the true ambient {rmse:.4f}" if rmse is not None else ""
            )
        finally:
            if self._cancel is cancel:
                self._cancel = None
        job.phase = job.status
        await self._push_state()

    def _restore_levels(self) -> None:
        """After a sequence (which ends with the LEDs off): the live levels again while a page watches."""
        levels = self.stream.settings.levels
        if self.clients and any(levels):
            self.stream.set_levels(levels)
        else:
            self.stream.all_off()

    def _phase(self, job: SequenceJob, text: str) -> None:
        job.phase = text
        self._spawn(self._push_state())

    def _landed(self, job: SequenceJob, index: int, file: str, label: str, preview: Preview) -> None:
        if index < len(job.steps):
            label = job.steps[index]["label"]  # the LED's name, not the plan's led:N
            job.steps[index] = {"label": label, "file": file}
        self._spawn(self._send_frame(preview, source=f"sequence {label}"))
        self._spawn(self._push_state())


class _PageView:
    """A fired sequence as the pages see it (a frame handler of the capture engine): each frame's
    preview and its file, handed to the event loop."""

    def __init__(self, server: SequenceRoutes, job: SequenceJob, loop: asyncio.AbstractEventLoop) -> None:
        self.server, self.job, self.loop = server, job, loop

    def frame_ready(self, event: FrameEvent) -> None:
        preview = self.server.renderer.render(event.frame.pixels, self.server.state.overlay)
        file = event.entry.file if event.entry is not None else ""
        self.loop.call_soon_threadsafe(self.server._landed, self.job, event.step.index, file, event.step.label, preview)

    def sequence_finished(self, result: CaptureResult) -> None:
        """The job's state says so once the report is written."""
