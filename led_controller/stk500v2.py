"""The Arduino Mega 2560's bootloader as a twin: STK500v2 (Atmel AVR068) over the serial link.

While a reset board's bootloader owns the UART (``led_controller/usb_link.py``), avrdude can program
it: ``make -C led_controller/firmware flash PORT=…`` runs ``avrdude -c wiring`` (STK500v2, DTR pulsed to
reset). The emulator's server feeds the bytes it receives in that window to :class:`Stk500v2Bootloader`,
which answers as the Arduino stk500v2 bootloader does and keeps what is written in :attr:`flash`, so
flashing is tested end to end with the real avrdude and no board (Debian 12's avrdude 7.1 has no
``dryrun`` programmer; it came with 7.2). Written from AVR068 and the bootloader's observable replies:
a signature of ``1E 98 01``, ``CMD_CHIP_ERASE_ISP`` refused (pages are erased as they are written, hence
avrdude's ``-D``), unknown commands ``STATUS_CMD_FAILED``.

Not modelled: the bootloader's own flash section (writes there are kept here, a real one refuses
them), fuses and lock bits (read as 0), the ``!!!`` monitor of some builds, EEPROM programming.
"""

from __future__ import annotations

from dataclasses import dataclass, field

MESSAGE_START = 0x1B
TOKEN = 0x0E
STATUS_CMD_OK = 0x00
STATUS_CMD_FAILED = 0xC0

CMD_SIGN_ON = 0x01
CMD_SET_PARAMETER = 0x02
CMD_GET_PARAMETER = 0x03
CMD_LOAD_ADDRESS = 0x06
CMD_ENTER_PROGMODE_ISP = 0x10
CMD_LEAVE_PROGMODE_ISP = 0x11
CMD_PROGRAM_FLASH_ISP = 0x13
CMD_READ_FLASH_ISP = 0x14
CMD_READ_FUSE_ISP = 0x18
CMD_READ_LOCK_ISP = 0x1A
CMD_READ_SIGNATURE_ISP = 0x1B
CMD_SPI_MULTI = 0x1D

ATMEGA2560_SIGNATURE = (0x1E, 0x98, 0x01)
FLASH_BYTES = 256 * 1024
_PARAMETERS = {0x90: 0x0F, 0x91: 0x02, 0x92: 0x0A}  # HW_VER, SW_MAJOR, SW_MINOR


@dataclass
class Stk500v2Bootloader:
    """An STK500v2 bootloader's message parser and flash (see the module docstring)."""

    flash: bytearray = field(default_factory=lambda: bytearray(b"\xff" * FLASH_BYTES))
    """Erased (0xFF) at first; pages written by ``CMD_PROGRAM_FLASH_ISP`` land here."""
    active: bool = False
    """A programmer spoke to it: the bootloader stays until ``CMD_LEAVE_PROGMODE_ISP``."""
    left: bool = False
    """The programmer ended its session: the bootloader starts the firmware."""
    written: int = 0
    _buffer: bytearray = field(default_factory=bytearray)
    _address: int = 0

    def reset(self) -> None:
        """The board was reset: a new session (the flash is kept, as a real one is)."""
        self._buffer.clear()
        self.active = self.left = False
        self._address = 0

    def feed(self, data: bytes) -> bytes:
        """Bytes from the host; returns the answers to every complete message (bytes not in a message are dropped)."""
        self._buffer += data
        out = bytearray()
        while True:
            start = self._buffer.find(MESSAGE_START)
            if start < 0:
                self._buffer.clear()
                return bytes(out)
            del self._buffer[:start]
            if len(self._buffer) < 5:
                return bytes(out)
            size = self._buffer[2] << 8 | self._buffer[3]
            if self._buffer[4] != TOKEN or size > 300:
                del self._buffer[:1]  # not a message start after all
                continue
            if len(self._buffer) < 6 + size:
                return bytes(out)
            message = bytes(self._buffer[: 6 + size])
            del self._buffer[: 6 + size]
            checksum = 0
            for byte in message[:-1]:
                checksum ^= byte
            if checksum != message[-1]:
                continue  # a damaged message is ignored; the programmer times out and retries
            self.active = True
            out += _frame(message[1], self._answer(message[5:-1]))

    def _answer(self, body: bytes) -> bytes:
        command = body[0]
        if command == CMD_SIGN_ON:
            return bytes([command, STATUS_CMD_OK, 8]) + b"AVRISP_2"
        if command == CMD_GET_PARAMETER:
            return bytes([command, STATUS_CMD_OK, _PARAMETERS.get(body[1] if len(body) > 1 else 0, 0)])
        if command in (CMD_SET_PARAMETER, CMD_ENTER_PROGMODE_ISP):
            return bytes([command, STATUS_CMD_OK])
        if command == CMD_LEAVE_PROGMODE_ISP:
            self.left = True
            return bytes([command, STATUS_CMD_OK])
        if command == CMD_LOAD_ADDRESS and len(body) >= 5:
            self._address = (int.from_bytes(body[1:5], "big") << 1) & 0xFFFFFFFF
            return bytes([command, STATUS_CMD_OK])
        if command == CMD_PROGRAM_FLASH_ISP and len(body) >= 10:
            size = body[1] << 8 | body[2]
            data = body[10 : 10 + size]
            end = min(self._address + len(data), FLASH_BYTES)
            self.flash[self._address : end] = data[: end - self._address]
            self._address += len(data)
            self.written += len(data)
            return bytes([command, STATUS_CMD_OK])
        if command == CMD_READ_FLASH_ISP and len(body) >= 3:
            size = body[1] << 8 | body[2]
            data = bytes(self.flash[self._address : self._address + size]).ljust(size, b"\xff")
            self._address += size
            return bytes([command, STATUS_CMD_OK]) + data + bytes([STATUS_CMD_OK])
        if command == CMD_READ_SIGNATURE_ISP and len(body) >= 5:
            return bytes([command, STATUS_CMD_OK, ATMEGA2560_SIGNATURE[min(body[4], 2)], STATUS_CMD_OK])
        if command in (CMD_READ_FUSE_ISP, CMD_READ_LOCK_ISP):
            return bytes([command, STATUS_CMD_OK, 0, STATUS_CMD_OK])
        if command == CMD_SPI_MULTI and len(body) >= 7:
            answer = ATMEGA2560_SIGNATURE[min(body[6], 2)] if body[4] == 0x30 else 0
            return bytes([command, STATUS_CMD_OK, 0, body[4], 0, answer, STATUS_CMD_OK])
        return bytes([command, STATUS_CMD_FAILED])  # chip erase (0x12) too, as the Mega's bootloader


def _frame(seq: int, body: bytes) -> bytes:
    head = bytes([MESSAGE_START, seq, len(body) >> 8, len(body) & 0xFF, TOKEN]) + body
    checksum = 0
    for byte in head:
        checksum ^= byte
    return head + bytes([checksum])
