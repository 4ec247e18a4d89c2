"""The live server's fuzzer: a real ``msflash live`` process, capped in memory, against hostile HTTP and WebSocket traffic.

``python -m tests.acquisition.app.live_fuzz_worker --examples N [--memory-gib G]``

It starts ``msflash live --rig sim --port 0`` in a subprocess whose address space is capped
(``RLIMIT_AS``, ``--memory-gib``), reads the page's token, then lets Hypothesis (derandomised, no
database) send it, over raw sockets so that anything can be sent:

- **HTTP requests**: any method, the server's paths and mutations of them (``..``, encoded dots,
  10 000 characters, NUL, non-ASCII), ``Host`` right, wrong or missing, ``Origin`` and
  ``Sec-Fetch-Site`` from elsewhere, the token right, wrong or missing, ``Content-Length`` shorter,
  longer, negative or huge, bodies of valid and broken JSON for the POST endpoints (wrong types, NaN,
  huge numbers, deep nesting, a key twice), random bytes, bodies over the 64 KiB limit, headers of
  100 KB, request lines that are not HTTP at all;
- **WebSocket sessions**: handshakes without the key, with another version or without the token,
  then frames the page never sends (text, binary, unmasked, reserved opcodes and bits, oversized,
  fragments without an end, invalid close codes, pings), closed abruptly or left half-way;
- **out-of-order calls**: a sequence fired, then settings, levels, LEDs off and another fire while
  it runs (explicit examples, a few: a sequence takes seconds).

**The rule.** A request gets an answer the server means: 2xx for a valid call, 400 (bad input,
one line), 403 (guard), 404, 405, 409 (busy), 413 (too large), 431 — or the connection closed for
bytes that are not HTTP. A 500 (the guard's "unexpected failure, LEDs off") is a bug: nothing here
touches a device fault. After every example the server must answer ``GET /api/state`` within 10 s
and still be running. At the end SIGTERM must stop it (exit 0, "LEDs off"), its stderr holding no
traceback and no "unexpected". Exit 0 and a JSON summary on the last stdout line (outcomes per kind
and status) if the rule held; 1 with the falsifying example otherwise.
"""

from __future__ import annotations

import argparse
import base64
import collections
import contextlib
import json
import os
import resource
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

ANSWER_TIMEOUT_S = 10.0
ALLOWED = {200, 202, 400, 403, 404, 405, 409, 413, 431}
PATHS = (
    "/",
    "/static/live.js",
    "/static/live.css",
    "/ws",
    "/api/state",
    "/api/runs",
    "/api/runs/x",
    "/runs/x/",
    "/runs/x/files/report.html",
    "/api/settings",
    "/api/levels",
    "/api/leds-off",
    "/api/mix",
    "/api/mix-fire",
    "/api/snapshot",
    "/api/pixel?view=live&x=0.5&y=0.5",
)
POSTS = ("/api/settings", "/api/levels", "/api/leds-off", "/api/mix", "/api/mix-fire", "/api/snapshot")
NASTY_STRINGS = (
    "",
    "\x00",
    "\ud800".encode("utf-8", "surrogatepass").decode("latin-1"),
    "../../etc/passwd",
    "%2e%2e%2f%2e%2e%2f",
    "é" * 50,
    "x" * 10_000,
    "\u202e",
    "🎉" * 20,
    "\r\nX-Injected: 1",
)


class Server:
    """``msflash live`` in a capped subprocess; its URL, port and token."""

    def __init__(self, runs: Path, memory_gib: float) -> None:
        limit = int(memory_gib * 2**30)

        def cap() -> None:
            resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

        self.transcript = runs.parent / "serial.log"
        command = [sys.executable, "-m", "msflash.acquisition.app.cli", "live", "--port", "0"]
        command += ["--runs", str(runs), "--log-serial", str(self.transcript)]
        self.process = subprocess.Popen(
            command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, preexec_fn=cap
        )
        assert self.process.stdout is not None
        url = self.process.stdout.readline().strip()
        if not url.startswith("http://127.0.0.1:"):
            raise SystemExit(f"live did not start: {url!r} {self.process.stderr.read() if self.process.stderr else ''}")
        self.port = int(url.rsplit(":", 1)[1].strip("/"))
        self.host = f"127.0.0.1:{self.port}"
        status, body = http(self, "GET", "/", {"Host": self.host})
        self.token = body.split('name="msflash-token" content="')[1].split('"')[0]

    def alive(self) -> bool:
        return self.process.poll() is None

    def stop(self) -> tuple[int, str]:
        self.process.send_signal(signal.SIGTERM)
        _, err = self.process.communicate(timeout=60)
        return self.process.returncode, err


def _read_answer(sock: socket.socket, wait_s: float, head_only: bool = False) -> tuple[int | None, str]:
    """The status and body of an HTTP answer; None if the server closed without one (a HEAD's answer has no body)."""
    sock.settimeout(wait_s)
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(65536)
        if not chunk:
            return (None, "") if not data else (_status(data), "")
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    if head_only:
        return _status(head), ""
    length = None
    for line in head.split(b"\r\n")[1:]:
        name, _, value = line.partition(b":")
        if name.strip().lower() == b"content-length":
            length = int(value.strip())
    while length is None or len(body) < length:  # no length: the answer ends with the connection
        try:
            chunk = sock.recv(65536)
        except ConnectionResetError:
            break
        if not chunk:
            break
        body += chunk
    return _status(head), body.decode("utf-8", "replace")


def _status(head: bytes) -> int | None:
    parts = head.split(b"\r\n", 1)[0].split()
    return int(parts[1]) if len(parts) > 1 and parts[1].isdigit() else None


def raw_request(
    server: Server, data: bytes, *, wait_s: float = ANSWER_TIMEOUT_S, head_only: bool = False
) -> tuple[int | None, str]:
    """Send ``data`` on a new connection; the answer's status and body (None: closed, or -1: no answer within
    ``wait_s`` — the server waits for the rest of a request, as it may)."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=ANSWER_TIMEOUT_S) as sock:
        try:
            sock.sendall(data)  # not half-closed: aiohttp takes a client's EOF as the connection's end
        except OSError:
            pass  # the server may close first on garbage
        try:
            return _read_answer(sock, wait_s, head_only)
        except ConnectionResetError:
            return None, ""
        except TimeoutError:
            return -1, ""


def http(
    server: Server, method: str, path: str, headers: dict[str, str], body: bytes = b"", *, length: str | None = None
) -> tuple[int | None, str]:
    lines = [f"{method} {path} HTTP/1.1"]
    headers = dict(headers)
    headers.setdefault("Connection", "close")
    headers["Content-Length"] = length if length is not None else str(len(body))
    lines += [f"{name}: {value}" for name, value in headers.items()]
    data = ("\r\n".join(lines) + "\r\n\r\n").encode("utf-8", "surrogateescape") + body
    return raw_request(server, data, head_only=method == "HEAD")


# -- strategies ----------------------------------------------------------------------------------
json_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(allow_nan=False, allow_infinity=False),
    st.sampled_from([0, -1, 1e300, 1e-300, 5e-324, 0.5, 1.5, 2.0, 1e6, 1e9]),
    st.text(max_size=20),
)
json_values = st.recursive(
    json_scalars,
    lambda inner: st.lists(inner, max_size=9) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)
known_keys = st.sampled_from(
    ["exposure_us", "gain", "overlay", "sequence_exposure", "mode", "levels", "channel", "level", "x"]
)
bodies = st.one_of(
    st.dictionaries(known_keys, json_values, max_size=4).map(lambda d: json.dumps(d).encode()),
    json_values.map(lambda v: json.dumps(v).encode()),
    st.sampled_from(
        [
            b'{"exposure_us": NaN}',
            b'{"gain": Infinity}',
            b'{"levels": [1e999]}',
            b'{"a": 1, "a": 2}',
            b"[" * 5000 + b"]" * 5000,
            b'{"levels": ' + b"[" * 200 + b"]" * 200 + b"}",
            b"\xff\xfe{}",
            b"",
            b'{"channel": 0, "level": 0.5',
            b'{"levels": [0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5]}',
            b'{"exposure_us": 1e12}',
            b'{"exposure_us": -5}',
            b'{"exposure_us": 0}',
            b'{"gain": 1e30}',
        ]
    ),
    st.binary(max_size=200),
    st.integers(min_value=65 * 1024, max_value=300 * 1024).map(lambda n: b'{"x": "' + b"a" * n + b'"}'),
)


@st.composite
def api_calls(draw: st.DrawFn) -> dict[str, Any]:
    """Well-formed calls of the page's API (host, token, length right) with hostile JSON bodies."""
    return {
        "method": "POST",
        "path": draw(st.sampled_from(POSTS)),
        "token": "right",
        "host": "right",
        "origin": draw(st.sampled_from([None, "self"])),
        "fetch_site": None,
        "body": draw(bodies),
        "length": None,
        "extra": {},
    }


@st.composite
def http_examples(draw: st.DrawFn) -> dict[str, Any]:
    if draw(st.booleans()):
        return draw(api_calls())
    method = draw(st.sampled_from(["GET", "POST", "POST", "POST", "HEAD", "PUT", "DELETE", "OPTIONS", "PATCH", "BREW"]))
    path = draw(st.sampled_from(PATHS))
    if draw(st.integers(0, 5)) == 0:
        path = path + draw(st.sampled_from(NASTY_STRINGS)).replace(" ", "%20").replace("\r\n", "%0d%0a")
    token = draw(st.sampled_from(["right", "right", "right", "wrong", "missing", "query"]))
    host = draw(st.sampled_from(["right", "right", "right", "evil", "missing", "localhost"]))
    origin = draw(st.sampled_from([None, None, None, "http://evil.example", "null", "self"]))
    fetch_site = draw(st.sampled_from([None, None, "cross-site", "same-origin"]))
    body = draw(bodies) if method in ("POST", "PUT", "PATCH") else b""
    length = draw(st.sampled_from([None, None, None, None, "-1", "99999999999", "0", "abc", "shorter", "longer"]))
    extra = draw(
        st.sampled_from(
            [{}, {}, {"X-Big": "a" * 100_000}, {"Transfer-Encoding": "chunked"}, {"Content-Encoding": "gzip"}]
        )
    )
    return {
        "method": method,
        "path": path,
        "token": token,
        "host": host,
        "origin": origin,
        "fetch_site": fetch_site,
        "body": body,
        "length": length,
        "extra": extra,
    }


def send_http(server: Server, example: dict[str, Any]) -> tuple[int | None, str]:
    headers: dict[str, str] = {}
    if example["host"] == "right":
        headers["Host"] = server.host
    elif example["host"] == "localhost":
        headers["Host"] = f"localhost:{server.port}"
    elif example["host"] == "evil":
        headers["Host"] = "evil.example"
    path = example["path"]
    if example["token"] == "right":
        headers["X-Msflash-Token"] = server.token
    elif example["token"] == "wrong":
        headers["X-Msflash-Token"] = server.token[:-1] + ("A" if server.token[-1] != "A" else "B")
    elif example["token"] == "query":
        path += ("&" if "?" in path else "?") + f"token={server.token}"
    if example["origin"] is not None:
        headers["Origin"] = f"http://{server.host}" if example["origin"] == "self" else example["origin"]
    if example["fetch_site"] is not None:
        headers["Sec-Fetch-Site"] = example["fetch_site"]
    headers.update(example["extra"])
    body = example["body"]
    length = example["length"]
    if length == "shorter":
        length = str(max(0, len(body) - 3))
    elif length == "longer":
        length = str(len(body) + 10)
    if headers.get("Content-Type") is None and body:
        headers["Content-Type"] = "application/json"
    return http(server, example["method"], path, headers, body, length=length)


garbage_requests = st.one_of(
    st.binary(min_size=1, max_size=300),
    st.sampled_from(
        [
            b"\r\n\r\n",
            b"GET\r\n\r\n",
            b"GET / HTTP/9.9\r\n\r\n",
            b"GET / HTTP/1.1\r\nHost\r\n\r\n",
            b"GET /" + b"a" * 70_000 + b" HTTP/1.1\r\n\r\n",
            b"GET / HTTP/1.1\r\n" + b"X: y\r\n" * 5000 + b"\r\n",
            b"POST /api/levels HTTP/1.1\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\nxx\r\n0\r\n\r\n",
            b"GET / HTTP/1.1\r\nHost: a\r\nHost: b\r\n\r\n",
            b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03",  # a TLS ClientHello's start
            b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n",  # HTTP/2's preface
        ]
    ),
)


def ws_frame(opcode: int, payload: bytes, *, masked: bool = True, fin: bool = True, rsv: int = 0) -> bytes:
    first = (0x80 if fin else 0) | (rsv << 4) | opcode
    length = len(payload)
    if length < 126:
        head = bytes([first, (0x80 if masked else 0) | length])
    elif length < 65536:
        head = bytes([first, (0x80 if masked else 0) | 126]) + struct.pack(">H", length)
    else:
        head = bytes([first, (0x80 if masked else 0) | 127]) + struct.pack(">Q", length)
    if not masked:
        return head + payload
    mask = os.urandom(4)
    return head + mask + bytes(b ^ mask[i % 4] for i, b in enumerate(payload))


ws_frames = st.lists(
    st.one_of(
        st.builds(lambda p: ws_frame(0x1, p), st.binary(max_size=100)),
        st.builds(lambda v: ws_frame(0x1, json.dumps(v).encode()), json_values),
        st.builds(lambda p: ws_frame(0x2, p), st.binary(max_size=100)),
        st.builds(lambda p: ws_frame(0x1, p, masked=False), st.binary(max_size=50)),
        st.builds(lambda op, p: ws_frame(op, p), st.sampled_from([0x3, 0x4, 0x5, 0xB, 0xF]), st.binary(max_size=20)),
        st.builds(lambda p: ws_frame(0x1, p, rsv=7), st.binary(max_size=20)),
        st.builds(lambda p: ws_frame(0x1, p, fin=False), st.binary(max_size=20)),
        st.builds(lambda p: ws_frame(0x9, p), st.binary(max_size=125)),
        st.builds(lambda code: ws_frame(0x8, struct.pack(">H", code)), st.integers(0, 65535)),
        st.just(ws_frame(0x2, b"a" * 5_000_000)),
        st.just(ws_frame(0x0, b"continuation without a start")),
    ),
    max_size=5,
)


@st.composite
def ws_examples(draw: st.DrawFn) -> dict[str, Any]:
    return {
        "key": draw(st.sampled_from(["good", "good", "good", "missing", "short"])),
        "version": draw(st.sampled_from(["13", "13", "13", "8", ""])),
        "token": draw(st.sampled_from(["right", "right", "wrong", "missing"])),
        "frames": draw(ws_frames),
        "end": draw(st.sampled_from(["abort", "close", "half", "read"])),
    }


def send_ws(server: Server, example: dict[str, Any]) -> tuple[int | None, str]:
    key = {"good": base64.b64encode(os.urandom(16)).decode(), "short": "abc", "missing": None}[example["key"]]
    token = {"right": server.token, "wrong": "x" * 32, "missing": None}[example["token"]]
    path = "/ws" + (f"?token={token}" if token is not None else "")
    lines = [f"GET {path} HTTP/1.1", f"Host: {server.host}", "Upgrade: websocket", "Connection: Upgrade"]
    if key is not None:
        lines.append(f"Sec-WebSocket-Key: {key}")
    if example["version"]:
        lines.append(f"Sec-WebSocket-Version: {example['version']}")
    with socket.create_connection(("127.0.0.1", server.port), timeout=ANSWER_TIMEOUT_S) as sock:
        sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        answer = b""
        while b"\r\n\r\n" not in answer:
            chunk = sock.recv(1)
            if not chunk:
                return None, ""
            answer += chunk
        status = _status(answer)
        if status != 101:
            return status, ""
        for frame in example["frames"]:
            try:
                sock.sendall(frame)
            except OSError:
                break
        if example["end"] == "close":
            with contextlib.suppress(OSError):
                sock.sendall(ws_frame(0x8, struct.pack(">H", 1000)))
        elif example["end"] == "read":
            with contextlib.suppress(OSError, TimeoutError):
                sock.settimeout(0.5)
                sock.recv(65536)
        elif example["end"] == "abort":
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))  # RST on close
        return 101, ""


def _unfinished(example: Any) -> bool:
    """Whether the example sent less than a whole request (the server rightly waits for the rest)."""
    if isinstance(example, bytes):
        return True  # garbage: any unterminated prefix of a request
    length = example["length"]
    return length in ("longer", "99999999999") or example["extra"].get("Transfer-Encoding") == "chunked"


# -- the run -------------------------------------------------------------------------------------
def main() -> int:
    parser = argparse.ArgumentParser()
    parser.add_argument("--examples", type=int, default=200)
    parser.add_argument("--memory-gib", type=float, default=3.0)
    args = parser.parse_args()
    outcomes: collections.Counter[str] = collections.Counter()
    broken: list[str] = []
    with tempfile.TemporaryDirectory() as tmp:
        server = Server(Path(tmp) / "runs", args.memory_gib)
        try:

            def judge(kind: str, example: Any, status: int | None, body: str) -> None:
                outcomes[f"{kind} {status if status is not None else 'closed'}"] += 1
                unfinished = kind in ("garbage", "http") and status == -1  # the server waits for the rest
                if status is not None and status not in ALLOWED and not (kind == "ws" and status == 101):
                    if not unfinished or not _unfinished(example):
                        raise AssertionError(f"{kind} {example!r:.300}: status {status} {body[:300]}")
                if not server.alive():
                    broken.append(f"{kind} {example!r:.300}: the server died")
                    raise SystemExit(1)
                state, _ = http(server, "GET", "/api/state", {"Host": server.host})
                if state != 200:
                    raise AssertionError(f"{kind} {example!r:.300}: /api/state answered {state} afterwards")

            examples = settings(
                max_examples=args.examples,
                derandomize=True,
                database=None,
                deadline=None,
                suppress_health_check=list(HealthCheck),
            )

            @examples
            @given(http_examples())
            def fuzz_http(example: dict[str, Any]) -> None:
                judge("http", example, *send_http(server, example))

            @settings(examples, max_examples=max(10, args.examples // 4))
            @given(garbage_requests)
            def fuzz_garbage(data: bytes) -> None:
                judge("garbage", data, *raw_request(server, data, wait_s=2.0))

            @settings(examples, max_examples=max(10, args.examples // 2))
            @given(ws_examples())
            def fuzz_ws(example: dict[str, Any]) -> None:
                judge("ws", example, *send_ws(server, example))

            try:
                fuzz_http()
                fuzz_garbage()
                fuzz_ws()
                out_of_order(server, judge)
            except AssertionError as err:
                broken.append(str(err))
        finally:
            status, err = server.stop() if server.alive() else (server.process.returncode, "")
        if status != 0 or "Traceback" in err or "unexpected" in err:
            broken.append(f"stop: exit {status}; stderr tail: {err[-2000:]}")
        if not broken and server.transcript.exists():
            sent = [line for line in server.transcript.read_text().splitlines() if line.startswith(">")]
            if sent and ":OFF*" not in sent[-1] and not any(":OFF*" in line for line in sent[-3:]):
                broken.append(f"stop: the last commands to the booth were {sent[-3:]}; expected OFF")
    if broken:
        print("\n".join(broken))
        return 1
    print(json.dumps({"examples": args.examples, "outcomes": dict(sorted(outcomes.items()))}))
    return 0


def out_of_order(server: Server, judge: Any) -> None:
    """A sequence fired, then every other call while it runs (409 where it would change the rig), twice."""
    token = {"Host": server.host, "X-Msflash-Token": server.token, "Content-Type": "application/json"}
    for calls in (
        [("/api/settings", b'{"exposure_us": 3000}'), ("/api/levels", b'{"levels": [1, 1, 1, 1, 1, 1, 1]}')],
        [("/api/leds-off", b""), ("/api/sequence", b"{}"), ("/api/settings", b'{"mode": "matching"}')],
    ):
        status, body = http(server, "POST", "/api/sequence", token, b'{"mode": "complementary"}')
        judge("order", "fire", status, body)
        for path, body_ in calls:
            judge("order", path, *http(server, "POST", path, token, body_))
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline:  # the sequence ends (done or failed), never hangs
            _, text = http(server, "GET", "/api/state", {"Host": server.host})
            if json.loads(text)["job"]["status"] != "running":
                break
            time.sleep(0.2)
        else:
            judge("order", "sequence", 599, "the sequence did not end within 300 s")


if __name__ == "__main__":
    sys.exit(main())
