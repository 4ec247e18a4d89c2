"""One folder argument for every command reading a sequence (acquisition/sequence/locate.py).

``capture --out D`` writes ``D/sequence``: ``estimate``, ``flash``, ``synthesize``, ``evaluate``,
``check`` and ``--rig replay:`` take ``D``, ``D/sequence`` or its ``sequence.json`` alike, and refuse
anything else with one line naming the folder and what was expected.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence.locate import locate_sequence

RECORDED = Path(__file__).resolve().parents[2] / "data" / "sequences" / "sim-macbeth-fluorescent"
"""A recorded sequence (a chart scene under fluorescent light, from ``msflash capture``)."""


@pytest.fixture
def capture_folder(tmp_path: Path) -> Path:
    """What ``capture --out D`` leaves: ``D/sequence`` holding the sequence."""
    folder = tmp_path / "D"
    shutil.copytree(RECORDED, folder / "sequence", ignore=shutil.ignore_patterns("README*"))
    return folder


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    out, err = capsys.readouterr()
    return status, out, err


def test_a_run_folder_its_sequence_and_its_sequence_json_are_the_same_sequence(capture_folder: Path):
    sequence = capture_folder / "sequence"
    assert locate_sequence(capture_folder) == sequence
    assert locate_sequence(sequence) == sequence
    assert locate_sequence(sequence / "sequence.json") == sequence


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (lambda root: root / "absent", "absent: not found; expected a sequence folder"),
        (lambda root: (root / "file.txt", (root / "file.txt").write_text("x"))[0], "is not a folder"),
        (lambda root: (root / "empty", (root / "empty").mkdir())[0], "no sequence.json in it or in sequence/"),
    ],
)
def test_no_sequence_is_refused_in_one_line_naming_the_folder(tmp_path: Path, make, expected: str):
    path = make(tmp_path)
    with pytest.raises(RecordingError) as caught:
        locate_sequence(path, "--white ")
    message = str(caught.value)
    assert "\n" not in message and message.startswith(f"--white {path}") and expected in message
    assert "run or capture folder holding one (sequence/sequence.json)" in message


def test_a_folder_of_runs_names_the_runs_inside(tmp_path: Path, capture_folder: Path):
    with pytest.raises(RecordingError, match=r"no sequence.json in it or in sequence/ \(found one in .*D: name it\)"):
        locate_sequence(capture_folder.parent)


def test_a_sequence_holding_another_sequence_is_ambiguous(capture_folder: Path):
    shutil.copy(capture_folder / "sequence" / "sequence.json", capture_folder / "sequence.json")
    with pytest.raises(RecordingError, match=r"holds both a sequence \(sequence.json\) and another in sequence/"):
        locate_sequence(capture_folder)


def test_estimate_flash_synthesize_check_and_evaluate_take_the_capture_folder(
    capsys: pytest.CaptureFixture[str], capture_folder: Path, tmp_path: Path
):
    by_folder = run(capsys, "estimate", str(capture_folder), "--json")
    by_sequence = run(capsys, "estimate", str(capture_folder / "sequence"), "--json")
    assert by_folder[0] == by_sequence[0] == 0
    assert json.loads(by_folder[1])["spectrum"] == json.loads(by_sequence[1])["spectrum"]
    status, out, _ = run(capsys, "flash", str(capture_folder), "--mode", "matching", "--json")
    assert status == 0 and len(json.loads(out)["flash_weights"]) == 7
    weights = ",".join(["0.5"] * 7)
    status, _, _ = run(
        capsys, "synthesize", str(capture_folder), "--weights", weights, "--out", str(tmp_path / "s.exr")
    )
    assert status == 0 and (tmp_path / "s.exr").is_file()
    _, out, _ = run(capsys, "check", str(capture_folder), "--json")  # exit 2: recorded before frame digests
    summary = json.loads(out)
    assert summary["sequence"] == str(capture_folder / "sequence") and summary["unverified"] == summary["frames"] == 9
    status, out, _ = run(capsys, "evaluate", str(capture_folder), "--chart", "macbeth", "--json")
    assert status == 0 and (capture_folder / "evaluation" / "report.html").is_file()


@pytest.mark.parametrize("command", [["estimate"], ["flash", "--mode", "matching"], ["check"]])
def test_a_folder_without_a_sequence_exits_2_with_one_line(capsys: pytest.CaptureFixture[str], tmp_path, command):
    status, out, err = run(capsys, command[0], str(tmp_path), *command[1:])
    assert status == 2 and out == ""
    assert err.count("\n") == 1 and err.startswith(f"msflash: error: {tmp_path}: no sequence.json in it")
