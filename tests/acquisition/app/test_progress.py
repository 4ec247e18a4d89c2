"""Progress bars on a terminal, lines elsewhere, and no library logs without ``-v`` (acquisition/progress.py).

The terminal is a real pseudo-terminal (``pty.fork``) with a window size, as a user's would be; the
other runs have their stdout and stderr on pipes, as a script's or a log's.
"""

from __future__ import annotations

import fcntl
import io
import os
import pty
import struct
import subprocess
import sys
import termios

import pytest

from msflash.acquisition import progress as app_progress
from msflash.lab.progress import CountedProgress, report_count

CLI = [sys.executable, "-m", "msflash.acquisition.app.cli"]
QUICK_TABLE1 = ["study", "table1", "--cameras", "3", "--illuminants", "2", "--leds", "3"]
"""A small Table 1: three cameras (three units of work), a few seconds serially."""


def on_terminal(argv: list[str]) -> str:
    """What ``msflash argv`` shows on a 30 × 100 terminal (stdout and stderr both on the pty), decoded."""
    pid, fd = pty.fork()
    if pid == 0:  # the child: its stdin, stdout and stderr are the pty's far end
        try:
            fcntl.ioctl(1, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))
            env = {key: value for key, value in os.environ.items() if key != "TERM"}
            os.execve(sys.executable, [*CLI, *argv], {**env, "TERM": "xterm"})
        finally:
            os._exit(127)
    chunks = []
    while True:
        try:
            data = os.read(fd, 65536)
        except OSError:  # EIO: the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    _, status = os.waitpid(pid, 0)
    os.close(fd)
    assert os.waitstatus_to_exitcode(status) == 0, b"".join(chunks).decode(errors="replace")
    return b"".join(chunks).decode(errors="replace")


def piped(argv: list[str]) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *argv], capture_output=True, text=True, timeout=240, check=True)


def test_a_study_draws_a_bar_with_an_eta_on_a_terminal():
    shown = on_terminal([*QUICK_TABLE1, "--scheduler", "none"])
    bar_lines = [part for part in shown.split("\r") if part.startswith("msflash: table1:") and "%|" in part]
    assert bar_lines, shown
    assert any("3/3 camera" in part for part in bar_lines), bar_lines  # it reached the end
    assert all("<" in part for part in bar_lines)  # [elapsed<remaining]: the ETA
    assert "camera 1/3 done" not in shown  # the bar replaces the line per camera
    assert "Table 1:" in shown  # the result itself


def test_run_shows_its_steps_and_frames_as_one_bar_on_a_terminal(tmp_path):
    shown = on_terminal(["run", "--out", str(tmp_path / "run")])
    bars = [part for part in shown.split("\r") if part.startswith("msflash: run:") and "%|" in part]
    assert any("4/4 step" in part for part in bars), bars
    assert any("capture: 9/9 frame" in part for part in bars), bars  # the frames beside the run's bar
    assert "captured step" not in shown  # no line per frame on a terminal
    assert "msflash: opening rig 'sim'" in shown and "done in" in shown  # the lines stay, above the bar


def test_capture_lines_on_a_pipe(tmp_path):
    result = piped(["capture", "--out", str(tmp_path / "capture")])
    assert "%|" not in result.stderr and "\r" not in result.stderr
    assert sum("captured step" in line for line in result.stderr.splitlines()) == 8  # ambient + 7 LEDs


def test_no_bar_on_a_terminal_with_json():
    shown = on_terminal([*QUICK_TABLE1, "--scheduler", "none", "--json"])
    assert "%|" not in shown and "\r msflash" not in shown
    assert '"spectrum_rmse"' in shown


def test_no_bar_when_not_a_terminal_but_a_line_per_unit():
    result = piped([*QUICK_TABLE1, "--scheduler", "none"])
    assert "%|" not in result.stderr and "\r" not in result.stderr
    units = [line for line in result.stderr.splitlines() if "table1: camera" in line]
    assert [line.split(" done")[0] for line in units] == [f"msflash: table1: camera {n}/3" for n in (1, 2, 3)]


def test_a_dask_study_prints_no_dask_log_without_v():
    quiet = piped([*QUICK_TABLE1, "--workers", "1"])
    assert "dask: local cluster with 1 workers" in quiet.stderr  # it did run on dask
    assert not [line for line in quiet.stderr.splitlines() if "distributed" in line], quiet.stderr
    verbose = piped(["-v", *QUICK_TABLE1, "--workers", "1"])
    assert any("distributed.scheduler" in line for line in verbose.stderr.splitlines())


def test_report_count_gives_numbers_to_a_counting_reporter_and_a_line_to_a_plain_one():
    counts = []

    class Counting:
        def __call__(self, message: str, /) -> None:
            raise AssertionError("a counting reporter gets counts, not lines")

        def count(self, label: str, done: int, total: int, unit: str, note: str) -> None:
            counts.append((label, done, total, unit, note))

    reporter = Counting()
    assert isinstance(reporter, CountedProgress)
    report_count(reporter, "pareto", 2, 9, "world")
    assert counts == [("pareto", 2, 9, "world", "pareto: world 2/9 done")]
    lines: list[str] = []
    report_count(lines.append, "pareto", 2, 9, "world", started=0.0)
    assert len(lines) == 1 and lines[0].startswith("pareto: world 2/9 done (") and lines[0].endswith(" s)")
    report_count(None, "pareto", 2, 9, "world")  # nobody listening: nothing happens, nothing fails


def test_without_bars_a_count_prints_its_note_and_a_counted_loop_closes(capsys):
    app_progress.configure(bars=False)
    with app_progress.counted("colour study", 2, "ambient") as advance:
        advance("colour study: tungsten done")
        advance(None)
    assert capsys.readouterr().err == "msflash: colour study: tungsten done\n"


def test_bars_are_wanted_only_on_a_terminal_without_json(monkeypatch):
    class Terminal(io.StringIO):
        def isatty(self) -> bool:
            return True

    monkeypatch.setenv("TERM", "xterm")
    assert app_progress.bars_wanted(False, Terminal())
    assert not app_progress.bars_wanted(True, Terminal())
    assert not app_progress.bars_wanted(False, io.StringIO())
    monkeypatch.setenv("TERM", "dumb")
    assert not app_progress.bars_wanted(False, Terminal())


@pytest.mark.parametrize("command", [["study", "table1"], ["bench"], ["capture"], ["colour-study"]])
def test_tqdm_is_not_imported_to_parse_a_command(command):
    """Bars cost nothing until drawn: parsing a command (``--help``) does not import tqdm."""
    code = (
        "import sys\nfrom msflash.acquisition.app.cli import main\n"
        f"try:\n    main({[*command, '--help']!r})\nexcept SystemExit:\n    pass\n"
        "print('tqdm' in sys.modules)"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert result.stdout.strip().splitlines()[-1] == "False"
