"""The live view's pages as slow consumers: each page gets the latest messages, never a queue of old ones.

A page that stops reading (a stalled tab, a client with a tiny receive buffer, a half-dead network) must
not stall the frame loop, the rig thread or the other pages, and must not count as watching for ever:

- every page has an :class:`Outbox` holding only the **latest** state and the **latest** frame of each view
  (the live image, the synthesised flash, its ambient, its capture: one view's frames never hide another's); the
  frame loop and the state pushes *offer* messages to it and never wait on a socket; a frame is
  written only once the one before has left the process, into a small kernel buffer
  (:data:`SEND_BUFFER_BYTES`), so a slow page is shown the newest frame, not one seconds old;
- one sender task per page sends what its outbox holds, each send bounded by :data:`SEND_TIMEOUT_S`;
- a send that does not finish in time drops the page: its connection is aborted (a cancelled send
  may have left half a WebSocket frame on the wire, so the connection cannot be used again) and it
  counts as gone, so "LEDs off when the last page has gone" fires for a stalled page too;
- closing every page on shutdown is bounded by :data:`CLOSE_TIMEOUT_S`, after which the
  connection is aborted (:func:`close_all`).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import socket
from collections.abc import Callable, Iterable

from aiohttp import web

log = logging.getLogger(__name__)

SEND_TIMEOUT_S = 2.0
"""The longest one message may take to leave for a page before that page is dropped."""
SEND_BUFFER_BYTES = 32 * 1024
"""The kernel's send buffer for a page's connection (Linux doubles it): a few frames, not the seconds of
frames a default auto-tuned buffer (up to 4 MiB) holds, so a slow page is shown the newest frame."""
WRITE_POLL_S = 0.01
"""How often a page's sender looks whether its last frame has left."""
CLOSE_TIMEOUT_S = 0.5
"""The longest a page's WebSocket close handshake may take on shutdown before its connection is aborted."""


class Outbox:
    """One page's WebSocket and the latest messages waiting for it.

    Parameters
    ----------
    transport
        Its connection (``request.transport``): aborted when the page is dropped.
    on_dropped
        Called once, on the event loop, when the page is dropped for a send that took too long.
    """

    def __init__(
        self,
        ws: web.WebSocketResponse,
        transport: asyncio.Transport | None,
        on_dropped: Callable[[Outbox], None],
    ) -> None:
        self.ws = ws
        self._transport = transport
        self._on_dropped = on_dropped
        self._state: str | None = None
        self._frames: dict[str, bytes] = {}
        """The latest frame of each view not yet sent (insertion order: the oldest view first)."""
        self._ready = asyncio.Event()
        self.dropped = False
        """True once the page was dropped (a send took longer than :data:`SEND_TIMEOUT_S`)."""
        sock = transport.get_extra_info("socket") if transport is not None else None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, SEND_BUFFER_BYTES)
        self._sender = asyncio.ensure_future(self._send_loop())

    def offer_state(self, text: str) -> None:
        """Queue ``text`` (a state message), replacing a state not yet sent; never waits."""
        self._state = text
        self._ready.set()

    def offer_frame(self, message: bytes, view: str = "live") -> None:
        """Queue ``message`` (a frame of ``view``), replacing that view's frame not yet sent; never waits."""
        self._frames[view] = message
        self._ready.set()

    async def send_now(self, text: str) -> None:
        """Send ``text`` first thing (the greeting), bounded like every send."""
        await self._bounded(self.ws.send_str(text))

    async def _send_loop(self) -> None:
        try:
            while not self.dropped:
                await self._ready.wait()
                self._ready.clear()
                state, self._state = self._state, None
                if state is not None:
                    await self._bounded(self.ws.send_str(state))
                while self._frames and not self.dropped:
                    view = next(iter(self._frames))
                    frame = self._frames.pop(view)
                    await self._bounded(self._after_the_last_left())
                    newer = self._frames.pop(view, None)
                    if newer is not None:  # a newer frame of the view came while the last one was leaving
                        frame = newer
                    if not self.dropped:
                        await self._bounded(self.ws.send_bytes(frame))
        except (ConnectionError, RuntimeError):
            return  # the page went away; its handler notices and removes it

    async def _after_the_last_left(self) -> None:
        """Wait until what was written before has left for the kernel (the page took it), so the frame
        written next is the newest one, not one queued behind others."""
        transport = self._transport
        while transport is not None and not transport.is_closing() and transport.get_write_buffer_size() > 0:
            await asyncio.sleep(WRITE_POLL_S)

    async def _bounded(self, send: object) -> None:
        try:
            await asyncio.wait_for(send, SEND_TIMEOUT_S)  # type: ignore[arg-type]
        except TimeoutError:
            self.drop(f"a message took longer than {SEND_TIMEOUT_S:g} s to leave")

    def drop(self, why: str) -> None:
        """Abort the page's connection and report it gone (once)."""
        if self.dropped:
            return
        self.dropped = True
        log.warning("live: dropping a page that does not read: %s", why)
        self.abort()
        self._on_dropped(self)

    def abort(self) -> None:
        """Close the page's connection at once, without a close handshake."""
        if self._transport is not None:
            self._transport.abort()

    async def close(self, code: int, message: bytes) -> None:
        """Close the WebSocket, or abort the connection when the handshake takes too long."""
        self._sender.cancel()
        with contextlib.suppress(BaseException):
            await self._sender
        try:
            await asyncio.wait_for(self.ws.close(code=code, message=message), CLOSE_TIMEOUT_S)
        except (TimeoutError, ConnectionError, RuntimeError):
            self.abort()

    def stop_sending(self) -> None:
        """Stop the sender task (the page's handler ended)."""
        self._sender.cancel()


async def close_all(outboxes: Iterable[Outbox], code: int = 1001, message: bytes = b"server stopping") -> None:
    """Close every page at once, each bounded by :data:`CLOSE_TIMEOUT_S` (then aborted)."""
    await asyncio.gather(*(outbox.close(code, message) for outbox in list(outboxes)), return_exceptions=True)
