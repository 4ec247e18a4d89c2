"""Every path option given a file that is not one to read (issue 19): a FIFO, ``/dev/zero``, a
directory, a symlink loop, a 20 MiB CSV, a name with non-UTF-8 bytes and a newline. Each exits 2
with one error line naming the path, before reading anything (processing/user_files.py).

The FIFO cases run in a child process with a timeout: a regression there blocks for ever, and
must fail this test rather than hang the suite. The child runs them all in one interpreter.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from msflash.acquisition.app.cli import main
from msflash.processing.user_files import shown_path
from tests.helpers import write_test_sequence

REPO = Path(__file__).resolve().parents[3]
KINDS = ("fifo", "device", "directory", "loop", "large", "odd-name")
BIG = 20 * (1 << 20)


def make_bad(kind: str, place: Path, name: str = "bad.csv") -> Path:
    """A path of ``kind`` at ``place / name`` (``/dev/zero`` through a symlink for ``device``)."""
    path = place / name
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "device":
        path.symlink_to("/dev/zero")
    elif kind == "directory":
        path.mkdir()
    elif kind == "loop":
        path.symlink_to(path.name)
    elif kind == "large":
        with path.open("wb") as stream:  # sparse: 20 MiB on stat, nothing on disk
            stream.truncate(BIG)
    elif kind == "odd-name":
        path = Path(os.fsdecode(os.fsencode(place) + b"/bad\xff\n" + name.encode()))
        path.write_bytes(b"\x00\x01 not a table")
    else:
        raise ValueError(kind)
    return path


def _sequence_json(kind: str, place: Path, sequence: Path) -> Path:
    target = place / "seq"
    shutil.copytree(sequence, target)
    (target / "sequence.json").unlink()
    make_bad(kind, target, "sequence.json")
    return target


def _frame(kind: str, place: Path, sequence: Path) -> Path:
    target = place / "seq"
    shutil.copytree(sequence, target)
    frame = target / json.loads((target / "sequence.json").read_text())["frames"][2]["file"]
    frame.unlink()
    make_bad(kind, frame.parent, frame.name)
    return target


def _calibration(kind: str, place: Path) -> Path:
    directory = place / "cal"
    directory.mkdir()
    make_bad(kind, directory, "calibration.json")
    return directory


def cases(kind: str, place: Path, sequence: Path) -> dict[str, tuple[list[str], str]]:
    """Option → (argv, the path the error must name), each with its own bad file under ``place``."""
    result: dict[str, tuple[list[str], str]] = {}

    def case(option: str, build: Callable[[Path], tuple[list[str], Path]]) -> None:
        folder = place / option.strip("-").replace(" ", "_").replace(".", "_")
        folder.mkdir()
        argv, named = build(folder)
        result[option] = (argv, shown_path(named))

    sim = ["run", "--rig", "sim", "--seed", "0"]
    case(
        "flash --target",
        lambda f: (["flash", str(sequence), "--mode", "complementary", "--target", str(p := make_bad(kind, f))], p),
    )
    for option in ("--led-spectra", "--sim-camera", "--scene", "--ambient"):
        case(f"run {option}", lambda f, o=option: ([*sim, "--out", str(f / "out"), o, str(p := make_bad(kind, f))], p))
    case(
        "capture --led-spectra",
        lambda f: (
            ["capture", "--rig", "sim", "--out", str(f / "out"), "--led-spectra", str(p := make_bad(kind, f))],
            p,
        ),
    )
    case(
        "calibrate leds FILE",
        lambda f: (["calibrate", "leds", str(p := make_bad(kind, f)), "--out", str(f / "cal")], p),
    )
    case(
        "calibrate leds --dark",
        lambda f: (
            ["calibrate", "leds", str(f / "led.csv"), "--dark", str(p := make_bad(kind, f)), "--out", str(f / "cal")],
            p,
        ),
    )
    if kind != "odd-name":  # the names below are fixed by the formats
        case(
            "estimate sequence.json",
            lambda f: (["estimate", str(s := _sequence_json(kind, f, sequence))], s / "sequence.json"),
        )
        case("estimate frame", lambda f: (["estimate", str(s := _frame(kind, f, sequence))], s))
        case(
            "flash --calibration",
            lambda f: (
                ["flash", str(sequence), "--mode", "complementary", "--calibration", str(c := _calibration(kind, f))],
                c / "calibration.json",
            ),
        )
    return result


def run_case(argv: list[str]) -> tuple[int, str]:
    """Exit status and stderr of ``main(argv)``, in this process."""
    err, out = io.StringIO(), io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out):
        status = main(argv)
    return status, err.getvalue()


def assert_refused(option: str, status: int, err: str, named: str) -> None:
    errors = [line for line in err.splitlines() if line.startswith("msflash: error: ")]
    assert status == 2, f"{option}: status {status}: {err}"
    assert len(errors) == 1, f"{option}: {err}"
    assert named in errors[0] or os.path.basename(named) in errors[0], f"{option}: {named!r} not in {errors[0]!r}"
    assert err.splitlines()[-1] == errors[0], f"{option}: the error is not the last line: {err}"


@pytest.fixture(scope="module")
def sequence(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_test_sequence(tmp_path_factory.mktemp("seq") / "tungsten")


@pytest.mark.parametrize("kind", [k for k in KINDS if k != "fifo"])
def test_each_path_option_refuses(kind: str, sequence: Path, tmp_path: Path) -> None:
    for option, (argv, named) in cases(kind, tmp_path, sequence).items():
        status, err = run_case(argv)
        assert_refused(option, status, err, named)
        if kind == "large" and option != "estimate frame":  # 20 MiB is a plausible frame
            assert "MiB" in err, f"{option}: the size is not said: {err}"


_CHILD = """
import json, sys
from pathlib import Path
from tests.acquisition.app.test_user_file_options import cases, run_case
for option, (argv, named) in cases("fifo", Path(sys.argv[1]), Path(sys.argv[2])).items():
    status, err = run_case(argv)
    print(json.dumps({"option": option, "status": status, "err": err, "named": named}), flush=True)
"""


def test_fifos_are_refused_without_blocking(sequence: Path, tmp_path: Path) -> None:
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    try:
        child = subprocess.run(
            [sys.executable, "-c", _CHILD, str(tmp_path), str(sequence)],
            cwd=REPO,
            env=env,
            capture_output=True,
            text=True,
            timeout=240,
        )
    except subprocess.TimeoutExpired as err:  # the hang of issue 19: name the cases that finished
        pytest.fail(f"a FIFO blocked msflash; finished before it: {err.stdout!r}")
    assert child.returncode == 0, child.stderr
    results = [json.loads(line) for line in child.stdout.splitlines()]
    assert len(results) == 11, child.stdout
    for result in results:
        assert "FIFO" in result["err"], result
        assert_refused(result["option"], result["status"], result["err"], result["named"])
