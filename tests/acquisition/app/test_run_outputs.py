"""Where ``msflash run`` / ``capture`` write: refused before any device opens, or one line after the sequence."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.sequence.reader import read_sequence
from tests.acquisition.support.report_pages import disk_full_for


@pytest.mark.parametrize("command", ["run", "capture"])
def test_out_under_a_regular_file_is_refused_before_capturing(
    tmp_path: Path, capsys: pytest.CaptureFixture, command: str
) -> None:
    blocker = tmp_path / "notes.txt"
    blocker.write_text("a file, not a folder\n")
    assert main([command, "--rig", "sim", "--out", str(blocker / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert (
        err[-1] == f"msflash: error: --out {blocker / 'run'}: {blocker} is a file; expected a folder (or a path "
        "where one can be made)"
    )
    assert not any("captured step" in line for line in err)  # nothing was captured


def test_run_json_that_cannot_be_written_is_one_line_and_the_sequence_stays(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Disk full when the summary is written (injected: no small file system can be mounted in CI;
    the same line was seen by hand on a full tmpfs for the report's images)."""
    disk_full_for(monkeypatch, lambda path: path.name == "run.json")
    out = tmp_path / "run"
    assert main(["run", "--rig", "sim", "--out", str(out)]) == 1
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert last.startswith(f"msflash: error: {out / 'run.json'}: could not be written ([Errno 28] No space left")
    assert f"The sequence is complete in {out / 'sequence'}" in last
    assert read_sequence(out / "sequence").complete
    assert not (out / "run.json").exists()
    monkeypatch.undo()
    assert json.loads((out / "sequence" / "sequence.json").read_text())["complete"] is True
