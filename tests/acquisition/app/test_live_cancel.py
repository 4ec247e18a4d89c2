"""``msflash live`` stops a fired sequence between frames on SIGTERM, instead of waiting for its end.

Every part is a real process: ``msflash booth-emulator`` serves a pty with a slow USB-serial link
(its latency timer: each reply waits for the next tick), ``msflash live --rig sim --booth-port``
drives it, and the test fires a sequence through the page's API. Once the sequence's first frame
has landed, SIGTERM: the capture must stop before its next step (the runner's cancellation), switch
the LEDs off (what the booth holds, read from its ``--state-file`` when it stops), keep the frames
written (the sequence on disk ``complete: false``, no report), and ``msflash live`` must exit 0.
With a 200 ms tick every remaining step costs at least two ticks (``SET``, then ``STAT`` for the
levels the simulated camera renders), so the seven steps left after the first frame take seconds:
had the capture waited for its end, the sequence would be complete. The waits are hang guards,
never timings.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.acquisition.app.test_live_slow_pages import (
    open_sockets,
    stalled_page,
    unfinished_handshake,
    wait_until_stalled,
)

ROOT = Path(__file__).resolve().parents[3]
HANG_GUARD_S = 120.0
MSFLASH = (sys.executable, "-m", "msflash.acquisition.app.cli")
LINK_TICK_MS = 200
"""The emulated USB-serial latency timer: below the driver's 1 s reply timeout, long enough to make a step slow."""


@contextmanager
def process(*argv: str) -> Iterator[subprocess.Popen]:
    """``msflash ARGV`` in a process of its own, killed if the test leaves it running."""
    child = subprocess.Popen([*MSFLASH, *argv], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        yield child
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        assert child.stdout is not None and child.stderr is not None
        child.stdout.close()
        child.stderr.close()


def wait_for(condition, what: str):  # noqa: ANN001, ANN201 - a predicate and its value
    """Poll ``condition`` until it is truthy; fail naming ``what`` after the hang guard."""
    deadline = time.monotonic() + HANG_GUARD_S
    while not (value := condition()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)
    return value


@dataclass
class LiveBeside:
    """``msflash live --rig sim`` driving a ``msflash booth-emulator`` on a pty, both real processes."""

    live: subprocess.Popen
    booth: subprocess.Popen
    url: str
    token: str
    state_file: Path
    runs: Path

    def post(self, path: str, body: dict) -> dict:
        request = urllib.request.Request(
            self.url.rstrip("/") + path,
            data=json.dumps(body).encode(),
            headers={"Content-Type": "application/json", "X-Msflash-Token": self.token},
        )
        with urllib.request.urlopen(request, timeout=HANG_GUARD_S) as answer:
            return json.loads(answer.read())

    def job(self) -> dict:
        with urllib.request.urlopen(self.url.rstrip("/") + "/api/state", timeout=HANG_GUARD_S) as answer:
            return json.loads(answer.read())["job"]

    def fire(self) -> tuple[str, dict]:
        """A sequence fired at the live exposure (no metering), once its first frame has landed: its run and job."""
        self.post("/api/settings", {"sequence_exposure": "live"})
        run = self.post("/api/sequence", {"mode": "complementary"})["run"]
        return run, wait_for(lambda: (state := self.job())["landed"] >= 1 and state, "the sequence's first frame")


@contextmanager
def live_beside_a_booth(tmp_path: Path) -> Iterator[LiveBeside]:
    """Both processes started, the page's URL and token read; the booth stopped (and must exit 0) at the end."""
    state_file = tmp_path / "booth-state.json"
    runs = tmp_path / "runs"
    with process("booth-emulator", "--state-file", str(state_file), "--latency-ms", str(LINK_TICK_MS)) as booth:
        assert booth.stdout is not None
        port = booth.stdout.readline().strip()
        assert port.startswith("/dev/pts/"), port
        with process("live", "--rig", "sim", "--booth-port", port, "--port", "0", "--runs", str(runs)) as live:
            assert live.stdout is not None and live.stderr is not None
            url = live.stdout.readline().strip()
            assert url.startswith("http://127.0.0.1:"), live.stderr.read() if live.poll() is not None else url
            token = next(
                line.rsplit(" ", 1)[1].strip() for line in iter(live.stderr.readline, "") if "session token" in line
            )
            yield LiveBeside(live, booth, url, token, state_file, runs)
        booth.send_signal(signal.SIGINT)
        assert booth.wait(HANG_GUARD_S) == 0


def test_sigterm_stops_a_fired_sequence_between_frames(tmp_path: Path) -> None:
    with live_beside_a_booth(tmp_path) as rig:
        run, fired = rig.fire()
        assert fired["status"] == "running" and fired["total"] == 9  # ambient, 7 LEDs, the flash
        signalled = time.monotonic()
        rig.live.send_signal(signal.SIGTERM)
        assert rig.live.wait(HANG_GUARD_S) == 0
        print(f"live exited {time.monotonic() - signalled:.2f} s after SIGTERM mid-sequence, no page open")
        assert rig.live.stderr is not None
        said = rig.live.stderr.read()
    runs, state_file = rig.runs, rig.state_file
    assert "stopping the sequence in progress before its next frame" in said, said
    assert "live view stopped; LEDs off" in said, said
    sequence = json.loads((runs / run / "sequence" / "sequence.json").read_text())
    assert sequence["complete"] is False
    written = [frame["role"] for frame in sequence["frames"]]
    assert 1 <= len(written) < 9 and "flash" not in written, written
    for frame in sequence["frames"]:  # every frame listed is on disk, whole (the writer drained)
        assert (runs / run / "sequence" / frame["file"]).stat().st_size > 0
    assert not (runs / run / "run.json").exists()  # a stopped sequence is not reported
    state = json.loads(state_file.read_text())
    assert state["leds_on"] is False and state["link"] == "open"


STOP_TIMES_S: dict[str, float] = {}
"""Seconds from the signal to the process's exit, per signal (measured, printed; never asserted below the guard)."""


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGINT], ids=["SIGTERM", "SIGINT"])
def test_a_signal_mid_sequence_with_stalled_pages_open_stops_live_with_the_leds_off(
    tmp_path: Path, stop: signal.Signals
) -> None:
    """Issue 32 item 1's promise while a sequence fires: pages that stopped reading (a tiny receive buffer,
    their sends blocked) and one that never finished its handshake stay open; the signal must still stop the
    capture before its next frame, switch the LEDs off and end ``live`` (exit 0), without waiting for them.
    The exit time is measured and printed (``-s``); only the hang guard bounds it (docs/reliability.md §6)."""
    with live_beside_a_booth(tmp_path) as rig:
        server_port = int(rig.url.rsplit(":", 1)[1].strip("/"))
        pages = [stalled_page(server_port, rig.token, receive_buffer=1024) for _ in range(3)]
        with open_sockets(*pages, unfinished_handshake(server_port)):
            for page in pages:  # each page's queue is full (its sends block) or the server dropped it
                wait_until_stalled(server_port, page)
            run, fired = rig.fire()
            assert fired["status"] == "running"
            signalled = time.monotonic()
            rig.live.send_signal(stop)
            leds_off_s = None  # when the booth itself holds the LEDs off (its state file), for the report
            while rig.live.poll() is None and time.monotonic() < signalled + HANG_GUARD_S:
                if leds_off_s is None and json.loads(rig.state_file.read_text())["leds_on"] is False:
                    leds_off_s = time.monotonic() - signalled
                time.sleep(0.01)
            status = rig.live.wait(HANG_GUARD_S)  # the stalled pages stay open meanwhile
            STOP_TIMES_S[stop.name] = time.monotonic() - signalled
            assert rig.live.stderr is not None
            said = rig.live.stderr.read()
    runs, state_file = rig.runs, rig.state_file
    print(
        f"live exited {STOP_TIMES_S[stop.name]:.2f} s after {stop.name} mid-sequence with 3 stalled pages open; "
        f"the booth held the LEDs off after {leds_off_s if leds_off_s is None else round(leds_off_s, 2)} s"
    )
    assert status == 0, said
    assert "stopping the sequence in progress before its next frame" in said, said
    assert said.strip().splitlines()[-1] == "msflash: live view stopped; LEDs off", said
    assert "Traceback" not in said, said
    sequence = json.loads((runs / run / "sequence" / "sequence.json").read_text())
    assert sequence["complete"] is False
    assert 1 <= len(sequence["frames"]) < 9
    state = json.loads(state_file.read_text())
    assert state["leds_on"] is False and state["link"] == "open"
