"""Architecture: the import-linter contracts of pyproject.toml, and where hardware libraries may be imported."""

from __future__ import annotations

import ast
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("acquisition", "processing", "calibration", "led_controller")
LINT_IMPORTS = ROOT / ".venv" / "bin" / "lint-imports"


def test_import_linter_contracts_hold() -> None:
    if not LINT_IMPORTS.exists():
        pytest.skip(f"{LINT_IMPORTS} is absent (run setup.sh)")
    result = subprocess.run([str(LINT_IMPORTS), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert " 0 broken" in result.stdout, result.stdout


def imported_top_level(path: Path) -> set[str]:
    """Top-level module names imported anywhere in a file (also inside functions)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def source_files() -> list[Path]:
    return sorted(p for package in PACKAGES if (ROOT / package).is_dir() for p in (ROOT / package).rglob("*.py"))


def test_scanner_sees_the_packages() -> None:
    files = source_files()
    assert any(p.relative_to(ROOT).as_posix() == "processing/ambient.py" for p in files)
    assert "gi" in imported_top_level(ROOT / "acquisition" / "aravis_camera.py")


def test_gi_only_in_aravis_camera() -> None:
    offenders = [p.relative_to(ROOT).as_posix() for p in source_files() if "gi" in imported_top_level(p)]
    assert offenders == ["acquisition/devices/aravis/camera.py"]


def test_serial_only_in_led_controller() -> None:
    offenders = [p.relative_to(ROOT).as_posix() for p in source_files() if "serial" in imported_top_level(p)]
    assert offenders, "expected the booth driver to import pyserial"
    assert all(path.startswith("led_controller/") for path in offenders), offenders
