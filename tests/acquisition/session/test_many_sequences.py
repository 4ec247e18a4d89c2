"""``msflash estimate|flash`` over many sequences on dask (acquisition/session/many.py, issue 21 item 5).

The runs on a local cluster are subprocesses: distributed keeps its event loops per process, and a
cluster started inside a test worker that had run other tests sometimes failed to start
(tests/lab/study/test_study.py).
"""

from __future__ import annotations

import json
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from msflash.acquisition.app.cli import main
from msflash.acquisition.errors import UsageError
from msflash.acquisition.sequence.image_files import read_image
from msflash.acquisition.session.many import SequenceRecord, exit_status, output_paths, sequence_inputs
from tests.helpers import led_mix, write_test_sequence

REPOSITORY = Path(__file__).resolve().parents[3]
MIXES = (
    [0.2, 0.05, 0.4, 0.3, 0.6, 0.1, 0.25],
    [0.5, 0.1, 0.1, 0.3, 0.2, 0.4, 0.05],
    [0.1, 0.3, 0.2, 0.6, 0.1, 0.2, 0.3],
)
"""Ambient weights of the day's sequences (three different in-span ambients)."""


@pytest.fixture(autouse=True)
def same_kind_of_process(monkeypatch: pytest.MonkeyPatch) -> None:
    """This test process may have the compiled kernels loaded (other tests), a worker process has not, and the block
    moments' two routes agree to rounding only (processing.frame_kernels.statistics_compiled): the one-by-one runs
    here and the workers (by inheritance) both take the numpy route, as two fresh processes would."""
    from msflash.processing import frame_kernels

    monkeypatch.setenv(frame_kernels.KERNELS_VARIABLE, "numpy")


@pytest.fixture(scope="module")
def day(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder of three noisy sequences, 0800, 0900, 1000: a time-lapse of an ambient."""
    folder = tmp_path_factory.mktemp("many") / "day"
    for hour, mix in zip(("0800", "0900", "1000"), MIXES, strict=True):
        write_test_sequence(folder / hour, led_mix(mix), noise=True)
    return folder


@pytest.fixture(scope="module")
def bad(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder whose sequence.json is not a sequence."""
    folder = tmp_path_factory.mktemp("bad") / "broken"
    folder.mkdir()
    (folder / "sequence.json").write_text("{}")
    return folder


def one_by_one(capsys: pytest.CaptureFixture[str], sequences: list[Path], *options: str) -> list[str]:
    """Each sequence's ``--json`` line from its own single-sequence run, in order."""
    lines = []
    for sequence in sequences:
        assert main([options[0], str(sequence), *options[1:], "--json"]) == 0
        out = capsys.readouterr().out.splitlines()
        assert len(out) == 1
        lines.append(out[0])
    return lines


def msflash(*argv: str, timeout: float = 240) -> subprocess.CompletedProcess[str]:
    """``msflash ARGV`` in a process of its own."""
    return subprocess.run(
        [sys.executable, "-m", "msflash.acquisition.app.cli", *argv],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPOSITORY,
    )


# -- which sequences ---------------------------------------------------------------------------
def test_a_folder_of_sequences_gives_its_sequences_in_name_order(day: Path, bad: Path) -> None:
    sequences, expanded = sequence_inputs([str(day), str(bad)])
    assert sequences == [str(day / "0800"), str(day / "0900"), str(day / "1000"), str(bad)]
    assert expanded
    assert sequence_inputs([str(day / "0900")]) == ([str(day / "0900")], False)


def test_several_sequences_and_no_name_in_out_is_refused_before_any_work() -> None:
    with pytest.raises(UsageError, match=r"--out x\.exr: 2 sequences would write the same file; expected .*\{name\}"):
        output_paths("x.exr", ["a/0800", "b/0900"])
    with pytest.raises(UsageError, match="a/0800 and b/0800 would both write out/0800.exr"):
        output_paths("out/{name}.exr", ["a/0800", "b/0800"])


def test_exit_status_is_2_when_any_input_was_refused() -> None:
    fine = SequenceRecord("a", {"sequence": "a"})
    assert exit_status([fine, fine]) == 0
    assert exit_status([fine, SequenceRecord("b", None, error="b: x", status=1)]) == 1
    assert exit_status([SequenceRecord("c", None, error="c: y", status=2), fine]) == 2


# -- in this process (--scheduler none) --------------------------------------------------------
def test_serial_run_gives_the_one_by_one_lines_and_names_the_bad_sequence(
    day: Path, bad: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    good = sorted(day.iterdir())
    expected = one_by_one(capsys, good, "estimate")
    status = main(["estimate", str(good[0]), str(bad), str(day / "0900"), str(day / "1000"), "--scheduler", "none"])
    captured = capsys.readouterr()
    assert status == 2
    lines = captured.out.splitlines()
    assert [lines[0], *lines[2:]] == expected
    assert json.loads(lines[1]) == {
        "sequence": str(bad),
        "error": f"{bad}/sequence.json: format is missing; expected 'msflash-sequence'",
        "status": 2,
    }
    errors = [line for line in captured.err.splitlines() if "error" in line]
    assert errors == [f"msflash: error: {bad}/sequence.json: format is missing; expected 'msflash-sequence'"]
    assert "msflash: 1 of 4 sequences failed" in captured.err


def test_one_sequence_alone_stays_the_single_command(day: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """No dask, no cluster line, the text output: one sequence is the command it always was."""
    assert main(["estimate", str(day / "0800")]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith(f"ambient estimate of {day / '0800'} (")
    assert "dask" not in captured.err


# -- on a local dask cluster of two workers ----------------------------------------------------
def test_two_workers_give_the_one_by_one_results_bit_for_bit(
    day: Path, bad: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """estimate over a folder and a bad sequence, flash with images: JSON numbers and image pixels identical."""
    good = sorted(day.iterdir())
    estimates = one_by_one(capsys, good, "estimate")
    single_out = tmp_path / "single"
    single_out.mkdir()
    flashes = []
    for sequence in good:
        out = single_out / f"{sequence.name}.exr"
        assert main(["flash", str(sequence), "--mode", "complementary", "--out", str(out), "--json"]) == 0
        flashes.append(capsys.readouterr().out.strip().replace(str(single_out), str(tmp_path / "many")))

    done = msflash("estimate", str(day), str(bad), "--workers", "2")
    assert done.returncode == 2, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert lines[:3] == estimates  # every float's repr equal: the same bits
    assert json.loads(lines[3])["error"].startswith(f"{bad}/sequence.json: format is missing")
    assert "msflash: dask: local cluster with 2 workers" in done.stderr
    assert all(line.startswith("msflash: ") for line in done.stderr.splitlines()), done.stderr  # dask silent

    template = str(tmp_path / "many" / "{name}.exr")
    done = msflash("flash", str(day), "--mode", "complementary", "--out", template, "--workers", "2")
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.splitlines() == flashes
    for sequence in good:
        mine, theirs = (
            read_image(tmp_path / "many" / f"{sequence.name}.exr"),
            read_image(single_out / f"{sequence.name}.exr"),
        )
        np.testing.assert_array_equal(mine, theirs)


_LOOPBACK_SCHEDULER = """
import sys
import distributed
from msflash.acquisition.app.cli import main
with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=False, protocol="tcp", host="127.0.0.1",
                              dashboard_address=":0") as cluster:
    status = main(["estimate", *sys.argv[1:], "--scheduler", cluster.scheduler_address])
sys.exit(status)
"""


def test_a_scheduler_at_an_address_gets_absolute_paths_and_gives_the_same_lines(
    day: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Its workers run in folders of their own: relative arguments are sent as absolute paths."""
    good = sorted(day.iterdir())[:2]
    expected = one_by_one(capsys, good, "estimate")
    done = subprocess.run(
        [sys.executable, "-c", _LOOPBACK_SCHEDULER, *(f"{day.name}/{sequence.name}" for sequence in good)],
        capture_output=True,
        text=True,
        timeout=240,
        cwd=day.parent,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.splitlines() == expected
    assert "msflash: dask: scheduler tcp://127.0.0.1:" in done.stderr


def test_a_scheduler_that_does_not_answer_is_refused_in_one_line(day: Path) -> None:
    with socket.socket() as probe:  # a loopback port nobody listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    done = msflash("estimate", str(day), "--scheduler", f"tcp://127.0.0.1:{port}", timeout=60)
    assert done.returncode == 2
    assert done.stdout == ""
    lines = done.stderr.splitlines()
    assert len(lines) == 1, done.stderr
    assert lines[0].startswith(f"msflash: error: --scheduler tcp://127.0.0.1:{port}: cannot connect (")


def test_flash_over_a_copy_keeps_its_images_apart(
    day: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two folders holding sequences of the same name would write one image twice: refused (exit 2) before work."""
    other = tmp_path / "other"
    shutil.copytree(day, other)
    status = main(["flash", str(day), str(other), "--mode", "matching", "--out", str(tmp_path / "{name}.exr")])
    captured = capsys.readouterr()
    assert status == 2
    assert captured.err.splitlines() == [
        f"msflash: error: --out {tmp_path}/{{name}}.exr: {day}/0800 and {other}/0800 would both write "
        f"{tmp_path}/0800.exr; expected sequence folders with different names"
    ]
    assert captured.out == ""
    assert not list(tmp_path.glob("*.exr"))


def test_name_in_out_is_the_run_folder_however_its_sequence_is_named(
    day: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``runs/*/sequence`` and ``runs/*/sequence/sequence.json`` name each run: was every one ``sequence``
    (``sequence.json``), refused as two sequences writing one file."""
    runs = tmp_path / "runs"
    for hour in ("0800", "0900"):
        shutil.copytree(day / hour, runs / hour / "sequence")
    for inner in ("sequence", "sequence/sequence.json"):
        out = tmp_path / inner.replace("/", "-")
        out.mkdir()
        status = main(
            ["flash", *(str(runs / hour / inner) for hour in ("0800", "0900")), "--mode", "matching"]
            + ["--scheduler", "none", "--json", "--out", str(out / "{name}.exr")]
        )
        captured = capsys.readouterr()
        assert status == 0, captured.err
        assert sorted(path.name for path in out.iterdir()) == ["0800.exr", "0900.exr"]
        assert [json.loads(line)["sequence"] for line in captured.out.splitlines()] == [
            str(runs / hour / "sequence") for hour in ("0800", "0900")
        ]
