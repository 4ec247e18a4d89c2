"""One owner per output folder (issue 19, build 3): two processes on one ``--out`` cannot both
write it; a lock or temporary files left by a killed writer are taken over or removed with a note.

The concurrency tests use real processes and only poll files and wait for exits (bounded by
timeouts that fail the test, never by sleeps that decide it)."""

from __future__ import annotations

import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import FolderInUseError
from msflash.acquisition.sequence.folder_claim import LOCK_FILE, FolderClaim, claim_folder
from msflash.acquisition.sequence.reader import read_sequence
from tests.helpers import wait_for_frames, write_test_sequence

REPO = Path(__file__).resolve().parents[3]
SLOW_CAPTURE = ["capture", "--sync", "booth", "--exposure-us", "1500000", "--scene", "macbeth"]


@contextlib.contextmanager
def claimed(folder: str | os.PathLike, what: str = "writing") -> Iterator[FolderClaim]:
    """:func:`claim_folder` as a ``with`` block."""
    claim = claim_folder(folder, what)
    try:
        yield claim
    finally:
        claim.release()


def _msflash(*args: str) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "msflash.acquisition.app.cli", *args],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )


def _finish(process: subprocess.Popen[bytes], timeout_s: float = 240.0) -> tuple[int, str]:
    try:
        _, err = process.communicate(timeout=timeout_s)
    except subprocess.TimeoutExpired:
        process.kill()
        process.communicate()
        pytest.fail(f"msflash did not finish within {timeout_s} s")
    return process.returncode, err.decode()


def test_two_runs_started_together_into_one_folder_one_wins(tmp_path: Path) -> None:
    out = tmp_path / "shared"
    first = _msflash("run", "--out", str(out), "--seed", "1")
    second = _msflash("run", "--out", str(out), "--seed", "2", "--ambient", "daylight")
    results = {first.pid: _finish(first), second.pid: _finish(second)}
    statuses = sorted(status for status, _ in results.values())
    assert statuses == [0, 2], results
    winner = next(pid for pid, (status, _) in results.items() if status == 0)
    loser_err = next(err for status, err in results.values() if status == 2)
    assert loser_err.count("\n") == 1 and loser_err.startswith("msflash: error: "), loser_err
    # Either it found the folder held (the usual case) or, had the winner finished first, full.
    assert f"in use by msflash process {winner} (msflash run" in loser_err or "already holds a run" in loser_err
    sequence = read_sequence(out / "sequence")
    assert sequence.complete
    run = json.loads((out / "run.json").read_text())
    assert run["frames"] == len(sequence.frames)
    # The sequence describes the winner's ambient over the winner's frames (the race mixed the two).
    truth = sequence.extra["msflash"]["true_ambient"]["name"]
    assert (truth == "daylight") == (winner == second.pid), (truth, winner, first.pid, second.pid)
    assert not (out / LOCK_FILE).exists() and not (out / "sequence" / LOCK_FILE).exists()


def test_a_second_capture_into_a_busy_folder_names_the_holder(tmp_path: Path) -> None:
    out = tmp_path / "busy"
    first = _msflash(*SLOW_CAPTURE, "--out", str(out))
    try:
        wait_for_frames(first, out / "sequence" / "sequence.json", 1)
        # Held still while the second one tries: under load the second's start-up took longer than the first's
        # remaining frames, the first finished and released the folder, and the refusal named no holder.
        first.send_signal(signal.SIGSTOP)
        status, err = _finish(_msflash("capture", "--out", str(out)))
        assert status == 2, err
        assert err.count("\n") == 1
        assert f"msflash: error: {out}: in use by msflash process {first.pid} (msflash capture, since " in err
        assert "expected a folder no other run is writing" in err
        # The writer inside it is claimed too (a library caller writing the sequence folder directly).
        with pytest.raises(FolderInUseError, match=f"in use by msflash process {first.pid}"):
            claim_folder(out / "sequence")
    finally:
        first.send_signal(signal.SIGKILL)
        first.communicate(timeout=60)
    # Killed: the kernel dropped its locks; the partial sequence is kept and the folder can be claimed again.
    assert not read_sequence(out / "sequence").complete
    with claimed(out / "sequence"):
        pass


def test_a_folder_claimed_in_this_process_is_refused_with_its_pid(tmp_path: Path) -> None:
    with claimed(tmp_path, "msflash test"):
        with pytest.raises(FolderInUseError) as caught:
            claim_folder(tmp_path)
    assert f"in use by msflash process {os.getpid()} (msflash test, since " in str(caught.value)
    assert not (tmp_path / LOCK_FILE).exists()
    with claimed(tmp_path):  # released: free again
        pass


def test_a_stale_lock_is_taken_over_with_a_note(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / LOCK_FILE).write_text("4194304\nmsflash run, since 2026-01-01 00:00:00 UTC\n")  # no one holds it
    with caplog.at_level(logging.WARNING), claimed(tmp_path):
        assert (tmp_path / LOCK_FILE).read_text().startswith(f"{os.getpid()}\n")
    assert "taking over from msflash process 4194304" in caplog.text


def test_temporary_files_of_a_killed_writer_are_removed_with_a_note(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    seq = tmp_path / "seq"
    (seq / "frames").mkdir(parents=True)
    stale = [seq / "frames" / ".000-ambient.tiff.k3j2_x.tmp.tiff", seq / ".sequence.json.a8f7.tmp"]
    for path in stale:
        path.write_bytes(b"half a file")
    with caplog.at_level(logging.WARNING):
        write_test_sequence(seq)
    assert read_sequence(seq).complete
    assert not any(path.exists() for path in stale)
    assert caplog.text.count("left by a writer that was stopped") == 2


def test_run_into_a_busy_folder_exits_2_in_process(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with claimed(tmp_path / "out", "msflash run"):
        assert main(["run", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"in use by msflash process {os.getpid()} (msflash run" in err
    assert not (tmp_path / "out" / "sequence").exists()


def _partial_with_a_stale_temporary(seq: Path) -> Path:
    write_test_sequence(seq)
    document = json.loads((seq / "sequence.json").read_text())
    document["complete"] = False  # as a killed writer leaves it
    (seq / "sequence.json").write_text(json.dumps(document))
    stale = seq / "frames" / ".008-led.tiff.q1w2e3.tmp.tiff"
    stale.write_bytes(b"half a frame")
    return stale


def test_reading_a_killed_writers_sequence_reports_its_temporary_files(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    stale = _partial_with_a_stale_temporary(tmp_path / "seq")
    (tmp_path / "seq" / LOCK_FILE).write_text("4194304\nmsflash capture, since 2026-01-01 00:00:00 UTC\n")
    with caplog.at_level(logging.WARNING):
        assert read_sequence(tmp_path / "seq").partial
    assert "1 temporary file(s) left by a writer that was stopped (frames/.008-led.tiff" in caplog.text
    assert stale.exists()  # reported, never deleted by a reader


def test_reading_a_sequence_a_live_writer_holds_reports_nothing(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    _partial_with_a_stale_temporary(tmp_path / "seq")
    with claimed(tmp_path / "seq"), caplog.at_level(logging.WARNING):
        assert read_sequence(tmp_path / "seq").partial
    assert "temporary file" not in caplog.text


def test_evaluate_into_a_folder_another_msflash_is_writing_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """msflash evaluate claims its --out like run and capture: a held folder is exit 2 naming the holder."""
    sequence = write_test_sequence(tmp_path / "seq")
    out = tmp_path / "evaluation"
    with claim_folder(out, "msflash evaluate (the other one)"):
        status = main(["evaluate", str(sequence), "--chart", "macbeth", "--out", str(out)])
    err = capsys.readouterr().err
    assert status == 2, err
    assert err.count("\n") == 1 and f"in use by msflash process {os.getpid()}" in err, err
    assert not (out / "evaluation.json").exists()
