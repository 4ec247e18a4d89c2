"""What the live server does with a socket and a request before it acts: the listening socket
(:func:`bind`), loopback addresses, request bodies read as every user's JSON is, the numbers and
flags in them checked, refusals as one-line JSON, malformed requests logged in one line."""

from __future__ import annotations

import contextlib
import ipaddress
import logging
import math
import socket
from typing import Any

import numpy as np
from aiohttp import web
from aiohttp.http_exceptions import HttpProcessingError
from aiohttp.web_protocol import RequestPayloadError

from msflash.acquisition.errors import UsageError
from msflash.processing.json_input import parse_json_document


class MalformedRequestsInOneLine(logging.Filter):
    """aiohttp logs a request that is not HTTP (a scanner, a TLS hello on the plain port) or whose body does not
    decode with a traceback:
    here it becomes one line at debug level (``-vv`` shows it); every other record passes unchanged."""

    def filter(self, record: logging.LogRecord) -> bool:
        error = record.exc_info[1] if record.exc_info else None
        if isinstance(error, HttpProcessingError | RequestPayloadError):
            record.msg = "live: refused a request that is not HTTP (%s)"
            record.args = (" ".join(str(error).split())[:200],)
            record.exc_info, record.exc_text = None, None
            record.levelno, record.levelname = logging.DEBUG, "DEBUG"
        return True


_AIOHTTP_SERVER_LOG = logging.getLogger("aiohttp.server")
if not any(isinstance(f, MalformedRequestsInOneLine) for f in _AIOHTTP_SERVER_LOG.filters):
    _AIOHTTP_SERVER_LOG.addFilter(MalformedRequestsInOneLine())


def loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def bind(host: str, port: int) -> socket.socket:
    """A listening TCP socket on ``host``:``port`` (0: any free port); a one-line error when it cannot be bound.

    A wildcard address (``0.0.0.0``, ``::``) is refused: the ``Host`` check needs the one address the page
    is reached by.
    """
    wildcard = False
    with contextlib.suppress(ValueError):
        wildcard = ipaddress.ip_address(host).is_unspecified
    if wildcard:
        raise UsageError(
            f"--host {host}: a wildcard address; expected the one address of this machine the page is "
            "opened by (the Host header is checked against it)"
        )
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind((host, port))
        sock.listen(64)
    except OSError as err:
        sock.close()
        raise UsageError(
            f"--host {host} --port {port}: cannot listen there ({err.strerror or err}); expected a free port "
            "on an address of this machine"
        ) from err
    sock.setblocking(False)
    return sock


def refuse(status: int, message: str) -> web.Response:
    return web.json_response({"error": message}, status=status)


def finite(value: Any) -> Any:
    """``value`` with NaN and infinities as None (JSON has neither) and numpy values as Python's."""
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


async def json_object(request: web.Request) -> dict[str, Any]:
    """The request's body as a JSON object, read as every user's JSON is (``processing/json_input.py``).

    The bytes are read whatever the headers claim (an unknown ``charset``, a ``Content-Encoding`` that
    does not decode) and taken as UTF-8, as JSON is; a NaN, an infinite or huge number, a key twice
    or nesting past :data:`~msflash.processing.json_input.MAX_NESTING` levels is refused naming its
    field (400), never a 500 that switches the LEDs off.
    """
    try:
        raw = await request.read()
    except web.HTTPException:
        raise  # the body is over client_max_size: 413
    except (RequestPayloadError, ValueError) as err:  # a body that does not decode (e.g. bad gzip)
        raise UsageError(f"request body: unreadable ({' '.join(str(err).split())}); expected a JSON object") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        raise UsageError(
            f"request body: not UTF-8 ({err.reason} at byte {err.start}); expected a JSON object"
        ) from None
    body = parse_json_document(text, "request body", UsageError)
    if not isinstance(body, dict):
        raise UsageError("request body: expected a JSON object")
    return body


def number(body: dict[str, Any], key: str, default: float) -> float:
    value = body.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(float(value)):
        raise UsageError(f"{key} {str(value)[:40]}: expected a finite number")
    return float(value)


def boolean(body: dict[str, Any], key: str) -> bool:
    value = body[key]
    if not isinstance(value, bool):
        raise UsageError(f"{key} {value!r}: expected true or false")
    return value
