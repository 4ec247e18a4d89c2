"""The live server of ``msflash live``: one aiohttp application owning one rig (docs/architecture.md §5.4).

**Threads.** The event loop serves HTTP and WebSockets; every call to the camera or the booth runs on one
rig thread (a single-worker executor), so the live stream, the sliders and a fired sequence never drive
the devices at once. Frames go to the page over a WebSocket as binary messages: a little-endian ``uint32``
length, a JSON header (frame number, histogram, saturated fraction, the booth's levels) and the JPEG.

**Safe by default.** Every request must name this server in ``Host`` (``127.0.0.1``/``localhost``/
``[::1]`` and the port, or the ``--host`` address): a page on another site that rebinds its DNS name to
127.0.0.1 is refused. A request carrying an ``Origin`` or ``Sec-Fetch-Site: cross-site`` from anywhere else
is refused. Every state-changing request (each POST) and the WebSocket need the session token, sent in the
``X-Msflash-Token`` header (the WebSocket: ``?token=``); the page served on loopback carries it, a page on
another address (``--host``) is served only to ``?token=`` (then a ``SameSite=Strict`` cookie lets its images
load). Files are served from the package's own page assets by name and from a run folder by
:func:`acquisition.app.live.runs.run_file` (no path out of the folder). The LEDs go off when the last page
has been gone :data:`LAST_CLIENT_GRACE_S` (a reload keeps them), when the server stops (Ctrl-C, SIGTERM, SIGHUP),
and on any error of a request or of the stream.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import html
import json
import logging
import secrets
import socket
import struct
from concurrent.futures import ThreadPoolExecutor
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from aiohttp import WSMsgType, web

from msflash.acquisition.app.live.camera_format import camera_format_json, format_request
from msflash.acquisition.app.live.charts import run_charts
from msflash.acquisition.app.live.clients import Outbox, close_all
from msflash.acquisition.app.live.mix_preview import MixPreview, preview_samples
from msflash.acquisition.app.live.preview import Preview, PreviewRenderer
from msflash.acquisition.app.live.requests import boolean, finite, json_object, loopback, number, refuse
from msflash.acquisition.app.live.run_job import SequenceRequest, new_run_folder, run_sequence
from msflash.acquisition.app.live.runs import list_runs, read_json, run_file, run_files, run_folder, run_page
from msflash.acquisition.app.live.snapshots import write_snapshot
from msflash.acquisition.app.live.state import LiveState, SequenceJob
from msflash.acquisition.devices.camera import RawFrame
from msflash.acquisition.errors import CameraError, CaptureCancelled, UsageError
from msflash.acquisition.session.engine import Cancellation, CaptureResult, FrameEvent
from msflash.acquisition.session.exposure import whole_pwm_periods
from msflash.acquisition.session.live import LiveStream
from msflash.acquisition.session.rig import Rig
from msflash.acquisition.session.run import RunOptions
from msflash.processing.led_wavelength import led_peaks_nm
from msflash.processing.synthesis import linearise

log = logging.getLogger(__name__)

TOKEN_HEADER = "X-Msflash-Token"
TOKEN_COOKIE = "msflash_token"
LAST_CLIENT_GRACE_S = 2.0
"""How long the LEDs stay on after the last page went away (a reload reconnects within it)."""
MAX_FPS = 25.0
"""The live stream's ceiling: frames are taken no faster (the machine is shared)."""
SHUTDOWN_TIMEOUT_S = 1.0
"""How long stopping waits for open connections' handlers before cancelling them."""
ASSETS = {"live.js": "text/javascript", "live.css": "text/css"}
"""The page's assets, served by name from the package (``static/``)."""


def _asset(name: str) -> str:
    return resources.files("msflash.acquisition.app.live").joinpath("static", name).read_text(encoding="utf-8")


class LiveServer:
    """The live view of one open rig, served on ``sock``.

    Parameters
    ----------
    rig
        The open rig; the server drives it from its rig thread and switches its LEDs off when it stops.
    runs
        The runs directory: fired sequences go to new folders in it, and its runs are listed.
    sock
        The listening socket (:func:`bind`); its address decides the allowed ``Host`` names.
    token
        The session token (default: a new random one).
    target
        The complementary flash's target illuminant.
    token_for_pages
        Ask the token for every request, pages and files too; None: when the address is not loopback.
    """

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
        self._loop: asyncio.AbstractEventLoop | None = None
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

    # -- the application ----------------------------------------------------------------------
    def app(self) -> web.Application:
        """The aiohttp application (its routes, the guard middleware, start-up and shutdown)."""
        app = web.Application(middlewares=[self._guard], client_max_size=64 * 1024)
        app.router.add_get("/", self._index)
        app.router.add_get("/static/{name}", self._static)
        app.router.add_get("/ws", self._websocket)
        app.router.add_get("/api/state", self._get_state)
        app.router.add_get("/api/runs", self._get_runs)
        app.router.add_get("/api/runs/{name}", self._get_run)
        app.router.add_get("/runs/{name}/", self._run_page)
        app.router.add_get("/runs/{name}/files/{path:.+}", self._run_file)
        app.router.add_post("/api/settings", self._post_settings)
        app.router.add_post("/api/levels", self._post_levels)
        app.router.add_post("/api/leds-off", self._post_leds_off)
        app.router.add_post("/api/sequence", self._post_sequence)
        app.router.add_post("/api/mix", self._post_mix)
        app.router.add_post("/api/mix-fire", self._post_mix_fire)
        app.router.add_post("/api/snapshot", self._post_snapshot)
        app.router.add_post("/api/camera-format", self._post_camera_format)
        app.router.add_post("/api/reconnect", self._post_reconnect)
        app.router.add_get("/api/pixel", self._get_pixel)
        app.on_startup.append(self._on_startup)
        app.on_shutdown.append(self._on_shutdown)
        app.on_cleanup.append(self._on_cleanup)
        return app

    async def serve(self, stop: asyncio.Event) -> None:
        """Serve until ``stop`` is set; then close the pages, switch the LEDs off and stop the rig thread."""
        # A connection that never finishes its request must not hold the shutdown (aiohttp waits 60 s).
        runner = web.AppRunner(self.app(), handle_signals=False, access_log=None, shutdown_timeout=SHUTDOWN_TIMEOUT_S)
        await runner.setup()
        site = web.SockSite(runner, self.sock)
        await site.start()
        try:
            await stop.wait()
        finally:
            await runner.cleanup()

    async def _on_startup(self, _app: web.Application) -> None:
        self._loop = asyncio.get_running_loop()
        self._spawn(self._frame_loop())
        self._spawn(self._load_newest_mix())

    async def _on_shutdown(self, _app: web.Application) -> None:
        await close_all(self.clients)  # bounded: a page that does not read is aborted

    def stop_sequence(self, reason: str = "msflash live is stopping") -> bool:
        """Ask a running sequence to stop between frames (its LEDs off, its frames kept); whether one runs.

        Safe from any thread or a signal handler: the capture checks it before each step.
        """
        cancel = self._cancel
        if cancel is None:
            return False
        cancel.cancel(reason)
        return True

    async def _on_cleanup(self, _app: web.Application) -> None:
        self.stop_sequence()  # a fired sequence stops between frames, not at its end
        for task in list(self._tasks):
            task.cancel()
        for task in list(self._tasks):
            with contextlib.suppress(BaseException):
                await task
        if self._off_timer is not None:
            self._off_timer.cancel()
        # The rig thread finishes what it is doing (a cancelled sequence ends at its next frame with its
        # LEDs off), then LEDs off.
        await asyncio.get_running_loop().run_in_executor(self.rig_thread, self._stop_rig)
        self.rig_thread.shutdown(wait=True)

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

    # -- the guard ------------------------------------------------------------------------------
    def _token_ok(self, given: str | None) -> bool:
        return given is not None and hmac.compare_digest(given.encode(), self.token.encode())

    @web.middleware
    async def _guard(self, request: web.Request, handler: Any) -> web.StreamResponse:
        host = request.headers.get("Host", "").lower()
        if host not in self.allowed_hosts:
            return refuse(403, f"Host '{host}': expected {' or '.join(sorted(self.allowed_hosts))}")
        origin = request.headers.get("Origin")
        if origin is not None and origin.lower() not in self.allowed_origins:
            return refuse(403, f"Origin '{origin}': cross-site requests are refused; expected this page's own")
        if request.headers.get("Sec-Fetch-Site", "same-origin") == "cross-site":
            return refuse(403, "Sec-Fetch-Site cross-site: refused; expected a request from this page")
        changes_state = request.method not in ("GET", "HEAD") or request.path == "/ws"
        given = request.headers.get(TOKEN_HEADER) or request.query.get("token")
        if (changes_state or self.remote) and not self._token_ok(given):
            cookie_ok = self.remote and not changes_state and self._token_ok(request.cookies.get(TOKEN_COOKIE))
            if not cookie_ok:
                return refuse(403, f"the session token is missing or wrong; expected it in {TOKEN_HEADER}")
        try:
            return await handler(request)
        except web.HTTPException:
            raise
        except UsageError as err:
            return refuse(400, str(err))
        except Exception as err:  # noqa: BLE001 - any failure: LEDs off, one line to the page
            log.error("live: %s %s failed: %s", request.method, request.path, err)
            await self._fail(err)
            return refuse(500, f"{type(err).__name__}: {err} (LEDs switched off)")

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

    # -- pages and files ----------------------------------------------------------------------
    async def _index(self, request: web.Request) -> web.Response:
        page = _asset("index.html").replace("{{TOKEN}}", html.escape(self.token, quote=True))
        response = web.Response(text=page, content_type="text/html", headers=_NO_STORE)
        if self.remote:
            response.set_cookie(TOKEN_COOKIE, self.token, httponly=True, samesite="Strict")
        return response

    async def _static(self, request: web.Request) -> web.Response:
        name = request.match_info["name"]
        if name not in ASSETS:
            raise web.HTTPNotFound(text=f"{name}: no such page asset")
        return web.Response(text=_asset(name), content_type=ASSETS[name], headers=_NO_STORE)

    async def _run_file(self, request: web.Request) -> web.StreamResponse:
        path = run_file(self.runs, request.match_info["name"], request.match_info["path"])
        if path is None:
            raise web.HTTPNotFound(text="no such file in a run folder")
        return web.FileResponse(path)

    async def _get_runs(self, _request: web.Request) -> web.Response:
        return web.json_response({"runs": list_runs(self.runs)})

    def _run_info(self, name: str) -> dict[str, Any]:
        folder = run_folder(self.runs, name)
        if folder is None:
            raise web.HTTPNotFound(text=f"{name}: no such run")
        summary = read_json(folder / "run.json")
        return {
            "name": name,
            "files": run_files(folder),
            "summary": summary if isinstance(summary, dict) else None,
            "charts": run_charts(folder),
        }

    async def _get_run(self, request: web.Request) -> web.Response:
        loop = asyncio.get_running_loop()  # the charts are drawn by matplotlib: off the event loop
        return web.json_response(finite(await loop.run_in_executor(None, self._run_info, request.match_info["name"])))

    async def _run_page(self, request: web.Request) -> web.StreamResponse:
        """The run's own ``report.html`` (what ``msflash run`` writes); the page's summary for a run without one."""
        info = await asyncio.get_running_loop().run_in_executor(None, self._run_info, request.match_info["name"])
        if "report.html" in info["files"]:
            raise web.HTTPFound(f"/runs/{info['name']}/files/report.html")
        return web.Response(text=run_page(info), content_type="text/html")

    # -- state --------------------------------------------------------------------------------
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

    def _camera_gain(self) -> dict[str, Any] | None:
        frame = self._last_raw
        native = frame.camera_gain if frame is not None else None
        return None if native is None else {"feature": native.feature, "value": native.value, "unit": native.unit}

    async def _get_state(self, _request: web.Request) -> web.Response:
        return web.json_response(self.state_json())

    async def _push_state(self) -> None:
        if not self.clients:
            return
        text = json.dumps({"type": "state", "state": self.state_json()})
        for page in list(self.clients):
            page.offer_state(text)  # never waits on a page (clients.py)

    def _busy(self) -> None:
        if self.state.job.status == "running":
            raise web.HTTPConflict(text="a sequence is running; expected its end first")

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

    def _camera_changed(self, info: Any) -> None:
        """The camera's format may have changed: the renderer (CFA, levels), the last frame and the page's figures."""
        self.renderer = PreviewRenderer(info, self.rig.camera_responsivities)
        self._last_raw = None
        self.camera_format = camera_format_json(info, self.stream)

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

    # -- the sequence ---------------------------------------------------------------------------
    async def _post_sequence(self, request: web.Request) -> web.Response:
        body = await json_object(request)
        self._busy()
        if self.rig.camera_responsivities is None:
            raise UsageError(
                f"rig '{self.rig.name}': the flash solvers need the camera's responsivities; expected "
                "--responsivity FILE.csv or --calibration DIR with a camera section"
            )
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

    # -- the flash before it fires (issue 33 item 2) ----------------------------------------------
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

    # -- the live stream ------------------------------------------------------------------------
    async def _websocket(self, request: web.Request) -> web.WebSocketResponse:
        ws = web.WebSocketResponse(heartbeat=10.0)
        await ws.prepare(request)
        page = Outbox(ws, request.transport, self._page_gone)
        self.clients.add(page)
        if self._off_timer is not None:
            self._off_timer.cancel()
            self._off_timer = None
        self._watching.set()
        try:
            await page.send_now(json.dumps({"type": "state", "state": self.state_json()}))
            for view, frame in list(self._view_frames.items()):
                page.offer_frame(frame, view)
            if not page.dropped:
                async for message in ws:  # the page sends nothing: commands are token-carrying POSTs
                    if message.type == WSMsgType.ERROR:
                        break
        finally:
            page.stop_sending()
            self._page_gone(page)
        return ws

    def _page_gone(self, page: Outbox) -> None:
        """A page closed, or was dropped for not reading: the last one gone starts the LEDs-off grace."""
        if page not in self.clients:
            return
        self.clients.discard(page)
        if page.dropped:
            self.pages_dropped += 1
        if not self.clients:
            self._watching.clear()
            loop = asyncio.get_running_loop()
            if self._off_timer is None:
                self._off_timer = loop.call_later(LAST_CLIENT_GRACE_S, lambda: self._spawn(self._last_client_gone()))

    async def _last_client_gone(self) -> None:
        self._off_timer = None
        if self.clients or self.state.job.status == "running":
            return  # a page came back; or the sequence ends with its LEDs off and restores none
        await self._on_rig(self._stop_rig)

    async def _frame_loop(self) -> None:
        loop = asyncio.get_running_loop()
        failed = ""
        while True:
            await self._watching.wait()
            if self.state.job.status == "running":
                await asyncio.sleep(0.1)
                continue
            started = loop.time()
            try:
                preview = await self._on_rig(self._grab)
            except Exception as err:  # noqa: BLE001 - LEDs off, shown on the page, then try again
                if str(err) != failed:
                    log.error("live: the stream failed: %s", err)
                failed = str(err)
                await self._fail(err)
                await asyncio.sleep(1.0)
                continue
            if failed:  # the stream works again: the error it showed is over
                failed, self.state.error = "", None
                await self._push_state()
            frame = self._last_raw
            raw_size = [int(frame.pixels.shape[1]), int(frame.pixels.shape[0])] if frame is not None else None
            await self._send_frame(preview, source="live", raw_size=raw_size)
            await asyncio.sleep(max(0.0, 1.0 / MAX_FPS - (loop.time() - started)))

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


_NO_STORE = {"Cache-Control": "no-store"}


def _booth_error(err: BaseException) -> bool:
    """Whether ``err`` came from the booth's side (its link or its controller)."""
    return any("booth" in kind.__name__.lower() or "serial" in kind.__module__ for kind in type(err).__mro__)


CFA_CHANNELS = {"R": 0, "G": 1, "B": 2}


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


class _PageView:
    """A fired sequence as the pages see it (a frame handler of the capture engine): each frame's
    preview and its file, handed to the event loop."""

    def __init__(self, server: LiveServer, job: SequenceJob, loop: asyncio.AbstractEventLoop) -> None:
        self.server, self.job, self.loop = server, job, loop

    def frame_ready(self, event: FrameEvent) -> None:
        preview = self.server.renderer.render(event.frame.pixels, self.server.state.overlay)
        file = event.entry.file if event.entry is not None else ""
        self.loop.call_soon_threadsafe(self.server._landed, self.job, event.step.index, file, event.step.label, preview)

    def sequence_finished(self, result: CaptureResult) -> None:
        """The job's state says so once the report is written."""
