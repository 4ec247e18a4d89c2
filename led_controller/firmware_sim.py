"""The booth firmware (``led_controller/firmware/``) running in simavr, on a pseudo-terminal.

:class:`SimulatedBooth` builds the AVR image and the simavr harness with ``make`` (gcc-avr,
avr-libc, libsimavr-dev), starts ``booth_sim`` on the image and offers what the tests need of
a far end: the slave :attr:`~SimulatedBooth.port` for :meth:`LedBooth.open`, the PWM
:attr:`~SimulatedBooth.levels` read from the timer registers, the camera's ExposureActive line
(:meth:`~SimulatedBooth.exposure_active`) and the trigger-output :attr:`~SimulatedBooth.pulses`.
Time is simavr's simulated time, paced to the wall clock (docs/booth-firmware.md, *simavr*).
"""

from __future__ import annotations

import fcntl
import os
import queue
import shutil
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from msflash.led_controller.usb_link import FTDI_LATENCY_S, MEGA_BOOTLOADER_S

FIRMWARE_DIR = Path(__file__).resolve().parent / "firmware"
"""The firmware's sources and Makefile (package data: an installed msflash carries them too)."""


def _build_directory() -> Path:
    """``firmware/build`` in a checkout; a user cache folder when the package folder is read-only (an installed wheel)."""
    if os.access(FIRMWARE_DIR, os.W_OK):
        return FIRMWARE_DIR / "build"
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return cache / "msflash" / "firmware-build"


BUILD_DIR = _build_directory()
ELF = BUILD_DIR / "booth.elf"
HARNESS = BUILD_DIR / "booth_sim"
_TOOLS = ("avr-gcc", "avr-size", "make", "gcc")
_HEADERS = (Path("/usr/lib/avr/include/avr/io.h"), Path("/usr/include/simavr/parts/uart_pty.h"))


CYCLES_PER_US = 16.0
"""The simulated ATmega2560 runs at 16 MHz."""
SIM_CHANNELS = 7
"""LED channels the harness reports (OC3A … OC5A), whatever the image drives."""


@dataclass(frozen=True)
class Exposure:
    """One camera exposure in simulated time and what each LED pin gave each row."""

    start_us: float
    """Simulated time the first row started exposing."""
    exposure_us: float
    line_us: float
    """The delay between rows (0: a global shutter)."""
    on_us: tuple[tuple[float, ...], ...]
    """``on_us[row][channel]``: µs the LED pin was high within that row's window, exact to the cycle
    (``sim/pin_model.c``)."""

    def fractions(self) -> tuple[tuple[float, ...], ...]:
        """Each row's energy from each LED as a fraction of the LED on for the whole exposure."""
        return tuple(tuple(on / self.exposure_us for on in row) for row in self.on_us)


class FirmwareSimError(RuntimeError):
    """The firmware could not be built or the simulator failed."""


@dataclass(frozen=True)
class TriggerPulse:
    """A rising edge of the booth's trigger output, as simavr saw it."""

    time_us: float
    settled_us: float | None
    """Simulated time since the LED duties last changed (the settle the camera got)."""
    levels: tuple[float, ...]
    """Per channel the PWM duty of its pin (high ticks per period / (TOP + 1)), or 0/1 for a pin the
    timer does not drive (pulse dimming between its pulses)."""


def toolchain_missing() -> str | None:
    """Why the firmware cannot be built here (one line), or None if it can."""
    missing = [tool for tool in _TOOLS if shutil.which(tool) is None]
    missing += [str(h) for h in _HEADERS if not h.exists()]
    if missing:
        return (
            "AVR toolchain not installed (missing " + ", ".join(missing) + "); expected "
            "gcc-avr avr-libc binutils-avr simavr libsimavr-dev (setup.sh installs them)"
        )
    return None


def build() -> None:
    """Build the firmware image and the simavr harness (``make``; serialised across processes)."""
    reason = toolchain_missing()
    if reason:
        raise FirmwareSimError(reason)
    BUILD_DIR.mkdir(parents=True, exist_ok=True)
    with open(BUILD_DIR / ".lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        done = subprocess.run(
            ["make", "-s", "-C", str(FIRMWARE_DIR), f"BUILD={BUILD_DIR}", "all"],
            capture_output=True,
            text=True,
            check=False,
        )
    if done.returncode != 0:
        raise FirmwareSimError(f"make -C {FIRMWARE_DIR} failed: {done.stderr.strip().splitlines()[-1:]}")


class SimulatedBooth:
    """``booth_sim`` running the firmware image; use as a context manager or call :meth:`close`.

    Parameters
    ----------
    elf
        The firmware image (built by :func:`build`), with ``channels`` (``CH=``) and PWM ``top``
        (``(1 << BITS) - 1``).
    bootloader_s
        A host's open of :attr:`port` resets the MCU, as a stock Mega's does: the bootloader then
        swallows the host's bytes for this long (wall-clock) before the firmware boots
        (``led_controller/usb_link.py``; the simavr bridge models it in C). Short replies wait for
        the USB-serial chip's latency timer (:data:`FTDI_LATENCY_S`).
    eeprom
        A file keeping the MCU's EEPROM (the booth's serial) across runs of the simulator.
    """

    def __init__(
        self,
        elf: Path = ELF,
        *,
        channels: int = 7,
        top: int = 0xFFFF,
        bootloader_s: float = MEGA_BOOTLOADER_S,
        eeprom: Path | None = None,
    ) -> None:
        self._top = top
        self._channels = channels
        link = ["--bootloader-ms", str(round(bootloader_s * 1000)), "--latency-us", str(round(FTDI_LATENCY_S * 1e6))]
        if eeprom is not None:
            link += ["--eeprom", str(eeprom)]
        self._process = subprocess.Popen(
            [str(HARNESS), *link, str(elf)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            bufsize=1,
        )
        self._answers: queue.Queue[str] = queue.Queue()
        self._pulses: list[TriggerPulse] = []
        self._trace: list[tuple[str, ...]] = []
        self.on_pulse: Callable[[TriggerPulse], None] | None = None
        """Called on the reader thread with each trigger-output pulse as it is seen (keep it short:
        answers to commands wait behind it)."""
        self._lock = threading.Lock()
        self._command_lock = threading.Lock()
        assert self._process.stdout is not None
        port = None
        for line in self._process.stdout:
            if line.startswith("pty "):
                port = line.split()[1]
                break
        if port is None:
            self.close()
            raise FirmwareSimError(f"booth_sim on {elf}: no pseudo-terminal announced; expected 'pty <path>'")
        self.port: str = port
        self._reader = threading.Thread(target=self._read, name=f"booth_sim {port}", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self._process.stdout is not None
        for line in self._process.stdout:
            words = line.split()
            if not words:
                continue
            if words[0] == "pulse":
                pulse = TriggerPulse(
                    float(words[1]), float(words[2]), tuple(float(w) for w in words[3 : 3 + self._channels])
                )
                with self._lock:
                    self._pulses.append(pulse)
                callback = self.on_pulse
                if callback is not None:
                    callback(pulse)
            elif words[0] in ("tx", "tcnt", "expin", "pulse_end"):
                with self._lock:
                    self._trace.append((words[0], *words[1:]))
            elif words[0] in ("ok", "error"):
                self._answers.put(line.strip())

    def _ask(self, command: str, timeout_s: float = 10.0) -> list[str]:
        with self._command_lock:
            assert self._process.stdin is not None
            try:
                self._process.stdin.write(command + "\n")
                self._process.stdin.flush()
            except (OSError, ValueError) as err:
                raise FirmwareSimError(
                    f"booth_sim: cannot send {command!r} ({err}); the simulator has stopped"
                ) from err
            try:
                answer = self._answers.get(timeout=timeout_s)
            except queue.Empty:
                raise FirmwareSimError(f"booth_sim: no answer to {command!r} within {timeout_s:g} s") from None
        if not answer.startswith("ok "):
            raise FirmwareSimError(f"booth_sim: {command!r} answered {answer!r}")
        return answer.split()[2:]

    @property
    def levels(self) -> tuple[float, ...]:
        """Get the LED levels now: each pin's PWM duty (high ticks per period / (TOP + 1)), or 0/1
        for a pin the timer does not drive (the pin model of ``sim/pin_model.c``)."""
        words = self._ask("levels")
        return tuple(float(w) for w in words[1 : 1 + self._channels])

    def now_us(self) -> float:
        """Simulated time in µs."""
        return float(self._ask("levels")[0])

    def expose(self, exposure_us: float, rows: int = 1, line_us: float = 0.0, latency_us: float = 0.0) -> Exposure:
        """A camera exposure starting ``latency_us`` from now (simulated), its flash window driven on
        ExposureActive; returns once its last row is over, with each row's LED on-times."""
        words = self._ask(
            f"expose {exposure_us:.4f} {rows} {line_us:.4f} {latency_us:.4f}",
            timeout_s=self._window_timeout(exposure_us, rows, line_us),
        )
        return self._exposure(words, exposure_us, rows, line_us)

    def integrate(self, start_us: float, exposure_us: float, rows: int = 1, line_us: float = 0.0) -> Exposure:
        """Each row's LED on-times over windows from ``start_us`` (simulated, absolute), once they are over."""
        words = self._ask(
            f"integrate {start_us:.4f} {exposure_us:.4f} {rows} {line_us:.4f}",
            timeout_s=self._window_timeout(exposure_us, rows, line_us),
        )
        return self._exposure(words, exposure_us, rows, line_us)

    def trace(self, on: bool = True) -> None:
        """Record (or stop recording) frame starts, TCNT writes and ExposureActive edges (:meth:`traced`)."""
        self._ask(f"trace {int(on)}")

    def traced(self) -> list[tuple[str, ...]]:
        """The trace lines so far: ``("tx", t_us)``, ``("tcnt", timer, t_us)``, ``("expin", level, t_us)``,
        ``("pulse_end", t_us)`` (a copy; words as text)."""
        with self._lock:
            return list(self._trace)

    @staticmethod
    def _window_timeout(exposure_us: float, rows: int, line_us: float) -> float:
        # Simulated time runs at most as fast as the wall clock: the window plus a margin.
        return 10.0 + 3.0 * (exposure_us + rows * line_us) * 1e-6

    def _exposure(self, words: list[str], exposure_us: float, rows: int, line_us: float) -> Exposure:
        cycles = [int(w) for w in words[1:]]
        if len(cycles) != rows * SIM_CHANNELS or any(c < 0 for c in cycles):
            raise FirmwareSimError(
                f"booth_sim: exposure answer {words[:4]!r}…; expected {rows} rows of {SIM_CHANNELS} on-times"
            )
        on = tuple(
            tuple(c / CYCLES_PER_US for c in cycles[r * SIM_CHANNELS : r * SIM_CHANNELS + self._channels])
            for r in range(rows)
        )
        return Exposure(float(words[0]), float(exposure_us), float(line_us), on)

    @property
    def pulses(self) -> list[TriggerPulse]:
        """Get the trigger-output pulses seen so far (a copy)."""
        with self._lock:
            return list(self._pulses)

    def exposure_active(self, edge: bool) -> None:
        """Drive the camera's ExposureActive input; returns once 2 ms of simulated time served it."""
        self._ask(f"exp {int(edge)}")

    def exposure_wire_loose(self) -> None:
        """Disconnect the ExposureActive wire: the input is then held by the firmware's pull-up, or floats
        (a random level every 100 µs of simulated time, as a real floating input picks up noise)."""
        self._ask("exp float")

    def link(self) -> dict[str, int]:
        """The board's link now: ``opens`` (hosts holding the port), ``resets`` (opens that reset the MCU),
        ``bootloader`` (1 while the bootloader owns the UART)."""
        words = self._ask("link")
        return {"opens": int(words[2]), "resets": int(words[4]), "bootloader": int(words[6])}

    def advance(self, seconds: float) -> None:
        """Wait until ``seconds`` of simulated time have passed (paced to the wall clock)."""
        target = self.now_us() + int(seconds * 1e6)
        while self.now_us() < target:
            time.sleep(0.002)

    def close(self) -> None:
        """Stop the simulator (the pty goes away, as an unplugged board)."""
        if self._process.poll() is None:
            try:
                assert self._process.stdin is not None
                self._process.stdin.write("quit\n")
                self._process.stdin.flush()
                self._process.wait(timeout=5.0)
            except (OSError, subprocess.TimeoutExpired):
                self._process.kill()
                self._process.wait()
        if hasattr(self, "_reader"):
            self._reader.join(timeout=5.0)  # stdout reached its end with the process
        for stream in (self._process.stdin, self._process.stdout):
            if stream is not None:
                try:
                    stream.close()
                except OSError:
                    pass

    def __enter__(self) -> SimulatedBooth:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.close()
