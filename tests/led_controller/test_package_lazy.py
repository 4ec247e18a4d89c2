"""The booth package loads its driver, pyserial and the emulator only when a name of them is used."""

from __future__ import annotations

import subprocess
import sys

import msflash.led_controller as led_controller


def test_every_public_name_resolves_to_its_defining_module() -> None:
    assert sorted(led_controller.__all__) == sorted(led_controller._HOME)
    for name in led_controller.__all__:
        value = getattr(led_controller, name)
        assert value.__module__ == f"msflash.led_controller.{led_controller._HOME[name]}"


def test_the_command_line_starts_without_the_booth_driver() -> None:
    """Every command imports the booth's errors to name a failure; that must not load the driver or the emulator
    (``booth*``, ``emulator*`` modules) nor pyserial."""
    probe = (
        "import sys; import msflash.acquisition.app.cli; "
        "print(sorted(m for m in sys.modules if m == 'serial' "
        "or m.startswith(('msflash.led_controller.booth', 'msflash.led_controller.emulator'))))"
    )
    loaded = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert loaded.strip() == "[]"
