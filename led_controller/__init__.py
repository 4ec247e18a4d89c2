"""msflash LED booth: wire protocol, driver, firmware emulator, discovery and checks."""

from msflash.led_controller.booth import LedBooth
from msflash.led_controller.emulator import BoothEmulator, ManualClock, PtyBoothServer, serve_on_pty
from msflash.led_controller.errors import BoothError, BoothNotFoundError, BoothProtocolError, BoothTimeoutError
from msflash.led_controller.protocol import BoothEvent, BoothInfo, BoothStatus

__all__ = [
    "BoothEmulator",
    "BoothError",
    "BoothEvent",
    "BoothInfo",
    "BoothNotFoundError",
    "BoothProtocolError",
    "BoothStatus",
    "BoothTimeoutError",
    "LedBooth",
    "ManualClock",
    "PtyBoothServer",
    "serve_on_pty",
]
