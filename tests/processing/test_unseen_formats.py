"""What other tools write that format v1 allows, or that measurement gives, read as it is (unseen-sequence sweep).

- Frame paths with ``\\`` separators: a tool on Windows writing ``str(Path("img") / name)``. The
  reader took them as one file name and refused the sequence ("… is missing").
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from acquisition.errors import RecordingError
from acquisition.sequence_format import read_sequence
from tests.processing.unseen_sequences import Case, check_case, render_case


def test_windows_separators_in_frame_paths_are_read(tmp_path: Path) -> None:
    rendered = render_case(Case("windows", quirks=("windows_paths",)), tmp_path / "windows")
    assert "\\" in json.loads((rendered.directory / "sequence.json").read_text())["frames"][0]["file"]
    sequence = read_sequence(rendered.directory)
    assert sequence.frames[0].file == "img/00_ambient.tif"
    assert sequence.load_frame(0).shape == sequence.load_frame(len(sequence.frames) - 1).shape
    assert check_case(Case("windows-cli", quirks=("windows_paths",)), tmp_path).defects == ()


def test_a_windows_path_leaving_the_directory_is_still_refused(tmp_path: Path) -> None:
    rendered = render_case(Case("escape"), tmp_path / "inside" / "escape")
    (tmp_path / "inside" / "outside.tif").write_bytes((rendered.directory / "img" / "01_led.tif").read_bytes())
    document = json.loads((rendered.directory / "sequence.json").read_text())
    document["frames"][1]["file"] = "..\\outside.tif"
    (rendered.directory / "sequence.json").write_text(json.dumps(document))
    with pytest.raises(RecordingError, match=r"frames\[1\]\.file '\.\./outside\.tif' points outside"):
        read_sequence(rendered.directory)
