"""Crash safety of ``msflash capture`` in a subprocess on the sim rig.

The capture runs booth-paced with a long exposure, so the booth's step period (about 0.3 s) keeps
the sequence going long enough to interrupt it once two frames are on disk; the test only polls
the sequence file, it never sleeps for a set time.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from msflash.acquisition.sequence.reader import read_sequence
from tests.helpers import wait_for_frames

REPO = Path(__file__).resolve().parents[3]
SLOW_CAPTURE = ["capture", "--sync", "booth", "--exposure-us", "300000", "--scene", "macbeth"]


def _start(out: Path, *extra: str) -> subprocess.Popen[bytes]:
    command = [sys.executable, "-m", "msflash.acquisition.app.cli", *SLOW_CAPTURE, "--out", str(out), *extra]
    return subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def test_sigkill_leaves_a_readable_partial_sequence(tmp_path: Path) -> None:
    out = tmp_path / "killed"
    process = _start(out)
    try:
        wait_for_frames(process, out / "sequence" / "sequence.json", 2)
        process.send_signal(signal.SIGKILL)
        assert process.wait(timeout=30) == -signal.SIGKILL
    finally:
        if process.poll() is None:
            process.kill()
        process.communicate()
    sequence = read_sequence(out / "sequence")
    assert not sequence.complete
    assert 2 <= len(sequence.frames) < 8
    for index in range(len(sequence.frames)):
        assert sequence.load_frame(index).shape[:2] == sequence.load_frame(0).shape[:2]


def test_sigint_exits_130_with_the_leds_off(tmp_path: Path) -> None:
    out = tmp_path / "interrupted"
    transcript = tmp_path / "booth.txt"
    process = _start(out, "--log-serial", str(transcript))
    try:
        wait_for_frames(process, out / "sequence" / "sequence.json", 2)
        os.kill(process.pid, signal.SIGINT)
        _, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 130, err.decode()
    assert "interrupted; LEDs off" in err.decode()
    lines = [line for line in transcript.read_text().splitlines() if line[:1] in "><"]
    requests = [line for line in lines if line.startswith(">")]
    # The booth was running its table when interrupted; the last thing the host asked was OFF,
    # and the booth acknowledged it.
    assert any(":ARM BOOTH " in line for line in requests)
    assert requests[-1].split(":", 2)[2].startswith("OFF*")
    assert lines[-1].startswith("< =") and ":OK OFF*" in lines[-1]
    sequence = read_sequence(out / "sequence")
    assert not sequence.complete and len(sequence.frames) >= 2
