"""The design lives in the repository: code cites docs/ pages that exist, never a document outside it."""

from __future__ import annotations

import doctest
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("acquisition", "processing", "calibration", "led_controller")
ARCHITECTURE = ROOT / "docs" / "architecture.md"

OUTSIDE_DOCUMENTS = re.compile(r"DESIGN §|DESIGN\.md|STYLE §|STYLE\.md|PAPER\.md")
"""The design notes that lived outside the repository (their content is in docs/architecture.md)."""
DOCS_PATH = re.compile(r"docs/[A-Za-z0-9_.-]+\.md")
SECTION_CITE = re.compile(r"docs/architecture\.md`?\s*§\s*(\d+(?:\.\d+)*)")


def python_files(*folders: str) -> list[Path]:
    return sorted(p for folder in folders if (ROOT / folder).is_dir() for p in (ROOT / folder).rglob("*.py"))


def citing_files() -> list[Path]:
    """Everything that may cite the docs: the packages, the tests, the README and the docs themselves."""
    return [*python_files(*PACKAGES, "tests"), ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]


def test_the_scan_sees_the_code() -> None:
    files = {p.relative_to(ROOT).as_posix() for p in python_files(*PACKAGES)}
    assert "acquisition/sequence/format.py" in files
    assert ARCHITECTURE.is_file()


def test_no_package_cites_a_document_outside_the_repository() -> None:
    offenders = [
        f"{path.relative_to(ROOT)}:{number}: {line.strip()}"
        for path in python_files(*PACKAGES, "tests")
        if path != Path(__file__).resolve()
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if OUTSIDE_DOCUMENTS.search(line)
    ]
    assert not offenders, "cite docs/architecture.md §N instead:\n" + "\n".join(offenders)


def test_every_cited_docs_page_exists() -> None:
    missing = [
        f"{path.relative_to(ROOT)}: {cited}"
        for path in citing_files()
        for cited in sorted(set(DOCS_PATH.findall(path.read_text(encoding="utf-8"))))
        if not (ROOT / cited).is_file()
    ]
    assert not missing, "cited docs pages that do not exist:\n" + "\n".join(missing)


def architecture_sections() -> set[str]:
    """Section numbers of docs/architecture.md: ``## 6. …`` gives "6", ``### 2.4 …`` gives "2.4"."""
    headings = re.findall(r"^#{2,4}\s+(\d+(?:\.\d+)*)\.?\s", ARCHITECTURE.read_text(encoding="utf-8"), re.MULTILINE)
    return set(headings)


def test_architecture_sections_are_numbered() -> None:
    sections = architecture_sections()
    assert {"1", "2", "3", "4", "5", "6", "7", "8"} <= sections, sorted(sections)


def test_every_cited_architecture_section_exists() -> None:
    sections = architecture_sections()
    missing = [
        f"{path.relative_to(ROOT)}: §{number}"
        for path in citing_files()
        for number in sorted(set(SECTION_CITE.findall(path.read_text(encoding="utf-8"))))
        if number not in sections
    ]
    assert not missing, f"cited sections absent from docs/architecture.md (it has {sorted(sections)}):\n" + "\n".join(
        missing
    )


def test_the_python_api_page_runs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """docs/python-api.md's worked example runs as written, in a fresh folder (issue 18, item 1)."""
    monkeypatch.chdir(tmp_path)
    result = doctest.testfile(
        str(ROOT / "docs" / "python-api.md"),
        module_relative=False,
        verbose=False,
        optionflags=doctest.NORMALIZE_WHITESPACE,
    )
    assert result.attempted >= 15
    assert result.failed == 0, capsys.readouterr().out


def test_help_msflash_shows_the_public_face() -> None:
    """``help(msflash)`` documents the five steps of the method and nothing else at the top."""
    import pydoc

    import msflash

    text = pydoc.render_doc(msflash, renderer=pydoc.plaintext)
    for name in msflash.__all__:
        assert name.strip("_") in text.lower(), name
    assert sorted(n for n in msflash.__all__ if not n.startswith("_")) == sorted(
        ["estimate_ambient", "read_sequence", "render_preview", "solve_flash", "synthesize_flash"]
    )
    for name in msflash.__all__:
        if not name.startswith("_"):
            assert (getattr(msflash, name).__doc__ or "").strip(), name
