"""Hypothesis strategies for structured-but-wrong sequences (issue 19 item 6).

Each mutation starts from a valid sequence (:func:`tests.helpers.write_test_sequence`) and breaks
one thing: a value in ``sequence.json`` (wrong type, NaN, huge, negative, denormal, long or odd
strings), a key (missing, extra), the nesting, the JSON text itself (truncated, bad bytes, BOM,
duplicate keys, non-standard literals), or one frame file (a link, a FIFO, a directory, truncated,
bit-flipped, another encoding, a lying header, a digest that does not match).

The rule deciding whether exit 0 is allowed (:class:`Expect`):

``REFUSE``
    The mutation breaks the format (docs/architecture.md §6): a changed type, a non-finite number,
    a required key removed, a broken or changed frame file. Exit 2 is required.
``SAME``
    Known harmless (an unknown key added, key order, whitespace): exit 0 with the unmutated
    outputs, exactly.
``EITHER``
    The mutation keeps every value's JSON type and finiteness (a number replaced by another
    number, a string by another string, an optional key removed, a frame entry dropped), so it
    may leave a valid sequence with other data: exit 0 (with finite results) or 2.

Whatever the class, exit 1 with "unexpected" (a traceback in the crash log), any other status, a
traceback on the terminal or a hang is a bug.
"""

from __future__ import annotations

import copy
import enum
import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from hypothesis import strategies as st

from tests.acquisition.support.tiff_files import write_baseline_tiff

JsonPath = tuple[str | int, ...]


class Expect(enum.Enum):
    REFUSE = "refuse"
    SAME = "same"
    EITHER = "either"


@dataclass(frozen=True)
class Mutation:
    """One change to a sequence directory: what it is (for the report) and what it must cause."""

    describe: str
    expect: Expect
    document: Any = None
    """The new ``sequence.json`` as an object (None: unchanged, or ``text`` is set)."""
    text: bytes | None = None
    """The new ``sequence.json`` as bytes (set for text-level mutations)."""
    frame_change: tuple[str, int, Any] | None = None
    """(kind, frame index, parameter) applied by :func:`apply_mutation` to one frame file."""

    def __repr__(self) -> str:
        return f"Mutation({self.describe!r}, {self.expect})"


OPTIONAL_KEYS = {("camera", "serial"), ("camera", "responsivity")}
"""Keys format v1 allows to be absent (``sha256``/``file_bytes`` only as a pair)."""

HOSTILE_NUMBERS = [math.nan, math.inf, -math.inf]
ODD_STRINGS = [
    "",
    " ",
    "\x00",
    "\ud800",
    "\u202eevil",
    "e\u0301",
    "\U0001f4a9" * 50,
    "x" * 100_000,
    "../../etc/passwd",
    "/etc/passwd",
    "frames/",
    ".",
    "frames/../../x",
    "\n\r\t",
    "\\\\?\\C:\\x",
]


def json_paths(document: Any, prefix: JsonPath = ()) -> list[JsonPath]:
    """Every path in ``document`` (objects' keys and lists' indices), containers included."""
    paths = [prefix] if prefix else []
    if isinstance(document, dict):
        for key, value in document.items():
            paths += json_paths(value, (*prefix, key))
    elif isinstance(document, list):
        for index, value in enumerate(document):
            paths += json_paths(value, (*prefix, index))
    return paths


def _get(document: Any, path: JsonPath) -> Any:
    for step in path:
        document = document[step]
    return document


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int | float):
        return "number" if math.isfinite(value) else "nonfinite"
    return type(value).__name__


def _is_unknown(path: JsonPath) -> bool:
    """Whether ``path`` lies under a key format v1 does not define (preserved, never interpreted)."""
    return any(isinstance(step, str) and step.startswith("x_fuzz") for step in path)


numbers = st.one_of(
    st.sampled_from(
        [
            0,
            -0.0,
            -1,
            1,
            5e-324,
            2.2250738585072014e-308,
            1e-300,
            1e300,
            1.7976931348623157e308,
            -1e300,
            2**63,
            2**64 + 1,
            -(2**63),
            10**300,
            0.5,
            1e-12,
        ]
    ),
    st.floats(allow_nan=False, allow_infinity=False),
    st.integers(min_value=-(2**70), max_value=2**70),
)
scalars = st.one_of(
    st.none(),
    st.booleans(),
    numbers,
    st.sampled_from(HOSTILE_NUMBERS),
    st.sampled_from(ODD_STRINGS),
    st.text(max_size=30),
)
values = st.recursive(
    scalars,
    lambda inner: st.one_of(st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=5), inner, max_size=3)),
    max_leaves=8,
)


@st.composite
def document_mutations(draw: st.DrawFn, document: dict) -> Mutation:
    """One change to the parsed ``sequence.json``: replace, delete, wrap, duplicate or add."""
    paths = json_paths(document)
    path = draw(st.sampled_from(paths), label="path")
    op = draw(
        st.sampled_from(["replace", "replace", "replace", "delete", "wrap", "duplicate", "extra_key"]), label="op"
    )
    changed = copy.deepcopy(document)
    parent = _get(changed, path[:-1])
    key = path[-1]
    old = parent[key]
    where = ".".join(map(str, path))
    if op == "replace":
        new = draw(values, label="value")
        same_kind = _kind(new) == _kind(old) or (new is None and tuple(path) in OPTIONAL_KEYS)
        parent[key] = new
        expect = Expect.EITHER if same_kind else Expect.REFUSE
        return Mutation(f"{where} = {new!r:.80}", expect, changed)
    if op == "delete":
        del parent[key]
        optional = tuple(path) in OPTIONAL_KEYS or (isinstance(key, int) and path[:-1] == ("frames",))
        return Mutation(f"delete {where}", Expect.EITHER if optional else Expect.REFUSE, changed)
    if op == "wrap":
        parent[key] = draw(st.sampled_from([[old], {"value": old}]), label="wrapper")
        return Mutation(f"wrap {where}", Expect.REFUSE, changed)
    if op == "duplicate":
        if isinstance(parent, list):
            parent.insert(key, copy.deepcopy(old))
            # Another frame entry naming the same file is refused ("one file per frame"); every
            # other list then has a value too many.
            return Mutation(f"duplicate {where}", Expect.REFUSE, changed)
        parent[f"{key}"] = old
        return Mutation(f"rewrite {where}", Expect.SAME, changed)
    # An unknown key: kept by the reader and never interpreted.
    target = old if isinstance(old, dict) else parent if isinstance(parent, dict) else changed
    target_path = path if isinstance(old, dict) else path[:-1] if isinstance(parent, dict) else ()
    name = "x_fuzz" + draw(st.sampled_from(["", "\u00e9", "\U0001f4a9", "\x00", " key"]), label="suffix")
    target[name] = draw(values, label="extra")
    # Except in camera.responsivity, whose channels beyond R, G and B are read as spectra.
    expect = Expect.EITHER if tuple(target_path) == ("camera", "responsivity") else Expect.SAME
    return Mutation(f"add {'.'.join(map(str, (*target_path, name)))}", expect, changed)


@st.composite
def text_mutations(draw: st.DrawFn, text: bytes) -> Mutation:
    """One change to the bytes of ``sequence.json``."""
    op = draw(
        st.sampled_from(
            [
                "truncate",
                "garbage",
                "literal",
                "bom",
                "invalid_utf8",
                "duplicate_key",
                "empty",
                "whitespace",
                "deep",
                "huge_integer",
            ]
        ),
        label="text op",
    )
    if op == "truncate":
        cut = draw(st.integers(0, len(text) - 2), label="cut")
        return Mutation(f"sequence.json truncated to {cut} bytes", Expect.REFUSE, text=text[:cut])
    if op == "garbage":
        at = draw(st.integers(0, len(text)), label="at")
        junk = draw(st.binary(min_size=1, max_size=8), label="junk")
        # Bytes inserted inside a string literal may leave valid JSON with another string: EITHER.
        return Mutation(f"{junk!r} inserted at byte {at}", Expect.EITHER, text=text[:at] + junk + text[at:])
    if op == "literal":
        literal = draw(st.sampled_from([b"NaN", b"Infinity", b"-Infinity", b"1e999", b"-1e999", b"0x10", b"1_000"]))
        field = draw(st.sampled_from([b'"exposure_us": ', b'"gain": ', b'"black_level": ', b'"white_level": ']))
        changed = text.replace(field, field + literal + b', "x_fuzz_was": ', 1)
        return Mutation(f"{field.decode()}{literal.decode()}", Expect.REFUSE, text=changed)
    if op == "bom":
        return Mutation("UTF-8 byte order mark", Expect.EITHER, text=b"\xef\xbb\xbf" + text)
    if op == "invalid_utf8":
        at = text.index(b'"test-render"') + 1
        return Mutation("invalid UTF-8 in camera.model", Expect.EITHER, text=text[:at] + b"\xff\xfe" + text[at:])
    if op == "duplicate_key":
        return Mutation(
            "camera.model given twice",
            Expect.REFUSE,
            text=text.replace(b'"model": ', b'"model": "twice", "model": ', 1),
        )
    if op == "empty":
        return Mutation("sequence.json empty", Expect.REFUSE, text=b"")
    if op == "whitespace":
        return Mutation("sequence.json re-indented", Expect.SAME, text=json.dumps(json.loads(text)).encode())
    if op == "deep":
        depth = draw(st.sampled_from([10, 1000, 50_000]), label="depth")
        return Mutation(f"frames[0].exposure_us nested {depth} deep", Expect.REFUSE, text=_deep_text(text, depth))
    digits = draw(st.sampled_from([20, 400, 5000, 100_000]), label="digits")
    changed = text.replace(b'"gain": ', b'"gain": ' + b"9" * digits + b', "x_fuzz_was": ', 1)
    return Mutation(
        f"frames[0].gain has {digits} digits", Expect.REFUSE if digits >= 400 else Expect.EITHER, text=changed
    )


def _deep_text(text: bytes, depth: int) -> bytes:
    """``frames[0].exposure_us`` replaced by a list nested ``depth`` deep (too deep for json.dumps)."""
    return text.replace(
        b'"exposure_us": ', b'"exposure_us": ' + b"[" * depth + b"1" + b"]" * depth + b', "x_fuzz_was": ', 1
    )


FRAME_KINDS = [
    "symlink_sibling",
    "symlink_outside",
    "symlink_dev_zero",
    "symlink_loop",
    "fifo",
    "directory",
    "truncate",
    "bitflip",
    "delete",
    "empty",
    "garbage",
    "encoding",
    "huge_header",
    "chmod_000",
    "header_bytes",
    "rename",
]
ODD_FILE_NAMES = [
    b"frames/\xff\xfe-led.tiff",
    "frames/e\u0301 \U0001f4a9.tiff".encode(),
    b"frames/new\nline.tiff",
    b"frames/tab\there.tiff",
    b"frames/-led.tiff",
    b"frames/" + b"n" * 250 + b".tiff",
    b"frames/.hidden.tiff",
    b"frames/a\x1b[31mred.tiff",
]


ENCODINGS = [
    "uint8",
    "float32",
    "float16",
    "uint32",
    "int16",
    "grey",
    "two_channels",
    "four_channels",
    "big_endian",
    "other_size",
]


@st.composite
def frame_mutations(draw: st.DrawFn, n_frames: int) -> Mutation:
    """One change to one frame file, with or without its recorded digest."""
    kind = draw(st.sampled_from(FRAME_KINDS), label="frame op")
    index = draw(st.integers(0, n_frames - 1), label="frame")
    parameter: Any = None
    if kind in ("truncate", "bitflip"):
        parameter = draw(st.integers(0, 17_999), label="byte")
    elif kind == "encoding":
        parameter = draw(st.sampled_from(ENCODINGS), label="encoding")
    elif kind == "rename":
        parameter = draw(st.sampled_from(ODD_FILE_NAMES), label="name")
    elif kind == "header_bytes":  # the TIFF header, its directory at byte 8 and the tags' data after it
        parameter = tuple(
            draw(
                st.lists(
                    st.tuples(st.integers(0, 399), st.integers(1, 255)),
                    min_size=1,
                    max_size=6,
                    unique_by=lambda change: change[0],
                ),
                label="header bytes",
            )
        )
    keep_digest = draw(st.booleans(), label="keep digest")
    return frame_mutation(kind, index, parameter, keep_digest)


def every_frame_mutation(index: int) -> list[Mutation]:
    """Each kind of frame change (each encoding; a cut and a flip at byte 100) on frame ``index``,
    with and without its digest: the cases every run goes through, whatever Hypothesis draws."""
    cases = [
        (kind, None)
        for kind in FRAME_KINDS
        if kind not in ("encoding", "truncate", "bitflip", "header_bytes", "rename")
    ]
    cases += [("rename", name) for name in ODD_FILE_NAMES]
    cases += [("encoding", encoding) for encoding in ENCODINGS] + [("truncate", 100), ("bitflip", 100)]
    cases += [
        ("header_bytes", ((2, 0x2B),)),
        ("header_bytes", ((4, 0xFF), (5, 0xFF), (6, 0xFF), (7, 0x7F))),
        ("header_bytes", ((30, 0xFF), (31, 0xFF))),
    ]
    return [frame_mutation(kind, index, parameter, keep) for kind, parameter in cases for keep in (True, False)]


def frame_mutation(kind: str, index: int, parameter: Any, keep_digest: bool) -> Mutation:
    """Frame ``index`` changed by ``kind`` (see :func:`apply_mutation`), its digest kept or dropped."""
    # Without its digest, a frame replaced by a readable image of the same shape and range (another
    # frame, another encoding of values that fit, a flipped bit among the pixels) is another valid
    # recording: EITHER. Everything
    # else must be refused by what the file is.
    # A frame renamed (its entry too) to a name that is valid UTF-8 is the same recording: EITHER
    # (check lists the new name). A name that is not UTF-8 is refused (format v1 names are UTF-8).
    if kind == "rename":
        either = parameter != ODD_FILE_NAMES[0]
        return Mutation(
            f"frames[{index}] renamed {parameter!r}",
            Expect.EITHER if either else Expect.REFUSE,
            frame_change=(kind, index, (parameter, keep_digest)),
        )
    either = not keep_digest and (
        kind in ("symlink_sibling", "bitflip", "header_bytes")
        or (kind == "encoding" and parameter in ("uint8", "big_endian", "float32", "float16"))
    )
    expect = Expect.EITHER if either else Expect.REFUSE
    if kind == "chmod_000" and os.geteuid() == 0:
        expect = Expect.EITHER  # root reads it anyway: unchanged content, but check reports "unverified"
    return Mutation(
        f"frames[{index}] {kind}{'' if parameter is None else f' {parameter}'}"
        f"{'' if keep_digest else ' (digest dropped)'}",
        expect,
        frame_change=(kind, index, (parameter, keep_digest)),
    )


def mutations(document: dict, text: bytes) -> st.SearchStrategy[Mutation]:
    """Any of the three families."""
    return st.one_of(document_mutations(document), text_mutations(text), frame_mutations(len(document["frames"])))


def apply_mutation(sequence: Path, mutation: Mutation) -> None:
    """Write ``mutation`` into ``sequence`` (a copy of the base sequence)."""
    json_path = sequence / "sequence.json"
    if mutation.document is not None:
        json_path.write_text(json.dumps(mutation.document, indent=1), encoding="utf-8", errors="surrogatepass")
    if mutation.text is not None:
        json_path.write_bytes(mutation.text)
    if mutation.frame_change is None:
        return
    kind, index, (parameter, keep_digest) = mutation.frame_change
    document = json.loads(json_path.read_text())
    if not keep_digest:
        document["frames"][index].pop("sha256")
        document["frames"][index].pop("file_bytes")
        json_path.write_text(json.dumps(document, indent=1))
    frame = sequence / document["frames"][index]["file"]
    sibling = sequence / document["frames"][(index + 1) % len(document["frames"])]["file"]
    if kind == "symlink_sibling":
        frame.unlink()
        frame.symlink_to(sibling.name)
    elif kind == "symlink_outside":
        outside = sequence.parent / "outside.tiff"
        outside.write_bytes(frame.read_bytes())
        frame.unlink()
        frame.symlink_to(outside)
    elif kind == "symlink_dev_zero":
        frame.unlink()
        frame.symlink_to("/dev/zero")
    elif kind == "symlink_loop":
        frame.unlink()
        frame.symlink_to(frame.name)
    elif kind == "fifo":
        frame.unlink()
        os.mkfifo(frame)
    elif kind == "directory":
        frame.unlink()
        frame.mkdir()
    elif kind == "truncate":
        data = frame.read_bytes()
        frame.write_bytes(data[: parameter % len(data)])
    elif kind == "bitflip":
        data = bytearray(frame.read_bytes())
        data[parameter % len(data)] ^= 0x10
        frame.write_bytes(bytes(data))
    elif kind == "delete":
        frame.unlink()
    elif kind == "empty":
        frame.write_bytes(b"")
    elif kind == "garbage":
        frame.write_bytes(bytes(range(256)) * 70)
    elif kind == "rename":
        os.rename(frame, os.fsencode(sequence) + b"/" + parameter)
        document["frames"][index]["file"] = os.fsdecode(parameter)
        json_path.write_text(json.dumps(document, indent=1), encoding="utf-8", errors="surrogateescape")
    elif kind == "header_bytes":
        data = bytearray(frame.read_bytes())
        for position, flips in parameter:
            data[position] ^= flips  # never 0: every listed byte changes
        frame.write_bytes(bytes(data))
    elif kind == "chmod_000":
        frame.chmod(0)
    elif kind == "huge_header":
        _write_huge_header_tiff(frame)
    elif kind == "encoding":
        _rewrite_encoding(frame, parameter)


def _rewrite_encoding(frame: Path, encoding: str) -> None:
    from msflash.acquisition.sequence.image_files import read_image

    pixels = read_image(frame)
    frame.unlink()
    if encoding == "uint8":
        write_baseline_tiff(frame, (pixels >> 8).astype(np.uint8))
    elif encoding in ("float32", "float16"):
        write_baseline_tiff(frame, pixels.astype(encoding))
    elif encoding in ("uint32", "int16"):
        write_baseline_tiff(frame, pixels.astype(encoding))
    elif encoding == "grey":
        write_baseline_tiff(frame, pixels[:, :, 0])
    elif encoding == "two_channels":
        write_baseline_tiff(frame, np.ascontiguousarray(pixels[:, :, :2]))
    elif encoding == "four_channels":
        write_baseline_tiff(frame, np.concatenate([pixels, pixels[:, :, :1]], axis=2))
    elif encoding == "big_endian":
        write_baseline_tiff(frame, pixels, big_endian=True)
    else:  # other_size
        write_baseline_tiff(frame, np.ascontiguousarray(pixels[:-1, :-1]))


def _write_huge_header_tiff(frame: Path) -> None:
    """A tiny file whose TIFF header claims a 60000×60000 RGB16 image (21.6 GB of pixels)."""
    import struct

    entries = [
        (256, 4, 1, 60000),
        (257, 4, 1, 60000),
        (258, 3, 1, 16),
        (259, 3, 1, 1),
        (262, 3, 1, 2),
        (273, 4, 1, 8),
        (277, 3, 1, 3),
        (278, 4, 1, 60000),
        (279, 4, 1, 60000 * 60000 * 6 % 2**32),
    ]
    ifd_offset = 8 + 64
    header = b"II*\x00" + struct.pack("<I", ifd_offset) + b"\x00" * 64
    ifd = struct.pack("<H", len(entries))
    for tag, kind, count, value in entries:
        ifd += (
            struct.pack("<HHII", tag, kind, count, value)
            if kind == 4
            else struct.pack("<HHIHH", tag, kind, count, value, 0)
        )
    frame.write_bytes(header + ifd + b"\x00\x00\x00\x00")
