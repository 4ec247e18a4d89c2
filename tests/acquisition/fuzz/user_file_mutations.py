"""Hypothesis strategies for a user's files that are wrong (issue 32 item 5): every file msflash reads
besides a sequence folder — spectral tables (CSV), spectrometer exports, ``calibration.json`` and the
tables it names, a reference chart's JSON, camera profiles.

Each mutation starts from one valid file and breaks it at one level:

- **bytes**: truncated, a bit flipped, junk inserted, replaced by binary junk, emptied, a UTF-8 byte
  order mark, CRLF or CR line ends, re-encoded as UTF-16, an undecodable byte, a million blank lines,
  a 20 MiB sparse file;
- **the file itself**: a symlink to ``/dev/zero``, to itself (a loop), dangling, to an identical copy
  elsewhere; a FIFO; a directory;
- **a table's cells** (CSV and exports; the cells of lines that hold only numbers): NaN, infinities,
  ``1e309``, 400 nines, denormals, ``1e308``, negatives, text, hex, underscores, other digits, an empty
  cell; a row deleted, duplicated, two rows swapped, all rows reversed; every value scaled by 10^±300;
  the rows replaced by 20 000 or 200 000 interpolated rows; a column added first or last, one removed,
  a header renamed;
- **a JSON document's values** (:mod:`tests.acquisition.fuzz.sequence_mutations`' values: wrong types,
  NaN, 10³⁰⁰, long and odd strings, nested lists), a key deleted, an unknown key added, nesting
  10 000 deep, an integer of 5 000 digits, a key given twice.

The rule deciding which exits are right (:class:`Expect`):

``REFUSE``
    The file is not one to read (not a regular file, empty, binary, over the size cap, a non-finite
    number or text where a number must be, a key twice): exit 2.
``SAME``
    The same data (a symlink to an identical copy, comment or blank lines): exit 0 with exactly the
    unmutated result.
``SAME_OR_REFUSE``
    The same data differently written (a BOM, CRLF, UTF-16, rows in another order): exit 0 with
    exactly the unmutated result, or exit 2 — never other numbers.
``EITHER``
    Other valid-looking data (a number for a number, a row fewer): exit 0 with sane results, or 2.

Whatever the class: exit 1, any other status, a traceback, more or less than one ``msflash: error:``
line, an error line that names neither the file nor its folder, or a hang is a bug.
"""

from __future__ import annotations

import enum
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import strategies as st

from tests.acquisition.fuzz.sequence_mutations import _get, json_paths, values


class Expect(enum.Enum):
    REFUSE = "refuse"
    SAME = "same"
    SAME_OR_REFUSE = "same-or-refuse"
    EITHER = "either"


@dataclass(frozen=True)
class FileMutation:
    """One change to one file: what it is (for the report), what it must cause, how to make it."""

    describe: str
    expect: Expect
    data: bytes | None = field(default=None, repr=False)
    """The file's new bytes (None: ``special`` replaces the file)."""
    special: str | None = None
    """``dev_zero``, ``loop``, ``dangling``, ``copy_link``, ``fifo``, ``directory``, ``sparse``."""

    def __repr__(self) -> str:
        return f"FileMutation({self.describe!r}, {self.expect})"


SPECIALS = {
    "dev_zero": Expect.REFUSE,
    "loop": Expect.REFUSE,
    "dangling": Expect.REFUSE,
    "fifo": Expect.REFUSE,
    "directory": Expect.REFUSE,
    "sparse": Expect.REFUSE,
    "copy_link": Expect.SAME,
}

NOT_A_NUMBER = ["nan", "NaN", "inf", "-inf", "Infinity", "1e309", "-1e309", "9" * 400, "abc", "0x10", "", "\x00", "--1"]
"""Cells that are no finite number: refused wherever a number is read."""
OTHER_NUMBERS = ["0", "-0", "-1", "1e308", "-1e308", "5e-324", "1e-400", "1e30", "0.5", "12345678", "+1", ".5", "1."]
"""Finite numbers (``1e-400`` reads as 0): another value, valid or refused by what it means."""
ODD_CELLS = ["1_000", "\u0661\u0662", "1,5", "1;5", " 7 ", "\t"]
"""Cells a reader may take as a number, split, or refuse: any of these is fine if the result is sane."""

NUMBER = re.compile(r"^\s*[-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?\s*$")
SEPARATORS = re.compile(r"[,;\t]| +")


def _lines(text: bytes) -> list[bytes]:
    return text.split(b"\n")


def data_rows(text: bytes) -> list[int]:
    """Indices of the lines (split at ``\\n``) whose cells are all plain numbers, at least two of them."""
    rows = []
    for index, line in enumerate(_lines(text)):
        cells = [c for c in SEPARATORS.split(line.decode("utf-8", "replace").strip()) if c != ""]
        if len(cells) >= 2 and all(NUMBER.match(c) for c in cells):
            rows.append(index)
    return rows


def _separator(line: bytes) -> bytes:
    for sep in (b",", b"\t", b";"):
        if sep in line:
            return sep
    return b" "


def _cells(line: bytes) -> tuple[bytes, list[bytes]]:
    """The separator and cells of a line (runs of spaces are one separator)."""
    sep = _separator(line)
    return sep, (line.split() if sep == b" " else line.split(sep))


@st.composite
def byte_mutations(draw: st.DrawFn, text: bytes, kind: str) -> FileMutation:
    """A change to the file's bytes or to what the file is (any format)."""
    op = draw(
        st.sampled_from(
            [
                "truncate",
                "bitflip",
                "insert",
                "binary",
                "empty",
                "bom",
                "crlf",
                "cr",
                "utf16",
                "undecodable",
                "blank_lines",
                "special",
            ]
        ),
        label="byte op",
    )
    if op == "truncate":
        cut = draw(st.integers(0, len(text) - 1), label="cut")
        # A JSON document cut before its last brace is broken; a table cut at a line may be a shorter table.
        broken = kind == "json" and cut < len(text.rstrip())
        return FileMutation(f"truncated to {cut} bytes", Expect.REFUSE if broken else Expect.EITHER, text[:cut])
    if op == "bitflip":
        at = draw(st.integers(0, len(text) - 1), label="at")
        bit = draw(st.integers(0, 7), label="bit")
        changed = bytearray(text)
        changed[at] ^= 1 << bit
        return FileMutation(f"bit {bit} of byte {at} flipped", Expect.EITHER, bytes(changed))
    if op == "insert":
        at = draw(st.integers(0, len(text)), label="at")
        junk = draw(st.binary(min_size=1, max_size=8), label="junk")
        return FileMutation(f"{junk!r} inserted at byte {at}", Expect.EITHER, text[:at] + junk + text[at:])
    if op == "binary":
        size = draw(st.sampled_from([1, 17, 4096, 70_000]), label="size")
        seed = draw(st.integers(0, 2**32 - 1), label="seed")
        junk = np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8).tobytes()
        return FileMutation(f"{size} random bytes", Expect.REFUSE, junk)
    if op == "empty":
        return FileMutation("empty", Expect.REFUSE, b"")
    if op == "bom":
        return FileMutation("UTF-8 byte order mark", Expect.SAME_OR_REFUSE, b"\xef\xbb\xbf" + text)
    if op == "crlf":
        return FileMutation("CRLF line ends", Expect.SAME_OR_REFUSE, text.replace(b"\n", b"\r\n"))
    if op == "cr":
        return FileMutation("CR line ends (classic Mac)", Expect.SAME_OR_REFUSE, text.replace(b"\n", b"\r"))
    if op == "utf16":
        return FileMutation("UTF-16 with BOM", Expect.SAME_OR_REFUSE, text.decode("utf-8").encode("utf-16"))
    if op == "undecodable":
        at = draw(st.integers(0, len(text)), label="at")
        return FileMutation(f"byte 0xff at {at}", Expect.EITHER, text[:at] + b"\xff" + text[at:])
    if op == "blank_lines":
        many = draw(st.sampled_from([1000, 1_000_000]), label="lines")
        # Blank lines at the end: nothing in any format reads them, but a reader looping per line
        # must not take minutes, and 1 MB stays under every cap.
        return FileMutation(f"{many} blank lines appended", Expect.SAME_OR_REFUSE, text + b"\n" * many)
    special = draw(st.sampled_from(sorted(SPECIALS)), label="special")
    return FileMutation(f"replaced by {special}", SPECIALS[special], special=special)


@st.composite
def table_mutations(draw: st.DrawFn, text: bytes, single: bool) -> FileMutation:
    """A change to the numbers of a table (a CSV or a spectrometer export): its lines of numbers.

    ``single``: the file holds one spectrum (``wavelength, value``), so a column added before it
    changes which numbers are read: refused, or the same result.
    """
    rows = data_rows(text)
    lines = _lines(text)
    op = draw(
        st.sampled_from(["cell", "cell", "cell", "row", "order", "scale", "dense", "column"]),
        label="table op",
    )
    if op == "cell":
        row = draw(st.sampled_from(rows), label="row")
        sep, cells = _cells(lines[row])
        column = draw(st.integers(0, len(cells) - 1), label="column")
        family = draw(st.sampled_from(["nan", "number", "odd"]), label="family")
        cell = draw(st.sampled_from({"nan": NOT_A_NUMBER, "number": OTHER_NUMBERS, "odd": ODD_CELLS}[family]))
        cells[column] = cell.encode()
        lines[row] = sep.join(cells)
        expect = Expect.REFUSE if family == "nan" else Expect.EITHER
        if family == "nan" and cell == "" and sep == b" ":
            expect = Expect.EITHER  # an empty cell between spaces is no cell: a row one value short
        where = f"line {row + 1} column {column + 1}"
        return FileMutation(f"{where} = {cell!r:.40}", expect, b"\n".join(lines))
    if op == "row":
        row = draw(st.sampled_from(rows), label="row")
        how = draw(st.sampled_from(["delete", "duplicate"]), label="how")
        if how == "delete":
            del lines[row]
        else:
            lines.insert(row, lines[row])
        return FileMutation(f"line {row + 1} {how}d", Expect.EITHER, b"\n".join(lines))
    if op == "order":
        how = draw(st.sampled_from(["swap", "reverse"]), label="how")
        if how == "swap":
            at = draw(st.integers(0, len(rows) - 2), label="at")
            a, b = rows[at], rows[at + 1]
            lines[a], lines[b] = lines[b], lines[a]
            describe = f"lines {a + 1} and {b + 1} swapped"
        else:
            picked = [lines[i] for i in rows]
            for index, line in zip(rows, reversed(picked), strict=True):
                lines[index] = line
            describe = "rows reversed"
        # The same numbers in another order: a reader sorts them (same result) or refuses them.
        return FileMutation(describe, Expect.SAME_OR_REFUSE, b"\n".join(lines))
    if op == "scale":
        power = draw(st.sampled_from([300, -300, 30, -30]), label="power")
        for index in rows:
            sep, cells = _cells(lines[index])
            lines[index] = sep.join(
                cells[:1] + [repr(float(c.decode().strip() or 0) * 10.0**power).encode() for c in cells[1:]]
            )
        return FileMutation(f"every value × 1e{power}", Expect.EITHER, b"\n".join(lines))
    if op == "dense":
        count = draw(st.sampled_from([20_000, 200_000]), label="rows")
        table = np.array([[float(c.strip() or 0) for c in _cells(lines[i])[1]] for i in rows])
        sep = _separator(lines[rows[0]])
        grid = np.linspace(table[0, 0], table[-1, 0], count)
        dense = np.column_stack([grid] + [np.interp(grid, table[:, 0], table[:, j]) for j in range(1, table.shape[1])])
        body = [sep.join(repr(float(v)).encode() for v in row) for row in dense]
        new = lines[: rows[0]] + body + lines[rows[-1] + 1 :]
        return FileMutation(f"{count} interpolated rows", Expect.EITHER, b"\n".join(new))
    how = draw(st.sampled_from(["first", "last", "drop", "rename"]), label="how")
    header = next((i for i in range(rows[0] - 1, -1, -1) if lines[i].strip()), None)  # the line above the numbers
    for index in ([header] if header is not None else []) + rows:
        sep, cells = _cells(lines[index])
        extra = b"extra" if index == header else b"0.25"
        if how == "first":
            cells.insert(1, extra)
        elif how == "last":
            cells.append(extra)
        elif how == "drop" and len(cells) > 2:
            cells.pop()
        elif how == "rename" and index == header and cells:
            cells[-1] = "\u00e9\U0001f4a9 \x1b[31mred".encode()
        lines[index] = sep.join(cells)
    expect = Expect.SAME_OR_REFUSE if single and how == "first" else Expect.EITHER
    return FileMutation(f"a column {how}", expect, b"\n".join(lines))


@st.composite
def json_mutations(draw: st.DrawFn, text: bytes) -> FileMutation:
    """A change to a JSON document's values or text."""
    document = json.loads(text)
    paths = json_paths(document)
    op = draw(st.sampled_from(["replace", "replace", "delete", "extra", "deep", "digits", "twice"]), label="json op")
    if op in ("replace", "delete", "extra"):
        path = draw(st.sampled_from(paths), label="path")
        changed = json.loads(text)
        parent = _get(changed, path[:-1])
        where = ".".join(map(str, path))
        if op == "replace":
            new = draw(values, label="value")
            parent[path[-1]] = new
            dumped = json.dumps(changed, indent=1).encode("utf-8", "surrogatepass")
            finite = all(
                not isinstance(v, float) or np.isfinite(v) for v in _leaves(new)
            )  # json.dumps writes NaN/Infinity
            return FileMutation(f"{where} = {new!r:.60}", Expect.EITHER if finite else Expect.REFUSE, dumped)
        if op == "delete":
            del parent[path[-1]]
            return FileMutation(f"delete {where}", Expect.EITHER, json.dumps(changed, indent=1).encode())
        target = parent if isinstance(parent, dict) else changed
        target["x_fuzz"] = draw(values, label="extra")
        dumped = json.dumps(changed, indent=1).encode("utf-8", "surrogatepass")
        finite = all(not isinstance(v, float) or np.isfinite(v) for v in _leaves(target["x_fuzz"]))
        return FileMutation(f"unknown key beside {where}", Expect.EITHER if finite else Expect.REFUSE, dumped)
    at = text.index(b"{") + 1
    if op == "deep":
        depth = draw(st.sampled_from([150, 10_000]), label="depth")
        return FileMutation(
            f"nested {depth} deep",
            Expect.REFUSE,
            text[:at] + b'"x_deep": ' + b"[" * depth + b"]" * depth + b"," + text[at:],
        )
    if op == "digits":
        digits = draw(st.sampled_from([400, 5000]), label="digits")
        return FileMutation(
            f"an integer of {digits} digits", Expect.REFUSE, text[:at] + b'"x_n": ' + b"9" * digits + b"," + text[at:]
        )
    key = next(iter(document))
    return FileMutation(f"key {key!r} twice", Expect.REFUSE, text[:at] + json.dumps(key).encode() + b": 1," + text[at:])


def _leaves(value: Any) -> list[Any]:
    if isinstance(value, dict):
        return [leaf for v in value.values() for leaf in _leaves(v)]
    if isinstance(value, list):
        return [leaf for v in value for leaf in _leaves(v)]
    return [value]


def file_mutations(text: bytes, kind: str, single: bool = False) -> st.SearchStrategy[FileMutation]:
    """Every family that fits a file of ``kind`` (``csv``, ``export`` or ``json``)."""
    if kind == "json":
        return st.one_of(byte_mutations(text, kind), json_mutations(text))
    return st.one_of(byte_mutations(text, kind), table_mutations(text, single))


def every_special(kind: str) -> list[FileMutation]:
    """What the file is, each kind once (the cases every run goes through)."""
    return [FileMutation(f"replaced by {special}", expect, special=special) for special, expect in SPECIALS.items()]


def apply_file_mutation(path: Path, mutation: FileMutation, outside: Path) -> None:
    """Write ``mutation`` at ``path`` (a copy of the base file); ``outside`` is a folder for a copy."""
    if mutation.data is not None:
        path.write_bytes(mutation.data)
        return
    original = path.read_bytes()
    path.unlink()
    special = mutation.special
    if special == "dev_zero":
        path.symlink_to("/dev/zero")
    elif special == "loop":
        path.symlink_to(path.name)
    elif special == "dangling":
        path.symlink_to(path.parent / "no-such-file.csv")
    elif special == "fifo":
        os.mkfifo(path)
    elif special == "directory":
        path.mkdir()
    elif special == "sparse":
        with path.open("wb") as stream:
            stream.write(original)
            stream.truncate(20 << 20)
    elif special == "copy_link":
        outside.mkdir(parents=True, exist_ok=True)
        copy = outside / path.name
        copy.write_bytes(original)
        path.symlink_to(copy)
    else:
        raise ValueError(special)
