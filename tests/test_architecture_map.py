"""docs/architecture.md is a map, and a true one: short, every file it names exists, its contracts are the code's.

Issue 31 item 5: the map holds the rooms, the route of a frame and the contracts in at most 300 lines, the
rest in other docs pages. Paths are checked from the repository root, and the hop table's (which are under
``acquisition/`` unless they start with ``processing/``) from ``acquisition/``; the contracts listed in §3.1
are those of ``pyproject.toml``, in order and word for word, and ``tests/test_layers.py`` runs them.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAP = ROOT / "docs" / "architecture.md"
MAX_LINES = 300
PATH_LIKE = re.compile(r"`([A-Za-z0-9_./{},-]+/[A-Za-z0-9_./{},-]*|[A-Za-z0-9_-]+\.(?:py|md|toml|sh))`")


def named_paths(text: str) -> set[str]:
    """Every path the map names in backticks, ``a/{b,c}/`` expanded to ``a/b/`` and ``a/c/``."""
    names: set[str] = set()
    for token in PATH_LIKE.findall(text):
        if token.startswith(("http", "../", "/")) or "." in token.split("/")[0] and not token.endswith((".py", ".md")):
            continue
        braces = re.search(r"\{([^}]*)\}", token)
        if braces:
            names |= {token[: braces.start()] + part + token[braces.end() :] for part in braces.group(1).split(",")}
        else:
            names.add(token)
    return names


def test_the_map_is_short() -> None:
    lines = MAP.read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_LINES, f"docs/architecture.md has {lines} lines; a map keeps at most {MAX_LINES}"


def test_every_file_the_map_names_exists() -> None:
    names = named_paths(MAP.read_text(encoding="utf-8"))
    assert {"acquisition/session/engine.py", "lab/bench/", "session/run.py"} <= names  # the scan sees them
    missing = sorted(name for name in names if not any((base / name).exists() for base in (ROOT, ROOT / "acquisition")))
    assert not missing, "docs/architecture.md names files that do not exist: " + ", ".join(missing)


def test_the_map_lists_the_contracts_the_code_holds() -> None:
    contracts = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["importlinter"]
    expected = [contract["name"].rstrip(".") for contract in contracts["contracts"]]
    section = MAP.read_text(encoding="utf-8").split("### 3.1", 1)[1].split("\n### ", 1)[0]
    listed = [item.rstrip(".") for item in re.findall(r"^\d+\. (.+)$", section, re.MULTILINE)]
    assert listed == expected, "§3.1 of docs/architecture.md is not the list of pyproject.toml's contracts"
