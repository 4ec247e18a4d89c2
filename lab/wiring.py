"""The booth's wiring diagram, drawn from the firmware's own pin table (``docs/booth-wiring.svg``).

``firmware/board/pins_mega2560.h`` is the one list of the Mega's booth pins: the board layer builds its
PWM table and trigger pins from it and this module draws it, so the diagram cannot drift from the
firmware. ``python -m msflash.lab.wiring --out docs/booth-wiring.svg`` rewrites it; the
tests regenerate it and compare. Every LED channel goes to a constant-current LED driver's PWM
(dimming/enable) input, never to an LED: an ATmega2560 pin is specified for 20 mA (40 mA absolute
maximum; 200 mA through all VCC/GND pins, 100 mA for the port E group), far from an LED's current.
"""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape

from msflash.led_controller.firmware_sim import FIRMWARE_DIR

PIN_TABLE = FIRMWARE_DIR / "board" / "pins_mega2560.h"
CONFIG = FIRMWARE_DIR / "core" / "booth_config.h"

PIN_CURRENT_MA = 20
"""ATmega2560 pin current at which its output levels are specified (VCC 5 V: VOH ≥ 4.2 V, VOL ≤ 0.9 V)."""
PIN_ABSOLUTE_MAX_MA = 40
"""ATmega2560 absolute maximum DC current per I/O pin."""
SUPPLY_PINS_MAX_MA = 200
"""ATmega2560 absolute maximum DC current through the VCC and GND pins."""


@dataclass(frozen=True)
class LedPin:
    """One LED channel's output pin."""

    channel: int
    port: str
    bit: int
    arduino: int
    timer: int
    unit: str
    name: str

    @property
    def avr(self) -> str:
        """Get the AVR pin name, e.g. ``PE3``."""
        return f"P{self.port}{self.bit}"

    @property
    def output(self) -> str:
        """Get the timer output, e.g. ``OC3A``."""
        return f"OC{self.timer}{self.unit}"


@dataclass(frozen=True)
class Pins:
    """The board's booth pins, as ``pins_mega2560.h`` lists them."""

    leds: tuple[LedPin, ...]
    trigger_out: tuple[str, int, int]
    exposure_in: tuple[str, int, int, str]


def read_pins(table: Path = PIN_TABLE, config: Path = CONFIG) -> Pins:
    """Parse the pin table (and the default channel names of ``booth_config.h``).

    Raises
    ------
    ValueError
        If the table does not have the expected ``X(…)`` entries.
    """
    text = table.read_text(encoding="ascii")
    names_match = re.search(r'#define BOOTH_NAMES "([^"]+)"', config.read_text(encoding="ascii"))
    names = names_match.group(1).split(",") if names_match else []
    block = re.search(r"#define BOOTH_LED_PINS\(X\)(.*?)\n\n", text, re.S)
    if block is None:
        raise ValueError(
            f"{table}: no BOOTH_LED_PINS(X) table; expected X(channel, port, bit, pin, timer, unit) entries"
        )
    leds = []
    for channel, port, bit, arduino, timer, unit in re.findall(
        r"X\((\d+),\s*([A-L]),\s*(\d),\s*(\d+),\s*(\d),\s*([ABC])\)", block.group(1)
    ):
        index = int(channel)
        leds.append(
            LedPin(
                index,
                port,
                int(bit),
                int(arduino),
                int(timer),
                unit,
                names[index] if index < len(names) else f"ch{index}",
            )
        )
    trigger = re.search(r"#define BOOTH_TRIGGER_OUT\(X\) X\(([A-L]),\s*(\d),\s*(\d+)\)", text)
    exposure = re.search(r"#define BOOTH_EXPOSURE_IN\(X\) X\(([A-L]),\s*(\d),\s*(\d+),\s*(\w+)\)", text)
    if not leds or trigger is None or exposure is None:
        raise ValueError(f"{table}: LED, trigger or exposure pins missing; expected the X(…) tables")
    return Pins(
        tuple(leds),
        (trigger.group(1), int(trigger.group(2)), int(trigger.group(3))),
        (exposure.group(1), int(exposure.group(2)), int(exposure.group(3)), exposure.group(4)),
    )


def _text(x: float, y: float, body: str, *, size: int = 12, anchor: str = "start", weight: str = "normal") -> str:
    return (
        f'<text x="{x:g}" y="{y:g}" font-size="{size}" text-anchor="{anchor}" font-weight="{weight}">'
        f"{escape(body)}</text>"
    )


def wiring_svg(pins: Pins) -> str:
    """The diagram as SVG text (deterministic: the same pins give the same bytes)."""
    row = 44
    top = 90
    height = top + row * (len(pins.leds) + 3) + 150
    out: list[str] = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="980" height="{height}" viewBox="0 0 980 {height}" '
        'font-family="DejaVu Sans, Arial, sans-serif">',
        "<title>msflash booth wiring: Arduino Mega 2560 (from firmware/board/pins_mega2560.h)</title>",
        '<rect width="100%" height="100%" fill="white"/>',
        _text(20, 30, "msflash booth wiring — Arduino Mega 2560", size=18, weight="bold"),
        _text(
            20,
            52,
            "generated from led_controller/firmware/board/pins_mega2560.h (python -m msflash.lab.wiring)",
            size=11,
        ),
        f'<rect x="20" y="{top - 25}" width="230" height="{row * (len(pins.leds) + 2) + 20}" rx="8" fill="#1f6fa8" stroke="black"/>',
        _text(135, top - 5, "Arduino Mega 2560", size=13, anchor="middle", weight="bold"),
    ]
    for i, led in enumerate(pins.leds):
        y = top + 20 + i * row
        out += [
            _text(240, y + 4, f"D{led.arduino} ({led.avr}, {led.output})", anchor="end"),
            f'<line x1="250" y1="{y}" x2="520" y2="{y}" stroke="black" stroke-width="2"/>',
            _text(260, y - 6, f"channel {led.channel}: {led.name} — PWM, 5 V logic", size=11),
            f'<rect x="520" y="{y - 16}" width="250" height="32" fill="#fff5d6" stroke="black"/>',
            _text(645, y + 4, "constant-current LED driver: PWM / EN in", size=11, anchor="middle"),
            f'<line x1="770" y1="{y}" x2="830" y2="{y}" stroke="black" stroke-width="2"/>',
            f'<polygon points="830,{y - 10} 830,{y + 10} 848,{y}" fill="#ffd24d" stroke="black"/>',
            f'<line x1="848" y1="{y - 10}" x2="848" y2="{y + 10}" stroke="black" stroke-width="2"/>',
            _text(858, y + 4, f"LED {led.name}", size=11),
        ]
    port, bit, arduino = pins.trigger_out
    y = top + 20 + len(pins.leds) * row
    out += [
        _text(240, y + 4, f"D{arduino} (P{port}{bit})", anchor="end"),
        f'<line x1="250" y1="{y}" x2="520" y2="{y}" stroke="black" stroke-width="2" marker-end="url(#arrow)"/>',
        _text(260, y - 6, "trigger out (booth master)", size=11),
    ]
    port, bit, arduino, irq = pins.exposure_in
    y += row
    out += [
        _text(240, y + 4, f"D{arduino} (P{port}{bit}, {irq})", anchor="end"),
        f'<line x1="250" y1="{y}" x2="520" y2="{y}" stroke="black" stroke-width="2"/>',
        _text(260, y - 6, "ExposureActive in (camera master)", size=11),
        f'<rect x="520" y="{y - 16 - row}" width="250" height="{row + 32}" fill="#e4f1e4" stroke="black"/>',
        _text(645, y - row / 2 - 6, "industrial camera: trigger input", size=11, anchor="middle"),
        _text(645, y - row / 2 + 10, "and ExposureActive output (high = exposing)", size=11, anchor="middle"),
    ]
    notes = [
        "GND: the Mega's GND to every LED driver's and the camera I/O's ground (one star point).",
        f"Pin currents (ATmega2560 datasheet): {PIN_CURRENT_MA} mA specified, {PIN_ABSOLUTE_MAX_MA} mA absolute maximum per pin, "
        f"{SUPPLY_PINS_MAX_MA} mA through all VCC/GND pins",
        "(100 mA for the port E group: D2, D3, D5). Drive a driver's logic input (µA–mA), never an LED straight off a pin.",
        "ExposureActive has the internal pull-up (~20–50 kΩ): a loose wire reads high (no edges). An open-collector or",
        "opto-isolated camera output pulls low while active: invert the line in the camera (LineInverter) so high = exposing.",
        "Camera inputs and outputs are often opto-isolated and 12–24 V: use the camera's 5 V/TTL lines or a level shifter.",
    ]
    y += 60
    for note in notes:
        out.append(_text(20, y, note, size=11))
        y += 18
    out.insert(
        2,
        '<defs><marker id="arrow" markerWidth="10" markerHeight="10" refX="9" refY="5" orient="auto">'
        '<path d="M0,0 L10,5 L0,10 z"/></marker></defs>',
    )
    out.append("</svg>")
    return "\n".join(out) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """Write (or print) the wiring diagram."""
    parser = argparse.ArgumentParser(prog="python -m msflash.lab.wiring", description=__doc__)
    parser.add_argument("--out", type=Path, default=None, help="write the SVG here (default: stdout)")
    args = parser.parse_args(argv)
    svg = wiring_svg(read_pins())
    if args.out is None:
        print(svg, end="")
    else:
        args.out.write_text(svg, encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
