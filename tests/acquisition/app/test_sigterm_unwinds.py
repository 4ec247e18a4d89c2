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
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from tests.helpers import write_test_sequence


def _staging(parent: Path) -> list[Path]:
    return sorted(parent.glob(".*.export-tmp"))


@dataclass(frozen=True)
class Export:
    """A sequence to export and a new folder ``out`` in an empty ``parent``."""

    sequence: Path
    parent: Path
    out: Path


@pytest.fixture
def export(tmp_path: Path) -> Export:
    parent = tmp_path / "exports"
    parent.mkdir()
    return Export(write_test_sequence(tmp_path / "seq", cfa="RGGB"), parent, parent / "out")


@contextmanager
def export_process(export: Export) -> Iterator[subprocess.Popen]:
    """A real ``msflash export`` of every format into ``export.out``; killed if still running at the end."""
    process = subprocess.Popen(
        [sys.executable, "-m", "msflash.acquisition.app.cli", "export", str(export.sequence)]
        + ["--to", "dng,ome-tiff,csv,exr", "--out", str(export.out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        # Under nohup the test runner ignores SIGHUP and msflash keeps an ignored SIGHUP ignored, as nohup asks.
        preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_DFL),
    )
    try:
        yield process
    finally:
        if process.poll() is None:
            process.kill()
            process.communicate()


def _stopped_while_staging(process: subprocess.Popen, parent: Path) -> None:
    """Wait until the export has a staging folder, then hold it still (SIGSTOP)."""
    deadline = time.monotonic() + 120  # a hang guard, not a timing
    while not _staging(parent):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "no staging folder appeared"
        time.sleep(0.005)
    os.kill(process.pid, signal.SIGSTOP)


@pytest.mark.parametrize("stop", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_a_stopping_signal_during_an_export_leaves_nothing_and_says_so_in_one_line(
    export: Export, stop: signal.Signals
) -> None:
    """SIGHUP is the terminal or SSH session closing under the command (it killed it where it stood)."""
    with export_process(export) as process:
        # Held still while the signal is sent: it lands while the files are being written.
        _stopped_while_staging(process, export.parent)
        assert _staging(export.parent) and not export.out.exists()
        os.kill(process.pid, stop)
        os.kill(process.pid, signal.SIGCONT)
        _, err = process.communicate(timeout=120)
    assert process.returncode == 128 + stop, err.decode()
    assert err.decode().strip().splitlines()[-1] == f"msflash: terminated ({stop.name})"
    assert "Traceback" not in err.decode()
    assert list(export.parent.iterdir()) == []


def test_a_killed_exports_staging_folder_is_removed_by_the_next_export_with_a_note(
    export: Export, capsys: pytest.CaptureFixture
) -> None:
    """SIGKILL runs no handler: the staging folder and the name's lock file stay; the next export takes over."""
    with export_process(export) as process:
        _stopped_while_staging(process, export.parent)
        os.kill(process.pid, signal.SIGKILL)
        process.communicate(timeout=120)
    left = _staging(export.parent)
    assert len(left) == 1 and (export.parent / ".out.export-lock").exists() and not export.out.exists()
    assert main(["export", str(export.sequence), "--to", "csv", "--out", str(export.out)]) == 0
    err = capsys.readouterr().err
    assert f"msflash: note: removed {left[0]}, the unfinished folder of an export that was stopped (killed?)" in err
    assert sorted(p.name for p in export.parent.iterdir()) == ["out"]


def test_of_two_exports_into_one_folder_the_second_names_the_first(
    export: Export, capsys: pytest.CaptureFixture
) -> None:
    with export_process(export) as first:
        _stopped_while_staging(first, export.parent)
        status = main(["export", str(export.sequence), "--to", "csv", "--out", str(export.out)])
        err = capsys.readouterr().err.strip().splitlines()
        os.kill(first.pid, signal.SIGCONT)
        _, first_err = first.communicate(timeout=120)
    assert status == 2 and len(err) == 1
    expected = f"msflash: error: --out {export.out}: another export is writing it: msflash process {first.pid}"
    assert err[0].startswith(expected)
    assert first.returncode == 0, first_err.decode()  # the first export was not disturbed
    assert sorted(p.name for p in export.parent.iterdir()) == ["out"]


def test_an_export_into_the_sequence_folder_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    sequence = write_test_sequence(tmp_path / "seq", cfa="RGGB")
    before = sorted(p.name for p in sequence.rglob("*"))
    assert main(["export", str(sequence), "--to", "csv", "--out", str(sequence / "frames" / "x")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is inside the sequence folder" in err[0] and "--out" in err[0]
    assert sorted(p.name for p in sequence.rglob("*")) == before
    assert main(["check", str(sequence)]) == 0
