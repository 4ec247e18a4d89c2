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
from pathlib import Path

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


def test_sigterm_stops_a_fired_sequence_between_frames(tmp_path: Path) -> None:
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

            def post(path: str, body: dict) -> dict:
                request = urllib.request.Request(
                    url.rstrip("/") + path,
                    data=json.dumps(body).encode(),
                    headers={"Content-Type": "application/json", "X-Msflash-Token": token},
                )
                with urllib.request.urlopen(request, timeout=HANG_GUARD_S) as answer:
                    return json.loads(answer.read())

            def job() -> dict:
                with urllib.request.urlopen(url.rstrip("/") + "/api/state", timeout=HANG_GUARD_S) as answer:
                    return json.loads(answer.read())["job"]

            post("/api/settings", {"sequence_exposure": "live"})  # no metering: straight to the sequence
            run = post("/api/sequence", {"mode": "complementary"})["run"]
            fired = wait_for(lambda: (state := job())["landed"] >= 1 and state, "the sequence's first frame")
            assert fired["status"] == "running" and fired["total"] == 9  # ambient, 7 LEDs, the flash
            live.send_signal(signal.SIGTERM)
            assert live.wait(HANG_GUARD_S) == 0
            said = live.stderr.read()
        booth.send_signal(signal.SIGINT)
        assert booth.wait(HANG_GUARD_S) == 0
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
