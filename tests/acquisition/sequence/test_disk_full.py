"""The disk fills up (or goes away) in the middle of ``msflash capture``: a runtime failure (exit 1)
in one line naming the frame, the cause and what is saved; the frames before stay readable, the
LEDs go off.

No small file system can be mounted without root here, so the failure is injected at the writer's
boundary with the disk: ``write_image`` raises the ``OSError`` (ENOSPC) that a full disk raises.
Everything else is real: the sim rig, the booth emulator on a pty, the writer thread, the CLI.
"""

from __future__ import annotations

import errno
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence import writer as sequence_writer
from msflash.acquisition.sequence.reader import read_sequence

FULL_AT = 3
"""The frame whose file finds the disk full (0-based)."""


@pytest.fixture
def disk_full_at_frame(monkeypatch: pytest.MonkeyPatch) -> None:
    real_write = sequence_writer.write_image_digest
    calls = {"n": 0}

    def write_image(path, pixels, metadata):  # noqa: ANN001 - the image_io signature
        calls["n"] += 1
        if calls["n"] > FULL_AT:
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        return real_write(path, pixels, metadata)

    monkeypatch.setattr(sequence_writer, "write_image_digest", write_image)


def test_a_full_disk_mid_capture_is_one_runtime_error_and_keeps_the_frames(
    disk_full_at_frame: None, tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out, transcript = tmp_path / "run", tmp_path / "booth.txt"
    status = main(["capture", "--exposure-us", "5000", "--out", str(out), "--log-serial", str(transcript)])
    err = capsys.readouterr().err
    assert status == 1  # the disk failed: a runtime failure, not bad input
    last = err.strip().splitlines()[-1]
    assert last.startswith(
        f"msflash: error: {out / 'sequence'}: writing frames/003-led.tiff failed: No space left on device"
    )
    assert f"{FULL_AT} frame(s) saved and readable (complete: false)" in last
    assert err.count("No space left on device") == 1  # said once, not again by the writer thread
    sequence = read_sequence(out / "sequence")
    assert not sequence.complete and [f.role for f in sequence.frames] == ["ambient", "led", "led"]
    assert all(sequence.load_frame(i).shape == sequence.load_frame(0).shape for i in range(FULL_AT))
    requests = [line for line in transcript.read_text().splitlines() if line.startswith((">", "<"))]
    assert ":OFF*" in requests[-2] and ":OK OFF*" in requests[-1]  # the LEDs went off at the end


def test_a_full_disk_while_writing_the_run_report_is_one_runtime_error(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The sequence (flash included) is on disk; the report's first EXR finds the disk full (injected at
    the report's write_image, as above): exit 1, one line naming it and saying the sequence is complete
    — it was an OSError traceback (checked by hand on a 760 kB tmpfs: same line)."""
    from msflash.acquisition.app import report

    def full(path, pixels, metadata, chromaticities=None):  # noqa: ANN001 - the image_io signature
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    monkeypatch.setattr(report, "write_image", full)
    out = tmp_path / "run"
    status = main(["run", "--exposure-us", "5000", "--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 1
    assert err[-1].startswith(f"msflash: error: {out}: the run report could not be written (")
    assert "No space left on device" in err[-1] and f"The sequence is complete in {out / 'sequence'}" in err[-1]
    sequence = read_sequence(out / "sequence")
    assert sequence.complete and sequence.frames[-1].role == "flash"
