"""SIGTERM and SIGHUP unwind every command as Ctrl-C does: a real ``msflash export`` process stopped mid-write.

Before, only ``run``, ``capture`` and the booth commands turned SIGTERM into an exception; elsewhere
Python's default action killed the process where it stood, and an export left its hidden staging
folder (``.NAME.*.export-tmp``) behind.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.helpers import write_test_sequence


def _staging(parent: Path) -> list[Path]:
    return sorted(parent.glob(".*.export-tmp"))


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_stopping_signal_during_an_export_leaves_nothing_and_says_so_in_one_line(
    tmp_path: Path, stop: signal.Signals
) -> None:
    """SIGHUP is the terminal or SSH session closing under the command (it killed it where it stood)."""
    sequence = write_test_sequence(tmp_path / "seq", cfa="RGGB")
    parent = tmp_path / "exports"
    parent.mkdir()
    out = parent / "out"
    process = subprocess.Popen(
        [sys.executable, "-m", "msflash.acquisition.app.cli", "export", str(sequence), "--to", "dng,ome-tiff,csv,exr"]
        + ["--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        deadline = time.monotonic() + 120  # a hang guard, not a timing
        while not _staging(parent):
            assert process.poll() is None, process.communicate()
            assert time.monotonic() < deadline, "no staging folder appeared"
            time.sleep(0.005)
        # Held still while the signal is sent: it lands while the files are being written.
        os.kill(process.pid, signal.SIGSTOP)
        assert _staging(parent) and not out.exists()
        os.kill(process.pid, stop)
        os.kill(process.pid, signal.SIGCONT)
        _, err = process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    assert process.returncode == 128 + stop, err.decode()
    assert err.decode().strip().splitlines()[-1] == f"msflash: terminated ({stop.name})"
    assert "Traceback" not in err.decode()
    assert list(parent.iterdir()) == []
