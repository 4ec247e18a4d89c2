"""The wheel carries everything msflash reads at run time, under ``msflash/`` only (built offline from the sources)."""

from __future__ import annotations

import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
FOLDERS = ("acquisition", "processing", "calibration", "led_controller", "lab")


def _tracked_files() -> list[str]:
    listed = subprocess.run(
        ["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
        cwd=REPO,
        capture_output=True,
        check=True,
    ).stdout.decode()
    return [name for name in listed.split("\0") if name and (REPO / name).exists()]


def test_the_wheel_holds_every_source_and_data_file_and_no_bare_package(tmp_path: Path) -> None:
    # A copy of the working tree (tracked and new files, symbolic links kept), so the build leaves the checkout alone.
    source = tmp_path / "src"
    for name in _tracked_files():
        target = source / name
        target.parent.mkdir(parents=True, exist_ok=True)
        origin = REPO / name
        if origin.is_symlink():
            target.symlink_to(origin.readlink())
        else:
            shutil.copy2(origin, target)
    built = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "--no-build-isolation", "--no-index"]
        + ["-w", str(tmp_path / "dist"), str(source)],
        capture_output=True,
        text=True,
        timeout=240,
        check=False,
    )
    assert built.returncode == 0, built.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("msflash-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())

    expected = {
        f"msflash/{name}"
        for name in _tracked_files()
        if name.split("/")[0] in FOLDERS and "/build/" not in name and not name.endswith(".pyc")
    }
    assert not expected - names, f"missing from the wheel: {sorted(expected - names)[:10]}"
    assert {"msflash/led_controller/firmware/Makefile", "msflash/led_controller/firmware/core/booth_core.c"} <= names
    assert any(n.startswith("msflash/processing/data/") for n in names)  # the spectral data the simulator reads
    tops = {name.split("/")[0] for name in names}
    assert tops == {"msflash", wheel.name.split("-py3")[0] + ".dist-info"}, tops  # no bare `processing` etc.
