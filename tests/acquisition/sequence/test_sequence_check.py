"""Frames provably intact: digests recorded as frames are written, ``msflash check``, and every reader refusing a changed frame."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import RecordingError
from msflash.acquisition.sequence import writer as sequence_writer
from msflash.acquisition.sequence.check import FILE_STATES, check_sequence
from msflash.acquisition.sequence.reader import read_sequence
from tests.helpers import forget_digests

REPOSITORY = Path(__file__).resolve().parents[3]
SAMPLES = REPOSITORY.parent / "shared" / "samples"
FRAME = "frames/003-led.tiff"
"""The frame the tests damage (frames[3])."""


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    status = main(list(argv))
    captured = capsys.readouterr()
    return status, captured.out, captured.err


def one_error(err: str, *names: str, after_progress: bool = False) -> str:
    """The one error line on stderr (the last, after progress lines, for commands that print them)."""
    lines = err.strip().splitlines()
    if after_progress:
        assert not any(line.startswith("msflash: error: ") for line in lines[:-1]), err
        lines = lines[-1:]
    assert len(lines) == 1 and lines[0].startswith("msflash: error: "), err
    for name in names:
        assert name in lines[0], f"{name!r} not in {lines[0]!r}"
    return lines[0]


def states(out: str) -> tuple[list[tuple[str, str, str]], dict]:
    """The per-file lines (state, position, file) and the JSON summary line of ``msflash check``."""
    *lines, summary = out.strip().splitlines()
    return [tuple(line.split()) for line in lines], json.loads(summary)  # type: ignore[misc]


def change_one_byte(path: Path) -> None:
    data = bytearray(path.read_bytes())
    middle = len(data) // 2  # inside the pixel strip: the file still decodes
    data[middle] ^= 0x01
    path.write_bytes(bytes(data))


# -- what the writer records -------------------------------------------------------------------------
def test_each_frame_records_the_sha256_and_length_of_its_file(base_sequence: Path) -> None:
    document = json.loads((base_sequence / "sequence.json").read_text())
    assert len(document["frames"]) == 8
    for entry in document["frames"]:
        data = (base_sequence / entry["file"]).read_bytes()
        assert entry["sha256"] == hashlib.sha256(data).hexdigest()
        assert entry["file_bytes"] == len(data)
    assert document["version"] == 1  # an optional field: same version (docs/architecture.md §6)


def test_run_records_digests_through_the_asynchronous_writer(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "run"
    assert main(["run", "--out", str(out)]) == 0
    capsys.readouterr()
    sequence = read_sequence(out / "sequence")
    assert [f.role for f in sequence.frames][-1] == "flash"
    for index, frame in enumerate(sequence.frames):
        assert frame.digest is not None
        assert frame.digest.sha256 == hashlib.sha256(sequence.frame_path(index).read_bytes()).hexdigest()
    status, out_text, err = run(capsys, "check", str(out / "sequence"))
    assert status == 0 and err == ""
    lines, summary = states(out_text)
    assert [line[0] for line in lines] == ["intact"] * 9 and summary["intact"] == 9


# -- msflash check, every state -----------------------------------------------------------------------
def test_an_intact_sequence_checks_with_exit_0(sequence: Path, capsys: pytest.CaptureFixture) -> None:
    status, out, err = run(capsys, "check", str(sequence))
    assert status == 0 and err == ""
    lines, summary = states(out)
    assert lines == [
        ("intact", f"frames[{i}]", f)
        for i, f in enumerate(sorted(p.relative_to(sequence).as_posix() for p in (sequence / "frames").iterdir()))
    ]
    assert summary == {
        "sequence": str(sequence),
        "complete": True,
        "frames": 8,
        "intact": 8,
        "mismatched": 0,
        "changed": 0,
        "truncated": 0,
        "missing": 0,
        "unreadable": 0,
        "unverified": 0,
        "undeclared": 0,
        "intact_sequence": True,
    }


@pytest.mark.parametrize(
    ("damage", "state", "said"),
    [
        (change_one_byte, "changed", "has changed since it was written"),
        (lambda path: path.unlink(), "missing", "is missing"),
        (lambda path: os.truncate(path, path.stat().st_size - 10), "truncated", "is truncated"),
    ],
)
def test_a_damaged_frame_is_named_with_its_state(
    sequence: Path, capsys: pytest.CaptureFixture, damage: Callable[[Path], None], state: str, said: str
) -> None:
    damage(sequence / FRAME)
    status, out, err = run(capsys, "check", str(sequence))
    assert status == 2
    one_error(err, "frames[3].file", FRAME, said)
    lines, summary = states(out)
    assert lines[3] == (state, "frames[3]", FRAME)
    assert [line[0] for i, line in enumerate(lines) if i != 3] == ["intact"] * 7
    assert summary[state] == 1 and summary["intact"] == 7 and summary["intact_sequence"] is False


def test_an_undeclared_file_is_listed_after_the_frames(sequence: Path, capsys: pytest.CaptureFixture) -> None:
    shutil.copy(sequence / FRAME, sequence / "frames" / "003-led copy.tiff")
    (sequence / "frames" / ".004-led.tiff.abc.tmp.tiff").write_bytes(b"half a frame")
    status, out, err = run(capsys, "check", str(sequence))
    assert status == 2
    lines, summary = states(out)
    assert [line[0] for line in lines[:8]] == ["intact"] * 8
    assert summary["undeclared"] == 2 and summary["intact_sequence"] is False
    assert out.splitlines()[8].split() == ["undeclared", "-", "frames/.004-led.tiff.abc.tmp.tiff"]
    assert out.splitlines()[9].split()[:2] == ["undeclared", "-"] and out.splitlines()[9].endswith("003-led copy.tiff")
    one_error(err, "frames/.004-led.tiff.abc.tmp.tiff", "not listed in sequence.json", "temporary file")


def test_every_problem_is_counted_and_the_first_is_named(sequence: Path, capsys: pytest.CaptureFixture) -> None:
    os.truncate(sequence / "frames" / "001-led.tiff", 100)
    (sequence / "frames" / "002-led.tiff").unlink()
    change_one_byte(sequence / FRAME)
    (sequence / "notes.txt").write_text("extra")
    status, out, err = run(capsys, "check", str(sequence), "--json")
    assert status == 2
    one_error(err, "frames[1].file", "001-led.tiff", "is truncated: 100 bytes of the")
    report = json.loads(out)
    assert [(f["state"], f["index"]) for f in report["files"]] == [
        ("intact", 0),
        ("truncated", 1),
        ("missing", 2),
        ("changed", 3),
        ("intact", 4),
        ("intact", 5),
        ("intact", 6),
        ("intact", 7),
        ("undeclared", None),
    ]
    assert {state: report[state] for state in FILE_STATES} == {
        "intact": 5,
        "mismatched": 0,
        "changed": 1,
        "truncated": 1,
        "missing": 1,
        "unreadable": 0,
        "unverified": 0,
        "undeclared": 1,
    }
    assert report["files"][0]["problem"] is None and "notes.txt" in report["files"][-1]["problem"]


def test_a_sequence_without_digests_reads_but_is_not_proven_intact(
    sequence: Path, capsys: pytest.CaptureFixture
) -> None:
    forget_digests(sequence)
    os.truncate(sequence / "frames" / "005-led.tiff", 300)
    status, out, err = run(capsys, "check", str(sequence))
    assert status == 2
    one_error(err, "frames[0].file", "no recorded SHA-256")
    lines, summary = states(out)
    assert [line[0] for line in lines] == ["unverified"] * 5 + ["unreadable"] + ["unverified"] * 2
    assert summary["unverified"] == 7 and summary["unreadable"] == 1


@pytest.mark.parametrize("name", ["sample-rgb-tungsten", "sample-bayer-fluorescent-12bit"])
def test_the_independent_samples_still_read_and_check_as_unverified(name: str, capsys: pytest.CaptureFixture) -> None:
    sample = SAMPLES / name
    if not sample.is_dir():
        pytest.skip(f"{sample} not present")
    assert main(["estimate", str(sample), "--json"]) == 0
    capsys.readouterr()
    status, out, err = run(capsys, "check", str(sample))
    assert status == 2 and "no recorded SHA-256" in one_error(err)
    lines, summary = states(out)
    assert {line[0] for line in lines} == {"unverified"} and summary["frames"] == len(lines)


def test_check_as_a_process(sequence: Path) -> None:
    change_one_byte(sequence / FRAME)
    done = subprocess.run(
        [sys.executable, "-m", "msflash.acquisition.app.cli", "check", str(sequence)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
        env={**os.environ, "PYTHONPATH": str(REPOSITORY)},
    )
    assert done.returncode == 2
    one_error(done.stderr, "frames[3].file", FRAME, "has changed")
    assert json.loads(done.stdout.splitlines()[-1])["changed"] == 1


def test_a_frame_replaced_by_a_fifo_is_unreadable_not_a_hang(sequence: Path, capsys: pytest.CaptureFixture) -> None:
    (sequence / FRAME).unlink()
    os.mkfifo(sequence / FRAME)
    status, out, err = run(capsys, "check", str(sequence))
    assert status == 2
    one_error(err, FRAME, "not a regular file")
    assert states(out)[0][3][0] == "unreadable"


def test_a_frame_replaced_by_a_directory_is_unreadable_not_a_crash(
    sequence: Path, capsys: pytest.CaptureFixture
) -> None:
    # Found by the sequence fuzzer (issue 19 item 6): fdopen refused the directory with IsADirectoryError.
    (sequence / FRAME).unlink()
    (sequence / FRAME).mkdir()
    status, out, err = run(capsys, "check", str(sequence))
    assert status == 2
    one_error(err, FRAME, "not a regular file")
    assert states(out)[0][3][0] == "unreadable"


# -- every reader refuses a changed frame -------------------------------------------------------------
@pytest.mark.parametrize("command", [["estimate"], ["flash", "--mode", "complementary"]])
def test_processing_refuses_a_changed_frame(sequence: Path, capsys: pytest.CaptureFixture, command: list[str]) -> None:
    change_one_byte(sequence / FRAME)
    status, out, err = run(capsys, command[0], str(sequence), *command[1:], "--json")
    assert status == 2 and out == ""
    one_error(err, "frames[3].file", FRAME, "has changed since it was written", "expected the frame file as written")


def test_a_truncated_frame_is_refused_as_truncated(sequence: Path, capsys: pytest.CaptureFixture) -> None:
    os.truncate(sequence / FRAME, 1000)
    status, _, err = run(capsys, "estimate", str(sequence))
    assert status == 2
    one_error(err, "frames[3].file", FRAME, "is truncated: 1000 bytes of the")


def test_replay_refuses_a_changed_recording(sequence: Path, tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    change_one_byte(sequence / FRAME)
    status, _, err = run(capsys, "run", "--rig", f"replay:{sequence}", "--out", str(tmp_path / "replayed"))
    assert status == 2
    one_error(err, "frames[3].file", FRAME, "has changed", after_progress=True)


def test_run_refuses_its_own_frame_changed_on_disk(
    tmp_path: Path, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A frame changed on disk after it was written (a failing disk, another program) is caught when
    ``run`` checks the digests of what it wrote (its report comes from the frames in memory)."""
    real_write = sequence_writer.write_image_digest

    def write_then_damage(path, pixels, attributes):  # noqa: ANN001 - the image_io signature
        digest = real_write(path, pixels, attributes)
        if path.name.startswith("000-"):
            change_one_byte(path)
        return digest

    monkeypatch.setattr(sequence_writer, "write_image_digest", write_then_damage)
    status, _, err = run(capsys, "run", "--out", str(tmp_path / "run"))
    assert status == 2
    one_error(err, "frames[0].file", "000-ambient.tiff", "has changed since it was written", after_progress=True)


# -- the fields themselves -----------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("change", "said"),
    [
        ({"sha256": "XYZ"}, "frames[2].sha256 is 'XYZ'; expected 64 lowercase hexadecimal digits"),
        ({"sha256": 7}, "frames[2].sha256 is a number; expected 64 lowercase hexadecimal digits"),
        ({"file_bytes": -1}, "frames[2].file_bytes is a number; expected an integer ≥ 0"),
        ({"file_bytes": 1.5}, "frames[2].file_bytes is a number; expected an integer ≥ 0"),
        ({"file_bytes": None}, "frames[2].file_bytes is missing but sha256 is given"),
    ],
)
def test_malformed_digest_fields_are_named(
    sequence: Path, capsys: pytest.CaptureFixture, change: dict, said: str
) -> None:
    path = sequence / "sequence.json"
    document = json.loads(path.read_text())
    document["frames"][2].update(change)
    if change.get("file_bytes", 0) is None:
        del document["frames"][2]["file_bytes"]
    path.write_text(json.dumps(document))
    for command in ("estimate", "check"):
        status, out, err = run(capsys, command, str(sequence))
        assert status == 2 and out == ""
        one_error(err, said)


def test_load_frame_refuses_a_changed_frame_and_reads_it_once_digests_are_dropped(sequence: Path) -> None:
    change_one_byte(sequence / FRAME)
    with pytest.raises(RecordingError, match=r"frames\[3\].file 'frames/003-led.tiff' has changed"):
        read_sequence(sequence).load_frame(3)
    forget_digests(sequence)
    assert read_sequence(sequence).load_frame(3).shape[2] == 3


def test_copying_a_sequence_records_the_new_files_digests(sequence: Path, tmp_path: Path) -> None:
    source = read_sequence(sequence)
    copied = sequence_writer.write_sequence(
        tmp_path / "copied", source, [source.load_frame(i) for i in range(len(source.frames))]
    )
    assert check_sequence(copied.directory).intact
    # The same pixels written again may make other bytes (OpenImageIO stamps the TIFF with the time to
    # the second): digests describe files, not frames, so frame equality ignores them.
    for index, frame in enumerate(copied.frames):
        assert frame.digest is not None
        assert frame.digest.sha256 == hashlib.sha256(copied.frame_path(index).read_bytes()).hexdigest()
    assert copied.frames == source.frames
    np.testing.assert_array_equal(copied.load_frame(3), source.load_frame(3))


# -- a frame is bound to its entry ----------------------------------------------------------------------
FILE_KEYS = ("file", "sha256", "file_bytes")


def edit_entries(sequence: Path, change: Callable[[list[dict]], None]) -> None:
    document = json.loads((sequence / "sequence.json").read_text())
    change(document["frames"])
    (sequence / "sequence.json").write_text(json.dumps(document))


def swap_files(frames: list[dict], a: int, b: int) -> None:
    """Swap what names a file (file, sha256, file_bytes) between two entries: each file stays intact."""
    for key in FILE_KEYS:
        frames[a][key], frames[b][key] = frames[b][key], frames[a][key]


def test_swapped_entries_are_refused_by_every_reader_and_named_by_check(
    sequence: Path, capsys: pytest.CaptureFixture
) -> None:
    edit_entries(sequence, lambda frames: swap_files(frames, 1, 2))
    status, out, err = run(capsys, "estimate", str(sequence), "--json")
    assert status == 2 and out == ""
    line = one_error(err, "frames[1].file 'frames/002-led.tiff'", "written for frames[2]", "not for this entry")
    assert "swapped" in line
    status, out, err = run(capsys, "check", str(sequence), "--json")
    assert status == 2
    report = json.loads(out)
    assert [(f["state"], f["index"]) for f in report["files"][:4]] == [
        ("intact", 0),
        ("mismatched", 1),
        ("mismatched", 2),
        ("intact", 3),
    ]
    assert report["files"][1]["problem"].startswith("swapped with frames[2]")
    assert report["files"][2]["problem"].startswith("swapped with frames[1]")
    assert report["mismatched"] == 2 and report["intact_sequence"] is False
    one_error(err, "frames[1].file", "swapped with frames[2]")


def test_duplicated_and_re_ordered_entries_are_named(sequence: Path, capsys: pytest.CaptureFixture) -> None:
    # frames[5] names a copy of frames[4]'s file (its own digest, so the copy is intact), and frames 6, 7
    # and 3 are rotated: 3 -> 6's file, 6 -> 7's, 7 -> 3's.
    shutil.copy(sequence / "frames" / "004-led.tiff", sequence / "frames" / "004-copy.tiff")

    def change(frames: list[dict]) -> None:
        frames[5]["file"] = "frames/004-copy.tiff"
        frames[5]["sha256"], frames[5]["file_bytes"] = frames[4]["sha256"], frames[4]["file_bytes"]
        named = {i: {key: frames[i][key] for key in FILE_KEYS} for i in (3, 6, 7)}
        for target, source in ((3, 6), (6, 7), (7, 3)):
            frames[target].update(named[source])

    edit_entries(sequence, change)
    (sequence / "frames" / "005-led.tiff").unlink()  # the file frames[5] named: gone with its entry
    status, out, err = run(capsys, "check", str(sequence), "--json")
    assert status == 2
    report = json.loads(out)
    by_index = {f["index"]: f for f in report["files"] if f["index"] is not None}
    assert [by_index[i]["state"] for i in range(8)] == ["intact"] * 3 + ["mismatched"] + ["intact"] + ["mismatched"] * 3
    assert by_index[5]["problem"].startswith("duplicated: frames[4] names a file written for frames[4] too")
    assert by_index[3]["problem"].startswith("re-ordered: its file was written for frames[6]")
    assert by_index[7]["problem"].startswith("re-ordered: its file was written for frames[3]")


def test_an_entry_edited_after_the_fact_is_refused(sequence: Path, capsys: pytest.CaptureFixture) -> None:
    """Levels or exposure edited in sequence.json: the frame was not taken under them."""

    def change(frames: list[dict]) -> None:
        frames[3]["exposure_us"] = frames[3]["exposure_us"] * 2

    edit_entries(sequence, change)
    with pytest.raises(RecordingError, match=r"frames\[3\]\.file 'frames/003-led\.tiff' was written for frames\[3\]"):
        read_sequence(sequence).load_frame(3)
    status, out, err = run(capsys, "check", str(sequence))
    assert status == 2
    one_error(err, "frames[3].file", "role, LED levels, exposure or gain differ from the entry")


def test_frames_of_another_tool_carry_no_binding_and_still_read() -> None:
    """The independent writer's samples say nothing of their entries: nothing to compare, nothing refused."""
    for sample in ("sample-rgb-tungsten", "sample-bayer-fluorescent-12bit"):
        recorded = read_sequence(SAMPLES / sample)
        for index in range(len(recorded.frames)):
            recorded.load_frame(index)
