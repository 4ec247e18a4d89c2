"""Reading an Intel HEX image, to compare what the emulated bootloader flashed with ``booth.hex``."""

from __future__ import annotations


def read_intel_hex(text: str) -> dict[int, int]:
    """The bytes an Intel HEX file puts where (address → byte), for comparing a flashed image.

    >>> read_intel_hex(":03000000010203F7\\n:00000001FF\\n")
    {0: 1, 1: 2, 2: 3}
    """
    memory: dict[int, int] = {}
    base = 0
    for number, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line:
            continue
        if not line.startswith(":"):
            raise ValueError(f"line {number}: {line[:20]!r}; expected an Intel HEX record ':…'")
        record = bytes.fromhex(line[1:])
        if sum(record) & 0xFF:
            raise ValueError(f"line {number}: checksum does not add up")
        count, address, kind, data = record[0], record[1] << 8 | record[2], record[3], record[4 : 4 + record[0]]
        if len(data) != count:
            raise ValueError(f"line {number}: {len(data)} data bytes; expected {count}")
        if kind == 0:
            for offset, byte in enumerate(data):
                memory[base + address + offset] = byte
        elif kind == 1:
            break
        elif kind == 2:
            base = int.from_bytes(data, "big") << 4
        elif kind == 4:
            base = int.from_bytes(data, "big") << 16
    return memory
