"""Memory is budgeted before it is spent (issue 32, item 2): decompression bombs refused unread, exit 2.

A bomb is a frame file of a few hundred kB that inflates to 4000 × 4000 16-bit RGB (91.6 MiB). Under an
address-space limit (``RLIMIT_AS``) a few hundred MiB above the process's size, in a subprocess,
``msflash estimate`` on a sequence with one, some or all frames replaced by bombs exits 2 with one line
naming the frame, the size and the budget (or the size against frame 0's, read from the headers) — never
a ``MemoryError`` (exit 1, "a bug") or the kernel's OOM killer.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import OpenImageIO as oiio
import pytest

from msflash.acquisition.app.cli import main as msflash_main
from msflash.acquisition.sequence.image_files import read_image_header
from tests.acquisition.session.test_estimate_stream import write_sequence

BOMB = (4000, 4000)
"""Height and width of a bomb frame (RGB, 16 bits: 91.6 MiB decoded)."""


def plant_bomb(sequence: Path, index: int) -> None:
    """Replace frame ``index``'s file by a bomb carrying the same self-description; its digest entry dropped."""
    document = json.loads((sequence / "sequence.json").read_text())
    entry = document["frames"][index]
    path = sequence / entry["file"]
    attributes = read_image_header(path).attributes
    height, width = BOMB
    spec = oiio.ImageSpec(width, height, 3, "uint16")
    spec.attribute("compression", "zip")
    spec.attribute("ImageDescription", json.dumps(attributes))
    output = oiio.ImageOutput.create(str(path))
    assert output is not None and output.open(str(path), spec)
    row = np.zeros((width, 3), dtype=np.uint16)
    for y in range(height):
        assert output.write_scanline(y, 0, row)
    output.close()
    assert path.stat().st_size < 2_000_000  # a small file …
    for key in ("sha256", "file_bytes"):  # optional (both or neither): the bomb passes the reader's digest check
        entry.pop(key, None)
    (sequence / "sequence.json").write_text(json.dumps(document))


@pytest.fixture(scope="module")
def bombs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A clean 4-LED sequence and copies with bombs in one (frame 2), some (2, 3) and all frames."""
    import shutil

    root = tmp_path_factory.mktemp("bombs")
    clean = write_sequence(root / "clean", n_led_frames=4, shape=(96, 128, 3))
    made = {"clean": clean}
    for name, frames in (("one", [2]), ("some", [2, 3]), ("all", [0, 1, 2, 3, 4])):
        copy = root / name
        shutil.copytree(clean, copy)
        for index in frames:
            plant_bomb(copy, index)
        made[name] = copy
    return made


CAPPED = textwrap.dedent(
    """
    import resource, sys
    from msflash.acquisition.app import cli, cli_process  # imported before the cap: code is not the budget's
    from msflash.acquisition.session import analysis, estimate_stream  # noqa: F401
    with open("/proc/self/status") as status:
        size = next(int(line.split()[1]) * 1024 for line in status if line.startswith("VmSize:"))
    headroom = int(sys.argv[1])
    resource.setrlimit(resource.RLIMIT_AS, (size + headroom, resource.getrlimit(resource.RLIMIT_AS)[1]))
    sys.exit(cli.main(sys.argv[2:]))
    """
)


def run_capped(tmp_path: Path, headroom: int, argv: list[str]) -> subprocess.CompletedProcess[str]:
    script = tmp_path / "capped.py"
    script.write_text(CAPPED)
    return subprocess.run(
        [sys.executable, str(script), str(headroom), *argv],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"},
        check=False,
    )


@pytest.mark.parametrize(("case", "named"), [("one", "frames/002"), ("some", "frames/002"), ("all", "frames/000")])
def test_bombs_are_refused_unread_under_an_address_space_limit(
    bombs: dict[str, Path], tmp_path: Path, case: str, named: str
) -> None:
    """The default budget (a share of what RLIMIT_AS leaves): exit 2, one line naming the frame and sizes."""
    done = run_capped(tmp_path, 300 << 20, ["estimate", "--json", str(bombs[case])])
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr[-2000:]
    assert len(lines) == 1 and named in lines[0], lines
    assert "MemoryError" not in done.stderr and "bug" not in done.stderr
    if case == "all":
        assert "91.6 MiB" in lines[0] and "memory budget of" in lines[0], lines[0]
    else:
        assert "4000×4000 pixels but frames[0].file" in lines[0], lines[0]


def test_the_clean_sequence_estimates_under_the_same_limit(bombs: dict[str, Path], tmp_path: Path) -> None:
    done = run_capped(tmp_path, 300 << 20, ["estimate", "--method", "global", "--json", str(bombs["clean"])])
    assert done.returncode == 0, done.stderr[-2000:]
    assert len(json.loads(done.stdout)["ambient_weights"]) == 4


def test_memory_budget_option_sets_the_budget_anywhere_on_the_line(
    bombs: dict[str, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """``--memory-budget``: a bomb within it would be read; a clean frame past it is refused, naming it."""
    clean = str(bombs["clean"])
    assert msflash_main(["estimate", clean, "--memory-budget", "16K", "--json"]) == 2
    error = capsys.readouterr().err.strip()
    assert "frames/000-ambient.tiff" in error and "72 KiB" in error and "16 KiB (--memory-budget)" in error, error
    assert msflash_main(["--memory-budget=1G", "estimate", "--method", "global", "--json", clean]) == 0
    capsys.readouterr()
    assert msflash_main(["estimate", clean, "--memory-budget", "lots"]) == 2
    assert "--memory-budget 'lots'" in capsys.readouterr().err


def test_a_stack_past_the_budget_is_refused_from_the_headers(
    bombs: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A local image (``flash --method local --out``) needs every frame at once: their sum is checked before any
    is decoded. A global one streams the frames (one at a time within the same budget)."""
    clean = str(bombs["clean"])
    out = ["--out", str(tmp_path / "f.exr"), "--memory-budget", "200K"]
    assert msflash_main(["flash", "--mode", "matching", "--method", "local", clean, *out]) == 2
    error = capsys.readouterr().err
    assert "5 ambient and LED frames at once needs 360 KiB" in error, error
    assert msflash_main(["flash", "--mode", "matching", "--method", "global", clean, *out]) == 0, (
        capsys.readouterr().err
    )
