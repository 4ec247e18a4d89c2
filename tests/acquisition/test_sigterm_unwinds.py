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

from msflash.acquisition.app.cli import main
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


def _export_process(sequence: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "-m", "msflash.acquisition.app.cli", "export", str(sequence), "--to", "dng,ome-tiff,csv,exr"]
        + ["--out", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def _stopped_while_staging(process: subprocess.Popen, parent: Path) -> None:
    """Wait until the export has a staging folder, then hold it still (SIGSTOP)."""
    deadline = time.monotonic() + 120  # a hang guard, not a timing
    while not _staging(parent):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "no staging folder appeared"
        time.sleep(0.005)
    os.kill(process.pid, signal.SIGSTOP)


def test_a_killed_exports_staging_folder_is_removed_by_the_next_export_with_a_note(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    """SIGKILL runs no handler: the staging folder and the name's lock file stay; the next export takes over."""
    sequence = write_test_sequence(tmp_path / "seq", cfa="RGGB")
    parent = tmp_path / "exports"
    parent.mkdir()
    out = parent / "out"
    process = _export_process(sequence, out)
    try:
        _stopped_while_staging(process, parent)
        os.kill(process.pid, signal.SIGKILL)
        process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()
    left = _staging(parent)
    assert len(left) == 1 and (parent / ".out.export-lock").exists() and not out.exists()
    assert main(["export", str(sequence), "--to", "csv", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"msflash: note: removed {left[0]}, the unfinished folder of an export that was stopped (killed?)" in err
    assert sorted(p.name for p in parent.iterdir()) == ["out"]


def test_of_two_exports_into_one_folder_the_second_names_the_first(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    sequence = write_test_sequence(tmp_path / "seq", cfa="RGGB")
    parent = tmp_path / "exports"
    parent.mkdir()
    out = parent / "out"
    first = _export_process(sequence, out)
    try:
        _stopped_while_staging(first, parent)
        status = main(["export", str(sequence), "--to", "csv", "--out", str(out)])
        err = capsys.readouterr().err.strip().splitlines()
        os.kill(first.pid, signal.SIGCONT)
        _, first_err = first.communicate(timeout=120)
    finally:
        if first.poll() is None:
            first.kill()
            first.communicate()
    assert status == 2 and len(err) == 1
    assert err[0].startswith(f"msflash: error: --out {out}: another export is writing it: msflash process {first.pid}")
    assert first.returncode == 0, first_err.decode()  # the first export was not disturbed
    assert sorted(p.name for p in parent.iterdir()) == ["out"]


def test_an_export_into_the_sequence_folder_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    sequence = write_test_sequence(tmp_path / "seq", cfa="RGGB")
    before = sorted(p.name for p in sequence.rglob("*"))
    assert main(["export", str(sequence), "--to", "csv", "--out", str(sequence / "frames" / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is inside the sequence folder" in err[0] and "--out" in err[0]
    assert sorted(p.name for p in sequence.rglob("*")) == before
    assert main(["check", str(sequence)]) == 0
