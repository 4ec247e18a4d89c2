"""Self-contained HTML reports: headings, text, tables and PNG images embedded as base64.

One file that opens anywhere (no side files, no scripts, no network): what ``msflash evaluate``
and ``msflash colour-study`` leave next to their images. Build a :class:`HtmlReport`, add
blocks in order, then :meth:`HtmlReport.write`.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 72em; color: #222; }
table { border-collapse: collapse; margin: 0.6em 0 1.2em; }
th, td { border: 1px solid #bbb; padding: 0.25em 0.6em; text-align: right; }
th { background: #eee; } td:first-child, th:first-child { text-align: left; }
figure { display: inline-block; margin: 0.4em; vertical-align: top; text-align: center; }
figure img { image-rendering: pixelated; border: 1px solid #ccc; }
figcaption { font-size: 0.85em; color: #555; }
.note { color: #555; font-size: 0.9em; }
"""

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _png_bytes(image: bytes | Path | str) -> bytes:
    data = image if isinstance(image, bytes) else Path(image).read_bytes()
    if not data.startswith(PNG_SIGNATURE):
        raise ValueError(
            f"HTML report: {'image bytes' if isinstance(image, bytes) else image} is not a PNG; expected PNG data"
        )
    return data


def _cell(value: object, digits: int) -> str:
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return html.escape(str(value))


@dataclass
class HtmlReport:
    """An HTML document built block by block.

    Examples
    --------
    >>> report = HtmlReport("ΔE <study>")
    >>> report.add_table(["ambient", "ΔE00"], [["tungsten", 18.25]], table_id="delta-e")
    >>> "<td>18.25</td>" in report.to_html() and "&lt;study&gt;" in report.to_html()
    True
    """

    title: str
    """Page title and first heading."""
    blocks: list[str] = field(default_factory=list)
    """HTML fragments, in order."""

    def add_heading(self, text: str, level: int = 2) -> None:
        """A section heading (h2 by default)."""
        level = min(max(int(level), 2), 6)
        self.blocks.append(f"<h{level}>{html.escape(text)}</h{level}>")

    def add_paragraph(self, text: str, note: bool = False) -> None:
        """A paragraph of plain text (escaped); ``note`` sets it in smaller grey type."""
        css = ' class="note"' if note else ""
        self.blocks.append(f"<p{css}>{html.escape(text)}</p>")

    def add_table(
        self,
        headers: Sequence[str],
        rows: Sequence[Sequence[object]],
        caption: str | None = None,
        table_id: str | None = None,
        digits: int = 2,
    ) -> None:
        """A table; floats are printed with ``digits`` decimals, everything else as text."""
        attributes = f' id="{html.escape(table_id, quote=True)}"' if table_id else ""
        parts = [f"<table{attributes}>"]
        if caption:
            parts.append(f"<caption>{html.escape(caption)}</caption>")
        parts.append("<tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in headers) + "</tr>")
        for row in rows:
            parts.append("<tr>" + "".join(f"<td>{_cell(value, digits)}</td>" for value in row) + "</tr>")
        parts.append("</table>")
        self.blocks.append("\n".join(parts))

    def add_images(self, images: Sequence[tuple[str, bytes | Path | str]], width_px: int | None = None) -> None:
        """A row of captioned PNG images (bytes or file paths), embedded as base64 data URIs."""
        figures = []
        for caption, image in images:
            encoded = base64.b64encode(_png_bytes(image)).decode("ascii")
            size = f' width="{int(width_px)}"' if width_px else ""
            alt = html.escape(caption, quote=True)
            figures.append(
                f'<figure><img src="data:image/png;base64,{encoded}" alt="{alt}"{size}>'
                f"<figcaption>{html.escape(caption)}</figcaption></figure>"
            )
        self.blocks.append("<div>" + "".join(figures) + "</div>")

    def to_html(self) -> str:
        """The whole document."""
        title = html.escape(self.title)
        body = "\n".join(self.blocks)
        return (
            f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n<title>{title}</title>\n'
            f"<style>{_STYLE}</style>\n</head>\n<body>\n<h1>{title}</h1>\n{body}\n</body>\n</html>\n"
        )

    def write(self, path: str | Path) -> Path:
        """Write the document (UTF-8) and return its path."""
        path = Path(path)
        path.write_text(self.to_html(), encoding="utf-8")
        return path
