"""``msflash bench --part decode``: decoding packed pixel formats, as ratios to copying Mono16.

Each round decodes one random frame of every packed family (Mono12p, Mono10p, Mono12Packed,
Mono10Packed; the Bayer variants share their code) and copies the same frame's Mono16 payload
into an owned array (what :func:`acquisition.devices.aravis.pixel_layouts.decode_pixels` does for a payload it
cannot keep). Rounds interleave the formats, so a machine busy with other work slows all of
them alike; the medians' ratios are the figures to compare, the milliseconds only this machine's.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np

from msflash.acquisition.devices.aravis.pixel_formats import packed_size, unpack_pixels

FORMATS = ("Mono12p", "Mono10p", "Mono12Packed", "Mono10Packed")
"""One packed format per decoding path and bit depth."""


def decode_bench(width: int = 2448, height: int = 2048, rounds: int = 11, seed: int = 0) -> dict[str, Any]:
    """Median decode time of each packed format and its ratio to copying the Mono16 frame.

    Parameters
    ----------
    width, height
        Frame size (default 5 MP, a common machine-vision sensor); ``width`` a multiple of 4.
    rounds
        Interleaved rounds; the median of each format's times is reported.
    seed
        Seed of the random payloads.

    Returns
    -------
    dict
        ``frame`` (size), ``rounds``, ``mono16_copy_ms`` and per format ``{ms, ratio_to_mono16_copy}``.
    """
    rng = np.random.default_rng(seed)
    payloads = {
        name: rng.integers(0, 256, packed_size(name, width, height), dtype=np.uint8).tobytes() for name in FORMATS
    }
    mono16 = bytearray(rng.integers(0, 256, 2 * width * height, dtype=np.uint8).tobytes())
    times: dict[str, list[float]] = {name: [] for name in (*FORMATS, "Mono16")}
    for _ in range(rounds):
        for name in FORMATS:
            start = time.perf_counter()
            unpack_pixels(payloads[name], name, width, height)
            times[name].append(time.perf_counter() - start)
        start = time.perf_counter()
        np.frombuffer(mono16, dtype="<u2").reshape(height, width).copy()
        times["Mono16"].append(time.perf_counter() - start)
    base = statistics.median(times["Mono16"])
    report: dict[str, Any] = {"frame": f"{width}x{height}", "rounds": rounds, "mono16_copy_ms": base * 1e3}
    for name in FORMATS:
        median = statistics.median(times[name])
        report[name] = {"ms": median * 1e3, "ratio_to_mono16_copy": median / base}
    return report
