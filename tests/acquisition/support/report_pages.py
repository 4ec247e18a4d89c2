"""Reading the HTML reports msflash writes (``run``, ``evaluate``, ``colour-study``), and a full disk while they are written.

:func:`parse_report` gives a page's images (``src``: a file beside the page, or a ``data:`` PNG),
links and tables (cells by table id, stripped). :func:`disk_full_for` makes ``Path.write_text`` fail
with ``ENOSPC`` for the files a predicate names (no small file system can be mounted in CI).
"""

from __future__ import annotations

import base64
import errno
from collections.abc import Callable
from html.parser import HTMLParser
from pathlib import Path

import pytest

_PNG_DATA = "data:image/png;base64,"


class ReportPage(HTMLParser):
    """Every ``<img src>`` and ``<a href>`` of a page, and its tables' cells by id."""

    def __init__(self) -> None:
        super().__init__()
        self.images: list[str] = []
        self.links: list[str] = []
        self.tables: dict[str, list[list[str]]] = {}
        self._table: str | None = None
        self._cell: list[str] | None = None

    @property
    def embedded(self) -> list[bytes]:
        """The images embedded in the page, decoded; every image must be an embedded PNG."""
        assert all(src.startswith(_PNG_DATA) for src in self.images), self.images
        return [base64.b64decode(src[len(_PNG_DATA) :]) for src in self.images]

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = dict(attrs)
        if tag == "img":
            self.images.append(values["src"] or "")
        elif tag == "a":
            self.links.append(values["href"] or "")
        elif tag == "table":
            self._table = values.get("id") or f"table-{len(self.tables)}"
            self.tables[self._table] = []
        elif tag == "tr" and self._table:
            self.tables[self._table].append([])
        elif tag in ("td", "th"):
            self._cell = []

    def handle_data(self, data: str) -> None:
        if self._cell is not None:
            self._cell.append(data)

    def handle_endtag(self, tag: str) -> None:
        if tag in ("td", "th") and self._cell is not None and self._table:
            self.tables[self._table][-1].append("".join(self._cell).strip())
            self._cell = None
        elif tag == "table":
            self._table = None


def parse_report(path: Path) -> ReportPage:
    """The report page at ``path``, parsed."""
    page = ReportPage()
    page.feed(path.read_text(encoding="utf-8"))
    return page


def disk_full_for(monkeypatch: pytest.MonkeyPatch, refused: Callable[[Path], bool]) -> None:
    """``Path.write_text`` raises ``ENOSPC`` for every path ``refused`` names, for the rest of the test."""
    real = Path.write_text

    def full_disk(self: Path, *args, **kwargs):  # noqa: ANN202 - Path.write_text's signature
        if refused(self):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(self, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", full_disk)
