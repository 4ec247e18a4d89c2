"""What every part of the live server shares (:class:`LiveCore`): the rig, its one rig thread, the state the page
draws, the pages watching, and the frames sent to them (docs/architecture.md §5.4).

The server's parts, one module each, stack as mixins over this state: :class:`LiveCore` →
:class:`~acquisition.app.live.flash_preview.FlashPreviewRoutes` (the flash before it fires) →
:class:`~acquisition.app.live.fired_sequence.SequenceRoutes` (Fire: a sequence into a new run folder) and
:class:`~acquisition.app.live.rig_controls.RigControls` (exposure, gain, LEDs, camera format, snapshot, pixel
readout) → :class:`~acquisition.app.live.server.LiveServer` (the application: guard, pages, WebSocket, stream).
Every call to the camera or the booth runs on the rig thread (:meth:`LiveCore._on_rig`); an error of a request or
of the stream switches the LEDs off (:meth:`LiveCore._fail`).
"""

from __future__ import annotations

import asyncio
import json
import logging
import secrets
import socket
import struct
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np
from aiohttp import web

from msflash.acquisition.app.live.camera_format import camera_format_json
from msflash.acquisition.app.live.clients import Outbox
from msflash.acquisition.app.live.mix_preview import MixPreview
from msflash.acquisition.app.live.preview import Preview, PreviewRenderer
from msflash.acquisition.app.live.requests import finite, loopback
from msflash.acquisition.app.live.runs import list_runs
from msflash.acquisition.app.live.state import LiveState
from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.errors import CameraError
from msflash.acquisition.session.engine import Cancellation
from msflash.acquisition.session.live import LiveStream
from msflash.acquisition.session.rig import Rig
from msflash.processing.led_wavelength import led_peaks_nm

log = logging.getLogger(__name__)


class LiveCore:
    """The shared state of a :class:`~acquisition.app.live.server.LiveServer` (its parameters are documented there)."""

    def __init__(
        self,
        rig: Rig,
        runs: Path,
        sock: socket.socket,
        token: str | None = None,
        target: str = "D65",
        token_for_pages: bool | None = None,
    ) -> None:
        self.rig = rig
        self.runs = Path(runs)
        self.sock = sock
        self.token = token or secrets.token_urlsafe(24)
        self.target = target
        address = sock.getsockname()
        self.host, self.port = str(address[0]), int(address[1])
        self.remote = not loopback(self.host) if token_for_pages is None else token_for_pages
        names = {"127.0.0.1", "localhost", "[::1]"} if not self.remote else set()
        names.add(f"[{self.host}]" if ":" in self.host else self.host)
        self.allowed_hosts = {f"{name}:{self.port}" for name in names}
        self.allowed_origins = {f"http://{host}" for host in self.allowed_hosts}
        self.stream = LiveStream(rig)
        info = rig.camera.info  # read once: on a real camera each read is feature round trips
        self.camera_model = info.model
        self.camera_format: dict[str, Any] = {}
        """The frame's size and format, and what the camera allows (:func:`camera_format_json`)."""
        self.renderer = PreviewRenderer(info, rig.camera_responsivities)
        self._camera_changed(info)
        self.state = LiveState()
        self.rig_thread = ThreadPoolExecutor(max_workers=1, thread_name_prefix="msflash-rig")
        self.clients: set[Outbox] = set()
        self.pages_dropped = 0
        """Pages dropped because they stopped reading (:mod:`acquisition.app.live.clients`)."""
        self._watching = asyncio.Event()
        self._off_timer: asyncio.TimerHandle | None = None
        self._tasks: set[asyncio.Task] = set()
        self._cancel: Cancellation | None = None
        """The running sequence's cancellation (:meth:`stop_sequence`), None when none runs."""
        self.mix: MixPreview | None = None
        """The last sequence's frames, ready to be synthesised under the page's mix (issue 33 item 2)."""
        self.mix_levels: tuple[float, ...] = ()
        """The mix the page shows (drive levels, one per LED)."""
        self.mix_capture: dict[str, Any] | None = None
        """The last mix fired from the preview: its files and how far the capture is from the synthesis."""
        self._mix_wanted: tuple[float, ...] | None = None
        self._mix_rendering = False
        self._last_raw: RawFrame | None = None
        self._view_frames: dict[str, bytes] = {}
        """The last frame of each flash-preview view, for pages that connect later."""
        self._last_mix_linear: np.ndarray | None = None
        self.live_frames = 0
        """Live frames grabbed (the page counts gaps in their numbers as dropped frames)."""

    @property
    def url(self) -> str:
        """The page's address, with the token when the server listens beyond loopback."""
        host = "127.0.0.1" if not self.remote else next(iter(self.allowed_hosts)).rsplit(":", 1)[0]
        return f"http://{host}:{self.port}/" + (f"?token={self.token}" if self.remote else "")

    def stop_sequence(self, reason: str = "msflash live is stopping") -> bool:
        """Ask a running sequence to stop between frames (its LEDs off, its frames kept); whether one runs.

        Safe from any thread or a signal handler: the capture checks it before each step.
        """
        cancel = self._cancel
        if cancel is None:
            return False
        cancel.cancel(reason)
        return True

    def _stop_rig(self) -> None:
        try:
            self.stream.pause()
        finally:
            self.stream.all_off()

    def _spawn(self, coroutine: Any) -> asyncio.Task:
        task = asyncio.ensure_future(coroutine)
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)
        return task

    async def _on_rig(self, function: Any, *args: Any) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self.rig_thread, function, *args)

    async def _fail(self, err: BaseException) -> None:
        """After an error: LEDs off (if the booth still answers), the error and what failed kept for the page."""
        self.state.error = f"{err} — LEDs switched off"
        self.state.error_source = (
            "camera" if isinstance(err, CameraError) else "booth" if _booth_error(err) else "other"
        )
        try:
            await self._on_rig(self._stop_rig)
        except Exception as off_err:  # noqa: BLE001 - the booth may be what failed
            log.error("live: switching the LEDs off after the error failed too: %s", off_err)
        await self._push_state()

    def state_json(self) -> dict[str, Any]:
        """Everything the page draws."""
        settings = self.stream.settings
        leds = self.rig.led_spectra
        peaks = led_peaks_nm(leds)  # the one number (processing/led_wavelength.py), as the sequence records it
        return finite(
            {
                "rig": self.rig.name,
                "camera": self.camera_model,
                "exposure_us": settings.exposure_us,
                "gain": settings.gain,
                "exposure_range_us": list(self.stream.exposure_range_us),
                "levels": list(settings.levels),
                "booth_levels": list(self.stream.last_booth_levels),
                "leds": [{"name": name, "peak_nm": peak} for name, peak in zip(leds.names, peaks)],
                "overlay": self.state.overlay,
                "sequence_exposure": self.state.sequence_exposure,
                "mode": self.state.mode,
                "job": self.state.job.to_json(),
                "frames": self.state.frames,
                "lost_frames": self.stream.lost_frames,
                "clients": len(self.clients),
                "pages_dropped": self.pages_dropped,
                "error": self.state.error,
                "error_source": self.state.error_source if self.state.error else None,
                "runs": list_runs(self.runs),
                "mix": self._mix_json(),
                "camera_gain": self._camera_gain(),
                "camera_format": self.camera_format,
            }
        )

    def _mix_json(self) -> dict[str, Any] | None:
        mix = self.mix
        if mix is None:
            return None
        return {
            "run": mix.run,
            "led_names": list(mix.led_names),
            "solved": {mode: list(levels) for mode, levels in mix.solved.items()},
            "levels": list(self.mix_levels),
            "capture": self.mix_capture,
        }

    def _camera_gain(self) -> dict[str, Any] | None:
        frame = self._last_raw
        native = frame.camera_gain if frame is not None else None
        return None if native is None else {"feature": native.feature, "value": native.value, "unit": native.unit}

    async def _push_state(self) -> None:
        if not self.clients:
            return
        text = json.dumps({"type": "state", "state": self.state_json()})
        for page in list(self.clients):
            page.offer_state(text)  # never waits on a page (clients.py)

    def _busy(self) -> None:
        if self.state.job.status == "running":
            raise web.HTTPConflict(text="a sequence is running; expected its end first")

    def _camera_changed(self, info: Any) -> None:
        """The camera's format may have changed: the renderer (CFA, levels), the last frame and the page's figures."""
        self.renderer = PreviewRenderer(info, self.rig.camera_responsivities)
        self._last_raw = None
        self.camera_format = camera_format_json(info, self.stream)

    def _grab(self) -> Preview:
        frame = self.stream.grab()
        self._last_raw = frame
        self.live_frames += 1
        return self.renderer.render(frame.pixels, self.state.overlay)

    async def _send_frame(
        self, preview: Preview, source: str, view: str = "live", raw_size: list[int] | None = None
    ) -> None:
        self.state.frames += 1
        header = json.dumps(
            {
                "type": "frame",
                "n": self.state.frames,
                "view": view,
                "live_n": self.live_frames,
                "source": source,
                "width": preview.width,
                "height": preview.height,
                "raw_size": raw_size,
                "histogram": preview.histogram,
                "saturated": preview.saturated_fraction,
                "booth_levels": list(self.stream.last_booth_levels) if source == "live" else None,
                "exposure_us": self.stream.settings.exposure_us,
                "gain": self.stream.settings.gain,
            }
        ).encode()
        message = struct.pack("<I", len(header)) + header + preview.jpeg
        if view != "live":
            self._view_frames[view] = message  # a page that connects later is shown the flash preview too
        for page in list(self.clients):
            page.offer_frame(message, view)  # the view's latest frame only; never waits on a page (clients.py)


def _booth_error(err: BaseException) -> bool:
    """Whether ``err`` came from the booth's side (its link or its controller)."""
    return any("booth" in kind.__name__.lower() or "serial" in kind.__module__ for kind in type(err).__mro__)
