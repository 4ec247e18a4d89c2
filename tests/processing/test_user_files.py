"""processing/user_files.py: the one safe way to open a user's file (issue 19)."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from msflash.calibration.errors import CalibrationError
from msflash.processing.errors import SpectralDataError
from msflash.processing.user_files import check_user_file, printable, read_user_bytes, read_user_text, shown_path

KIND = "a test table"
REPO = Path(__file__).resolve().parents[2]


def test_a_regular_file_is_read(tmp_path: Path) -> None:
    path = tmp_path / "ok.csv"
    path.write_bytes(b"wavelength_nm,a\n400,1\n")
    assert read_user_bytes(path, KIND, 100) == b"wavelength_nm,a\n400,1\n"
    assert read_user_text(path, KIND, 100).startswith("wavelength_nm")
    assert check_user_file(path, KIND, 100).st_size == 22


def test_a_symlink_to_a_regular_file_is_followed(tmp_path: Path) -> None:
    (tmp_path / "real.csv").write_text("x")
    (tmp_path / "link.csv").symlink_to("real.csv")
    assert read_user_text(tmp_path / "link.csv", KIND, 10) == "x"


@pytest.mark.parametrize(
    ("make", "what"),
    [
        (lambda p: os.mkfifo(p), "is a FIFO"),
        (lambda p: p.symlink_to("/dev/zero"), "is a character device"),
        (lambda p: p.mkdir(), "is a directory"),
        (lambda p: p.symlink_to(p.name), "is a loop of symbolic links"),
        (lambda p: None, r"cannot be read \(no such file\)"),
    ],
    ids=["fifo", "dev-zero", "directory", "symlink-loop", "missing"],
)
def test_what_is_not_a_regular_file_is_refused_before_opening(tmp_path: Path, make, what: str) -> None:
    path = tmp_path / "bad.csv"
    make(path)
    # check_user_file only stats; read_user_bytes must refuse before opening (a FIFO would block).
    for call in (check_user_file, read_user_bytes):
        with pytest.raises(
            SpectralDataError, match=rf"^{re.escape(str(tmp_path))}/bad\.csv: {what}.*; expected {KIND}"
        ):
            call(path, KIND, 1 << 20)


def test_a_socket_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "s"
    with socket.socket(socket.AF_UNIX) as server:
        server.bind(str(path))
        with pytest.raises(SpectralDataError, match="is a socket"):
            read_user_bytes(path, KIND, 100)


def test_the_cap_is_checked_before_reading_and_named(tmp_path: Path) -> None:
    path = tmp_path / "big.csv"
    with path.open("wb") as stream:
        stream.truncate(20 << 20)
    with pytest.raises(SpectralDataError, match=rf"big\.csv: is 20\.0 MiB; expected {KIND} of at most 16\.0 MiB"):
        read_user_bytes(path, KIND, 16 << 20)
    read_user_bytes(path, KIND, 20 << 20)  # exactly the cap is allowed


def test_the_callers_error_type_is_raised(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match="is a directory"):
        read_user_text(tmp_path, KIND, 10, CalibrationError)


def test_undecodable_text_is_named(tmp_path: Path) -> None:
    path = tmp_path / "latin.csv"
    path.write_bytes(b"caf\xe9")
    with pytest.raises(SpectralDataError, match=rf"latin\.csv: is not UTF-8 text .* at byte 3\); expected {KIND}"):
        read_user_text(path, KIND, 10)


def test_any_bytes_in_a_name_are_shown_on_one_line(tmp_path: Path) -> None:
    name = os.fsdecode(b"bad\xff\n\x1b[31m.csv")
    assert shown_path(tmp_path / name) == f"{tmp_path}/bad\\xff\\n\\x1b[31m.csv"
    assert shown_path(os.fsencode(tmp_path / name)) == shown_path(tmp_path / name)
    with pytest.raises(SpectralDataError) as raised:
        read_user_bytes(tmp_path / name, KIND, 10)
    message = str(raised.value)
    assert "\n" not in message and "\x1b" not in message and "bad\\xff\\n" in message
    message.encode("utf-8")  # no lone surrogate left to break a UTF-8 stream
    assert printable("µm\tx\x00") == "µm\\tx\\x00"


_READ_ZERO = """
from unittest import mock
import msflash.processing.user_files as user_files
# A size stat under-reports (a /proc-like file, a file growing): the read still stops at cap + 1 bytes.
with mock.patch.object(user_files, "_check_stat", lambda shown, info, kind, cap, error: info):
    try:
        user_files.read_user_bytes("/dev/zero", "a table", 1 << 20)
    except user_files.SpectralDataError as err:
        print(err)
"""


def test_the_read_stops_past_the_cap_even_if_stat_lies() -> None:
    child = subprocess.run(
        [sys.executable, "-c", _READ_ZERO],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == "/dev/zero: is larger than 1.0 MiB; expected a table of at most 1.0 MiB"


_OPEN_FIFO = """
import os, sys
from unittest import mock
import msflash.processing.user_files as user_files
# A FIFO swapped in after the check: the non-blocking open returns at once, fstat refuses it.
os.mkfifo(sys.argv[1])
with mock.patch.object(user_files, "check_user_file", lambda *args: None):
    try:
        user_files.read_user_bytes(sys.argv[1], "a table", 100)
    except user_files.SpectralDataError as err:
        print(err)
"""


def test_a_fifo_swapped_in_after_the_check_does_not_block(tmp_path: Path) -> None:
    child = subprocess.run(
        [sys.executable, "-c", _OPEN_FIFO, str(tmp_path / "f")],
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert child.returncode == 0, child.stderr
    assert child.stdout.strip() == f"{tmp_path}/f: is a FIFO (named pipe); expected a table, a regular file"
