"""msflash LED booth: wire protocol, driver, firmware emulator, discovery and checks.

The names below are loaded when first used (PEP 562): importing the package, or its ``errors``
module alone (as every msflash command does, to name a booth failure), does not load the driver,
pyserial and the emulator (their share of a command's start: docs/measurements.md).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

from msflash.one_copy import one_copy

one_copy(__name__)  # "import led_controller" from the repository root: a one-line ImportError naming msflash.…

if TYPE_CHECKING:
    from msflash.led_controller.booth import LedBooth
    from msflash.led_controller.emulator import BoothEmulator, ManualClock
    from msflash.led_controller.emulator_pty import PtyBoothServer, serve_on_pty
    from msflash.led_controller.errors import BoothError, BoothNotFoundError, BoothProtocolError, BoothTimeoutError
    from msflash.led_controller.protocol import BoothEvent, BoothInfo, BoothStatus

_HOME = {
    "BoothEmulator": "emulator",
    "BoothError": "errors",
    "BoothEvent": "protocol",
    "BoothInfo": "protocol",
    "BoothNotFoundError": "errors",
    "BoothProtocolError": "errors",
    "BoothStatus": "protocol",
    "BoothTimeoutError": "errors",
    "LedBooth": "booth",
    "ManualClock": "emulator",
    "PtyBoothServer": "emulator_pty",
    "serve_on_pty": "emulator_pty",
}
"""Each public name and the module that defines it."""

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


def __getattr__(name: str) -> Any:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'msflash.led_controller' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"msflash.led_controller.{home}"), name)
    globals()[name] = value  # once loaded, an attribute like any other
    return value
