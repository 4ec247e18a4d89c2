"""``msflash live``'s guard, by plain HTTP (aiohttp's client): Host, Origin, the token, run files, LEDs off.

The booth's levels are read from the emulator at the far end of the pty, never from the server.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
from pathlib import Path
from typing import Any

import aiohttp
import pytest
from yarl import URL

from msflash.acquisition.app import cli
from msflash.acquisition.app.live.requests import bind
from msflash.acquisition.app.live.server import LAST_CLIENT_GRACE_S, TOKEN_HEADER, LiveServer
from msflash.acquisition.errors import UsageError
from msflash.acquisition.session.rig import open_rig
from tests.acquisition.support.live import (
    emulator_levels,
    live_server,
    page_token,
    serve_in_thread,
    start_live_process,
    stopped_with_the_leds_off,
    wait_until,
)


def request(method: str, url: str | URL, headers: dict[str, str] | None = None, body: Any = None) -> tuple[int, str]:
    """One request by aiohttp's client: (status, body text)."""

    async def go() -> tuple[int, str]:
        async with aiohttp.ClientSession() as session:
            data = body if isinstance(body, str | bytes) or body is None else json.dumps(body)
            async with session.request(method, url, headers=headers or {}, data=data) as response:
                return response.status, await response.text()

    return asyncio.run(go())


def test_foreign_host_origin_and_missing_token_are_refused(tmp_path: Path) -> None:
    with live_server(tmp_path / "runs") as server:
        base = f"http://127.0.0.1:{server.port}"
        status, page = request("GET", base + "/")
        assert status == 200 and f'content="{server.token}"' in page  # loopback: the page carries the token
        set_led2 = {"channel": 2, "level": 0.25}
        token = {TOKEN_HEADER: server.token}
        for headers, why in (
            ({}, "no token"),
            ({TOKEN_HEADER: "wrong"}, "a wrong token"),
            ({**token, "Origin": "http://evil.example"}, "a foreign Origin"),
            ({**token, "Host": f"evil.example:{server.port}"}, "a rebound DNS name"),
            ({**token, "Sec-Fetch-Site": "cross-site"}, "a cross-site fetch"),
        ):
            status, text = request("POST", base + "/api/levels", headers, set_led2)
            assert status == 403, why
            assert json.loads(text)["error"]
        assert emulator_levels(server) == (0.0,) * 7  # nothing reached the booth
        status, _ = request("GET", base + "/api/state", {"Host": f"evil.example:{server.port}"})
        assert status == 403

        async def websocket(url: str) -> int:
            async with aiohttp.ClientSession() as session:
                try:
                    async with session.ws_connect(url):
                        return 101
                except aiohttp.WSServerHandshakeError as err:
                    return err.status

        assert asyncio.run(websocket(base + "/ws")) == 403
        status, _ = request("POST", base + "/api/levels", {**token, "Origin": base}, set_led2)
        assert status == 200
        assert emulator_levels(server)[2] == pytest.approx(0.25, abs=1e-4)


def test_only_files_inside_a_run_folder_are_served(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    (runs / "r1" / "sequence").mkdir(parents=True)
    (runs / "r1" / "run.json").write_text('{"frames": 9}\n')
    (runs / "r1" / "report.html").write_text("# msflash run\n")
    (tmp_path / "secret.txt").write_text("SECRET\n")
    (runs / "r1" / "link.txt").symlink_to(tmp_path / "secret.txt")
    with live_server(runs) as server:
        base = f"http://127.0.0.1:{server.port}"
        status, text = request("GET", base + "/runs/r1/files/report.html")
        assert (status, text) == (200, "# msflash run\n")
        status, text = request("GET", base + "/runs/r1/")  # a run's page is the report `run` wrote
        assert (status, text) == (200, "# msflash run\n")
        for path in (
            "/runs/r1/files/../../secret.txt",
            "/runs/r1/files/%2e%2e/%2e%2e/secret.txt",
            "/runs/r1/files/..%2f..%2fsecret.txt",
            "/runs/r1/files/link.txt",
            "/runs/..%2f/files/secret.txt",
            "/static/..%2fserver.py",
            "/static/server.py",
        ):
            status, text = request("GET", URL(base + path, encoded=True))
            assert status in (400, 403, 404), path
            assert "SECRET" not in text and "import" not in text, path
        status, text = request("GET", base + "/api/runs")
        assert json.loads(text)["runs"] == [{"name": "r1", "reported": True, "frames": 9}]


def test_bad_input_is_one_line_and_leaves_the_booth_alone(tmp_path: Path) -> None:
    with live_server(tmp_path / "runs") as server:
        base = f"http://127.0.0.1:{server.port}"
        token = {TOKEN_HEADER: server.token}
        for body, field in (
            ({"channel": 0, "level": 2.0}, "levels"),
            ({"channel": 9, "level": 0.5}, "channel"),
            ({"channel": 0, "level": "bright"}, "level"),
            ("not json", "request body"),
            ({"exposure_us": -5}, "exposure_us"),
        ):
            status, text = request(
                "POST", base + "/api/levels" if "exposure_us" not in body else base + "/api/settings", token, body
            )
            assert status == 400, body
            message = json.loads(text)["error"]
            assert field in message and "\n" not in message
        assert emulator_levels(server) == (0.0,) * 7


def test_a_page_that_only_the_token_opens_when_asked(tmp_path: Path) -> None:
    # What --host ADDRESS does beyond loopback, forced here on 127.0.0.1 (the tests listen on loopback only).
    with live_server(tmp_path / "runs", token_for_pages=True) as server:
        base = f"http://127.0.0.1:{server.port}"
        assert request("GET", base + "/")[0] == 403
        assert request("GET", base + "/api/state")[0] == 403
        assert server.url.endswith(f"?token={server.token}")

        async def with_cookie() -> tuple[int, int]:
            # unsafe: aiohttp's jar keeps no cookie of an IP address unless told to (browsers do keep them)
            async with aiohttp.ClientSession(cookie_jar=aiohttp.CookieJar(unsafe=True)) as session:
                async with session.get(server.url) as page:
                    first = page.status
                async with session.get(base + "/api/state") as state:  # the page's cookie opens the rest
                    return first, state.status

        assert asyncio.run(with_cookie()) == (200, 200)


def test_leds_go_off_when_the_last_page_leaves_and_when_the_server_stops(tmp_path: Path) -> None:
    sock = bind("127.0.0.1", 0)
    with open_rig("sim") as rig:
        server = LiveServer(rig, tmp_path / "runs", sock)
        base = f"http://127.0.0.1:{server.port}"
        token = {TOKEN_HEADER: server.token}
        with serve_in_thread(server):

            async def watch_then_leave() -> tuple[float, ...]:
                async with aiohttp.ClientSession() as session:
                    async with session.ws_connect(f"{base}/ws?token={server.token}") as ws:
                        first = await ws.receive_json()
                        assert first["type"] == "state"
                        frame = await ws.receive_bytes()  # a live frame: uint32 length, JSON header, JPEG
                        length = int.from_bytes(frame[:4], "little")
                        assert json.loads(frame[4 : 4 + length])["width"] == 640
                        assert frame[4 + length : 4 + length + 2] == b"\xff\xd8"
                        async with session.post(base + "/api/levels", headers=token, json={"levels": [0.5] * 7}) as r:
                            assert r.status == 200
                        return emulator_levels(server)

            assert asyncio.run(watch_then_leave()) == pytest.approx((0.5,) * 7, abs=1e-4)
            wait_until(
                lambda: emulator_levels(server) == (0.0,) * 7,
                "LEDs off after the last page left",
                10 * LAST_CLIENT_GRACE_S,
            )
            assert request("POST", base + "/api/levels", token, {"levels": [0.3] * 7})[0] == 200
            assert emulator_levels(server) == pytest.approx((0.3,) * 7, abs=1e-4)
        # The server stopped (as on Ctrl-C): LEDs off before the rig itself is closed.
        assert emulator_levels(server) == (0.0,) * 7
    sock.close()


def test_live_refuses_a_busy_port_and_a_mosaic_on_the_fake_in_one_line(tmp_path: Path, capsys) -> None:
    busy = bind("127.0.0.1", 0)
    try:
        port = busy.getsockname()[1]
        assert cli.main(["live", "--port", str(port), "--runs", str(tmp_path / "runs")]) == 2
        error = capsys.readouterr().err.strip()
        assert error.startswith("msflash: error: --host 127.0.0.1 --port") and "\n" not in error
    finally:
        busy.close()
    assert cli.main(["live", "--rig", "aravis-fake", "--cfa", "RGGB", "--port", "0"]) == 2
    assert "--cfa" in capsys.readouterr().err
    assert not os.path.exists(tmp_path / "runs")


@pytest.mark.parametrize(
    ("arguments", "why"),
    [
        (
            ["--rig", "sim", "--roi", "0,0,64,48"],
            "--roi: describes a hardware rig's camera or booth, but the rig is 'sim'",
        ),
        (["--rig", "sim", "--camera", "Fake_1"], "--rig sim: --camera/--port name hardware devices; expected --rig hw"),
        (
            ["--rig", "hw", "--flicker", "100:0.3"],
            "--flicker: describes the simulated world's lamp, but the rig is 'hw'",
        ),
        (["--rig", "replay:runs/x"], "--rig replay:runs/x: a replay serves a recorded sequence in its order"),
    ],
)
def test_live_opens_its_rig_as_run_does_refusing_what_the_rig_would_ignore(
    tmp_path: Path, capsys, arguments: list[str], why: str
) -> None:
    """``live`` takes rig_choice's option groups and its one opener: the same refusals as ``run``."""
    assert cli.main(["live", *arguments, "--port", "0", "--runs", str(tmp_path / "runs")]) == 2
    error = capsys.readouterr().err.strip()
    assert why in error and "\n" not in error


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGHUP], ids=["ctrl-c", "terminal-closed"])
def test_msflash_live_serves_the_page_and_ctrl_c_stops_it_with_the_leds_off(
    tmp_path: Path, stop: signal.Signals
) -> None:
    process, url, transcript = start_live_process(tmp_path)
    try:
        assert url.startswith("http://127.0.0.1:") and url.endswith("/")
        status, page = request("GET", url)
        token = page_token(page)
        assert status == 200 and len(token) >= 24
        assert request("POST", url + "api/levels", {TOKEN_HEADER: token}, {"channel": 1, "level": 0.5})[0] == 200
        process.send_signal(stop)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert process.returncode == 0, err
    assert err.strip().splitlines()[-1] == "msflash: live view stopped; LEDs off"
    sent = [line for line in transcript.read_text().splitlines() if line.startswith(">")]
    assert ":SET 0000 8000 0000" in [line for line in sent if ":SET " in line][-1]
    assert stopped_with_the_leds_off(transcript)


def test_a_sequence_at_the_live_exposure_and_a_second_fire_while_it_runs(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    with live_server(runs) as server:
        base = f"http://127.0.0.1:{server.port}"
        token = {TOKEN_HEADER: server.token}
        assert (
            request("POST", base + "/api/settings", token, {"exposure_us": 4000, "sequence_exposure": "live"})[0] == 200
        )
        status, text = request("POST", base + "/api/sequence", token, {"mode": "matching"})
        assert status == 202
        run = json.loads(text)["run"]
        assert request("POST", base + "/api/sequence", token, {})[0] == 409  # one sequence at a time

        def finished() -> dict | None:
            job = json.loads(request("GET", base + "/api/state")[1])["job"]
            return job if job["status"] in ("done", "failed") else None

        job = wait_until(finished, "the sequence to finish", timeout_s=240)
        assert job["status"] == "done" and job["run"] == run and job["landed"] == job["total"] == 9
        summary = json.loads((runs / run / "run.json").read_text())
        assert summary["recaptured_mode"] == "matching"
        assert summary["exposure"]["mode"] == "fixed" and summary["exposure"]["ambient_exposure_us"] == 4000
        sequence = json.loads((runs / run / "sequence" / "sequence.json").read_text())
        assert [frame["exposure_us"] for frame in sequence["frames"]] == [4000] * 9
        assert emulator_levels(server) == (0.0,) * 7  # no page watches: the sequence left the LEDs off
        info = json.loads(request("GET", f"{base}/api/runs/{run}")[1])
        assert "report.html" in info["files"] and '<g id="band">' in info["charts"]["ambient"]
        # One palette with the report's spectra.png (acquisition/app/plot_style.py), axes labelled with units.
        from msflash.acquisition.app.plot_style import PALETTE, SPECTRAL_AXIS_LABEL

        ambient = info["charts"]["ambient"]
        estimate = ambient[ambient.index('<g id="estimate">') :].split("</g>")[0]
        assert f"stroke: {PALETTE.ambient.lower()}" in estimate.lower()
        mixes = info["charts"]["mixes"]
        matching = mixes[mixes.index('<g id="mix-matching-flash">') :].split("</g>")[0]
        assert f"stroke: {PALETTE.matching.lower()}" in matching.lower()
        assert "wavelength (nm)" in ambient and SPECTRAL_AXIS_LABEL.split(" (")[0] in ambient
        assert "<clipPath id=" in ambient  # what leaves the axes is clipped to them (the band did not)


def test_a_wildcard_address_is_refused() -> None:
    with pytest.raises(UsageError, match="wildcard"):
        bind("0.0.0.0", 0)


def test_hostile_request_bodies_are_400_naming_the_field_and_leave_the_leds_on(tmp_path: Path) -> None:
    # Each of these was a 500 ("… (LEDs switched off)") or a JSON value taken silently: a huge
    # integer (OverflowError), an unknown charset (LookupError; JSON is read as UTF-8 whatever it
    # claims), a gzip body that does not inflate,
    # nesting deeper than the recursion limit, a key twice (the last one won).
    with live_server(tmp_path / "runs") as server:
        base = f"http://127.0.0.1:{server.port}"
        token = {TOKEN_HEADER: server.token}
        status, _ = request("POST", base + "/api/levels", token, {"channel": 2, "level": 0.25})
        assert status == 200
        assert emulator_levels(server)[2] == pytest.approx(0.25, abs=1e-4)
        json_type = {**token, "Content-Type": "application/json"}
        for path, headers, body, field in (
            ("/api/settings", json_type, '{"exposure_us": 1' + "0" * 400 + "}", "exposure_us"),
            ("/api/settings", json_type, '{"gain": NaN}', "gain"),
            ("/api/levels", json_type, '{"levels": [Infinity, 0, 0, 0, 0, 0, 0]}', "levels[0]"),
            ("/api/settings", {**token, "Content-Type": "application/json; charset=bogus"}, '{"gain": "x"}', "gain"),
            ("/api/settings", {**json_type, "Content-Encoding": "gzip"}, "not gzip", "request body"),
            ("/api/settings", json_type, "[" * 60_000, "request body"),
            ("/api/settings", json_type, '{"a":' * 10_000 + "1" + "}" * 10_000, "request body"),
            ("/api/settings", json_type, '{"overlay": true, "overlay": false}', "overlay"),
            ("/api/settings", json_type, b'{"mode": "\xff"}', "request body"),
            ("/api/levels", json_type, '{"channel": 2}', "level"),  # the value missing: not taken as 0
        ):
            status, text = request("POST", base + path, headers, body)
            assert status == 400, (body[:40], text)
            message = json.loads(text)["error"]
            assert field in message and "\n" not in message and len(message) < 300, message
        # No request failed as a server error, so the live level is still lit.
        assert emulator_levels(server)[2] == pytest.approx(0.25, abs=1e-4)
        assert server.state.error is None
