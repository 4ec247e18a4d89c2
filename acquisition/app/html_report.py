"""HTML reports: headings, text, tables and PNG images, the one HTML writer of msflash.

``msflash evaluate`` and ``msflash colour-study`` embed their images as base64
(:meth:`HtmlReport.add_images`: one file that opens anywhere, no side files, no scripts, no
network); ``msflash run``'s report links the PNG files beside it by relative path
(:meth:`HtmlReport.add_linked_images`: the full-size previews are on disk already). Build a
:class:`HtmlReport`, add blocks in order, then :meth:`HtmlReport.write`.
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
figure { display: inline-block; margin: 0.4em; vertical-align: top; text-align: center; box-sizing: border-box; }
figure img { image-rendering: pixelated; border: 1px solid #ccc; max-width: 100%; height: auto; }
figure.plot img { image-rendering: auto; border: none; }
figcaption { font-size: 0.85em; color: #555; }
.note { color: #555; font-size: 0.9em; }
.warning { color: #a33c00; }
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


def _figures(
    sources: Sequence[tuple[str, str, str | None]], width_px: int | None, columns: int | None, plot: bool
) -> str:
    """``<figure>``s of (caption, src, link or None) in one ``<div>``."""
    figures = []
    css = ' class="plot"' if plot else ""
    share = f' style="width: calc({100 / columns:.3f}% - 0.8em)"' if columns else ""
    size = f' width="{int(width_px)}"' if width_px else ""
    for caption, src, link in sources:
        alt = html.escape(caption, quote=True)
        image = f'<img src="{html.escape(src, quote=True)}" alt="{alt}"{size}>'
        if link is not None:
            image = f'<a href="{html.escape(link, quote=True)}">{image}</a>'
        figures.append(f"<figure{css}{share}>{image}<figcaption>{html.escape(caption)}</figcaption></figure>")
    return "<div>" + "".join(figures) + "</div>"


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

    def add_paragraph(self, text: str, note: bool = False, warning: bool = False) -> None:
        """A paragraph of plain text (escaped); ``note`` sets it in smaller grey type, ``warning`` in orange."""
        classes = " ".join(name for name, on in (("note", note), ("warning", warning)) if on)
        css = f' class="{classes}"' if classes else ""
        self.blocks.append(f"<p{css}>{html.escape(text)}</p>")

    def add_table(
        self,
        headers: Sequence[str],
        rows: Sequence[Sequence[object]],
        table_id: str | None = None,
        digits: int = 2,
    ) -> None:
        """A table; floats are printed with ``digits`` decimals, everything else as text."""
        attributes = f' id="{html.escape(table_id, quote=True)}"' if table_id else ""
        parts = [f"<table{attributes}>"]
        parts.append("<tr>" + "".join(f"<th>{html.escape(str(h))}</th>" for h in headers) + "</tr>")
        for row in rows:
            parts.append("<tr>" + "".join(f"<td>{_cell(value, digits)}</td>" for value in row) + "</tr>")
        parts.append("</table>")
        self.blocks.append("\n".join(parts))

    def add_images(
        self,
        images: Sequence[tuple[str, bytes | Path | str]],
        width_px: int | None = None,
        columns: int | None = None,
        plot: bool = False,
    ) -> None:
        """A row of captioned PNG images (bytes or file paths), embedded as base64 data URIs.

        ``width_px`` fixes the shown width; ``columns`` shares the page's width between that many
        images per row (each shown at most at its own size); ``plot`` marks drawn figures (smooth
        scaling, no frame) rather than camera images (pixels kept square).
        """
        sources = [
            (caption, "data:image/png;base64," + base64.b64encode(_png_bytes(image)).decode("ascii"), None)
            for caption, image in images
        ]
        self.blocks.append(_figures(sources, width_px, columns, plot))

    def add_linked_images(
        self,
        images: Sequence[tuple[str, Path]],
        base: Path,
        columns: int | None = None,
        plot: bool = False,
    ) -> None:
        """A row of captioned PNG files shown by their path relative to ``base`` (the report's folder).

        Each image links to its file (open it at full size). The files must exist, be PNGs and
        lie under ``base``, so the report never points at nothing.
        """
        sources = []
        for caption, image in images:
            path = Path(image)
            _png_bytes(path)
            relative = path.resolve().relative_to(Path(base).resolve()).as_posix()
            sources.append((caption, relative, relative))
        self.blocks.append(_figures(sources, None, columns, plot))

    def add_file_links(self, names: Sequence[str], base: Path) -> None:
        """A list of links to the files ``names`` (paths relative to ``base``, the report's folder) that exist."""
        present = [name for name in names if (Path(base) / name).is_file()]
        items = "".join(f'<li><a href="{html.escape(n, quote=True)}">{html.escape(n)}</a></li>' for n in present)
        self.blocks.append(f"<ul>{items}</ul>")

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
