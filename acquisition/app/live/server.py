"""The live server of ``msflash live``: one aiohttp application owning one rig (docs/architecture.md §5.4).

**Threads.** The event loop serves HTTP and WebSockets; every call to the camera or the booth runs on one
rig thread (a single-worker executor), so the live stream, the sliders and a fired sequence never drive
the devices at once. Frames go to the page over a WebSocket as binary messages: a little-endian ``uint32``
length, a JSON header (frame number, histogram, saturated fraction, the booth's levels) and the JPEG.

**Safe by default** (the guard: docs/route-of-a-frame.md): ``Host`` must name this server (no DNS rebinding),
cross-site requests are refused, every POST and the WebSocket need the session token, and files come only from
the page's assets and from inside a run folder (:func:`acquisition.app.live.runs.run_file`). The LEDs go off
when the last page has been gone :data:`LAST_CLIENT_GRACE_S`, when the server stops, and on any error of a
request or of the stream.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import html
import json
import logging
from importlib import resources
from typing import Any

from aiohttp import WSMsgType, web

from msflash.acquisition.app.live.charts import run_charts
from msflash.acquisition.app.live.clients import Outbox, close_all
from msflash.acquisition.app.live.fired_sequence import SequenceRoutes
from msflash.acquisition.app.live.requests import finite, refuse
from msflash.acquisition.app.live.rig_controls import RigControls
from msflash.acquisition.app.live.runs import list_runs, read_json, run_file, run_files, run_folder, run_page
from msflash.acquisition.errors import UsageError

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


class LiveServer(RigControls, SequenceRoutes):
    """The live view of one open rig, served on ``sock``.

    Parameters
    ----------
    rig
        The open rig; the server drives it from its rig thread and switches its LEDs off when it stops.
    runs
        The runs directory: fired sequences go to new folders in it, and its runs are listed.
    sock
        The listening socket (:func:`bind`); its address decides the allowed ``Host`` names.
    token_for_pages
        Ask the token for every request, pages and files too; None: when the address is not loopback.
    """

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
        self._spawn(self._frame_loop())
        self._spawn(self._load_newest_mix())

    async def _on_shutdown(self, _app: web.Application) -> None:
        await close_all(self.clients)  # bounded: a page that does not read is aborted

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

    async def _get_state(self, _request: web.Request) -> web.Response:
        return web.json_response(self.state_json())

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


_NO_STORE = {"Cache-Control": "no-store"}
