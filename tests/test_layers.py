"""Architecture: the import-linter contracts of pyproject.toml, and where hardware libraries may be imported."""

from __future__ import annotations

import ast
import subprocess
import sys
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
    assert "gi" in imported_top_level(ROOT / "acquisition" / "devices" / "aravis" / "gi_typelib.py")


def test_gi_only_in_the_aravis_folder() -> None:
    """Aravis (through gi) is imported only under acquisition/devices/aravis/ (issue 18, item 2): the
    rest of msflash runs without the GObject typelib."""
    importers = [p.relative_to(ROOT).as_posix() for p in source_files() if "gi" in imported_top_level(p)]
    assert importers, "expected the Aravis camera to import gi"
    assert all(path.startswith("acquisition/devices/aravis/") for path in importers), importers


def test_serial_only_in_led_controller() -> None:
    offenders = [p.relative_to(ROOT).as_posix() for p in source_files() if "serial" in imported_top_level(p)]
    assert offenders, "expected the booth driver to import pyserial"
    assert all(path.startswith("led_controller/") for path in offenders), offenders


def test_code_imports_the_packages_only_under_msflash() -> None:
    """Every import of our own packages goes through the ``msflash`` namespace (issue 18, item 1):
    a bare ``processing`` would be a user's folder of that name, or nothing."""
    files = source_files() + sorted((ROOT / "tests").rglob("*.py")) + sorted((ROOT / "msflash").glob("*.py"))
    offenders = [p.relative_to(ROOT).as_posix() for p in files if imported_top_level(p) & set(PACKAGES)]
    assert offenders == []


def test_the_install_provides_msflash_and_no_bare_package(tmp_path: Path) -> None:
    """Outside the checkout, ``msflash.processing`` imports and ``processing`` does not: nothing installs
    the four generic names (the subpackages live in the four top-level folders, linked under msflash/)."""
    code = (
        "import importlib.util, json, msflash.processing.ambient as ambient\n"
        "print(json.dumps([ambient.__name__] + [importlib.util.find_spec(n) is None for n in "
        f"{list(PACKAGES)!r}]))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120, check=True
    )
    assert result.stdout.strip() == '["msflash.processing.ambient", true, true, true, true]'
