"""One copy of each module: a product folder imported under its bare name from the repository root is refused.

``msflash/`` links the folders (``msflash/processing`` → ``processing/``), so from the repository root
``import processing.spectra`` used to load a second copy of the code whose ``Spectra`` was another class than
``msflash.processing.spectra.Spectra``. Each folder's ``__init__`` now refuses its bare name with one line
naming the import to use (:func:`msflash.one_copy.one_copy`).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FOLDERS = {
    "acquisition": "acquisition.plan",
    "processing": "processing.spectra",
    "calibration": "calibration.errors",
    "led_controller": "led_controller.protocol",
    "lab": "lab.study",
}


@pytest.mark.parametrize("folder", sorted(FOLDERS))
def test_a_folder_under_its_bare_name_fails_with_one_line_naming_msflash(folder: str) -> None:
    module = FOLDERS[folder]
    run = subprocess.run([sys.executable, "-c", f"import {module}"], cwd=ROOT, capture_output=True, text=True)
    assert run.returncode == 1 and (ROOT / folder / "__init__.py").is_file()
    assert run.stderr.strip().splitlines()[-1] == (
        f"ImportError: '{folder}' is msflash's folder: import msflash.{folder} "
        "(under its bare name it would be a second copy of msflash)"
    )


def test_from_the_repository_root_msflash_names_load_the_one_copy() -> None:
    code = (
        "import sys, msflash.processing.spectra as s\n"
        "assert 'processing' not in sys.modules and 'processing.spectra' not in sys.modules\n"
        "print(s.Spectra.__module__)"
    )
    run = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, check=True)
    assert run.stdout.strip() == "msflash.processing.spectra"
