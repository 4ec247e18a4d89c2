"""Booth figures for ``msflash bench``: command round trip and pattern upload over a pty."""

from __future__ import annotations

import statistics
import time
from typing import Any

from msflash.led_controller.booth import LedBooth
from msflash.led_controller.emulator import BoothEmulator
from msflash.led_controller.emulator_pty import serve_on_pty


def run_bench(*, round_trips: int = 200, uploads: int = 10, steps: int = 16, channels: int = 8) -> dict[str, Any]:
    """Time the driver against the emulator on a real pseudo-terminal.

    Parameters
    ----------
    round_trips : int
        Number of ``PING`` commands timed.
    uploads : int
        Number of pattern-table uploads timed.
    steps, channels : int
        Size of the uploaded pattern table.

    Returns
    -------
    dict
        ``booth_round_trip_ms_median``, ``booth_round_trip_ms_p95``,
        ``booth_pattern_upload_ms_median`` (``steps`` × ``channels`` table), and the sizes used.
    """
    if round_trips < 1 or uploads < 1 or steps < 1 or channels < 1:
        raise ValueError("run_bench: counts and sizes must be positive; expected integers >= 1")
    names = tuple(f"ch{i}" for i in range(channels))
    emulator = BoothEmulator(names=names, peaks_nm=tuple(400.0 + 40 * i for i in range(channels)), watchdog_s=0)
    table = [[((s + c) % 7) / 6 for c in range(channels)] for s in range(steps)]
    with serve_on_pty(emulator) as server, LedBooth.open(server.port, timeout_s=2.0) as booth:
        booth.ping()  # warm up the link and the threads
        trips = []
        for _ in range(round_trips):
            t0 = time.perf_counter()
            booth.ping()
            trips.append((time.perf_counter() - t0) * 1e3)
        upload = []
        for _ in range(uploads):
            t0 = time.perf_counter()
            booth.load_pattern(table)
            upload.append((time.perf_counter() - t0) * 1e3)
    trips.sort()
    return {
        "booth_round_trip_ms_median": statistics.median(trips),
        "booth_round_trip_ms_p95": trips[min(len(trips) - 1, int(0.95 * len(trips)))],
        "booth_pattern_upload_ms_median": statistics.median(upload),
        "booth_pattern_steps": steps,
        "booth_pattern_channels": channels,
        "booth_round_trips": round_trips,
    }
