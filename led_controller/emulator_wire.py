"""The emulator's side of the wire: its own CRC, its own frame reader and writer (``docs/booth-protocol.md`` §2).

Written from the protocol page, apart from the driver's ``protocol.py`` (only the marks and limits
are shared), so that a parser bug cannot look consistent on both sides. :func:`read_request` walks
a request line field by field, the way the firmware walks its buffer, and raises
:class:`FrameRejected` with the code and text the booth answers on sequence 00.
"""

from __future__ import annotations

from dataclasses import dataclass

from msflash.led_controller.protocol import MARK_REQUEST, MAX_BODY, ErrorCode


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _crc_table()


def firmware_crc(data: bytes) -> int:
    """CRC-16/CCITT-FALSE, table-driven as the firmware computes it (independent of the driver's)."""
    crc = 0xFFFF
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ _CRC_TABLE[((crc >> 8) ^ byte) & 0xFF]
    return crc


def is_hex(text: bytes) -> bool:
    """Whether ``text`` is one or more upper-case hex digits."""
    return bool(text) and all(chr(b) in "0123456789ABCDEF" for b in text)


def encode_frame(mark: str, seq: int, body: str) -> bytes:
    """A reply or event frame, ``<mark>SS:LLL:<body>*CCCC\\n``; a body over :data:`MAX_BODY` becomes an ``E_LEN`` error."""
    payload = body.encode("ascii")
    if len(payload) > MAX_BODY:  # the firmware's buffer: never a longer frame than the protocol allows
        payload = b"ERR - %s reply longer than %d bytes" % (ErrorCode.LENGTH.value.encode(), MAX_BODY)
    head = b"%s%02X:%03X:%s" % (mark.encode("ascii"), seq, len(payload), payload)
    return head + b"*%04X\n" % firmware_crc(head)


class FrameRejected(Exception):
    """A request line the booth cannot read: the error code and text of its ``ERR -`` reply."""

    def __init__(self, code: ErrorCode, text: str) -> None:
        super().__init__(text)
        self.code = code
        self.text = text


@dataclass(frozen=True)
class Request:
    """A readable request: its sequence number, command name and argument words."""

    seq: int
    name: str
    args: list[str]


def read_request(line: bytes) -> Request:
    """Read ``'?' SS ':' LLL ':' body '*' CCCC`` (no line end), checked in the firmware's order.

    Raises
    ------
    FrameRejected
        At the first field that is wrong (length, checksum field, checksum, header, body, sequence 00).
    """
    if len(line) < 13:
        raise FrameRejected(ErrorCode.FRAME, "frame too short")
    star = len(line) - 5
    if line[star] != ord("*"):
        raise FrameRejected(ErrorCode.FRAME, "no checksum field")
    head, crc_text = line[:star], line[star + 1 :]
    if not is_hex(crc_text):
        raise FrameRejected(ErrorCode.FRAME, "checksum not hex")
    if firmware_crc(head) != int(crc_text, 16):
        raise FrameRejected(ErrorCode.CRC, "checksum mismatch")
    if head[0] != ord(MARK_REQUEST) or head[3] != ord(":") or head[7] != ord(":"):
        raise FrameRejected(ErrorCode.FRAME, "bad header")
    seq_text, len_text, body = head[1:3], head[4:7], head[8:]
    if not is_hex(seq_text) or not is_hex(len_text):
        raise FrameRejected(ErrorCode.FRAME, "header not hex")
    if int(len_text, 16) != len(body) or len(body) > MAX_BODY:
        raise FrameRejected(ErrorCode.LENGTH, "length mismatch")
    if any(b < 0x20 or b > 0x7E or b == 0x2A for b in body):
        raise FrameRejected(ErrorCode.FRAME, "body not printable")
    seq = int(seq_text, 16)
    if seq == 0:
        raise FrameRejected(ErrorCode.FRAME, "sequence 00 is reserved")
    words = body.decode("ascii").split(" ")
    return Request(seq, words[0], words[1:])
