"""Reading a sequence while ``capture`` writes it (issue 19 item 6): ``check`` and ``estimate``
either read a consistent prefix (``complete: false``, every listed frame intact) or refuse with
one line, never crash. The writer is a real process; the readers run in this one, as fast as they
can, so they meet the writer at every stage (bounded by timeouts that fail the test, never by
sleeps that decide it)."""

from __future__ import annotations

import json
import math
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from tests.helpers import wait_for_frames

REPO = Path(__file__).resolve().parents[3]


def _read(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def _assert_clear(status: int, err: str) -> None:
    assert "Traceback" not in err and "unexpected" not in err, err
    assert status in (0, 2), (status, err)
    if status == 2:
        assert len([line for line in err.splitlines() if line.startswith("msflash: error: ")]) == 1, err


@pytest.mark.timeout(600)
def test_check_and_estimate_read_a_consistent_prefix_while_capture_writes(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "live"
    sequence = out / "sequence"
    writer = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "msflash.acquisition.app.cli",
            "capture",
            "--sync",
            "booth",
            "--exposure-us",
            "1500000",
            "--scene",
            "macbeth",
            "--out",
            str(out),
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    partial_checks, prefixes, estimates = 0, set(), {0: 0, 2: 0}
    try:
        wait_for_frames(writer, sequence / "sequence.json", 1)
        while writer.poll() is None:
            status, stdout, err = _read(capsys, "check", str(sequence), "--json")
            _assert_clear(status, err)
            summary = json.loads(stdout)
            if status == 0:
                assert summary["intact"] == summary["frames"] and summary["intact_sequence"], summary
                if not summary["complete"]:
                    partial_checks += 1
                    prefixes.add(summary["frames"])
            status, stdout, err = _read(capsys, "estimate", str(sequence), "--json")
            _assert_clear(status, err)
            estimates[status] += 1
            if status == 0:
                assert all(math.isfinite(v) for v in json.loads(stdout)["spectrum"])
    finally:
        if writer.poll() is None:
            writer.send_signal(signal.SIGKILL)
        _, writer_err = writer.communicate(timeout=120)
    assert writer.returncode == 0, writer_err.decode()
    # The readers met the sequence part-written, at more than one length, and always consistent.
    assert partial_checks >= 2 and len(prefixes) >= 2, (partial_checks, prefixes)
    status, stdout, err = _read(capsys, "check", str(sequence), "--json")
    assert status == 0, err
    assert json.loads(stdout)["complete"] and json.loads(stdout)["frames"] == 8
    # (The slow exposure saturates the chart, so estimate refuses the whole sequence too, by name.)
    status, _, err = _read(capsys, "estimate", str(sequence), "--json")
    _assert_clear(status, err)
